#include "matdeform/pyramid_deformer.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {

using Vec3 = Eigen::Vector3d;

inline Vec3 row(const double* X, int v) { return Vec3(X[3 * v], X[3 * v + 1], X[3 * v + 2]); }

// Relative thresholds below which a fan counts as degenerate (its vertex becomes a follower).
constexpr double kAreaEps = 1e-10;   // |polygon vector area| against sum |x_i - c|^2
constexpr double kLengthEps = 1e-8;  // l_i against the mean |x_i - c|
constexpr double kReproduceEps = 1e-9;
constexpr double kPi = 3.14159265358979323846;  // |sum w_i v'_i - v'| against the mean |x_i - c|

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

namespace {

// Chunks per thread of the parallel loops: small enough for the claims to balance a late worker.
int chunks() { return 4 * num_threads(); }
constexpr int kMinChunk = 256;

// Largest |a_v - b_v| over the listed vertices, in parallel.
double max_move(const Vertices& A, const Vertices& B, const std::vector<int>& verts) {
  const int n = static_cast<int>(verts.size());
  const int parts = std::max(1, std::min(chunks(), n / kMinChunk));
  std::vector<double> part(static_cast<size_t>(parts), 0.0);
  run_tasks(parts, [&](int p) {
    const int b = static_cast<int>(static_cast<int64_t>(n) * p / parts);
    const int e = static_cast<int>(static_cast<int64_t>(n) * (p + 1) / parts);
    double mx = 0;
    for (int r = b; r < e; ++r) {
      const int v = verts[static_cast<size_t>(r)];
      const double d = (A.row(v) - B.row(v)).squaredNorm();
      // NaN must not hide behind max(): it propagates as infinity
      mx = std::isnan(d) ? std::numeric_limits<double>::infinity() : std::max(mx, d);
    }
    part[static_cast<size_t>(p)] = mx;
  });
  double mx = 0;
  for (double x : part) mx = std::max(mx, x);
  return std::sqrt(mx);
}

}  // namespace

// One resolution of the mesh with everything a sweep needs.
struct PyramidLevel {
  Vertices rest;
  PyramidCoordinates coords;
  std::vector<double> cot_beta;          // per slot
  std::vector<double> weight_per_len;    // per slot: w_i / l_i, for the stretch factor
  std::vector<int> free;                 // vertices placed in step 1
  std::vector<std::vector<int>> colors;  // free split into independent sets
  std::vector<int> pushers;              // controls with a description next to a free vertex
  std::vector<int> pushed, pushed_offsets, pushed_by;  // CSR: free vertex <- pushers rows
  std::vector<int> push_row;                           // vertex -> row in pushed, or -1
  int num_passive = 0;
  // Towards the next coarser level: coarse[v] is v's index there, or -1 when v was removed;
  // removed vertices are never neighbours of each other, so each is placed from kept ones.
  std::vector<int> coarse;
  std::vector<int> removed;

  PyramidLevel(const Vertices& vertices, const Faces& faces, const std::vector<char>& is_control);
  Vec3 follow(int v, const double* X) const;
  Vec3 place(int v, const double* X, bool stretch) const;
  // Step 2 from positions x: per pusher its shift, per pushed vertex the mean of its pushers'.
  void shifts(const double* x, std::vector<Vec3>* shift, std::vector<Vec3>* pushes) const;
  // to_v = place(v, from) + push_v + tau_v for v in verts.
  void apply(const std::vector<int>& verts, const double* from, double* to, const Vertices* tau,
             const PyramidSolveOptions& o, const std::vector<Vec3>& pushes) const;
  // One sweep over the free vertices (Gauss-Seidel by colours, or Jacobi), tau optional.
  void sweep(Vertices* X, const Vertices* tau, const PyramidSolveOptions& o) const;
  // Y_v = the placement of v from X (a Jacobi step) for v in verts; other rows untouched.
  void jacobi(const std::vector<int>& verts, const Vertices& X, const Vertices* tau,
              const PyramidSolveOptions& o, Vertices* Y) const;
  // Sweeps (Anderson-accelerated) until the largest sweep move < limit or max_iterations.
  // Returns the sweeps done; *move is the last sweep's largest move (absolute).
  int iterate(Vertices* X, const Vertices* tau, const PyramidSolveOptions& o, int max_iterations,
              double limit, double* move, std::vector<double>* moves, double diag) const;
};

