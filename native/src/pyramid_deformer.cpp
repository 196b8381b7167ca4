#include "matdeform/pyramid_deformer.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"
#include "matdeform/transforms.hpp"
#include "simd.hpp"
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

// Chunks per thread of the parallel loops: small enough for the claims to balance a late worker
// (a colour of the cat is ~1000 vertices: chunks of 256 left one of two threads idle 12 % of a
// sweep; 64 gave 10-15 % more sweeps per second with two threads).
int chunks() { return 16 * num_threads(); }
constexpr int kMinChunk = 64;

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

// The placement kernel's unit: four free vertices of one colour and one valence m, placed side by
// side (four lanes of a Vec4d) so that the square roots (2m + 1 per vertex with stretch, m + 1
// without) run four at a time. Their m neighbour entries are group_ring[4 e + lane] and
// group_val[12 e + 4 f + lane] for e = entry .. entry + m - 1 and the fields f = 0: w_i / l_i,
// 1: w_i, 2: cot(beta_i). The last group of a valence repeats its last vertex to fill the lanes;
// only the first of the repeats is written.
struct PlaceGroup {
  int v[4];
  int m;
  int entry;
};
constexpr int kGroupMaxValence = 16;  // higher valences are placed one by one

struct PyramidSolver;

struct PlaceArgs {
  const PyramidSolver* solver;  // the scalar placement, for lanes whose plane vanished
  const PlaceGroup* groups;
  const int* ring;
  const double* val;
  const double* from;
  double* to;
  const int* push_row;  // null: no step 2
  const Vec3* pushes;
  bool stretch;
};

// Everything a sweep needs: the description plus the colouring and step 2's adjacency.
struct PyramidSolver {
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
  // The placement kernel's copy of the description (see PlaceGroup), per colour.
  std::vector<std::vector<PlaceGroup>> color_groups;
  std::vector<std::vector<int>> color_singles;  // placed one by one: followers, high valence
  std::vector<int> group_ring;                  // 4 neighbour ids per group entry
  std::vector<double> group_val;                // w_i/l_i, w_i, cot(beta_i): 4 each per entry

  PyramidSolver(const Vertices& vertices, const Faces& faces, const std::vector<char>& is_control);
  Vec3 follow(int v, const double* X) const;
  Vec3 place(int v, const double* X, bool stretch) const;
  // Step 2 from positions x: per pusher its shift, per pushed vertex the mean of its pushers'.
  void shifts(const double* x, std::vector<Vec3>* shift, std::vector<Vec3>* pushes) const;
  void build_groups();
  // to_v = place(v, from) + push_v for the free vertices of one colour.
  void apply(int color, const double* from, double* to, const PyramidSolveOptions& o,
             const std::vector<Vec3>& pushes) const;
  // One sweep over the free vertices (Gauss-Seidel by colours, or Jacobi).
  void sweep(Vertices* X, const PyramidSolveOptions& o) const;
  // Sweeps (Anderson-accelerated) until the largest sweep move < limit or max_iterations.
  // Returns the sweeps done; *move is the last sweep's largest move (absolute). Throws
  // std::runtime_error once a sweep moves a vertex by more than `blowup` (or not finitely).
  int iterate(Vertices* X, const PyramidSolveOptions& o, int max_iterations, double limit,
              double* move, std::vector<double>* moves, double diag,
              double blowup = std::numeric_limits<double>::infinity()) const;
};

PyramidSolver::PyramidSolver(const Vertices& vertices, const Faces& faces,
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
  build_groups();
}

