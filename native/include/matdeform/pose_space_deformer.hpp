// Pose-space surface manipulation: example shapes + translational and rotational handles.
//
// The MeshIK family (Sumner et al. 2005) with a rotation-invariant encoding (Lipman et al. 2005)
// and pose-space interpolation. Per example k and face i: the deformation gradient
// T_ik = R_ik S_ik (rest -> example, fourth-vertex frames), S_ik symmetric (rest frame); per dual
// edge (i, j) the relative rotation log w_ijk = log(R_ik^T R_jk). deform():
//  1. pose: handle centroids (over the bounding-box diagonal) and best-fit handle rotations in a
//     frame (the frame face, or a best fit of all handle vertices), plus the prescribed joint
//     rotations -> example weights by cardinal radial basis interpolation (phi(r) = r with a
//     constant term): 1 at its own example, 0 at the others, summing to 1, continuous, bounded;
//  2. blend: Q_ij = exp(sum_k w_k w_ijk), S_i = sum_k w_k S_ik;
//  3. step 1: rotations R_i minimising sum w_ij |R_j - R_i Q_ij|^2 + joint and handle penalties,
//     projected to the nearest rotation; step 2: positions minimising
//     sum |grad_i x - R_i S_i|^2 + handle penalties.
// Step 1's matrix depends on Q (the paper refactors it per edit). Here it is solved in a gauge
// where it is nearly constant (rotations integrated along a spanning tree, then Gauss-Newton
// steps of the geodesic energy), by conjugate gradients preconditioned with the scalar
// face-graph Laplacian factored once; consistent blends (an example) converge at once. Step 2's
// matrix is constant and factored once. With a coarse face count both steps run on a
// quadric-simplified mesh that dense vertices follow through harmonic weights and per-example
// detail vectors. Lengths are in the mesh's unit, angles in radians. See docs/pose_space.md.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

struct PoseSpaceOptions {
  // Face whose frame (rotation and centroid) the handle positions are measured in. Without it a
  // best-fit rigid frame of all handle vertices is used.
  std::optional<int> frame;
  // Rotational handles: (face_a, face_b) pairs; deform() prescribes R_a^T R_b for each.
  std::vector<std::array<int, 2>> rotational;
  // Faces that keep their rest shape and place.
  std::vector<int> frozen;
  // Target face count of the coarse mesh; nullopt solves on the full mesh.
  std::optional<int> coarse_faces;
  // Penalty weights, relative: positions against the mean diagonal of the step-2 matrix,
  // rotations against unit dual-edge weights in step 1. All > 0.
  double position_weight = 100.0;
  double rotation_weight = 1.0;  // faces inside a handle follow its best-fit rotation
  double joint_weight = 100.0;   // rotational pairs
  bool handle_rotations = true;  // false: translational handles do not constrain step 1
  bool area_weights = false;     // step 2 weighs faces by rest area (default: every face 1)
  // Step 1 energy. Chordal (the paper, default): sum w_e |R_b - R_a Q|^2, then projection to
  // rotations; solved by conjugate gradients preconditioned with the scalar face-graph
  // Laplacian factored once, in the gauge of two Gauss-Newton steps of the geodesic energy.
  // Geodesic: sum w_e |log(R_a Q R_b^T)|^2 by Gauss-Newton steps in the Lie algebra alone,
  // each one substitution with that factor (faster, less robust to unreliable edges).
  enum class RotationEnergy { kChordal, kGeodesic };
  RotationEnergy rotation_energy = RotationEnergy::kChordal;
  int rotation_iterations = 10;  // at most: CG iterations (chordal) or Gauss-Newton steps, >= 1
  // Chordal CG stops at this relative energy-norm error (0 < tol < 1).
  double rotation_tolerance = 1e-6;
  // Gauss-Newton steps that make the chordal solve's gauge; they are also the whole solve of
  // the natural shape when a solve with the handle rotations follows (>= 1).
  int gauge_steps = 2;
  // Dual edges whose relative rotation reaches this angle (radians) in some example weigh 1/2
  // in step 1, w_e = 1 / (1 + (max_k angle_ek / reliability_angle)^2); infinity: all 1.
  double reliability_angle = 0.5;
  // Weight of the handles' own orientations in the pose vector (0: positions only).
  double orientation_weight = 1.0;
  // Example weights: smoothing ridge on the kernel matrix, relative to its largest entry (>= 0; 0
  // interpolates exactly), and whether negative weights are clipped and the rest renormalised.
  double weight_regularization = 0.0;
  bool convex_weights = false;
  // Multiresolution: coarse vertices each dense vertex follows (harmonic weights, largest kept).
  int transfer_neighbors = 8;
};

