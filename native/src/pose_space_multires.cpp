// Multiresolution for the pose-space method: both solves run on a coarse mesh (quadric
// simplification by meshoptimizer, in a numbering-independent order, cleared of flat faces,
// folds and slivers) whose vertices are dense vertices; every dense vertex follows the coarse
// solution through harmonic weights (the largest few kept) plus a per-example detail vector
// turned by its coarse neighbours' rotations. See docs/pose_space.md, "Multiresolution".
#include <meshoptimizer.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <numeric>
#include <string>
#include <utility>

#include "matdeform/mesh.hpp"
#include "matdeform/weights.hpp"
#include "pose_space_internal.hpp"

namespace matdeform {
namespace pose_space {

namespace {

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

}  // namespace

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

}  // namespace pose_space

using namespace pose_space;  // NOLINT: this file is part of the method

// Multiresolution transfer weights: harmonic on the dense vertex graph (edge weights
// 1/length^2), one Dirichlet anchor per coarse vertex, the largest few kept per vertex.
void PoseSpaceDeformer::Impl::build_transfer(const Faces& afaces) {
  const int ln = static_cast<int>(lvertices.size()), lm = static_cast<int>(lfaces.rows());
  const IndexPairs edges = mesh_edges(afaces);
  Eigen::VectorXd phi(edges.rows());
  double mean_len = 0.0;
  for (Eigen::Index e = 0; e < edges.rows(); ++e) {
    phi(e) = (rest.row(edges(e, 0)) - rest.row(edges(e, 1))).norm();
    mean_len += phi(e);
  }
  mean_len /= static_cast<double>(std::max<Eigen::Index>(edges.rows(), 1));
  for (Eigen::Index e = 0; e < edges.rows(); ++e) {
    const double rel = std::max(phi(e) / mean_len, 1e-6);
    phi(e) = 1.0 / (rel * rel);
  }
  AnchorList anchors(ln);
  for (int c = 0; c < ln; ++c) anchors[c] = {lvertices[c]};
  // The largest few per vertex, renormalised (the dense (n, ln) matrix would take 8 n ln
  // bytes: 1.9 GB at a million faces and 1000 coarse faces, several copies at its peak).
  const SparseWeights W = largest_harmonic_weights(n, edges, phi, anchors, opt.transfer_neighbors);
  tr_ptr = W.ptr;
  tr_idx = W.idx;
  tr_w = W.w;
  for (int v = 0; v < n; ++v) {  // rest of free parts have none
    double sum = 0.0;
    for (int k = tr_ptr[v]; k < tr_ptr[v + 1]; ++k) sum += tr_w[k];
    for (int k = tr_ptr[v]; k < tr_ptr[v + 1]; ++k) tr_w[k] /= sum;
  }
  larea = double_areas(lrest, lfaces);
  std::vector<int> cnt(ln + 1, 0);
  for (int f = 0; f < lm; ++f)
    for (int l = 0; l < 3; ++l) ++cnt[lfaces(f, l) + 1];
  for (int c = 0; c < ln; ++c) cnt[c + 1] += cnt[c];
  vf_ptr = cnt;
  vf_idx.resize(static_cast<size_t>(cnt[ln]));
  std::vector<int> cur(cnt.begin(), cnt.end() - 1);
  for (int f = 0; f < lm; ++f)
    for (int l = 0; l < 3; ++l) vf_idx[cur[lfaces(f, l)]++] = f;
}

// Detail vectors: d_v^k = M_vk^-1 (x_vk - sum_c b_vc y_ck), M_vk = sum_c b_vc R_ck.
void PoseSpaceDeformer::Impl::build_details(const std::vector<Vertices>& examples,
                                            const std::vector<Matrix3Array>& example_rotations) {
  const int ln = static_cast<int>(lvertices.size());
  const int q = std::max(p, 1);
  detail = RowMatrix::Zero(n, 3 * q);
  for (int k = 0; k < q; ++k) {
    const Vertices X = p == 0 ? rest : examples[k];
    const Vertices y = gather_rows(X, lvertices);
    Matrix3Array Rv(ln, Mat3::Identity());
    if (p > 0) vertex_rotations(example_rotations[k], &Rv);
    for (int v = 0; v < n; ++v) {
      Mat3 M = Mat3::Zero();
      for (int t = tr_ptr[v]; t < tr_ptr[v + 1]; ++t) M += tr_w[t] * Rv[tr_idx[t]];
      const Vec3 off = X.row(v).transpose() - base_position(v, y);
      const Eigen::FullPivLU<Mat3> lu(M);
      // A vertex whose neighbours' rotations cancel (never for neighbouring rest of a
      // sane example) keeps no detail for this example.
      if (lu.isInvertible() && std::abs(M.determinant()) > 1e-3) {
        detail.row(v).segment<3>(3 * k) = lu.solve(off).transpose();
      }
    }
  }
}

void PoseSpaceDeformer::Impl::vertex_rotations(const Matrix3Array& Rf, Matrix3Array* Rv) const {
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
Vec3 PoseSpaceDeformer::Impl::dense_position(int v, const Vertices& y, const Matrix3Array& Rv,
                                             const Eigen::VectorXd& w) const {
  if (!multires) return y.row(level_of[v]).transpose();
  return base_position(v, y) + offset(v, Rv, w);
}

Vec3 PoseSpaceDeformer::Impl::base_position(int v, const Vertices& y) const {
  Vec3 s = Vec3::Zero();
  for (int k = tr_ptr[v]; k < tr_ptr[v + 1]; ++k) s += tr_w[k] * y.row(tr_idx[k]).transpose();
  return s;
}

Vec3 PoseSpaceDeformer::Impl::offset(int v, const Matrix3Array& Rv,
                                     const Eigen::VectorXd& w) const {
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
Vec3 PoseSpaceDeformer::Impl::row_target(int v, const Vec3& t, const Matrix3Array& Rv,
                                         const Eigen::VectorXd& w) const {
  return multires ? Vec3(t - offset(v, Rv, w)) : t;
}

PositionSolver::Row PoseSpaceDeformer::Impl::make_row(int v) const {
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

}  // namespace matdeform
