#include "matdeform/edge_deformer.hpp"

#include <Eigen/Geometry>
#include <Eigen/SparseCore>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>

#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"
#include "matdeform/transforms.hpp"
#include "simd.hpp"
#include "sparse_cholesky.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {

using V3 = Eigen::Vector3d;

// Positions (constraints, starts, results) may lie at most this many rest diagonals from the
// rest mesh's centre: squared lengths and the kernels' products of four lengths stay finite
// (the mesh itself is at most 1e50 across, validate_mesh), and a result beyond it has lost
// every digit of the mesh's shape anyway.
constexpr double kMaxReach = 1e50;
// A move below this many diagonals is round-off: the iterate is a fixed point in double
// precision, whatever the rate says.
constexpr double kRoundOff = 1e-12;
// Per-edge stiffness (stretch or bend times edge_weight times kappa) at most this: the
// normal-equation entries, sums of a few dozen of them, stay finite.
constexpr double kMaxStiffness = 1e300;

// Anchor turns (from the start to the constrained positions) up to which the first estimation
// step takes the start's own edge frames; beyond, it carries them by the anchors' rotations
// (EdgeDeformer::solve). Below it the plain step's linear error, ~(1 - cos) of the turn, is
// under 3.5 % and carrying costs more than it saves (a live drag turns ~1 degree per update).
constexpr double kCarryMinAngle = 15.0 * 3.14159265358979323846 / 180.0;

// Rest data of one edge as the per-iteration kernels read it. Vertex fields are slots (rows of
// the position buffers, see Impl); l < 0 means the edge has no sigma term. Stiffness is folded
// in: c_rho = lambda w kappa, c_sig = mu w kappa.
struct EdgeTerm {
  int i, j, l, m;
  double rest_len;  // |rho_0|
  double c_rho;
  double alpha, beta;
  double c_sig;
  double s_l, s_n, s_b;  // c_sig * (sigma_0 in the rest frame (l_0, n_0, l_0 x n_0))
};

// Box-constrained least squares: (x, y) in [0,1]^2 minimising |r + x u + y w|^2, with a tiny
// pull towards (1/2, 1/2) that picks one minimiser when there are many (parallel projections).
void box_least_squares(const V3& r, const V3& u, const V3& w, double* x_out, double* y_out) {
  const double uu = u.squaredNorm(), ww = w.squaredNorm(), uw = u.dot(w);
  const double ur = u.dot(r), wr = w.dot(r);
  const double eps = 1e-12 * (uu + ww) + std::numeric_limits<double>::min();
  const double a = uu + eps, c = ww + eps;
  auto f = [&](double x, double y) {
    return (r + x * u + y * w).squaredNorm() +
           eps * ((x - 0.5) * (x - 0.5) + (y - 0.5) * (y - 0.5));
  };
  auto clamp01 = [](double t) { return std::min(1.0, std::max(0.0, t)); };
  // Unconstrained minimiser of the (strictly convex) regularised quadratic.
  const double det = a * c - uw * uw;
  const double gx = -ur + 0.5 * eps, gy = -wr + 0.5 * eps;
  double x = (c * gx - uw * gy) / det, y = (a * gy - uw * gx) / det;
  if (!(x >= 0.0 && x <= 1.0 && y >= 0.0 && y <= 1.0)) {
    // Otherwise the minimum lies on the box boundary: best of the four clamped 1-d minima.
    double best = std::numeric_limits<double>::infinity();
    for (int side = 0; side < 4; ++side) {
      double cx, cy;
      if (side < 2) {
        cx = side;
        cy = clamp01((gy - uw * cx) / c);
      } else {
        cy = side - 2;
        cx = clamp01((gx - uw * cy) / a);
      }
      const double v = f(cx, cy);
      if (v < best) {
        best = v;
        x = cx;
        y = cy;
      }
    }
  }
  *x_out = x;
  *y_out = y;
}

// Twice the area-weighted normal of the edge (i, j) between faces (i, j, l) and (j, i, m), with
// the orientation taken from the first face only (so inconsistently wound neighbours still add).
template <class A>
V3 edge_normal2(const A& xi, const A& xj, const A& xl, const A& xm) {
  return (xj - xi).cross(xl - xi) + (xi - xj).cross(xm - xj);
}

// ---- per-iteration kernels (baseline and AVX2+FMA builds, see simd.hpp)

// The kernel's copy of the edge terms: four edges side by side (structure of arrays), so that
// the square roots and divisions of the estimation step run four edges at a time. Lanes without
// a bend term have l = m = i and zero bend stiffness; padding lanes have every field zero.
struct EdgeGroup {
  int i[4], j[4], l[4], m[4];
  double rest_len[4], c_rho[4], alpha[4], beta[4], c_sig[4], s_l[4], s_n[4], s_b[4];
  double r0[3][4];  // rest edge direction, for the collapsed-edge fallback
};

struct EstimateArgs {
  const EdgeGroup* groups;
  const Vec4d* P;  // positions by slot
  double p_rho, p_sig;
  const Vec4d* carry;  // carried estimation only: unit quaternion (x, y, z, w) by slot
};

// Four (x, y, z, pad) rows -> x, y, z of the four.
MD_ALWAYS_INLINE void load_soa(const Vec4d* P, const int* idx, Vec4d* x, Vec4d* y, Vec4d* z) {
  const Vec4d a = P[idx[0]], b = P[idx[1]], c = P[idx[2]], d = P[idx[3]];
  const Vec4d t0 = MD_UNPACK_EVEN(a, b);  // a0 b0 a2 b2
  const Vec4d t1 = MD_UNPACK_ODD(a, b);   // a1 b1 a3 b3
  const Vec4d t2 = MD_UNPACK_EVEN(c, d);
  const Vec4d t3 = MD_UNPACK_ODD(c, d);
  *x = MD_LOW_HALVES(t0, t2);
  *y = MD_LOW_HALVES(t1, t3);
  *z = MD_HIGH_HALVES(t0, t2);
}

// Adds (x_k, y_k, z_k, 0) to row idx[k] of Y, k = 0..3 in order (rows may repeat).
MD_ALWAYS_INLINE void add_aos(const Vec4d& x, const Vec4d& y, const Vec4d& z, const int* idx,
                              Vec4d* Y) {
  const Vec4d zero = {0, 0, 0, 0};
  const Vec4d t0 = MD_UNPACK_EVEN(x, y);     // x0 y0 x2 y2
  const Vec4d t1 = MD_UNPACK_ODD(x, y);      // x1 y1 x3 y3
  const Vec4d t2 = MD_UNPACK_EVEN(z, zero);  // z0 0 z2 0
  const Vec4d t3 = MD_UNPACK_ODD(z, zero);
  Y[idx[0]] += MD_LOW_HALVES(t0, t2);
  Y[idx[1]] += MD_LOW_HALVES(t1, t3);
  Y[idx[2]] += MD_HIGH_HALVES(t0, t2);
  Y[idx[3]] += MD_HIGH_HALVES(t1, t3);
}

