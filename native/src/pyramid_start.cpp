// The start of the Newton iteration, from the control positions alone (docs/pyramid.md):
//  1. the controls split into clusters (connected through edges between controls); each
//     cluster of at least three points not on a line gets its best-fit similarity, all of them
//     the best-fit similarity of every control;
//  2. a rotation (unit quaternion) and a log-scale per vertex, harmonic (uniform graph Laplacian)
//     between the clusters that carry one, the overall fit where none does;
//  3. every rest edge rotated and scaled by the mean of its ends' similarities, and the free
//     vertices placed by least squares on those edges (a Poisson solve) with the controls fixed.
// Both solves use matrices that depend on the mesh and the controls only, factored once.
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SparseCore>
#include <cmath>
#include <string>
#include <utility>

#include "matdeform/mesh.hpp"
#include "matdeform/transforms.hpp"
#include "pyramid_internal.hpp"

namespace matdeform {
namespace pyramid {

namespace {
// Pulls the rotation field towards the overall fit where no cluster fixes it (a part whose
// clusters are all single points); negligible next to a Dirichlet condition.
constexpr double kFieldPull = 1e-6;
}  // namespace

struct Start::Impl {
  Vertices rest;
  std::vector<int> control;
  IndexPairs edges;                   // among vertices the controls reach
  std::vector<std::vector<int>> rot;  // clusters that carry a rotation: rows of `control`
  std::vector<int> field_index;       // vertex -> unknown of the field solve, or -1
  std::vector<int> field_vertex;
  std::unique_ptr<SparseCholesky> field;
  std::vector<int> pos_index;  // vertex -> unknown of the Poisson solve (free vertices), or -1
  std::vector<int> pos_vertex;
  std::unique_ptr<SparseCholesky> poisson;
};

Start::Start(const Vertices& rest, const Faces& faces, const std::vector<int>& control,
             const std::vector<char>& is_free)
    : impl_(std::make_unique<Impl>()) {
  Impl& S = *impl_;
  const int n = static_cast<int>(rest.rows());
  S.rest = rest;
  S.control = control;
  std::vector<int> control_row(static_cast<size_t>(n), -1);
  for (size_t j = 0; j < control.size(); ++j)
    control_row[static_cast<size_t>(control[j])] = static_cast<int>(j);
  std::vector<char> active(is_free.begin(), is_free.end());
  for (int c : control) active[static_cast<size_t>(c)] = 1;
  const IndexPairs all = mesh_edges(faces);
  std::vector<int> keep;
  for (Eigen::Index e = 0; e < all.rows(); ++e) {
    if (active[static_cast<size_t>(all(e, 0))] && active[static_cast<size_t>(all(e, 1))]) {
      keep.push_back(static_cast<int>(e));
    }
  }
  S.edges.resize(static_cast<Eigen::Index>(keep.size()), 2);
  for (size_t e = 0; e < keep.size(); ++e)
    S.edges.row(static_cast<Eigen::Index>(e)) = all.row(keep[e]);

  // 1. Control clusters: components of the edges between controls.
  DisjointSets sets(n);
  for (Eigen::Index e = 0; e < S.edges.rows(); ++e) {
    const int a = S.edges(e, 0), b = S.edges(e, 1);
    if (control_row[static_cast<size_t>(a)] >= 0 && control_row[static_cast<size_t>(b)] >= 0) {
      sets.unite(a, b);
    }
  }
  std::vector<std::vector<int>> clusters(static_cast<size_t>(n));
  for (int c : control)
    clusters[static_cast<size_t>(sets.find(c))].push_back(control_row[static_cast<size_t>(c)]);
  std::vector<char> fixed_rotation(static_cast<size_t>(n), 0);
  for (auto& cl : clusters) {
    if (cl.size() < 3) continue;
    Vec3 m = Vec3::Zero();
    for (int j : cl) m += rest.row(control[static_cast<size_t>(j)]).transpose();
    m /= static_cast<double>(cl.size());
    Mat3 Sc = Mat3::Zero();
    for (int j : cl) {
      const Vec3 p = rest.row(control[static_cast<size_t>(j)]).transpose() - m;
      Sc += p * p.transpose();
    }
    const Eigen::SelfAdjointEigenSolver<Mat3> eig(Sc, Eigen::EigenvaluesOnly);
    if (!(eig.eigenvalues()(1) > 1e-12 * eig.eigenvalues()(2))) continue;  // on a line
    for (int j : cl) fixed_rotation[static_cast<size_t>(control[static_cast<size_t>(j)])] = 1;
    S.rot.push_back(std::move(cl));
  }

  // Graph Laplacians restricted to the unknowns of each solve.
  auto laplacian = [&](const std::vector<char>& unknown, std::vector<int>* index,
                       std::vector<int>* vertex, double pull) {
    index->assign(static_cast<size_t>(n), -1);
    vertex->clear();
    for (int v = 0; v < n; ++v) {
      if (unknown[static_cast<size_t>(v)]) {
        (*index)[static_cast<size_t>(v)] = static_cast<int>(vertex->size());
        vertex->push_back(v);
      }
    }
    const int u = static_cast<int>(vertex->size());
    std::vector<Eigen::Triplet<double>> t;
    for (int i = 0; i < u; ++i) t.emplace_back(i, i, pull);
    for (Eigen::Index e = 0; e < S.edges.rows(); ++e) {
      const int a = (*index)[static_cast<size_t>(S.edges(e, 0))];
      const int b = (*index)[static_cast<size_t>(S.edges(e, 1))];
      if (a >= 0) t.emplace_back(a, a, 1.0);
      if (b >= 0) t.emplace_back(b, b, 1.0);
      if (a >= 0 && b >= 0) t.emplace_back(std::max(a, b), std::min(a, b), -1.0);
    }
    Eigen::SparseMatrix<double> L(u, u);
    L.setFromTriplets(t.begin(), t.end());
    return L;
  };
  if (!S.rot.empty()) {
    std::vector<char> unknown(static_cast<size_t>(n), 0);
    for (int v = 0; v < n; ++v)
      unknown[static_cast<size_t>(v)] =
          active[static_cast<size_t>(v)] && !fixed_rotation[static_cast<size_t>(v)];
    const Eigen::SparseMatrix<double> L =
        laplacian(unknown, &S.field_index, &S.field_vertex, kFieldPull);
    if (L.rows() > 0) S.field = std::make_unique<SparseCholesky>(L, SparseCholesky::Reuse::Once);
  }
  const Eigen::SparseMatrix<double> L = laplacian(is_free, &S.pos_index, &S.pos_vertex, 0.0);
  if (L.rows() > 0) S.poisson = std::make_unique<SparseCholesky>(L, SparseCholesky::Reuse::Once);
}

Start::~Start() = default;

Vertices Start::operator()(const Vertices& target, const Vectors3* rotation_vectors) const {
  const Impl& S = *impl_;
  const int n = static_cast<int>(S.rest.rows());
  const size_t k = S.control.size();
  std::vector<Vec3> a(k), b(k);
  for (size_t j = 0; j < k; ++j) {
    a[j] = S.rest.row(S.control[j]).transpose();
    b[j] = target.row(static_cast<Eigen::Index>(j)).transpose();
  }
  Mat3 A;
  Vec3 ca, cb;
  fit_similarity(a, b, &A, &ca, &cb);
  // The overall similarity, as rotation (quaternion) and log-scale.
  auto split = [](const Mat3& M, Eigen::Quaterniond* q, double* log_scale) {
    const double s = std::cbrt(M.determinant());
    if (!(s > 0) || !std::isfinite(s)) {  // targets on one point: nothing to turn or scale by
      *q = Eigen::Quaterniond::Identity();
      *log_scale = 0;
      return;
    }
    *q = Eigen::Quaterniond(Mat3(M / s));
    q->normalize();
    *log_scale = std::log(s);
  };
  Eigen::Quaterniond qg;
  double lg;
  split(A, &qg, &lg);
  // 2. The field: rows (qw, qx, qy, qz, log s) per vertex; with rotation vectors (0, rotation
  // vector, log s) instead: quaternions cannot tell a turn from one and a half, logs can.
  const bool logs = rotation_vectors != nullptr && !S.rot.empty();
  Eigen::Matrix<double, Eigen::Dynamic, 5, Eigen::RowMajor> field(n, 5);
  for (int v = 0; v < n; ++v) field.row(v) << qg.w(), qg.x(), qg.y(), qg.z(), lg;
  Vec3 mean = Vec3::Zero();  // of the clusters' logs
  for (const auto& cl : S.rot) {
    if (!logs && !S.field) break;
    std::vector<Vec3> ac, bc;
    for (int j : cl)
      ac.push_back(a[static_cast<size_t>(j)]), bc.push_back(b[static_cast<size_t>(j)]);
    Mat3 Ac;
    Vec3 u, w;
    fit_similarity(ac, bc, &Ac, &u, &w);
    Eigen::Quaterniond q;
    double l;
    split(Ac, &q, &l);
    if (logs) {
      // The cluster's log nearest to its controls' vectors, each checked against its rotation.
      const Mat3 R = q.toRotationMatrix();
      Vec3 near = Vec3::Zero();
      for (int j : cl) {
        const Vec3 vj = rotation_vectors->row(j).transpose();
        check_rotation_vector(vj, R, "rotation_vectors[" + std::to_string(j) + "]",
                              "the rotation fitted to its control cluster");
        near += vj;
      }
      const Vec3 r = rotation_log_near(R, near / static_cast<double>(cl.size()));
      mean += r;
      for (int j : cl) field.row(S.control[static_cast<size_t>(j)]) << 0.0, r.x(), r.y(), r.z(), l;
    } else {
      // The same hemisphere as the overall fit: the blend then turns the short way from it.
      const double sgn = q.coeffs().dot(qg.coeffs()) < 0 ? -1.0 : 1.0;
      for (int j : cl)
        field.row(S.control[static_cast<size_t>(j)]) << sgn * q.w(), sgn * q.x(), sgn * q.y(),
            sgn * q.z(), l;
    }
  }
  if (logs) {
    // Where no cluster fixes it, the overall fit's log nearest to the clusters' mean.
    const Vec3 rg =
        rotation_log_near(qg.toRotationMatrix(), mean / static_cast<double>(S.rot.size()));
    for (size_t i = 0; i < S.field_vertex.size(); ++i)
      field.row(S.field_vertex[i]) << 0.0, rg.x(), rg.y(), rg.z(), lg;
  }
  if (S.field) {
    const int u = S.field->rows();
    Eigen::Matrix<double, Eigen::Dynamic, 5, Eigen::ColMajor> rhs(u, 5), sol(u, 5);
    for (int i = 0; i < u; ++i)
      rhs.row(i) = kFieldPull * field.row(S.field_vertex[static_cast<size_t>(i)]);
    for (Eigen::Index e = 0; e < S.edges.rows(); ++e) {
      const int va = S.edges(e, 0), vb = S.edges(e, 1);
      const int ia = S.field_index[static_cast<size_t>(va)],
                ib = S.field_index[static_cast<size_t>(vb)];
      if (ia >= 0 && ib < 0) rhs.row(ia) += field.row(vb);
      if (ib >= 0 && ia < 0) rhs.row(ib) += field.row(va);
    }
    S.field->solve(rhs.data(), sol.data(), 5);
    for (int i = 0; i < u; ++i) field.row(S.field_vertex[static_cast<size_t>(i)]) = sol.row(i);
  }
  // Per-vertex similarity s R.
  std::vector<Mat3> T(static_cast<size_t>(n), Mat3::Identity());
  for (int v = 0; v < n; ++v) {
    if (logs) {
      const Vec3 r(field(v, 1), field(v, 2), field(v, 3));
      T[static_cast<size_t>(v)] = std::exp(field(v, 4)) * rotation_exp(r);
      continue;
    }
    Eigen::Quaterniond q(field(v, 0), field(v, 1), field(v, 2), field(v, 3));
    if (!(q.norm() > 1e-6)) q = qg;  // opposite turns cancelled: no rotation to blend
    q.normalize();
    T[static_cast<size_t>(v)] = std::exp(field(v, 4)) * q.toRotationMatrix();
  }
  // 3. Poisson: sum over edges |x_i - x_j - T_ij (r_i - r_j)|^2, controls fixed.
  Vertices X = S.rest;
  for (size_t j = 0; j < k; ++j) X.row(S.control[j]) = target.row(static_cast<Eigen::Index>(j));
  if (!S.poisson) return X;
  const int u = S.poisson->rows();
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::ColMajor> rhs = Eigen::MatrixXd::Zero(u, 3),
                                                            sol(u, 3);
  for (Eigen::Index e = 0; e < S.edges.rows(); ++e) {
    const int va = S.edges(e, 0), vb = S.edges(e, 1);
    const Vec3 t = 0.5 * (T[static_cast<size_t>(va)] + T[static_cast<size_t>(vb)]) *
                   (S.rest.row(va) - S.rest.row(vb)).transpose();
    const int ia = S.pos_index[static_cast<size_t>(va)], ib = S.pos_index[static_cast<size_t>(vb)];
    if (ia >= 0) {
      rhs.row(ia) += t.transpose();
      if (ib < 0) rhs.row(ia) += X.row(vb);
    }
    if (ib >= 0) {
      rhs.row(ib) -= t.transpose();
      if (ia < 0) rhs.row(ib) += X.row(va);
    }
  }
  S.poisson->solve(rhs.data(), sol.data(), 3);
  for (int i = 0; i < u; ++i) X.row(S.pos_vertex[static_cast<size_t>(i)]) = sol.row(i);
  return X;
}

}  // namespace pyramid
}  // namespace matdeform
