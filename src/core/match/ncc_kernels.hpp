// Private to the core: the vector helpers the matcher's search engines share, and the peak rule.
//
// The peak rule (the paper's discrimination criterion delta needs the best and the second peak
// of a pixel's profile S(x, d) over its range [lo, hi]):
//   - a peak is an interior local maximum: S(d) > S(d - 1) and S(d) >= S(d + 1), lo < d < hi;
//   - the best is the highest peak, the first (smallest d) of equal values;
//   - the second is the highest of the other peaks and of a range end where the profile rises
//     towards the end (S(lo) > S(lo + 1), S(hi) > S(hi - 1): the true peak may lie beyond it).
//     Two local maxima are never adjacent, so "another peak" is always outside +-1 px of the
//     best.
// It is stated once here, as a fold over 8-lane groups of a profile (foldPeaks, per lane: the
// lane's best, its index and the lane's best other maximum) and a reduction (pickPeak). The
// full-range and sparse engines use exactly these two. The narrowed-range engine receives S one
// disparity at a time for 8 pixels and applies the same rule in streaming form
// (chunkSearchImpl in search_narrowed.cpp); test_matcher checks that all engines agree with the
// brute-force reference (reference_matcher.cpp), which states the rule in scalar form.
#pragma once

#include <algorithm>
#include <limits>
#include <type_traits>

#include "matcher_internal.hpp"
#include "simd.hpp"

