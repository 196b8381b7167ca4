#include "convert.hpp"
#include "matdeform/transforms.hpp"

namespace py = pybind11;
using namespace matdeform;

void bind_transforms(py::module_& m) {
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
