// Private: the per-pose kernels are built twice, for baseline x86-64 (what the wheel targets) and
// for AVX2+FMA, and the second is picked at run time where the CPU has it.
//
// Why by hand: GCC's target_clones("avx2") left the 4-wide row updates scalar (no FMA, no ymm),
// while explicit vector types give one ymm FMA per factor entry, about 35 % less time for the
// substitution on the project's VM. A kernel body is written once as an always-inline function
// and instantiated inside two wrappers, so each copy is compiled for its wrapper's ISA.
#pragma once

#if defined(__x86_64__) && defined(__GNUC__)
#define MD_X86_DISPATCH 1
#define MD_TARGET_AVX2 __attribute__((target("avx2,fma")))
#else
#define MD_X86_DISPATCH 0
#define MD_TARGET_AVX2
#endif
#define MD_ALWAYS_INLINE inline __attribute__((always_inline))

namespace matdeform {

// Four doubles (x, y, z, pad), unaligned and allowed to alias double arrays.
typedef double Vec4d __attribute__((vector_size(32), aligned(8), may_alias));

// True when the AVX2+FMA builds are to be used: the CPU runs them (checked once) and they are
// not switched off.
bool cpu_has_avx2_fma();

// Tests only: false makes every kernel take its baseline build. Returns the previous setting.
bool set_avx2_kernels_enabled(bool enabled);

}  // namespace matdeform
