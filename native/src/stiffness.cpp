#include "matdeform/stiffness.hpp"

namespace matdeform {

Eigen::VectorXd bend_from_shear(const IndexPairs& pairs, const Eigen::VectorXd& shear) {
  Eigen::VectorXd phi(pairs.rows());
  for (Eigen::Index e = 0; e < pairs.rows(); ++e) {
    phi(e) = 0.5 * (shear(pairs(e, 0)) + shear(pairs(e, 1)));
  }
  return phi;
}

Eigen::VectorXd bend_from_vertex(const DualEdges& dual, const Eigen::VectorXd& s) {
  Eigen::VectorXd phi(dual.shared.rows());
  for (Eigen::Index e = 0; e < dual.shared.rows(); ++e) {
    phi(e) = 0.5 * (s(dual.shared(e, 0)) + s(dual.shared(e, 1)));
  }
  return phi;
}

Eigen::VectorXd shear_from_vertex(const Faces& faces, const Eigen::VectorXd& s) {
  Eigen::VectorXd psi(faces.rows());
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    psi(f) = (s(faces(f, 0)) + s(faces(f, 1)) + s(faces(f, 2))) / 3.0;
  }
  return psi;
}

}  // namespace matdeform
