#include "matdeform/threads.hpp"

#include <stdexcept>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace matdeform {

void set_num_threads(int n) {
  if (n < 1) throw std::invalid_argument("num_threads must be >= 1");
#ifdef _OPENMP
  omp_set_num_threads(n);
#endif
}

int num_threads() {
#ifdef _OPENMP
  return omp_get_max_threads();
#else
  return 1;
#endif
}

}  // namespace matdeform
