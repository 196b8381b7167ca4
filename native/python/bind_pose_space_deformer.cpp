// Thin bindings for pose_space_deformer.hpp; matdeform/pose_space.py validates and documents.
#include <string>

#include "convert.hpp"
#include "matdeform/pose_space_deformer.hpp"

namespace py = pybind11;
using namespace matdeform;

namespace {

using Pairs = std::vector<std::array<int, 2>>;

// rotations (r,3,3) or None -> matrices.
std::optional<Matrix3Array> to_rotations(const std::optional<py_convert::DoubleArray>& a) {
  if (!a) return std::nullopt;
  return py_convert::to_matrices3(*a);
}

}  // namespace

void bind_pose_space_deformer(py::module_& m) {
  py::class_<PoseSpaceDeformer>(m, "PoseSpaceDeformer")
      .def(py::init([](const Vertices& vertices, const Faces& faces,
                       const std::vector<Vertices>& examples,
                       const std::vector<std::vector<int>>& handles, std::optional<int> frame,
                       const Pairs& rotational, std::optional<int> coarse,
                       const std::vector<int>& frozen, double position_weight,
                       double rotation_weight, double joint_weight, bool handle_rotations,
                       double weight_regularization, bool convex_weights, int transfer_neighbors,
                       const std::string& rotation_energy, int rotation_iterations,
                       double reliability_angle, double orientation_weight, int gauge_steps,
                       bool area_weights, double rotation_tolerance) {
             PoseSpaceOptions o;
             o.frame = frame;
             o.rotational = rotational;
             o.coarse_faces = coarse;
             o.frozen = frozen;
             o.position_weight = position_weight;
             o.rotation_weight = rotation_weight;
             o.joint_weight = joint_weight;
             o.handle_rotations = handle_rotations;
             o.weight_regularization = weight_regularization;
             o.convex_weights = convex_weights;
             o.transfer_neighbors = transfer_neighbors;
             if (rotation_energy == "geodesic") {
               o.rotation_energy = PoseSpaceOptions::RotationEnergy::kGeodesic;
             } else if (rotation_energy != "chordal") {
               throw std::invalid_argument("rotation_energy: expected 'chordal' or 'geodesic'");
             }
             o.rotation_iterations = rotation_iterations;
             o.reliability_angle = reliability_angle;
             o.orientation_weight = orientation_weight;
             o.gauge_steps = gauge_steps;
             o.area_weights = area_weights;
             o.rotation_tolerance = rotation_tolerance;
             py::gil_scoped_release release;
             return std::make_unique<PoseSpaceDeformer>(vertices, faces, examples, handles, o);
           }),
           py::arg("vertices"), py::arg("faces"), py::arg("examples"), py::arg("handles"),
           py::arg("frame"), py::arg("rotational"), py::arg("coarse"), py::arg("frozen"),
           py::arg("position_weight"), py::arg("rotation_weight"), py::arg("joint_weight"),
           py::arg("handle_rotations"), py::arg("weight_regularization"), py::arg("convex_weights"),
           py::arg("transfer_neighbors"), py::arg("rotation_energy") = "chordal",
           py::arg("rotation_iterations") = 10, py::arg("reliability_angle") = 0.5,
           py::arg("orientation_weight") = 1.0, py::arg("gauge_steps") = 2,
           py::arg("area_weights") = false, py::arg("rotation_tolerance") = 1e-6)
      .def(
          "deform",
          [](const PoseSpaceDeformer& self, const std::vector<Vertices>& handle_positions,
             const std::optional<py_convert::DoubleArray>& rotations,
             const std::optional<Eigen::Matrix4d>& frame_transform) {
            const std::optional<Matrix3Array> rot = to_rotations(rotations);
            py::gil_scoped_release release;
            return self.deform(handle_positions, rot ? &*rot : nullptr,
                               frame_transform ? &*frame_transform : nullptr);
          },
          py::arg("handle_positions"), py::arg("rotations") = py::none(),
          py::arg("frame_transform") = py::none())
      .def(
          "pose_weights",
          [](const PoseSpaceDeformer& self, const std::vector<Vertices>& handle_positions,
             const std::optional<py_convert::DoubleArray>& rotations,
             const std::optional<Eigen::Matrix4d>& frame_transform) {
            const std::optional<Matrix3Array> rot = to_rotations(rotations);
            return self.pose_weights(handle_positions, rot ? &*rot : nullptr,
                                     frame_transform ? &*frame_transform : nullptr);
          },
          py::arg("handle_positions"), py::arg("rotations") = py::none(),
          py::arg("frame_transform") = py::none())
      // Without the GIL while waiting: another thread's deform() holds the deformer's lock.
      .def_property_readonly("example_weights",
                             [](const PoseSpaceDeformer& self) {
                               py::gil_scoped_release release;
                               return self.example_weights();
                             })
      .def_property_readonly("last_stats",
                             [](const PoseSpaceDeformer& self) {
                               const PoseSpaceStats s = [&] {
                                 py::gil_scoped_release release;
                                 return self.last_stats();
                               }();
                               py::dict d;
                               d["iterations_first"] = s.iterations_first;
                               d["iterations_second"] = s.iterations_second;
                               d["ms_weights"] = s.ms_weights;
                               d["ms_blend"] = s.ms_blend;
                               d["ms_rotations"] = s.ms_rotations;
                               d["ms_positions"] = s.ms_positions;
                               d["ms_fit"] = s.ms_fit;
                               d["ms_transfer"] = s.ms_transfer;
                               d["ms_gauge"] = s.ms_gauge;
                               d["ms_chordal"] = s.ms_chordal;
                               return d;
                             })
      .def_property_readonly("multiresolution", &PoseSpaceDeformer::multiresolution)
      .def_property_readonly("solve_faces", &PoseSpaceDeformer::solve_faces)
      .def_property_readonly("solve_vertices", &PoseSpaceDeformer::solve_vertices);
}
