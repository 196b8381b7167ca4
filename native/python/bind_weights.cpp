#include "convert.hpp"
#include "matdeform/weights.hpp"

namespace py = pybind11;
using namespace matdeform;

void bind_weights(py::module_& m) {
  m.def(
      "harmonic_weights",
      [](int num_faces, const IndexPairs& pairs, const Eigen::VectorXd& phi,
         const AnchorList& anchors) {
        py::gil_scoped_release release;
        return harmonic_weights(num_faces, pairs, phi, anchors);
      },
      py::arg("num_faces"), py::arg("pairs"), py::arg("phi"), py::arg("anchors"));
}
