// Learning bending and shearing stiffness from example poses (Popa et al. 2006, Sec. 6).
//
// Two stages, so callers can try other mappings without recomputing the expensive part:
//  1. learn_distortions(): per pose s and face i, T_si = Vt_si V_0i^-1 = S_si Q_si (polar), then
//       bend(e = (i,j)) = max_s |Q_si - Q_sj|_F^2                       (isotropic, (E,1))
//       bend(e, a)      = max_s (a-th component of the relative rotation of i and j)^2
//                                                                       (anisotropic, (E,3))
//       shear(i)        = max_s |S_si - I|_F^2                          ((m,))
//     All values are dimensionless and invariant to rigid motions of each pose.
//  2. stiffness_from_distortion(): distortion d >= 0 -> stiffness in [eps, 1], large d -> eps.
#pragma once

#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

// How the anisotropic bending components are measured, for each dual edge (i, j) and pose s.
enum class AxisFrame {
  // Axis-angle vector of the relative rotation Q_si^T Q_sj, in the coordinates of the reference
  // mesh (the object frame). The hinge of a joint has the same axis here in every pose, and the
  // value is invariant to a rigid motion of the pose.
  kRest,
  // Difference of the axis-angle vectors log Q_sj - log Q_si in world coordinates: the quantity
  // the per-axis blending of Sec. 5 interpolates. Depends on the global orientation of the pose.
  kWorldLogDifference,
};

struct Distortions {
  RowMatrix bend;         // (E,1) isotropic or (E,3) anisotropic, in the order of `pairs`
  Eigen::VectorXd shear;  // (m,)
};

// rest (n,3) reference vertices, faces (m,3), pairs (E,2) dual edges (usually
// dual_edges(faces).pairs), poses: l >= 1 arrays of (n,3) with the connectivity of rest.
// A face collapsed to zero area in a pose (gradient det <= 0) has no rotation: that pose is
// skipped for it and its dual edges. (A triangle flipped over keeps det > 0 with the fourth-vertex
// frame and reads as a rotation.)
// Throws std::invalid_argument for bad sizes, out-of-range indices, non-finite coordinates or a
// degenerate rest face. Parallel over faces and edges (OpenMP).
Distortions learn_distortions(const Vertices& rest, const Faces& faces, const IndexPairs& pairs,
                              const std::vector<Vertices>& poses, bool anisotropic,
                              AxisFrame frame = AxisFrame::kRest);

struct StiffnessMap {
  // Stiffness floor: the output lies in [eps, 1]. 0 < eps <= 1.
  double eps = 0.01;
  // "Clamping the bottom 1%" (Sec. 6), read as: the `clamp_percent` % most flexible values are
  // raised to the stiffness of the (100 - clamp_percent)-th percentile of distortion, i.e. the
  // distortions are clipped from above at that percentile before normalising. A few near-
  // degenerate triangles in one pose then cannot squash everybody else towards stiffness 1.
  // The percentile uses linear interpolation between order statistics (numpy's default) over all
  // entries of the field (all three axes together for anisotropic bending). 0 disables.
  double clamp_percent = 1.0;
  // Shape of the falloff in u = clipped distortion / its maximum, u in [0, 1]:
  //   sharpness == 0: g(u) = 1 - u                       (the paper's linear scaling)
  //   sharpness > 0 : g(u) = (exp(-a u) - exp(-a)) / (1 - exp(-a)), a = sharpness
  // and stiffness = eps + (1 - eps) g(u), so u = 0 -> 1 and u = 1 -> eps exactly.
  double sharpness = 0.0;
};

// d (rows, cols) >= 0 -> stiffness of the same shape. The normalising maximum is never taken
// below 1e-12 (round-off level), so an undeformed field maps to ones, not to noise in [eps, 1].
// Throws std::invalid_argument for negative or non-finite entries or bad parameters.
RowMatrix stiffness_from_distortion(const RowMatrix& d, const StiffnessMap& map);

// Spreads distortions over the face graph (regional rather than per-edge flexibility; the
// per-edge maxima are noisy at the mesh scale). Each pass replaces every face value by the mean
// of itself and its dual-edge neighbours. Bending is moved to faces first (mean over the face's
// dual edges, per column) and back to edges at the end (mean of the edge's two faces).
// passes == 0 returns d unchanged. num_faces = m, pairs (E,2) as in learn_distortions.
// Throws std::invalid_argument for non-finite distortions or pairs outside [0, num_faces).
Distortions smooth_distortions(const Distortions& d, int num_faces, const IndexPairs& pairs,
                               int passes);

// Region-level bending statistic: the spread of the face rotations around their local mean,
//   spread(i, s) = 3 - |mean_{j ~ i} Q_sj|_F^2 = mean_{j ~ i} |Q_sj - mean Q_s|_F^2   (in [0, 3])
// where "mean over j ~ i" is `passes` passes of the face-graph averaging of smooth_distortions
// applied to the rotation field Q_s of pose s. A rigid part (bone) has spread ~0 however it
// moves; a region that bends as a whole (a torso) has a large spread even when every single dual
// edge bends only a little, which the per-edge |Q_i - Q_j|^2 cannot see. Faces collapsed in a
// pose are left out of that pose's averages (weight 0). Invariant to rigid motions of each pose.
// Returns (m, l): column s for pose s. passes >= 0 (0: all zeros). Parallel over poses (OpenMP).
RowMatrix rotation_spread(const Vertices& rest, const Faces& faces, const IndexPairs& pairs,
                          const std::vector<Vertices>& poses, int passes);

struct LearnedStiffness {
  RowMatrix bend;         // (E,1) or (E,3), in [eps, 1]
  Eigen::VectorXd shear;  // (m,), in [eps, 1]
};

// learn_distortions, then smooth_distortions (smoothing_passes >= 0), then the same map for bend
// and shear (each normalised by its own maximum).
LearnedStiffness learn_stiffness(const Vertices& rest, const Faces& faces, const IndexPairs& pairs,
                                 const std::vector<Vertices>& poses, bool anisotropic,
                                 const StiffnessMap& map, AxisFrame frame = AxisFrame::kRest,
                                 int smoothing_passes = 0);

}  // namespace matdeform