PyramidLevel::PyramidLevel(const Vertices& vertices, const Faces& faces,
                           const std::vector<char>& is_control)
    : rest(vertices) {
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
  // Free vertices: reached from a control through edges, not controls, not isolated.
  std::vector<char> reached(static_cast<size_t>(n), 0);
  std::vector<int> queue;
  for (int v = 0; v < n; ++v)
    if (is_control[static_cast<size_t>(v)]) reached[static_cast<size_t>(v)] = 1, queue.push_back(v);
  for (size_t q = 0; q < queue.size(); ++q) {
    const int v = queue[q];
    for (int s = off[v]; s < off[v + 1]; ++s) {
      if (!reached[static_cast<size_t>(nb[s])]) {
        reached[static_cast<size_t>(nb[s])] = 1;
        queue.push_back(nb[s]);
      }
    }
  }
  std::vector<char> is_free(static_cast<size_t>(n), 0);
  for (int v = 0; v < n; ++v) {
    if (is_control[static_cast<size_t>(v)]) continue;
    if (reached[static_cast<size_t>(v)] &&
        coords.kind[static_cast<size_t>(v)] != kPyramidIsolated) {
      is_free[static_cast<size_t>(v)] = 1;
      free.push_back(v);
    } else {
      ++num_passive;
    }
  }
  // Greedy colouring: same-coloured vertices are never neighbours, so each colour is placed in
  // parallel and later colours see the new positions (Gauss-Seidel).
  std::vector<int> color(static_cast<size_t>(n), -1);
  std::vector<char> mark;
  for (int v : free) {
    std::fill(mark.begin(), mark.end(), 0);
    for (int s = off[v]; s < off[v + 1]; ++s) {
      const int c = color[static_cast<size_t>(nb[s])];
      if (c >= 0) {
        if (static_cast<size_t>(c) >= mark.size()) mark.resize(static_cast<size_t>(c) + 1, 0);
        mark[static_cast<size_t>(c)] = 1;
      }
    }
    size_t c = 0;
    while (c < mark.size() && mark[c]) ++c;
    color[static_cast<size_t>(v)] = static_cast<int>(c);
    if (c >= colors.size()) colors.resize(c + 1);
    colors[c].push_back(v);
  }
  // Step 2: controls with a description push their free neighbours.
  std::vector<std::vector<int>> by(static_cast<size_t>(n));
  for (int c = 0; c < n; ++c) {
    if (!is_control[static_cast<size_t>(c)] ||
        coords.kind[static_cast<size_t>(c)] > kPyramidBoundary)
      continue;
    bool any = false;
    for (int s = off[c]; s < off[c + 1]; ++s) {
      if (is_free[static_cast<size_t>(nb[s])]) {
        by[static_cast<size_t>(nb[s])].push_back(static_cast<int>(pushers.size()));
        any = true;
      }
    }
    if (any) pushers.push_back(c);
  }
  pushed_offsets.push_back(0);
  push_row.assign(static_cast<size_t>(n), -1);
  for (int v : free) {
    if (by[static_cast<size_t>(v)].empty()) continue;
    push_row[static_cast<size_t>(v)] = static_cast<int>(pushed.size());
    pushed.push_back(v);
    pushed_by.insert(pushed_by.end(), by[static_cast<size_t>(v)].begin(),
                     by[static_cast<size_t>(v)].end());
    pushed_offsets.push_back(static_cast<int>(pushed_by.size()));
  }
}

Vec3 PyramidLevel::follow(int v, const double* X) const {
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
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(Hm, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Vector3d sig = svd.singularValues();
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) {
    D(2, 2) = -1;
    sig(2) = -sig(2);
  }
  const Eigen::Matrix3d R = svd.matrixU() * D * svd.matrixV().transpose();
  return c + (sig.sum() / s0) * (R * (row(R0, v) - c0));
}

