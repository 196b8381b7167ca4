// Per-triangle local frames and deformation gradients (Sumner & Popovic 2004, used by Popa et
// al. 2006 Sec. 4.2-4.3).
#pragma once

#include "matdeform/types.hpp"

namespace matdeform {

// Frame of triangle (a, b, c): columns b-a, c-a, d-a with the fourth vertex
// d = a + n / sqrt(|n|), n = (b-a) x (c-a). The sqrt makes |d-a| scale like an edge length,
// so the frame stays well conditioned and scales with the triangle. Spans the same space as the
// paper's (v4-v1, v4-v2, v4-v3), which gives identical gradients.
Eigen::Matrix3d face_frame(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                           const Eigen::Vector3d& c);

// The fourth vertex d above.
Eigen::Vector3d fourth_vertex(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                              const Eigen::Vector3d& c);

// T_i = frame(deformed_i) * frame(rest_i)^-1 for every face (the affine part of the map that
// takes the rest triangle and its fourth vertex onto the deformed ones). Both meshes share faces.
// Throws std::invalid_argument for a degenerate (zero-area) rest face, a rest mesh that
// validate_mesh refuses or non-finite deformed positions.
Matrix3Array deformation_gradients(const Vertices& rest, const Vertices& deformed,
                                   const Faces& faces);

}  // namespace matdeform
