#include <string>

#include "convert.hpp"
#include "matdeform/pyramid_deformer.hpp"

namespace py = pybind11;
using namespace matdeform;

namespace {
py::dict to_dict(const PyramidCoordinates& pc) {
  py::dict d;
  d["offsets"] = py::array_t<int>(static_cast<py::ssize_t>(pc.offsets.size()), pc.offsets.data());
  d["neighbors"] =
      py::array_t<int>(static_cast<py::ssize_t>(pc.neighbors.size()), pc.neighbors.data());
  const auto slots = static_cast<py::ssize_t>(pc.alpha.size());
  d["alpha"] = py::array_t<double>(slots, pc.alpha.data());
  d["beta"] = py::array_t<double>(slots, pc.beta.data());
  d["length"] = py::array_t<double>(slots, pc.length.data());
  d["weight"] = py::array_t<double>(slots, pc.weight.data());
  d["normal"] = pc.normal;
  d["offset"] = pc.offset;
  d["height"] = pc.height;
  d["kind"] = py::array_t<signed char>(static_cast<py::ssize_t>(pc.kind.size()), pc.kind.data());
  return d;
}
}  // namespace

void bind_pyramid_deformer(py::module_& m) {
  m.def(
      "pyramid_coordinates",
      [](const Vertices& vertices, const Faces& faces) {
        PyramidCoordinates pc;
        {
          py::gil_scoped_release release;
          pc = pyramid_coordinates(vertices, faces);
        }
        return to_dict(pc);
      },
      py::arg("vertices"), py::arg("faces"));
  py::class_<PyramidDeformer>(m, "PyramidDeformer")
      .def(py::init(
               [](const Vertices& vertices, const Faces& faces, const std::vector<int>& control) {
                 py::gil_scoped_release release;
                 return std::make_unique<PyramidDeformer>(vertices, faces, control);
               }),
           py::arg("vertices"), py::arg("faces"), py::arg("control"))
      .def(
          "deform",
          [](PyramidDeformer& self, const Vertices& control_positions, int iterations, double tol,
             std::optional<Vertices> initial, double scale_weight,
             std::optional<py::function> progress, double progress_seconds,
             std::optional<Vectors3> rotation_vectors, int lbfgs_iterations) {
            PyramidSolveOptions o;
            o.max_lbfgs_iterations = lbfgs_iterations;
            o.progress_seconds = progress_seconds;
            if (progress) {
              // Called between iterations on this thread; the function outlives the call, so
              // the callback holds a pointer (copies of it need no reference count, no GIL).
              const py::function* f = &*progress;
              o.progress = [f](int iterations, double step) {
                py::gil_scoped_acquire gil;
                (*f)(iterations, step);
              };
            }
            o.max_iterations = iterations;
            o.tol = tol;
            o.scale_weight = scale_weight;
            o.initial = initial ? &*initial : nullptr;
            o.rotation_vectors = rotation_vectors ? &*rotation_vectors : nullptr;
            py::gil_scoped_release release;
            return self.deform(control_positions, o);
          },
          py::arg("control_positions"), py::arg("iterations"), py::arg("tol"), py::arg("initial"),
          py::arg("scale_weight"), py::arg("progress") = py::none(),
          py::arg("progress_seconds") = 0.1, py::arg("rotation_vectors") = py::none(),
          py::arg("lbfgs_iterations") = -1)
      .def(
          "start",
          [](const PyramidDeformer& self, const Vertices& control_positions,
             std::optional<Vectors3> rotation_vectors) {
            py::gil_scoped_release release;
            return self.start(control_positions, rotation_vectors ? &*rotation_vectors : nullptr);
          },
          py::arg("control_positions"), py::arg("rotation_vectors") = py::none())
      .def(
          "energy",
          [](const PyramidDeformer& self, const Vertices& X, double scale_weight) {
            Vertices g;
            double E;
            {
              py::gil_scoped_release release;
              E = self.energy(X, scale_weight, &g);
            }
            return py::make_tuple(E, g);
          },
          py::arg("positions"), py::arg("scale_weight"))
      .def(
          "reconstruct",
          [](const PyramidDeformer& self, const Vertices& X, bool stretch) {
            py::gil_scoped_release release;
            return self.reconstruct(X, stretch);
          },
          py::arg("positions"), py::arg("stretch"))
      .def_property_readonly(
          "coordinates", [](const PyramidDeformer& self) { return to_dict(self.coordinates()); })
      .def_property_readonly("last_iterations", &PyramidDeformer::last_iterations)
      .def_property_readonly("last_step", &PyramidDeformer::last_step)
      .def_property_readonly("last_steps", &PyramidDeformer::last_steps)
      .def_property_readonly("last_converged", &PyramidDeformer::last_converged)
      .def_property_readonly("last_energy", &PyramidDeformer::last_energy)
      .def_property_readonly("last_factorizations", &PyramidDeformer::last_factorizations)
      .def_property_readonly("last_lbfgs_iterations", &PyramidDeformer::last_lbfgs_iterations)
      .def_property_readonly("num_free", &PyramidDeformer::num_free)
      .def_property_readonly("num_passive", &PyramidDeformer::num_passive)
      .def_property_readonly("diagonal", &PyramidDeformer::diagonal);
}