Vec3 PyramidLevel::place(int v, const double* X, bool stretch) const {
  const signed char kind = coords.kind[static_cast<size_t>(v)];
  if (kind == kPyramidIsolated) return row(X, v);
  if (kind == kPyramidFollower) return follow(v, X);
  const int o = coords.offsets[static_cast<size_t>(v)];
  const int m = coords.offsets[static_cast<size_t>(v) + 1] - o;
  const int* ring = coords.neighbors.data() + o;
  const Vec3 c = centroid(X, ring, m);
  const Vec3 N = newell(X, ring, m, c);
  const double nn = N.norm();
  double spread2 = 0;
  for (int i = 0; i < m; ++i) spread2 += (row(X, ring[i]) - c).squaredNorm();
  // The current neighbours have collapsed onto a line or a point: no plane, follow instead.
  if (!(nn > kAreaEps * spread2)) return follow(v, X);
  const Vec3 n = N / nn;
  // Eq. 1: v' = sum w_i v'_i, relative to c on the plane P through c.
  const double* w = coords.weight.data() + o;
  Vec3 vp = Vec3::Zero();
  double wsum = 1.0;
  if (stretch) {
    // w_i |v' - v'_i| / l_i with v' the projection of the current v.
    Vec3 p = row(X, v) - c;
    p -= n.dot(p) * n;
    const double* wl = weight_per_len.data() + o;
    wsum = 0;
    for (int i = 0; i < m; ++i) {
      Vec3 q = row(X, ring[i]) - c;
      q -= n.dot(q) * n;
      const double wi = wl[i] * (p - q).norm();
      vp += wi * q;
      wsum += wi;
    }
    if (!(wsum > 1e-300) || !vp.allFinite()) {  // v' on every v'_i at once: no stretch
      vp.setZero();
      wsum = 1.0;
      stretch = false;
    }
  }
  if (!stretch) {
    for (int i = 0; i < m; ++i) {
      Vec3 q = row(X, ring[i]) - c;
      q -= n.dot(q) * n;
      vp += w[i] * q;
    }
  }
  vp /= wsum;
  // Eq. 2: v = v' + n mean(h_i), h_i = |v' - v'_i| cot(beta_i) + (v_i - v'_i).n; the second
  // terms are the neighbours' heights above P, which average to zero about their mean c.
  const double* cb = cot_beta.data() + o;
  double h = 0;
  for (int i = 0; i < m; ++i) {
    Vec3 q = row(X, ring[i]) - c;
    q -= n.dot(q) * n;
    h += (vp - q).norm() * cb[i];
  }
  return c + vp + (h / m) * n;
}

void PyramidLevel::shifts(const double* x, std::vector<Vec3>* shift,
                          std::vector<Vec3>* pushes) const {
  // Per control: the shift of its neighbours along n that would put the control at the mean
  // height mean(h_i) its description predicts above their plane (paper step 2).
  const auto& off = coords.offsets;
  shift->resize(pushers.size());
  parallel_ranges(static_cast<int>(pushers.size()), kMinChunk, chunks(), [&](int b, int e) {
    for (int j = b; j < e; ++j) {
      const int v = pushers[static_cast<size_t>(j)];
      const int o = off[static_cast<size_t>(v)];
      const int m = off[static_cast<size_t>(v) + 1] - o;
      const int* ring = coords.neighbors.data() + o;
      const Vec3 c = centroid(x, ring, m);
      const Vec3 N = newell(x, ring, m, c);
      double spread2 = 0;
      for (int i = 0; i < m; ++i) spread2 += (row(x, ring[i]) - c).squaredNorm();
      (*shift)[static_cast<size_t>(j)].setZero();
      if (!(N.norm() > kAreaEps * spread2)) continue;
      const Vec3 n = N.normalized();
      const Vec3 dv = row(x, v) - c;
      const double H = n.dot(dv);
      const Vec3 p = dv - H * n;
      double target = 0;
      for (int i = 0; i < m; ++i) {
        Vec3 q = row(x, ring[i]) - c;
        q -= n.dot(q) * n;
        target += (p - q).norm() * cot_beta[static_cast<size_t>(o + i)];
      }
      (*shift)[static_cast<size_t>(j)] = (H - target / m) * n;
    }
  });
  // A vertex next to several controls takes the mean of their shifts.
  pushes->resize(pushed.size());
  for (size_t j = 0; j < pushed.size(); ++j) {
    Vec3 s = Vec3::Zero();
    const int qb = pushed_offsets[j], qe = pushed_offsets[j + 1];
    for (int q = qb; q < qe; ++q) s += (*shift)[static_cast<size_t>(pushed_by[q])];
    (*pushes)[j] = s / (qe - qb);
  }
}