MD_ALWAYS_INLINE double dot3(const Vec4d& a, const Vec4d& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

// Four unit quaternions, an edge's (the normalised sum of its two vertices' quaternions, which
// lie on the same side: they come from one continuous field), applied to vectors.
struct Rot4 {
  Vec4d x, y, z, w;
  MD_ALWAYS_INLINE void apply(Vec4d* vx, Vec4d* vy, Vec4d* vz) const {
    // v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    const Vec4d cx = y * *vz - z * *vy, cy = z * *vx - x * *vz, cz = x * *vy - y * *vx;
    const Vec4d dx = y * cz - z * cy, dy = z * cx - x * cz, dz = x * cy - y * cx;
    *vx += 2.0 * (w * cx + dx);
    *vy += 2.0 * (w * cy + dy);
    *vz += 2.0 * (w * cz + dz);
  }
};

MD_ALWAYS_INLINE Rot4 edge_rotations(const Vec4d* Q, const int* i, const int* j) {
  const Vec4d a0 = Q[i[0]] + Q[j[0]], a1 = Q[i[1]] + Q[j[1]], a2 = Q[i[2]] + Q[j[2]],
              a3 = Q[i[3]] + Q[j[3]];
  const Vec4d t0 = MD_UNPACK_EVEN(a0, a1), t1 = MD_UNPACK_ODD(a0, a1);
  const Vec4d t2 = MD_UNPACK_EVEN(a2, a3), t3 = MD_UNPACK_ODD(a2, a3);
  Rot4 q{MD_LOW_HALVES(t0, t2), MD_LOW_HALVES(t1, t3), MD_HIGH_HALVES(t0, t2),
         MD_HIGH_HALVES(t1, t3)};
  const Vec4d one = {1, 1, 1, 1};
  Vec4d len;
  sqrt4(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w, &len);
  const Vec4d inv = one / len;  // the sum of two unit quaternions at < 180 degrees is not 0
  q.x *= inv;
  q.y *= inv;
  q.z *= inv;
  q.w *= inv;
  return q;
}

// Estimation step (Eq. 10 with Eq. 15): for each edge the targets
//   rho* = (1 - p_rho) L_rho(V^k) + p_rho |rho_0| l^k,
//   sigma* = (1 - p_sig) L_sig(V^k) + p_sig (s_l l^k + s_n n^k + s_b (l^k x n^k)),
// times the edge's stiffness, with l^k = (x_i - x_j) / |x_i - x_j| and n^k along
// (x_j - x_i) x (x_i - x_l) + (x_i - x_j) x (x_m - x_j) = (x_j - x_i) x (x_l - x_m), the sum of
// the two faces' area-weighted normals. A collapsed edge takes its rest direction; an edge
// whose normal vanishes (faces folded onto each other) gets no bending pull this iteration.
// Carried (the first iteration when the anchors turn, see EdgeDeformer::solve): the rest
// parts (p_rho |rho_0| l^k, p_sig (...)) are turned further by the edge's rotation.
// The targets go straight into the right-hand side of the measure step (Eq. 11), D^T c target
// per edge, scattered into Y (rows by slot; rows of fixed vertices are scratch).
template <bool kCarry>
MD_ALWAYS_INLINE void estimate_body(const EstimateArgs& a, int gb, int ge, Vec4d* Y) {
  for (int g = gb; g < ge; ++g) {
    const EdgeGroup& t = a.groups[g];
    Vec4d xi, yi, zi, xj, yj, zj, xl, yl, zl, xm, ym, zm;
    load_soa(a.P, t.i, &xi, &yi, &zi);
    load_soa(a.P, t.j, &xj, &yj, &zj);
    load_soa(a.P, t.l, &xl, &yl, &zl);
    load_soa(a.P, t.m, &xm, &ym, &zm);
    const Vec4d one = {1, 1, 1, 1};
    const Vec4d dx = xi - xj, dy = yi - yj, dz = zi - zj;
    const Vec4d len2 = dx * dx + dy * dy + dz * dz;
    const Vec4d rl = MD_LD4(t.rest_len);
    const Vec4m has_dir = (len2 > 0.0) & (len2 > 1e-24 * rl * rl);
    Vec4d len;
    sqrt4(MD_SELECT4(has_dir, len2, one), &len);
    const Vec4d inv = one / len;
    const Vec4d lx = MD_SELECT4(has_dir, dx * inv, MD_LD4(t.r0[0]));
    const Vec4d ly = MD_SELECT4(has_dir, dy * inv, MD_LD4(t.r0[1]));
    const Vec4d lz = MD_SELECT4(has_dir, dz * inv, MD_LD4(t.r0[2]));
    [[maybe_unused]] Rot4 q{};
    Vec4d lcx = lx, lcy = ly, lcz = lz;  // the rest direction of rho*, carried
    if constexpr (kCarry) {
      q = edge_rotations(a.carry, t.i, t.j);
      q.apply(&lcx, &lcy, &lcz);
    }
    const Vec4d cr = MD_LD4(t.c_rho);
    const Vec4d k1 = cr * (1.0 - a.p_rho), k2 = cr * rl * a.p_rho;
    const Vec4d tx = k1 * dx + k2 * lcx, ty = k1 * dy + k2 * lcy, tz = k1 * dz + k2 * lcz;

    const Vec4d al = MD_LD4(t.alpha), be = MD_LD4(t.beta);
    const Vec4d sx = al * xi + (one - al) * xj - be * xl - (one - be) * xm;
    const Vec4d sy = al * yi + (one - al) * yj - be * yl - (one - be) * ym;
    const Vec4d sz = al * zi + (one - al) * zj - be * zl - (one - be) * zm;
    const Vec4d wx = xl - xm, wy = yl - ym, wz = zl - zm;
    const Vec4d cx = dz * wy - dy * wz, cy = dx * wz - dz * wx, cz = dy * wx - dx * wy;
    const Vec4d c2 = cx * cx + cy * cy + cz * cz;
    const Vec4m good = has_dir & (c2 > 1e-24 * len2 * (wx * wx + wy * wy + wz * wz));
    Vec4d cn;
    sqrt4(MD_SELECT4(good, c2, one), &cn);
    const Vec4d ic = one / cn;
    const Vec4d nx = cx * ic, ny = cy * ic, nz = cz * ic;
    const Vec4d bx = ly * nz - lz * ny, by = lz * nx - lx * nz, bz = lx * ny - ly * nx;
    const Vec4d cs = MD_LD4(t.c_sig), sl = MD_LD4(t.s_l), sn = MD_LD4(t.s_n), sb = MD_LD4(t.s_b);
    const Vec4d k3 = cs * (1.0 - a.p_sig);
    Vec4d ex = sl * lx + sn * nx + sb * bx, ey = sl * ly + sn * ny + sb * by,
          ez = sl * lz + sn * nz + sb * bz;
    if constexpr (kCarry) q.apply(&ex, &ey, &ez);
    const Vec4d rx = MD_SELECT4(good, ex, cs * sx);
    const Vec4d ry = MD_SELECT4(good, ey, cs * sy);
    const Vec4d rz = MD_SELECT4(good, ez, cs * sz);
    const Vec4d ux = k3 * sx + a.p_sig * rx, uy = k3 * sy + a.p_sig * ry,
                uz = k3 * sz + a.p_sig * rz;
    // D_rho^T t = (t, -t) on (i, j); D_sig^T u = (alpha, 1 - alpha, -beta, beta - 1) u.
    const Vec4d am = one - al, bm = be - one;
    add_aos(tx + al * ux, ty + al * uy, tz + al * uz, t.i, Y);
    add_aos(am * ux - tx, am * uy - ty, am * uz - tz, t.j, Y);
    add_aos(-be * ux, -be * uy, -be * uz, t.l, Y);
    add_aos(bm * ux, bm * uy, bm * uz, t.m, Y);
  }
}
void estimate_base(const EstimateArgs& a, int b, int e, Vec4d* Y) {
  estimate_body<false>(a, b, e, Y);
}
MD_TARGET_AVX2 void estimate_avx2(const EstimateArgs& a, int b, int e, Vec4d* Y) {
  estimate_body<false>(a, b, e, Y);
}
void estimate_carry_base(const EstimateArgs& a, int b, int e, Vec4d* Y) {
  estimate_body<true>(a, b, e, Y);
}
MD_TARGET_AVX2 void estimate_carry_avx2(const EstimateArgs& a, int b, int e, Vec4d* Y) {
  estimate_body<true>(a, b, e, Y);
}

}  // namespace

