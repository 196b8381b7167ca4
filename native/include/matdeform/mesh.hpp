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

// Undirected mesh edges (a, b), a < b, one row per edge used by any face, sorted
// lexicographically: the order per-edge arrays (edge weights) use.
IndexPairs mesh_edges(const Faces& faces);

}  // namespace matdeform
