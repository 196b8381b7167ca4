#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <stdexcept>

#include "matdeform/mesh.hpp"
#include "matdeform/pyramid_deformer.hpp"
#include "matdeform/threads.hpp"
#include "pyramid_internal.hpp"
#include "test_meshes.hpp"
#include "test_permutation.hpp"

using namespace matdeform;

namespace {
double diagonal(const Vertices& V) {
  return (V.colwise().maxCoeff() - V.colwise().minCoeff()).norm();
}

// A grid with a bump (open, boundary and valence-2 corners).
void bumpy_grid(int nx, int ny, Vertices* V, Faces* F) {
  meshes::make_grid(nx, ny, V, F);
  for (Eigen::Index v = 0; v < V->rows(); ++v) {
    const double x = (*V)(v, 0) - nx / 2.0, y = (*V)(v, 1) - ny / 2.0;
    (*V)(v, 2) = 1.5 * std::exp(-(x * x + y * y) / 12.0);
  }
}

}  // namespace

TEST(VertexFans, ClosedOpenAndOrderedByFaces) {
  Vertices V;
  Faces F;
  meshes::make_grid(2, 2, &V, &F);
  const VertexFans fans = vertex_fans(static_cast<int>(V.rows()), F);
  // Centre vertex 4 of the 3x3 grid: a closed fan of six neighbours, each consecutive pair a face
  // in the faces' own orientation.
  EXPECT_EQ(fans.kind[4], kFanClosed);
  ASSERT_EQ(fans.offsets[5] - fans.offsets[4], 6);
  for (int i = 0; i < 6; ++i) {
    const int a = fans.ring[fans.offsets[4] + i], b = fans.ring[fans.offsets[4] + (i + 1) % 6];
    bool found = false;
    for (Eigen::Index f = 0; f < F.rows(); ++f)
      for (int k = 0; k < 3; ++k)
        found |= F(f, k) == 4 && F(f, (k + 1) % 3) == a && F(f, (k + 2) % 3) == b;
    EXPECT_TRUE(found) << a << " " << b;
  }
  EXPECT_EQ(fans.kind[1], kFanOpen);
  EXPECT_EQ(fans.kind[0], kFanOpen);  // corner: open fan with one or two faces
}

TEST(VertexFans, NonManifoldAndIsolated) {
  // Three triangles on the edge (0,1), and vertex 5 in no face.
  Vertices V = Vertices::Zero(6, 3);
  Faces F(3, 3);
  F << 0, 1, 2, 1, 0, 3, 0, 1, 4;
  const VertexFans fans = vertex_fans(6, F);
  EXPECT_EQ(fans.kind[0], kFanNonManifold);
  EXPECT_EQ(fans.kind[1], kFanNonManifold);
  EXPECT_EQ(fans.kind[2], kFanOpen);
  EXPECT_EQ(fans.kind[5], kFanIsolated);
  EXPECT_EQ(fans.offsets[6] - fans.offsets[5], 0);
}

namespace {
// A closed tube along x (rings of `around` vertices, `rings` of them, radius 0.5, length
// `length`), capped by a fan around a centre vertex at each end (the last two vertices).
void tube(int around, int rings, double length, Vertices* V, Faces* F) {
  const double kPi = 3.14159265358979323846;
  *V = Vertices(around * rings + 2, 3);
  for (int i = 0; i < rings; ++i) {
    for (int j = 0; j < around; ++j) {
      const double a = 2 * kPi * j / around;
      V->row(i * around + j) << length * i / (rings - 1), 0.5 * std::cos(a), 0.5 * std::sin(a);
    }
  }
  const int c0 = around * rings, c1 = c0 + 1;
  V->row(c0) << 0, 0, 0;
  V->row(c1) << length, 0, 0;
  *F = Faces(2 * around * (rings - 1) + 2 * around, 3);
  int f = 0;
  for (int i = 0; i + 1 < rings; ++i) {
    for (int j = 0; j < around; ++j) {
      const int a = i * around + j, b = i * around + (j + 1) % around;
      F->row(f++) << a, b, b + around;
      F->row(f++) << a, b + around, a + around;
    }
  }
  for (int j = 0; j < around; ++j) {
    F->row(f++) << c0, (j + 1) % around, j;
    F->row(f++) << c1, (rings - 1) * around + j, (rings - 1) * around + (j + 1) % around;
  }
}

Vertices rows_of(const Vertices& X, const std::vector<int>& ids) {
  Vertices C(static_cast<Eigen::Index>(ids.size()), 3);
  for (size_t j = 0; j < ids.size(); ++j) C.row(static_cast<Eigen::Index>(j)) = X.row(ids[j]);
  return C;
}

// The tube's two end rings as controls, the far one turned by `angle` about z around its centre
// and moved: a bend.
std::vector<int> bent_tube(double angle, Vertices* V, Faces* F, Vertices* targets) {
  tube(10, 25, 6.0, V, F);
  std::vector<int> control;
  for (int j = 0; j < 10; ++j) control.push_back(j), control.push_back(24 * 10 + j);
  *targets = rows_of(*V, control);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  for (Eigen::Index j = 1; j < targets->rows(); j += 2) {
    targets->row(j) = (R * (targets->row(j).transpose() - Eigen::Vector3d(6, 0, 0))).transpose() +
                      Eigen::RowVector3d(6 - 0.8 * angle, 1.2 * angle, 0);
  }
  return control;
}
}  // namespace

