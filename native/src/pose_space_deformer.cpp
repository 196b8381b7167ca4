#include "matdeform/pose_space_deformer.hpp"

#include <meshoptimizer.h>

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <Eigen/SparseCore>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <map>
#include <mutex>
#include <numeric>
#include <queue>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>

#include "matdeform/frames.hpp"
#include "matdeform/mesh.hpp"
#include "matdeform/transforms.hpp"
#include "matdeform/weights.hpp"
#include "sparse_cholesky.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {

using Clock = std::chrono::steady_clock;
using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

constexpr double kPi = 3.14159265358979323846;
// Per-edit loops over faces or vertices: below this size they run serially (waking the pool's
// workers costs more than the work: the 17k-face transfer took 0.75 ms on two threads, 0.24 ms
// on one).
constexpr int kParallelMin = 16384;
constexpr int kTasks = 8;
// Positions (examples, handle targets, the frame) lie within this many bounding-box diagonals
// of the rest mesh's centre. Then every product the solve forms (squared lengths of pose
// vectors, cross products of target edges, the Kabsch cross-covariance) stays below ~1e200;
// far beyond, they overflow to inf and NaN (handles scaled by 1e155 did).
constexpr double kMaxReach = 1e50;
// Within that reach a non-finite result is a defect, but it is never returned.
constexpr const char* kOverflow =
    "handle_positions: the solve overflowed (a non-finite value); rescale the mesh and the "
    "positions (only shapes matter)";

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

[[noreturn]] void fail(const std::string& msg) { throw std::invalid_argument(msg); }

std::string item(const char* name, size_t i) {
  return std::string(name) + "[" + std::to_string(i) + "]";
}

std::string number(double x) {
  std::ostringstream s;
  s << x;
  return s.str();
}

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

// Rotation R minimising sum_i |R (p_i - mean p) - (q_i - mean q)|^2 (Kabsch). Points on a line
// get the smallest rotation taking the source direction to the target direction, a single point
// the identity.
Mat3 best_rotation(const Vertices& P, const Vertices& Q) {
  if (P.rows() == 0) return Mat3::Identity();
  const Eigen::RowVector3d pc = P.colwise().mean(), qc = Q.colwise().mean();
  const Mat3 H = (P.rowwise() - pc).transpose() * (Q.rowwise() - qc);
  Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Vec3 sv = svd.singularValues();
  if (!(sv(0) > 1e-300)) return Mat3::Identity();
  const Mat3 U = svd.matrixU(), V = svd.matrixV();
  if (sv(1) <= 1e-10 * sv(0)) {
    return Eigen::Quaterniond::FromTwoVectors(U.col(0), V.col(0)).toRotationMatrix();
  }
  Mat3 D = Mat3::Identity();
  if ((V * U.transpose()).determinant() < 0.0) D(2, 2) = -1.0;
  return V * D * U.transpose();
}

// Second singular value over the first of the centred point set: 0 for collinear points.
double planarity(const Vertices& P) {
  if (P.rows() < 3) return 0.0;
  const Eigen::RowVector3d c = P.colwise().mean();
  const Mat3 C = (P.rowwise() - c).transpose() * (P.rowwise() - c);
  Eigen::SelfAdjointEigenSolver<Mat3> es(C);
  const Vec3 ev = es.eigenvalues();  // ascending
  return ev(2) > 0.0 ? std::sqrt(std::max(ev(1), 0.0) / ev(2)) : 0.0;
}