void PyramidLevel::apply(const std::vector<int>& verts, const double* from, double* to,
                         const Vertices* tau, const PyramidSolveOptions& o,
                         const std::vector<Vec3>& pushes) const {
  parallel_ranges(static_cast<int>(verts.size()), kMinChunk, chunks(), [&](int b, int e) {
    for (int r = b; r < e; ++r) {
      const int v = verts[static_cast<size_t>(r)];
      Vec3 p = place(v, from, o.stretch);
      if (o.push && push_row[static_cast<size_t>(v)] >= 0) {
        p += pushes[static_cast<size_t>(push_row[static_cast<size_t>(v)])];
      }
      if (tau) p += tau->row(v).transpose();
      to[3 * v] = p(0), to[3 * v + 1] = p(1), to[3 * v + 2] = p(2);
    }
  });
}

void PyramidLevel::sweep(Vertices* X, const Vertices* tau, const PyramidSolveOptions& o) const {
  // Step 2 folded into step 1: each free vertex is placed from its description plus the shift
  // its controls ask for, both from the sweep's start. The fixed point is then the same for
  // Jacobi and for Gauss-Seidel in any colour order.
  std::vector<Vec3> shift, pushes;
  if (o.push) shifts(X->data(), &shift, &pushes);
  if (o.method == PyramidMethod::Jacobi) {
    const Vertices old = *X;
    apply(free, old.data(), X->data(), tau, o, pushes);
  } else {
    for (const auto& cls : colors) apply(cls, X->data(), X->data(), tau, o, pushes);
  }
}

void PyramidLevel::jacobi(const std::vector<int>& verts, const Vertices& X, const Vertices* tau,
                          const PyramidSolveOptions& o, Vertices* Y) const {
  std::vector<Vec3> shift, pushes;
  if (o.push) shifts(X.data(), &shift, &pushes);
  apply(verts, X.data(), Y->data(), tau, o, pushes);
}

int PyramidLevel::iterate(Vertices* X, const Vertices* tau, const PyramidSolveOptions& o,
                          int max_iterations, double limit, double* move,
                          std::vector<double>* moves, double diag) const {
  const int nf = static_cast<int>(free.size());
  *move = 0;
  if (nf == 0) return 0;
  // Anderson acceleration (Walker & Ni 2011) of the sweep map G over the free coordinates:
  // x+ = G(x) - dG gamma with gamma = argmin |f - dF gamma|, f = G(x) - x, over the last
  // `window` differences. Plain loops, not Eigen products, which would start OpenMP threads
  // beside the task pool.
  const int window = std::max(0, o.anderson);
  const Eigen::Index len = 3 * static_cast<Eigen::Index>(nf);
  Eigen::VectorXd x, g, f, f_prev, g_prev;
  Eigen::MatrixXd dF, dG, gram;
  if (window > 0) {
    x.resize(len), g.resize(len);
    dF.resize(len, window), dG.resize(len, window);
    gram = Eigen::MatrixXd::Zero(window, window);
  }
  auto dot = [len](const double* a, const double* b) {
    double s0 = 0, s1 = 0;
    Eigen::Index i = 0;
    for (; i + 1 < len; i += 2) s0 += a[i] * b[i], s1 += a[i + 1] * b[i + 1];
    if (i < len) s0 += a[i] * b[i];
    return s0 + s1;
  };
  int stored = 0, head = 0, it = 0;
  Vertices Y;
  while (it < max_iterations) {
    Y = *X;
    sweep(&Y, tau, o);
    // The move is the sweep's (the fixed-point residual), not the accelerated step's.
    *move = max_move(Y, *X, free);
    if (window > 0) {
      for (int r = 0; r < nf; ++r) {
        const int v = free[static_cast<size_t>(r)];
        x.segment<3>(3 * r) = X->row(v).transpose();
        g.segment<3>(3 * r) = Y.row(v).transpose();
      }
      f = g - x;
      if (it > 0) {
        dF.col(head) = f - f_prev;
        dG.col(head) = g - g_prev;
        stored = std::min(stored + 1, window);
        for (int j = 0; j < stored; ++j) {
          gram(head, j) = gram(j, head) = dot(dF.col(head).data(), dF.col(j).data());
        }
        head = (head + 1) % window;
      }
      f_prev = f;
      g_prev = g;
      if (stored > 0) {
        Eigen::MatrixXd A = gram.topLeftCorner(stored, stored);
        Eigen::VectorXd rhs(stored);
        for (int j = 0; j < stored; ++j) rhs(j) = dot(dF.col(j).data(), f.data());
        A.diagonal().array() += 1e-10 * A.diagonal().maxCoeff() + 1e-300;
        const Eigen::VectorXd gamma = A.ldlt().solve(rhs);
        if (gamma.allFinite()) {
          double* gp = g.data();
          for (int j = 0; j < stored; ++j) {
            const double c = gamma(j);
            const double* col = dG.col(j).data();
            for (Eigen::Index i = 0; i < len; ++i) gp[i] -= c * col[i];
          }
          for (int r = 0; r < nf; ++r) {
            Y.row(free[static_cast<size_t>(r)]) = g.segment<3>(3 * r).transpose();
          }
        }
      }
    }
    X->swap(Y);
    ++it;
    if (!std::isfinite(*move)) throw std::runtime_error("pyramid deformer: the iteration diverged");
    if (moves) moves->push_back(diag > 0 ? *move / diag : *move);
    if (*move < limit) break;
  }
  return it;
}

