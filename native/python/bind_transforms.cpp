#include "convert.hpp"
#include "matdeform/transforms.hpp"

namespace py = pybind11;
using namespace matdeform;

void bind_transforms(py::module_& m) {
  m.attr("ROTATION_VECTOR_TOLERANCE") = kRotationVectorTolerance;
  m.def(
      "transform_log",
      [](const Eigen::Matrix3d& M) {
        const TransformLog L = transform_log(M);
        return py::make_tuple(Eigen::Matrix3d(L.log_stretch), Eigen::Vector3d(L.rotation));
      },
      py::arg("matrix"));
  m.def(
      "transform_exp",
      [](const Eigen::Matrix3d& log_stretch, const Eigen::Vector3d& rotation) {
        TransformLog L;
        L.log_stretch = 0.5 * (log_stretch + log_stretch.transpose());
        L.rotation = rotation;
        L.similarity = false;
        return Eigen::Matrix3d(transform_exp(L));
      },
      py::arg("log_stretch"), py::arg("rotation"));
  m.def(
      "unwrap_rotations",
      [](const py_convert::DoubleArray& rotations, int k, std::optional<Vectors3> start) {
        // rotations: (N*k,3,3), frame-major; start: (k,3) or None. Returns (N*k,3).
        const Matrix3Array R = py_convert::to_matrices3(rotations);
        std::vector<Eigen::Vector3d> s;
        if (start) {
          for (Eigen::Index a = 0; a < start->rows(); ++a) s.emplace_back(start->row(a));
        }
        std::vector<Eigen::Vector3d> v;
        {
          py::gil_scoped_release release;
          v = unwrap_rotations(R, k, s);
        }
        Vectors3 out(static_cast<Eigen::Index>(v.size()), 3);
        for (size_t i = 0; i < v.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = v[i];
        return out;
      },
      py::arg("rotations"), py::arg("k"), py::arg("start") = py::none());
  m.def(
      "polar_decompose",
      [](const Eigen::Matrix3d& M) {
        Eigen::Matrix3d S, R;
        polar_decompose(M, &S, &R);
        return py::make_tuple(S, R);
      },
      py::arg("matrix"));
  m.def(
      "blend_transforms",
      [](const py_convert::DoubleArray& transforms, const RowMatrix& weights) {
        const Matrix3Array T = py_convert::to_matrices3(transforms);
        std::vector<TransformLog> logs;
        logs.reserve(T.size());
        for (const auto& M : T) logs.push_back(transform_log(M));
        Matrix3Array out;
        {
          py::gil_scoped_release release;
          blend_all(logs, weights, &out);
        }
        return py_convert::from_matrices3(out);
      },
      py::arg("transforms"), py::arg("weights"));
}
