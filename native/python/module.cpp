// matdeform._core: thin bindings over the C++ core. Validation with readable messages lives in
// the Python package; the core re-checks and throws std::invalid_argument (-> ValueError).
#include <pybind11/pybind11.h>

namespace py = pybind11;

void bind_mesh(py::module_& m);
void bind_frames(py::module_& m);
void bind_transforms(py::module_& m);
void bind_weights(py::module_& m);
void bind_stiffness(py::module_& m);
void bind_deformer(py::module_& m);
void bind_threads(py::module_& m);
void bind_learn(py::module_& m);
void bind_pyramid_deformer(py::module_& m);
void bind_edge_deformer(py::module_& m);
void bind_pose_space_deformer(py::module_& m);

PYBIND11_MODULE(_core, m) {
  m.doc() = "Material-aware mesh deformation core (C++)";
  bind_mesh(m);
  bind_frames(m);
  bind_transforms(m);
  bind_weights(m);
  bind_stiffness(m);
  bind_deformer(m);
  bind_threads(m);
  bind_learn(m);
  bind_pyramid_deformer(m);
  bind_edge_deformer(m);
  bind_pose_space_deformer(m);
}