namespace {

// Removes an independent set of vertices by half-edge collapses (no two removed vertices are
// neighbours, so each keeps its whole one-ring): interior manifold non-control vertices of
// valence 3-10, flattest first, each onto the neighbour whose collapse keeps every face's
// orientation. Returns the faces of the coarser mesh in the old indices; removed[v] marks v.
Faces coarsen(const Vertices& V, const Faces& F, const PyramidCoordinates& pc,
              const std::vector<char>& is_control, std::vector<char>* removed) {
  const int n = static_cast<int>(V.rows());
  const int m = static_cast<int>(F.rows());
  std::vector<std::array<int, 3>> faces(static_cast<size_t>(m));
  std::vector<std::vector<int>> vf(static_cast<size_t>(n));
  for (int f = 0; f < m; ++f) {
    for (int k = 0; k < 3; ++k) {
      faces[static_cast<size_t>(f)][k] = F(f, k);
      vf[static_cast<size_t>(F(f, k))].push_back(f);
    }
  }
  std::vector<char> alive(static_cast<size_t>(m), 1), blocked(static_cast<size_t>(n), 0);
  removed->assign(static_cast<size_t>(n), 0);
  std::vector<std::pair<double, int>> order;
  for (int v = 0; v < n; ++v) {
    const int val = pc.offsets[static_cast<size_t>(v) + 1] - pc.offsets[static_cast<size_t>(v)];
    if (is_control[static_cast<size_t>(v)] || pc.kind[static_cast<size_t>(v)] != kPyramidInterior ||
        val < 3 || val > 10)
      continue;
    double spread = 0;
    for (int s = pc.offsets[v]; s < pc.offsets[v + 1]; ++s) spread += pc.length[s];
    order.emplace_back(std::abs(pc.height(v)) * val / spread, v);
  }
  std::sort(order.begin(), order.end());
  auto normal = [&](const std::array<int, 3>& t) {
    const Vec3 a = V.row(t[0]), b = V.row(t[1]), c = V.row(t[2]);
    return Vec3((b - a).cross(c - a));
  };
  std::vector<int> nu, nv;
  for (const auto& [cost, v] : order) {
    if (blocked[static_cast<size_t>(v)]) continue;
    const int o = pc.offsets[static_cast<size_t>(v)];
    const int val = pc.offsets[static_cast<size_t>(v) + 1] - o;
    nv.assign(pc.neighbors.begin() + o, pc.neighbors.begin() + o + val);
    std::sort(nv.begin(), nv.end());
    // Targets nearest first.
    std::vector<std::pair<double, int>> targets;
    for (int u : nv) targets.emplace_back((V.row(u) - V.row(v)).squaredNorm(), u);
    std::sort(targets.begin(), targets.end());
    for (const auto& [d2, u] : targets) {
      // Link condition: u and v share exactly the two vertices opposite their edge.
      nu.clear();
      for (int f : vf[static_cast<size_t>(u)])
        for (int k = 0; k < 3; ++k) nu.push_back(faces[static_cast<size_t>(f)][k]);
      std::sort(nu.begin(), nu.end());
      nu.erase(std::unique(nu.begin(), nu.end()), nu.end());
      int common = 0;
      for (int w : nv) common += w != u && std::binary_search(nu.begin(), nu.end(), w) ? 1 : 0;
      if (common != 2) continue;
      // Every face of v that survives keeps its orientation and a fair shape.
      bool ok = true;
      for (int f : vf[static_cast<size_t>(v)]) {
        auto t = faces[static_cast<size_t>(f)];
        if (t[0] == u || t[1] == u || t[2] == u) continue;
        const Vec3 before = normal(t);
        for (int& x : t)
          if (x == v) x = u;
        const Vec3 after = normal(t);
        if (!(after.dot(before) > 0.5 * after.norm() * before.norm())) ok = false;
      }
      if (!ok) continue;
      for (int f : vf[static_cast<size_t>(v)]) {
        auto& t = faces[static_cast<size_t>(f)];
        if (t[0] == u || t[1] == u || t[2] == u) {
          alive[static_cast<size_t>(f)] = 0;
          for (int x : t) {
            auto& l = vf[static_cast<size_t>(x)];
            if (x != v) l.erase(std::remove(l.begin(), l.end(), f), l.end());
          }
          continue;
        }
        for (int& x : t)
          if (x == v) x = u;
        vf[static_cast<size_t>(u)].push_back(f);
      }
      vf[static_cast<size_t>(v)].clear();
      (*removed)[static_cast<size_t>(v)] = 1;
      for (int w : nv) blocked[static_cast<size_t>(w)] = 1;
      break;
    }
  }
  int alive_count = 0;
  for (char a : alive) alive_count += a;
  Faces out(alive_count, 3);
  int r = 0;
  for (int f = 0; f < m; ++f) {
    if (!alive[static_cast<size_t>(f)]) continue;
    for (int k = 0; k < 3; ++k) out(r, k) = faces[static_cast<size_t>(f)][k];
    ++r;
  }
  return out;
}

// The coarsest level keeps at least this many vertices; levels that remove less than 5 % of
// their vertices end the hierarchy.
constexpr int kCoarsest = 200;
constexpr int kMaxLevels = 16;

}  // namespace