TEST(PyramidDeformer, ReconstructsTheRestMeshAndKeepsItAtRest) {
  Vertices V;
  Faces F;
  bumpy_grid(10, 8, &V, &F);
  const std::vector<int> control = {0, 10, 88, 98, 49};
  PyramidDeformer d(V, F, control);
  const double diag = diagonal(V);
  EXPECT_LT((d.reconstruct(V, false) - V).cwiseAbs().maxCoeff(), 1e-10 * diag);
  EXPECT_LT((d.reconstruct(V, true) - V).cwiseAbs().maxCoeff(), 1e-10 * diag);
  // The rest pose is the minimum (energy 0): the start is the rest mesh and one Newton step
  // of size 0 confirms it.
  PyramidSolveOptions o;
  const Vertices X = d.deform(rows_of(V, control), o);
  EXPECT_LT((X - V).cwiseAbs().maxCoeff(), 1e-12 * diag);
  EXPECT_EQ(d.last_iterations(), 1);
  EXPECT_TRUE(d.last_converged());
  EXPECT_LT(d.last_energy(), 1e-24 * diag * diag);
}

TEST(PyramidDeformer, RigidControlsGiveTheMovedRestMesh) {
  Vertices V, T;
  Faces F;
  const std::vector<int> control = bent_tube(0.0, &V, &F, &T);
  PyramidDeformer d(V, F, control);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.9, Eigen::Vector3d(1, 2, -1).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(0.5, -1.0, 2.0);
  for (double scale : {1.0, 1.4}) {
    const Vertices expect = (scale * V * R.transpose()).rowwise() + t;
    PyramidSolveOptions o;
    // A similarity is a minimum of energy 0 only when size is free.
    o.scale_weight = scale == 1.0 ? 0.003 : 0.0;
    Vertices X = d.deform(rows_of(expect, control), o);
    EXPECT_LT((X - expect).cwiseAbs().maxCoeff(), 1e-12 * diagonal(expect)) << scale;
    EXPECT_TRUE(d.last_converged());
    EXPECT_LE(d.last_iterations(), 1);
    // From a perturbed start Newton's method returns to it.
    Vertices start = expect;
    for (Eigen::Index v = 0; v < start.rows(); ++v) start(v, 1) += 0.02 * std::sin(3.0 * v);
    o.initial = &start;
    X = d.deform(rows_of(expect, control), o);
    EXPECT_LT((X - expect).cwiseAbs().maxCoeff(), 1e-10 * diagonal(expect)) << scale;
    EXPECT_TRUE(d.last_converged());
    EXPECT_LE(d.last_iterations(), 6);
  }
}