struct EdgeDeformer::Impl {
  int n = 0, nf = 0, nfix = 0, nc = 0;
  Vertices rest;
  std::vector<int> slot;          // vertex -> slot: [0, nf) solver rows, then fixed vertices
  std::vector<int> slot_vertex;   // slot -> vertex
  std::vector<EdgeGroup> groups;  // edges touching a free vertex, ordered by slot, 4 per group
  int num_terms = 0;
  // Free x fixed coupling (CSR by solver row; column = fixed slot - nf).
  std::vector<int> c_ptr, c_col;
  std::vector<double> c_val;
  std::unique_ptr<SparseCholesky> chol;

  // 4 doubles per row (x, y, z, pad), viewed as Vec4d by the kernels: two position buffers by
  // slot (current and next iterate), the constant right-hand side, and one right-hand-side
  // accumulator per parallel part of the estimation step (the first is solved in place).
  std::vector<double> P0, P1, b0;
  std::vector<std::vector<double>> acc;
  std::vector<double> part_move;  // per part: largest squared move of an iteration
  std::mutex busy;  // solve() calls from several threads (the GIL is released) take turns

  // Anchors: groups of constrained vertices (CSR over constrained indices, caller order), the
  // caller's or those joined by mesh edges. Each is fitted with a rotation in solve().
  std::vector<int> anchor_ptr, anchor_idx;
  std::vector<int> anchor_of;  // (nc,) anchor of each constrained vertex
  std::vector<double> carry;   // 4 per slot: rotation quaternion of the carried estimation
  V3 centre = V3::Zero();      // of the rest bounding box

  // Largest coordinate distance of rows of X from the rest centre, in rest diagonals.
  double reach(const Vertices& X, double diag) const {
    double r = 0.0;
    for (Eigen::Index v = 0; v < X.rows(); ++v)
      for (int k = 0; k < 3; ++k) r = std::max(r, std::abs(X(v, k) - centre(k)));
    return r / diag;
  }

  bool carry_rotations(const Vec4d* from, const Vec4d* to, const Vectors3* given);
};

// Best-fit rotation of anchor g from the points from(c) to to(c) (constrained indices c); false
// (no fit) for fewer than three points, points in a line, or a collapsed target.
template <class From, class To>
bool fit_anchor(const std::vector<int>& ptr, const std::vector<int>& idx, int g, From from, To to,
                Eigen::Matrix3d* R) {
  const int b = ptr[g], e = ptr[g + 1];
  if (e - b < 3) return false;
  V3 cf = V3::Zero(), ct = V3::Zero();
  for (int q = b; q < e; ++q) {
    cf += from(idx[q]);
    ct += to(idx[q]);
  }
  cf /= e - b;
  ct /= e - b;
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (int q = b; q < e; ++q) H += (to(idx[q]) - ct) * (from(idx[q]) - cf).transpose();
  double trace;
  return fit_rotation(H, R, &trace);
}

// The start when the anchors turn (see EdgeDeformer::solve): a rotation per anchor, the best
// fit of its vertices from -> to (slots nf + c), or the caller's vectors `given` (num_anchors,3),
// spread over the free vertices by the system's own response A_ff r_f = -A_fc r_c (rotation
// vectors r; vertices of anchors without a fit and passive vertices hold 0), then turned into
// quaternions by slot in `carry`. False (carry untouched) when no anchor turns by more than
// kCarryMinAngle.
bool EdgeDeformer::Impl::carry_rotations(const Vec4d* from, const Vec4d* to,
                                         const Vectors3* given) {
  const int na = static_cast<int>(anchor_ptr.size()) - 1;
  std::vector<V3> rot(na, V3::Zero());
  double largest = 0.0;
  for (int g = 0; g < na; ++g) {
    if (given) {
      rot[g] = given->row(g).transpose();
    } else {
      const auto at = [&](const Vec4d* p) {
        return [this, p](int c) { return V3(p[nf + c][0], p[nf + c][1], p[nf + c][2]); };
      };
      Eigen::Matrix3d R;
      if (fit_anchor(anchor_ptr, anchor_idx, g, at(from), at(to), &R)) rot[g] = rotation_log(R);
    }
    // an anchor id without vertices (caller anchors) turns nothing
    if (anchor_ptr[g + 1] > anchor_ptr[g]) largest = std::max(largest, rot[g].norm());
  }
  if (!(largest > kCarryMinAngle) || nf == 0) return false;

  carry.assign(4 * (static_cast<size_t>(nf) + nfix), 0.0);
  Vec4d* Q = reinterpret_cast<Vec4d*>(carry.data());
  for (int g = 0; g < na; ++g) {
    for (int q = anchor_ptr[g]; q < anchor_ptr[g + 1]; ++q) {
      Q[nf + anchor_idx[q]] = Vec4d{rot[g](0), rot[g](1), rot[g](2), 0.0};
    }
  }
  for (int r = 0; r < nf; ++r) {
    Vec4d b = {0, 0, 0, 0};
    for (int q = c_ptr[r]; q < c_ptr[r + 1]; ++q) b -= c_val[q] * Q[nf + c_col[q]];
    b[3] = 0.0;
    Q[r] = b;
  }
  chol->solve_permuted4(carry.data());
  for (size_t s = 0; s < static_cast<size_t>(nf) + nfix; ++s) {
    const V3 r(Q[s][0], Q[s][1], Q[s][2]);
    const double angle = r.norm();
    const Eigen::Quaterniond u(angle > 0.0 ? Eigen::AngleAxisd(angle, r / angle)
                                           : Eigen::AngleAxisd::Identity());
    Q[s] = Vec4d{u.x(), u.y(), u.z(), u.w()};
  }
  return true;
}