struct PyramidDeformer::Impl {
  std::vector<PyramidLevel> levels;
  std::vector<std::vector<int>> control;  // per level: control vertex ids in that level
};

PyramidDeformer::PyramidDeformer(const Vertices& vertices, const Faces& faces,
                                 const std::vector<int>& control)
    : impl_(std::make_unique<Impl>()) {
  validate_mesh(vertices, faces);
  const int n = static_cast<int>(vertices.rows());
  if (control.empty()) throw std::invalid_argument("control: expected at least one vertex");
  std::vector<char> is_control(static_cast<size_t>(n), 0);
  for (int c : control) {
    if (c < 0 || c >= n) {
      throw std::invalid_argument("control: vertex " + std::to_string(c) + " outside [0, " +
                                  std::to_string(n) + ")");
    }
    if (is_control[static_cast<size_t>(c)]) {
      throw std::invalid_argument("control: vertex " + std::to_string(c) + " given twice");
    }
    is_control[static_cast<size_t>(c)] = 1;
  }
  control_ = control;
  diag_ = (vertices.colwise().maxCoeff() - vertices.colwise().minCoeff()).norm();
  impl_->levels.emplace_back(vertices, faces, is_control);
  impl_->control.push_back(control);
  Faces F = faces;
  while (static_cast<int>(impl_->levels.size()) < kMaxLevels) {
    PyramidLevel& fine = impl_->levels.back();
    const int nl = static_cast<int>(fine.rest.rows());
    if (nl <= kCoarsest) break;
    std::vector<char> removed;
    const Faces coarse_faces = coarsen(fine.rest, F, fine.coords, is_control, &removed);
    int kept = 0;
    for (char r : removed) kept += r ? 0 : 1;
    if (kept > 0.95 * nl || kept < 3) break;
    fine.coarse.assign(static_cast<size_t>(nl), -1);
    Vertices V(kept, 3);
    std::vector<char> ctrl(static_cast<size_t>(kept), 0);
    for (int v = 0, k = 0; v < nl; ++v) {
      if (removed[static_cast<size_t>(v)]) {
        fine.removed.push_back(v);
        continue;
      }
      fine.coarse[static_cast<size_t>(v)] = k;
      V.row(k) = fine.rest.row(v);
      ctrl[static_cast<size_t>(k)] = is_control[static_cast<size_t>(v)];
      ++k;
    }
    F = coarse_faces;
    for (Eigen::Index f = 0; f < F.rows(); ++f)
      for (int k = 0; k < 3; ++k) F(f, k) = fine.coarse[static_cast<size_t>(F(f, k))];
    std::vector<int> cc;
    for (int c : impl_->control.back()) cc.push_back(fine.coarse[static_cast<size_t>(c)]);
    is_control = std::move(ctrl);
    impl_->control.push_back(std::move(cc));
    impl_->levels.emplace_back(V, F, is_control);
  }
}

