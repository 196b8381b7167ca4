// Step 2 of the pose-space method: vertex positions whose deformation gradients best match the
// per-face targets R_i S_i (Sumner-Popovic frames with the fourth vertex eliminated per face),
// with the handle rows as penalties and frozen vertices fixed. The matrix is constant and
// factored once per set of rows. See docs/pose_space.md, "Step 2: positions".
#include <Eigen/Dense>
#include <Eigen/SparseCore>
#include <algorithm>
#include <string>

#include "matdeform/frames.hpp"
#include "matdeform/mesh.hpp"
#include "pose_space_internal.hpp"

namespace matdeform {
namespace pose_space {

GradientOperator::GradientOperator(const Vertices& V, const Faces& F, bool area_weights) {
  const Eigen::Index m = F.rows();
  Gp.resize(m);
  Hp.resize(m);
  Eigen::VectorXd weight = Eigen::VectorXd::Ones(m);
  if (area_weights) {
    weight = double_areas(V, F);
    weight /= weight.mean();
  }
  Eigen::VectorXd diag = Eigen::VectorXd::Zero(V.rows());
  for (Eigen::Index i = 0; i < m; ++i) {
    const Mat3 Vf = face_frame(V.row(F(i, 0)), V.row(F(i, 1)), V.row(F(i, 2)));
    Eigen::FullPivLU<Mat3> lu(Vf);
    if (!lu.isInvertible()) {
      fail("faces[" + std::to_string(i) + "] is degenerate (zero area) in the rest mesh");
    }
    const Mat3 Einv = lu.inverse();
    Eigen::Matrix<double, 4, 3> G;
    G.row(0) = -Einv.colwise().sum();
    G.bottomRows<3>() = Einv;
    const Eigen::Matrix4d H = G * G.transpose();
    const Eigen::Vector3d h = H.block<3, 1>(0, 3);
    const double hdd = H(3, 3);
    Gp[i] = weight(i) * (G.topRows<3>() - (h / hdd) * G.row(3));
    Hp[i] = weight(i) * (H.topLeftCorner<3, 3>() - h * h.transpose() / hdd);
    for (int l = 0; l < 3; ++l) diag(F(i, l)) += Hp[i](l, l);
  }
  mean_diagonal = diag.mean();
}

PositionSolver::PositionSolver(const Vertices& rest, const Faces& F, const GradientOperator& grad,
                               std::vector<int> fixed, const std::vector<Row>& rows, double lambda,
                               const std::vector<int>& part)
    : rest_(rest), F_(F), grad_(grad), rows_(rows), lambda_(lambda) {
  const int n = static_cast<int>(rest.rows());
  const int parts = n > 0 ? *std::max_element(part.begin(), part.end()) + 1 : 0;
  std::vector<char> held(parts, 0);
  for (int v : fixed) held[part[v]] = 1;
  for (const Row& row : rows)
    for (int v : row.idx) held[part[v]] = 1;
  std::vector<std::vector<int>> members(parts);
  for (int v = 0; v < n; ++v) members[part[v]].push_back(v);
  for (int c = 0; c < parts; ++c) {
    if (held[c] || members[c].empty()) continue;
    fixed.push_back(members[c][0]);
    gauge_.push_back(std::move(members[c]));
  }
  unknown_.assign(n, 0);
  for (int v : fixed) unknown_[v] = -1;
  int u = 0;
  for (int v = 0; v < n; ++v) {
    if (unknown_[v] >= 0) unknown_[v] = u++;
  }
  num_unknowns_ = u;
  std::vector<int> fixed_index(n, -1);
  std::vector<int> fixed_list;
  for (int v = 0; v < n; ++v) {
    if (unknown_[v] < 0) {
      fixed_index[v] = static_cast<int>(fixed_list.size());
      fixed_list.push_back(v);
    }
  }
  std::vector<Eigen::Triplet<double>> kff, kfx;
  auto add = [&](int a, int b, double val) {
    const int ua = unknown_[a], ub = unknown_[b];
    if (ua < 0) return;
    if (ub >= 0) {
      if (ua >= ub) kff.emplace_back(ua, ub, val);
    } else {
      kfx.emplace_back(ua, fixed_index[b], val);
    }
  };
  for (Eigen::Index i = 0; i < F.rows(); ++i)
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) add(F(i, a), F(i, b), grad.Hp[i](a, b));
  for (const Row& row : rows)
    for (size_t a = 0; a < row.idx.size(); ++a)
      for (size_t b = 0; b < row.idx.size(); ++b)
        add(row.idx[a], row.idx[b], lambda * row.beta[a] * row.beta[b]);
  Eigen::SparseMatrix<double> K(u, u), Kx(u, static_cast<int>(fixed_list.size()));
  K.setFromTriplets(kff.begin(), kff.end());
  Kx.setFromTriplets(kfx.begin(), kfx.end());
  const Vertices xf = gather_rows(rest, fixed_list);
  c0_ = Kx * xf;  // the fixed vertices always sit at rest
  if (u > 0) chol_ = std::make_unique<SparseCholesky>(K, SparseCholesky::Reuse::PerPose);
}

void PositionSolver::solve(const Matrix3Array& T, const Vertices* row_targets,
                           Vertices* out) const {
  const int u = num_unknowns_;
  Eigen::Matrix<double, Eigen::Dynamic, 3> B = -c0_;
  for (Eigen::Index i = 0; i < F_.rows(); ++i) {
    const Mat3 TG = T[i] * grad_.Gp[i].transpose();  // column l: the term of corner l
    for (int l = 0; l < 3; ++l) {
      const int uv = unknown_[F_(i, l)];
      if (uv >= 0) B.row(uv) += TG.col(l).transpose();
    }
  }
  for (size_t q = 0; q < rows_.size(); ++q) {
    const Row& row = rows_[q];
    for (size_t a = 0; a < row.idx.size(); ++a) {
      const int uv = unknown_[row.idx[a]];
      if (uv >= 0) B.row(uv) += lambda_ * row.beta[a] * row_targets->row(q);
    }
  }
  Eigen::Matrix<double, Eigen::Dynamic, 3> X(u, 3);
  if (u > 0) chol_->solve(B.data(), X.data(), 3);
  *out = rest_;
  for (Eigen::Index v = 0; v < rest_.rows(); ++v) {
    if (unknown_[v] >= 0) out->row(v) = X.row(unknown_[v]);
  }
  for (const std::vector<int>& vs : gauge_) {
    const Eigen::RowVector3d shift =
        gather_rows(rest_, vs).colwise().mean() - gather_rows(*out, vs).colwise().mean();
    for (int v : vs) out->row(v) += shift;
  }
}

}  // namespace pose_space
}  // namespace matdeform
