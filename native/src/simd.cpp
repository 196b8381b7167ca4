#include "simd.hpp"

#include <algorithm>
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

namespace {

// Written out because Eigen's products would be the baseline build's two lanes (and its
// matrix products would run on OpenMP threads, fighting the task pool's workers).
MD_ALWAYS_INLINE void dot2_body(const double* a, const double* b, const double* c, std::ptrdiff_t n,
                                double* ab, double* ac) {
  Vec4d b0 = {0, 0, 0, 0}, b1 = b0, c0 = b0, c1 = b0;
  std::ptrdiff_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const Vec4d a0 = MD_LD4(a + i), a1 = MD_LD4(a + i + 4);
    b0 += a0 * MD_LD4(b + i), b1 += a1 * MD_LD4(b + i + 4);
    c0 += a0 * MD_LD4(c + i), c1 += a1 * MD_LD4(c + i + 4);
  }
  const Vec4d sb = b0 + b1, sc = c0 + c1;
  double rb = (sb[0] + sb[1]) + (sb[2] + sb[3]), rc = (sc[0] + sc[1]) + (sc[2] + sc[3]);
  for (; i < n; ++i) rb += a[i] * b[i], rc += a[i] * c[i];
  *ab = rb, *ac = rc;
}
void dot2_base(const double* a, const double* b, const double* c, std::ptrdiff_t n, double* ab,
               double* ac) {
  dot2_body(a, b, c, n, ab, ac);
}
MD_TARGET_AVX2 void dot2_avx2(const double* a, const double* b, const double* c, std::ptrdiff_t n,
                              double* ab, double* ac) {
  dot2_body(a, b, c, n, ab, ac);
}

MD_ALWAYS_INLINE void subtract_body(const double* cols, std::ptrdiff_t ld, int k,
                                    const double* gamma, const double* base, double* out,
                                    std::ptrdiff_t n) {
  constexpr std::ptrdiff_t kBlock = 512;  // out stays in L1 while the columns stream past
  for (std::ptrdiff_t i0 = 0; i0 < n; i0 += kBlock) {
    const std::ptrdiff_t i1 = std::min(n, i0 + kBlock);
    std::copy(base + i0, base + i1, out + i0);
    for (int j = 0; j < k; ++j) {
      const double* col = cols + j * ld;
      const double gj = gamma[j];
      std::ptrdiff_t i = i0;
      for (; i + 4 <= i1; i += 4) {
        *reinterpret_cast<Vec4d*>(out + i) = MD_LD4(out + i) - gj * MD_LD4(col + i);
      }
      for (; i < i1; ++i) out[i] -= gj * col[i];
    }
  }
}
void subtract_base(const double* cols, std::ptrdiff_t ld, int k, const double* gamma,
                   const double* base, double* out, std::ptrdiff_t n) {
  subtract_body(cols, ld, k, gamma, base, out, n);
}
MD_TARGET_AVX2 void subtract_avx2(const double* cols, std::ptrdiff_t ld, int k, const double* gamma,
                                  const double* base, double* out, std::ptrdiff_t n) {
  subtract_body(cols, ld, k, gamma, base, out, n);
}

}  // namespace

void dot2(const double* a, const double* b, const double* c, std::ptrdiff_t n, double* ab,
          double* ac) {
  (cpu_has_avx2_fma() ? dot2_avx2 : dot2_base)(a, b, c, n, ab, ac);
}

void subtract_columns(const double* cols, std::ptrdiff_t ld, int k, const double* gamma,
                      const double* base, double* out, std::ptrdiff_t n) {
  (cpu_has_avx2_fma() ? subtract_avx2 : subtract_base)(cols, ld, k, gamma, base, out, n);
}

const char* simd_path() { return MD_VECTOR_EXT ? "vector extension" : "portable"; }

}  // namespace matdeform