void PyramidSolver::build_groups() {
  const auto& off = coords.offsets;
  color_groups.assign(colors.size(), {});
  color_singles.assign(colors.size(), {});
  group_ring.clear();
  group_val.clear();
  for (size_t c = 0; c < colors.size(); ++c) {
    std::vector<std::vector<int>> by_valence(kGroupMaxValence + 1);
    for (int v : colors[c]) {
      const int m = off[static_cast<size_t>(v) + 1] - off[static_cast<size_t>(v)];
      if (coords.kind[static_cast<size_t>(v)] <= kPyramidBoundary && m <= kGroupMaxValence) {
        by_valence[static_cast<size_t>(m)].push_back(v);
      } else {
        color_singles[c].push_back(v);
      }
    }
    for (int m = 0; m <= kGroupMaxValence; ++m) {
      const auto& vs = by_valence[static_cast<size_t>(m)];
      for (size_t b = 0; b < vs.size(); b += 4) {
        PlaceGroup g;
        g.m = m;
        g.entry = static_cast<int>(group_ring.size() / 4);
        for (int l = 0; l < 4; ++l) g.v[l] = vs[std::min(b + l, vs.size() - 1)];
        for (int i = 0; i < m; ++i) {
          for (int l = 0; l < 4; ++l) group_ring.push_back(coords.neighbors[off[g.v[l]] + i]);
          for (int l = 0; l < 4; ++l) group_val.push_back(weight_per_len[off[g.v[l]] + i]);
          for (int l = 0; l < 4; ++l) group_val.push_back(coords.weight[off[g.v[l]] + i]);
          for (int l = 0; l < 4; ++l) group_val.push_back(cot_beta[off[g.v[l]] + i]);
        }
        color_groups[c].push_back(g);
      }
    }
  }
}

