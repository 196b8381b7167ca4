#include "convert.hpp"
#include "matdeform/frames.hpp"

namespace py = pybind11;
using namespace matdeform;

void bind_frames(py::module_& m) {
  m.def(
      "deformation_gradients",
      [](const Vertices& rest, const Vertices& deformed, const Faces& faces) {
        Matrix3Array T;
        {
          py::gil_scoped_release release;
          T = deformation_gradients(rest, deformed, faces);
        }
        return py_convert::from_matrices3(T);
      },
      py::arg("rest"), py::arg("deformed"), py::arg("faces"));
  m.def(
      "face_frame",
      [](const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
        return Eigen::Matrix3d(face_frame(a, b, c));
      },
      py::arg("a"), py::arg("b"), py::arg("c"));
}
