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
// matrix products would run on OpenMP threads, fighting the task pool's workers). Each column's
// sums are formed in the same order whether it is taken alone or in a pair: two accumulators
// per product (entries i mod 8 < 4 and >= 4), then the tail in order.
MD_ALWAYS_INLINE void dot2_one(const double* a, const double* b, const double* c, std::ptrdiff_t n,
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
// Two columns a, d per read of b and c: the shared operands are loaded once for both (at 5k
// vertices the history is in cache and the pass is bound by loads, not by memory).
MD_ALWAYS_INLINE void dot2_pair(const double* a, const double* d, const double* b, const double* c,
                                std::ptrdiff_t n, double* out_b, double* out_c) {
  Vec4d b0 = {0, 0, 0, 0}, b1 = b0, c0 = b0, c1 = b0, e0 = b0, e1 = b0, f0 = b0, f1 = b0;
  std::ptrdiff_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const Vec4d x0 = MD_LD4(b + i), x1 = MD_LD4(b + i + 4);
    const Vec4d y0 = MD_LD4(c + i), y1 = MD_LD4(c + i + 4);
    const Vec4d a0 = MD_LD4(a + i), a1 = MD_LD4(a + i + 4);
    b0 += a0 * x0, b1 += a1 * x1, c0 += a0 * y0, c1 += a1 * y1;
    const Vec4d d0 = MD_LD4(d + i), d1 = MD_LD4(d + i + 4);
    e0 += d0 * x0, e1 += d1 * x1, f0 += d0 * y0, f1 += d1 * y1;
  }
  const Vec4d sb = b0 + b1, sc = c0 + c1, se = e0 + e1, sf = f0 + f1;
  double rb = (sb[0] + sb[1]) + (sb[2] + sb[3]), rc = (sc[0] + sc[1]) + (sc[2] + sc[3]);
  double re = (se[0] + se[1]) + (se[2] + se[3]), rf = (sf[0] + sf[1]) + (sf[2] + sf[3]);
  for (; i < n; ++i) {
    rb += a[i] * b[i], rc += a[i] * c[i];
    re += d[i] * b[i], rf += d[i] * c[i];
  }
  out_b[0] = rb, out_c[0] = rc, out_b[1] = re, out_c[1] = rf;
}
MD_ALWAYS_INLINE void dot2_columns_body(const double* cols, std::ptrdiff_t ld, int k,
                                        const double* b, const double* c, std::ptrdiff_t n,
                                        double* ab, double* ac) {
  int j = 0;
  for (; j + 2 <= k; j += 2) dot2_pair(cols + j * ld, cols + (j + 1) * ld, b, c, n, ab + j, ac + j);
  if (j < k) dot2_one(cols + j * ld, b, c, n, ab + j, ac + j);
}
void dot2_columns_base(const double* cols, std::ptrdiff_t ld, int k, const double* b,
                       const double* c, std::ptrdiff_t n, double* ab, double* ac) {
  dot2_columns_body(cols, ld, k, b, c, n, ab, ac);
}
MD_TARGET_AVX2 void dot2_columns_avx2(const double* cols, std::ptrdiff_t ld, int k, const double* b,
                                      const double* c, std::ptrdiff_t n, double* ab, double* ac) {
  dot2_columns_body(cols, ld, k, b, c, n, ab, ac);
}

// Each output entry is base - gamma_0 col_0 - gamma_1 col_1 - ..., subtracted in that order (as
// one pass per column would), but kept in registers across the columns: one load per column
// entry instead of a load, a load and a store.
MD_ALWAYS_INLINE void subtract_body(const double* cols, std::ptrdiff_t ld, int k,
                                    const double* gamma, const double* base, double* out,
                                    std::ptrdiff_t n) {
  std::ptrdiff_t i = 0;
  for (; i + 16 <= n; i += 16) {
    Vec4d o0 = MD_LD4(base + i), o1 = MD_LD4(base + i + 4), o2 = MD_LD4(base + i + 8),
          o3 = MD_LD4(base + i + 12);
    for (int j = 0; j < k; ++j) {
      const double* col = cols + j * ld + i;
      const double gj = gamma[j];
      o0 = o0 - gj * MD_LD4(col), o1 = o1 - gj * MD_LD4(col + 4);
      o2 = o2 - gj * MD_LD4(col + 8), o3 = o3 - gj * MD_LD4(col + 12);
    }
    *reinterpret_cast<Vec4d*>(out + i) = o0, *reinterpret_cast<Vec4d*>(out + i + 4) = o1;
    *reinterpret_cast<Vec4d*>(out + i + 8) = o2, *reinterpret_cast<Vec4d*>(out + i + 12) = o3;
  }
  for (; i + 4 <= n; i += 4) {
    Vec4d o = MD_LD4(base + i);
    for (int j = 0; j < k; ++j) o = o - gamma[j] * MD_LD4(cols + j * ld + i);
    *reinterpret_cast<Vec4d*>(out + i) = o;
  }
  // The last entries column by column: with the columns innermost GCC pairs the products in
  // vector registers and subtracts them unfused, which would change the bits.
  const std::ptrdiff_t tail = i;
  for (; i < n; ++i) out[i] = base[i];
  for (int j = 0; j < k; ++j) {
    for (i = tail; i < n; ++i) out[i] -= gamma[j] * cols[j * ld + i];
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

void dot2_columns(const double* cols, std::ptrdiff_t ld, int k, const double* b, const double* c,
                  std::ptrdiff_t n, double* ab, double* ac) {
  (cpu_has_avx2_fma() ? dot2_columns_avx2 : dot2_columns_base)(cols, ld, k, b, c, n, ab, ac);
}

void subtract_columns(const double* cols, std::ptrdiff_t ld, int k, const double* gamma,
                      const double* base, double* out, std::ptrdiff_t n) {
  (cpu_has_avx2_fma() ? subtract_avx2 : subtract_base)(cols, ld, k, gamma, base, out, n);
}

const char* simd_path() { return MD_VECTOR_EXT ? "vector extension" : "portable"; }

}  // namespace matdeform
