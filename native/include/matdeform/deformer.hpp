// Material-aware deformation (Popa, Julius, Sheffer 2006): weights + blending + repositioning.
#pragma once

#include <memory>
#include <optional>
#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

class PoissonRepositioner;

// Precomputes everything that depends on the mesh, anchors and stiffness: the blending weights
// (Eq. 1) and the factorisation of the repositioning system (Eq. 4). deform() then blends the
// anchor transforms (Eq. 2), assembles the right-hand side and back-substitutes.
//
// Pinning:
//  - pinned given: exactly those vertices are fixed in deform().
//  - pinned empty (nullopt): with 4x4 transforms the vertices of each anchor's faces follow their
//    anchor's full transform (factored in the constructor); with 3x3 transforms nothing is fixed
//    and each component keeps its vertex mean at rest (factored on the first such call, then
//    cached).
class MaterialDeformer {
 public:
  // vertices (n,3); faces (m,3); anchors: k disjoint non-empty face lists; shear (m,) > 0;
  // bend (E,) > 0 in dual_edges() order.
  MaterialDeformer(const Vertices& vertices, const Faces& faces, const AnchorList& anchors,
                   const Eigen::VectorXd& shear, const Eigen::VectorXd& bend,
                   std::optional<std::vector<int>> pinned);
  ~MaterialDeformer();

  // transforms: k 4x4 matrices (bottom row ignored). With has_translation false only the 3x3
  // block is used. pinned_positions: (|pinned|,3) or nullptr. Returns (n,3).
  Vertices deform(const std::vector<Eigen::Matrix4d>& transforms, bool has_translation,
                  const Vertices* pinned_positions) const;

  const RowMatrix& weights() const { return weights_; }  // (m,k)
  // Per-face blended transforms T_i of the last deform() call.
  const Matrix3Array& face_transforms() const { return blended_; }
  int num_anchors() const { return static_cast<int>(anchors_.size()); }

 private:
  const PoissonRepositioner& repositioner(bool follow) const;

  Vertices rest_;
  Faces faces_;
  AnchorList anchors_;
  Eigen::VectorXd shear_;
  std::optional<std::vector<int>> pinned_;
  RowMatrix weights_;
  // Vertex -> anchors whose faces use it (for following anchors), CSR.
  std::vector<int> anchor_vertices_;                     // unique, sorted
  std::vector<int> av_offsets_, av_anchors_;             // per anchor_vertices_ entry
  mutable std::unique_ptr<PoissonRepositioner> follow_;  // anchor vertices (or pinned) fixed
  mutable std::unique_ptr<PoissonRepositioner> free_;    // nothing fixed (pinned empty, 3x3)
  mutable Matrix3Array blended_;
};

}  // namespace matdeform