// The gradient against central differences of the energy, and each pyramid's Hessian terms
// against central differences of the gradient, on a tube bent far from rest with a random
// perturbation (pyramids stretched, compressed and turned), with and without the size term.
TEST(PyramidDeformer, GradientAndHessianMatchFiniteDifferences) {
  Vertices V, T;
  Faces F;
  const std::vector<int> control = bent_tube(1.2, &V, &F, &T);
  PyramidDeformer d(V, F, control);
  PyramidSolveOptions o;
  o.max_iterations = 2;
  Vertices X = d.deform(T, o);
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.05);
  for (Eigen::Index v = 0; v < X.rows(); ++v)
    for (int c = 0; c < 3; ++c) X(v, c) += noise(rng);
  const pyramid::Placement pl(V, F);
  const pyramid::Pyramids P = pyramid::make_pyramids(V, pl.coords, std::vector<char>(V.rows(), 1));
  ASSERT_EQ(P.count(), V.rows());
  for (double kappa : {0.0, 0.3}) {
    Vertices g;
    d.energy(X, kappa, &g);
    Vertices D(X.rows(), 3);
    for (Eigen::Index v = 0; v < X.rows(); ++v)
      for (int c = 0; c < 3; ++c) D(v, c) = noise(rng);
    const double h = 1e-6;
    const double fd =
        (d.energy(X + h * D, kappa, nullptr) - d.energy(X - h * D, kappa, nullptr)) / (2 * h);
    const double an = (g.array() * D.array()).sum();
    EXPECT_NEAR(fd, an, 1e-6 * std::abs(an)) << kappa;
    double worst = 0, scale = 0;
    std::vector<double> u, coef(pyramid::kTerms);
    for (int c = 0; c < P.count(); ++c) {
      const int b = P.offsets[c], M = P.offsets[c + 1] - b;
      u.assign(static_cast<size_t>(pyramid::kTerms * 3 * M), 0.0);
      const pyramid::Fit fit = pyramid::fit_pyramid(P, c, X.data(), kappa);
      pyramid::hessian_terms(P, c, fit, kappa, true, u.data(), coef.data());
      // H Dc from the terms: 2 (Dc - mean) - sum_q coef_q u_q (u_q . Dc).
      Eigen::VectorXd Dc(3 * M), Hd(3 * M);
      for (int k = 0; k < M; ++k) Dc.segment<3>(3 * k) = D.row(P.members[b + k]).transpose();
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (int k = 0; k < M; ++k) mean += Dc.segment<3>(3 * k) / M;
      for (int k = 0; k < M; ++k) Hd.segment<3>(3 * k) = 2 * (Dc.segment<3>(3 * k) - mean);
      for (int q = 0; q < pyramid::kTerms; ++q) {
        const Eigen::Map<const Eigen::VectorXd> uq(u.data() + q * 3 * M, 3 * M);
        Hd -= coef[q] * uq.dot(Dc) * uq;
      }
      // The pyramid's own gradient at X +- h D.
      auto grad = [&](double s) {
        Vertices Y = X + s * D;
        const pyramid::Fit f = pyramid::fit_pyramid(P, c, Y.data(), kappa);
        Eigen::VectorXd out(3 * M);
        for (int k = 0; k < M; ++k) {
          const Eigen::Vector3d p(P.rest[3 * (b + k)], P.rest[3 * (b + k) + 1],
                                  P.rest[3 * (b + k) + 2]);
          out.segment<3>(3 * k) =
              2 * (Y.row(P.members[b + k]).transpose() - f.centre - f.scale * (f.R * p));
        }
        return out;
      };
      const Eigen::VectorXd fdH = (grad(1e-6) - grad(-1e-6)) / 2e-6;
      worst = std::max(worst, (fdH - Hd).cwiseAbs().maxCoeff());
      scale = std::max(scale, fdH.cwiseAbs().maxCoeff());
    }
    EXPECT_LT(worst, 1e-5 * scale) << kappa;
  }
}

// The positive semidefinite version: no negative eigenvalue, and equal to the exact Hessian
// where the exact one already has none (a pyramid moved by a similarity).
TEST(PyramidDeformer, ProjectedHessianIsPositiveSemidefinite) {
  Vertices V, T;
  Faces F;
  const std::vector<int> control = bent_tube(0.0, &V, &F, &T);
  const pyramid::Placement pl(V, F);
  const pyramid::Pyramids P = pyramid::make_pyramids(V, pl.coords, std::vector<char>(V.rows(), 1));
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.15);
  Vertices X = V;
  for (Eigen::Index v = 0; v < X.rows(); ++v)
    for (int c = 0; c < 3; ++c) X(v, c) += noise(rng);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Vertices W = 1.3 * V * R.transpose();
  auto dense = [&](const Vertices& Y, int c, bool exact, double kappa, bool* clamped) {
    const int M = P.offsets[c + 1] - P.offsets[c];
    std::vector<double> u(static_cast<size_t>(pyramid::kTerms * 3 * M)), coef(pyramid::kTerms);
    const pyramid::Fit fit = pyramid::fit_pyramid(P, c, Y.data(), kappa);
    *clamped = pyramid::hessian_terms(P, c, fit, kappa, exact, u.data(), coef.data());
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(3 * M, 3 * M);
    for (int k = 0; k < M; ++k)
      for (int l = 0; l < M; ++l)
        H.block<3, 3>(3 * k, 3 * l) = 2 * ((k == l) - 1.0 / M) * Eigen::Matrix3d::Identity();
    for (int q = 0; q < pyramid::kTerms; ++q) {
      const Eigen::Map<const Eigen::VectorXd> uq(u.data() + q * 3 * M, 3 * M);
      H -= coef[q] * uq * uq.transpose();
    }
    return H;
  };
  int clamped_count = 0;
  for (int c = 0; c < P.count(); ++c) {
    bool clamped;
    const Eigen::MatrixXd Hp = dense(X, c, false, 0.003, &clamped);
    clamped_count += clamped;
    EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(Hp).eigenvalues().minCoeff(), -1e-9);
    const Eigen::MatrixXd A = dense(W, c, false, 0.0, &clamped);
    EXPECT_FALSE(clamped);
    const Eigen::MatrixXd B = dense(W, c, true, 0.0, &clamped);
    EXPECT_LT((A - B).cwiseAbs().maxCoeff(), 1e-9);
  }
  EXPECT_GT(clamped_count, 0);  // the noise compressed some pyramids: the clamp did something
}

