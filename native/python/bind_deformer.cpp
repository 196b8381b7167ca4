#include "convert.hpp"
#include "matdeform/deformer.hpp"

namespace py = pybind11;
using namespace matdeform;

namespace {
// (k,3,3) or (k,4,4) as k 4x4 matrices; affine: whether they were 4x4.
std::vector<Eigen::Matrix4d> anchor_transforms(const py_convert::DoubleArray& transforms,
                                               bool* affine) {
  if (transforms.ndim() != 3 || transforms.shape(1) != transforms.shape(2) ||
      (transforms.shape(1) != 3 && transforms.shape(1) != 4)) {
    throw std::invalid_argument("transforms must have shape (k,3,3) or (k,4,4)");
  }
  *affine = transforms.shape(1) == 4;
  const int s = *affine ? 4 : 3;
  std::vector<Eigen::Matrix4d> T(static_cast<size_t>(transforms.shape(0)),
                                 Eigen::Matrix4d::Identity());
  auto r = transforms.unchecked<3>();
  for (size_t a = 0; a < T.size(); ++a)
    for (int x = 0; x < s; ++x)
      for (int y = 0; y < s; ++y) T[a](x, y) = r(static_cast<py::ssize_t>(a), x, y);
  return T;
}
}  // namespace

void bind_deformer(py::module_& m) {
  py::class_<MaterialDeformer>(m, "MaterialDeformer")
      .def(py::init([](const Vertices& vertices, const Faces& faces, const AnchorList& anchors,
                       const Eigen::VectorXd& shear, const RowMatrix& bend,
                       std::optional<std::vector<int>> pinned,
                       std::optional<std::vector<int>> region, const Eigen::Matrix3d& axes) {
             DeformerOptions options;
             options.pinned = std::move(pinned);
             options.region = std::move(region);
             options.axes = axes;
             py::gil_scoped_release release;
             return std::make_unique<MaterialDeformer>(vertices, faces, anchors, shear, bend,
                                                       options);
           }),
           py::arg("vertices"), py::arg("faces"), py::arg("anchors"), py::arg("shear"),
           py::arg("bend"), py::arg("pinned") = py::none(), py::arg("region") = py::none(),
           py::arg("axes") = Eigen::Matrix3d::Identity())
      .def(
          "deform",
          [](const MaterialDeformer& self, const py_convert::DoubleArray& transforms,
             std::optional<Vertices> pinned_positions, std::optional<Vectors3> rotation_vectors) {
            bool affine = false;
            const std::vector<Eigen::Matrix4d> T = anchor_transforms(transforms, &affine);
            py::gil_scoped_release release;
            return self.deform(T, affine, pinned_positions ? &*pinned_positions : nullptr,
                               rotation_vectors ? &*rotation_vectors : nullptr);
          },
          py::arg("transforms"), py::arg("pinned_positions") = py::none(),
          py::arg("rotation_vectors") = py::none())
      .def(
          "deform_into",
          [](const MaterialDeformer& self, const py_convert::DoubleArray& transforms,
             std::optional<Vertices> pinned_positions, py::array out,
             std::optional<Vectors3> rotation_vectors) {
            // Not array_t<float>: that would cast a wrong array into a copy and write there.
            if (!py::isinstance<py::array_t<float>>(out) || out.ndim() != 2 ||
                out.shape(0) != self.num_vertices() || out.shape(1) != 3 ||
                !(out.flags() & py::array::c_style) || !out.writeable()) {
              throw std::invalid_argument(
                  "out: expected a writeable C-contiguous float32 array of shape (n,3)");
            }
            bool affine = false;
            const std::vector<Eigen::Matrix4d> T = anchor_transforms(transforms, &affine);
            float* dst = static_cast<float*>(out.mutable_data());
            py::gil_scoped_release release;
            self.deform(T, affine, pinned_positions ? &*pinned_positions : nullptr, dst,
                        rotation_vectors ? &*rotation_vectors : nullptr);
          },
          py::arg("transforms"), py::arg("pinned_positions"), py::arg("out"),
          py::arg("rotation_vectors") = py::none())
      .def_property_readonly("weights", &MaterialDeformer::weights)
      .def("axis_weights", &MaterialDeformer::axis_weights, py::arg("axis"))
      .def_property_readonly("anisotropic", &MaterialDeformer::anisotropic)
      .def_property_readonly("num_region_vertices", &MaterialDeformer::num_region_vertices)
      // Tests only: whether the last deform() reached the threaded substitution.
      .def_property_readonly("substitution_threads", &MaterialDeformer::substitution_threads)
      .def_property_readonly("face_transforms", [](const MaterialDeformer& self) {
        Matrix3Array T;
        {
          py::gil_scoped_release release;  // may wait for a deform() on another thread
          T = self.face_transforms();
        }
        return py_convert::from_matrices3(T);
      });
}