EdgeDeformer::EdgeDeformer(const Vertices& vertices, const Faces& faces,
                           const std::vector<int>& constrained, const EdgeDeformerOptions& options)
    : impl_(std::make_unique<Impl>()) {
  validate_mesh(vertices, faces);
  Impl& d = *impl_;
  const int n = n_ = static_cast<int>(vertices.rows());
  d.n = n;
  d.rest = vertices;
  if (!std::isfinite(options.stretch) || options.stretch < 0.0) {
    throw std::invalid_argument("stretch: expected a finite value >= 0");
  }
  if (!std::isfinite(options.bend) || !(options.bend > 0.0)) {
    throw std::invalid_argument("bend: expected a finite value > 0");
  }
  if (constrained.empty()) throw std::invalid_argument("constrained: expected at least one vertex");
  std::vector<char> is_fixed(n, 0);
  for (int v : constrained) {
    if (v < 0 || v >= n) {
      throw std::invalid_argument("constrained: vertex " + std::to_string(v) + " outside [0, " +
                                  std::to_string(n) + ")");
    }
    if (is_fixed[v]) {
      throw std::invalid_argument("constrained: vertex " + std::to_string(v) + " repeated");
    }
    is_fixed[v] = 1;
  }
  d.nc = static_cast<int>(constrained.size());

  edges_ = mesh_edges(faces);
  const int E = static_cast<int>(edges_.rows());
  if (options.edge_weight.size() != 0 && options.edge_weight.size() != E) {
    throw std::invalid_argument("edge_weight: expected one value per mesh edge (" +
                                std::to_string(E) + ")");
  }
  for (Eigen::Index e = 0; e < options.edge_weight.size(); ++e) {
    if (!std::isfinite(options.edge_weight(e)) || !(options.edge_weight(e) > 0.0)) {
      throw std::invalid_argument("edge_weight: expected finite values > 0");
    }
  }
  const bool has_field = options.direction.rows() != 0;
  if (has_field && options.direction.rows() != n) {
    throw std::invalid_argument("direction: expected shape (n,3) with n = " + std::to_string(n));
  }
  if (has_field && !options.direction.allFinite()) {
    throw std::invalid_argument("direction: contains NaN or infinity");
  }

  const V3 lo = vertices.colwise().minCoeff(), hi = vertices.colwise().maxCoeff();
  diag_ = n > 0 ? (hi - lo).norm() : 0.0;
  if (!(diag_ > 0.0)) diag_ = 1.0;
  d.centre = n > 0 ? V3(0.5 * (lo + hi)) : V3::Zero();

  // Interior manifold edges: exactly one face pair shares them.
  auto edge_index = [&](int a, int b) {
    int lo_e = 0, hi_e = E;
    while (lo_e < hi_e) {
      const int mid = (lo_e + hi_e) / 2;
      if (edges_(mid, 0) < a || (edges_(mid, 0) == a && edges_(mid, 1) < b)) {
        lo_e = mid + 1;
      } else {
        hi_e = mid;
      }
    }
    return lo_e;
  };
  const DualEdges dual = dual_edges(faces);
  std::vector<int> pair_count(E, 0), pair_of(E, -1);
  for (Eigen::Index p = 0; p < dual.pairs.rows(); ++p) {
    const int e = edge_index(dual.shared(p, 0), dual.shared(p, 1));
    if (e >= E || edges_(e, 0) != dual.shared(p, 0) || edges_(e, 1) != dual.shared(p, 1)) {
      throw std::logic_error("dual edge without a mesh edge");
    }
    ++pair_count[e];
    pair_of[e] = static_cast<int>(p);
  }

  // Anisotropy (Eq. 13): kappa from the tangential part of the field (the vertex normal part is
  // dropped); isotropic (1) where f_i + f_j vanishes.
  kappa_ = Eigen::VectorXd::Ones(E);
  if (has_field) {
    Vertices N = Vertices::Zero(n, 3);
    for (Eigen::Index f = 0; f < faces.rows(); ++f) {
      const V3 a = vertices.row(faces(f, 0)), b = vertices.row(faces(f, 1)),
               c = vertices.row(faces(f, 2));
      const V3 cr = (b - a).cross(c - a);
      for (int k = 0; k < 3; ++k) N.row(faces(f, k)) += cr.transpose();
    }
    Vertices ft(n, 3);
    for (int v = 0; v < n; ++v) {
      V3 fv = options.direction.row(v).transpose();
      const double nn = N.row(v).norm();
      if (nn > 0.0) {
        const V3 u = N.row(v).transpose() / nn;
        fv -= fv.dot(u) * u;
      }
      ft.row(v) = fv.transpose();
    }
    for (int e = 0; e < E; ++e) {
      const int a = edges_(e, 0), b = edges_(e, 1);
      const V3 s = (ft.row(a) + ft.row(b)).transpose();
      const V3 r = (vertices.row(a) - vertices.row(b)).transpose();
      const double scale = ft.row(a).norm() + ft.row(b).norm();
      const double sn = s.norm(), rn = r.norm();
      if (sn > 1e-9 * scale && rn > 0.0) kappa_(e) = std::min(1.0, std::abs(s.dot(r)) / (sn * rn));
    }
  }

  // Edge terms on the rest mesh (Eq. 4-5).
  opposite_ = IndexPairs::Constant(E, 2, -1);
  coefficients_ = RowMatrix::Constant(E, 2, std::numeric_limits<double>::quiet_NaN());
  std::vector<EdgeTerm> all(E);
  std::vector<double> all_dir(3 * static_cast<size_t>(E));
  for (int e = 0; e < E; ++e) {
    EdgeTerm& t = all[e];
    const double w = options.edge_weight.size() ? options.edge_weight(e) : 1.0;
    t.i = edges_(e, 0);
    t.j = edges_(e, 1);
    t.l = t.m = -1;
    t.alpha = t.beta = 0.0;
    t.c_sig = t.s_l = t.s_n = t.s_b = 0.0;
    if (pair_count[e] == 1) {
      const int f = dual.pairs(pair_of[e], 0), g = dual.pairs(pair_of[e], 1);
      int i = -1, j = -1, l = -1, m = -1;
      for (int k = 0; k < 3; ++k) {
        const int a = faces(f, k), b = faces(f, (k + 1) % 3);
        if (std::min(a, b) == t.i && std::max(a, b) == t.j) {
          i = a;
          j = b;
          l = faces(f, (k + 2) % 3);
        }
      }
      for (int k = 0; k < 3; ++k) {
        if (faces(g, k) != t.i && faces(g, k) != t.j) m = faces(g, k);
      }
      if (i >= 0 && m >= 0 && l != m) {
        const V3 xi = vertices.row(i), xj = vertices.row(j), xl = vertices.row(l),
                 xm = vertices.row(m);
        const V3 c = edge_normal2(xi, xj, xl, xm);
        const double len2 = (xi - xj).squaredNorm();
        // the same test as the iteration's (estimate_body): |c| above 1e-12 |x_ij| |x_lm|
        if (len2 > 0.0 && c.squaredNorm() > 1e-24 * len2 * (xl - xm).squaredNorm()) {
          const V3 nrm = c.normalized();
          const V3 ldir = (xi - xj) / std::sqrt(len2);
          const V3 bdir = ldir.cross(nrm);
          // sigma = p - q parallel to n: no tangential part, i.e. the projections onto the plane
          // normal to n meet: P(x_j - x_m) + alpha P(x_i - x_j) - beta P(x_l - x_m) = 0.
          const Eigen::Matrix3d Pn = Eigen::Matrix3d::Identity() - nrm * nrm.transpose();
          double alpha, beta;
          box_least_squares(Pn * (xj - xm), Pn * (xi - xj), -(Pn * (xl - xm)), &alpha, &beta);
          const V3 sigma = alpha * xi + (1 - alpha) * xj - beta * xl - (1 - beta) * xm;
          t.i = i;
          t.j = j;
          t.l = l;
          t.m = m;
          t.alpha = alpha;
          t.beta = beta;
          t.c_sig = options.bend * w * kappa_(e);
          t.s_l = t.c_sig * sigma.dot(ldir);
          t.s_n = t.c_sig * sigma.dot(nrm);
          t.s_b = t.c_sig * sigma.dot(bdir);
          opposite_(e, 0) = l;
          opposite_(e, 1) = m;
          coefficients_(e, 0) = i == edges_(e, 0) ? alpha : 1.0 - alpha;
          coefficients_(e, 1) = beta;
        }
      }
    }
    const V3 r = (vertices.row(t.i) - vertices.row(t.j)).transpose();
    const double rl = r.norm();
    const V3 dir = rl > 0.0 ? V3(r / rl) : V3::Zero();
    for (int k = 0; k < 3; ++k) all_dir[3 * static_cast<size_t>(e) + k] = dir(k);
    t.c_rho = options.stretch * w * kappa_(e);
    t.rest_len = rl;
    if (!(t.c_rho <= kMaxStiffness && t.c_sig <= kMaxStiffness)) {
      throw std::invalid_argument(
          "stretch, bend, edge_weight: their products exceed 1e300 (only their ratios matter: "
          "scale them down)");
    }
  }

  // Passive vertices: in no face, or in a part (through edges) without a constrained vertex.
  DisjointSets sets(n);
  std::vector<char> used(n, 0);
  for (int e = 0; e < E; ++e) {
    sets.unite(edges_(e, 0), edges_(e, 1));
    used[edges_(e, 0)] = used[edges_(e, 1)] = 1;
  }
  std::vector<char> root_fixed(n, 0);
  for (int v : constrained) root_fixed[sets.find(v)] = 1;
  std::vector<int> fixed_list(constrained.begin(), constrained.end());
  for (int v = 0; v < n; ++v) {
    if (!is_fixed[v] && (!used[v] || !root_fixed[sets.find(v)])) {
      is_fixed[v] = 1;
      fixed_list.push_back(v);
    }
  }
  // Anchors: the caller's groups, else the constrained vertices joined by mesh edges.
  {
    std::vector<int> of(constrained.size());
    int count_a = 0;
    if (!options.anchors.empty()) {
      if (options.anchors.size() != constrained.size()) {
        throw std::invalid_argument("anchors: expected one id per constrained vertex (" +
                                    std::to_string(constrained.size()) + "), got " +
                                    std::to_string(options.anchors.size()));
      }
      for (size_t c = 0; c < constrained.size(); ++c) {
        const int a = options.anchors[c];
        // bounded so that a (count,3) array of rotation vectors stays a sane size
        if (a < 0 || static_cast<size_t>(a) >= constrained.size()) {
          throw std::invalid_argument("anchors: id " + std::to_string(a) + " outside [0, " +
                                      std::to_string(constrained.size()) + ")");
        }
        of[c] = a;
        count_a = std::max(count_a, a + 1);
      }
    } else {
      DisjointSets anchors(n);
      std::vector<char> is_con(n, 0);
      for (int v : constrained) is_con[v] = 1;
      for (int e = 0; e < E; ++e) {
        const int a = edges_(e, 0), b = edges_(e, 1);
        if (is_con[a] && is_con[b]) anchors.unite(a, b);
      }
      std::vector<int> label(n, -1);
      for (size_t c = 0; c < constrained.size(); ++c) {
        int& l = label[anchors.find(constrained[c])];
        if (l < 0) l = count_a++;
        of[c] = l;
      }
    }
    std::vector<int> count(count_a, 0);
    for (int a : of) ++count[a];
    d.anchor_of = of;
    d.anchor_ptr.assign(count.size() + 1, 0);
    for (size_t g = 0; g < count.size(); ++g) d.anchor_ptr[g + 1] = d.anchor_ptr[g] + count[g];
    d.anchor_idx.resize(constrained.size());
    std::vector<int> fill(d.anchor_ptr.begin(), d.anchor_ptr.end() - 1);
    for (size_t c = 0; c < constrained.size(); ++c)
      d.anchor_idx[fill[of[c]]++] = static_cast<int>(c);
  }
  std::vector<int> free_index(n, -1), free_verts;
  for (int v = 0; v < n; ++v) {
    if (!is_fixed[v]) {
      free_index[v] = static_cast<int>(free_verts.size());
      free_verts.push_back(v);
    }
  }
  const int nf = d.nf = static_cast<int>(free_verts.size());
  d.nfix = static_cast<int>(fixed_list.size());
  std::vector<int> fixed_slot(n, -1);
  for (size_t s = 0; s < fixed_list.size(); ++s) fixed_slot[fixed_list[s]] = static_cast<int>(s);

  // Normal equations (the same matrix for x, y and z): sum_e c_e D_e^T D_e over the stretch
  // stencils (1, -1 on i, j) and the bend stencils (alpha, 1 - alpha, -beta, beta - 1).
  std::vector<Eigen::Triplet<double>> aff, afc;
  aff.reserve(static_cast<size_t>(20) * E);
  auto add_stencil = [&](const int* v, const double* c, int k, double weight) {
    for (int r = 0; r < k; ++r) {
      const int fr = free_index[v[r]];
      if (fr < 0) continue;
      for (int s = 0; s < k; ++s) {
        const double val = weight * c[r] * c[s];
        const int fs = free_index[v[s]];
        if (fs >= 0) {
          if (fs <= fr) aff.emplace_back(fr, fs, val);
        } else {
          afc.emplace_back(fr, fixed_slot[v[s]], val);
        }
      }
    }
  };
  for (const EdgeTerm& t : all) {
    const int rv[2] = {t.i, t.j};
    const double rc[2] = {1.0, -1.0};
    if (t.c_rho > 0.0) add_stencil(rv, rc, 2, t.c_rho);
    if (t.l >= 0) {
      const int sv[4] = {t.i, t.j, t.l, t.m};
      const double sc[4] = {t.alpha, 1.0 - t.alpha, -t.beta, t.beta - 1.0};
      add_stencil(sv, sc, 4, t.c_sig);
    }
  }
  Eigen::SparseMatrix<double> Aff(nf, nf);
  Aff.setFromTriplets(aff.begin(), aff.end());
  const char* singular =
      "the constraints do not determine every vertex (singular system): with stretch = 0 each "
      "flat part needs three constrained vertices that are not in a line";
  try {
    d.chol = std::make_unique<SparseCholesky>(Aff, SparseCholesky::Reuse::PerPose);
  } catch (const std::exception&) {
    // Aff is finite (checked above), so a failed factorisation means it is not positive
    // definite: some vertex is not determined (invalid_argument), or CHOLMOD gave up
    // (runtime_error).
    throw std::invalid_argument(singular);
  }
  if (nf > 0) ++factorizations_;

  // Slots: solver row order first, then fixed vertices (constrained in the caller's order).
  const std::vector<int>& perm = d.chol->permutation();  // row r is free vertex perm[r]
  std::vector<int> free_row(nf);
  for (int r = 0; r < nf; ++r) free_row[perm[r]] = r;
  d.slot.assign(n, -1);
  d.slot_vertex.assign(n, -1);
  for (int f = 0; f < nf; ++f) d.slot[free_verts[f]] = free_row[f];
  for (size_t s = 0; s < fixed_list.size(); ++s) d.slot[fixed_list[s]] = nf + static_cast<int>(s);
  for (int v = 0; v < n; ++v) d.slot_vertex[d.slot[v]] = v;

  // A nearly singular system is not always caught by the factorisation (rounding can leave a
  // tiny positive pivot): solve A x = A r for a fixed r and require x = r.
  if (nf > 0) {
    Eigen::MatrixXd R(nf, 3);
    for (int f = 0; f < nf; ++f)
      for (int k = 0; k < 3; ++k) R(f, k) = std::sin(1.0 + 0.7 * f + 2.1 * k);
    const Eigen::SparseMatrix<double> Afull = Aff.selfadjointView<Eigen::Lower>();
    const Eigen::MatrixXd B = Afull * R;
    std::vector<double> Y(4 * static_cast<size_t>(nf), 0.0);
    for (int f = 0; f < nf; ++f)
      for (int k = 0; k < 3; ++k) Y[4 * static_cast<size_t>(free_row[f]) + k] = B(f, k);
    d.chol->solve_permuted4(Y.data());
    double err = 0.0;
    for (int f = 0; f < nf; ++f)
      for (int k = 0; k < 3; ++k)
        err = std::max(err, std::abs(Y[4 * static_cast<size_t>(free_row[f]) + k] - R(f, k)));
    if (!(err < 1e-4)) throw std::invalid_argument(singular);
  }

  // Coupling to fixed vertices, by solver row.
  {
    Eigen::SparseMatrix<double, Eigen::RowMajor> Afc(nf, d.nfix);
    Afc.setFromTriplets(afc.begin(), afc.end());
    d.c_ptr.assign(nf + 1, 0);
    for (int r = 0; r < nf; ++r) {
      const int f = perm[r];
      d.c_ptr[r + 1] =
          d.c_ptr[r] + static_cast<int>(Afc.outerIndexPtr()[f + 1] - Afc.outerIndexPtr()[f]);
    }
    d.c_col.resize(d.c_ptr[nf]);
    d.c_val.resize(d.c_ptr[nf]);
    for (int r = 0; r < nf; ++r) {
      const int f = perm[r];
      int o = d.c_ptr[r];
      for (auto q = Afc.outerIndexPtr()[f]; q < Afc.outerIndexPtr()[f + 1]; ++q, ++o) {
        d.c_col[o] = Afc.innerIndexPtr()[q];
        d.c_val[o] = Afc.valuePtr()[q];
      }
    }
  }

  // Terms that reach a free vertex, in slot order of their first vertex (the estimation step
  // then walks the position buffer roughly in order), with vertices turned into slots.
  std::vector<int> keep;
  for (int e = 0; e < E; ++e) {
    const EdgeTerm& t = all[e];
    bool reaches = (t.c_rho > 0.0) && (!is_fixed[t.i] || !is_fixed[t.j]);
    if (t.l >= 0)
      reaches = reaches || !is_fixed[t.i] || !is_fixed[t.j] || !is_fixed[t.l] || !is_fixed[t.m];
    if (reaches) keep.push_back(e);
  }
  auto key = [&](int e) { return std::min(d.slot[all[e].i], d.slot[all[e].j]); };
  std::stable_sort(keep.begin(), keep.end(), [&](int a, int b) { return key(a) < key(b); });
  std::vector<EdgeTerm> terms(keep.size());
  for (size_t q = 0; q < keep.size(); ++q) {
    EdgeTerm t = all[keep[q]];
    t.i = d.slot[t.i];
    t.j = d.slot[t.j];
    if (t.l >= 0) {
      t.l = d.slot[t.l];
      t.m = d.slot[t.m];
    }
    terms[q] = t;
  }
  d.num_terms = static_cast<int>(terms.size());
  d.groups.assign((terms.size() + 3) / 4, EdgeGroup{});
  for (size_t q = 0; q < terms.size(); ++q) {
    EdgeGroup& g = d.groups[q / 4];
    const size_t k = q % 4;
    const EdgeTerm& t = terms[q];
    g.i[k] = t.i;
    g.j[k] = t.j;
    g.l[k] = t.l >= 0 ? t.l : t.i;
    g.m[k] = t.l >= 0 ? t.m : t.i;
    g.rest_len[k] = t.rest_len;
    g.c_rho[k] = t.c_rho;
    g.alpha[k] = t.alpha;
    g.beta[k] = t.beta;
    g.c_sig[k] = t.c_sig;
    g.s_l[k] = t.s_l;
    g.s_n[k] = t.s_n;
    g.s_b[k] = t.s_b;
    for (int c = 0; c < 3; ++c) g.r0[c][k] = all_dir[3 * static_cast<size_t>(keep[q]) + c];
  }

  const size_t rows = static_cast<size_t>(nf) + d.nfix;
  d.P0.assign(4 * rows, 0.0);
  d.P1.assign(4 * rows, 0.0);
  d.b0.assign(4 * static_cast<size_t>(nf), 0.0);
}

