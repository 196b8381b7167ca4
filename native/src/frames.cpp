#include "matdeform/frames.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <stdexcept>
#include <string>

#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"

namespace matdeform {

Eigen::Vector3d fourth_vertex(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                              const Eigen::Vector3d& c) {
  const Eigen::Vector3d n = (b - a).cross(c - a);
  const double len = n.norm();
  if (len == 0.0) return a;
  return a + n / std::sqrt(len);
}

Eigen::Matrix3d face_frame(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                           const Eigen::Vector3d& c) {
  Eigen::Matrix3d V;
  V.col(0) = b - a;
  V.col(1) = c - a;
  V.col(2) = fourth_vertex(a, b, c) - a;
  return V;
}

Matrix3Array deformation_gradients(const Vertices& rest, const Vertices& deformed,
                                   const Faces& faces) {
  if (rest.rows() != deformed.rows()) {
    throw std::invalid_argument("deformed must have as many vertices as rest");
  }
  validate_mesh(rest, faces);
  if (!deformed.allFinite()) throw std::invalid_argument("deformed: contains NaN or infinity");
  const Eigen::Index m = faces.rows();
  Matrix3Array out(static_cast<size_t>(m));
  bool degenerate = false;
  Eigen::Index bad = -1;
#pragma omp parallel for schedule(static) num_threads(num_threads()) if (m > 20000)
  for (Eigen::Index i = 0; i < m; ++i) {
    const int a = faces(i, 0), b = faces(i, 1), c = faces(i, 2);
    const Eigen::Matrix3d V = face_frame(rest.row(a), rest.row(b), rest.row(c));
    const Eigen::Matrix3d Vt = face_frame(deformed.row(a), deformed.row(b), deformed.row(c));
    Eigen::FullPivLU<Eigen::Matrix3d> lu(V);
    if (!lu.isInvertible()) {
#pragma omp critical
      {
        degenerate = true;
        bad = i;
      }
      out[static_cast<size_t>(i)].setIdentity();
      continue;
    }
    out[static_cast<size_t>(i)] = Vt * lu.inverse();
  }
  if (degenerate) {
    throw std::invalid_argument(
        "rest face " + std::to_string(bad) +
        " is degenerate (zero area); its deformation gradient is undefined");
  }
  return out;
}

}  // namespace matdeform
