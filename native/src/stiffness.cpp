#include "matdeform/stiffness.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

namespace matdeform {

void check_stiffness(const double* x, Eigen::Index size, const char* name) {
  if (size == 0) return;
  double lo = x[0], hi = x[0];
  for (Eigen::Index i = 0; i < size; ++i) {
    if (!std::isfinite(x[i]) || !(x[i] > 0.0)) {
      throw std::invalid_argument(std::string(name) + ": stiffness must be finite and > 0");
    }
    lo = std::min(lo, x[i]);
    hi = std::max(hi, x[i]);
  }
  if (hi > kMaxStiffnessRatio * lo) {
    std::ostringstream msg;
    msg << name << ": stiffness ratio max/min = " << hi / lo << " is above 1e12; raise the "
        << "smallest values (only ratios matter)";
    throw std::invalid_argument(msg.str());
  }
}

Eigen::VectorXd bend_from_shear(const IndexPairs& pairs, const Eigen::VectorXd& shear) {
  check_indices(pairs, shear.size(), "pairs");
  Eigen::VectorXd phi(pairs.rows());
  for (Eigen::Index e = 0; e < pairs.rows(); ++e) {
    phi(e) = 0.5 * (shear(pairs(e, 0)) + shear(pairs(e, 1)));
  }
  return phi;
}

Eigen::VectorXd bend_from_vertex(const DualEdges& dual, const Eigen::VectorXd& s) {
  if (dual.pairs.rows() != dual.shared.rows()) {
    throw std::invalid_argument("shared: expected one row per dual edge");
  }
  check_indices(dual.shared, s.size(), "shared");
  Eigen::VectorXd phi(dual.shared.rows());
  for (Eigen::Index e = 0; e < dual.shared.rows(); ++e) {
    phi(e) = 0.5 * (s(dual.shared(e, 0)) + s(dual.shared(e, 1)));
  }
  return phi;
}

Eigen::VectorXd shear_from_vertex(const Faces& faces, const Eigen::VectorXd& s) {
  check_indices(faces, s.size(), "faces");
  Eigen::VectorXd psi(faces.rows());
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    psi(f) = (s(faces(f, 0)) + s(faces(f, 1)) + s(faces(f, 2))) / 3.0;
  }
  return psi;
}

}  // namespace matdeform
