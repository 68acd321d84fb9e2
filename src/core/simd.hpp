// Private to the core: 8-lane float helpers on GCC vector types and the dispatch attribute of the
// hot kernels (AVX-512, AVX2 and baseline clones chosen at load time), shared by the matcher's
// files and the depth-edge filter. Not installed, not part of the API.
#pragma once

#include <cstdint>
#include <cstring>

namespace endo_stereo {
namespace simd {

// --- Vectorisable kernels. Built for x86-64-v4 (AVX-512), for AVX2 and for the baseline, chosen
// at load time, so the library runs on any x86-64 and uses the widest set the CPU has. The
// vectors stay 8 lanes wide; the v4 clone gains AVX-512's 32 registers and mask registers (full
// search -4.5%, +-4 px range -7% on the benchmark's 960x540 case, 2026-11-23). The core builds
// with -ffp-contract=off (CMakeLists.txt): v4 has FMA, and a fused multiply-add rounds once
// where the other clones round twice, so without it the clones' outputs would differ. --------
// ES_KERNEL_CLONE (1 baseline, 2 avx2, 3 x86-64-v4) builds one clone alone, as the target
// attribute of that clone: test_simd_clones builds the matcher once per clone this way and
// checks that all of them, and the dispatched library, give the same output.
#if defined(ES_KERNEL_CLONE) && ES_KERNEL_CLONE == 1
#define ES_KERNEL
#elif defined(ES_KERNEL_CLONE) && ES_KERNEL_CLONE == 2
#define ES_KERNEL __attribute__((target("avx2")))
#elif defined(ES_KERNEL_CLONE) && ES_KERNEL_CLONE == 3
#define ES_KERNEL __attribute__((target("arch=x86-64-v4")))
#elif defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && \
    !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
#define ES_KERNEL __attribute__((target_clones("arch=x86-64-v4", "avx2", "default")))
#else
#define ES_KERNEL
#endif
#define ES_INLINE __attribute__((always_inline)) inline

// The vector helpers are always inlined into the AVX2 or baseline clone; the ABI note GCC gives
// for 32-byte vector values in baseline code does not apply.
#pragma GCC diagnostic ignored "-Wpsabi"
typedef float V8f __attribute__((vector_size(32)));
typedef int V8i __attribute__((vector_size(32)));
typedef uint32_t V8u __attribute__((vector_size(32)));
// Eight bytes (per-pixel codes and flags) and their masks, selected as bytes.
typedef uint8_t V8u8 __attribute__((vector_size(8)));
typedef int8_t V8s8 __attribute__((vector_size(8)));

ES_INLINE V8f load8(const float* p) {
  V8f v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
ES_INLINE void store8(float* p, V8f v) { std::memcpy(p, &v, sizeof(v)); }
ES_INLINE V8f max8(V8f a, V8f b) { return a > b ? a : b; }
ES_INLINE V8f splat8(float f) { return V8f{f, f, f, f, f, f, f, f}; }
// Whether any lane of a comparison mask is set.
ES_INLINE bool anyLane(V8i m) {
  typedef long long V4l __attribute__((vector_size(32)));
  const V4l t = reinterpret_cast<V4l>(m);
  return ((t[0] | t[1]) | (t[2] | t[3])) != 0;
}

}  // namespace simd
}  // namespace endo_stereo