Vertices gather_rows(const Vertices& X, const std::vector<int>& ids) {
  Vertices out(static_cast<Eigen::Index>(ids.size()), 3);
  for (size_t i = 0; i < ids.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = X.row(ids[i]);
  return out;
}

// Rotation factor of the deformation gradient of one triangle, rest (a,b,c) -> (a2,b2,c2).
Mat3 face_rotation(const Mat3& rest_frame_inverse, const Vec3& a, const Vec3& b, const Vec3& c) {
  Mat3 S, R;
  polar_decompose(face_frame(a, b, c) * rest_frame_inverse, &S, &R);
  return R;
}

// Symmetric 3x3 as 6 numbers: xx yy zz xy xz yz.
inline void pack_sym(const Mat3& S, double* o) {
  o[0] = S(0, 0);
  o[1] = S(1, 1);
  o[2] = S(2, 2);
  o[3] = 0.5 * (S(0, 1) + S(1, 0));
  o[4] = 0.5 * (S(0, 2) + S(2, 0));
  o[5] = 0.5 * (S(1, 2) + S(2, 1));
}

bool lex_less(const Vec3& a, const Vec3& b) {
  return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
}

// Centroid of a triangle summed in lexicographic order of its corners, so the same bits for any
// corner order (a root chosen by distance must not depend on the numbering, even in ties).
Vec3 centroid(const Vertices& V, int a, int b, int c) {
  std::array<Vec3, 3> p = {V.row(a).transpose(), V.row(b).transpose(), V.row(c).transpose()};
  std::sort(p.begin(), p.end(), lex_less);
  return (p[0] + p[1] + p[2]) / 3.0;
}

// Mean of the rows `ids` of V, summed in lexicographic order of the points (the same bits for
// any numbering).
Vec3 canonical_mean(const Vertices& V, std::vector<int> ids) {
  std::sort(ids.begin(), ids.end(),
            [&](int a, int b) { return lex_less(V.row(a).transpose(), V.row(b).transpose()); });
  Vec3 sum = Vec3::Zero();
  for (int i : ids) sum += V.row(i).transpose();
  return sum / static_cast<double>(std::max<size_t>(ids.size(), 1));
}

// The face whose rest centroid is nearest to `point` (ties: lexicographic centroid), a choice
// that does not depend on the numbering of faces or vertices. Among the faces in `candidates`
// (-1 when it is empty).
int nearest_face(const Vertices& V, const Faces& F, const Vec3& point,
                 const std::vector<int>& candidates) {
  int best = -1;
  double bd = 0.0;
  Vec3 bc = Vec3::Zero();
  for (const int f : candidates) {
    const Vec3 c = centroid(V, F(f, 0), F(f, 1), F(f, 2));
    const double d = (c - point).squaredNorm();
    const bool better = best < 0 || d < bd || (d == bd && lex_less(c, bc));
    if (better) {
      best = f;
      bd = d;
      bc = c;
    }
  }
  return best;
}

// ------------------------------------------------------------------------------------------
// Cardinal radial basis interpolation of the example weights.
//
// w(x) = A^T phi(x) + b with phi_l(x) = |x - P_l| and [Phi - mu I, 1; 1^T, 0] [A; b^T] = [I; 0].
// Phi symmetric makes A symmetric with zero row sums, so sum_k w_k = 1 everywhere; with mu = 0,
// w(P_k) = e_k. phi(r) = r is conditionally positive definite of order 1: the system is
// non-singular for distinct centres, and with the constant term the weights stay bounded
// (they tend to direction-dependent constants far from the examples).
class Interpolator {
 public:
  Interpolator() = default;
  Interpolator(const RowMatrix& centers, double regularization, bool convex)
      : centers_(centers), convex_(convex) {
    const Eigen::Index p = centers.rows();
    if (p <= 1) return;
    Eigen::MatrixXd Phi(p, p);
    for (Eigen::Index a = 0; a < p; ++a)
      for (Eigen::Index b = 0; b < p; ++b) Phi(a, b) = (centers.row(a) - centers.row(b)).norm();
    const double big = Phi.maxCoeff();
    for (Eigen::Index a = 0; a < p; ++a) {
      for (Eigen::Index b = a + 1; b < p; ++b) {
        if (!(Phi(a, b) > 1e-9 * big)) {
          fail("examples[" + std::to_string(a) + "] and examples[" + std::to_string(b) +
               "] have the same pose (handle positions and joint rotations), so their weights "
               "are undefined");
        }
      }
    }
    Eigen::MatrixXd S = Eigen::MatrixXd::Zero(p + 1, p + 1);
    S.topLeftCorner(p, p) = Phi;
    // phi(r) = r is conditionally negative definite: -Phi is the positive (energy) matrix on
    // sum a = 0, so the smoothing ridge is subtracted. It pulls the weights at the examples
    // towards mixtures and keeps the partition of unity.
    S.topLeftCorner(p, p).diagonal().array() -= regularization * big;
    // The constant's column scaled like Phi (b = big * c): poses far apart (an example 1e40
    // times the others) otherwise leave a pivot below the rank threshold.
    S.topRightCorner(p, 1).setConstant(big);
    S.bottomLeftCorner(1, p).setConstant(big);
    Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(p + 1, p);
    rhs.topRows(p).setIdentity();
    Eigen::FullPivLU<Eigen::MatrixXd> lu(S);
    if (!lu.isInvertible()) fail("examples: the pose interpolation system is singular");
    const Eigen::MatrixXd sol = lu.solve(rhs);
    A_ = sol.topRows(p);
    b_ = big * sol.row(p).transpose();
  }

  Eigen::VectorXd operator()(const Eigen::VectorXd& x) const {
    const Eigen::Index p = centers_.rows();
    if (p == 0) return Eigen::VectorXd();
    if (p == 1) return Eigen::VectorXd::Ones(1);
    // A's columns sum to 0, so phi may be shifted by |x - P_0|. The shifted values are formed
    // without cancellation, |x - P_l| - |x - P_0| = (P_0 - P_l).(2x - P_l - P_0) / (sum), so
    // far from the examples (|x| >> |P|) the weights keep their sum 1 and their limits.
    const Eigen::VectorXd p0 = centers_.row(0).transpose();
    const double phi0 = (x - p0).norm();
    Eigen::VectorXd phi(p);
    for (Eigen::Index l = 0; l < p; ++l) {
      const Eigen::VectorXd pl = centers_.row(l).transpose();
      const double den = (x - pl).norm() + phi0;
      phi(l) = den > 0.0 ? (p0 - pl).dot(2.0 * x - pl - p0) / den : 0.0;
    }
    Eigen::VectorXd w = A_.transpose() * phi + b_;
    if (convex_) {
      w = w.cwiseMax(0.0);
      w /= w.sum();  // >= 1 before clipping: sum w = 1 and clipping only raises entries
    }
    return w;
  }

 private:
  RowMatrix centers_;
  Eigen::MatrixXd A_;
  Eigen::VectorXd b_;
  bool convex_ = false;
};

// ------------------------------------------------------------------------------------------
// Step 1: absolute rotations from relative ones.
//
// Links l = (a, b) with weight w_l ask R_b = R_a Q_l (dual edges: the blended relative
// rotations; rotational pairs: the prescribed joint rotation). Energy
//     sum_l w_l |R_b - R_a Q_l|^2 + sum_f lambda_f |R_f - Z_f|^2,   R = I on fixed faces.
// In the gauge R_f = Y_f P_f, with P integrated along a BFS tree (P_root = I, P_b = P_a Q_l on
// tree links), each link term becomes |Y_b - Y_a D_l|^2 with D_l = P_a Q_l P_b^T: the identity
// on tree links, close to it elsewhere. The rows of Y decouple and the matrix is the block
// "connection Laplacian" with blocks D_l; the scalar Laplacian (D = I), factored once, is its
// preconditioner.
class RotationSolver {
 public:
  // tree_roots: where the gauge's spanning tree starts, every fixed face and one face in each
  // rotation component without one (faces the tree does not reach keep the identity gauge).
  RotationSolver(int m, const IndexPairs& dual, const std::vector<std::array<int, 2>>& pairs,
                 double pair_weight, const std::vector<int>& fixed,
                 const std::vector<int>& tree_roots, const std::vector<int>& penalty_faces,
                 double penalty_weight, const std::vector<double>& edge_cost,
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

  // The same constraints with the geodesic energy sum_l w_l |log(R_a Q_l R_b^T)|^2 +
  // sum_f lambda_f |log(Z_f R_f^T)|^2, by Gauss-Newton in the Lie algebra: with R = exp(xi) P,
  // each link asks xi_b - xi_a = log(P_a Q_l P_b^T), a scalar Laplacian system (the constant
  // preconditioner matrix itself) with three right-hand sides. P starts as the tree gauge (or
  // init) and is updated by exp(xi) until max |xi| < 1e-10 or max_iterations solves. Exact in
  // one solve when the relative rotations are consistent. Returns the number of solves.
  int solve_log(const Matrix3Array& Q, const Matrix3Array* G, const Matrix3Array& Z,
                const Matrix3Array* init, int max_iterations, Matrix3Array* R) const {
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
    int it = 0;
    while (it < max_iterations) {
      run(L, [&](int b, int e) {
        for (int l = b; l < e; ++l) {
          if (!active_[l]) continue;
          const Mat3& q = l < E ? Q[l] : (*G)[l - E];
          d_[l] = small_log(P[la_[l]] * q * P[lb_[l]].transpose());
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
          if (penalty_[f] > 0.0) acc += penalty_[f] * rotation_log(Z[f] * P[f].transpose());
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
      }
      if (change < 1e-10) break;
    }
    return it;
  }

  // Chordal energy (the paper's linear step 1). Q: one relative rotation per dual edge; G: one
  // per rotational pair, or nullptr (pairs inactive); Z: targets of the penalty faces (indexed
  // by face); init: a rotation field used as the gauge and starting guess, or nullptr (the tree
  // gauge). Writes m rotations (projected) to R; returns the CG iteration count.
  int solve(const Matrix3Array& Q, const Matrix3Array* G, const Matrix3Array& Z,
            const Matrix3Array* init, int max_iterations, double tolerance, Matrix3Array* R) const {
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

 private:
  static void run(int n, const std::function<void(int, int)>& body) {
    if (n < kParallelMin) {
      body(0, n);
    } else {
      parallel_ranges(n, kParallelMin / 2, kTasks, body);
    }
  }

  void apply(const Matrix3Array& X, Matrix3Array* out) const {
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

  void precondition(const Matrix3Array& r, Matrix3Array* z) const {
    const int u = static_cast<int>(faces_.size());
    buf_in_.resize(static_cast<size_t>(9) * u);
    buf_out_.resize(buf_in_.size());
    for (int i = 0; i < u; ++i)
      for (int c = 0; c < 9; ++c) buf_in_[static_cast<size_t>(c) * u + i] = r[i].data()[c];
    chol_->solve(buf_in_.data(), buf_out_.data(), 9);
    for (int i = 0; i < u; ++i)
      for (int c = 0; c < 9; ++c) (*z)[i].data()[c] = buf_out_[static_cast<size_t>(c) * u + i];
  }

  static double dot(const Matrix3Array& a, const Matrix3Array& b) {
    double s = 0.0;
    for (size_t i = 0; i < a.size(); ++i) s += (a[i].array() * b[i].array()).sum();
    return s;
  }

  // Stops when the energy-norm error estimate sqrt(r . M^-1 r) is below `tolerance` times the
  // solution's energy norm sqrt(x . b), or after max_iterations.
  int cg(int max_iterations, double tolerance) const {
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

  int m_ = 0, num_dual_ = 0;
  std::vector<int> la_, lb_;
  std::vector<double> lw_, penalty_;
  std::vector<int> unknown_, faces_;
  std::vector<int> adj_ptr_, adj_;  // 2 l + (this face is b)
  std::vector<int> order_, parent_link_;
  std::unique_ptr<SparseCholesky> chol_;
  // Per-call workspace.
  mutable Matrix3Array P_, D_, B_, X_;
  mutable std::vector<Vec3> d_;
  mutable std::vector<char> active_;
  mutable std::vector<double> buf_in_, buf_out_;
};

// ------------------------------------------------------------------------------------------
// Step 2: positions from per-face targets T_i = R_i S_i.
//
// Energy sum_i |X_i E_i - T_i|^2 (X_i the deformed frame with the fourth vertex, E_i the
// inverse rest frame) + lambda sum_q |sum_c beta_qc x_c - t_q|^2 (handle rows), fixed vertices
// at rest. Each fourth vertex appears in one face only and is eliminated exactly per face
// (Schur complement), so the system has one unknown per vertex and three right-hand sides.
struct GradientOperator {
  // Per face, times its weight: the rows of (D E) for a, b, c after eliminating the fourth
  // vertex (G'), and the 3x3 Schur block of the face's Hessian. With area weights (area over
  // the mean area) the energy is the integral of |grad x - T|^2; a sliver's gradient terms grow
  // like 1/width^2, and unweighted they would dominate (coarse meshes have slivers).
  std::vector<Mat3> Gp, Hp;
  double mean_diagonal = 1.0;

  GradientOperator(const Vertices& V, const Faces& F, bool area_weights) {
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
};

class PositionSolver {
 public:
  struct Row {
    std::vector<int> idx;  // level vertices
    std::vector<double> beta;
  };

  // part: the mesh part of each vertex (parts 0 .. max). A part that no fixed vertex and no row
  // holds gets a translation gauge: its first vertex is fixed, and its rest mean is restored
  // after the solve.
  PositionSolver(const Vertices& rest, const Faces& F, const GradientOperator& grad,
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

  // T: one target per face; row_targets: (rows,3) or nullptr when there are no rows.
  void solve(const Matrix3Array& T, const Vertices* row_targets, Vertices* out) const {
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

 private:
  const Vertices& rest_;
  const Faces& F_;
  const GradientOperator& grad_;
  std::vector<Row> rows_;
  double lambda_;
  std::vector<int> unknown_;
  int num_unknowns_ = 0;
  std::vector<std::vector<int>> gauge_;  // vertices of each part whose mean is restored
  Eigen::Matrix<double, Eigen::Dynamic, 3> c0_;
  std::unique_ptr<SparseCholesky> chol_;
};

// ------------------------------------------------------------------------------------------
// Coarse mesh by quadric edge collapse (meshoptimizer). The input is put in a canonical order
// first (vertices by position, faces by their sorted canonical corners) so the coarse mesh does
// not depend on how the caller numbered vertices and faces. meshopt_simplify keeps a subset of
// the original vertices, so coarse vertices are dense vertices.
// `jitter` > 0 moves the positions meshopt sees (not the coarse vertices) by up to jitter x the
// mean edge length, by a hash of the position (so still numbering independent): on a flat
// region or a straight crease that gives collapses a cost and meshopt's flip test a normal.
void simplify_mesh(const Vertices& V, const Faces& F, int target_faces, double jitter,
                   std::vector<int>* coarse_vertices, Faces* coarse_faces) {
  const int n = static_cast<int>(V.rows()), m = static_cast<int>(F.rows());
  std::vector<int> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    for (int c = 0; c < 3; ++c) {
      if (V(a, c) != V(b, c)) return V(a, c) < V(b, c);
    }
    return a < b;
  });
  std::vector<unsigned> rank(n);
  for (int i = 0; i < n; ++i) rank[order[i]] = static_cast<unsigned>(i);
  std::vector<float> pos(static_cast<size_t>(3) * n);
  for (int i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) pos[3 * i + c] = static_cast<float>(V(order[i], c));
  std::vector<std::array<unsigned, 3>> tri(m);
  for (int f = 0; f < m; ++f) {
    std::array<unsigned, 3> t = {rank[F(f, 0)], rank[F(f, 1)], rank[F(f, 2)]};
    const int s = static_cast<int>(std::min_element(t.begin(), t.end()) - t.begin());
    tri[f] = {t[s], t[(s + 1) % 3], t[(s + 2) % 3]};  // same orientation, smallest corner first
  }
  std::sort(tri.begin(), tri.end());
  if (jitter > 0.0) {
    double mean_edge = 0.0;
    for (int f = 0; f < m; ++f)
      for (int c = 0; c < 3; ++c) mean_edge += (V.row(F(f, c)) - V.row(F(f, (c + 1) % 3))).norm();
    mean_edge /= 3.0 * m;
    for (int i = 0; i < n; ++i) {
      const Vec3 p = V.row(order[i]).transpose();
      for (int c = 0; c < 3; ++c) {
        double h = std::sin(p.dot(Vec3(12.9898 + c, 78.233 - c, 37.719 + 2 * c))) * 43758.5453;
        h -= std::floor(h);
        pos[3 * i + c] += static_cast<float>(jitter * mean_edge * (h - 0.5));
      }
    }
  }
  std::vector<unsigned> idx(static_cast<size_t>(3) * m), out(static_cast<size_t>(3) * m);
  for (int f = 0; f < m; ++f)
    for (int c = 0; c < 3; ++c) idx[3 * f + c] = tri[f][c];
  const size_t count =
      meshopt_simplify(out.data(), idx.data(), idx.size(), pos.data(), static_cast<size_t>(n),
                       sizeof(float) * 3, static_cast<size_t>(3) * target_faces, 1.0f, 0, nullptr);
  if (count < 12) fail("coarse: simplification left fewer than 4 faces");
  std::vector<int> used(n, -1);
  for (size_t k = 0; k < count; ++k) used[out[k]] = 0;
  coarse_vertices->clear();
  for (int i = 0; i < n; ++i) {
    if (used[i] == 0) {
      used[i] = static_cast<int>(coarse_vertices->size());
      coarse_vertices->push_back(order[i]);
    }
  }
  coarse_faces->resize(static_cast<Eigen::Index>(count / 3), 3);
  for (size_t k = 0; k < count; ++k) {
    (*coarse_faces)(static_cast<Eigen::Index>(k / 3), static_cast<Eigen::Index>(k % 3)) =
        used[out[k]];
  }
}

// Delaunay-style edge flips on the coarse mesh: quadric simplification optimises geometric
// error, not shape, and leaves long slivers whose deformation gradients are meaningless when the
// surface bends across them. An edge (a, b) between triangles (a, b, c) and (b, a, d) is flipped
// to (c, d) when the angles at c and d sum to more than pi, (c, d) is not an edge yet, and both
// new triangles keep the orientation of the old pair (normals within 30 degrees). Vertices are
// untouched, so coarse vertices stay dense vertices.
void flip_slivers(const Vertices& V, Faces* F) {
  const int m = static_cast<int>(F->rows());
  auto P = [&](int v) { return Vec3(V.row(v).transpose()); };
  auto angle = [&](int at, int u, int w) {
    const Vec3 x = P(u) - P(at), y = P(w) - P(at);
    return std::atan2(x.cross(y).norm(), x.dot(y));
  };
  for (int pass = 0; pass < 50; ++pass) {
    std::map<std::pair<int, int>, std::vector<int>> edge_faces;
    for (int f = 0; f < m; ++f)
      for (int k = 0; k < 3; ++k) {
        const int a = (*F)(f, k), b = (*F)(f, (k + 1) % 3);
        edge_faces[{std::min(a, b), std::max(a, b)}].push_back(f);
      }
    std::vector<char> touched(m, 0);
    int flips = 0;
    for (const auto& [edge, fs] : edge_faces) {
      if (fs.size() != 2 || touched[fs[0]] || touched[fs[1]]) continue;
      const int f1 = fs[0], f2 = fs[1];
      // Orient: f1 = (a, b, c) with a -> b, f2 holding b -> a with opposite d.
      int a = -1, b = -1, c = -1, d = -1;
      for (int k = 0; k < 3; ++k) {
        const int x = (*F)(f1, k), y = (*F)(f1, (k + 1) % 3);
        if (std::min(x, y) == edge.first && std::max(x, y) == edge.second) {
          a = x;
          b = y;
          c = (*F)(f1, (k + 2) % 3);
        }
      }
      for (int k = 0; k < 3; ++k) {
        if ((*F)(f2, k) != a && (*F)(f2, k) != b) d = (*F)(f2, k);
      }
      if (c == d || d < 0 || edge_faces.count({std::min(c, d), std::max(c, d)})) continue;
      if (angle(c, a, b) + angle(d, b, a) <= kPi + 1e-9) continue;
      const Vec3 n_old = (P(b) - P(a)).cross(P(c) - P(a)).normalized() +
                         (P(a) - P(b)).cross(P(d) - P(b)).normalized();
      const Vec3 n1 = (P(a) - P(c)).cross(P(d) - P(c)), n2 = (P(d) - P(c)).cross(P(b) - P(c));
      const double cos30 = 0.8660254037844386 * n_old.norm();
      if (n1.norm() == 0.0 || n2.norm() == 0.0 || n1.normalized().dot(n_old) < cos30 ||
          n2.normalized().dot(n_old) < cos30) {
        continue;
      }
      F->row(f1) << c, a, d;
      F->row(f2) << c, d, b;
      touched[f1] = touched[f2] = 1;
      ++flips;
    }
    if (flips == 0) break;
  }
}

// Zero-area coarse faces. On a flat region or along a straight crease a collapse costs no
// quadric error, and meshoptimizer's flip test (in float) lets it leave three collinear corners.
// Such a face (a, b, c) has c on its longest edge (a, b); flipping (a, b) splits the neighbour
// (b, a, d) at c into (c, a, d) and (c, d, b), which is the surface that is there. The
// degenerate face has no normal, so the neighbour's normal judges the flip. A run of collinear
// faces clears from its end, one flip a pass. Returns the faces that stay flat.
bool flat_face(const Vec3& p, const Vec3& q, const Vec3& r, double min_area2) {
  const double a2 = (q - p).cross(r - p).norm();
  const double l2 = std::max({(q - p).squaredNorm(), (r - q).squaredNorm(), (p - r).squaredNorm()});
  return !(a2 > 1e-6 * l2) || !(a2 > min_area2);
}

int unflatten_faces(const Vertices& V, Faces* F, double min_area2) {
  const int m = static_cast<int>(F->rows());
  auto P = [&](int v) { return Vec3(V.row(v).transpose()); };
  auto flat = [&](int f) {
    return flat_face(P((*F)(f, 0)), P((*F)(f, 1)), P((*F)(f, 2)), min_area2);
  };
  int left = 0;
  for (int pass = 0; pass < 200; ++pass) {  // a run of k collinear faces takes k passes
    std::map<std::pair<int, int>, std::array<int, 2>> edge_faces;
    for (int f = 0; f < m; ++f)
      for (int k = 0; k < 3; ++k) {
        const int a = (*F)(f, k), b = (*F)(f, (k + 1) % 3);
        auto it =
            edge_faces.try_emplace({std::min(a, b), std::max(a, b)}, std::array<int, 2>{f, -1});
        if (!it.second) it.first->second[1] = it.first->second[1] < 0 ? f : m;  // m: non-manifold
      }
    std::vector<char> touched(m, 0);
    int flips = 0;
    left = 0;
    for (int f = 0; f < m; ++f) {
      if (!flat(f)) continue;
      ++left;
      if (touched[f]) continue;
      int k = 0;  // longest edge (a, b) = corners (k, k + 1)
      double best = -1.0;
      for (int j = 0; j < 3; ++j) {
        const double l = (P((*F)(f, (j + 1) % 3)) - P((*F)(f, j))).squaredNorm();
        if (l > best) best = l, k = j;
      }
      const int a = (*F)(f, k), b = (*F)(f, (k + 1) % 3), c = (*F)(f, (k + 2) % 3);
      const auto& pair = edge_faces.at({std::min(a, b), std::max(a, b)});
      const int g = pair[0] == f ? pair[1] : pair[0];
      if (g < 0 || g >= m || touched[g] || flat(g)) continue;
      int d = -1;
      for (int j = 0; j < 3; ++j)
        if ((*F)(g, j) != a && (*F)(g, j) != b) d = (*F)(g, j);
      if (d < 0 || d == c || edge_faces.count({std::min(c, d), std::max(c, d)})) continue;
      const Vec3 ng =
          (P((*F)(g, 1)) - P((*F)(g, 0))).cross(P((*F)(g, 2)) - P((*F)(g, 0))).normalized();
      const Vec3 n1 = (P(a) - P(c)).cross(P(d) - P(c)), n2 = (P(d) - P(c)).cross(P(b) - P(c));
      if (flat_face(P(c), P(a), P(d), min_area2) || flat_face(P(c), P(d), P(b), min_area2) ||
          n1.normalized().dot(ng) < 0.8660254037844386 ||
          n2.normalized().dot(ng) < 0.8660254037844386)
        continue;
      F->row(f) << c, a, d;
      F->row(g) << c, d, b;
      touched[f] = touched[g] = 1;
      ++flips;
    }
    if (flips == 0) break;
  }
  return left;
}

// Pairs of faces on the same three corners with opposite orientation (a fold meshoptimizer can
// leave around a vertex of valence two) enclose no surface: both go. Returns the count removed.
int remove_folds(Faces* F) {
  const int m = static_cast<int>(F->rows());
  std::map<std::array<int, 3>, std::vector<int>> by_corners;
  for (int f = 0; f < m; ++f) {
    std::array<int, 3> key = {(*F)(f, 0), (*F)(f, 1), (*F)(f, 2)};
    std::sort(key.begin(), key.end());
    by_corners[key].push_back(f);
  }
  std::vector<char> drop(m, 0);
  int removed = 0;
  for (const auto& [key, fs] : by_corners) {
    if (fs.size() < 2) continue;
    for (int f : fs) drop[f] = 1;
    removed += static_cast<int>(fs.size());
  }
  if (removed == 0) return 0;
  Faces kept(m - removed, 3);
  for (int f = 0, k = 0; f < m; ++f)
    if (!drop[f]) kept.row(k++) = F->row(f);
  *F = kept;
  return removed;
}

// A corner of a flat face with exactly three faces around it (a closed fan) is dropped: its
// fan becomes the one triangle on its three neighbours, when that triangle is not flat and keeps
// the fan's orientation. This clears a flat face whose flip would duplicate an edge.
int remove_valence3(const Vertices& V, Faces* F, double min_area2) {
  const int m = static_cast<int>(F->rows());
  auto P = [&](int v) { return Vec3(V.row(v).transpose()); };
  std::vector<std::vector<int>> vf(V.rows());
  for (int f = 0; f < m; ++f)
    for (int k = 0; k < 3; ++k) vf[(*F)(f, k)].push_back(f);
  std::vector<char> touched(m, 0), drop(m, 0);
  int removed = 0;
  for (int f = 0; f < m; ++f) {
    if (touched[f] || !flat_face(P((*F)(f, 0)), P((*F)(f, 1)), P((*F)(f, 2)), min_area2)) continue;
    for (int k = 0; k < 3; ++k) {
      const int v = (*F)(f, k);
      const auto& fs = vf[v];
      if (fs.size() != 3 || touched[fs[0]] || touched[fs[1]] || touched[fs[2]]) continue;
      // next[x] = y for each fan face (v, x, y); a closed fan is one 3-cycle.
      std::map<int, int> next;
      Vec3 n_old = Vec3::Zero();
      for (int g : fs) {
        int j = 0;
        while ((*F)(g, j) != v) ++j;
        next[(*F)(g, (j + 1) % 3)] = (*F)(g, (j + 2) % 3);
        n_old += (P((*F)(g, 1)) - P((*F)(g, 0))).cross(P((*F)(g, 2)) - P((*F)(g, 0)));
      }
      if (next.size() != 3) continue;
      const int x0 = next.begin()->first, x1 = next[x0], x2 = next.count(x1) ? next[x1] : -1;
      if (x2 < 0 || !next.count(x2) || next[x2] != x0) continue;
      const Vec3 n = (P(x1) - P(x0)).cross(P(x2) - P(x0));
      if (flat_face(P(x0), P(x1), P(x2), min_area2) || n.dot(n_old) <= 0.0) continue;
      F->row(fs[0]) << x0, x1, x2;
      drop[fs[1]] = drop[fs[2]] = 1;
      for (int g : fs) touched[g] = 1;
      removed += 1;
      break;
    }
  }
  if (removed == 0) return 0;
  Faces kept(m - 2 * removed, 3);
  for (int f = 0, k = 0; f < m; ++f)
    if (!drop[f]) kept.row(k++) = F->row(f);
  *F = kept;
  return removed;
}

// The coarse level: simplify, clear flat faces (folds, flips, valence-3 vertices, repeated while
// any of them changes something), drop vertices no face uses, then flip slivers. When a flat
// face or a non-manifold edge remains (meshopt folds flat regions over themselves once it has
// made a zero-area face), simplify again with jittered positions, then at nearby targets, in a
// fixed order; if all fail the bind fails (a degenerate face is never returned).
void coarse_mesh(const Vertices& V, const Faces& F, int target, double diag,
                 std::vector<int>* coarse_vertices, Vertices* coarse_rest, Faces* coarse_faces) {
  const int m = static_cast<int>(F.rows());
  const double min_area2 = 1e-12 * diag * diag;
  for (int attempt = 0; attempt < 7; ++attempt) {
    // target, then target, target + 2 %, - 2 %, + 4 %, - 4 %, + 6 % with jitter
    const int step = attempt / 2, sign = attempt % 2 ? -1 : 1;
    const int t = std::clamp(target + sign * step * std::max(1, target / 50), 4, m - 1);
    simplify_mesh(V, F, t, attempt == 0 ? 0.0 : 0.01, coarse_vertices, coarse_faces);
    Vertices R = gather_rows(V, *coarse_vertices);
    Faces& CF = *coarse_faces;
    for (int round = 0; round < 50; ++round) {
      int changed = remove_folds(&CF);  // meshopt's own folds, and any a fan removal made
      if (unflatten_faces(R, &CF, min_area2) > 0) changed += remove_valence3(R, &CF, min_area2);
      if (changed == 0) break;
    }
    // Drop vertices that lost all their faces (valence-3 removals, folds); the order is kept.
    std::vector<int> level(R.rows(), -1), kept;
    for (Eigen::Index f = 0; f < CF.rows(); ++f)
      for (int k = 0; k < 3; ++k) level[CF(f, k)] = 0;
    for (Eigen::Index i = 0; i < R.rows(); ++i) {
      if (level[i] == 0) {
        level[i] = static_cast<int>(kept.size());
        kept.push_back((*coarse_vertices)[i]);
      }
    }
    for (Eigen::Index f = 0; f < CF.rows(); ++f)
      for (int k = 0; k < 3; ++k) CF(f, k) = level[CF(f, k)];
    *coarse_vertices = kept;
    *coarse_rest = gather_rows(V, kept);
    flip_slivers(*coarse_rest, &CF);
    // Valid: no flat face, and no edge on more than two faces (meshopt can leave those too).
    bool ok = CF.rows() >= 4;
    std::map<std::pair<int, int>, int> edge_count;
    for (Eigen::Index f = 0; ok && f < CF.rows(); ++f) {
      for (int k = 0; k < 3; ++k) {
        const int a = CF(f, k), b = CF(f, (k + 1) % 3);
        ok = ok && ++edge_count[{std::min(a, b), std::max(a, b)}] <= 2;
      }
      ok = ok && !flat_face(coarse_rest->row(CF(f, 0)).transpose(),
                            coarse_rest->row(CF(f, 1)).transpose(),
                            coarse_rest->row(CF(f, 2)).transpose(), min_area2);
    }
    if (ok) return;
  }
  fail(
      "coarse: the simplified mesh has a degenerate face or a non-manifold edge; choose another "
      "face count");
}
}  // namespace

// ------------------------------------------------------------------------------------------

struct PoseSpaceDeformer::Impl {
  // Dense input.
  Vertices rest;
  Faces faces;
  int n = 0, m = 0, p = 0, h = 0, r = 0;
  double diag = 1.0;
  Vec3 center = Vec3::Zero();  // of the rest bounding box
  PoseSpaceOptions opt;
  std::vector<std::vector<int>> handles;
  std::vector<int> handle_all;       // concatenated handle vertices
  std::vector<int> handle_offset;    // h + 1
  std::vector<int> frozen_vertices;  // sorted dense ids
  std::vector<char> is_frozen_vertex;
  // Mesh parts (connected through edges). A part with a handle vertex, a frozen face, the frame
  // face or a rotational face is solved; the others are output at rest.
  int parts = 1;
  std::vector<int> vpart;         // dense vertex -> part
  std::vector<char> at_rest;      // dense vertices output at rest: frozen, or in a free part
  std::vector<char> part_frozen;  // parts holding frozen faces (no fitted rotation)
  // Frame.
  int frame = -1;
  std::array<int, 3> frame_vertices = {-1, -1, -1};
  std::array<int, 3> frame_in_handles = {-1, -1, -1};  // position in handle_all, or -1
  Mat3 frame_rest_inverse = Mat3::Identity();
  Vec3 frame_rest_centroid = Vec3::Zero();
  Vertices handle_rest;       // rest positions of handle_all
  std::vector<int> oriented;  // handles whose orientation is part of the pose
  // Pose space.
  Interpolator interp_full, interp_positions;
  std::string positions_error;  // why the positions-only interpolator is unavailable
  // Solve level (the coarse mesh, or the dense mesh itself, or its solved parts).
  bool multires = false;
  bool whole = true;  // the level is the dense mesh, same numbering
  Vertices lrest;
  Faces lfaces;
  std::vector<int> lvertices;   // dense id of each level vertex
  std::vector<int> level_of;    // dense vertex -> level vertex, or -1
  std::vector<int> lface_part;  // level face -> part
  // Level faces whose rotation is the natural shape's turned by their part's fitted rotation
  // (rotation components of the final step-1 solve that nothing else holds).
  std::vector<char> lface_follow;
  std::vector<int> lvpart;  // level vertex -> part
  IndexPairs ldual;
  RowMatrix omega;    // (E, 3p) relative rotation logs
  RowMatrix stretch;  // (lm, 6p)
  std::vector<std::array<int, 2>> lpairs;
  std::vector<int> lhandle_faces, lhandle_owner;
  std::vector<int> lfixed_faces, lfixed_vertices;
  std::unique_ptr<GradientOperator> grad;
  std::unique_ptr<RotationSolver> rot_a, rot_b;
  std::unique_ptr<PositionSolver> pos_a, pos_b;
  mutable std::unique_ptr<PositionSolver> pos_b_frame;
  std::vector<PositionSolver::Row> handle_rows, frame_rows;
  double lambda_pos = 1.0;
  // Multiresolution transfer: per dense vertex, coarse neighbours with harmonic weights, and
  // detail vectors (n, 3 max(p,1)).
  std::vector<int> tr_ptr, tr_idx;
  std::vector<double> tr_w;
  RowMatrix detail;
  std::vector<int> vf_ptr, vf_idx;  // coarse vertex -> coarse faces
  Eigen::VectorXd larea;            // coarse face areas: slivers count little in vertex rotations
  // Last call. deform() holds `busy` for its whole run: the solvers' per-call workspaces, the
  // lazily built frame solver and these results are shared by every call on this deformer.
  mutable std::mutex busy;
  mutable Eigen::VectorXd last_weights;
  mutable PoseSpaceStats stats;

  // Frame (rotation, origin) of a full shape X.
  void frame_of(const Vertices& X, Mat3* R, Vec3* o) const {
    if (frame >= 0) {
      const Vec3 a = X.row(frame_vertices[0]), b = X.row(frame_vertices[1]),
                 c = X.row(frame_vertices[2]);
      *R = face_rotation(frame_rest_inverse, a, b, c);
      *o = (a + b + c) / 3.0;
    } else {
      *R = Mat3::Identity();
      *o = Vec3::Zero();
      // Without handles the pose is the joint rotations alone; a frozen region holds the model
      // in place, so positions are measured in the mesh's own frame.
      if (h == 0 || !frozen_vertices.empty()) return;
      const Vertices XH = gather_rows(X, handle_all);
      *R = best_rotation(handle_rest, XH);
      *o = XH.colwise().mean().transpose();
    }
  }

  // Pose vector: handle centroids in the frame (over the bounding-box diagonal), then the joint
  // rotation logs (over pi) when given.
  int pose_dim(bool joints) const {
    return 3 * h + 3 * static_cast<int>(oriented.size()) + (joints ? 3 * r : 0);
  }

  // Pose vector: handle centroids in the frame (over the bounding-box diagonal), the handles'
  // best-fit rotations relative to the frame (logs over pi, times orientation_weight; handles
  // with at least three non-collinear vertices), then the joint rotation logs (over pi).
  Eigen::VectorXd pose_vector(const Vertices& targets, const Mat3& R, const Vec3& o,
                              const Matrix3Array* joints) const {
    Eigen::VectorXd x(pose_dim(joints != nullptr));
    for (int j = 0; j < h; ++j) {
      const int b = handle_offset[j], e = handle_offset[j + 1];
      const Vec3 c = targets.middleRows(b, e - b).colwise().mean().transpose();
      x.segment<3>(3 * j) = R.transpose() * (c - o) / diag;
    }
    int at = 3 * h;
    for (int j : oriented) {
      const int b = handle_offset[j], e = handle_offset[j + 1];
      const Mat3 Rj = best_rotation(handle_rest.middleRows(b, e - b), targets.middleRows(b, e - b));
      x.segment<3>(at) = opt.orientation_weight * rotation_log(R.transpose() * Rj) / kPi;
      at += 3;
    }
    if (joints) {
      for (int q = 0; q < r; ++q) x.segment<3>(at + 3 * q) = rotation_log((*joints)[q]) / kPi;
    }
    return x;
  }

  Eigen::VectorXd example_pose(const Vertices& X, bool with_joints) const {
    Mat3 R;
    Vec3 o;
    frame_of(X, &R, &o);
    Matrix3Array joints;
    if (with_joints) {
      for (const auto& pr : opt.rotational) {
        joints.push_back(example_face_rotation(X, pr[0]).transpose() *
                         example_face_rotation(X, pr[1]));
      }
    }
    return pose_vector(gather_rows(X, handle_all), R, o, with_joints ? &joints : nullptr);
  }

  Mat3 example_face_rotation(const Vertices& X, int f) const {
    const Mat3 Vr = face_frame(rest.row(faces(f, 0)), rest.row(faces(f, 1)), rest.row(faces(f, 2)));
    return face_rotation(Vr.inverse(), X.row(faces(f, 0)), X.row(faces(f, 1)), X.row(faces(f, 2)));
  }

  // Distance (max norm) of point x from the rest centre, when beyond kMaxReach diagonals.
  std::optional<double> beyond_reach(const Vec3& x) const {
    const double d = (x - center).cwiseAbs().maxCoeff();
    if (d > kMaxReach * diag) return d;
    return std::nullopt;
  }
  // Throws for the first row of X beyond reach, naming `what`.
  void check_reach(const Vertices& X, const std::string& what) const {
    for (Eigen::Index i = 0; i < X.rows(); ++i) {
      if (const auto d = beyond_reach(X.row(i).transpose())) {
        fail(what + ": row " + std::to_string(i) + " lies " + number(*d) +
             " from the rest mesh, over " + number(kMaxReach) +
             " times its size; rescale the mesh and the positions (only shapes matter)");
      }
    }
  }

  void check_inputs(const std::vector<Vertices>& hp, const Matrix3Array* rotations,
                    const Eigen::Matrix4d* frame_transform) const {
    if (static_cast<int>(hp.size()) != h) {
      fail("handle_positions: expected " + std::to_string(h) + " arrays, got " +
           std::to_string(hp.size()));
    }
    for (int j = 0; j < h; ++j) {
      const int k = handle_offset[j + 1] - handle_offset[j];
      if (hp[j].rows() != k) {
        fail(item("handle_positions", j) + ": expected shape (" + std::to_string(k) + ",3), got (" +
             std::to_string(hp[j].rows()) + ",3)");
      }
      if (!hp[j].allFinite()) fail(item("handle_positions", j) + ": contains NaN or infinity");
      check_reach(hp[j], item("handle_positions", j));
    }
    if (rotations) {
      if (static_cast<int>(rotations->size()) != r) {
        fail("rotations: expected " + std::to_string(r) + " rotations, got " +
             std::to_string(rotations->size()));
      }
      for (int q = 0; q < r; ++q) {
        const Mat3& G = (*rotations)[q];
        if (!G.allFinite() || !(G.transpose() * G).isIdentity(1e-6) || G.determinant() < 0.0) {
          fail(item("rotations", q) + ": expected a rotation matrix (orthonormal, det +1)");
        }
      }
    }
    if (frame_transform) {
      if (frame < 0) fail("frame_transform: given, but the deformer has no frame face");
      const Eigen::Matrix4d& T = *frame_transform;
      const Mat3 Rf = T.topLeftCorner<3, 3>();
      if (!T.allFinite() || !(Rf.transpose() * Rf).isIdentity(1e-6) || Rf.determinant() < 0.0 ||
          !T.row(3).isApprox(Eigen::RowVector4d(0, 0, 0, 1), 1e-12)) {
        fail(
            "frame_transform: expected a rigid 4x4 transform (rotation, translation, bottom row "
            "0 0 0 1)");
      }
      if (const auto d = beyond_reach(Rf * frame_rest_centroid + T.topRightCorner<3, 1>())) {
        fail("frame_transform: moves the frame face " + number(*d) + " from the rest mesh, over " +
             number(kMaxReach) +
             " times its size; rescale the mesh and the positions (only shapes matter)");
      }
    } else if (frame >= 0 && p >= 2 &&
               (frame_in_handles[0] < 0 || frame_in_handles[1] < 0 || frame_in_handles[2] < 0)) {
      fail(
          "frame_transform: required, because the vertices of the frame face are not all handle "
          "vertices");
    }
  }

  Vertices concat_targets(const std::vector<Vertices>& hp) const {
    Vertices t(static_cast<Eigen::Index>(handle_all.size()), 3);
    for (int j = 0; j < h; ++j) t.middleRows(handle_offset[j], hp[j].rows()) = hp[j];
    return t;
  }

  // Frame of the edit: from frame_transform, the handle targets, or a best fit.
  void edit_frame(const Vertices& targets, const Eigen::Matrix4d* frame_transform, Mat3* R,
                  Vec3* o) const {
    if (frame >= 0 && frame_transform) {
      *R = frame_transform->topLeftCorner<3, 3>();
      *o = *R * frame_rest_centroid + frame_transform->topRightCorner<3, 1>();
    } else if (frame >= 0) {
      const Vec3 a = targets.row(frame_in_handles[0]), b = targets.row(frame_in_handles[1]),
                 c = targets.row(frame_in_handles[2]);
      try {
        *R = face_rotation(frame_rest_inverse, a, b, c);
      } catch (const std::invalid_argument&) {
        fail("handle_positions: the frame face's vertices are placed on a line");
      }
      *o = (a + b + c) / 3.0;
    } else {
      *R = Mat3::Identity();
      *o = Vec3::Zero();
      if (h == 0 || !frozen_vertices.empty()) return;
      *R = best_rotation(handle_rest, targets);
      *o = targets.colwise().mean().transpose();
    }
  }

  Eigen::VectorXd weights(const Vertices& targets, const Matrix3Array* rotations,
                          const Eigen::Matrix4d* frame_transform) const {
    if (p == 0) return Eigen::VectorXd();
    if (p == 1) return Eigen::VectorXd::Ones(1);
    const bool joints = rotations && r > 0;
    if (!joints && !positions_error.empty()) fail(positions_error);
    Mat3 R;
    Vec3 o;
    edit_frame(targets, frame_transform, &R, &o);
    const Eigen::VectorXd x = pose_vector(targets, R, o, joints ? rotations : nullptr);
    return joints ? interp_full(x) : interp_positions(x);
  }

  // ---------------------------------------------------------------------------- per level

  void blend(const Eigen::VectorXd& w, Matrix3Array* Q, Matrix3Array* S) const {
    const int E = static_cast<int>(ldual.rows()), lm = static_cast<int>(lfaces.rows());
    Q->resize(E);
    S->resize(lm);
    auto body_q = [&](int b, int e) {
      for (int l = b; l < e; ++l) {
        Vec3 om = Vec3::Zero();
        for (int k = 0; k < p; ++k) om += w(k) * omega.row(l).segment<3>(3 * k).transpose();
        (*Q)[l] = rotation_exp(om);
      }
    };
    auto body_s = [&](int b, int e) {
      for (int i = b; i < e; ++i) {
        double s[6] = {1, 1, 1, 0, 0, 0};
        if (p > 0) {
          std::fill(s, s + 6, 0.0);
          for (int k = 0; k < p; ++k)
            for (int c = 0; c < 6; ++c) s[c] += w(k) * stretch(i, 6 * k + c);
        }
        Mat3& M = (*S)[i];
        M << s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2];
      }
    };
    if (E < kParallelMin) {
      body_q(0, E);
      body_s(0, lm);
    } else {
      parallel_ranges(E, kParallelMin / 2, kTasks, body_q);
      parallel_ranges(lm, kParallelMin / 2, kTasks, body_s);
    }
  }

  void vertex_rotations(const Matrix3Array& Rf, Matrix3Array* Rv) const {
    const int nc = static_cast<int>(lrest.rows());
    Rv->resize(nc);
    for (int c = 0; c < nc; ++c) {
      Mat3 sum = Mat3::Zero();
      for (int k = vf_ptr[c]; k < vf_ptr[c + 1]; ++k) sum += larea[vf_idx[k]] * Rf[vf_idx[k]];
      (*Rv)[c] = nearest_rotation(sum);
    }
  }

  // Dense vertex v from level positions y: single resolution y_v; multiresolution
  // sum_c b_vc y_c + (sum_c b_vc R_c) d_v(w).
  Vec3 dense_position(int v, const Vertices& y, const Matrix3Array& Rv,
                      const Eigen::VectorXd& w) const {
    if (!multires) return y.row(level_of[v]).transpose();
    return base_position(v, y) + offset(v, Rv, w);
  }
  Vec3 base_position(int v, const Vertices& y) const {
    Vec3 s = Vec3::Zero();
    for (int k = tr_ptr[v]; k < tr_ptr[v + 1]; ++k) s += tr_w[k] * y.row(tr_idx[k]).transpose();
    return s;
  }
  Vec3 offset(int v, const Matrix3Array& Rv, const Eigen::VectorXd& w) const {
    Mat3 M = Mat3::Zero();
    for (int k = tr_ptr[v]; k < tr_ptr[v + 1]; ++k) M += tr_w[k] * Rv[tr_idx[k]];
    Vec3 d = Vec3::Zero();
    if (p == 0) {
      d = detail.row(v).segment<3>(0).transpose();
    } else {
      for (int k = 0; k < p; ++k) d += w(k) * detail.row(v).segment<3>(3 * k).transpose();
    }
    return M * d;
  }

  // Level-space targets of a row for dense vertex v with dense target t.
  Vec3 row_target(int v, const Vec3& t, const Matrix3Array& Rv, const Eigen::VectorXd& w) const {
    return multires ? Vec3(t - offset(v, Rv, w)) : t;
  }

  PositionSolver::Row make_row(int v) const {
    PositionSolver::Row row;
    if (!multires) {
      row.idx = {level_of[v]};
      row.beta = {1.0};
    } else {
      for (int k = tr_ptr[v]; k < tr_ptr[v + 1]; ++k) {
        row.idx.push_back(tr_idx[k]);
        row.beta.push_back(tr_w[k]);
      }
    }
    return row;
  }

  // final: the rotations step 2 uses. The natural shape of a call that also solves with the
  // handle rotations only feeds the rigid fits and the start of that solve, so the Gauss-Newton
  // gauge steps suffice for it.
  int solve_rotations(const RotationSolver& solver, const Matrix3Array& Q, const Matrix3Array* G,
                      const Matrix3Array& Z, const Matrix3Array* init, bool final,
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

  Vertices run(const std::vector<Vertices>& hp, const Matrix3Array* rotations,
               const Eigen::Matrix4d* frame_transform) const;
};

// ------------------------------------------------------------------------------------------

PoseSpaceDeformer::PoseSpaceDeformer(const Vertices& vertices, const Faces& faces,
                                     const std::vector<Vertices>& examples,
                                     const std::vector<std::vector<int>>& handles,
                                     const PoseSpaceOptions& options)
    : impl_(std::make_unique<Impl>()) {
  Impl& I = *impl_;
  validate_mesh(vertices, faces);
  I.rest = vertices;
  I.faces = faces;
  I.opt = options;
  I.n = static_cast<int>(vertices.rows());
  I.m = static_cast<int>(faces.rows());
  I.p = static_cast<int>(examples.size());
  I.h = static_cast<int>(handles.size());
  I.r = static_cast<int>(options.rotational.size());
  const int n = I.n, m = I.m;
  if (m == 0) fail("faces: expected at least one triangle");
  {
    std::vector<char> used(n, 0);
    for (int f = 0; f < m; ++f)
      for (int l = 0; l < 3; ++l) used[faces(f, l)] = 1;
    for (int v = 0; v < n; ++v) {
      if (!used[v]) fail("vertices: vertex " + std::to_string(v) + " is not used by any face");
    }
  }
  const DualEdges dual = dual_edges(faces);
  I.diag = (vertices.colwise().maxCoeff() - vertices.colwise().minCoeff()).norm();
  I.center = (vertices.colwise().minCoeff() +
              0.5 * (vertices.colwise().maxCoeff() - vertices.colwise().minCoeff()))
                 .transpose();
  if (!(options.position_weight > 0.0) || !std::isfinite(options.position_weight)) {
    fail("position_weight: expected a finite value > 0");
  }
  if (!(options.rotation_weight > 0.0) || !std::isfinite(options.rotation_weight)) {
    fail("rotation_weight: expected a finite value > 0");
  }
  if (!(options.joint_weight > 0.0) || !std::isfinite(options.joint_weight)) {
    fail("joint_weight: expected a finite value > 0");
  }
  if (!(options.weight_regularization >= 0.0) || !std::isfinite(options.weight_regularization)) {
    fail("weight_regularization: expected a finite value >= 0");
  }
  if (options.transfer_neighbors < 1) fail("transfer_neighbors: expected >= 1");
  if (options.rotation_iterations < 1) fail("rotation_iterations: expected >= 1");
  if (options.gauge_steps < 1) fail("gauge_steps: expected >= 1");
  if (!(options.rotation_tolerance > 0.0) || !(options.rotation_tolerance < 1.0)) {
    fail("rotation_tolerance: expected a value in (0, 1)");
  }
  if (!(options.reliability_angle > 0.0)) fail("reliability_angle: expected a value > 0");
  if (!(options.orientation_weight >= 0.0) || !std::isfinite(options.orientation_weight)) {
    fail("orientation_weight: expected a finite value >= 0");
  }

  // Examples.
  for (int k = 0; k < I.p; ++k) {
    if (examples[k].rows() != n) {
      fail(item("examples", k) + ": expected shape (" + std::to_string(n) + ",3), got (" +
           std::to_string(examples[k].rows()) + ",3)");
    }
    if (!examples[k].allFinite()) fail(item("examples", k) + ": contains NaN or infinity");
    I.check_reach(examples[k], item("examples", k));
  }

  // Handles: non-empty, in range, unique, disjoint.
  I.handles = handles;
  std::vector<int> owner(n, -1);
  I.handle_offset.push_back(0);
  for (int j = 0; j < I.h; ++j) {
    if (handles[j].empty()) fail(item("handles", j) + ": a handle needs at least one vertex");
    for (int v : handles[j]) {
      if (v < 0 || v >= n) {
        fail(item("handles", j) + ": vertex " + std::to_string(v) + " outside [0, " +
             std::to_string(n) + ")");
      }
      if (owner[v] == j) fail(item("handles", j) + ": vertex " + std::to_string(v) + " repeated");
      if (owner[v] >= 0) {
        fail("handles: handles " + std::to_string(owner[v]) + " and " + std::to_string(j) +
             " share vertex " + std::to_string(v));
      }
      owner[v] = j;
      I.handle_all.push_back(v);
    }
    I.handle_offset.push_back(static_cast<int>(I.handle_all.size()));
  }
  I.handle_rest = gather_rows(vertices, I.handle_all);

  // Frozen faces.
  I.is_frozen_vertex.assign(n, 0);
  {
    std::vector<char> seen(m, 0);
    for (size_t q = 0; q < options.frozen.size(); ++q) {
      const int f = options.frozen[q];
      if (f < 0 || f >= m) {
        fail("frozen: face " + std::to_string(f) + " outside [0, " + std::to_string(m) + ")");
      }
      if (seen[f]) fail("frozen: face " + std::to_string(f) + " repeated");
      seen[f] = 1;
      for (int l = 0; l < 3; ++l) I.is_frozen_vertex[faces(f, l)] = 1;
    }
    for (int v = 0; v < n; ++v) {
      if (I.is_frozen_vertex[v]) I.frozen_vertices.push_back(v);
    }
    for (int v : I.handle_all) {
      if (I.is_frozen_vertex[v]) {
        fail("handles: vertex " + std::to_string(v) +
             " belongs to a frozen face, which keeps its rest position");
      }
    }
  }

  // Frame face.
  if (options.frame) {
    const int f = *options.frame;
    if (f < 0 || f >= m) {
      fail("frame: face " + std::to_string(f) + " outside [0, " + std::to_string(m) + ")");
    }
    I.frame = f;
    std::vector<int> pos(n, -1);
    for (size_t s = 0; s < I.handle_all.size(); ++s) pos[I.handle_all[s]] = static_cast<int>(s);
    for (int l = 0; l < 3; ++l) {
      I.frame_vertices[l] = faces(f, l);
      I.frame_in_handles[l] = pos[faces(f, l)];
    }
    const Vec3 a = vertices.row(faces(f, 0)), b = vertices.row(faces(f, 1)),
               c = vertices.row(faces(f, 2));
    I.frame_rest_inverse = face_frame(a, b, c).inverse();
    I.frame_rest_centroid = (a + b + c) / 3.0;
  }

  // Rotational pairs.
  for (int q = 0; q < I.r; ++q) {
    const auto& pr = options.rotational[q];
    for (int s = 0; s < 2; ++s) {
      if (pr[s] < 0 || pr[s] >= m) {
        fail(item("rotational", q) + ": face " + std::to_string(pr[s]) + " outside [0, " +
             std::to_string(m) + ")");
      }
    }
    if (pr[0] == pr[1]) fail(item("rotational", q) + ": the two faces must differ");
  }

  // Parts (vertices connected through edges): those with a control are solved, the others
  // stay exactly at rest.
  {
    DisjointSets sets(n);
    for (int f = 0; f < m; ++f) {
      sets.unite(faces(f, 0), faces(f, 1));
      sets.unite(faces(f, 0), faces(f, 2));
    }
    std::vector<int> label(n, -1);
    I.vpart.resize(n);
    I.parts = 0;
    for (int v = 0; v < n; ++v) {
      const int root = sets.find(v);
      if (label[root] < 0) label[root] = I.parts++;
      I.vpart[v] = label[root];
    }
  }
  std::vector<int> fpart(m);
  for (int f = 0; f < m; ++f) fpart[f] = I.vpart[faces(f, 0)];
  std::vector<char> controlled(I.parts, 0);
  I.part_frozen.assign(I.parts, 0);
  for (int v : I.handle_all) controlled[I.vpart[v]] = 1;
  for (int f : options.frozen) controlled[fpart[f]] = I.part_frozen[fpart[f]] = 1;
  if (I.frame >= 0) controlled[fpart[I.frame]] = 1;
  for (const auto& pr : options.rotational) controlled[fpart[pr[0]]] = controlled[fpart[pr[1]]] = 1;
  I.at_rest.assign(n, 0);
  for (int v = 0; v < n; ++v) I.at_rest[v] = I.is_frozen_vertex[v] || !controlled[I.vpart[v]];
  Faces afaces;  // faces of the solved parts, in dense order
  std::vector<int> aface_ids;
  for (int f = 0; f < m; ++f) {
    if (controlled[fpart[f]]) aface_ids.push_back(f);
  }
  I.whole = static_cast<int>(aface_ids.size()) == m;
  if (I.whole) {
    afaces = faces;
  } else {
    afaces.resize(static_cast<Eigen::Index>(aface_ids.size()), 3);
    for (size_t i = 0; i < aface_ids.size(); ++i)
      afaces.row(static_cast<Eigen::Index>(i)) = faces.row(aface_ids[i]);
  }
  int active_vertices = 0;
  for (int v = 0; v < n; ++v) active_vertices += controlled[I.vpart[v]];

  // Pose space.
  if (options.orientation_weight > 0.0) {
    for (int j = 0; j < I.h; ++j) {
      const int b = I.handle_offset[j], e = I.handle_offset[j + 1];
      if (e - b >= 3 && planarity(I.handle_rest.middleRows(b, e - b)) > 1e-3)
        I.oriented.push_back(j);
    }
  }
  if (I.p >= 2) {
    if (I.h == 0 && I.r == 0) {
      fail(
          "handles: with two or more examples the pose must be measured from at least one handle "
          "or rotational pair");
    }
    const bool own_frame = I.frame < 0 && I.frozen_vertices.empty();
    if (I.h == 1 && own_frame && I.r == 0) {
      fail(
          "handles: a single handle measured in its own best-fit frame says nothing about the "
          "pose; add handles, a frame face, a frozen region or rotational pairs");
    }
    if (I.h > 0 && own_frame && planarity(I.handle_rest) < 1e-6) {
      fail(
          "handles: the handle vertices lie on a line, so the frame the pose is measured in is "
          "undefined; add handle vertices off that line or give a frame face");
    }
    try {
      for (int k = 0; k < I.p; ++k) {
        // Checked here so that a degenerate face reports the example.
        if (I.frame >= 0) (void)I.example_face_rotation(examples[k], I.frame);
        for (const auto& pr : options.rotational) {
          (void)I.example_face_rotation(examples[k], pr[0]);
          (void)I.example_face_rotation(examples[k], pr[1]);
        }
      }
    } catch (const std::invalid_argument&) {
      fail("examples: a frame or rotational face is degenerate in an example");
    }
    if (I.r > 0) {
      RowMatrix P(I.p, I.pose_dim(true));
      for (int k = 0; k < I.p; ++k) P.row(k) = I.example_pose(examples[k], true).transpose();
      I.interp_full = Interpolator(P, options.weight_regularization, options.convex_weights);
    }
    if (I.h == 0) {
      I.positions_error =
          "rotations: required, because without handles the pose is given by the joint rotations "
          "alone";
    } else {
      RowMatrix P(I.p, I.pose_dim(false));
      for (int k = 0; k < I.p; ++k) P.row(k) = I.example_pose(examples[k], false).transpose();
      try {
        I.interp_positions = Interpolator(P, options.weight_regularization, options.convex_weights);
      } catch (const std::invalid_argument& e) {
        if (I.r == 0) throw;
        I.positions_error =
            std::string("rotations: required to tell the examples apart (") + e.what() + ")";
      }
    }
  }

  // Solve level.
  if (options.coarse_faces && (*options.coarse_faces < 4 || *options.coarse_faces >= m)) {
    fail("coarse: expected a face count in [4, " + std::to_string(m) + "), got " +
         std::to_string(*options.coarse_faces));
  }
  if (aface_ids.empty()) return;  // no part has a control: deform() returns the rest mesh
  if (options.coarse_faces) {
    const int target = *options.coarse_faces;
    if (target >= afaces.rows()) {
      fail("coarse: expected fewer faces than the " + std::to_string(afaces.rows()) +
           " of the parts being solved (the parts without a control stay at rest), got " +
           std::to_string(target));
    }
    // meshopt takes float positions: beyond ~3e38 they are infinite.
    const double far = vertices.cwiseAbs().maxCoeff();
    if (!(far < 1e37)) {
      fail("coarse: the mesh lies " + number(far) +
           " from the origin and the simplifier works in single precision; move the mesh nearer "
           "the origin or solve at full resolution");
    }
    I.multires = true;
    I.whole = false;
    coarse_mesh(vertices, afaces, target, I.diag, &I.lvertices, &I.lrest, &I.lfaces);
  } else if (I.whole) {
    I.lrest = vertices;
    I.lfaces = faces;
    I.lvertices.resize(n);
    std::iota(I.lvertices.begin(), I.lvertices.end(), 0);
  } else {
    for (int v = 0; v < n; ++v) {
      if (controlled[I.vpart[v]]) I.lvertices.push_back(v);
    }
    I.lrest = gather_rows(vertices, I.lvertices);
  }
  const int ln = static_cast<int>(I.lvertices.size());
  I.level_of.assign(n, -1);
  for (int c = 0; c < ln; ++c) I.level_of[I.lvertices[c]] = c;
  const std::vector<int>& level_of = I.level_of;
  std::vector<int> lface_of;  // single resolution: dense face -> level face
  if (!I.multires && !I.whole) {
    I.lfaces.resize(afaces.rows(), 3);
    lface_of.assign(m, -1);
    for (Eigen::Index f = 0; f < afaces.rows(); ++f) {
      for (int l = 0; l < 3; ++l) I.lfaces(f, l) = level_of[afaces(f, l)];
      lface_of[aface_ids[f]] = static_cast<int>(f);
    }
  }
  const int lm = static_cast<int>(I.lfaces.rows());
  I.ldual = I.whole ? dual.pairs : dual_edges(I.lfaces).pairs;
  I.lface_part.resize(lm);
  for (int f = 0; f < lm; ++f) I.lface_part[f] = I.vpart[I.lvertices[I.lfaces(f, 0)]];
  std::vector<int> lvpart(ln);
  for (int c = 0; c < ln; ++c) lvpart[c] = I.vpart[I.lvertices[c]];
  if (I.multires) {
    // Each solved part must come out as one piece of the coarse mesh.
    int count = 0;
    const std::vector<int> lcomp = face_components(lm, I.ldual, &count);
    std::vector<int> pieces(I.parts, 0), seen(count, 0);
    for (int f = 0; f < lm; ++f) {
      if (!seen[lcomp[f]]) ++pieces[I.lface_part[f]];
      seen[lcomp[f]] = 1;
    }
    for (int c = 0; c < I.parts; ++c) {
      if (!controlled[c] || pieces[c] == 1) continue;
      std::string which;
      for (int f = 0; f < m && which.empty(); ++f) {
        if (fpart[f] == c) which = "the part with face " + std::to_string(f);
      }
      fail("coarse: " + (I.parts == 1 ? std::string("the mesh") : which) +
           (pieces[c] == 0 ? " vanishes from the simplified mesh"
                           : " falls apart into " + std::to_string(pieces[c]) + " pieces") +
           "; choose a larger face count");
    }
  }

  // Multiresolution transfer weights: harmonic on the dense vertex graph (edge weights
  // 1/length^2), one Dirichlet anchor per coarse vertex, the largest few kept per vertex.
  if (I.multires) {
    const IndexPairs edges = mesh_edges(afaces);
    Eigen::VectorXd phi(edges.rows());
    double mean_len = 0.0;
    for (Eigen::Index e = 0; e < edges.rows(); ++e) {
      phi(e) = (vertices.row(edges(e, 0)) - vertices.row(edges(e, 1))).norm();
      mean_len += phi(e);
    }
    mean_len /= static_cast<double>(std::max<Eigen::Index>(edges.rows(), 1));
    for (Eigen::Index e = 0; e < edges.rows(); ++e) {
      const double rel = std::max(phi(e) / mean_len, 1e-6);
      phi(e) = 1.0 / (rel * rel);
    }
    AnchorList anchors(ln);
    for (int c = 0; c < ln; ++c) anchors[c] = {I.lvertices[c]};
    // The largest few per vertex, renormalised (the dense (n, ln) matrix would take 8 n ln
    // bytes: 1.9 GB at a million faces and 1000 coarse faces, several copies at its peak).
    const SparseWeights W =
        largest_harmonic_weights(n, edges, phi, anchors, options.transfer_neighbors);
    I.tr_ptr = W.ptr;
    I.tr_idx = W.idx;
    I.tr_w = W.w;
    for (int v = 0; v < n; ++v) {  // vertices of free parts have none
      double sum = 0.0;
      for (int k = I.tr_ptr[v]; k < I.tr_ptr[v + 1]; ++k) sum += I.tr_w[k];
      for (int k = I.tr_ptr[v]; k < I.tr_ptr[v + 1]; ++k) I.tr_w[k] /= sum;
    }
    I.larea = double_areas(I.lrest, I.lfaces);
    std::vector<int> cnt(ln + 1, 0);
    for (int f = 0; f < lm; ++f)
      for (int l = 0; l < 3; ++l) ++cnt[I.lfaces(f, l) + 1];
    for (int c = 0; c < ln; ++c) cnt[c + 1] += cnt[c];
    I.vf_ptr = cnt;
    I.vf_idx.resize(static_cast<size_t>(cnt[ln]));
    std::vector<int> cur(cnt.begin(), cnt.end() - 1);
    for (int f = 0; f < lm; ++f)
      for (int l = 0; l < 3; ++l) I.vf_idx[cur[I.lfaces(f, l)]++] = f;
  }

  // Encodings of the examples on the level: relative rotation logs per dual edge and the
  // rest-frame stretch per face.
  const int E = static_cast<int>(I.ldual.rows());
  I.omega = RowMatrix::Zero(E, 3 * I.p);
  I.stretch = RowMatrix::Zero(lm, 6 * I.p);
  std::vector<Matrix3Array> example_rotations(I.p);
  for (int k = 0; k < I.p; ++k) {
    const Vertices ex = I.whole ? examples[k] : gather_rows(examples[k], I.lvertices);
    const Matrix3Array T = deformation_gradients(I.lrest, ex, I.lfaces);
    Matrix3Array& R = example_rotations[k];
    R.resize(lm);
    for (int i = 0; i < lm; ++i) {
      Mat3 Sl;
      try {
        polar_decompose(T[i], &Sl, &R[i]);
      } catch (const std::invalid_argument&) {
        fail(item("examples", k) + ": " + (I.multires ? "coarse " : "") + "face " +
             std::to_string(i) + " is degenerate (zero area)");
      }
      pack_sym(R[i].transpose() * T[i], &I.stretch(i, 6 * k));
    }
    for (int e = 0; e < E; ++e) {
      I.omega.row(e).segment<3>(3 * k) =
          rotation_log(R[I.ldual(e, 0)].transpose() * R[I.ldual(e, 1)]).transpose();
    }
  }

  // Detail vectors: d_v^k = M_vk^-1 (x_vk - sum_c b_vc y_ck), M_vk = sum_c b_vc R_ck.
  if (I.multires) {
    const int q = std::max(I.p, 1);
    I.detail = RowMatrix::Zero(n, 3 * q);
    for (int k = 0; k < q; ++k) {
      const Vertices X = I.p == 0 ? vertices : examples[k];
      const Vertices y = gather_rows(X, I.lvertices);
      Matrix3Array Rv(ln, Mat3::Identity());
      if (I.p > 0) I.vertex_rotations(example_rotations[k], &Rv);
      for (int v = 0; v < n; ++v) {
        Mat3 M = Mat3::Zero();
        for (int t = I.tr_ptr[v]; t < I.tr_ptr[v + 1]; ++t) M += I.tr_w[t] * Rv[I.tr_idx[t]];
        const Vec3 off = X.row(v).transpose() - I.base_position(v, y);
        const Eigen::FullPivLU<Mat3> lu(M);
        // A vertex whose neighbours' rotations cancel (never for neighbouring vertices of a
        // sane example) keeps no detail for this example.
        if (lu.isInvertible() && std::abs(M.determinant()) > 1e-3) {
          I.detail.row(v).segment<3>(3 * k) = lu.solve(off).transpose();
        }
      }
    }
  }

  // Level constraint sets.
  std::vector<char> lface_frozen(lm, 0);
  for (int c = 0; c < ln; ++c) {
    if (I.is_frozen_vertex[I.lvertices[c]]) I.lfixed_vertices.push_back(c);
  }
  if (!I.multires) {
    for (int f : options.frozen) lface_frozen[I.whole ? f : lface_of[f]] = 1;
  } else {
    for (int f = 0; f < lm; ++f) {
      lface_frozen[f] = I.is_frozen_vertex[I.lvertices[I.lfaces(f, 0)]] &&
                        I.is_frozen_vertex[I.lvertices[I.lfaces(f, 1)]] &&
                        I.is_frozen_vertex[I.lvertices[I.lfaces(f, 2)]];
    }
  }
  for (int f = 0; f < lm; ++f) {
    if (lface_frozen[f]) I.lfixed_faces.push_back(f);
  }
  if (!options.frozen.empty() && I.lfixed_faces.empty()) {
    fail(
        "frozen: the frozen region contains no face of the coarse mesh; enlarge it or use a "
        "larger coarse face count");
  }
  std::vector<std::vector<int>> part_members(I.parts), lpart_faces(I.parts);
  for (int v = 0; v < n; ++v) part_members[I.vpart[v]].push_back(v);
  for (int f = 0; f < lm; ++f) lpart_faces[I.lface_part[f]].push_back(f);
  // Rotational pairs on the level.
  for (int q = 0; q < I.r; ++q) {
    std::array<int, 2> lp;
    for (int s = 0; s < 2; ++s) {
      const int f = options.rotational[q][s];
      const Vec3 c = centroid(vertices, faces(f, 0), faces(f, 1), faces(f, 2));
      lp[s] = I.multires ? nearest_face(I.lrest, I.lfaces, c, lpart_faces[fpart[f]])
              : I.whole  ? f
                         : lface_of[f];
    }
    if (lp[0] == lp[1]) {
      fail(item("rotational", q) +
           ": both faces fall on the same coarse face; use a larger "
           "coarse face count");
    }
    I.lpairs.push_back(lp);
  }
  // Faces under each handle: single resolution, faces with all corners in the handle;
  // multiresolution, coarse faces whose corners are handle vertices or the strongest coarse
  // neighbour of one.
  if (options.handle_rotations) {
    std::vector<int> lowner(ln, -1);
    for (int j = 0; j < I.h; ++j) {
      for (int v : handles[j]) {
        if (level_of[v] >= 0 && lowner[level_of[v]] < 0) lowner[level_of[v]] = j;
        if (I.multires) {
          int best = -1;
          for (int t = I.tr_ptr[v]; t < I.tr_ptr[v + 1]; ++t) {
            if (best < 0 || I.tr_w[t] > I.tr_w[best]) best = t;
          }
          if (best >= 0 && lowner[I.tr_idx[best]] < 0) lowner[I.tr_idx[best]] = j;
        }
      }
    }
    for (int f = 0; f < lm; ++f) {
      const int j = lowner[I.lfaces(f, 0)];
      if (j >= 0 && lowner[I.lfaces(f, 1)] == j && lowner[I.lfaces(f, 2)] == j &&
          !lface_frozen[f]) {
        I.lhandle_faces.push_back(f);
        I.lhandle_owner.push_back(j);
      }
    }
  }

  // Solvers.
  std::vector<double> edge_cost(E, 0.0);
  for (int e = 0; e < E; ++e)
    for (int k = 0; k < I.p; ++k)
      edge_cost[e] = std::max(edge_cost[e], I.omega.row(e).segment<3>(3 * k).norm());
  // Reliability of each dual edge: strongly distorted faces in an example have ill-defined
  // rotations, and their edges turn by up to pi; they count less (1/2 at reliability_angle).
  std::vector<double> edge_weight(E, 1.0);
  if (std::isfinite(options.reliability_angle)) {
    for (int e = 0; e < E; ++e) {
      const double x = edge_cost[e] / options.reliability_angle;
      edge_weight[e] = 1.0 / (1.0 + x * x);
    }
  }
  I.grad = std::make_unique<GradientOperator>(I.lrest, I.lfaces, options.area_weights);
  // Rotation components: faces linked by dual edges or rotational pairs. Each needs a fixed
  // face, a penalty face or a prescribed rotation to pin its global rotation.
  int rcount = 0;
  std::vector<int> rcomp;
  {
    DisjointSets sets(lm);
    for (Eigen::Index e = 0; e < I.ldual.rows(); ++e) sets.unite(I.ldual(e, 0), I.ldual(e, 1));
    for (const auto& lp : I.lpairs) sets.unite(lp[0], lp[1]);
    rcomp.resize(lm);
    std::vector<int> label(lm, -1);
    for (int f = 0; f < lm; ++f) {
      const int root = sets.find(f);
      if (label[root] < 0) label[root] = rcount++;
      rcomp[f] = label[root];
    }
  }
  // Its root face: the one nearest the frame face if that is in it, else nearest the rest
  // centroid of the parts it touches (choices by geometry, not by the numbering).
  std::vector<int> rroot(rcount, -1);
  {
    std::vector<std::vector<int>> touches(rcount), rfaces(rcount);  // its parts, its faces
    for (int f = 0; f < lm; ++f) {
      touches[rcomp[f]].push_back(I.lface_part[f]);
      rfaces[rcomp[f]].push_back(f);
    }
    for (std::vector<int>& t : touches) {
      std::sort(t.begin(), t.end());
      t.erase(std::unique(t.begin(), t.end()), t.end());
    }
    int frame_comp = -1;
    const Vec3 frame_point =
        I.frame < 0 ? Vec3::Zero()
                    : centroid(vertices, faces(I.frame, 0), faces(I.frame, 1), faces(I.frame, 2));
    if (I.frame >= 0) {
      const int lf = I.multires
                         ? nearest_face(I.lrest, I.lfaces, frame_point, lpart_faces[fpart[I.frame]])
                     : I.whole ? I.frame
                               : lface_of[I.frame];
      frame_comp = rcomp[lf];
    }
    for (int k = 0; k < rcount; ++k) {
      Vec3 point = frame_point;
      if (k != frame_comp) {
        std::vector<int> ids;
        for (int c : touches[k])
          ids.insert(ids.end(), part_members[c].begin(), part_members[c].end());
        point = canonical_mean(vertices, ids);
      }
      rroot[k] = nearest_face(I.lrest, I.lfaces, point, rfaces[k]);
    }
  }
  std::vector<char> rfrozen(rcount, 0), rheld(rcount, 0);
  for (int f : I.lfixed_faces) rfrozen[rcomp[f]] = 1;
  for (int f : I.lhandle_faces) rheld[rcomp[f]] = 1;
  // Tree roots: the fixed faces, then the root of every rotation component without one.
  auto tree_roots = [&](const std::vector<int>& fixed) {
    std::vector<int> roots = fixed;
    std::vector<char> has(rcount, 0);
    for (int f : fixed) has[rcomp[f]] = 1;
    for (int k = 0; k < rcount; ++k) {
      if (!has[k]) roots.push_back(rroot[k]);
    }
    return roots;
  };
  // The natural shape is solved with the frozen faces fixed, or else the root face.
  std::vector<int> fixed_a = I.lfixed_faces;
  for (int k = 0; k < rcount; ++k) {
    if (!rfrozen[k]) fixed_a.push_back(rroot[k]);
  }
  I.rot_a = std::make_unique<RotationSolver>(lm, I.ldual, I.lpairs, options.joint_weight, fixed_a,
                                             tree_roots(fixed_a), std::vector<int>{}, 0.0,
                                             edge_cost, edge_weight);
  I.lface_follow.assign(lm, 1);
  if (!I.lhandle_faces.empty()) {
    // A rotation component without frozen or handle faces follows its part's fitted rotation;
    // in this solve its root is held (only to keep the matrix definite).
    std::vector<int> fixed_b = I.lfixed_faces;
    for (int k = 0; k < rcount; ++k) {
      if (!rfrozen[k] && !rheld[k]) fixed_b.push_back(rroot[k]);
    }
    for (int f = 0; f < lm; ++f) I.lface_follow[f] = !rfrozen[rcomp[f]] && !rheld[rcomp[f]];
    I.rot_b = std::make_unique<RotationSolver>(lm, I.ldual, I.lpairs, options.joint_weight, fixed_b,
                                               tree_roots(fixed_b), I.lhandle_faces,
                                               options.rotation_weight, edge_cost, edge_weight);
  }
  // Position penalty relative to the mean diagonal of the gradient term; with
  // multiresolution, dense rows are scaled by coarse/dense vertex counts so the balance
  // matches a single-resolution solve.
  I.lambda_pos = options.position_weight * I.grad->mean_diagonal *
                 (I.multires ? static_cast<double>(ln) / active_vertices : 1.0);
  for (int v : I.handle_all) I.handle_rows.push_back(I.make_row(v));
  if (I.frame >= 0) {
    for (int l = 0; l < 3; ++l) I.frame_rows.push_back(I.make_row(I.frame_vertices[l]));
  }
  I.lvpart = lvpart;
  I.pos_a = std::make_unique<PositionSolver>(I.lrest, I.lfaces, *I.grad, I.lfixed_vertices,
                                             std::vector<PositionSolver::Row>{}, 0.0, I.lvpart);
  I.pos_b = std::make_unique<PositionSolver>(I.lrest, I.lfaces, *I.grad, I.lfixed_vertices,
                                             I.handle_rows, I.lambda_pos, I.lvpart);
}

PoseSpaceDeformer::~PoseSpaceDeformer() = default;

Vertices PoseSpaceDeformer::Impl::run(const std::vector<Vertices>& hp,
                                      const Matrix3Array* rotations,
                                      const Eigen::Matrix4d* frame_transform) const {
  const ParkWorkersOnExit park;
  stats = PoseSpaceStats();
  auto t0 = Clock::now();
  const Vertices targets = concat_targets(hp);
  const Eigen::VectorXd w = weights(targets, rotations, frame_transform);
  stats.ms_weights = ms_since(t0);
  if (!w.allFinite()) fail(kOverflow);
  if (lfaces.rows() == 0) {  // no part has a control: everything stays at rest
    last_weights = w;
    return rest;
  }

  t0 = Clock::now();
  Matrix3Array Q, S;
  blend(w, &Q, &S);
  stats.ms_blend = ms_since(t0);
  const Matrix3Array* G = rotations && r > 0 ? rotations : nullptr;
  const int lm = static_cast<int>(lfaces.rows());

  // Step 1 and 2 without handles: the natural blended shape, up to a rigid motion.
  t0 = Clock::now();
  Matrix3Array R0;
  stats.iterations_first =
      solve_rotations(*rot_a, Q, G, Matrix3Array(), nullptr, rot_b == nullptr, &R0);
  stats.ms_rotations += ms_since(t0);
  t0 = Clock::now();
  Matrix3Array T(lm);
  for (int i = 0; i < lm; ++i) T[i] = R0[i] * S[i];
  Vertices y0;
  pos_a->solve(T, nullptr, &y0);
  stats.ms_positions += ms_since(t0);

  // Fit the natural shape to the handles: one rotation per part (none for a part with frozen
  // faces: they hold it in place), one per handle for its faces.
  t0 = Clock::now();
  Matrix3Array Rv0;
  if (multires) vertex_rotations(R0, &Rv0);
  std::vector<int> cverts = handle_all;
  Vertices ctargets = targets;
  Vertices frame_targets;
  if (frame >= 0 && frame_transform) {
    // The frame face as the natural shape has it, turned and moved to frame_transform.
    Vertices xf(3, 3);
    for (int l = 0; l < 3; ++l) xf.row(l) = dense_position(frame_vertices[l], y0, Rv0, w);
    const Mat3 Rn = face_rotation(frame_rest_inverse, xf.row(0), xf.row(1), xf.row(2));
    const Mat3 Rf = frame_transform->topLeftCorner<3, 3>();
    const Vec3 o = Rf * frame_rest_centroid + frame_transform->topRightCorner<3, 1>();
    const Eigen::RowVector3d c = xf.colwise().mean();
    frame_targets.resize(3, 3);
    for (int l = 0; l < 3; ++l) {
      frame_targets.row(l) = (Rf * Rn.transpose() * (xf.row(l) - c).transpose() + o).transpose();
      cverts.push_back(frame_vertices[l]);
    }
    ctargets.conservativeResize(ctargets.rows() + 3, 3);
    ctargets.bottomRows(3) = frame_targets;
  }
  Vertices x0(static_cast<Eigen::Index>(cverts.size()), 3);
  for (size_t s = 0; s < cverts.size(); ++s) {
    x0.row(static_cast<Eigen::Index>(s)) = dense_position(cverts[s], y0, Rv0, w).transpose();
  }
  std::vector<Mat3> Gpart(parts, Mat3::Identity());
  {
    std::vector<std::vector<int>> rows(parts);
    for (size_t s = 0; s < cverts.size(); ++s)
      rows[vpart[cverts[s]]].push_back(static_cast<int>(s));
    for (int c = 0; c < parts; ++c) {
      if (part_frozen[c] || rows[c].empty()) continue;
      Gpart[c] = best_rotation(gather_rows(x0, rows[c]), gather_rows(ctargets, rows[c]));
    }
  }
  stats.ms_fit = ms_since(t0);

  t0 = Clock::now();
  Matrix3Array R(lm);
  if (rot_b) {
    Matrix3Array Z(lm, Mat3::Identity()), init(lm);
    std::vector<Mat3> Gj(h);
    for (int j = 0; j < h; ++j) {
      Gj[j] = Gpart[vpart[handle_all[handle_offset[j]]]];
      const int b = handle_offset[j], e = handle_offset[j + 1];
      if (e - b < 3) continue;
      const Vertices xs = x0.middleRows(b, e - b), ts = targets.middleRows(b, e - b);
      if (planarity(xs) > 1e-6 && planarity(ts) > 1e-6) Gj[j] = best_rotation(xs, ts);
    }
    for (int i = 0; i < lm; ++i) init[i] = Gpart[lface_part[i]] * R0[i];
    for (size_t s = 0; s < lhandle_faces.size(); ++s) {
      const int f = lhandle_faces[s];
      Z[f] = Gj[lhandle_owner[s]] * R0[f];
    }
    stats.iterations_second = solve_rotations(*rot_b, Q, G, Z, &init, true, &R);
  }
  for (int i = 0; i < lm; ++i) {
    if (lface_follow[i]) R[i] = Gpart[lface_part[i]] * R0[i];
  }
  stats.ms_rotations += ms_since(t0);

  t0 = Clock::now();
  for (int i = 0; i < lm; ++i) T[i] = R[i] * S[i];
  Matrix3Array Rv;
  if (multires) vertex_rotations(R, &Rv);
  const bool with_frame = frame >= 0 && frame_transform;
  const size_t nrows = handle_rows.size() + (with_frame ? 3 : 0);
  Vertices row_t(static_cast<Eigen::Index>(nrows), 3);
  for (size_t s = 0; s < handle_all.size(); ++s) {
    row_t.row(static_cast<Eigen::Index>(s)) =
        row_target(handle_all[s], targets.row(static_cast<Eigen::Index>(s)).transpose(), Rv, w)
            .transpose();
  }
  if (with_frame) {
    for (int l = 0; l < 3; ++l) {
      row_t.row(static_cast<Eigen::Index>(handle_all.size()) + l) =
          row_target(frame_vertices[l], frame_targets.row(l).transpose(), Rv, w).transpose();
    }
    if (!pos_b_frame) {
      std::vector<PositionSolver::Row> rows = handle_rows;
      rows.insert(rows.end(), frame_rows.begin(), frame_rows.end());
      pos_b_frame = std::make_unique<PositionSolver>(lrest, lfaces, *grad, lfixed_vertices, rows,
                                                     lambda_pos, lvpart);
    }
  }
  Vertices y;
  (with_frame ? pos_b_frame : pos_b)->solve(T, nrows ? &row_t : nullptr, &y);
  stats.ms_positions += ms_since(t0);

  if (whole) {
    if (!y.allFinite()) fail(kOverflow);
    last_weights = w;
    return y;
  }
  if (!multires) {
    Vertices X = rest;
    for (Eigen::Index c = 0; c < y.rows(); ++c) X.row(lvertices[c]) = y.row(c);
    if (!X.allFinite()) fail(kOverflow);
    last_weights = w;
    return X;
  }

  t0 = Clock::now();
  Vertices X(n, 3);
  auto body = [&](int b, int e) {
    for (int v = b; v < e; ++v) {
      if (at_rest[v]) {
        X.row(v) = rest.row(v);
      } else {
        X.row(v) = dense_position(v, y, Rv, w).transpose();
      }
    }
  };
  if (n < kParallelMin) {
    body(0, n);
  } else {
    parallel_ranges(n, kParallelMin / 2, kTasks, body);
  }
  stats.ms_transfer = ms_since(t0);
  if (!X.allFinite()) fail(kOverflow);
  last_weights = w;
  return X;
}

Vertices PoseSpaceDeformer::deform(const std::vector<Vertices>& handle_positions,
                                   const Matrix3Array* rotations,
                                   const Eigen::Matrix4d* frame_transform) const {
  impl_->check_inputs(handle_positions, rotations, frame_transform);
  const std::lock_guard<std::mutex> lock(impl_->busy);
  const PoseSpaceStats kept = impl_->stats;
  try {
    return impl_->run(handle_positions, rotations, frame_transform);
  } catch (...) {
    impl_->stats = kept;  // a refused call changes nothing
    throw;
  }
}

Eigen::VectorXd PoseSpaceDeformer::pose_weights(const std::vector<Vertices>& handle_positions,
                                                const Matrix3Array* rotations,
                                                const Eigen::Matrix4d* frame_transform) const {
  impl_->check_inputs(handle_positions, rotations, frame_transform);
  Eigen::VectorXd w =
      impl_->weights(impl_->concat_targets(handle_positions), rotations, frame_transform);
  if (!w.allFinite()) fail(kOverflow);
  return w;
}

Eigen::VectorXd PoseSpaceDeformer::example_weights() const {
  const std::lock_guard<std::mutex> lock(impl_->busy);
  return impl_->last_weights;
}
PoseSpaceStats PoseSpaceDeformer::last_stats() const {
  const std::lock_guard<std::mutex> lock(impl_->busy);
  return impl_->stats;
}
int PoseSpaceDeformer::num_examples() const { return impl_->p; }
int PoseSpaceDeformer::num_handles() const { return impl_->h; }
int PoseSpaceDeformer::num_rotational() const { return impl_->r; }
bool PoseSpaceDeformer::multiresolution() const { return impl_->multires; }
const Faces& PoseSpaceDeformer::solve_faces() const { return impl_->lfaces; }
const std::vector<int>& PoseSpaceDeformer::solve_vertices() const { return impl_->lvertices; }

}  // namespace matdeform
