// The private factor/solve wrapper, in particular the multi-threaded substitution used per pose.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Eigen/SparseCore>
#include <future>
#include <vector>

#include "matdeform/threads.hpp"
#include "sparse_cholesky.hpp"
#include "test_timeout.hpp"

namespace {

using matdeform::SparseCholesky;

// Graph Laplacian of an nx x ny grid with diagonals (a triangulated sheet), plus `shift` on the
// diagonal, plus a separate path graph of `path` nodes: an SPD matrix whose elimination tree is
// a forest with balanced nested-dissection subtrees.
Eigen::SparseMatrix<double> sheet_and_path(int nx, int ny, int path, double shift) {
  const int n = nx * ny + path;
  std::vector<Eigen::Triplet<double>> t;
  auto edge = [&](int a, int b, double w) {
    t.emplace_back(a, a, w);
    t.emplace_back(b, b, w);
    t.emplace_back(a, b, -w);
    t.emplace_back(b, a, -w);
  };
  for (int y = 0; y < ny; ++y) {
    for (int x = 0; x < nx; ++x) {
      const int v = y * nx + x;
      if (x + 1 < nx) edge(v, v + 1, 1.0 + 0.1 * ((x * 7 + y) % 5));
      if (y + 1 < ny) edge(v, v + nx, 0.5 + 0.1 * ((x + 3 * y) % 4));
      if (x + 1 < nx && y + 1 < ny) edge(v, v + nx + 1, 0.3);
    }
  }
  for (int p = 0; p + 1 < path; ++p) edge(nx * ny + p, nx * ny + p + 1, 2.0);
  for (int v = 0; v < n; ++v) t.emplace_back(v, v, shift * (1 + v % 3));
  Eigen::SparseMatrix<double> A(n, n);
  A.setFromTriplets(t.begin(), t.end());
  return A;
}

Eigen::MatrixXd rhs(int n, int k) {
  Eigen::MatrixXd B(n, k);
  for (int c = 0; c < k; ++c) {
    for (int i = 0; i < n; ++i) B(i, c) = std::sin(0.37 * i + 1.3 * c) + 0.01 * c;
  }
  return B;
}

Eigen::MatrixXd solve(const SparseCholesky& chol, const Eigen::MatrixXd& B) {
  Eigen::MatrixXd X(B.rows(), B.cols());
  chol.solve(B.data(), X.data(), static_cast<int>(B.cols()));
  return X;
}

TEST(SparseCholesky, SmallSystemsMatchDenseLLT) {
  const Eigen::SparseMatrix<double> A = sheet_and_path(6, 5, 7, 1e-2);
  const Eigen::MatrixXd Ad(A);
  for (auto reuse : {SparseCholesky::Reuse::Once, SparseCholesky::Reuse::PerPose}) {
    SparseCholesky chol(A, reuse);
    for (int k : {1, 3, 4, 5, 9}) {
      const Eigen::MatrixXd B = rhs(A.rows(), k);
      const Eigen::MatrixXd expect = Ad.llt().solve(B);
      EXPECT_LT((solve(chol, B) - expect).cwiseAbs().maxCoeff(), 1e-10) << "k=" << k;
    }
  }
}

TEST(SparseCholesky, ParallelSubstitutionMatchesSerial) {
  const Eigen::SparseMatrix<double> A = sheet_and_path(200, 160, 500, 1e-3);
  SparseCholesky chol(A, SparseCholesky::Reuse::PerPose);
  const int before = matdeform::num_threads();
  for (int k : {3, 6}) {
    const Eigen::MatrixXd B = rhs(A.rows(), k);
    matdeform::set_num_threads(1);
    const Eigen::MatrixXd serial = solve(chol, B);
    EXPECT_EQ(chol.substitution_threads(), 1);
    // A X = B to round-off (relative residual), so both paths are checked against the matrix.
    EXPECT_LT((A * serial - B).norm() / B.norm(), 1e-12);
    for (int threads : {2, 3}) {
      matdeform::set_num_threads(threads);
      const Eigen::MatrixXd parallel = solve(chol, B);
#ifdef _OPENMP
      EXPECT_EQ(chol.substitution_threads(), threads);
#endif
      EXPECT_LT((parallel - serial).cwiseAbs().maxCoeff(), 1e-12 * serial.cwiseAbs().maxCoeff());
      EXPECT_LT((A * parallel - B).norm() / B.norm(), 1e-12);
    }
  }
  matdeform::set_num_threads(before);
}

TEST(SparseCholesky, ConcurrentFactorisationsAndSolvesMatchSerialOnes) {
  // Two threads factoring at once got wrong factors (the serial OpenBLAS below CHOLMOD is not
  // safe for concurrent calls); one factor solved from two threads shares its workspace.
  const Eigen::SparseMatrix<double> A = sheet_and_path(120, 120, 50, 1e-3);
  const Eigen::MatrixXd B = rhs(static_cast<int>(A.rows()), 3);
  for (auto reuse : {SparseCholesky::Reuse::Once, SparseCholesky::Reuse::PerPose}) {
    const SparseCholesky shared(A, reuse);
    const Eigen::MatrixXd expect = solve(shared, B);
    auto worker = [&] {
      int wrong = 0;
      for (int rep = 0; rep < 3; ++rep) {
        const SparseCholesky own(A, reuse);
        wrong += solve(own, B) != expect;
        for (int k = 0; k < 5; ++k) wrong += solve(shared, B) != expect;
      }
      return wrong;
    };
    auto a = std::async(std::launch::async, worker), b = std::async(std::launch::async, worker);
    EXPECT_EQ(matdeform::test_timeout::get_or_exit(a, 120, "factor thread a"), 0);
    EXPECT_EQ(matdeform::test_timeout::get_or_exit(b, 120, "factor thread b"), 0);
  }
}

TEST(SparseCholesky, NotPositiveDefiniteThrowsInvalidArgument) {
  // invalid_argument (ValueError in Python) with a message saying what to change.
  Eigen::SparseMatrix<double> A = sheet_and_path(5, 5, 0, 0.0);  // singular: constants
  EXPECT_THROW(SparseCholesky(A, SparseCholesky::Reuse::PerPose), std::invalid_argument);
}

TEST(SparseCholesky, RefactorFactorsNewValuesOnTheAnalysedPattern) {
  // A 1D Laplacian with a shift: refactor with other values, and refuse an indefinite one.
  const int n = 50;
  auto matrix = [&](double shift) {
    std::vector<Eigen::Triplet<double>> t;
    for (int i = 0; i < n; ++i) {
      t.emplace_back(i, i, 2.0 + shift);
      if (i + 1 < n) t.emplace_back(i + 1, i, -1.0);
    }
    Eigen::SparseMatrix<double> A(n, n);
    A.setFromTriplets(t.begin(), t.end());
    A.makeCompressed();
    return A;
  };
  SparseCholesky chol(matrix(0.0), SparseCholesky::Reuse::Refactor);
  EXPECT_EQ(chol.nonzeros(), 2 * n - 1);
  Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(n, -1, 2), x(n);
  EXPECT_THROW(chol.solve(b.data(), x.data(), 1), std::logic_error);  // nothing factored yet
  for (double shift : {0.5, 0.01, 3.0}) {
    const Eigen::SparseMatrix<double> A = matrix(shift);
    ASSERT_TRUE(chol.refactor(A.valuePtr()));
    chol.solve(b.data(), x.data(), 1);
    const Eigen::SparseMatrix<double> full = A.selfadjointView<Eigen::Lower>();
    EXPECT_LT((full * x - b).cwiseAbs().maxCoeff(), 1e-12) << shift;
  }
  EXPECT_FALSE(chol.refactor(matrix(-3.0).valuePtr()));
  EXPECT_THROW(chol.solve(b.data(), x.data(), 1), std::logic_error);
  Eigen::SparseMatrix<double> bad = matrix(1.0);
  bad.valuePtr()[3] = std::nan("");
  EXPECT_FALSE(chol.refactor(bad.valuePtr()));
}

}  // namespace
