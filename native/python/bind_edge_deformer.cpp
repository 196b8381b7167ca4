#include "convert.hpp"
#include "matdeform/edge_deformer.hpp"

namespace py = pybind11;
using namespace matdeform;

void bind_edge_deformer(py::module_& m) {
  py::class_<EdgeDeformer>(m, "EdgeDeformer")
      .def(py::init([](const Vertices& vertices, const Faces& faces,
                       const std::vector<int>& constrained, double stretch, double bend,
                       std::optional<Eigen::VectorXd> edge_weight,
                       std::optional<Vertices> direction, std::optional<std::vector<int>> anchors) {
             EdgeDeformerOptions o;
             o.stretch = stretch;
             o.bend = bend;
             if (edge_weight) o.edge_weight = std::move(*edge_weight);
             if (direction) o.direction = std::move(*direction);
             if (anchors) o.anchors = std::move(*anchors);
             py::gil_scoped_release release;
             return std::make_unique<EdgeDeformer>(vertices, faces, constrained, o);
           }),
           py::arg("vertices"), py::arg("faces"), py::arg("constrained"), py::arg("stretch"),
           py::arg("bend"), py::arg("edge_weight") = py::none(), py::arg("direction") = py::none(),
           py::arg("anchors") = py::none())
      .def(
          "solve",
          [](EdgeDeformer& self, const Vertices& constrained_positions, int iterations, double tol,
             double p_stretch, double p_bend, const Eigen::Vector3d& gravity,
             std::optional<Vertices> initial, double relaxation,
             std::optional<Vectors3> rotation_vectors) {
            EdgeSolveOptions o;
            o.iterations = iterations;
            o.tol = tol;
            o.p_stretch = p_stretch;
            o.p_bend = p_bend;
            o.gravity = gravity;
            o.relaxation = relaxation;
            py::gil_scoped_release release;
            return self.solve(constrained_positions, o, initial ? &*initial : nullptr,
                              rotation_vectors ? &*rotation_vectors : nullptr);
          },
          py::arg("constrained_positions"), py::arg("iterations"), py::arg("tol"),
          py::arg("p_stretch"), py::arg("p_bend"), py::arg("gravity"),
          py::arg("initial") = py::none(), py::arg("relaxation") = 1.0,
          py::arg("rotation_vectors") = py::none())
      .def_property_readonly("last_iterations", &EdgeDeformer::last_iterations)
      .def_property_readonly("last_move", &EdgeDeformer::last_move)
      .def_property_readonly("last_error", &EdgeDeformer::last_error)
      .def_property_readonly("last_converged", &EdgeDeformer::last_converged)
      .def_property_readonly("factorizations", &EdgeDeformer::factorizations)
      .def_property_readonly("edges", &EdgeDeformer::edges)
      .def_property_readonly("opposite", &EdgeDeformer::opposite)
      .def_property_readonly("bend_coefficients", &EdgeDeformer::bend_coefficients)
      .def_property_readonly("anisotropy", &EdgeDeformer::anisotropy)
      .def_property_readonly("num_free", &EdgeDeformer::num_free)
      .def_property_readonly("num_anchors", &EdgeDeformer::num_anchors)
      .def_property_readonly("anchors", &EdgeDeformer::anchors)
      .def_property_readonly("diagonal", &EdgeDeformer::diagonal);
  m.def("factorization_count", &EdgeDeformer::process_factorizations,
        "sparse Cholesky factorisations done in this process (all solvers)");
}
