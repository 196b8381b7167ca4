// Thin bindings for learn.hpp; matdeform/learn.py validates and documents the public API.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <stdexcept>
#include <string>

#include "matdeform/learn.hpp"

namespace py = pybind11;
namespace md = matdeform;

namespace {

md::AxisFrame parse_frame(const std::string& frame) {
  if (frame == "rest") return md::AxisFrame::kRest;
  if (frame == "world") return md::AxisFrame::kWorldLogDifference;
  throw std::invalid_argument("frame must be 'rest' or 'world', got '" + frame + "'");
}

}  // namespace

void bind_learn(py::module_& m) {
  m.def(
      "learn_distortions",
      [](const md::Vertices& rest, const md::Faces& faces, const md::IndexPairs& pairs,
         const std::vector<md::Vertices>& poses, bool anisotropic, const std::string& frame) {
        md::Distortions d;
        const md::AxisFrame f = parse_frame(frame);
        {
          py::gil_scoped_release release;
          d = md::learn_distortions(rest, faces, pairs, poses, anisotropic, f);
        }
        return py::make_tuple(d.bend, d.shear);
      },
      py::arg("rest"), py::arg("faces"), py::arg("pairs"), py::arg("poses"), py::arg("anisotropic"),
      py::arg("frame"));
  m.def(
      "smooth_distortions",
      [](const md::RowMatrix& bend, const Eigen::VectorXd& shear, const md::IndexPairs& pairs,
         int passes) {
        md::Distortions d{bend, shear};
        d = md::smooth_distortions(d, static_cast<int>(shear.size()), pairs, passes);
        return py::make_tuple(d.bend, d.shear);
      },
      py::arg("bend"), py::arg("shear"), py::arg("pairs"), py::arg("passes"));
  m.def(
      "rotation_spread",
      [](const md::Vertices& rest, const md::Faces& faces, const md::IndexPairs& pairs,
         const std::vector<md::Vertices>& poses, int passes) {
        py::gil_scoped_release release;
        return md::rotation_spread(rest, faces, pairs, poses, passes);
      },
      py::arg("rest"), py::arg("faces"), py::arg("pairs"), py::arg("poses"), py::arg("passes"));
  m.def(
      "stiffness_from_distortion",
      [](const md::RowMatrix& d, double eps, double clamp_percent, double sharpness) {
        md::StiffnessMap map;
        map.eps = eps;
        map.clamp_percent = clamp_percent;
        map.sharpness = sharpness;
        return md::stiffness_from_distortion(d, map);
      },
      py::arg("distortion"), py::arg("eps"), py::arg("clamp_percent"), py::arg("sharpness"));
}
