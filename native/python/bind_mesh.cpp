#include "convert.hpp"
#include "matdeform/mesh.hpp"

namespace py = pybind11;
using namespace matdeform;

void bind_mesh(py::module_& m) {
  m.def(
      "dual_edges",
      [](const Faces& faces) {
        DualEdges d = dual_edges(faces);
        return py::make_tuple(std::move(d.pairs), std::move(d.shared));
      },
      py::arg("faces"), "(pairs (E,2), shared (E,2)) for faces (m,3)");
  m.def("validate_mesh", &validate_mesh, py::arg("vertices"), py::arg("faces"));
  m.def("double_areas", &double_areas, py::arg("vertices"), py::arg("faces"));
  m.def(
      "face_components",
      [](int num_faces, const IndexPairs& pairs) {
        int count = 0;
        std::vector<int> label = face_components(num_faces, pairs, &count);
        return py::make_tuple(
            py::array_t<int>(static_cast<py::ssize_t>(label.size()), label.data()), count);
      },
      py::arg("num_faces"), py::arg("pairs"));
  m.def("mesh_edges", &mesh_edges, py::arg("faces"), "(E,2) undirected edges a < b, sorted");
}