PyramidDeformer::~PyramidDeformer() = default;

const PyramidCoordinates& PyramidDeformer::coordinates() const { return impl_->levels[0].coords; }
int PyramidDeformer::num_vertices() const { return static_cast<int>(impl_->levels[0].rest.rows()); }
int PyramidDeformer::num_colors() const { return static_cast<int>(impl_->levels[0].colors.size()); }
int PyramidDeformer::num_passive() const { return impl_->levels[0].num_passive; }
std::vector<int> PyramidDeformer::level_sizes() const {
  std::vector<int> out;
  for (const auto& l : impl_->levels) out.push_back(static_cast<int>(l.rest.rows()));
  return out;
}

Vertices PyramidDeformer::reconstruct(const Vertices& X, bool stretch) const {
  const PyramidLevel& l0 = impl_->levels[0];
  if (X.rows() != l0.rest.rows()) {
    throw std::invalid_argument("positions: expected shape (" + std::to_string(l0.rest.rows()) +
                                ",3)");
  }
  if (!X.allFinite()) throw std::invalid_argument("positions: contains NaN or infinity");
  const ParkWorkersOnExit park;
  Vertices Y = X;
  parallel_ranges(static_cast<int>(X.rows()), kMinChunk, chunks(), [&](int b, int e) {
    for (int v = b; v < e; ++v) Y.row(v) = l0.place(v, X.data(), stretch).transpose();
  });
  return Y;
}

Vertices PyramidDeformer::deform(const Vertices& control_positions,
                                 const PyramidSolveOptions& options) {
  const ParkWorkersOnExit park;
  const auto& levels = impl_->levels;
  const int n = num_vertices();
  const int k = static_cast<int>(control_.size());
  if (control_positions.rows() != k) {
    throw std::invalid_argument("control_positions: expected shape (" + std::to_string(k) +
                                ",3), got " + std::to_string(control_positions.rows()) + " rows");
  }
  if (!control_positions.allFinite()) {
    throw std::invalid_argument("control_positions: contains NaN or infinity");
  }
  if (options.max_iterations < 0) throw std::invalid_argument("iterations: expected >= 0");
  if (!(options.tol >= 0) || !std::isfinite(options.tol)) {
    throw std::invalid_argument("tol: expected a finite value >= 0");
  }
  if (options.anderson < 0) throw std::invalid_argument("anderson: expected >= 0");
  Vertices X = levels[0].rest;
  if (options.initial) {
    if (options.initial->rows() != n) {
      throw std::invalid_argument("initial: expected shape (" + std::to_string(n) + ",3)");
    }
    if (!options.initial->allFinite()) {
      throw std::invalid_argument("initial: contains NaN or infinity");
    }
    X = *options.initial;
  }
  for (int j = 0; j < k; ++j) X.row(control_[static_cast<size_t>(j)]) = control_positions.row(j);
  const double limit = options.tol * diag_;
  last_moves_.clear();
  last_iterations_ = 0;
  last_move_ = std::numeric_limits<double>::quiet_NaN();
  if (options.max_iterations == 0) return X;

  double move = 0;
  if (options.multilevel && levels.size() > 1) {
    // Nonlinear multigrid (FAS V-cycles); one iteration is one cycle.
    const std::vector<int>& free0 = levels[0].free;
    Vertices old;
    for (int it = 0; it < options.max_iterations; ++it) {
      old = X;
      cycle(0, &X, nullptr, options, limit);
      move = max_move(X, old, free0);
      ++last_iterations_;
      if (!std::isfinite(move)) throw std::runtime_error("pyramid deformer: the cycle diverged");
      if (options.record_moves) last_moves_.push_back(diag_ > 0 ? move / diag_ : move);
      if (move < limit) break;
    }
  } else {
    last_iterations_ = levels[0].iterate(&X, nullptr, options, options.max_iterations, limit, &move,
                                         options.record_moves ? &last_moves_ : nullptr, diag_);
  }
  last_move_ = levels[0].free.empty() ? 0.0 : (diag_ > 0 ? move / diag_ : move);
  return X;
}