Vec3 PyramidSolver::follow(int v, const double* X) const {
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
  // The scale is tr(R^T H) / s0 (the signed sum of the singular values). fit_rotation's
  // quaternion fit is ~6x cheaper than the SVD (followers are up to 3 % of a decimated mesh
  // and took a quarter of its sweep with an SVD each), which remains for H of rank <= 1.
  Eigen::Matrix3d Rp;
  double trace = 0;
  if (fit_rotation(Hm, &Rp, &trace)) return c + (trace / s0) * (Rp * (row(R0, v) - c0));
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

Vec3 PyramidSolver::place(int v, const double* X, bool stretch) const {
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

namespace {

// x, y, z of rows idx[0..3] of an (n,3) array.
MD_ALWAYS_INLINE void gather3(const double* X, const int* idx, Vec4d* x, Vec4d* y, Vec4d* z) {
  const double *a = X + 3 * idx[0], *b = X + 3 * idx[1], *c = X + 3 * idx[2], *d = X + 3 * idx[3];
  *x = Vec4d{a[0], b[0], c[0], d[0]};
  *y = Vec4d{a[1], b[1], c[1], d[1]};
  *z = Vec4d{a[2], b[2], c[2], d[2]};
}

// PyramidSolver::place for the four vertices of each group in [gb, ge), written with their
// step-2 shift into a.to: the same arithmetic to round-off (products by 1/m and 1/|N| where
// place() divides, FMA in the AVX2 build), four lanes at a time. A lane whose current
// neighbours have no plane (the scalar path's follower fallback) is redone by the scalar code.
MD_ALWAYS_INLINE void place_body(const PlaceArgs& a, int gb, int ge) {
  const Vec4d zero = {0, 0, 0, 0}, one = {1, 1, 1, 1};
  Vec4d dx[kGroupMaxValence], dy[kGroupMaxValence], dz[kGroupMaxValence];
  for (int g = gb; g < ge; ++g) {
    const PlaceGroup& G = a.groups[g];
    const int m = G.m;
    const int* ring = a.ring + 4 * static_cast<size_t>(G.entry);
    const double* val = a.val + 12 * static_cast<size_t>(G.entry);
    Vec4d cx = zero, cy = zero, cz = zero;
    for (int i = 0; i < m; ++i) {
      gather3(a.from, ring + 4 * i, &dx[i], &dy[i], &dz[i]);
      cx += dx[i], cy += dy[i], cz += dz[i];
    }
    const double inv_m = 1.0 / m;
    cx *= inv_m, cy *= inv_m, cz *= inv_m;
    Vec4d spread2 = zero;
    for (int i = 0; i < m; ++i) {
      dx[i] -= cx, dy[i] -= cy, dz[i] -= cz;
      spread2 += dx[i] * dx[i] + dy[i] * dy[i] + dz[i] * dz[i];
    }
    // Newell normal of the neighbour polygon
    Vec4d nx = dy[m - 1] * dz[0] - dz[m - 1] * dy[0];
    Vec4d ny = dz[m - 1] * dx[0] - dx[m - 1] * dz[0];
    Vec4d nz = dx[m - 1] * dy[0] - dy[m - 1] * dx[0];
    for (int i = 1; i < m; ++i) {
      nx += dy[i - 1] * dz[i] - dz[i - 1] * dy[i];
      ny += dz[i - 1] * dx[i] - dx[i - 1] * dz[i];
      nz += dx[i - 1] * dy[i] - dy[i - 1] * dx[i];
    }
    Vec4d nn;
    sqrt4(nx * nx + ny * ny + nz * nz, &nn);
    const Vec4m plane = nn > kAreaEps * spread2;
    const Vec4d inv_nn = one / MD_SELECT4(plane, nn, one);
    nx *= inv_nn, ny *= inv_nn, nz *= inv_nn;
    for (int i = 0; i < m; ++i) {  // v'_i - c on the plane P through c
      const Vec4d t = nx * dx[i] + ny * dy[i] + nz * dz[i];
      dx[i] -= t * nx, dy[i] -= t * ny, dz[i] -= t * nz;
    }
    // Eq. 1, with the stretch factors |v' - v'_i| / l_i when asked for.
    Vec4d vx = zero, vy = zero, vz = zero;
    Vec4m plain = plane;  // lanes that still need the plain weights
    if (a.stretch) {
      Vec4d px, py, pz;
      gather3(a.from, G.v, &px, &py, &pz);
      px -= cx, py -= cy, pz -= cz;
      const Vec4d t = nx * px + ny * py + nz * pz;
      px -= t * nx, py -= t * ny, pz -= t * nz;
      Vec4d wsum = zero;
      for (int i = 0; i < m; ++i) {
        const Vec4d ex = px - dx[i], ey = py - dy[i], ez = pz - dz[i];
        Vec4d len;
        sqrt4(ex * ex + ey * ey + ez * ez, &len);
        const Vec4d wi = MD_LD4(val + 12 * i) * len;
        vx += wi * dx[i], vy += wi * dy[i], vz += wi * dz[i];
        wsum += wi;
      }
      const double inf = std::numeric_limits<double>::infinity();
      const Vec4m good = (wsum > 1e-300) & (vx < inf) & (vx > -inf) & (vy < inf) & (vy > -inf) &
                         (vz < inf) & (vz > -inf);
      const Vec4d inv_w = one / MD_SELECT4(good, wsum, one);
      vx *= inv_w, vy *= inv_w, vz *= inv_w;
      plain = plane & ~good;
    }
    bool any_plain = false;
    for (int l = 0; l < 4; ++l) any_plain |= plain[l] != 0;
    if (any_plain) {
      Vec4d wx = zero, wy = zero, wz = zero;
      for (int i = 0; i < m; ++i) {
        const Vec4d w = MD_LD4(val + 12 * i + 4);
        wx += w * dx[i], wy += w * dy[i], wz += w * dz[i];
      }
      vx = MD_SELECT4(plain, wx, vx), vy = MD_SELECT4(plain, wy, vy);
      vz = MD_SELECT4(plain, wz, vz);
    }
    // Eq. 2: v = v' + n mean(h_i), h_i = |v' - v'_i| cot(beta_i) + (v_i - v'_i).n.
    Vec4d h = zero;
    for (int i = 0; i < m; ++i) {
      const Vec4d ex = vx - dx[i], ey = vy - dy[i], ez = vz - dz[i];
      Vec4d len;
      sqrt4(ex * ex + ey * ey + ez * ez, &len);
      h += len * MD_LD4(val + 12 * i + 8);
    }
    h *= inv_m;
    const Vec4d ox = cx + vx + h * nx, oy = cy + vy + h * ny, oz = cz + vz + h * nz;
    for (int l = 0; l < 4; ++l) {
      const int v = G.v[l];
      // A padding lane repeats its predecessor: placing it again would, in place (Gauss-Seidel)
      // and on the scalar fallback, start from the vertex's new position.
      if (l > 0 && v == G.v[l - 1]) break;
      Vec3 p = plane[l] ? Vec3(ox[l], oy[l], oz[l]) : a.solver->place(v, a.from, a.stretch);
      if (a.push_row) {
        const int r = a.push_row[v];
        if (r >= 0) p += a.pushes[r];
      }
      a.to[3 * v] = p(0), a.to[3 * v + 1] = p(1), a.to[3 * v + 2] = p(2);
    }
  }
}
void place_base(const PlaceArgs& a, int gb, int ge) { place_body(a, gb, ge); }
MD_TARGET_AVX2 void place_avx2(const PlaceArgs& a, int gb, int ge) { place_body(a, gb, ge); }

}  // namespace

void PyramidSolver::shifts(const double* x, std::vector<Vec3>* shift,
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

void PyramidSolver::apply(int color, const double* from, double* to, const PyramidSolveOptions& o,
                          const std::vector<Vec3>& pushes) const {
  const auto& groups = color_groups[static_cast<size_t>(color)];
  const auto& singles = color_singles[static_cast<size_t>(color)];
  const PlaceArgs args{this,
                       groups.data(),
                       group_ring.data(),
                       group_val.data(),
                       from,
                       to,
                       o.push ? push_row.data() : nullptr,
                       pushes.data(),
                       o.stretch};
  void (*kernel)(const PlaceArgs&, int, int) = cpu_has_avx2_fma() ? place_avx2 : place_base;
  // One range over the single vertices, then the groups: one wait per colour. The singles
  // (followers, high valence) cost several groups each, so they are claimed first and the
  // groups even out the threads' shares (~5 % more sweeps per second with two threads on
  // cat 5k; the order within a colour does not change the result).
  const int ng = static_cast<int>(groups.size()), ns = static_cast<int>(singles.size());
  parallel_ranges(ng + ns, kMinChunk / 4, chunks(), [&](int b, int e) {
    for (int r = b; r < std::min(e, ns); ++r) {
      const int v = singles[static_cast<size_t>(r)];
      Vec3 p = place(v, from, o.stretch);
      if (o.push && push_row[static_cast<size_t>(v)] >= 0) {
        p += pushes[static_cast<size_t>(push_row[static_cast<size_t>(v)])];
      }
      to[3 * v] = p(0), to[3 * v + 1] = p(1), to[3 * v + 2] = p(2);
    }
    if (e > ns) kernel(args, std::max(b, ns) - ns, e - ns);
  });
}

void PyramidSolver::sweep(Vertices* X, const PyramidSolveOptions& o) const {
  // Step 2 folded into step 1: each free vertex is placed from its description plus the shift
  // its controls ask for, both from the sweep's start. The fixed point is then the same for
  // Jacobi and for Gauss-Seidel in any colour order.
  std::vector<Vec3> shift, pushes;
  if (o.push) shifts(X->data(), &shift, &pushes);
  const int nc = static_cast<int>(colors.size());
  if (o.method == PyramidMethod::Jacobi) {
    const Vertices old = *X;
    for (int c = 0; c < nc; ++c) apply(c, old.data(), X->data(), o, pushes);
  } else {
    for (int c = 0; c < nc; ++c) apply(c, X->data(), X->data(), o, pushes);
  }
}

int PyramidSolver::iterate(Vertices* X, const PyramidSolveOptions& o, int max_iterations,
                           double limit, double* move, std::vector<double>* moves, double diag,
                           double blowup) const {
  const int nf = static_cast<int>(free.size());
  *move = 0;
  if (nf == 0) return 0;
  // Anderson acceleration (Walker & Ni 2011) of the sweep map G over the free coordinates:
  // x+ = G(x) - dG gamma with gamma = argmin |f - dF gamma|, f = G(x) - x, over the last
  // `window` differences. The length-3nf work is two passes on the task pool: one reads the
  // sweep's result, appends the new difference columns and forms the new Gram row and dF^T f
  // together (one read of dF), the other applies gamma (one read of dG). They run in a fixed
  // number of chunks whose partial sums are added in order, so the result does not depend on
  // the thread count. (Eigen's matrix products would run on OpenMP threads and fight the
  // pool's workers.)
  const int window = std::max(0, o.anderson);
  const Eigen::Index len = 3 * static_cast<Eigen::Index>(nf);
  Eigen::VectorXd f_prev, g_prev, gamma;
  std::vector<double> dF, dG;  // column j at j * len
  Eigen::MatrixXd gram;
  const int parts = std::max(1, std::min(16, nf / 512));
  std::vector<double> part, part_move(static_cast<size_t>(parts), 0.0);
  if (window > 0) {
    f_prev.resize(len), g_prev.resize(len);
    dF.resize(static_cast<size_t>(len) * window), dG.resize(static_cast<size_t>(len) * window);
    gram = Eigen::MatrixXd::Zero(window, window);
    part.assign(static_cast<size_t>(parts) * 2 * window, 0.0);
  }
  auto chunk = [&](int p, int* b, int* e) {
    *b = static_cast<int>(static_cast<int64_t>(nf) * p / parts);
    *e = static_cast<int>(static_cast<int64_t>(nf) * (p + 1) / parts);
  };
  int stored = 0, head = 0, it = 0;
  auto reported = std::chrono::steady_clock::now();
  // After each sweep: count it, record its move, report progress when due; true once the
  // stopping rule is met.
  auto finished = [&]() {
    ++it;
    if (!(*move <= blowup)) {  // also NaN and infinity
      throw std::runtime_error(
          "pyramid deformer: the iteration diverged (a sweep moved a vertex by more than 100 "
          "times the size of the mesh and its controls): the pose may be too strong for so few "
          "control vertices; add controls, or try stretch=False or push=False");
    }
    const double rel = diag > 0 ? *move / diag : *move;
    if (moves) moves->push_back(rel);
    if (o.progress) {
      const auto now = std::chrono::steady_clock::now();
      if (std::chrono::duration<double>(now - reported).count() >= o.progress_seconds) {
        reported = now;
        o.progress(it, rel);
      }
    }
    return *move < limit;
  };
  if (window == 0) {
    Vertices Y;
    while (it < max_iterations) {
      Y = *X;
      sweep(&Y, o);
      *move = max_move(Y, *X, free);
      X->swap(Y);
      if (finished()) break;
    }
    return it;
  }
  // With Anderson the sweep runs in place on X: the iterate it started from is kept packed in
  // x_now (the accelerated step's output, or the previous sweep's result), so no copy of the
  // whole mesh is made per sweep.
  Eigen::VectorXd x_now(len);
  for (int r = 0; r < nf; ++r) {
    for (int c = 0; c < 3; ++c) x_now(3 * r + c) = (*X)(free[static_cast<size_t>(r)], c);
  }
  while (it < max_iterations) {
    sweep(X, o);
    // The move is the sweep's (the fixed-point residual), not the accelerated step's, taken in
    // the pass that reads the sweep's result anyway.
    const bool append = it > 0;
    const int n_cols = append ? std::min(stored + 1, window) : 0;
    run_tasks(parts, [&](int p) {
      int b, e;
      chunk(p, &b, &e);
      double* fp = f_prev.data();
      double* gp = g_prev.data();
      const double* xp = x_now.data();
      double* dfh = dF.data() + head * len;
      double* dgh = dG.data() + head * len;
      double mx = 0;
      for (int r = b; r < e; ++r) {
        const int v = free[static_cast<size_t>(r)];
        double d2 = 0;
        for (int c = 0; c < 3; ++c) {
          const Eigen::Index i = 3 * static_cast<Eigen::Index>(r) + c;
          const double g = (*X)(v, c), f = g - xp[i];
          d2 += f * f;
          if (append) {
            dfh[i] = f - fp[i];
            dgh[i] = g - gp[i];
          }
          fp[i] = f;
          gp[i] = g;
        }
        // NaN must not hide behind max(): it propagates as infinity
        mx = std::isnan(d2) ? std::numeric_limits<double>::infinity() : std::max(mx, d2);
      }
      part_move[static_cast<size_t>(p)] = mx;
      double* out = part.data() + static_cast<size_t>(p) * 2 * window;
      const Eigen::Index ib = 3 * static_cast<Eigen::Index>(b),
                         n3 = 3 * static_cast<Eigen::Index>(e - b);
      dot2_columns(dF.data() + ib, len, n_cols, dfh + ib, fp + ib, n3, out, out + window);
    });
    *move = std::sqrt(*std::max_element(part_move.begin(), part_move.end()));
    if (append) {
      stored = n_cols;
      for (int j = 0; j < stored; ++j) {
        double sum = 0;
        for (int p = 0; p < parts; ++p) sum += part[static_cast<size_t>(p) * 2 * window + j];
        gram(head, j) = gram(j, head) = sum;
      }
      head = (head + 1) % window;
    }
    bool accelerated = false;
    if (stored > 0) {
      Eigen::VectorXd rhs = Eigen::VectorXd::Zero(stored);
      for (int p = 0; p < parts; ++p) {
        for (int j = 0; j < stored; ++j)
          rhs(j) += part[static_cast<size_t>(p) * 2 * window + window + j];
      }
      Eigen::MatrixXd A = gram.topLeftCorner(stored, stored);
      A.diagonal().array() += 1e-10 * A.diagonal().maxCoeff() + 1e-300;
      gamma = A.ldlt().solve(rhs);
      if (gamma.allFinite()) {
        accelerated = true;
        run_tasks(parts, [&](int p) {
          int b, e;
          chunk(p, &b, &e);
          const Eigen::Index ib = 3 * static_cast<Eigen::Index>(b),
                             n3 = 3 * static_cast<Eigen::Index>(e - b);
          subtract_columns(dG.data() + ib, len, stored, gamma.data(), g_prev.data() + ib,
                           x_now.data() + ib, n3);
          for (int r = b; r < e; ++r) {
            const int v = free[static_cast<size_t>(r)];
            const Eigen::Index i0 = 3 * static_cast<Eigen::Index>(r);
            for (int c = 0; c < 3; ++c) (*X)(v, c) = x_now(i0 + c);
          }
        });
      }
    }
    if (!accelerated) x_now = g_prev;  // the plain step: X holds the sweep's result already
    if (finished()) break;
  }
  return it;
}

namespace {

// The rest mesh moved by the similarity (rotation, uniform scale, translation) that best maps
// the controls' rest positions onto their targets (Umeyama 1991). The sweeps converge slowly from
// the rest pose, and for a rigid motion of all controls this start is the answer.
Vertices similarity_start(const Vertices& rest, const std::vector<int>& control,
                          const Vertices& target) {
  const Eigen::Index k = target.rows();
  Vec3 c0 = Vec3::Zero(), c1 = Vec3::Zero();
  for (Eigen::Index j = 0; j < k; ++j) {
    c0 += rest.row(control[static_cast<size_t>(j)]).transpose();
    c1 += target.row(j).transpose();
  }
  c0 /= static_cast<double>(k);
  c1 /= static_cast<double>(k);
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  double s0 = 0;
  for (Eigen::Index j = 0; j < k; ++j) {
    const Vec3 a = rest.row(control[static_cast<size_t>(j)]).transpose() - c0;
    H += (target.row(j).transpose() - c1) * a.transpose();
    s0 += a.squaredNorm();
  }
  Eigen::Matrix3d A = Eigen::Matrix3d::Identity();
  if (s0 > 0 && H.allFinite() && H.norm() > 0) {
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    Eigen::Vector3d sig = svd.singularValues();
    if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1, sig(2) *= -1;
    // One or two controls (or collinear ones) leave the rotation about their line free: the fit
    // then picks the smallest rotation, which is what the SVD's ordering gives.
    A = (sig.sum() / s0) * (svd.matrixU() * D * svd.matrixV().transpose());
  }
  Vertices X(rest.rows(), 3);
  for (Eigen::Index v = 0; v < rest.rows(); ++v) {
    X.row(v) = (A * (rest.row(v).transpose() - c0) + c1).transpose();
  }
  return X;
}

}  // namespace

struct PyramidDeformer::Impl : PyramidSolver {
  using PyramidSolver::PyramidSolver;
};

PyramidDeformer::PyramidDeformer(const Vertices& vertices, const Faces& faces,
                                 const std::vector<int>& control) {
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
  impl_ = std::make_unique<Impl>(vertices, faces, is_control);
}

PyramidDeformer::~PyramidDeformer() = default;

const PyramidCoordinates& PyramidDeformer::coordinates() const { return (*impl_).coords; }
int PyramidDeformer::num_vertices() const { return static_cast<int>((*impl_).rest.rows()); }
int PyramidDeformer::num_colors() const { return static_cast<int>((*impl_).colors.size()); }
int PyramidDeformer::num_passive() const { return (*impl_).num_passive; }
Vertices PyramidDeformer::reconstruct(const Vertices& X, bool stretch) const {
  const PyramidSolver& l0 = *impl_;
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
  const PyramidSolver& level = *impl_;
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
  if (!(options.progress_seconds >= 0)) {
    throw std::invalid_argument("progress_seconds: expected a value >= 0");
  }
  Vertices X = level.rest;
  if (options.initial) {
    if (options.initial->rows() != n) {
      throw std::invalid_argument("initial: expected shape (" + std::to_string(n) + ",3)");
    }
    if (!options.initial->allFinite()) {
      throw std::invalid_argument("initial: contains NaN or infinity");
    }
    X = *options.initial;
  } else {
    X = similarity_start(level.rest, control_, control_positions);
  }
  for (int j = 0; j < k; ++j) X.row(control_[static_cast<size_t>(j)]) = control_positions.row(j);
  const double limit = options.tol * diag_;
  last_moves_.clear();
  last_iterations_ = 0;
  last_move_ = std::numeric_limits<double>::quiet_NaN();
  if (options.max_iterations == 0) return X;

  // A sweep that converges moves a vertex by about the extent of the configuration it starts
  // from at most, so a move of 100x the extent of the start and the controls means the iteration
  // is running away (growing modes took a capped cylinder of diagonal 4.9 to 1e77 in
  // 20000 sweeps without overflowing a double, docs/pyramid.md).
  Eigen::RowVector3d lo = X.colwise().minCoeff(), hi = X.colwise().maxCoeff();
  if (k > 0) {
    lo = lo.cwiseMin(control_positions.colwise().minCoeff());
    hi = hi.cwiseMax(control_positions.colwise().maxCoeff());
  }
  const double blowup = 100.0 * (diag_ + (hi - lo).norm());
  double move = 0;
  last_iterations_ = level.iterate(&X, options, options.max_iterations, limit, &move,
                                   options.record_moves ? &last_moves_ : nullptr, diag_, blowup);
  last_move_ = level.free.empty() ? 0.0 : (diag_ > 0 ? move / diag_ : move);
  return X;
}

}  // namespace matdeform
