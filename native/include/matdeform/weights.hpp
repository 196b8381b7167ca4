// Harmonic blending weights under bending stiffness (Popa et al. 2006, Eq. 1).
#pragma once

#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

// Minimises sum_e phi_e |w_f - w_g|^2 over dual edges e = (f, g), with the faces of anchor a
// fixed to the unit vector e_a. Returns W (m,k).
//  - pairs: (E,2) dual edges in [0, num_faces), phi: (E,) bending stiffness > 0, max/min at
//    most kMaxStiffnessRatio (stiffness.hpp).
//  - anchors: k non-empty, pairwise disjoint lists of face indices.
// Faces whose face-graph component holds no anchor get an all-zero row (identity transform);
// every other row is a convex combination: entries in [0,1] summing to 1 (maximum principle).
// One sparse Cholesky factorisation, all k right-hand sides in one solve.
RowMatrix harmonic_weights(int num_faces, const IndexPairs& pairs, const Eigen::VectorXd& phi,
                           const AnchorList& anchors);

// The `keep` largest entries of every row of harmonic_weights, without the dense (m,k) matrix:
// the k columns are solved a block at a time (one factorisation) and each row keeps its best
// entries, larger weight first, then lower anchor for weights within 1e-12 (ties, so that
// round-off does not choose between symmetric anchors), only entries > 0. Memory is
// O(m (block + keep)) instead of 8 m k bytes (gigabytes at a million faces and 500 anchors).
// Row f owns idx/w[ptr[f] .. ptr[f+1]); weights as computed (not renormalised). keep >= 1.
struct SparseWeights {
  std::vector<int> ptr, idx;
  std::vector<double> w;
};
SparseWeights largest_harmonic_weights(int num_faces, const IndexPairs& pairs,
                                       const Eigen::VectorXd& phi, const AnchorList& anchors,
                                       int keep);

// Throws std::invalid_argument unless every anchor is non-empty, in range and no face belongs to
// two anchors.
void validate_anchors(int num_faces, const AnchorList& anchors);

}  // namespace matdeform