namespace endo_stereo {
namespace detail {

using namespace simd;

/// Calls fn(std::integral_constant<int, G>) with G = n / 8 when 1 <= G <= 8, else
/// fn(std::integral_constant<int, 0>) (G at run time); n is a multiple of 8.
template <typename Fn>
ES_INLINE void byGroups(int n, Fn&& fn) {
  if (n == 64) {  // the full search's count first: one predictable branch, no jump table
    fn(std::integral_constant<int, 8>());
    return;
  }
  switch (n / 8) {
    case 1:
      fn(std::integral_constant<int, 1>());
      break;
    case 2:
      fn(std::integral_constant<int, 2>());
      break;
    case 3:
      fn(std::integral_constant<int, 3>());
      break;
    case 4:
      fn(std::integral_constant<int, 4>());
      break;
    case 5:
      fn(std::integral_constant<int, 5>());
      break;
    case 6:
      fn(std::integral_constant<int, 6>());
      break;
    case 7:
      fn(std::integral_constant<int, 7>());
      break;
    case 8:
      fn(std::integral_constant<int, 8>());
      break;
    default:
      fn(std::integral_constant<int, 0>());
      break;
  }
}

/// A column's window sums afresh: cs[k] = sum over j < rows of l[j * l_step] * r[j * r_step + k],

/// h[k] += a[k] - b[k]; n whole groups (a window slid by one column).
ES_INLINE void addSubGroups(int n, float* __restrict h, const float* __restrict a,
                            const float* __restrict b) {
  byGroups(
      n, [&](auto groups) __attribute__((always_inline)) {
        constexpr int kG = decltype(groups)::value;
        const int m = kG > 0 ? 8 * kG : n;
        for (int k = 0; k < m; k += 8) store8(h + k, load8(h + k) + (load8(a + k) - load8(b + k)));
      });
}

/// Greatest lane, in every lane (three butterfly steps).
ES_INLINE V8f hmax8(V8f v) {
  v = max8(v, __builtin_shufflevector(v, v, 4, 5, 6, 7, 0, 1, 2, 3));
  v = max8(v, __builtin_shufflevector(v, v, 2, 3, 0, 1, 6, 7, 4, 5));
  return max8(v, __builtin_shufflevector(v, v, 1, 0, 3, 2, 5, 4, 7, 6));
}
/// Least lane, in every lane.
ES_INLINE V8i hmin8(V8i v) {
  V8i t = __builtin_shufflevector(v, v, 4, 5, 6, 7, 0, 1, 2, 3);
  v = t < v ? t : v;
  t = __builtin_shufflevector(v, v, 2, 3, 0, 1, 6, 7, 4, 5);
  v = t < v ? t : v;
  t = __builtin_shufflevector(v, v, 1, 0, 3, 2, 5, 4, 7, 6);
  return t < v ? t : v;
}

/// Interior local maxima of one group v (its lanes' neighbours in left and right), folded into
/// the per-lane trackers: the lane's best (first of equal values: strict >), its index, and the
/// best of the lane's other maxima. With kMasked only lanes strictly inside (klo, khi) count.
template <bool kMasked>
ES_INLINE void foldPeaks(V8f v, V8f left, V8f right, V8i kk, V8i vklo, V8i vkhi, V8f& bv, V8f& sv,
                         V8i& bk) {
  V8i mx = (v > left) & (v >= right);
  if (kMasked) mx &= (kk > vklo) & (kk < vkhi);
  const V8f mv = mx ? v : splat8(kNegInf);
  const V8i gt = mv > bv;
  sv = gt ? bv : max8(sv, mv);
  bk = gt ? kk : bk;
  bv = gt ? mv : bv;
}

/// foldPeaks on the group of prof at k, its neighbours loaded from prof.
template <bool kMasked>
ES_INLINE void peakGroup(int k, V8i kk, V8i vklo, V8i vkhi, const float* __restrict prof, V8f& bv,
                         V8f& sv, V8i& bk) {
  foldPeaks<kMasked>(load8(prof + k), load8(prof + k - 1), load8(prof + k + 1), kk, vklo, vkhi, bv,
                     sv, bk);
}

/// foldPeaks on a group held in a register, its neighbours taken from the groups before and
/// after by lane shifts. The full-range engine stores a profile's groups just before it analyses
/// them, and a load at prof + k - 1 straddles two of those stores, which the store buffer cannot
/// forward (a stall per group); the values are the same.
template <bool kMasked>
ES_INLINE void peakGroupReg(V8f prev, V8f v, V8f next, V8i kk, V8i vklo, V8i vkhi, V8f& bv, V8f& sv,
                            V8i& bk) {
  foldPeaks<kMasked>(v, __builtin_shufflevector(prev, v, 7, 8, 9, 10, 11, 12, 13, 14),
                     __builtin_shufflevector(v, next, 1, 2, 3, 4, 5, 6, 7, 8), kk, vklo, vkhi, bv,
                     sv, bk);
}

/// The best and the second peak from the per-lane trackers of foldPeaks (bv: each lane's best,
/// bk: its index, sv: the lane's best other maximum) over the profile prof, indices klo .. khi
/// (index k is disparity d0 + k): the highest maximum at its smallest index (lanes hold distinct
/// indices), every other maximum and a rising range end competing for the second.
/// best_d, best_l, best_r are written only when there is a peak.
ES_INLINE void pickPeak(V8f bv, V8f sv, V8i bk, const float* prof, int klo, int khi, int d0,
                        float* best, float* best_d, float* best_l, float* best_r, float* second) {
  const V8f bmax = hmax8(bv);
  const float b = bmax[0];
  float sec = kNegInf;
  if (b != kNegInf) {
    const int big = std::numeric_limits<int>::max();
    const V8i cand = bv == bmax ? bk : V8i{big, big, big, big, big, big, big, big};
    const int bi = hmin8(cand)[0];
    const V8i sel = bk == V8i{bi, bi, bi, bi, bi, bi, bi, bi};
    sec = hmax8(sel ? sv : bv)[0];
    *best_d = static_cast<float>(d0 + bi);
    *best_l = prof[bi - 1];
    *best_r = prof[bi + 1];
  }
  if (prof[klo] > prof[klo + 1]) sec = std::max(sec, prof[klo]);
  if (prof[khi] > prof[khi - 1]) sec = std::max(sec, prof[khi]);
  *best = b;
  *second = sec;
}

}  // namespace detail
}  // namespace endo_stereo
