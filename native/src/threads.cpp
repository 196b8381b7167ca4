#include "matdeform/threads.hpp"

#include <atomic>
#include <stdexcept>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace matdeform {

namespace {
// One count for the whole process. (omp_set_num_threads sets a per-thread value: a thread
// started later, e.g. a Python thread, would still see the default.)
std::atomic<int> g_threads{0};  // 0: not set yet

int default_threads() {
#ifdef _OPENMP
  return omp_get_max_threads();  // OMP_NUM_THREADS, or the core count
#else
  return 1;
#endif
}
}  // namespace

void set_num_threads(int n) {
  if (n < 1) throw std::invalid_argument("num_threads must be >= 1");
  g_threads.store(n, std::memory_order_relaxed);
}

int num_threads() {
  int n = g_threads.load(std::memory_order_relaxed);
  if (n > 0) return n;
  int expected = 0;
  g_threads.compare_exchange_strong(expected, default_threads(), std::memory_order_relaxed);
  return g_threads.load(std::memory_order_relaxed);
}

}  // namespace matdeform
