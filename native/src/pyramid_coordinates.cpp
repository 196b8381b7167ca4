// The pyramid description (angles and lengths of every vertex relative to its one-ring) and the
// paper's reconstruction from it (Eq. 1-2).
#include <Eigen/Geometry>
#include <cmath>
#include <vector>

#include "matdeform/mesh.hpp"
#include "matdeform/transforms.hpp"
#include "pyramid_internal.hpp"

namespace matdeform {

namespace {

using pyramid::row;
using pyramid::Vec3;

// Relative thresholds below which a fan counts as degenerate (its vertex becomes a follower).
constexpr double kAreaEps = 1e-10;      // |polygon vector area| against sum |x_i - c|^2
constexpr double kLengthEps = 1e-8;     // l_i against the mean |x_i - c|
constexpr double kReproduceEps = 1e-9;  // |sum w_i v'_i - v'| against the mean |x_i - c|
constexpr double kPi = 3.14159265358979323846;

// Newell normal (twice the vector area) of the neighbour polygon x_1..x_m about their mean c;
// the last edge closes the polygon. For a closed fan it is the sum of the fan's face area vectors
// whatever the position of the vertex itself, so it is the usual area-weighted vertex normal.
inline Vec3 newell(const double* X, const int* ring, int m, const Vec3& c) {
  Vec3 N = Vec3::Zero();
  Vec3 a = row(X, ring[m - 1]) - c;
  for (int i = 0; i < m; ++i) {
    const Vec3 b = row(X, ring[i]) - c;
    N += a.cross(b);
    a = b;
  }
  return N;
}

inline Vec3 centroid(const double* X, const int* ring, int m) {
  Vec3 c = Vec3::Zero();
  for (int i = 0; i < m; ++i) c += row(X, ring[i]);
  return c / m;
}

// Describes vertex v from its ring (rest positions X). Returns false when the fan is degenerate.
bool describe(const double* X, int v, const int* ring, int m, bool open, double* alpha,
              double* beta, double* length, double* weight, Vec3* normal, double* offset,
              double* height) {
  if (m < 3) return false;
  const Vec3 c = centroid(X, ring, m);
  double spread = 0, spread2 = 0;
  for (int i = 0; i < m; ++i) {
    const double r = (row(X, ring[i]) - c).norm();
    spread += r / m;
    spread2 += r * r;
  }
  const Vec3 N = newell(X, ring, m, c);
  if (!(N.norm() > kAreaEps * spread2)) return false;
  const Vec3 n = N.normalized();
  const Vec3 dv = row(X, v) - c;
  const double H = n.dot(dv);
  const Vec3 p = dv - H * n;  // v' relative to c
  std::vector<Vec3> e(static_cast<size_t>(m));
  std::vector<double> t(static_cast<size_t>(m));
  for (int i = 0; i < m; ++i) {
    const Vec3 d = row(X, ring[i]) - c;
    t[i] = n.dot(d);
    e[i] = d - t[i] * n - p;  // v'_i - v'
    length[i] = e[i].norm();
    if (!(length[i] > kLengthEps * spread)) return false;
  }
  for (int i = 0; i < m; ++i) {
    const Vec3& a = e[i];
    const Vec3& b = e[(i + 1) % m];
    alpha[i] = std::atan2(n.dot(a.cross(b)), a.dot(b));
    beta[i] = std::atan2(length[i], H - t[i]);
  }
  // The projected fan must not fold: every face's angle at v' in (0, pi), so that v' sees the
  // whole neighbour polygon (its kernel) and the weights below are positive. Folded fans make
  // the local placement unstable (weights of both signs, above 1), see docs/pyramid.md.
  double turn = 0;
  for (int i = 0; i < (open ? m - 1 : m); ++i) {
    if (!(alpha[i] > 0 && alpha[i] < kPi)) return false;
    turn += alpha[i];
  }
  if (!open && std::abs(turn - 2 * kPi) > 1e-6) return false;
  // Mean value weights w_i = (tan(alpha_{i-1}/2) + tan(alpha_i/2)) / l_i (Floater 2003), with
  // signed angles so that they reproduce v' for any polygon (Hormann & Floater 2006). Multiplied
  // by prod_j cos(alpha_j/2) >= 0 they read sin((alpha_{i-1}+alpha_i)/2) prod_{j != i-1,i}
  // cos(alpha_j/2) / l_i, which stays finite when v' lies on an edge (alpha = pi): an open fan's
  // closing edge on a straight boundary.
  double sum = 0, sum_abs = 0;
  for (int i = 0; i < m; ++i) {
    const int prev = (i + m - 1) % m;
    double w = std::sin(0.5 * (alpha[prev] + alpha[i]));
    for (int j = 0; j < m; ++j)
      if (j != prev && j != i) w *= std::cos(0.5 * alpha[j]);
    weight[i] = w / length[i];
    sum += weight[i];
    sum_abs += std::abs(weight[i]);
  }
  if (!(std::abs(sum) > 1e-9 * sum_abs)) return false;
  Vec3 rep = Vec3::Zero();
  for (int i = 0; i < m; ++i) {
    weight[i] /= sum;
    rep += weight[i] * e[i];
  }
  if (!(rep.norm() <= kReproduceEps * spread)) return false;
  *normal = n;
  *offset = -n.dot(c);
  *height = H;
  return true;
}

}  // namespace

PyramidCoordinates pyramid_coordinates(const Vertices& vertices, const Faces& faces) {
  validate_mesh(vertices, faces);
  const int n = static_cast<int>(vertices.rows());
  const VertexFans fans = vertex_fans(n, faces);
  PyramidCoordinates pc;
  pc.offsets = fans.offsets;
  pc.neighbors = fans.ring;
  const size_t slots = fans.ring.size();
  pc.alpha.assign(slots, 0.0);
  pc.beta.assign(slots, 0.0);
  pc.length.assign(slots, 0.0);
  pc.weight.assign(slots, 0.0);
  pc.normal = Vertices::Zero(n, 3);
  pc.offset = Eigen::VectorXd::Zero(n);
  pc.height = Eigen::VectorXd::Zero(n);
  pc.kind.assign(static_cast<size_t>(n), kPyramidIsolated);
  const double* X = vertices.data();
  for (int v = 0; v < n; ++v) {
    const signed char fk = fans.kind[static_cast<size_t>(v)];
    if (fk == kFanIsolated) continue;
    const int o = pc.offsets[static_cast<size_t>(v)];
    const int m = pc.offsets[static_cast<size_t>(v) + 1] - o;
    Vec3 nv;
    bool ok = false;
    if (fk == kFanClosed || fk == kFanOpen) {
      ok = describe(X, v, pc.neighbors.data() + o, m, fk == kFanOpen, pc.alpha.data() + o,
                    pc.beta.data() + o, pc.length.data() + o, pc.weight.data() + o, &nv,
                    &pc.offset(v), &pc.height(v));
    }
    if (ok) {
      pc.kind[static_cast<size_t>(v)] = fk == kFanClosed ? kPyramidInterior : kPyramidBoundary;
      pc.normal.row(v) = nv.transpose();
    } else {
      pc.kind[static_cast<size_t>(v)] = kPyramidFollower;
      for (int s = o; s < o + m; ++s) pc.alpha[s] = pc.beta[s] = pc.length[s] = pc.weight[s] = 0;
      pc.offset(v) = pc.height(v) = 0;
    }
  }
  return pc;
}

namespace pyramid {

Placement::Placement(const Vertices& vertices, const Faces& faces) : rest(vertices) {
  coords = pyramid_coordinates(vertices, faces);
  const int n = static_cast<int>(vertices.rows());
  const auto& off = coords.offsets;
  const auto& nb = coords.neighbors;
  cot_beta.assign(nb.size(), 0.0);
  weight_per_len.assign(nb.size(), 0.0);
  for (int v = 0; v < n; ++v) {
    if (coords.kind[static_cast<size_t>(v)] > kPyramidBoundary) continue;
    // cot(beta_i) straight from the heights (1 / tan(beta) loses digits near pi/2).
    const Vec3 nv = coords.normal.row(v).transpose();
    const Vec3 c = centroid(rest.data(), nb.data() + off[v], off[v + 1] - off[v]);
    for (int s = off[v]; s < off[v + 1]; ++s) {
      const double t = nv.dot(rest.row(nb[s]).transpose() - c);
      cot_beta[s] = (coords.height(v) - t) / coords.length[s];
      weight_per_len[s] = coords.weight[s] / coords.length[s];
    }
  }
}

Vec3 Placement::follow(int v, const double* X) const {
  // Best-fit similarity (Kabsch with scale) of v and its neighbours, rest -> current.
  const int o = coords.offsets[static_cast<size_t>(v)];
  const int m = coords.offsets[static_cast<size_t>(v) + 1] - o;
  const int* ring = coords.neighbors.data() + o;
  if (m == 0) return row(X, v);
  const double* R0 = rest.data();
  Vec3 c = row(X, v), c0 = row(R0, v);
  for (int i = 0; i < m; ++i) {
    c += row(X, ring[i]);
    c0 += row(R0, ring[i]);
  }
  c /= m + 1;
  c0 /= m + 1;
  Eigen::Matrix3d Hm = (row(X, v) - c) * (row(R0, v) - c0).transpose();
  double s0 = (row(R0, v) - c0).squaredNorm();
  for (int i = 0; i < m; ++i) {
    const Vec3 a0 = row(R0, ring[i]) - c0;
    Hm += (row(X, ring[i]) - c) * a0.transpose();
    s0 += a0.squaredNorm();
  }
  if (!(s0 > 0) || !Hm.allFinite()) return c;
  Eigen::Matrix3d R;
  double trace = 0;
  best_rotation(Hm, &R, &trace);
  return c + (trace / s0) * (R * (row(R0, v) - c0));
}

Vec3 Placement::place(int v, const double* X, bool stretch) const {
  const signed char kind = coords.kind[static_cast<size_t>(v)];
  if (kind == kPyramidIsolated) return row(X, v);
  if (kind == kPyramidFollower) return follow(v, X);
  const int o = coords.offsets[static_cast<size_t>(v)];
  const int m = coords.offsets[static_cast<size_t>(v) + 1] - o;
  const int* ring = coords.neighbors.data() + o;
  // The neighbours relative to their mean c, gathered once.
  constexpr int kStack = 24;
  Vec3 stack[kStack];
  std::vector<Vec3> heap;
  Vec3* d = stack;
  if (m > kStack) {
    heap.resize(static_cast<size_t>(m));
    d = heap.data();
  }
  Vec3 c = Vec3::Zero();
  for (int i = 0; i < m; ++i) {
    d[i] = row(X, ring[i]);
    c += d[i];
  }
  c /= m;
  double spread2 = 0;
  for (int i = 0; i < m; ++i) {
    d[i] -= c;
    spread2 += d[i].squaredNorm();
  }
  Vec3 N = d[m - 1].cross(d[0]);
  for (int i = 1; i < m; ++i) N += d[i - 1].cross(d[i]);
  const double nn = N.norm();
  // The current neighbours have collapsed onto a line or a point: no plane, follow instead.
  if (!(nn > kAreaEps * spread2)) return follow(v, X);
  const Vec3 n = N / nn;
  for (int i = 0; i < m; ++i) d[i] -= n.dot(d[i]) * n;  // v'_i - c on the plane P through c
  // Eq. 1: v' = sum w_i v'_i.
  Vec3 vp = Vec3::Zero();
  bool done = false;
  if (stretch) {
    // w_i |v' - v'_i| / l_i with v' the projection of the current v.
    Vec3 p = row(X, v) - c;
    p -= n.dot(p) * n;
    const double* wl = weight_per_len.data() + o;
    double wsum = 0;
    for (int i = 0; i < m; ++i) {
      const double wi = wl[i] * (p - d[i]).norm();
      vp += wi * d[i];
      wsum += wi;
    }
    // Unless v' sits on every v'_i at once (then there is nothing to scale by).
    if (wsum > 1e-300 && vp.allFinite()) {
      vp /= wsum;
      done = true;
    }
  }
  if (!done) {
    const double* w = coords.weight.data() + o;
    vp.setZero();
    for (int i = 0; i < m; ++i) vp += w[i] * d[i];
  }
  // Eq. 2: v = v' + n mean(h_i), h_i = |v' - v'_i| cot(beta_i) + (v_i - v'_i).n; the second
  // terms are the neighbours' heights above P, which average to zero about their mean c.
  const double* cb = cot_beta.data() + o;
  double h = 0;
  for (int i = 0; i < m; ++i) h += (vp - d[i]).norm() * cb[i];
  return c + vp + (h / m) * n;
}

}  // namespace pyramid

}  // namespace matdeform