void PyramidDeformer::cycle(size_t l, Vertices* X, const Vertices* tau,
                            const PyramidSolveOptions& o, double limit) const {
  const auto& levels = impl_->levels;
  const PyramidLevel& L = levels[l];
  double move = 0;
  if (l + 1 == levels.size()) {
    L.iterate(X, tau, o, o.coarse_iterations, 0.1 * limit, &move, nullptr, diag_);
    return;
  }
  for (int s = 0; s < o.level_sweeps; ++s) L.sweep(X, tau, o);
  // Restrict by injection; the coarse problem x = P_c(x) + tau_c gets
  // tau_c = R (P(x) + tau) - P_c(R x), so that R x solves it once x solves the fine one.
  const PyramidLevel& C = levels[l + 1];
  const auto& map = L.coarse;
  Vertices Q = *X;
  L.jacobi(L.free, *X, tau, o, &Q);
  Vertices Xc(C.rest.rows(), 3);
  for (size_t v = 0; v < map.size(); ++v)
    if (map[v] >= 0) Xc.row(map[v]) = X->row(static_cast<Eigen::Index>(v));
  Vertices Qc = Xc;
  C.jacobi(C.free, Xc, nullptr, o, &Qc);
  Vertices tc = Vertices::Zero(C.rest.rows(), 3);
  // Residual r = P(x) + tau - x; restricted by averaging each kept vertex's own residual with
  // those of its removed neighbours (each shared among its kept neighbours).
  Vertices r = Q - *X;
  Vertices rc = Vertices::Zero(C.rest.rows(), 3);
  Eigen::VectorXd wc = Eigen::VectorXd::Zero(C.rest.rows());
  for (size_t v = 0; v < map.size(); ++v)
    if (map[v] >= 0) rc.row(map[v]) += r.row(static_cast<Eigen::Index>(v)), wc(map[v]) += 1;
  if (o.restrict_average) {
    const auto& off = L.coords.offsets;
    for (int v : L.removed) {
      const int m = off[v + 1] - off[v];
      for (int s = off[v]; s < off[v + 1]; ++s) {
        const int w = map[static_cast<size_t>(L.coords.neighbors[s])];
        rc.row(w) += r.row(v) / m;
        wc(w) += 1.0 / m;
      }
    }
  }
  for (size_t v = 0; v < map.size(); ++v) {
    const int w = map[v];
    if (w >= 0) tc.row(w) = Xc.row(w) - Qc.row(w) + o.coarse_scale * rc.row(w) / wc(w);
  }
  const Vertices Xc0 = Xc;
  cycle(l + 1, &Xc, &tc, o, limit);
  // Prolongate: kept vertices take the coarse correction, removed ones (whose neighbours are
  // all kept) are placed from their descriptions.
  for (size_t v = 0; v < map.size(); ++v) {
    const int w = map[v];
    if (w >= 0) X->row(static_cast<Eigen::Index>(v)) += o.coarse_damping * (Xc.row(w) - Xc0.row(w));
  }
  L.jacobi(L.removed, *X, tau, o, X);
  for (int s = 0; s < o.level_sweeps; ++s) L.sweep(X, tau, o);
}

}  // namespace matdeform
