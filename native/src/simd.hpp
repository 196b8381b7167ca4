// Private: the per-pose kernels are built twice, for baseline x86-64 (what the wheel targets) and
// for AVX2+FMA, and the second is picked at run time where the CPU has it.
//
// Why by hand: GCC's target_clones("avx2") left the 4-wide row updates scalar (no FMA, no ymm),
// while explicit vector types give one ymm FMA per factor entry, about 35 % less time for the
// substitution on the project's VM. A kernel body is written once as an always-inline function
// and instantiated inside two wrappers, so each copy is compiled for its wrapper's ISA.
//
// Vec4d is chosen at compile time:
//   - GCC and Clang: their vector extension (one ymm register with AVX2, two xmm or NEON
//     registers otherwise); on x86-64 the AVX2+FMA copies are added and dispatched.
//   - any other compiler (MSVC), or MATDEFORM_PORTABLE_SIMD defined (the CMake option of the
//     same name, which the test command builds once): a plain struct of four doubles with the
//     same operators, left to the optimiser, and no AVX2 copies.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

#if (defined(__GNUC__) || defined(__clang__)) && !defined(MATDEFORM_PORTABLE_SIMD)
#define MD_VECTOR_EXT 1
#else
#define MD_VECTOR_EXT 0
#endif

#if MD_VECTOR_EXT && defined(__x86_64__)
#define MD_X86_DISPATCH 1
#define MD_TARGET_AVX2 __attribute__((target("avx2,fma")))
#else
#define MD_X86_DISPATCH 0
#define MD_TARGET_AVX2
#endif

#if defined(__GNUC__) || defined(__clang__)
#define MD_ALWAYS_INLINE inline __attribute__((always_inline))
#define MD_MAY_ALIAS __attribute__((may_alias))
#define MD_PREFETCH(p) __builtin_prefetch(p)
#elif defined(_MSC_VER)
#define MD_ALWAYS_INLINE __forceinline
#define MD_MAY_ALIAS
#define MD_PREFETCH(p) ((void)(p))
#else
#define MD_ALWAYS_INLINE inline
#define MD_MAY_ALIAS
#define MD_PREFETCH(p) ((void)(p))
#endif

namespace matdeform {

#if MD_VECTOR_EXT

// Four doubles (x, y, z, pad), unaligned and allowed to alias double arrays.
typedef double Vec4d __attribute__((vector_size(32), aligned(8), may_alias));
// Their bit patterns, for building doubles from integer fields (exp4): a cast between the two,
// (Vec4u)x, keeps the bits.
typedef std::uint64_t Vec4u __attribute__((vector_size(32), aligned(8)));
// Lane masks, as comparisons of two Vec4d give them (all bits set where true).
typedef long long Vec4m __attribute__((vector_size(32), aligned(8), may_alias));

// Lane helpers, as macros: a function returning a vector warns about the ABI in the baseline
// build. MD_SELECT4(m, a, b) is lane-wise m ? a : b (m from a comparison, all bits set where
// true). MD_UNPACK_EVEN/ODD(a, b) give {a0, b0, a2, b2} and {a1, b1, a3, b3}, the pairings of a
// 4x4 transpose; MD_LOW/HIGH_HALVES(a, b) give {a0, a1, b0, b1} and {a2, a3, b2, b3}.
// __builtin_shufflevector is in Clang and in GCC >= 12.
#define MD_SELECT4(m, a, b) ((Vec4d)((((Vec4m)(a)) & (m)) | (((Vec4m)(b)) & ~(m))))
#define MD_UNPACK_EVEN(a, b) __builtin_shufflevector((a), (b), 0, 4, 2, 6)
#define MD_UNPACK_ODD(a, b) __builtin_shufflevector((a), (b), 1, 5, 3, 7)
#define MD_LOW_HALVES(a, b) __builtin_shufflevector((a), (b), 0, 1, 4, 5)
#define MD_HIGH_HALVES(a, b) __builtin_shufflevector((a), (b), 2, 3, 6, 7)

#else

// The same operators as GCC's vector types: lane-wise, a scalar operand applies to every lane,
// and braces initialise the lanes ({0, 0, 0, 0}). Standard layout, alignment of a double, so
// that double arrays can be read as Vec4d exactly as with the vector extension.
template <class T>
struct MD_MAY_ALIAS Lanes4 {
  typedef T Scalar;  // a non-deduced operand type: vec + 1 converts the 1 to the lane type
  T v[4];
  T& operator[](int i) { return v[i]; }
  const T& operator[](int i) const { return v[i]; }
  // (Vec4u)x keeps the bits, as a cast between GCC vector types of one size does. A conversion
  // function, not a constructor: the struct stays an aggregate, so braces still initialise it.
  template <class U>
  explicit operator Lanes4<U>() const {
    static_assert(sizeof(U) == sizeof(T), "a bit cast needs lanes of one size");
    Lanes4<U> out;
    std::memcpy(&out, v, sizeof out);
    return out;
  }
};

#define MD_LANES4_OP(op)                                                                     \
  template <class T>                                                                         \
  MD_ALWAYS_INLINE Lanes4<T> operator op(const Lanes4<T>& a, const Lanes4<T>& b) {           \
    return {{a.v[0] op b.v[0], a.v[1] op b.v[1], a.v[2] op b.v[2], a.v[3] op b.v[3]}};       \
  }                                                                                          \
  template <class T>                                                                         \
  MD_ALWAYS_INLINE Lanes4<T> operator op(const Lanes4<T>& a, typename Lanes4<T>::Scalar s) { \
    return {{a.v[0] op s, a.v[1] op s, a.v[2] op s, a.v[3] op s}};                           \
  }                                                                                          \
  template <class T>                                                                         \
  MD_ALWAYS_INLINE Lanes4<T> operator op(typename Lanes4<T>::Scalar s, const Lanes4<T>& a) { \
    return {{s op a.v[0], s op a.v[1], s op a.v[2], s op a.v[3]}};                           \
  }                                                                                          \
  template <class T>                                                                         \
  MD_ALWAYS_INLINE Lanes4<T>& operator op##=(Lanes4<T>& a, const Lanes4<T>& b) {             \
    return a = a op b;                                                                       \
  }                                                                                          \
  template <class T>                                                                         \
  MD_ALWAYS_INLINE Lanes4<T>& operator op##=(Lanes4<T>& a, typename Lanes4<T>::Scalar s) {   \
    return a = a op s;                                                                       \
  }
