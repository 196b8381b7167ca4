// Step 1 of the pose-space method: absolute per-face rotations from the blended relative ones.
//
// Links (dual edges with the blended relative rotations Q, rotational pairs with the prescribed
// joint rotations G) and penalties (faces inside a translational handle pulled to its fitted
// rotation) ask R_b = R_a Q_l and R_f = Z_f. The chordal energy (the paper's linear step,
// RotationSolver::solve) is solved by conjugate gradients in a gauge made by Gauss-Newton steps
// of the geodesic energy (RotationSolver::solve_log), both preconditioned / solved with the
// scalar face-graph Laplacian factored once; the results are projected to rotations
// (nearest_rotation). See docs/pose_space.md, "Step 1: rotations".
#include <Eigen/Dense>
#include <Eigen/SparseCore>
#include <algorithm>
#include <cmath>
#include <functional>
#include <queue>
#include <tuple>

#include "matdeform/transforms.hpp"
#include "pose_space_internal.hpp"
#include "task_pool.hpp"

namespace matdeform {
namespace pose_space {

// Nearest proper rotation in the Frobenius norm (the rotation factor of the polar
// decomposition). Least-squares rotations come out near-orthogonal up to a scale (averages of
// rotations shrink). Scaled Newton steps X <- (g X + X^-T / g) / 2, g = det(X)^(-1/3), remove
// the scale and converge for any det > 0; once X is close to orthogonal, Newton-Schulz steps
// X <- X (3 I - X^T X) / 2 finish without divisions. det <= 0 goes through an SVD.
Mat3 nearest_rotation(const Mat3& M) {
  if (!M.allFinite()) return Mat3::Identity();
  Mat3 X = M;
  for (int it = 0; it < 40; ++it) {
    const Mat3 E = X.transpose() * X - Mat3::Identity();
    const double err = E.cwiseAbs().maxCoeff();
    if (err < 1e-15) return X;
    if (err < 0.1) {
      X -= 0.5 * X * E;
      continue;
    }
    const double d = X.determinant();
    if (!(d > 0.0)) break;
    const double g = 1.0 / std::cbrt(d);
    X = 0.5 * (g * X + X.inverse().transpose() / g);
  }
  Eigen::JacobiSVD<Mat3> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 U = svd.matrixU();
  const Mat3 V = svd.matrixV();
  if ((U * V.transpose()).determinant() < 0.0) U.col(2) = -U.col(2);
  return U * V.transpose();
}

namespace {

// rotation_log for the small residual rotations of the per-edit loops: the axis-angle vector
// from the skew part, theta / sin(theta) by its series below 0.1 rad; larger angles use
// rotation_log (exact up to pi).
inline Vec3 small_log(const Mat3& R) {
  const Vec3 v(0.5 * (R(2, 1) - R(1, 2)), 0.5 * (R(0, 2) - R(2, 0)), 0.5 * (R(1, 0) - R(0, 1)));
  const double s2 = v.squaredNorm();  // sin^2(theta)
  const double c = 0.5 * (R.trace() - 1.0);
  if (c > 0.995 && s2 < 0.01) {
    // asin(s)/s = 1 + s^2/6 + 3 s^4/40 + 5 s^6/112 + 35 s^8/1152 (error < 3e-12 for s < 0.1)
    return v * (1.0 + s2 * (1.0 / 6 + s2 * (3.0 / 40 + s2 * (5.0 / 112 + s2 * (35.0 / 1152)))));
  }
  return rotation_log(R);
}

}  // namespace

RotationSolver::RotationSolver(int m, const IndexPairs& dual,
                               const std::vector<std::array<int, 2>>& pairs, double pair_weight,
                               const std::vector<int>& fixed, const std::vector<int>& tree_roots,
                               const std::vector<int>& penalty_faces, double penalty_weight,
                               const std::vector<double>& edge_cost,
                               const std::vector<double>& edge_weight)
    : m_(m), num_dual_(static_cast<int>(dual.rows())) {
  const int E = num_dual_, r = static_cast<int>(pairs.size());
  la_.resize(E + r);
  lb_.resize(E + r);
  lw_.resize(E + r);
  for (int e = 0; e < E; ++e) {
    la_[e] = dual(e, 0);
    lb_[e] = dual(e, 1);
    lw_[e] = edge_weight.empty() ? 1.0 : edge_weight[e];
  }
  for (int q = 0; q < r; ++q) {
    la_[E + q] = pairs[q][0];
    lb_[E + q] = pairs[q][1];
    lw_[E + q] = pair_weight;
  }
  penalty_.assign(m, 0.0);
  for (int f : penalty_faces) penalty_[f] = penalty_weight;
  unknown_.assign(m, 0);
  for (int f : fixed) unknown_[f] = -1;
  for (int f = 0; f < m; ++f) {
    if (unknown_[f] >= 0) {
      unknown_[f] = static_cast<int>(faces_.size());
      faces_.push_back(f);
    }
  }
  const int u = static_cast<int>(faces_.size());
  // Per unknown face: its links (gather form, so the operator runs in parallel race-free).
  std::vector<int> count(u + 1, 0);
  for (int l = 0; l < E + r; ++l) {
    if (unknown_[la_[l]] >= 0) ++count[unknown_[la_[l]] + 1];
    if (unknown_[lb_[l]] >= 0) ++count[unknown_[lb_[l]] + 1];
  }
  for (int i = 0; i < u; ++i) count[i + 1] += count[i];
  adj_ptr_ = count;
  adj_.resize(static_cast<size_t>(count[u]));
  std::vector<int> cur(count.begin(), count.end() - 1);
  for (int l = 0; l < E + r; ++l) {
    if (unknown_[la_[l]] >= 0) adj_[cur[unknown_[la_[l]]]++] = 2 * l;      // this face is a
    if (unknown_[lb_[l]] >= 0) adj_[cur[unknown_[lb_[l]]]++] = 2 * l + 1;  // this face is b
  }
  // Constant preconditioner: the scalar Laplacian of all links plus the penalties.
  if (u > 0) {
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(static_cast<size_t>(3 * (E + r) + u));
    for (int i = 0; i < u; ++i) trip.emplace_back(i, i, penalty_[faces_[i]]);
    for (int l = 0; l < E + r; ++l) {
      const int ua = unknown_[la_[l]], ub = unknown_[lb_[l]];
      if (ua >= 0) trip.emplace_back(ua, ua, lw_[l]);
      if (ub >= 0) trip.emplace_back(ub, ub, lw_[l]);
      if (ua >= 0 && ub >= 0) trip.emplace_back(std::max(ua, ub), std::min(ua, ub), -lw_[l]);
    }
    Eigen::SparseMatrix<double> M(u, u);
    M.setFromTriplets(trip.begin(), trip.end());
    chol_ = std::make_unique<SparseCholesky>(M, SparseCholesky::Reuse::PerPose);
  }
  // Spanning tree of the gauge, grown from the tree roots by Prim's algorithm:
  // edges whose relative rotation is small in every example first (ties in breadth-first
  // order), so the few unreliable edges (strongly distorted faces) end up off the tree and
  // their inconsistency stays local.
  std::vector<std::vector<int>> inc(m);
  for (int e = 0; e < E; ++e) {
    inc[la_[e]].push_back(e);
    inc[lb_[e]].push_back(e);
  }
  std::vector<char> seen(m, 0);
  using Item = std::tuple<double, long, int>;  // cost, insertion order, edge
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> heap;
  long counter = 0;
  auto push_edges = [&](int f) {
    for (int e : inc[f]) {
      const int g = la_[e] == f ? lb_[e] : la_[e];
      if (!seen[g]) heap.emplace(edge_cost.empty() ? 0.0 : edge_cost[e], counter++, e);
    }
  };
  for (int f : tree_roots) seen[f] = 1;
  for (int f : tree_roots) push_edges(f);
  parent_link_.assign(m, -1);
  while (!heap.empty()) {
    const int e = std::get<2>(heap.top());
    heap.pop();
    const int g = seen[la_[e]] ? lb_[e] : la_[e];
    if (seen[g]) continue;
    seen[g] = 1;
    parent_link_[g] = e;
    order_.push_back(g);
    push_edges(g);
  }
}

int RotationSolver::solve_log(const Matrix3Array& Q, const Matrix3Array* G, const Matrix3Array& Z,
                              const Matrix3Array* init, int max_iterations, Matrix3Array* R,
                              const std::vector<Vec3>* pair_turns,
                              const std::vector<Vec3>* face_turns) const {
  const int E = num_dual_, L = static_cast<int>(la_.size());
  const int u = static_cast<int>(faces_.size());
  Matrix3Array& P = *R;
  P.assign(m_, Mat3::Identity());
  if (init) {
    for (int f : faces_) P[f] = (*init)[f];
  } else {
    for (int f : order_) {
      const int e = parent_link_[f];
      P[f] = la_[e] == f ? Mat3(P[lb_[e]] * Q[e].transpose()) : Mat3(P[la_[e]] * Q[e]);
    }
  }
  if (u == 0) return 0;
  active_.assign(L, 1);
  for (int l = E; l < L; ++l) active_[l] = G ? 1 : 0;
  d_.resize(L);
  buf_in_.resize(static_cast<size_t>(3) * u);
  buf_out_.resize(buf_in_.size());
  // Turns: each branched residual is the log of its rotation nearest to what is left of the
  // residual expected at the start (expected minus the steps taken since: phi, per face).
  const bool pair_branch = pair_turns && G;
  const bool track = pair_branch || face_turns;
  if (track) phi_.assign(m_, Vec3::Zero());
  if (pair_branch) {
    // At the start face b is turned against face a by C = P_a^T P_b (taken on its principal
    // branch); the link asks for G, so its residual P_a G P_b^T = P_a (G C^T) P_a^T has the log
    // P_a log(G C^T), on the branch of g - log(C).
    pair_expect_.resize(L - E);
    for (int l = E; l < L; ++l) {
      const Mat3 C = P[la_[l]].transpose() * P[lb_[l]];
      const Vec3 near = (*pair_turns)[l - E] - rotation_log(C);
      pair_expect_[l - E] = P[la_[l]] * rotation_log_near((*G)[l - E] * C.transpose(), near);
    }
  }
  int it = 0;
  while (it < max_iterations) {
    run(L, [&](int b, int e) {
      for (int l = b; l < e; ++l) {
        if (!active_[l]) continue;
        const Mat3& q = l < E ? Q[l] : (*G)[l - E];
        if (pair_branch && l >= E) {
          d_[l] = rotation_log_near(P[la_[l]] * q * P[lb_[l]].transpose(),
                                    pair_expect_[l - E] - (phi_[lb_[l]] - phi_[la_[l]]));
        } else {
          d_[l] = small_log(P[la_[l]] * q * P[lb_[l]].transpose());
        }
      }
    });
    run(u, [&](int b, int e) {
      for (int i = b; i < e; ++i) {
        const int f = faces_[i];
        Vec3 acc = Vec3::Zero();
        for (int k = adj_ptr_[i]; k < adj_ptr_[i + 1]; ++k) {
          const int l = adj_[k] >> 1;
          if (!active_[l]) continue;
          acc += (adj_[k] & 1 ? lw_[l] : -lw_[l]) * d_[l];  // + for b, - for a
        }
        if (penalty_[f] > 0.0) {
          const Mat3 res = Z[f] * P[f].transpose();
          acc += penalty_[f] * (face_turns ? rotation_log_near(res, (*face_turns)[f] - phi_[f])
                                           : rotation_log(res));
        }
        for (int c = 0; c < 3; ++c) buf_in_[static_cast<size_t>(c) * u + i] = acc(c);
      }
    });
    chol_->solve(buf_in_.data(), buf_out_.data(), 3);
    ++it;
    double change = 0.0;
    for (int i = 0; i < u; ++i) {
      const Vec3 xi(buf_out_[i], buf_out_[static_cast<size_t>(u) + i],
                    buf_out_[static_cast<size_t>(2) * u + i]);
      change = std::max(change, xi.norm());
      P[faces_[i]] = rotation_exp(xi) * P[faces_[i]];
      if (track) phi_[faces_[i]] += xi;
    }
    if (change < 1e-10) break;
  }
  return it;
}

int RotationSolver::solve(const Matrix3Array& Q, const Matrix3Array* G, const Matrix3Array& Z,
                          const Matrix3Array* init, int max_iterations, double tolerance,
                          Matrix3Array* R) const {
  const int E = num_dual_, L = static_cast<int>(la_.size());
  const int u = static_cast<int>(faces_.size());
  Matrix3Array& P = P_;
  P.assign(m_, Mat3::Identity());
  if (init) {
    for (int f : faces_) P[f] = (*init)[f];  // the starting guess is the gauge
  } else {
    for (int f : order_) {
      const int e = parent_link_[f];
      P[f] = la_[e] == f ? Mat3(P[lb_[e]] * Q[e].transpose()) : Mat3(P[la_[e]] * Q[e]);
    }
  }
  D_.resize(L);
  active_.assign(L, 1);
  for (int l = 0; l < L; ++l) {
    if (l >= E && !G) {
      active_[l] = 0;
      continue;
    }
    const Mat3& q = l < E ? Q[l] : (*G)[l - E];
    D_[l] = P[la_[l]] * q * P[lb_[l]].transpose();
  }
  R->assign(m_, Mat3::Identity());
  if (u == 0) return 0;
  B_.assign(u, Mat3::Zero());
  X_.resize(u);
  run(u, [&](int b, int e) {
    for (int i = b; i < e; ++i) {
      const int f = faces_[i];
      Mat3 acc = Mat3::Zero();
      for (int k = adj_ptr_[i]; k < adj_ptr_[i + 1]; ++k) {
        const int l = adj_[k] >> 1;
        if (!active_[l]) continue;
        const bool is_a = !(adj_[k] & 1);
        const int other = is_a ? lb_[l] : la_[l];
        if (unknown_[other] < 0) acc += lw_[l] * (is_a ? D_[l].transpose() : D_[l]);
      }
      if (penalty_[f] > 0.0) acc += penalty_[f] * Z[f] * P[f].transpose();
      B_[i] = acc;
      X_[i] = Mat3::Identity();
    }
  });
  const int iterations = cg(max_iterations, tolerance);
  run(u, [&](int b, int e) {
    for (int i = b; i < e; ++i) {
      const int f = faces_[i];
      (*R)[f] = nearest_rotation(X_[i] * P[f]);
    }
  });
  return iterations;
}

void RotationSolver::run(int n, const std::function<void(int, int)>& body) {
  if (n < kParallelMin) {
    body(0, n);
  } else {
    parallel_ranges(n, kParallelMin / 2, kTasks, body);
  }
}

void RotationSolver::apply(const Matrix3Array& X, Matrix3Array* out) const {
  const int u = static_cast<int>(faces_.size());
  run(u, [&](int b, int e) {
    for (int i = b; i < e; ++i) {
      Mat3 acc = penalty_[faces_[i]] * X[i];
      for (int k = adj_ptr_[i]; k < adj_ptr_[i + 1]; ++k) {
        const int l = adj_[k] >> 1;
        if (!active_[l]) continue;
        const bool is_a = !(adj_[k] & 1);
        const int other = unknown_[is_a ? lb_[l] : la_[l]];
        acc += lw_[l] * X[i];
        if (other >= 0) {
          acc -= lw_[l] * (is_a ? Mat3(X[other] * D_[l].transpose()) : Mat3(X[other] * D_[l]));
        }
      }
      (*out)[i] = acc;
    }
  });
}

void RotationSolver::precondition(const Matrix3Array& r, Matrix3Array* z) const {
  const int u = static_cast<int>(faces_.size());
  buf_in_.resize(static_cast<size_t>(9) * u);
  buf_out_.resize(buf_in_.size());
  for (int i = 0; i < u; ++i)
    for (int c = 0; c < 9; ++c) buf_in_[static_cast<size_t>(c) * u + i] = r[i].data()[c];
  chol_->solve(buf_in_.data(), buf_out_.data(), 9);
  for (int i = 0; i < u; ++i)
    for (int c = 0; c < 9; ++c) (*z)[i].data()[c] = buf_out_[static_cast<size_t>(c) * u + i];
}

double RotationSolver::dot(const Matrix3Array& a, const Matrix3Array& b) {
  double s = 0.0;
  for (size_t i = 0; i < a.size(); ++i) s += (a[i].array() * b[i].array()).sum();
  return s;
}

// Stops when the energy-norm error estimate sqrt(r . M^-1 r) is below `tolerance` times the
// solution's energy norm sqrt(x . b), or after max_iterations.
int RotationSolver::cg(int max_iterations, double tolerance) const {
  const size_t u = faces_.size();
  Matrix3Array r(u), z(u), p(u), q(u);
  apply(X_, &q);
  for (size_t i = 0; i < u; ++i) r[i] = B_[i] - q[i];
  precondition(r, &z);
  p = z;
  double rz = dot(r, z);
  int it = 0;
  for (; it < max_iterations; ++it) {
    const double scale = std::abs(dot(X_, B_));
    if (rz <= tolerance * tolerance * scale) break;
    apply(p, &q);
    const double pq = dot(p, q);
    if (!(pq > 0.0)) break;
    const double alpha = rz / pq;
    for (size_t i = 0; i < u; ++i) {
      X_[i] += alpha * p[i];
      r[i] -= alpha * q[i];
    }
    precondition(r, &z);
    const double rz_new = dot(r, z);
    const double beta = rz_new / rz;
    rz = rz_new;
    for (size_t i = 0; i < u; ++i) p[i] = z[i] + beta * p[i];
  }
  return it;
}

}  // namespace pose_space

using namespace pose_space;  // NOLINT: this file is part of the method

// final: the rotations step 2 uses. The natural shape of a call that also solves with the
// handle rotations only feeds the rigid fits and the start of that solve, so the Gauss-Newton
// gauge steps suffice for it.
int PoseSpaceDeformer::Impl::solve_rotations(const RotationSolver& solver, const Matrix3Array& Q,
                                             const Matrix3Array* G, const Matrix3Array& Z,
                                             const Matrix3Array* init, bool final,
                                             Matrix3Array* R) const {
  if (!final) return solver.solve_log(Q, G, Z, init, opt.gauge_steps, R);
  if (opt.rotation_energy == PoseSpaceOptions::RotationEnergy::kChordal) {
    // Two Gauss-Newton steps of the geodesic energy give a gauge in which the chordal
    // system is close to the constant preconditioner wherever the blend is consistent.
    Matrix3Array gauge;
    const auto t0 = Clock::now();
    solver.solve_log(Q, G, Z, init, opt.gauge_steps, &gauge);
    const auto t1 = Clock::now();
    const int it =
        solver.solve(Q, G, Z, &gauge, opt.rotation_iterations, opt.rotation_tolerance, R);
    stats.ms_chordal += ms_since(t1);
    stats.ms_gauge += std::chrono::duration<double, std::milli>(t1 - t0).count();
    return it;
  }
  return solver.solve_log(Q, G, Z, init, opt.rotation_iterations, R);
}

}  // namespace matdeform