EdgeDeformer::~EdgeDeformer() = default;

int EdgeDeformer::num_free() const { return impl_->nf; }

int EdgeDeformer::num_anchors() const { return static_cast<int>(impl_->anchor_ptr.size()) - 1; }

const std::vector<int>& EdgeDeformer::anchors() const { return impl_->anchor_of; }

long long EdgeDeformer::process_factorizations() { return SparseCholesky::factorizations(); }

// Rotation vectors of solve(): one finite row per anchor, each a log of the rotation fitted to
// its anchor from rest to the constrained positions (where there is a fit), and the rest mesh
// as the start.
void EdgeDeformer::check_rotation_vectors(const Vertices& constrained_positions,
                                          const Vertices* initial, const Vectors3& v) const {
  const Impl& d = *impl_;
  const int na = num_anchors();
  if (v.rows() != na || v.cols() != 3) {
    throw std::invalid_argument("rotation_vectors: expected shape (" + std::to_string(na) +
                                ",3), one per anchor, got (" + std::to_string(v.rows()) + "," +
                                std::to_string(v.cols()) + ")");
  }
  if (initial) {
    throw std::invalid_argument(
        "rotation_vectors: the start is then the rest mesh carried by them; initial must be "
        "None");
  }
  const auto rest = [&](int c) { return V3(d.rest.row(d.slot_vertex[d.nf + c]).transpose()); };
  const auto target = [&](int c) { return V3(constrained_positions.row(c).transpose()); };
  for (int a = 0; a < na; ++a) {
    const V3 va = v.row(a).transpose();
    const std::string name = "rotation_vectors[" + std::to_string(a) + "]";
    if (!va.allFinite()) throw std::invalid_argument(name + ": contains NaN or infinity");
    Eigen::Matrix3d R;
    if (!fit_anchor(d.anchor_ptr, d.anchor_idx, a, rest, target, &R)) continue;
    const double err = rotation_vector_mismatch(va, R);
    if (!(err <= kRotationVectorTolerance)) {
      std::ostringstream msg;
      msg << name << ": its exp differs from the rotation fitted to anchor " << a
          << " (rest -> constrained_positions) by " << err << " rad (tolerance "
          << kRotationVectorTolerance
          << "); expected a log of that rotation, i.e. its principal log plus whole turns "
             "about the same axis";
      if (std::isnan(err)) msg << " (this vector, " << va.norm() << " rad, is too long)";
      throw std::invalid_argument(msg.str());
    }
  }
}