MD_LANES4_OP(+)
MD_LANES4_OP(-)
MD_LANES4_OP(*)
MD_LANES4_OP(/)
MD_LANES4_OP(&)
#undef MD_LANES4_OP

template <class T>
MD_ALWAYS_INLINE Lanes4<T> operator-(const Lanes4<T>& a) {
  return {{-a.v[0], -a.v[1], -a.v[2], -a.v[3]}};
}

template <class T>
MD_ALWAYS_INLINE Lanes4<T> operator~(const Lanes4<T>& a) {
  return {{~a.v[0], ~a.v[1], ~a.v[2], ~a.v[3]}};
}

template <class T>
MD_ALWAYS_INLINE Lanes4<T> operator<<(const Lanes4<T>& a, int n) {
  return {{a.v[0] << n, a.v[1] << n, a.v[2] << n, a.v[3] << n}};
}

typedef Lanes4<double> Vec4d;
typedef Lanes4<std::uint64_t> Vec4u;
typedef Lanes4<long long> Vec4m;  // lane masks: -1 where true, 0 where false

// Comparisons give masks, as with the vector extension.
#define MD_LANES4_CMP(op)                                                    \
  MD_ALWAYS_INLINE Vec4m operator op(const Vec4d& a, const Vec4d& b) {       \
    return {{a.v[0] op b.v[0] ? -1LL : 0LL, a.v[1] op b.v[1] ? -1LL : 0LL,   \
             a.v[2] op b.v[2] ? -1LL : 0LL, a.v[3] op b.v[3] ? -1LL : 0LL}}; \
  }                                                                          \
  MD_ALWAYS_INLINE Vec4m operator op(const Vec4d& a, double s) { return a op Vec4d{{s, s, s, s}}; }
MD_LANES4_CMP(>)
MD_LANES4_CMP(<)
#undef MD_LANES4_CMP

// The lane helpers of the vector-extension build (see there).
#define MD_SELECT4 select4
#define MD_UNPACK_EVEN unpack_even
#define MD_UNPACK_ODD unpack_odd
#define MD_LOW_HALVES low_halves
#define MD_HIGH_HALVES high_halves
MD_ALWAYS_INLINE Vec4d select4(const Vec4m& m, const Vec4d& a, const Vec4d& b) {
  return {{m.v[0] ? a.v[0] : b.v[0], m.v[1] ? a.v[1] : b.v[1], m.v[2] ? a.v[2] : b.v[2],
           m.v[3] ? a.v[3] : b.v[3]}};
}
MD_ALWAYS_INLINE Vec4d unpack_even(const Vec4d& a, const Vec4d& b) {
  return {{a.v[0], b.v[0], a.v[2], b.v[2]}};
}
MD_ALWAYS_INLINE Vec4d unpack_odd(const Vec4d& a, const Vec4d& b) {
  return {{a.v[1], b.v[1], a.v[3], b.v[3]}};
}
MD_ALWAYS_INLINE Vec4d low_halves(const Vec4d& a, const Vec4d& b) {
  return {{a.v[0], a.v[1], b.v[0], b.v[1]}};
}
MD_ALWAYS_INLINE Vec4d high_halves(const Vec4d& a, const Vec4d& b) {
  return {{a.v[2], a.v[3], b.v[2], b.v[3]}};
}

#endif

// True if some lane of a comparison's mask (-1 where true) is set.
template <class Mask>
MD_ALWAYS_INLINE bool any_lane(const Mask& m) {
  return (m[0] | m[1] | m[2] | m[3]) != 0;
}

static_assert(sizeof(Vec4d) == 4 * sizeof(double) && alignof(Vec4d) == alignof(double),
              "Vec4d must overlay four doubles of an array");

// Four consecutive doubles as a vector (a macro: returning vectors from functions warns about the
// ABI in the baseline build).
#define MD_LD4(p) (*reinterpret_cast<const Vec4d*>(p))

// Square root lane by lane. It vectorises only where the file is built with -fno-math-errno
// (native/CMakeLists.txt), else each lane calls sqrt for errno's sake.
MD_ALWAYS_INLINE void sqrt4(const Vec4d& a, Vec4d* out) {
  *out = Vec4d{std::sqrt(a[0]), std::sqrt(a[1]), std::sqrt(a[2]), std::sqrt(a[3])};
}

// True when the AVX2+FMA builds are to be used: the CPU runs them (checked once) and they are
// not switched off.
bool cpu_has_avx2_fma();

// Tests only: false makes every kernel take its baseline build. Returns the previous setting.
bool set_avx2_kernels_enabled(bool enabled);

// Which Vec4d this build uses: "vector extension" or "portable".
const char* simd_path();

}  // namespace matdeform
