// Mesh topology: dual edges (face pairs sharing a mesh edge), validation and components.
#pragma once

#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

// Face pairs that share a mesh edge.
//  pairs(e) = (f, g) with f < g, rows sorted lexicographically and unique. An edge shared by
//  more than two faces (non-manifold) contributes every pair of its faces.
//  shared(e) = (a, b), a < b: the vertices of the mesh edge that pair e shares (the first one
//  found if two faces share more than one edge).
struct DualEdges {
  IndexPairs pairs;
  IndexPairs shared;
};

// Throws std::invalid_argument for a negative vertex index.
DualEdges dual_edges(const Faces& faces);

// Throws std::invalid_argument naming `name` unless every one of the `size` entries at `data`
// lies in [0, upper). Every index that reaches the core from outside goes through this (or
// validate_mesh) before it is used to address memory.
void check_indices(const int* data, Eigen::Index size, Eigen::Index upper, const char* name);
template <class IndexMatrix>
void check_indices(const IndexMatrix& indices, Eigen::Index upper, const char* name) {
  check_indices(indices.data(), indices.size(), upper, name);
}

// Mesh sizes the core accepts: the largest extent of the bounding box (over x, y, z) lies in
// [kMinMeshSize, kMaxMeshSize]. Inside it the per-face products (squared cross products, up to
// size^4 in the repositioning's elimination) stay within double range with room for the
// stiffness ratio; outside it the user rescales the mesh (only shapes matter, not units).
constexpr double kMinMeshSize = 1e-50;
constexpr double kMaxMeshSize = 1e50;

// Throws std::invalid_argument when faces reference vertices outside [0, num_vertices) or a
// face repeats a vertex, when any vertex coordinate is not finite, and when the mesh size is
// outside [kMinMeshSize, kMaxMeshSize].
void validate_mesh(const Vertices& vertices, const Faces& faces);

// Union-find over [0, n) (path halving). Every set's root is its smallest element, so the
// result does not depend on the order in which elements are linked. The one union-find of the
// core: components of faces (face_components) and of vertices (the solvers) both use it.
class DisjointSets {
 public:
  explicit DisjointSets(int n);
  int find(int x);
  // Merges the sets of a and b; returns false when they were already one set.
  bool unite(int a, int b);

 private:
  std::vector<int> parent_;
};

// Connected components of the face graph (faces linked by dual edges). Returns one label per
// face in [0, count) and sets count. Throws std::invalid_argument for pairs outside
// [0, num_faces).
std::vector<int> face_components(int num_faces, const IndexPairs& pairs, int* count);

// Twice the area of each face, length m. Throws std::invalid_argument for out-of-range faces.
Eigen::VectorXd double_areas(const Vertices& vertices, const Faces& faces);

// Ordered one-ring of every vertex, walked through the faces around it (by shared edges, so
// face orientation does not matter). ring[offsets[v] .. offsets[v+1]) are v's neighbours:
//  - kFanClosed: a closed fan, in cyclic order (faces (v, ring[i], ring[i+1]), last wraps);
//  - kFanOpen: one open fan from one boundary neighbour to the other (no wrap-around face);
//  - kFanNonManifold: anything else (an edge in more than two of v's faces, several fans);
//    ring lists the distinct neighbours in increasing index order;
//  - kFanIsolated: v is in no face, ring is empty.
// Where the faces are consistently oriented the order follows them (face (v, ring[i],
// ring[i+1]) has that orientation), so the ring turns counter-clockwise about the outward normal.
enum FanKind : signed char { kFanClosed = 0, kFanOpen = 1, kFanNonManifold = 2, kFanIsolated = 3 };
struct VertexFans {
  std::vector<int> offsets;  // n + 1
  std::vector<int> ring;
  std::vector<signed char> kind;  // FanKind per vertex
};

// faces must hold indices in [0, num_vertices) (validate_mesh()).
VertexFans vertex_fans(int num_vertices, const Faces& faces);
// Undirected mesh edges (a, b), a < b, one row per edge used by any face, sorted
// lexicographically: the order per-edge arrays (edge weights) use.
IndexPairs mesh_edges(const Faces& faces);

}  // namespace matdeform
