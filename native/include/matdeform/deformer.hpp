// Material-aware deformation (Popa, Julius, Sheffer 2006): weights + blending + repositioning.
#pragma once

#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "matdeform/transforms.hpp"
#include "matdeform/types.hpp"

namespace matdeform {

class PoissonRepositioner;

struct DeformerOptions {
  // Vertices fixed in deform() (full-mesh indices). See MaterialDeformer for the rules.
  std::optional<std::vector<int>> pinned;
  // Region of interest (paper Sec. 7): face indices. Only these faces are solved for; vertices
  // shared with faces outside the region stay at rest, all other outside vertices are untouched.
  std::optional<std::vector<int>> region;
  // Anisotropy axes (Sec. 5): orthonormal columns x, y, z in mesh coordinates.
  Eigen::Matrix3d axes = Eigen::Matrix3d::Identity();
};

// Precomputes everything that depends on the mesh, anchors and stiffness: the blending weights
// (Eq. 1, once per bending field) and the factorisation of the repositioning system (Eq. 4).
// deform() then blends the anchor transforms (Eq. 2), assembles the right-hand side and
// back-substitutes.
//
// Pinning:
//  - pinned given: exactly those vertices are fixed in deform().
//  - pinned empty (nullopt): with 4x4 transforms the vertices of each anchor's faces follow their
//    anchor's full transform (factored in the constructor); with 3x3 transforms nothing is fixed
//    and each component keeps its vertex mean at rest (factored on the first such call, then
//    cached).
//  - with a region, its boundary vertices are always fixed at rest in addition.
//  - a part (vertices joined by faces) with no anchor face and no pinned vertex is fixed at
//    rest: deform() returns its rest positions bit for bit.
//
// Threads: deform() and face_transforms() may be called from several threads at once. Calls on
// one deformer are serialised (they share its workspaces); calls on different deformers run
// concurrently, each on the shared task pool when it is free and serially when it is not.
class MaterialDeformer {
 public:
  // vertices (n,3); faces (m,3); anchors: k disjoint non-empty face lists; shear (m,) > 0;
  // bend (E,1) isotropic or (E,3) per rotation axis, > 0, rows in dual_edges() order; each
  // field's max/min at most kMaxStiffnessRatio. Throws std::invalid_argument for bad input.
  MaterialDeformer(const Vertices& vertices, const Faces& faces, const AnchorList& anchors,
                   const Eigen::VectorXd& shear, const RowMatrix& bend,
                   const DeformerOptions& options = {});
  ~MaterialDeformer();

  // transforms: k 4x4 matrices (bottom row ignored). With has_translation false only the 3x3
  // block is used. pinned_positions: (|pinned|,3) or nullptr. Returns (n,3).
  // rotation_vectors: (k,3) or nullptr. Row a is a log of the rotation factor R_a of anchor a's
  // 3x3 block (polar decomposition M = S R), of any length: the caller picks the branch, e.g.
  // 3 pi about the twist axis for a turn and a half, and the blend uses it in place of R_a's
  // principal log (angle <= pi). exp(row a) must equal R_a within kRotationVectorTolerance
  // (rad); otherwise std::invalid_argument, and nothing is changed. nullptr: principal logs.
  Vertices deform(const std::vector<Eigen::Matrix4d>& transforms, bool has_translation,
                  const Vertices* pinned_positions,
                  const Vectors3* rotation_vectors = nullptr) const;
  // The same, rounded to float32 into out: n rows of 3 floats (C order), what a shape key or a
  // point cache stores; no (n,3) result is allocated per call.
  void deform(const std::vector<Eigen::Matrix4d>& transforms, bool has_translation,
              const Vertices* pinned_positions, float* out,
              const Vectors3* rotation_vectors = nullptr) const;

  // (m,k) blending weights on the full mesh (mean of the axes when anisotropic; zero rows
  // outside the region).
  const RowMatrix& weights() const { return weights_full_; }
  // (m,k) weights of one rotation axis (0,1,2); equals weights() when isotropic.
  RowMatrix axis_weights(int axis) const;
  // Per-face blended transforms T_i of the last deform() call (identity outside the region).
  Matrix3Array face_transforms() const;
  int num_anchors() const { return static_cast<int>(anchors_.size()); }
  bool anisotropic() const { return axis_weights_.size() == 3; }
  int num_vertices() const { return static_cast<int>(rest_.rows()); }
  int num_region_vertices() const { return static_cast<int>(sub_vertices_.size()); }
  // Threads the last deform()'s back-substitution ran on (1 = serial, 0 before the first call).
  // For tests that must reach the parallel path.
  int substitution_threads() const;

 private:
  const PoissonRepositioner& repositioner(bool follow) const;
  // deform() on the region, under mutex_: sub_out gets (region vertices,3).
  void solve_region(const std::vector<Eigen::Matrix4d>& transforms, bool has_translation,
                    const Vertices* pinned_positions, const Vectors3* rotation_vectors,
                    Vertices* sub_out) const;
  std::vector<int> fixed_set(const std::vector<int>& primary) const;

  Vertices rest_;                           // full mesh
  Vertices sub_rest_;                       // region only
  Faces sub_faces_;                         // region faces, region vertex indices
  std::vector<int> sub_vertices_;           // region vertex -> full vertex
  std::vector<int> sub_face_ids_;           // region face -> full face
  std::vector<int> boundary_;               // region vertex ids kept at rest
  AnchorList anchors_;                      // region face ids
  Eigen::VectorXd shear_;                   // region faces
  std::optional<std::vector<int>> pinned_;  // region vertex ids
  Eigen::Matrix3d axes_;
  std::vector<RowMatrix> axis_weights_;  // 1 (isotropic) or 3, each (m_region,k)
  RowMatrix mean_weights_;               // (m_region,k)
  RowMatrix weights_full_;               // (m,k)
  // Region vertex -> anchors that use it, CSR over the sorted anchor_vertices_.
  std::vector<int> anchor_vertices_;
  std::vector<int> av_offsets_, av_anchors_;
  // Per fixed vertex of follow_ (its order): the [begin, end) of its anchors in av_anchors_,
  // empty for boundary and non-anchor vertices, so that deform() does no searching.
  std::vector<std::pair<int, int>> follow_anchors_;
  // Region vertex ids in parts with no anchor face and no pinned vertex: fixed at rest.
  std::vector<int> still_;
  mutable std::unique_ptr<PoissonRepositioner> follow_;
  mutable std::unique_ptr<PoissonRepositioner> free_;
  // Anchor logs of the last deform(); face_transforms() re-blends them on request, so the
  // per-pose path never stores all m transforms.
  mutable std::vector<TransformLog> last_logs_;
  mutable int last_substitution_threads_ = 0;
  mutable Vertices work_out_;  // the float32 deform()'s region result, kept between calls
  // Guards free_, last_logs_ and the repositioners' workspaces.
  mutable std::mutex mutex_;
};

}  // namespace matdeform
