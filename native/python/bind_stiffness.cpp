#include "convert.hpp"
#include "matdeform/stiffness.hpp"

namespace py = pybind11;
using namespace matdeform;

void bind_stiffness(py::module_& m) {
  m.def("bend_from_shear", &bend_from_shear, py::arg("pairs"), py::arg("shear"));
  m.def(
      "bend_from_vertex",
      [](const IndexPairs& pairs, const IndexPairs& shared, const Eigen::VectorXd& s) {
        return bend_from_vertex(DualEdges{pairs, shared}, s);
      },
      py::arg("pairs"), py::arg("shared"), py::arg("stiffness"));
  m.def("shear_from_vertex", &shear_from_vertex, py::arg("faces"), py::arg("stiffness"));
}