// What the last deform() did (for benchmarks and tests). Times in milliseconds.
struct PoseSpaceStats {
  // Iterations of the two step-1 solves: the natural shape (Gauss-Newton steps when the handle
  // solve follows, else CG iterations) and the solve with the handle rotations (CG iterations,
  // Gauss-Newton steps with the geodesic energy; 0 when skipped).
  int iterations_first = 0;
  int iterations_second = 0;
  double ms_weights = 0, ms_blend = 0, ms_rotations = 0, ms_positions = 0, ms_fit = 0,
         ms_transfer = 0;
  double ms_gauge = 0, ms_chordal = 0;  // parts of ms_rotations (final chordal solve)
};

// Thread-safe: concurrent deform() calls on one deformer take turns (a mutex guards the
// solvers' workspaces and the last call's weights and stats); different deformers and
// pose_weights() run concurrently.
class PoseSpaceDeformer {
 public:
  // rest (n,3); faces (m,3), every vertex used, no degenerate face (a connected part with no
  // handle vertex, frozen face, frame face or rotational face is output at rest, bit for bit;
  // each other part is solved in its own rotation and translation gauge); examples: p >= 0
  // arrays (n,3) with the connectivity of rest; handles: h >= 0 disjoint non-empty vertex lists.
  // Throws std::invalid_argument on bad input.
  PoseSpaceDeformer(const Vertices& rest, const Faces& faces, const std::vector<Vertices>& examples,
                    const std::vector<std::vector<int>>& handles,
                    const PoseSpaceOptions& options = {});
  ~PoseSpaceDeformer();
  PoseSpaceDeformer(const PoseSpaceDeformer&) = delete;
  PoseSpaceDeformer& operator=(const PoseSpaceDeformer&) = delete;

  // handle_positions: h arrays (|handles[j]|,3), world positions. rotations: r rotations
  // R_a^T R_b of the rotational pairs, or nullptr (joints free, pose from positions only).
  // frame_transform: rigid 4x4 moving the rest frame face to its place, or nullptr (then the
  // frame is measured from the handle positions, which must cover the frame face's vertices).
  // Returns (n,3).
  Vertices deform(const std::vector<Vertices>& handle_positions, const Matrix3Array* rotations,
                  const Eigen::Matrix4d* frame_transform = nullptr) const;

  // The example weights (p,) deform() would use for these inputs.
  Eigen::VectorXd pose_weights(const std::vector<Vertices>& handle_positions,
                               const Matrix3Array* rotations,
                               const Eigen::Matrix4d* frame_transform = nullptr) const;

  // (p,) weights of the last deform() (empty before the first call or with p = 0), and its
  // stats. Copies: another thread's deform() may replace them at any time.
  Eigen::VectorXd example_weights() const;
  PoseSpaceStats last_stats() const;

  int num_examples() const;
  int num_handles() const;
  int num_rotational() const;
  bool multiresolution() const;
  // The mesh step 1 and 2 run on: the coarse faces (in coarse vertex indices) and the dense
  // index of each coarse vertex; the full mesh without multiresolution.
  const Faces& solve_faces() const;
  const std::vector<int>& solve_vertices() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace matdeform
