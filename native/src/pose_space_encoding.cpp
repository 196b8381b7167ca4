// The rotation-invariant encoding of the pose-space method's examples (Lipman et al. 2005, as
// in MeshIK): per example k and level face i the deformation gradient T_ik = R_ik S_ik (rest ->
// example, fourth-vertex frames, polar decomposition), stored as the stretch S_ik (symmetric,
// in the rest frame), and per dual edge (i, j) the relative rotation log
// omega_ijk = log(R_ik^T R_jk). A rigid motion of an example changes neither. See
// docs/pose_space.md, "Encoding".
#include <stdexcept>
#include <string>

#include "matdeform/frames.hpp"
#include "matdeform/transforms.hpp"
#include "pose_space_internal.hpp"

namespace matdeform {

using namespace pose_space;  // NOLINT: this file is part of the method

namespace {

// Symmetric 3x3 as 6 numbers: xx yy zz xy xz yz.
inline void pack_sym(const Mat3& S, double* o) {
  o[0] = S(0, 0);
  o[1] = S(1, 1);
  o[2] = S(2, 2);
  o[3] = 0.5 * (S(0, 1) + S(1, 0));
  o[4] = 0.5 * (S(0, 2) + S(2, 0));
  o[5] = 0.5 * (S(1, 2) + S(2, 1));
}

}  // namespace

void PoseSpaceDeformer::Impl::encode_examples(const std::vector<Vertices>& examples,
                                              std::vector<Matrix3Array>* example_rotations) {
  const int lm = static_cast<int>(lfaces.rows());
  example_rotations->assign(p, Matrix3Array());
  const int E = static_cast<int>(ldual.rows());
  omega = RowMatrix::Zero(E, 3 * p);
  stretch = RowMatrix::Zero(lm, 6 * p);
  for (int k = 0; k < p; ++k) {
    const Vertices ex = whole ? examples[k] : gather_rows(examples[k], lvertices);
    const Matrix3Array T = deformation_gradients(lrest, ex, lfaces);
    Matrix3Array& R = (*example_rotations)[k];
    R.resize(lm);
    for (int i = 0; i < lm; ++i) {
      Mat3 Sl;
      try {
        polar_decompose(T[i], &Sl, &R[i]);
      } catch (const std::invalid_argument&) {
        fail(item("examples", k) + ": " + (multires ? "coarse " : "") + "face " +
             std::to_string(i) + " is degenerate (zero area)");
      }
      pack_sym(R[i].transpose() * T[i], &stretch(i, 6 * k));
    }
    for (int e = 0; e < E; ++e) {
      omega.row(e).segment<3>(3 * k) =
          rotation_log(R[ldual(e, 0)].transpose() * R[ldual(e, 1)]).transpose();
    }
  }
}

}  // namespace matdeform