// Newton's method proper converges quadratically: each of the last steps is at most a constant
// times the square of the one before (a wrong Hessian term gives linear convergence).
TEST(PyramidDeformer, ConvergesQuadraticallyOnABentTube) {
  Vertices V, T;
  Faces F;
  const std::vector<int> control = bent_tube(1.0, &V, &F, &T);
  PyramidDeformer d(V, F, control);
  PyramidSolveOptions o;
  o.tol = 1e-10;  // about the round-off floor of the steps (~1e-12 here)
  const Vertices X = d.deform(T, o);
  ASSERT_TRUE(d.last_converged());
  const std::vector<double>& s = d.last_steps();
  // The L-BFGS phase ends with steps below 1e-4 of the diagonal; Newton's method then needs a
  // few iterations (a wrong inverse-Hessian update in that phase leaves it far longer).
  EXPECT_GT(d.last_lbfgs_iterations(), 0);
  EXPECT_LE(d.last_lbfgs_iterations(), 40);
  ASSERT_GE(s.size(), 3u);
  EXPECT_LE(s.size(), 4u);
  const size_t n = s.size();
  EXPECT_LT(s[n - 1], 1e-10);
  // Each step at most a few times the square of the one before, down to round-off.
  for (size_t i = n - 3; i + 1 < n; ++i) {
    EXPECT_LT(s[i + 1], 20 * s[i] * s[i] + 1e-11) << i << ": " << s[i] << " -> " << s[i + 1];
  }
  Vertices g;
  d.energy(X, o.scale_weight, &g);
  double gmax = 0;
  for (Eigen::Index v = 0; v < X.rows(); ++v) {
    if (std::find(control.begin(), control.end(), v) == control.end()) {
      gmax = std::max(gmax, g.row(v).norm());
    }
  }
  EXPECT_LT(gmax, 1e-11);
}

TEST(PyramidDeformer, SameResultUnderRelabellingAndThreadCounts) {
  Vertices V, T;
  Faces F;
  const std::vector<int> control = bent_tube(1.4, &V, &F, &T);
  PyramidDeformer d(V, F, control);
  PyramidSolveOptions o;
  const int before = num_threads();
  set_num_threads(2);
  const Vertices X = d.deform(T, o);
  ASSERT_TRUE(d.last_converged());
  set_num_threads(1);
  const Vertices X1 = d.deform(T, o);
  set_num_threads(before);
  EXPECT_EQ((X - X1).cwiseAbs().maxCoeff(), 0.0);
  std::mt19937 rng(11);
  for (int trial = 0; trial < 3; ++trial) {
    const permutation::Relabelling r = permutation::relabel(V, F, rng);
    PyramidDeformer e(r.vertices, r.faces, r.vertex_ids(control));
    const Vertices Y = e.deform(T, o);
    EXPECT_LT(permutation::max_permuted_error(X, Y, r), 1e-9);
  }
}

TEST(PyramidDeformer, APartWithoutControlsStaysExactlyAtRest) {
  Vertices A, B, T;
  Faces FA, FB;
  const std::vector<int> control = bent_tube(0.8, &A, &FA, &T);
  bumpy_grid(5, 4, &B, &FB);
  Vertices V(A.rows() + B.rows(), 3);
  V << A, (B.rowwise() + Eigen::RowVector3d(0, 5, 0));
  Faces F(FA.rows() + FB.rows(), 3);
  F << FA, (FB.array() + static_cast<int>(A.rows())).matrix();
  PyramidDeformer d(V, F, control);
  EXPECT_EQ(d.num_passive(), B.rows());
  PyramidSolveOptions o;
  for (int warm = 0; warm < 2; ++warm) {
    Vertices start = V * 1.5;  // also a warm start elsewhere puts the island back at rest
    o.initial = warm ? &start : nullptr;
    const Vertices X = d.deform(T, o);
    EXPECT_TRUE(d.last_converged());
    for (Eigen::Index v = A.rows(); v < V.rows(); ++v) {
      for (int c = 0; c < 3; ++c) EXPECT_EQ(X(v, c), V(v, c)) << v;
    }
  }
}

