#include "simd.hpp"

#include <atomic>

namespace matdeform {

namespace {
std::atomic<bool> g_avx2_enabled{true};
}  // namespace

bool cpu_has_avx2_fma() {
#if MD_X86_DISPATCH
  static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  return has && g_avx2_enabled.load(std::memory_order_relaxed);
#else
  return false;
#endif
}

bool set_avx2_kernels_enabled(bool enabled) { return g_avx2_enabled.exchange(enabled); }

const char* simd_path() { return MD_VECTOR_EXT ? "vector extension" : "portable"; }

}  // namespace matdeform
