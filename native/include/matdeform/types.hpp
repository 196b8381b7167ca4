// Shared array types. Row-major so numpy (n,3) arrays map without copies.
#pragma once

#include <Eigen/Core>
#include <vector>

namespace matdeform {

using Vertices = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;  // (n,3) positions
using Faces = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;        // (m,3) triangles
using IndexPairs = Eigen::Matrix<int, Eigen::Dynamic, 2, Eigen::RowMajor>;   // (E,2) index pairs
using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using Matrix3Array = std::vector<Eigen::Matrix3d>;  // one 3x3 per face or anchor
using AnchorList = std::vector<std::vector<int>>;   // per anchor: face indices

}  // namespace matdeform
