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

DualEdges dual_edges(const Faces& faces);

// Throws std::invalid_argument when faces reference vertices outside [0, num_vertices) or a
// face repeats a vertex, and when any vertex coordinate is not finite.
void validate_mesh(const Vertices& vertices, const Faces& faces);

// Connected components of the face graph (faces linked by dual edges). Returns one label per
// face in [0, count) and sets count.
std::vector<int> face_components(int num_faces, const IndexPairs& pairs, int* count);

// Twice the area of each face, length m.
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

}  // namespace matdeform
