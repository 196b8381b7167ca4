// numpy <-> core conversions shared by the bind_*.cpp files. Shapes are validated in Python;
// these only check what is needed to stay memory safe.
#pragma once

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <stdexcept>

#include "matdeform/types.hpp"

namespace matdeform::py_convert {

namespace py = pybind11;
using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;
using RowMatrix3 = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;
using RowMap3 = Eigen::Map<const RowMatrix3>;

// (k,3,3) numpy -> k matrices.
inline Matrix3Array to_matrices3(const DoubleArray& a) {
  if (a.ndim() != 3 || a.shape(1) != 3 || a.shape(2) != 3) {
    throw std::invalid_argument("expected an array of shape (k,3,3)");
  }
  Matrix3Array out(static_cast<size_t>(a.shape(0)));
  const double* src = a.data();
  for (size_t i = 0; i < out.size(); ++i) out[i] = RowMap3(src + 9 * i);
  return out;
}

// k matrices -> (k,3,3) numpy.
inline py::array_t<double> from_matrices3(const Matrix3Array& m) {
  py::array_t<double> out({static_cast<py::ssize_t>(m.size()), py::ssize_t{3}, py::ssize_t{3}});
  double* dst = out.mutable_data();
  for (size_t i = 0; i < m.size(); ++i) Eigen::Map<RowMatrix3>(dst + 9 * i) = m[i];
  return out;
}

}  // namespace matdeform::py_convert
