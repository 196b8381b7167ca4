// Stiffness field conversions (Popa et al. 2006, Sec. 4.1).
#pragma once

#include "matdeform/mesh.hpp"

namespace matdeform {

// Largest max/min ratio accepted within one stiffness field. Beyond it the factorisations lose
// every digit (a ratio of 1e16 made CHOLMOD fail outright); only ratios matter, so a user
// raises the smallest values instead.
constexpr double kMaxStiffnessRatio = 1e12;

// Throws std::invalid_argument naming `name` unless all `size` values at x are finite, > 0 and
// within kMaxStiffnessRatio of each other.
void check_stiffness(const double* x, Eigen::Index size, const char* name);

// Each conversion throws std::invalid_argument for an index outside the stiffness array it reads.

// phi_fg = (psi_f + psi_g) / 2 for each dual edge (the paper's derived bending stiffness).
Eigen::VectorXd bend_from_shear(const IndexPairs& pairs, const Eigen::VectorXd& shear);

// Per-vertex stiffness s (n,) to per-dual-edge bending: the mean of s over the two vertices of
// the shared mesh edge (the hinge the two faces bend about).
Eigen::VectorXd bend_from_vertex(const DualEdges& dual, const Eigen::VectorXd& s);

// Per-vertex stiffness s (n,) to per-face shear: the mean over the face's three vertices.
Eigen::VectorXd shear_from_vertex(const Faces& faces, const Eigen::VectorXd& s);

}  // namespace matdeform