// Placement commutes with a similarity for every vertex kind, followers included: the grid's
// valence-2 corners (a planar fit: follow()'s SVD path) and a folded fan (its polar path).
TEST(PyramidDeformer, PlacementCommutesWithASimilarity) {
  Vertices V;
  Faces F;
  bumpy_grid(7, 6, &V, &F);
  V(8 * 3 + 4, 0) += 1.4;  // past its ring: a folded fan, a follower with a full-rank fit
  PyramidDeformer d(V, F, {0});
  int followers = 0;
  for (signed char k : d.coordinates().kind) followers += k == kPyramidFollower;
  ASSERT_GE(followers, 5);
  ASSERT_EQ(d.coordinates().kind[8 * 3 + 4], kPyramidFollower);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.3, -1, 0.6).normalized()).toRotationMatrix();
  for (double scale : {0.6, 1.0, 2.5}) {
    const Vertices W = (scale * V * R.transpose()).rowwise() + Eigen::RowVector3d(-1, 4, 2);
    for (bool stretch : {false, true}) {
      EXPECT_LT((d.reconstruct(W, stretch) - W).cwiseAbs().maxCoeff(), 1e-10 * diagonal(W))
          << scale << " " << stretch;
    }
  }
}

TEST(PyramidDeformer, DescriptionInvariantUnderSimilarity) {
  Vertices V;
  Faces F;
  bumpy_grid(6, 5, &V, &F);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(0.2, 1, 0.4).normalized()).toRotationMatrix();
  const Vertices W = (2.5 * V * R.transpose()).rowwise() + Eigen::RowVector3d(1, 2, 3);
  const PyramidCoordinates a = pyramid_coordinates(V, F), b = pyramid_coordinates(W, F);
  ASSERT_EQ(a.alpha.size(), b.alpha.size());
  for (size_t s = 0; s < a.alpha.size(); ++s) {
    EXPECT_NEAR(a.alpha[s], b.alpha[s], 1e-10);
    EXPECT_NEAR(a.beta[s], b.beta[s], 1e-10);
    EXPECT_NEAR(2.5 * a.length[s], b.length[s], 1e-10);
  }
}

TEST(PyramidDeformer, BadInputThrows) {
  Vertices V;
  Faces F;
  meshes::make_bar(4, 4.0, &V, &F);
  const int n = static_cast<int>(V.rows());
  EXPECT_THROW(PyramidDeformer(V, F, {}), std::invalid_argument);
  EXPECT_THROW(PyramidDeformer(V, F, {n}), std::invalid_argument);
  EXPECT_THROW(PyramidDeformer(V, F, {-1}), std::invalid_argument);
  EXPECT_THROW(PyramidDeformer(V, F, {2, 2}), std::invalid_argument);
  Faces G = F;
  G(0, 1) = n + 3;
  EXPECT_THROW(PyramidDeformer(V, G, {0}), std::invalid_argument);
  Vertices U = V;
  U(1, 1) = std::nan("");
  EXPECT_THROW(PyramidDeformer(U, F, {0}), std::invalid_argument);
  PyramidDeformer d(V, F, {0, 1});
  PyramidSolveOptions o;
  EXPECT_THROW(d.deform(Vertices::Zero(3, 3), o), std::invalid_argument);
  Vertices C = Vertices::Zero(2, 3);
  C(0, 0) = INFINITY;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  C(0, 0) = 1e60;  // beyond the core's size range: "rescale the mesh", not inf or NaN
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  C(0, 0) = 0;
  o.max_iterations = -1;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  o.max_iterations = 5;
  o.tol = -1;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  o.tol = 1e-6;
  o.scale_weight = std::nan("");
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  o.scale_weight = 0.003;
  const Vertices wrong = Vertices::Zero(3, 3);
  o.initial = &wrong;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  const Vertices huge = V * 1e200;
  o.initial = &huge;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  EXPECT_THROW(d.reconstruct(wrong, false), std::invalid_argument);
  EXPECT_THROW(d.energy(wrong, 0.0, nullptr), std::invalid_argument);
}