Vertices EdgeDeformer::solve(const Vertices& constrained_positions, const EdgeSolveOptions& options,
                             const Vertices* initial, const Vectors3* rotation_vectors) {
  Impl& d = *impl_;
  if (constrained_positions.rows() != d.nc) {
    throw std::invalid_argument("constrained_positions: expected shape (" + std::to_string(d.nc) +
                                ",3)");
  }
  if (!constrained_positions.allFinite()) {
    throw std::invalid_argument("constrained_positions: contains NaN or infinity");
  }
  if (initial && (initial->rows() != d.n || !initial->allFinite())) {
    throw std::invalid_argument("initial: expected finite values of shape (" + std::to_string(d.n) +
                                ",3)");
  }
  if (options.iterations < 1) throw std::invalid_argument("iterations: expected >= 1");
  if (!std::isfinite(options.tol) || options.tol < 0.0) {
    throw std::invalid_argument("tol: expected a finite value >= 0");
  }
  if (!(options.p_stretch >= 0.0 && options.p_stretch <= 1.0)) {
    throw std::invalid_argument("p_stretch: expected a value in [0, 1]");
  }
  if (!(options.p_bend >= 0.0 && options.p_bend <= 1.0)) {
    throw std::invalid_argument("p_bend: expected a value in [0, 1]");
  }
  if (!(options.relaxation > 0.0 && options.relaxation <= 1.0)) {
    throw std::invalid_argument("relaxation: expected a value in (0, 1]");
  }
  if (!options.gravity.allFinite())
    throw std::invalid_argument("gravity: contains NaN or infinity");
  const char* far =
      " lies beyond 1e50 mesh sizes of the rest mesh: rescale the mesh (only its "
      "shape matters)";
  if (!(d.reach(constrained_positions, diag_) <= kMaxReach)) {
    throw std::invalid_argument(std::string("constrained_positions:") + far);
  }
  if (initial && !(d.reach(*initial, diag_) <= kMaxReach)) {
    throw std::invalid_argument(std::string("initial:") + far);
  }

  if (rotation_vectors) check_rotation_vectors(constrained_positions, initial, *rotation_vectors);

  const std::lock_guard<std::mutex> lock(d.busy);
  const ParkWorkersOnExit park;
  const int nf = d.nf;
  const Vertices& X0 = initial ? *initial : d.rest;
  Vec4d* cur = reinterpret_cast<Vec4d*>(d.P0.data());
  Vec4d* next = reinterpret_cast<Vec4d*>(d.P1.data());
  Vec4d* b0 = reinterpret_cast<Vec4d*>(d.b0.data());
  for (int v = 0; v < d.n; ++v) {
    cur[d.slot[v]] = Vec4d{X0(v, 0), X0(v, 1), X0(v, 2), 0.0};
  }
  // In the first iteration constrained vertices jump to their targets and passive ones (parts
  // without a constrained vertex, loose vertices) to rest, where they stay bit for bit.
  double move0 = 0.0;
  for (int c = 0; c < d.nc; ++c) {
    const Vec4d p = {constrained_positions(c, 0), constrained_positions(c, 1),
                     constrained_positions(c, 2), 0.0};
    next[nf + c] = p;
    const Vec4d dv = p - cur[nf + c];
    move0 = std::max(move0, dot3(dv, dv));
  }
  const bool anchors_moved = move0 > 0.0;
  for (int s = nf + d.nc; s < nf + d.nfix; ++s) {
    const int v = d.slot_vertex[s];
    const Vec4d r = {d.rest(v, 0), d.rest(v, 1), d.rest(v, 2), 0.0};
    const Vec4d dv = r - cur[s];
    move0 = std::max(move0, dot3(dv, dv));
    cur[s] = next[s] = r;
  }

  // Constant part of the right-hand side: -A_fc x_fixed + g/2 (Eq. 9 with E_g = -sum <g, v>).
  const Vec4d g2 = {0.5 * options.gravity(0), 0.5 * options.gravity(1), 0.5 * options.gravity(2),
                    0.0};
  for (int r = 0; r < nf; ++r) {
    Vec4d b = g2;
    for (int q = d.c_ptr[r]; q < d.c_ptr[r + 1]; ++q) b -= d.c_val[q] * next[nf + d.c_col[q]];
    b[3] = 0.0;
    b0[r] = b;
  }

  // The first estimation step takes its edge frames from the start V^0, which knows nothing of
  // the anchors' turn; its measure step, being linear, can only shear a turn into the mesh, and
  // past ~90 degrees that sends parts through each other (a tube's rings through its axis, a
  // half turn the wrong way that no later iteration undoes). So when the anchors turn, the
  // first estimation step also turns each edge's rest quantities by the anchors' rotations
  // spread over the mesh (Impl::carry_rotations).
  // Given rotation vectors are the turns from rest: carried whatever the positions show (a
  // whole turn puts every anchor back where it was).
  const bool carried = rotation_vectors ? d.carry_rotations(cur, next, rotation_vectors)
                                        : anchors_moved && d.carry_rotations(cur, next, nullptr);
  const bool avx2 = cpu_has_avx2_fma();
  const int ng = static_cast<int>(d.groups.size());
  // Parallel parts of the estimation step, each scattering into its own accumulator. Below
  // ~8k edges per part the split costs more than it saves.
  constexpr int kMinGroups = 2048, kMaxParts = 8;
  const int parts = std::max(1, std::min({num_threads(), ng / kMinGroups, kMaxParts}));
  const size_t rows = static_cast<size_t>(nf) + d.nfix;
  if (static_cast<int>(d.acc.size()) < parts) d.acc.resize(parts);
  for (int p = 0; p < parts; ++p) d.acc[p].resize(4 * rows);
  d.part_move.assign(static_cast<size_t>(parts), 0.0);
  Vec4d* Y = reinterpret_cast<Vec4d*>(d.acc[0].data());
  const double stop = options.tol * diag_;
  int it = 0;
  double move = 0.0;
  // The iteration converges linearly, often slowly (a tube twisted by a few degrees at stretch
  // 1: each move 0.99 of the last), and then the distance left is about move rho / (1 - rho),
  // a hundred moves: a small last move alone stopped 28 % short of that twist. rho: the largest
  // ratio of successive moves over the last kRateWindow iterations (after the first, whose move
  // includes the anchors' jump), so a momentary fast step does not pass for the rate.
  constexpr int kRateWindow = 4;
  double ratios[kRateWindow] = {};
  int num_ratios = 0;
  double previous = 0.0, error = 0.0;
  bool converged = false;
  while (it < options.iterations) {
    const bool carry = carried && it == 0;
    const EstimateArgs ea{d.groups.data(), cur, options.p_stretch, options.p_bend,
                          carry ? reinterpret_cast<const Vec4d*>(d.carry.data()) : nullptr};
    run_tasks(parts, [&](int p) {
      Vec4d* acc = reinterpret_cast<Vec4d*>(d.acc[p].data());
      if (p == 0) {
        std::copy(d.b0.begin(), d.b0.end(), d.acc[0].begin());
      } else {
        std::fill(d.acc[p].begin(), d.acc[p].begin() + 4 * static_cast<size_t>(nf), 0.0);
      }
      const int b = static_cast<int>(static_cast<int64_t>(ng) * p / parts);
      const int e = static_cast<int>(static_cast<int64_t>(ng) * (p + 1) / parts);
      if (carry) {
        (avx2 ? estimate_carry_avx2 : estimate_carry_base)(ea, b, e, acc);
      } else {
        (avx2 ? estimate_avx2 : estimate_base)(ea, b, e, acc);
      }
    });
    if (parts > 1) {
      parallel_ranges(nf, 4096, 8, [&](int b, int e) {
        for (int p = 1; p < parts; ++p) {
          const Vec4d* acc = reinterpret_cast<const Vec4d*>(d.acc[p].data());
          for (int r = b; r < e; ++r) Y[r] += acc[r];
        }
      });
    }
    d.chol->solve_permuted4(reinterpret_cast<double*>(Y));
    // The move and the next iterate, in the estimation step's parts (a serial loop over 30k
    // rows left the second thread idle for ~3 % of an iteration).
    // A carried first step is the start, taken in full: relaxation damps the iteration's
    // two-cycles, and blending this step with V^0 would shear the turn back in.
    const double w = carry ? 1.0 : options.relaxation;
    run_tasks(parts, [&](int p) {
      const int b = static_cast<int>(static_cast<int64_t>(nf) * p / parts);
      const int e = static_cast<int>(static_cast<int64_t>(nf) * (p + 1) / parts);
      double mp = 0.0;
      for (int r = b; r < e; ++r) {
        const Vec4d dv = Y[r] - cur[r];
        mp = std::max(mp, dot3(dv, dv));
        next[r] = w == 1.0 ? Y[r] : cur[r] + w * dv;
      }
      d.part_move[p] = mp;
    });
    double m2 = 0.0;
    for (int p = 0; p < parts; ++p) m2 = std::max(m2, d.part_move[p]);
    move = std::sqrt(std::max(w * w * m2, it == 0 ? move0 : 0.0));
    if (it == 0) {
      // From now on both buffers hold the constrained positions.
      for (int c = 0; c < d.nc; ++c) cur[nf + c] = next[nf + c];
    }
    std::swap(cur, next);
    ++it;
    if (it >= 3 && previous > 0.0) ratios[num_ratios++ % kRateWindow] = move / previous;
    previous = move;
    error = std::numeric_limits<double>::infinity();  // unknown until the rate is
    if (move <= kRoundOff * diag_) {
      error = move;  // a fixed point to round-off
    } else if (num_ratios >= kRateWindow) {
      const double rho = *std::max_element(ratios, ratios + kRateWindow);
      if (rho < 1.0) error = move * rho / (1.0 - rho);
    }
    if (stop > 0.0 && error <= stop) {
      converged = true;
      break;
    }
  }
  Vertices out(d.n, 3);
  for (int v = 0; v < d.n; ++v) {
    const Vec4d& p = cur[d.slot[v]];
    out.row(v) << p[0], p[1], p[2];
  }
  // E.g. gravity far too strong for the stiffness: refused, and the call changes nothing.
  if (!(std::isfinite(move) && d.reach(out, diag_) <= kMaxReach)) {
    throw std::runtime_error(
        "the iteration left the range the solver represents (1e50 mesh sizes around the rest "
        "mesh): rescale the mesh, or weaken gravity");
  }
  last_iterations_ = it;
  last_move_ = move / diag_;
  last_error_ = error / diag_;
  last_converged_ = converged;
  return out;
}

}  // namespace matdeform
