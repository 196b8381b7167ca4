#include "convert.hpp"
#include "matdeform/threads.hpp"

namespace py = pybind11;

void bind_threads(py::module_& m) {
  m.def("set_num_threads", &matdeform::set_num_threads, py::arg("n"));
  m.def("num_threads", &matdeform::num_threads);
}
