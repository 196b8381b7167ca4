// Shared array types. Row-major so numpy (n,3) arrays map without copies.
#pragma once

#include <Eigen/Core>
#include <vector>

namespace matdeform {

using Vertices = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;  // (n,3) positions
using Faces = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;        // (m,3) triangles
using IndexPairs = Eigen::Matrix<int, Eigen::Dynamic, 2, Eigen::RowMajor>;   // (E,2) index pairs
using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using Vectors3 = Vertices;  // (k,3) vectors, e.g. one rotation vector (axis * angle) per anchor
using Matrix3Array = std::vector<Eigen::Matrix3d>;  // one 3x3 per face or anchor
using AnchorList = std::vector<std::vector<int>>;   // per anchor: face indices

// Per-face 3x3 matrices in groups of four faces, structure of arrays, as the per-pose kernels
// use them (four faces fill one AVX2 register): entry e (column-major, 0..8) of face 4 g + l is
// element kGroupStride * g + 4 * e + l. A mesh of m faces has (m + 3) / 4 groups.
constexpr int kGroupFaces = 4;
constexpr int kGroupStride = 36;  // doubles per group
inline int num_groups(int num_faces) { return (num_faces + kGroupFaces - 1) / kGroupFaces; }

}  // namespace matdeform
