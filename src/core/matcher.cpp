// The robust matcher of Bernhardt, Abi-Nahed and Abugharbieh (2012), METHOD.md sections 2 and 3,
// plus our measure against foreground fattening at depth edges.
//
// How the work is organised (why it is fast, exact, and the same for any thread count):
// - Intensities are stored as float (value - 128), so every product lies in [-16384, 16384] and
//   every window sum of products of a window up to 32 x 32 stays below 2^24: window sums are exact
//   integers in float arithmetic. Running sums, fresh sums and any order of summation give
//   bit-identical values, so the output cannot depend on how rows are split between threads.
//   Window means and variances come from integral images (int32, exact: see boxAt).
// - Rows are processed in fixed stripes (cv::parallel_for_ over stripe indices that do not depend
//   on the thread count). For one window size, a row is matched by one of two engines:
//   * dense rows (most pixels still undecided: always at the first window), full search: the
//     "lanes" engine. Each column holds its vertical window sums of L(x, y') R(x - d, y') for all
//     d, contiguous in d (8 disparities per vector), carried from row to row by one row in and
//     one row out; a pixel's window sums slide along the row; its profile S(x, .) is formed 8
//     disparities at a time and analysed per lane (best interior local maximum, its index, the
//     best other maximum), and offered to the right-to-left tracker of every right pixel x - d,
//     held mirrored so that it is contiguous in d too: S_RL(q, d) = S_LR(q + d, d) is the
//     left-right check without a second pass.
//   * dense rows with per-pixel search ranges (temporal priors): disparities are streamed in
//     increasing order over the column intervals whose pixels search them; for each d the
//     vertical sums are updated by one row, summed horizontally, turned into the NCC slice
//     S(., d) and fed to a per-pixel streaming peak tracker (and the right-to-left tracker).
//   * sparse rows (the pixels that failed with the smaller windows): the vertical window sums are
//     kept per column for all d at once (so a failed region that spans many rows is updated by
//     running sums), the profile of each failed pixel is built from them, and the right-to-left
//     profile is computed only for the right pixels that those profiles point at, from column
//     sums indexed by the right column (w columns per profile).
//   All compute S with the same float expression from the same exact sums, so they agree.
// - Only the pixels that failed with one window go on to the next; pixels whose left patch lacks
//   structure at a window are not matched with it at all.
//
// Against foreground fattening (ours; METHOD.md "What a faithful prototype measured"): a pixel
// accepted with a window of width w is rejected when, inside that same window, the accepted
// disparities reach farther than edge_disparity_jump_px from its own. A window straddling a
// depth edge is exactly the case where a confident, left-right-consistent match can be the
// other surface's disparity, and the fattened band around an edge is never wider than the window
// that produced it, so testing each pixel's own window catches it. Measured on Middlebury in
// docs/matcher_design.md.

#include "endo_stereo/core/matcher.hpp"

#include <algorithm>
#if defined(__SSE2__)
#include <immintrin.h>
#endif
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>
#include <type_traits>
#include <vector>

#include "edge_test.hpp"
#include "simd.hpp"

namespace endo_stereo {

namespace {

constexpr float kNegInf = -std::numeric_limits<float>::infinity();
// Fixed stripes of rows, so the work split never depends on the thread count.
constexpr int kStripeRows = 32;
// Column blocks used to find, per disparity, the column intervals worth computing (dense rows).
constexpr int kBlock = 32;
// Sentinel of an empty effective range.
constexpr int kEmptyLo = std::numeric_limits<int>::max() / 2;
constexpr int kEmptyHi = std::numeric_limits<int>::min() / 2;

struct Interval {
  int a, b;  // inclusive
};

/// Columns of the dense engine's vertical window sums of one disparity that hold valid values,
/// for the row computed last (`cur_row`) and the row before it (`prev`), as sorted disjoint
/// intervals.
struct VValidity {
  int cur_row = -10;
  std::vector<Interval> cur, prev;
};

/// Per-row window statistics at one window size (index = column).
struct RowMaps {
  std::vector<float> mean_l;  // window mean of L - 128
  std::vector<float> inv_l;   // sqrt(n / (n sum L^2 - (sum L)^2)), 0 where flat
  std::vector<float> sum_r;   // window sum of R - 128
  std::vector<float> inv_r;
  std::vector<float> gamma_l;  // stdev of the Laplacian over the window
  std::vector<float> gamma_r;
  std::vector<float> sum_r_rev, inv_r_rev;                // mirrored: index W - 1 - x
  std::vector<int> stamp_l, stamp_r, stamp_gl, stamp_gr;  // sparse rows: computed for this stamp
};

/// Layout of the dense engine's right-to-left trackers (lanePass2), 8 copies of `used` floats
/// for the values and 8 for the disparities, chosen against 4K aliasing: a load whose address
/// matches an earlier, still pending store's in the low 12 bits waits as if it depended on it.
/// A pixel's tracker groups span up to 288 bytes of its copy; the next pixel uses the next copy
/// 4 bytes lower. The copy stride is 1028 bytes mod 4 KiB, so the next 3 pixels' copies lie 1, 2
/// and 3 KiB away (mod 4 KiB) from this one's; the disparities lie 512 bytes (mod 4 KiB) after
/// the values, so no copy within 3 pixels overlaps another's stores there either. Layout only:
/// the values computed are the same.
inline void layoutTrackers(int used, int* stride, int* d_off) {
  *stride = (used / 1024) * 1024 + 257;
  if (*stride < used) *stride += 1024;
  const int values = 8 * *stride;
  *d_off = (values / 1024) * 1024 + 128;
  if (*d_off < values) *d_off += 1024;
}

/// Scratch of one worker, reused between rows, stripes, levels and frames.
struct Scratch {
  int width = 0;
  int num_d = 0;
  int dpad = 0;           // num_d rounded up to a multiple of 8
  int stamp = 0;          // increases with every processed row
  const int* rlo_row = nullptr;  // requested ranges of the row being processed
  const int* rhi_row = nullptr;
  // Dense engine.
  std::vector<float> v;          // vertical window sums, num_d rows of width
  std::vector<VValidity> valid;  // per disparity
  std::vector<float> tmp_a, tmp_b, hsum;
  std::vector<int> cover;     // per block, per disparity: pixels whose range holds it
  std::vector<int> iv_start;  // per disparity: first index into ivs
  std::vector<Interval> ivs;  // the intervals of all disparities, grouped by disparity
  std::vector<Interval> pieces, merged, need, runs, out_ivs;
  std::vector<int> block_a, block_b, blocks, active, pick, cand_q;
  std::vector<int> block_k0, block_k1, iv_count;  // per block: disparity indices covered
  std::vector<Interval> iv_by_k;                  // per disparity index: up to one per block
  // Sparse engine: vertical window sums of one column for all disparities, [column][dpad].
  std::vector<float> colsum;
  std::vector<int> col_row, col_k0, col_k1, col_used, col_done, hot;
  std::vector<int> req_stamp, req_k0, req_k1, run_lo, run_hi, rl_ok;
  std::vector<int> vh_lo, vh_hi, vh_glo, vh_ghi;  // runRequests' sliding minimum / maximum
  // Right-to-left profiles: vertical window sums indexed by the RIGHT column q, [q][dpad]:
  // colsum_r[q][k] = sum over the window's rows of L(y', q + d_k) R(y', q). The profile of right
  // pixel q is then the sum of w whole columns (q - r .. q + r), not a diagonal through 64 + w
  // left columns. Same bookkeeping as the left columns.
  std::vector<float> colsum_r;
  std::vector<int> colr_row, colr_k0, colr_k1, colr_used, colr_done, hot_r;
  std::vector<float> hvec, prof;
  // Right-to-left profiles: the window sums hr of right pixel rl_q on the disparity indices
  // [rl_k0, rl_k1]; in uniform rows slid to the next right pixel when it is rl_q + 1 in the same
  // row (rl_stamp).
  std::vector<float> hr;
  int rl_q = -10, rl_k0 = 0, rl_k1 = -1, rl_stamp = -1;
  float* prof0 = nullptr;  // profile buffer, index 0 = first disparity of the range
  // Dense engine ("lanes over disparity"): vertical window sums of every column for the
  // disparity groups it needs, [column][dpad], carried down the stripe by running sums.
  std::vector<float> vl;
  std::vector<int> vl_g0, vl_g1;  // per column: 8-lane groups held (g0 > g1: none)
  std::vector<int> span_lo, span_hi;
  int vl_row = -10;               // row the sums hold (all columns), -10 = none
  int span_stripe = -1;           // stripe whose per-column groups vl_g0/vl_g1 were set for
  // Reversed, padded row arrays (index rpad + W - 1 - q for right column q, so that q = x - d for
  // increasing d is contiguous): right statistics and the right-to-left tracker.
  int rpad = 0;
  std::vector<float> srr, irr, hrow, lprof, lmbuf;
  // The dense engine's right-to-left trackers (lanePass2): 8 copies of the best values, then 8 of
  // their disparities, in one buffer laid out by layoutTrackers.
  std::vector<float> rb_buf;
  int rb_stride = 0;  // floats from one copy to the next
  int rb_d_off = 0;   // floats from the values' first copy to the disparities' first copy
  // Row state.
  RowMaps maps;
  std::vector<float> elo, ehi, act;  // effective range and activity of this row, as float
  std::vector<int> elo_i, ehi_i;
  std::vector<float> p1, p2, best, best_d, best_l, best_r, second;
  std::vector<float> rb_v, rb_d;

  void ensure(int w, int nd) {
    if (w == width && nd == num_d) return;
    width = w;
    num_d = nd;
    dpad = (nd + 7) / 8 * 8;
    v.assign(static_cast<size_t>(nd) * w, 0.f);
    valid.assign(nd, VValidity{});
    for (auto* vec : {&tmp_a,
                      &tmp_b,
                      &hsum,
                      &elo,
                      &ehi,
                      &act,
                      &p1,
                      &p2,
                      &best,
                      &best_d,
                      &best_l,
                      &best_r,
                      &second,
                      &rb_v,
                      &rb_d,
                      &maps.mean_l,
                      &maps.inv_l,
                      &maps.sum_r,
                      &maps.inv_r,
                      &maps.gamma_l,
                      &maps.gamma_r,
                      &maps.sum_r_rev,
                      &maps.inv_r_rev}) {
      vec->assign(w + 64, 0.f);
    }
    maps.stamp_l.assign(w, -1);
    maps.stamp_r.assign(w, -1);
    maps.stamp_gl.assign(w, -1);
    maps.stamp_gr.assign(w, -1);
    elo_i.assign(w, 0);
    ehi_i.assign(w, 0);
    const int nb = (w + kBlock - 1) / kBlock;
    cover.assign(static_cast<size_t>(nb) * (nd + 1), 0);
    iv_start.assign(nd + 1, 0);
    block_a.assign(nb, 0);
    block_b.assign(nb, 0);
    block_k0.assign(nb, 0);
    block_k1.assign(nb, -1);
    iv_count.assign(nd, 0);
    iv_by_k.assign(static_cast<size_t>(nd) * nb, Interval{0, -1});
    // + 8: padding for whole 8-lane groups past the last disparity of a column.
    colsum.assign(static_cast<size_t>(w) * dpad + 8, 0.f);
    col_row.assign(w, -10);
    col_k0.assign(w, 0);
    col_k1.assign(w, -1);
    col_used.assign(w, -10);
    col_done.assign(w, -1);
    req_stamp.assign(w, -1);
    req_k0.assign(w, 0);
    req_k1.assign(w, -1);
    run_lo.assign(w, 0);
    run_hi.assign(w, 0);
    // Run of up to w pixels, padded by 2r on each side and rounded up to a block of 2r + 1
    // (r <= 16: windows up to 33 px).
    for (auto* vec : {&vh_lo, &vh_hi, &vh_glo, &vh_ghi}) vec->assign(w + 4 * 17 + 34, 0);
    hot.reserve(w);
    colsum_r.assign(static_cast<size_t>(w) * dpad + 8, 0.f);
    colr_row.assign(w, -10);
    colr_k0.assign(w, 0);
    colr_k1.assign(w, -1);
    colr_used.assign(w, -10);
    colr_done.assign(w, -1);
    hot_r.reserve(w);
    vl.assign(static_cast<size_t>(w) * dpad + 8, 0.f);
    // Reads of the mirrored arrays stay within [rpad - 7, rpad + W + 6] (effective ranges lie
    // inside the image, groups round them by at most 7).
    rpad = 8;
    for (auto* vec : {&srr, &irr}) vec->assign(rpad + w + 16, 0.f);
    layoutTrackers(rpad + w + 16, &rb_stride, &rb_d_off);
    rb_buf.assign(static_cast<size_t>(rb_d_off) + 8 * static_cast<size_t>(rb_stride), 0.f);
    vl_g0.assign(w, 0);
    vl_g1.assign(w, -1);
    span_lo.assign(w, 0);
    span_hi.assign(w, 0);
    hrow.assign(dpad + 16, 0.f);
    lprof.assign(dpad + 24, 0.f);
    lmbuf.assign(dpad + 24, 0.f);
    hvec.assign(dpad + 8, 0.f);
    hr.assign(dpad + 8, 0.f);
    rl_stamp = -1;
    // 8 floats before (prof0[-1] is read, masked) and 16 after (whole groups past the end).
    prof.assign(dpad + 24, 0.f);
    prof0 = prof.data() + 8;
  }
  /// Forget all window sums (new stripe or new window size).
  void resetSums() {
    for (auto& vv : valid) {
      vv.cur_row = -10;
      vv.cur.clear();
      vv.prev.clear();
    }
    std::fill(col_row.begin(), col_row.end(), -10);
    hot.clear();
    std::fill(colr_row.begin(), colr_row.end(), -10);
    hot_r.clear();
    vl_row = -10;
    span_stripe = -1;
  }
};

using namespace simd;
// Sum of w consecutive 8-lane loads starting at p, with four partial sums so the additions do
// not form one long dependency chain (exact: integer-valued data).
ES_INLINE V8f boxSum8(const float* p, int w) {
  V8f a0 = load8(p);
  if (w == 1) return a0;
  V8f a1 = load8(p + 1), a2 = splat8(0.f), a3 = splat8(0.f);
  int j = 2;
  for (; j + 1 < w; j += 2) {
    a2 += load8(p + j);
    a3 += load8(p + j + 1);
    if (j + 3 < w) {
      a0 += load8(p + j + 2);
      a1 += load8(p + j + 3);
      j += 2;
    }
  }
  if (j < w) a2 += load8(p + j);
  return (a0 + a1) + (a2 + a3);
}

ES_KERNEL void vRunning(int n, float* __restrict v, const float* __restrict l_in,
                        const float* __restrict r_in, const float* __restrict l_out,
                        const float* __restrict r_out) {
  for (int i = 0; i < n; ++i) v[i] += l_in[i] * r_in[i] - l_out[i] * r_out[i];
}

ES_KERNEL void vSet(int n, float* __restrict v, const float* __restrict l,
                    const float* __restrict r) {
  for (int i = 0; i < n; ++i) v[i] = l[i] * r[i];
}

ES_KERNEL void vAdd(int n, float* __restrict v, const float* __restrict l,
                    const float* __restrict r) {
  for (int i = 0; i < n; ++i) v[i] += l[i] * r[i];
}

ES_KERNEL void addShifted(int n, float* __restrict out, const float* __restrict in) {
  for (int i = 0; i < n; ++i) out[i] += in[i];
}

ES_KERNEL void copyShifted(int n, float* __restrict out, const float* __restrict in) {
  for (int i = 0; i < n; ++i) out[i] = in[i];
}

ES_KERNEL void pairSum(int n, float* __restrict out, const float* __restrict a,
                       const float* __restrict b) {
  for (int i = 0; i < n; ++i) out[i] = a[i] + b[i];
}

/// out[i] = sum_{j < w} in[i + j] for i in [0, n): sums of 2, 4, 8, 16 neighbours built by
/// doubling, so the cost is O(n log w) in vectorisable passes. Exact on the integer-valued data.
void boxSumRow(const float* in, int n, int w, float* out, float* ta, float* tb) {
  const float* cur = in;  // sums of `span` consecutive inputs, valid for indices [0, len)
  int span = 1;
  int len = n + w - 1;
  int offset = 0;
  bool first = true;
  float* bufs[2] = {ta, tb};
  int which = 0;
  int rest = w;
  while (true) {
    if (rest & 1) {
      if (first) {
        copyShifted(n, out, cur + offset);
        first = false;
      } else {
        addShifted(n, out, cur + offset);
      }
      offset += span;
    }
    rest >>= 1;
    if (!rest) break;
    float* nxt = bufs[which];
    which ^= 1;
    const int nlen = len - span;
    pairSum(nlen, nxt, cur, cur + span);
    cur = nxt;
    len = nlen;
    span *= 2;
  }
}

// Column sums of the sparse engine (r read mirrored, so that disparities are contiguous). Their
// counts n are whole 8-lane groups (the requests are rounded out to groups: columnRequest), so
// the kernels run over groups, and for up to 8 groups (64 disparities: a full search of 64, or
// the few groups of a narrowed range) with the group count fixed at compile time: the loops
// unroll, and colFresh keeps its sums in registers across the rows. The same operations in the
// same order: the same values.

/// Calls fn(std::integral_constant<int, G>) with G = n / 8 when 1 <= G <= 8, else
/// fn(std::integral_constant<int, 0>) (G at run time); n is a multiple of 8.
template <typename Fn>
ES_INLINE void byGroups(int n, Fn&& fn) {
  if (n == 64) {  // the full search's count first: one predictable branch, no jump table
    fn(std::integral_constant<int, 8>());
    return;
  }
  switch (n / 8) {
    case 1: fn(std::integral_constant<int, 1>()); break;
    case 2: fn(std::integral_constant<int, 2>()); break;
    case 3: fn(std::integral_constant<int, 3>()); break;
    case 4: fn(std::integral_constant<int, 4>()); break;
    case 5: fn(std::integral_constant<int, 5>()); break;
    case 6: fn(std::integral_constant<int, 6>()); break;
    case 7: fn(std::integral_constant<int, 7>()); break;
    case 8: fn(std::integral_constant<int, 8>()); break;
    default: fn(std::integral_constant<int, 0>()); break;
  }
}

/// A column's window sums afresh: cs[k] = sum over j < rows of l[j * l_step] * r[j * r_step + k],
/// the rows summed in increasing order (one call instead of one per row); n whole groups.
ES_KERNEL void colFresh(int n, float* __restrict cs, const float* __restrict l, size_t l_step,
                        const float* __restrict r, size_t r_step, int rows) {
  byGroups(n, [&](auto groups) __attribute__((always_inline)) {
    constexpr int kG = decltype(groups)::value;
    if (kG > 0) {
      V8f acc[kG > 0 ? kG : 1];
      const V8f l0 = splat8(l[0]);
      for (int g = 0; g < kG; ++g) acc[g] = l0 * load8(r + 8 * g);
      for (int j = 1; j < rows; ++j) {
        const V8f lj = splat8(l[j * l_step]);
        const float* __restrict rj = r + j * r_step;
        for (int g = 0; g < kG; ++g) acc[g] += lj * load8(rj + 8 * g);
      }
      for (int g = 0; g < kG; ++g) store8(cs + 8 * g, acc[g]);
      return;
    }
    const V8f l0 = splat8(l[0]);
    for (int k = 0; k < n; k += 8) store8(cs + k, l0 * load8(r + k));
    for (int j = 1; j < rows; ++j) {
      const V8f lj = splat8(l[j * l_step]);
      const float* __restrict rj = r + j * r_step;
      for (int k = 0; k < n; k += 8) store8(cs + k, load8(cs + k) + lj * load8(rj + k));
    }
  });
}
/// cs[k] += l_in * r_in[k] - l_out * r_out[k]: one row in and one out; n whole groups.
ES_INLINE void colStep(int n, float* __restrict cs, float l_in, const float* __restrict r_in,
                       float l_out, const float* __restrict r_out) {
  if (n == 64) {  // written per element: GCC's own vectorisation of it measured fewer instructions
    for (int k = 0; k < 64; ++k) cs[k] += l_in * r_in[k] - l_out * r_out[k];
    return;
  }
  const V8f li = splat8(l_in), lo = splat8(l_out);
  byGroups(n, [&](auto groups) __attribute__((always_inline)) {
    constexpr int kG = decltype(groups)::value;
    const int m = kG > 0 ? 8 * kG : n;
    for (int k = 0; k < m; k += 8) {
      store8(cs + k, load8(cs + k) + (li * load8(r_in + k) - lo * load8(r_out + k)));
    }
  });
}
ES_KERNEL void colRunning(int n, float* __restrict cs, float l_in, const float* __restrict r_in,
                          float l_out, const float* __restrict r_out) {
  colStep(n, cs, l_in, r_in, l_out, r_out);
}
/// h[k] += a[k]; n whole groups.
ES_KERNEL void vecAdd(int n, float* __restrict h, const float* __restrict a) {
  byGroups(n, [&](auto groups) __attribute__((always_inline)) {
    constexpr int kG = decltype(groups)::value;
    const int m = kG > 0 ? 8 * kG : n;
    for (int k = 0; k < m; k += 8) store8(h + k, load8(h + k) + load8(a + k));
  });
}
/// h[k] += a[k] - b[k]; n whole groups (also the dense engine's window slide, inlined there).
ES_INLINE void addSubGroups(int n, float* __restrict h, const float* __restrict a,
                            const float* __restrict b) {
  byGroups(n, [&](auto groups) __attribute__((always_inline)) {
    constexpr int kG = decltype(groups)::value;
    const int m = kG > 0 ? 8 * kG : n;
    for (int k = 0; k < m; k += 8) store8(h + k, load8(h + k) + (load8(a + k) - load8(b + k)));
  });
}
ES_KERNEL void vecAddSub(int n, float* __restrict h, const float* __restrict a,
                         const float* __restrict b) {
  addSubGroups(n, h, a, b);
}

/// Inputs of the dense engine's per-disparity update of one row interval. Pointers are offset so
/// that index i is column x = a + i (left quantities) or right column x - d (right quantities and
/// rb_*). When v is set, the horizontal window sum is taken from it directly (w loads per value,
/// cheaper than the doubling passes for small windows); otherwise h holds it.
struct SliceArgs {
  int n;
  int w;
  float d;
  const float* v;  // vertical sums at column x - r, or null
  const float* h;  // window sums of L * R(x - d), when v is null
  const float* mean_l;
  const float* inv_l;
  const float* sum_r;  // at x - d
  const float* inv_r;  // at x - d
  const float* elo;
  const float* ehi;
  const float* act;
  float *p1, *p2, *best, *best_d, *best_l, *best_r, *second;
  float *rb_v, *rb_d;  // at x - d
};

// The streaming peak tracker. At disparity d a pixel knows S(d-2), S(d-1) (p2, p1) and S(d):
// d-1 is an interior local maximum when S(d-1) > S(d-2) and S(d-1) >= S(d) with d-2 inside its
// range. The highest interior maximum is the best (its neighbours kept for the parabola); every
// other maximum, and a range end where the profile rises towards it (the true peak may lie
// beyond), competes for the peak gap. Local maxima are never adjacent, so "outside +-1 px of the
// best" holds by construction. Written once on GCC vector types (8 lanes: AVX2 in the avx2 clone,
// two SSE halves otherwise) for the body, once in scalar form for the tail; the same lane by lane.
template <bool kOwn, bool kRl, int kW>
ES_INLINE void sliceUpdate(const SliceArgs& g) {
  const float d = g.d, dm1 = g.d - 1.f;
  const float* __restrict vs = g.v;
  const float* __restrict h = g.h;
  const float* __restrict mean_l = g.mean_l;
  const float* __restrict inv_l = g.inv_l;
  const float* __restrict sum_r = g.sum_r;
  const float* __restrict inv_r = g.inv_r;
  const float* __restrict elo = g.elo;
  const float* __restrict ehi = g.ehi;
  const float* __restrict act = g.act;
  float* __restrict p1 = g.p1;
  float* __restrict p2 = g.p2;
  float* __restrict best = g.best;
  float* __restrict best_d = g.best_d;
  float* __restrict best_l = g.best_l;
  float* __restrict best_r = g.best_r;
  float* __restrict second = g.second;
  float* __restrict rb_v = g.rb_v;
  float* __restrict rb_d = g.rb_d;
  const int w = kW > 0 ? kW : g.w;
  int i = 0;
  const int n = g.n;
  const V8f vd = splat8(d);
  const V8f vdm1 = splat8(dm1);
  const V8f vninf = splat8(kNegInf);
  const V8f vzero = splat8(0.f);
  for (; i + 8 <= n; i += 8) {
    // With the window width known at compile time (kW) the horizontal sum unrolls: the first
    // window is where almost all pixels are decided.
    const V8f hs = (kW > 0 || vs) ? boxSum8(vs + i, w) : load8(h + i);
    const V8f s = (hs - load8(mean_l + i) * load8(sum_r + i)) * load8(inv_l + i) * load8(inv_r + i);
    const V8f lo = load8(elo + i), hi = load8(ehi + i);
    const V8i inr = (lo <= vd) & (vd <= hi);
    if (kOwn) {
      const V8i own = inr & (load8(act + i) > vzero);
      const V8f a1 = load8(p1 + i), a2 = load8(p2 + i), bb = load8(best + i);
      const V8i is_max = own & (vd >= lo + 2.f) & (a1 > a2) & (a1 >= s);
      const V8i new_best = is_max & (a1 > bb);
      V8f cand = new_best ? bb : (is_max ? a1 : vninf);
      const V8i lo_end = own & (vd == lo + 1.f) & (a1 > s);
      const V8i hi_end = own & (vd == hi) & (s > a1);
      cand = max8(cand, lo_end ? a1 : vninf);
      cand = max8(cand, hi_end ? s : vninf);
      store8(second + i, max8(load8(second + i), cand));
      if (anyLane(new_best)) {  // rare once the profile has risen: skip the selects and stores
        store8(best + i, new_best ? a1 : bb);
        store8(best_d + i, new_best ? vdm1 : load8(best_d + i));
        store8(best_l + i, new_best ? a2 : load8(best_l + i));
        store8(best_r + i, new_best ? s : load8(best_r + i));
      }
      store8(p2 + i, own ? a1 : a2);
      store8(p1 + i, own ? s : a1);
    }
    if (kRl) {
      // Right-to-left profile of right pixel x - d: S_RL(x - d, d) = S_LR(x, d). Strict > keeps
      // the smallest disparity among equal values (d increases).
      const V8f rv = load8(rb_v + i);
      const V8i up = inr & (s > rv);
      store8(rb_v + i, up ? s : rv);
      store8(rb_d + i, up ? vd : load8(rb_d + i));
    }
  }
  for (; i < n; ++i) {
    float hs;
    if (vs) {
      hs = vs[i];
      for (int j = 1; j < w; ++j) hs += vs[i + j];
    } else {
      hs = h[i];
    }
    const float s = (hs - mean_l[i] * sum_r[i]) * inv_l[i] * inv_r[i];
    const bool inr = (elo[i] <= d) & (d <= ehi[i]);
    if (kOwn) {
      const bool own = inr & (act[i] > 0.f);
      const float a1 = p1[i], a2 = p2[i], bb = best[i];
      const bool is_max = own & (d >= elo[i] + 2.f) & (a1 > a2) & (a1 >= s);
      const bool new_best = is_max & (a1 > bb);
      float cand = new_best ? bb : (is_max ? a1 : kNegInf);
      const bool lo_end = own & (d == elo[i] + 1.f) & (a1 > s);
      const bool hi_end = own & (d == ehi[i]) & (s > a1);
      cand = std::max(cand, lo_end ? a1 : kNegInf);
      cand = std::max(cand, hi_end ? s : kNegInf);
      second[i] = std::max(second[i], cand);
      best[i] = new_best ? a1 : bb;
      best_d[i] = new_best ? dm1 : best_d[i];
      best_l[i] = new_best ? a2 : best_l[i];
      best_r[i] = new_best ? s : best_r[i];
      p2[i] = own ? a1 : a2;
      p1[i] = own ? s : a1;
    }
    if (kRl) {
      const float rv = rb_v[i];
      const bool up = inr & (s > rv);
      rb_v[i] = up ? s : rv;
      rb_d[i] = up ? d : rb_d[i];
    }
  }
}

ES_KERNEL void sliceOwnAndRl(const SliceArgs& g) { sliceUpdate<true, true, 0>(g); }
ES_KERNEL void sliceOwnAndRl7(const SliceArgs& g) { sliceUpdate<true, true, 7>(g); }

/// The NCC from exact sums; both engines use this same expression, so they agree bit for bit.
inline float nccValue(float h, float mean_l, float sum_r, float inv_l, float inv_r) {
  return (h - mean_l * sum_r) * inv_l * inv_r;
}

/// Per-frame images shared (read-only) by the workers.
struct FrameData {
  cv::Mat lf, rf;        // CV_32F value - 128
  cv::Mat rf_rev;        // CV_32F rf mirrored left-right, padded (sparse engine)
  int rev_pad = 0;       // columns of padding on the left of rf_rev
  cv::Mat lf_pad;        // CV_32F lf with zero columns around it (right-indexed column sums)
  int l_pad = 0;         // columns of padding on the left of lf_pad
  cv::Mat int_l, int_r;  // CV_32S integral images of the 8-bit views
  cv::Mat lap_l, lap_r;  // CV_16S 3x3 Laplacian on 0..255 (|value| <= 1020)
  // Integral images of the squares, of the Laplacian and of its square, CV_32S taken modulo
  // 2^32 (wrappedIntegrals): read only through window differences (boxAt, statsRowInt,
  // gammaRowInt), which are exact.
  cv::Mat sq_l, sq_r, int_lap_l, int_lap_r, sq_lap_l, sq_lap_r;
  // CV_32S requested range per pixel (clamped), lo > hi = none; with a full search one row that
  // every row shares (no per-frame fill of two whole images).
  cv::Mat range_lo, range_hi;
};

}  // namespace

struct RobustMatcher::Impl : FrameData {
  cv::Mat state;       // CV_8U: 0 = undecided/failed so far, 1 = accepted
  cv::Mat window_idx;  // CV_8U window index that accepted
  cv::Mat tmp1, tmp2, tmp3, tmp4, tmp5, code_before;
  std::vector<std::vector<int>> open_rows;
  std::vector<int> open_level;
  std::vector<int> n_req_rows;

  std::mutex pool_mutex;
  std::vector<std::unique_ptr<Scratch>> pool;

  std::unique_ptr<Scratch> acquire() {
    std::lock_guard<std::mutex> lock(pool_mutex);
    if (pool.empty()) return std::make_unique<Scratch>();
    auto s = std::move(pool.back());
    pool.pop_back();
    return s;
  }
  void release(std::unique_ptr<Scratch> s) {
    std::lock_guard<std::mutex> lock(pool_mutex);
    pool.push_back(std::move(s));
  }
};

RobustMatcher::RobustMatcher(const MatcherParams& matcher_params,
                             const PostFilterParams& filter_params)
    : impl_(nullptr) {
  setParams(matcher_params, filter_params);
  impl_ = new Impl();
}

RobustMatcher::~RobustMatcher() { delete impl_; }

void RobustMatcher::setParams(const MatcherParams& matcher_params,
                              const PostFilterParams& filter_params) {
  std::string err = matcher_params.validate();
  if (!err.empty()) throw std::invalid_argument("RobustMatcher: " + err);
  err = filter_params.validate();
  if (!err.empty()) throw std::invalid_argument("RobustMatcher: " + err);
  matcher_params_ = matcher_params;
  filter_params_ = filter_params;
}

namespace {

/// Everything one row needs at one window size.
struct LevelContext {
  const MatcherParams* mp;
  const FrameData* im;
  bool uniform_ranges;  // no per-pixel range: every pixel searches [dmin, dmax] (cut at borders)
  int level;
  int w, r;
  int width, height;
  int dmin, dmax;
  cv::Mat* state;  // 1 = accepted earlier
  cv::Mat* window_idx;
  // Per row: the columns still open (requested range, not accepted), sorted; built at the
  // row's first sparse window size, filtered at each later one, so the larger windows never scan
  // whole rows; open_level = the window size (level) the list is for (-1: none yet).
  std::vector<std::vector<int>>* open_rows;
  std::vector<int>* open_level;
  std::vector<int>* n_req_rows;  // per row: pixels with a requested range (first window)
  MatchResult* out;
};

// Window box sum of a CV_32S integral image at (x, y), half width r. The integral may have
// wrapped modulo 2^32 (wrappedIntegrals): every window sum of this matcher (at most 32 x 32 terms
// of magnitude <= 1020^2) lies in (-2^31, 2^31), so the four-corner difference taken modulo 2^32
// is the exact sum.
inline double boxAt(const cv::Mat& integral, int x, int y, int r) {
  const uint32_t* top = integral.ptr<uint32_t>(y - r);
  const uint32_t* bot = integral.ptr<uint32_t>(y + r + 1);
  return static_cast<double>(
      static_cast<int32_t>((bot[x + r + 1] - top[x + r + 1]) - (bot[x - r] - top[x - r])));
}

typedef uint32_t V8u __attribute__((vector_size(32)));
// Eight bytes (per-pixel codes and flags) and their masks, selected as bytes.
typedef uint8_t V8u8 __attribute__((vector_size(8)));
typedef int8_t V8s8 __attribute__((vector_size(8)));

/// Inclusive prefix sum over the 8 lanes of @p v (three shifted adds), plus @p carry in every lane.
ES_INLINE V8u lanePrefix(V8u v, V8u carry) {
  const V8u z = {0, 0, 0, 0, 0, 0, 0, 0};
  v += __builtin_shufflevector(z, v, 0, 8, 9, 10, 11, 12, 13, 14);
  v += __builtin_shufflevector(z, v, 0, 1, 8, 9, 10, 11, 12, 13);
  v += __builtin_shufflevector(z, v, 0, 1, 2, 3, 8, 9, 10, 11);
  return v + carry;
}
ES_INLINE V8u lastLane(V8u v) { return __builtin_shufflevector(v, v, 7, 7, 7, 7, 7, 7, 7, 7); }

/// One row of the four integral images (see wrappedIntegrals): out[x + 1] = out_above[x + 1] +
/// the row's prefix sum up to x, for v, v^2, g, g^2; modulo 2^32. Eight columns at a time (the
/// row's prefix sums within a vector by shifted adds, the running total carried from vector to
/// vector), the rest one by one; unsigned 32-bit additions, so the same values in any order.
ES_KERNEL void integralRow(int W, const uint8_t* __restrict v, const int16_t* __restrict g,
                           const uint32_t* __restrict pv, const uint32_t* __restrict ps,
                           const uint32_t* __restrict pg, const uint32_t* __restrict pq,
                           uint32_t* __restrict ov, uint32_t* __restrict os,
                           uint32_t* __restrict og, uint32_t* __restrict oq) {
  typedef uint8_t V8b __attribute__((vector_size(8)));
  typedef int16_t V8s __attribute__((vector_size(16)));
  typedef int32_t V8i32 __attribute__((vector_size(32)));
  ov[0] = os[0] = og[0] = oq[0] = 0;
  V8u cv = {0, 0, 0, 0, 0, 0, 0, 0}, cs = cv, cg = cv, cq = cv;
  auto put = [](uint32_t* o, const uint32_t* p, V8u sum) {
    V8u above;
    std::memcpy(&above, p, sizeof(above));
    const V8u out = sum + above;
    std::memcpy(o, &out, sizeof(out));
  };
  int x = 0;
  for (; x + 8 <= W; x += 8) {
    V8b vb;
    V8s gs;
    std::memcpy(&vb, v + x, sizeof(vb));
    std::memcpy(&gs, g + x, sizeof(gs));
    const V8u a = __builtin_convertvector(vb, V8u);
    const V8i32 gi = __builtin_convertvector(gs, V8i32);
    cv = lanePrefix(a, cv);
    cs = lanePrefix(a * a, cs);
    cg = lanePrefix(reinterpret_cast<V8u>(gi), cg);
    cq = lanePrefix(reinterpret_cast<V8u>(gi * gi), cq);
    put(ov + x + 1, pv + x + 1, cv);
    put(os + x + 1, ps + x + 1, cs);
    put(og + x + 1, pg + x + 1, cg);
    put(oq + x + 1, pq + x + 1, cq);
    cv = lastLane(cv);
    cs = lastLane(cs);
    cg = lastLane(cg);
    cq = lastLane(cq);
  }
  uint32_t rv = cv[0], rs = cs[0], rg = cg[0], rq = cq[0];
  for (; x < W; ++x) {
    const uint32_t vv = v[x];
    const int32_t gg = g[x];
    rv += vv;
    rs += vv * vv;
    rg += static_cast<uint32_t>(gg);
    rq += static_cast<uint32_t>(gg * gg);
    ov[x + 1] = rv + pv[x + 1];
    os[x + 1] = rs + ps[x + 1];
    og[x + 1] = rg + pg[x + 1];
    oq[x + 1] = rq + pq[x + 1];
  }
}

/// Integral images (CV_32S, (H + 1) x (W + 1), zero first row and column) of v and v^2 for the
/// 8-bit image @p img and of g and g^2 for its Laplacian @p lap (CV_16S), all modulo 2^32 (the
/// sum of v is cv::integral's CV_32S result wherever that does not overflow), in one pass: half
/// the memory of double integrals, and box sums in 8-lane integer vectors. Exact through boxAt
/// and the row kernels (see boxAt).
void wrappedIntegrals(const cv::Mat& img, const cv::Mat& lap, cv::Mat& sum, cv::Mat& sq,
                      cv::Mat& int_lap, cv::Mat& sq_lap) {
  const int H = img.rows, W = img.cols;
  sum.create(H + 1, W + 1, CV_32S);
  sq.create(H + 1, W + 1, CV_32S);
  int_lap.create(H + 1, W + 1, CV_32S);
  sq_lap.create(H + 1, W + 1, CV_32S);
  std::fill(sum.ptr<uint32_t>(0), sum.ptr<uint32_t>(0) + W + 1, 0u);
  std::fill(sq.ptr<uint32_t>(0), sq.ptr<uint32_t>(0) + W + 1, 0u);
  std::fill(int_lap.ptr<uint32_t>(0), int_lap.ptr<uint32_t>(0) + W + 1, 0u);
  std::fill(sq_lap.ptr<uint32_t>(0), sq_lap.ptr<uint32_t>(0) + W + 1, 0u);
  for (int y = 0; y < H; ++y) {
    integralRow(W, img.ptr<uint8_t>(y), lap.ptr<int16_t>(y), sum.ptr<uint32_t>(y),
                sq.ptr<uint32_t>(y), int_lap.ptr<uint32_t>(y), sq_lap.ptr<uint32_t>(y),
                sum.ptr<uint32_t>(y + 1), sq.ptr<uint32_t>(y + 1), int_lap.ptr<uint32_t>(y + 1),
                sq_lap.ptr<uint32_t>(y + 1));
  }
}

/// Left statistics of column x of row y (inside the border), into s.maps. The same expressions
/// as statsRowInt/gammaRowInt, so lazily and row-wide computed values are identical.
// n * sum(x^2) - sum(x)^2 is exact in double (integers below 2^53); the rest runs in float,
// which vectorises twice as wide. Every path uses these two functions, so values agree.
inline float invStd(double n, double sum, double sq) {
  const double a = n * sq - sum * sum;
  return a > 0.5 ? 1.f / std::sqrt(static_cast<float>(a) / static_cast<float>(n)) : 0.f;
}
inline float gammaOf(double n, double sum, double sq) {
  const double a = n * sq - sum * sum;  // n^2 times the variance of the Laplacian
  return std::sqrt(std::max(0.f, static_cast<float>(a))) / static_cast<float>(n);
}

inline void computeMapL(const LevelContext& c, Scratch& s, int x, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  const double sum = boxAt(c.im->int_l, x, y, c.r);
  const double sq = boxAt(c.im->sq_l, x, y, c.r);
  s.maps.mean_l[x] = static_cast<float>((sum - 128.0 * n) / n);
  s.maps.inv_l[x] = invStd(n, sum, sq);
}
inline void computeGammaL(const LevelContext& c, Scratch& s, int x, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  s.maps.gamma_l[x] = gammaOf(n, boxAt(c.im->int_lap_l, x, y, c.r),
                              boxAt(c.im->sq_lap_l, x, y, c.r));
}
inline void computeMapR(const LevelContext& c, Scratch& s, int q, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  const double sum = boxAt(c.im->int_r, q, y, c.r);
  const double sq = boxAt(c.im->sq_r, q, y, c.r);
  s.maps.sum_r[q] = static_cast<float>(sum - 128.0 * n);
  s.maps.inv_r[q] = invStd(n, sum, sq);
}
inline void computeGammaR(const LevelContext& c, Scratch& s, int q, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  s.maps.gamma_r[q] = gammaOf(n, boxAt(c.im->int_lap_r, q, y, c.r),
                              boxAt(c.im->sq_lap_r, q, y, c.r));
}

// The row-wide statistics are the same expressions as invStd/gammaOf, split into passes that
// vectorise: the double part, then the float square roots with SSE (the scalar std::sqrt keeps
// an errno branch that blocks vectorisation). IEEE division, square root and conversions are
// correctly rounded in vector and scalar form alike, so the values are bit-identical to the
// lazily computed ones.
/// p[i] := p[i] > 0 ? 1 / sqrt(p[i]) : 0, and (second form) p[i] := sqrt(p[i]) / den (p >= 0).
void invSqrtRow(int n, float* p) {
  int i = 0;
#if defined(__SSE2__)
  const __m128 one = _mm_set1_ps(1.f), zero = _mm_setzero_ps();
  for (; i + 4 <= n; i += 4) {
    const __m128 v = _mm_loadu_ps(p + i);
    const __m128 r = _mm_div_ps(one, _mm_sqrt_ps(v));
    _mm_storeu_ps(p + i, _mm_and_ps(_mm_cmpgt_ps(v, zero), r));
  }
#endif
  for (; i < n; ++i) p[i] = p[i] > 0.f ? 1.f / std::sqrt(p[i]) : 0.f;
}
void sqrtDivRow(int n, float* p, float den) {
  int i = 0;
#if defined(__SSE2__)
  const __m128 dv = _mm_set1_ps(den);
  for (; i + 4 <= n; i += 4) {
    _mm_storeu_ps(p + i, _mm_div_ps(_mm_sqrt_ps(_mm_loadu_ps(p + i)), dv));
  }
#endif
  for (; i < n; ++i) p[i] = std::sqrt(p[i]) / den;
}

/// First pass of the NCC statistics of row y, columns [x0, x1], window sums read from the
/// integral images as boxAt reads them: mean (left) or sum (right) of the window, and in @p inv
/// the quotient (n sum L^2 - (sum L)^2) / n where it exceeds the flatness threshold, else 0;
/// invSqrtRow turns it into the value of invStd. a > 0.5 gives a quotient of at least
/// 0.5 / 1024 (windows up to 32 x 32): > 0 marks it.
template <bool kAsMean>
ES_INLINE void statsRowIntImpl(const cv::Mat& int_sum, const cv::Mat& int_sq, int y, int r, int x0,
                               int x1, double n, float* __restrict mean_or_sum,
                               float* __restrict inv) {
  const uint32_t* __restrict ts = int_sum.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bs = int_sum.ptr<uint32_t>(y + r + 1);
  const uint32_t* __restrict tq = int_sq.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bq = int_sq.ptr<uint32_t>(y + r + 1);
  const float nf = static_cast<float>(n);
  for (int x = x0; x <= x1; ++x) {
    const double sum = static_cast<double>(
        static_cast<int32_t>((bs[x + r + 1] - ts[x + r + 1]) - (bs[x - r] - ts[x - r])));
    const double sq = static_cast<double>(
        static_cast<int32_t>((bq[x + r + 1] - tq[x + r + 1]) - (bq[x - r] - tq[x - r])));
    const double a = n * sq - sum * sum;
    const float q = static_cast<float>(a) / nf;  // unconditional: the loop vectorises
    inv[x] = a > 0.5 ? q : 0.f;
    mean_or_sum[x] = kAsMean ? static_cast<float>((sum - 128.0 * n) / n)
                             : static_cast<float>(sum - 128.0 * n);
  }
}
ES_KERNEL void statsRowInt(const cv::Mat& int_sum, const cv::Mat& int_sq, int y, int r, int x0,
                           int x1, double n, float* mean_or_sum, float* inv, bool as_mean) {
  if (as_mean) {
    statsRowIntImpl<true>(int_sum, int_sq, y, r, x0, x1, n, mean_or_sum, inv);
  } else {
    statsRowIntImpl<false>(int_sum, int_sq, y, r, x0, x1, n, mean_or_sum, inv);
  }
}
/// First pass of the structure values of row y: max(0, n sum G^2 - (sum G)^2) as float;
/// sqrtDivRow turns it into the value of gammaOf.
ES_KERNEL void gammaRowInt(const cv::Mat& int_sum, const cv::Mat& int_sq, int y, int r, int x0,
                           int x1, double n, float* __restrict g) {
  const uint32_t* __restrict ts = int_sum.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bs = int_sum.ptr<uint32_t>(y + r + 1);
  const uint32_t* __restrict tq = int_sq.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bq = int_sq.ptr<uint32_t>(y + r + 1);
  for (int x = x0; x <= x1; ++x) {
    const double sum = static_cast<double>(
        static_cast<int32_t>((bs[x + r + 1] - ts[x + r + 1]) - (bs[x - r] - ts[x - r])));
    const double sq = static_cast<double>(
        static_cast<int32_t>((bq[x + r + 1] - tq[x + r + 1]) - (bq[x - r] - tq[x - r])));
    const double a = n * sq - sum * sum;
    g[x] = std::max(0.f, static_cast<float>(a));
  }
}

/// All statistics of row y (columns r .. W - 1 - r), as computeMapL/R give them one by one.
/// With @p with_gamma false only the NCC statistics are computed, on columns [x0, x1] (the
/// structure values are then computed lazily where needed).
void computeRowMaps(const LevelContext& c, Scratch& s, int y, bool with_gamma = true, int x0 = -1,
                    int x1 = -1) {
  const int r = c.r;
  if (x0 < 0) {
    x0 = r;
    x1 = c.width - 1 - r;
  }
  const double n = static_cast<double>(c.w) * c.w;
  statsRowInt(c.im->int_l, c.im->sq_l, y, r, x0, x1, n, s.maps.mean_l.data(), s.maps.inv_l.data(),
              true);
  invSqrtRow(x1 - x0 + 1, s.maps.inv_l.data() + x0);
  statsRowInt(c.im->int_r, c.im->sq_r, y, r, x0, x1, n, s.maps.sum_r.data(), s.maps.inv_r.data(),
              false);
  invSqrtRow(x1 - x0 + 1, s.maps.inv_r.data() + x0);
  if (!with_gamma) {
    // Mirrored copies for the sparse engine's profiles: R statistics at x - d for increasing d.
    const int W = c.width;
    for (int x = x0; x <= x1; ++x) {
      s.maps.sum_r_rev[W - 1 - x] = s.maps.sum_r[x];
      s.maps.inv_r_rev[W - 1 - x] = s.maps.inv_r[x];
    }
    return;
  }
  gammaRowInt(c.im->int_lap_l, c.im->sq_lap_l, y, r, x0, x1, n, s.maps.gamma_l.data());
  sqrtDivRow(x1 - x0 + 1, s.maps.gamma_l.data() + x0, static_cast<float>(n));
  gammaRowInt(c.im->int_lap_r, c.im->sq_lap_r, y, r, x0, x1, n, s.maps.gamma_r.data());
  sqrtDivRow(x1 - x0 + 1, s.maps.gamma_r.data() + x0, static_cast<float>(n));
}

/// Right NCC statistics of row y on columns [x0, x1] (inside the border), vectorised, with their
/// mirrored copies, marked computed for this row: the same values needMapR gives one by one.
void rowMapsR(const LevelContext& c, Scratch& s, int y, int x0, int x1) {
  if (x0 > x1) return;
  const double n = static_cast<double>(c.w) * c.w;
  statsRowInt(c.im->int_r, c.im->sq_r, y, c.r, x0, x1, n, s.maps.sum_r.data(), s.maps.inv_r.data(),
              false);
  invSqrtRow(x1 - x0 + 1, s.maps.inv_r.data() + x0);
  const int W = c.width;
  for (int x = x0; x <= x1; ++x) {
    s.maps.sum_r_rev[W - 1 - x] = s.maps.sum_r[x];
    s.maps.inv_r_rev[W - 1 - x] = s.maps.inv_r[x];
    s.maps.stamp_r[x] = s.stamp;
  }
}

/// Left NCC statistics of row y on the columns of [x0, x1] (inside the border) not yet computed
/// for this row, vectorised per run of such columns, marked computed: the same values needMapL
/// gives one by one (the lazy form cost a scalar box sum per column and was the larger part of
/// the sparse rows' right-to-left profiles with per-pixel ranges).
void ensureMapsL(const LevelContext& c, Scratch& s, int y, int x0, int x1) {
  const double n = static_cast<double>(c.w) * c.w;
  int* stamp = s.maps.stamp_l.data();
  int x = x0;
  while (x <= x1) {
    if (stamp[x] == s.stamp) {
      ++x;
      continue;
    }
    int e = x;
    while (e + 1 <= x1 && stamp[e + 1] != s.stamp) ++e;
    statsRowInt(c.im->int_l, c.im->sq_l, y, c.r, x, e, n, s.maps.mean_l.data(),
                s.maps.inv_l.data(), true);
    invSqrtRow(e - x + 1, s.maps.inv_l.data() + x);
    std::fill(stamp + x, stamp + e + 1, s.stamp);
    x = e + 1;
  }
}

inline void needMapL(const LevelContext& c, Scratch& s, int x, int y) {
  if (s.maps.stamp_l[x] != s.stamp) {
    computeMapL(c, s, x, y);
    s.maps.stamp_l[x] = s.stamp;
  }
}
inline void needMapR(const LevelContext& c, Scratch& s, int q, int y) {
  if (s.maps.stamp_r[q] != s.stamp) {
    computeMapR(c, s, q, y);
    s.maps.stamp_r[q] = s.stamp;
  }
}
inline void needGammaL(const LevelContext& c, Scratch& s, int x, int y) {
  if (s.maps.stamp_gl[x] != s.stamp) {
    computeGammaL(c, s, x, y);
    s.maps.stamp_gl[x] = s.stamp;
  }
}
inline void needGammaR(const LevelContext& c, Scratch& s, int q, int y) {
  if (s.maps.stamp_gr[q] != s.stamp) {
    computeGammaR(c, s, q, y);
    s.maps.stamp_gr[q] = s.stamp;
  }
}

/// Effective range of pixel (x, y) at this window: its requested range, cut so that both windows
/// lie inside the images. @return false when empty (also outside [r, W - r)).
inline bool effectiveRange(const LevelContext& c, const Scratch& s, int x, int* lo, int* hi) {
  if (x < c.r || x >= c.width - c.r) return false;
  *lo = std::max(s.rlo_row[x], x - (c.width - 1 - c.r));
  *hi = std::min(s.rhi_row[x], x - c.r);
  return *lo <= *hi;
}

// ---------------------------------------------------------------------------------------------
// Dense engine.
// ---------------------------------------------------------------------------------------------

/// Make the vertical window sums of disparity index k valid on the columns @p need (sorted,
/// disjoint intervals) of row y: columns already computed for row y are kept, columns valid for
/// row y - 1 are updated by one row in and one row out, the rest are summed afresh over the
/// window's rows. All exact, so the three ways give identical values.
void ensureV(const LevelContext& c, Scratch& s, int k, int y, const std::vector<Interval>& need) {
  const int d = c.dmin + k;
  const int r = c.r;
  const cv::Mat& lf = c.im->lf;
  const cv::Mat& rf = c.im->rf;
  VValidity& vv = s.valid[k];
  if (vv.cur_row != y) {
    if (vv.cur_row == y - 1) {
      std::swap(vv.prev, vv.cur);
    } else {
      vv.prev.clear();
    }
    vv.cur.clear();
    vv.cur_row = y;
  }
  float* v = s.v.data() + static_cast<size_t>(k) * c.width;
  // The common case: the same intervals as on the previous row (a smooth range map moves its
  // intervals only now and then).
  if (vv.cur.empty() && vv.prev.size() == need.size() &&
      std::equal(need.begin(), need.end(), vv.prev.begin(),
                 [](const Interval& p, const Interval& q) { return p.a == q.a && p.b == q.b; })) {
    for (const Interval& iv : need) {
      const int ra = iv.a, n = iv.b - ra + 1;
      vRunning(n, v + ra, lf.ptr<float>(y + r) + ra, rf.ptr<float>(y + r) + ra - d,
               lf.ptr<float>(y - r - 1) + ra, rf.ptr<float>(y - r - 1) + ra - d);
    }
    vv.cur = need;
    return;
  }
  // pieces := need minus cur.
  s.pieces.clear();
  size_t ci = 0;
  for (const Interval& nv : need) {
    int x = nv.a;
    while (ci < vv.cur.size() && vv.cur[ci].b < x) ++ci;
    for (size_t j = ci; j < vv.cur.size() && vv.cur[j].a <= nv.b; ++j) {
      if (vv.cur[j].a > x) s.pieces.push_back({x, vv.cur[j].a - 1});
      x = std::max(x, vv.cur[j].b + 1);
    }
    if (x <= nv.b) s.pieces.push_back({x, nv.b});
  }
  if (s.pieces.empty()) return;
  auto fresh = [&](int fa, int fb) {
    const int n = fb - fa + 1;
    vSet(n, v + fa, lf.ptr<float>(y - r) + fa, rf.ptr<float>(y - r) + fa - d);
    for (int yy = y - r + 1; yy <= y + r; ++yy) {
      vAdd(n, v + fa, lf.ptr<float>(yy) + fa, rf.ptr<float>(yy) + fa - d);
    }
  };
  size_t pi = 0;
  for (const Interval& p : s.pieces) {
    int px = p.a;
    while (pi < vv.prev.size() && vv.prev[pi].b < px) ++pi;
    for (size_t j = pi; j < vv.prev.size() && vv.prev[j].a <= p.b; ++j) {
      const Interval& iv = vv.prev[j];
      if (iv.a > px) fresh(px, iv.a - 1);
      const int ra = std::max(px, iv.a), e = std::min(p.b, iv.b);
      // prev is only set when row y - 1 was computed, so y - r - 1 >= 0 here.
      vRunning(e - ra + 1, v + ra, lf.ptr<float>(y + r) + ra, rf.ptr<float>(y + r) + ra - d,
               lf.ptr<float>(y - r - 1) + ra, rf.ptr<float>(y - r - 1) + ra - d);
      px = e + 1;
      if (px > p.b) break;
    }
    if (px <= p.b) fresh(px, p.b);
  }
  // cur := cur U pieces (both sorted and disjoint).
  s.merged.clear();
  size_t i = 0, j = 0;
  while (i < vv.cur.size() || j < s.pieces.size()) {
    const Interval next =
        (j >= s.pieces.size() || (i < vv.cur.size() && vv.cur[i].a < s.pieces[j].a))
            ? vv.cur[i++]
            : s.pieces[j++];
    if (!s.merged.empty() && next.a <= s.merged.back().b + 1) {
      s.merged.back().b = std::max(s.merged.back().b, next.b);
    } else {
      s.merged.push_back(next);
    }
  }
  std::swap(vv.cur, s.merged);
}

/// For each disparity, the column intervals worth computing: the hull, within each block of
/// kBlock columns, of the columns @p cols (sorted), for the blocks where one of them has the
/// disparity in its effective range; intervals closer than a window width are merged (their
/// vertical sums overlap anyway). Clipped to the columns where both windows fit. Results in
/// s.ivs / s.iv_start. Cost O(columns + blocks * disparities).
void buildIntervals(const LevelContext& c, Scratch& s, const std::vector<int>& cols) {
  const int W = c.width, nd = c.dmax - c.dmin + 1, r = c.r;
  const int nb = static_cast<int>(s.block_a.size());
  // Coverage per block as a difference array over the disparity indices (kept all zero between
  // calls: only the indices a block touched are cleared again below), and the span it touches.
  // Only coverage > 0 matters, so a pixel with the same range as the pixel before it in its
  // block adds nothing (the common case: neighbours' ranges are alike), and skipping it also
  // spares the chain of increments of one counter, each waiting for the one before.
  s.blocks.clear();
  int last_k0 = -1, last_k1 = -1, cur_b = -1;
  const int* __restrict elo = s.elo_i.data();
  const int* __restrict ehi = s.ehi_i.data();
  int* __restrict block_a = s.block_a.data();
  int* __restrict block_b = s.block_b.data();
  int* __restrict block_k0 = s.block_k0.data();
  int* __restrict block_k1 = s.block_k1.data();
  int* __restrict cover = s.cover.data();
  const int dmin = c.dmin;
  for (const int x : cols) {
    const int b = x / kBlock;  // x >= 0
    const int k0 = elo[x] - dmin, k1 = ehi[x] - dmin;
    if (b != cur_b) {
      cur_b = b;
      s.blocks.push_back(b);
      block_a[b] = x;
      block_k0[b] = nd;
      block_k1[b] = -1;
    } else if (k0 == last_k0 && k1 == last_k1) {
      block_b[b] = x;
      continue;
    }
    last_k0 = k0;
    last_k1 = k1;
    int* cv = cover + static_cast<size_t>(b) * (nd + 1);
    ++cv[k0];
    --cv[k1 + 1];
    block_k0[b] = std::min(block_k0[b], k0);
    block_k1[b] = std::max(block_k1[b], k1);
    block_b[b] = x;
  }
  // Blocks in column order, each over the disparities it covers: every disparity's intervals
  // come out sorted by column and merged exactly as a scan of all blocks per disparity would.
  std::fill(s.iv_count.begin(), s.iv_count.begin() + nd, 0);
  for (int b : s.blocks) {
    int* cv = s.cover.data() + static_cast<size_t>(b) * (nd + 1);
    const int k0 = s.block_k0[b], k1 = s.block_k1[b];
    int count = 0;
    for (int k = k0; k <= k1; ++k) {
      count += cv[k];
      cv[k] = 0;
      if (count <= 0) continue;
      const int d = c.dmin + k;
      const int lo = std::max(r, d + r), hi = std::min(W - 1 - r, d + W - 1 - r);
      const int a = std::max(lo, s.block_a[b]), e = std::min(hi, s.block_b[b]);
      if (a > e) continue;
      Interval* list = s.iv_by_k.data() + static_cast<size_t>(k) * nb;
      int& n = s.iv_count[k];
      if (n > 0 && list[n - 1].b + c.w >= a) {
        list[n - 1].b = e;
      } else {
        list[n++] = {a, e};
      }
    }
    cv[k1 + 1] = 0;
  }
  s.ivs.clear();
  for (int k = 0; k < nd; ++k) {
    s.iv_start[k] = static_cast<int>(s.ivs.size());
    const Interval* list = s.iv_by_k.data() + static_cast<size_t>(k) * nb;
    s.ivs.insert(s.ivs.end(), list, list + s.iv_count[k]);
  }
  s.iv_start[nd] = static_cast<int>(s.ivs.size());
}

/// NCC slice of disparity index k over columns [a, b] of row y, fed to the peak tracker (own
/// profiles and right-to-left profiles); the vertical sums v (of disparity k) must be valid on
/// [a - r, b + r].
void sliceRange(const LevelContext& c, Scratch& s, int k, int a, int b, const float* v) {
  const int d = c.dmin + k;
  const int r = c.r;
  // Up to 15 columns the horizontal sum is read straight from the vertical sums inside the
  // tracker; beyond, the doubling passes are cheaper.
  const bool direct = c.w <= 15;
  {
    const int ra = a, rb = b;
    if (ra > rb) return;
    const int n = rb - ra + 1;
    SliceArgs g;
    g.n = n;
    g.w = c.w;
    g.d = static_cast<float>(d);
    if (direct) {
      g.v = v + ra - r;
      g.h = nullptr;
    } else {
      boxSumRow(v + ra - r, n, c.w, s.hsum.data(), s.tmp_a.data(), s.tmp_b.data());
      g.v = nullptr;
      g.h = s.hsum.data();
    }
    g.mean_l = s.maps.mean_l.data() + ra;
    g.inv_l = s.maps.inv_l.data() + ra;
    g.sum_r = s.maps.sum_r.data() + ra - d;
    g.inv_r = s.maps.inv_r.data() + ra - d;
    g.elo = s.elo.data() + ra;
    g.ehi = s.ehi.data() + ra;
    g.act = s.act.data() + ra;
    g.p1 = s.p1.data() + ra;
    g.p2 = s.p2.data() + ra;
    g.best = s.best.data() + ra;
    g.best_d = s.best_d.data() + ra;
    g.best_l = s.best_l.data() + ra;
    g.best_r = s.best_r.data() + ra;
    g.second = s.second.data() + ra;
    g.rb_v = s.rb_v.data() + ra - d;
    g.rb_d = s.rb_d.data() + ra - d;
    if (direct && c.w == 7) {
      sliceOwnAndRl7(g);
    } else {
      sliceOwnAndRl(g);
    }
  }
}

/// NCC slices of disparity index k over the column intervals @p out_ivs (sorted, disjoint) of
/// row y (per-pixel ranges).
void denseSlices(const LevelContext& c, Scratch& s, int k, int y, const Interval* out_ivs,
                 int count) {
  if (count <= 0) return;
  const int r = c.r;
  s.need.clear();
  for (int i = 0; i < count; ++i) {
    const int a = out_ivs[i].a - r, b = out_ivs[i].b + r;
    if (!s.need.empty() && a <= s.need.back().b + 1) {
      s.need.back().b = std::max(s.need.back().b, b);
    } else {
      s.need.push_back({a, b});
    }
  }
  ensureV(c, s, k, y, s.need);
  const float* v = s.v.data() + static_cast<size_t>(k) * c.width;
  for (int i = 0; i < count; ++i) sliceRange(c, s, k, out_ivs[i].a, out_ivs[i].b, v);
}

// ---------------------------------------------------------------------------------------------
// Sparse engine.
// ---------------------------------------------------------------------------------------------

/// The disparity indices [k0, k1] column x's sums must hold at row y: the union of the effective
/// ranges of the pixels whose windows contain the column (the only NCC values it feeds), widened
/// to whole 8-lane groups. Cached per row.
inline void columnRequest(const LevelContext& c, Scratch& s, int x, int* k0, int* k1) {
  if (s.req_stamp[x] == s.stamp) {
    *k0 = s.req_k0[x];
    *k1 = s.req_k1[x];
    return;
  }
  int lo, hi;
  if (c.uniform_ranges) {
    lo = std::max(c.dmin, x - c.width + 1);
    hi = std::min(c.dmax, x);
  } else {
    lo = std::numeric_limits<int>::max();
    hi = std::numeric_limits<int>::min();
    for (int xx = std::max(c.r, x - c.r); xx <= std::min(c.width - 1 - c.r, x + c.r); ++xx) {
      int a, b;
      if (!effectiveRange(c, s, xx, &a, &b)) continue;
      lo = std::min(lo, a);
      hi = std::max(hi, b);
    }
    if (lo > hi) lo = hi = c.dmin;
  }
  // Whole 8-lane groups (lo, hi >= dmin: bit operations instead of signed divisions).
  *k0 = (lo - c.dmin) & ~7;
  *k1 = std::min(s.dpad - 1, (hi - c.dmin) | 7);
  s.req_stamp[x] = s.stamp;
  s.req_k0[x] = *k0;
  s.req_k1[x] = *k1;
}

/// Running update of column x's sums from row y - 1 to row y, over its held window.
inline void columnRunning(const LevelContext& c, Scratch& s, int x, int y) {
  const int r = c.r;
  const int k0 = s.col_k0[x], n = s.col_k1[x] - k0 + 1;
  float* cs = s.colsum.data() + static_cast<size_t>(x) * s.dpad + k0;
  // rf_rev(y', rev_pad + W - 1 - x') = rf(y', x'), so R(y', x - d) = rf_rev(y', base + k).
  const int base = c.im->rev_pad + c.width - 1 - x + c.dmin + k0;
  colRunning(n, cs, c.im->lf.ptr<float>(y + r)[x], c.im->rf_rev.ptr<float>(y + r) + base,
             c.im->lf.ptr<float>(y - r - 1)[x], c.im->rf_rev.ptr<float>(y - r - 1) + base);
  s.col_row[x] = y;
}

/// Make column x's vertical window sums valid for row y on the disparities it is asked for:
/// running update from row y - 1 when that is what it holds, else summed afresh. The right image
/// is read mirrored, so R(y', x - d) for increasing d is contiguous. A column computed afresh
/// joins the stripe's hot columns, which are carried down by running sums while they keep being
/// used (see updateHotColumns), so a failed region spanning many rows costs one row in and one
/// row out per row, not a whole window.
inline void ensureColumn(const LevelContext& c, Scratch& s, int x, int y) {
  if (s.col_done[x] == s.stamp) return;  // already made valid for this row's request
  s.col_done[x] = s.stamp;
  int k0, k1;
  columnRequest(c, s, x, &k0, &k1);
  s.col_used[x] = y;
  const bool covers = s.col_k0[x] <= k0 && k1 <= s.col_k1[x];
  if (s.col_row[x] == y && covers) return;
  if (s.col_row[x] == y - 1 && covers) {
    columnRunning(c, s, x, y);
    return;
  }
  if (s.col_row[x] == y || s.col_row[x] == y - 1) {
    k0 = std::min(k0, s.col_k0[x]);
    k1 = std::max(k1, s.col_k1[x]);
  }
  const int r = c.r;
  const int n = k1 - k0 + 1;
  float* cs = s.colsum.data() + static_cast<size_t>(x) * s.dpad + k0;
  const cv::Mat& lf = c.im->lf;
  const cv::Mat& rr = c.im->rf_rev;
  const int base = c.im->rev_pad + c.width - 1 - x + c.dmin + k0;
  colFresh(n, cs, lf.ptr<float>(y - r) + x, lf.step1(), rr.ptr<float>(y - r) + base, rr.step1(),
           c.w);
  s.col_k0[x] = k0;
  s.col_k1[x] = k1;
  if (s.col_row[x] < y - 1) s.hot.push_back(x);
  s.col_row[x] = y;
}

/// Running update of the hot columns from row y - 1 to row y. Column x holds sums of
/// scalar(y', x) * run(y', base0 + step * x + k) over the window's rows: the left-indexed sums
/// (scalar L, run the mirrored R, step -1) and the right-indexed ones (scalar R, run the padded L,
/// step +1) share it.
ES_KERNEL void hotRunning(int count, const int* __restrict cols, int base0, int step, int dp,
                          const int* __restrict k0, const int* __restrict k1,
                          const float* __restrict s_in, const float* __restrict v_in,
                          const float* __restrict s_out, const float* __restrict v_out,
                          float* __restrict colsum) {
  for (int i = 0; i < count; ++i) {
    const int x = cols[i];
    const int a = k0[x], n = k1[x] - a + 1;
    float* __restrict cs = colsum + static_cast<size_t>(x) * dp + a;
    const int base = base0 + step * x + a;
    colStep(n, cs, s_in[x], v_in + base, s_out[x], v_out + base);
  }
}

/// Carry the hot columns of one set of column sums to row y; drop those not used for a few rows
/// (a column used once should not be carried for the rest of the stripe: a running step costs 2
/// products per disparity, a fresh sum w).
void carryHotColumns(const LevelContext& c, int y, std::vector<int>& hot, std::vector<int>& row,
                     const std::vector<int>& used, const std::vector<int>& k0,
                     const std::vector<int>& k1, std::vector<float>& colsum, int dp,
                     const cv::Mat& scalar_img, const cv::Mat& run_img, int base0, int step) {
  const int keep = std::max(2, c.w / 4);
  size_t out = 0;
  for (size_t i = 0; i < hot.size(); ++i) {
    const int x = hot[i];
    if (row[x] != y - 1 || y - used[x] > keep) continue;
    row[x] = y;
    hot[out++] = x;
  }
  hot.resize(out);
  if (out == 0) return;
  const int r = c.r;
  hotRunning(static_cast<int>(out), hot.data(), base0, step, dp, k0.data(), k1.data(),
             scalar_img.ptr<float>(y + r), run_img.ptr<float>(y + r),
             scalar_img.ptr<float>(y - r - 1), run_img.ptr<float>(y - r - 1), colsum.data());
}

// Left-indexed column sums: L(y', x) the scalar, R(y', x - d) read mirrored (rf_rev).
void updateHotColumns(const LevelContext& c, Scratch& s, int y) {
  carryHotColumns(c, y, s.hot, s.col_row, s.col_used, s.col_k0, s.col_k1, s.colsum, s.dpad,
                  c.im->lf, c.im->rf_rev, c.im->rev_pad + c.width - 1 + c.dmin, -1);
}

// Right-indexed column sums (see Scratch::colsum_r): the same three ways to make a column valid
// (kept, one row in and one out, afresh), the same hot-column carrying. R(y', q) is the scalar,
// L(y', q + d) for increasing d the contiguous run (lf_pad).
void updateHotColumnsR(const LevelContext& c, Scratch& s, int y) {
  carryHotColumns(c, y, s.hot_r, s.colr_row, s.colr_used, s.colr_k0, s.colr_k1, s.colsum_r,
                  s.dpad, c.im->rf, c.im->lf_pad, c.im->l_pad + c.dmin, +1);
}

/// Make right column q's sums valid for row y on disparity indices [k0, k1] (whole 8-lane groups).
inline void ensureColumnR(const LevelContext& c, Scratch& s, int q, int y, int k0, int k1) {
  s.colr_used[q] = y;
  const bool covers = s.colr_k0[q] <= k0 && k1 <= s.colr_k1[q];
  if (s.colr_row[q] == y && covers) return;
  const int r = c.r;
  const cv::Mat& lp = c.im->lf_pad;
  const cv::Mat& rf = c.im->rf;
  if (s.colr_row[q] == y - 1 && covers) {
    const int a = s.colr_k0[q], n = s.colr_k1[q] - a + 1;
    const int base = c.im->l_pad + q + c.dmin + a;
    colRunning(n, s.colsum_r.data() + static_cast<size_t>(q) * s.dpad + a,
               rf.ptr<float>(y + r)[q], lp.ptr<float>(y + r) + base, rf.ptr<float>(y - r - 1)[q],
               lp.ptr<float>(y - r - 1) + base);
    s.colr_row[q] = y;
    return;
  }
  if (s.colr_row[q] == y || s.colr_row[q] == y - 1) {
    k0 = std::min(k0, s.colr_k0[q]);
    k1 = std::max(k1, s.colr_k1[q]);
  }
  const int n = k1 - k0 + 1;
  float* cs = s.colsum_r.data() + static_cast<size_t>(q) * s.dpad + k0;
  const int base = c.im->l_pad + q + c.dmin + k0;
  colFresh(n, cs, rf.ptr<float>(y - r) + q, rf.step1(), lp.ptr<float>(y - r) + base, lp.step1(),
           c.w);
  s.colr_k0[q] = k0;
  s.colr_k1[q] = k1;
  if (s.colr_row[q] < y - 1) s.hot_r.push_back(q);
  s.colr_row[q] = y;
}

/// S(x, d) for d = lo .. lo + n - 1 of one left pixel (mean_l, inv_l) against the mirrored right
/// statistics (index i = d - lo). The same expression as nccValue.
template <int kN>
ES_INLINE void nccProfileN(int n, const float* __restrict h, float mean_l, float inv_l,
                           const float* __restrict sum_r_rev, const float* __restrict inv_r_rev,
                           float* __restrict out) {
  const int m = kN > 0 ? kN : n;
  for (int i = 0; i < m; ++i) out[i] = (h[i] - mean_l * sum_r_rev[i]) * inv_l * inv_r_rev[i];
}
/// S over a profile of n disparities (n == 64, the full search, with the count fixed at
/// compile time).
ES_KERNEL void nccProfile(int n, const float* __restrict h, float mean_l, float inv_l,
                          const float* __restrict sum_r_rev, const float* __restrict inv_r_rev,
                          float* __restrict out) {
  if (n == 64) {
    nccProfileN<64>(n, h, mean_l, inv_l, sum_r_rev, inv_r_rev, out);
  } else {
    nccProfileN<0>(n, h, mean_l, inv_l, sum_r_rev, inv_r_rev, out);
  }
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

/// One 8-lane group of a dense pixel's profile: S for the lanes k .. k + 7, stored to prof, and
/// the right-to-left offers; with kMasked only the lanes inside [klo, khi] offer.
template <bool kMasked>
ES_INLINE void laneGroup(int k, V8i kk, V8f dv, V8i vklo, V8i vkhi, V8f ml, V8f il,
                         const float* __restrict h, const float* __restrict srr,
                         const float* __restrict irr, float* __restrict prof,
                         float* __restrict rbv, float* __restrict rbd) {
  const V8f sv = (load8(h + k) - ml * load8(srr + k)) * il * load8(irr + k);
  store8(prof + k, sv);
  const V8f rv = load8(rbv + k);
  V8i up = sv > rv;
  if (kMasked) up &= (kk >= vklo) & (kk <= vkhi);
  store8(rbv + k, up ? sv : rv);
  store8(rbd + k, up ? dv : load8(rbd + k));
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
/// after by lane shifts. The dense engine stores a profile's groups just before it analyses
/// them, and a load at prof + k - 1 straddles two of those stores, which the store buffer cannot
/// forward (a stall per group); the values are the same.
template <bool kMasked>
ES_INLINE void peakGroupReg(V8f prev, V8f v, V8f next, V8i kk, V8i vklo, V8i vkhi, V8f& bv,
                            V8f& sv, V8i& bk) {
  foldPeaks<kMasked>(v, __builtin_shufflevector(prev, v, 7, 8, 9, 10, 11, 12, 13, 14),
                     __builtin_shufflevector(v, next, 1, 2, 3, 4, 5, 6, 7, 8), kk, vklo, vkhi, bv,
                     sv, bk);
}

/// The groups g0 .. g1 of one dense pixel (lanePass2): its profile S formed and offered to the
/// right-to-left trackers (laneGroup), then, for an active pixel, the peak trackers folded over it
/// with each group's neighbours in registers (peakGroupReg; whole vector loads, forwarded from
/// the stores just made; the lanes whose neighbour lies outside g0 .. g1 are masked: range
/// ends). kNG > 0: g1 - g0 + 1 == kNG, known at compile time.
template <int kNG>
ES_INLINE void pixelGroups(int g0, int g1, V8i kk0, V8f dv0, V8i vklo, V8i vkhi, V8f ml, V8f il,
                           const float* __restrict h, const float* __restrict srr,
                           const float* __restrict irr, float* __restrict prof,
                           float* __restrict rbvm, float* __restrict rbdm, bool act, V8f& bv,
                           V8f& sv, V8i& bk) {
  const V8f eight_f = splat8(8.f);
  const V8i eight_i = {8, 8, 8, 8, 8, 8, 8, 8};
  const int n = kNG > 0 ? kNG : g1 - g0 + 1;
  laneGroup<true>(8 * g0, kk0, dv0, vklo, vkhi, ml, il, h, srr, irr, prof, rbvm, rbdm);
  {
    V8f dv = dv0 + eight_f;
    V8i kk = kk0 + eight_i;
    for (int j = 1; j < n - 1; ++j, dv += eight_f, kk += eight_i) {
      laneGroup<false>(8 * (g0 + j), kk, dv, vklo, vkhi, ml, il, h, srr, irr, prof, rbvm, rbdm);
    }
    if (n > 1) laneGroup<true>(8 * g1, kk, dv, vklo, vkhi, ml, il, h, srr, irr, prof, rbvm, rbdm);
  }
  if (!act) return;
  V8f prev = splat8(kNegInf), cur = load8(prof + 8 * g0);
  V8f next = load8(prof + 8 * g0 + 8);
  peakGroupReg<true>(prev, cur, next, kk0, vklo, vkhi, bv, sv, bk);
  V8i kk = kk0 + eight_i;
  for (int j = 1; j < n - 1; ++j, kk += eight_i) {
    prev = cur;
    cur = next;
    next = load8(prof + 8 * (g0 + j) + 8);
    peakGroupReg<false>(prev, cur, next, kk, vklo, vkhi, bv, sv, bk);
  }
  if (n > 1) peakGroupReg<true>(cur, next, load8(prof + 8 * g1 + 8), kk, vklo, vkhi, bv, sv, bk);
}

/// Peak analysis of one complete profile prof[0..n) (disparities lo..lo+n-1, n >= 3), the same
/// rules as the dense engines: per lane the best interior maximum (first of equal values), its
/// index and the lane's best other maximum, then butterfly reductions. prof[-1] and whole groups
/// past n must be readable (masked).
ES_KERNEL void scanProfile(const float* __restrict prof, int n, int lo, float* best,
                           float* best_d, float* best_l, float* best_r, float* second) {
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i eight_i = {8, 8, 8, 8, 8, 8, 8, 8};
  const V8i vklo = {0, 0, 0, 0, 0, 0, 0, 0};
  const int khi = n - 1;
  const V8i vkhi = {khi, khi, khi, khi, khi, khi, khi, khi};
  V8f bv = splat8(kNegInf), sv = splat8(kNegInf);
  V8i bk = {0, 0, 0, 0, 0, 0, 0, 0};
  const int g1 = khi / 8;
  V8i kk = lane;
  if (n == 64) {
    // A full search of 64: only the first and the last group hold a range end (masked); the
    // count fixed at compile time.
    peakGroup<true>(0, kk, vklo, vkhi, prof, bv, sv, bk);
    kk += eight_i;
    for (int g = 1; g < 7; ++g, kk += eight_i) {
      peakGroup<false>(8 * g, kk, vklo, vkhi, prof, bv, sv, bk);
    }
    peakGroup<true>(56, kk, vklo, vkhi, prof, bv, sv, bk);
  } else {
    for (int g = 0; g <= g1; ++g, kk += eight_i) {
      peakGroup<true>(8 * g, kk, vklo, vkhi, prof, bv, sv, bk);
    }
  }
  const V8f bmax = hmax8(bv);
  const float b = bmax[0];
  float sec = kNegInf;
  if (b != kNegInf) {
    const int big = std::numeric_limits<int>::max();
    const V8i cand = bv == bmax ? bk : V8i{big, big, big, big, big, big, big, big};
    const int bi = hmin8(cand)[0];
    const V8i sel = bk == V8i{bi, bi, bi, bi, bi, bi, bi, bi};
    sec = hmax8(sel ? sv : bv)[0];
    *best_d = static_cast<float>(lo + bi);
    *best_l = prof[bi - 1];
    *best_r = prof[bi + 1];
  }
  if (prof[0] > prof[1]) sec = std::max(sec, prof[0]);
  if (prof[khi] > prof[khi - 1]) sec = std::max(sec, prof[khi]);
  *best = b;
  *second = sec;
}

// ---------------------------------------------------------------------------------------------
// Dense engine, lanes over disparity. For each column x the vertical window sums of
// L(x, y') R(x - d, y') are held for all the disparities it feeds, contiguous in d (the right
// view is read mirrored), and carried from row to row by one row in and one row out. A pixel's
// window sums are then w columns added lane by lane (or, with a full search, slid along the row),
// its profile S(x, d) is formed 8 disparities at a time, analysed by scanProfile (the same
// rules as the sparse engine), and offered to the right-to-left tracker of every right pixel
// x - d, held mirrored so that it too is contiguous in d. Pixels are visited in increasing x, so
// each right pixel sees its disparities in increasing order: strict > keeps the smallest d.
// ---------------------------------------------------------------------------------------------

/// Per-column groups for a stripe with per-pixel ranges: the union of the requested ranges of the
/// stripe's pixels whose windows contain the column (a superset of what the column feeds).
void stripeSpans(const LevelContext& c, Scratch& s, int stripe) {
  const int W = c.width, r = c.r;
  const int y0 = std::max(r, stripe * kStripeRows);
  const int y1 = std::min(c.height - r, (stripe + 1) * kStripeRows);
  std::vector<int>& lo = s.span_lo;  // per column: min lo / max hi over the stripe's rows
  std::vector<int>& hi = s.span_hi;
  std::fill(lo.begin(), lo.begin() + W, kEmptyLo);
  std::fill(hi.begin(), hi.begin() + W, kEmptyHi);
  for (int y = y0; y < y1; ++y) {
    const int* rl = c.im->range_lo.ptr<int>(y);
    const int* rh = c.im->range_hi.ptr<int>(y);
    for (int x = 0; x < W; ++x) {
      if (rl[x] > rh[x]) continue;
      lo[x] = std::min(lo[x], rl[x]);
      hi[x] = std::max(hi[x], rh[x]);
    }
  }
  for (int x = 0; x < W; ++x) {
    int a = kEmptyLo, b = kEmptyHi;
    for (int xx = std::max(0, x - r); xx <= std::min(W - 1, x + r); ++xx) {
      a = std::min(a, lo[xx]);
      b = std::max(b, hi[xx]);
    }
    if (a > b) {
      s.vl_g0[x] = 0;
      s.vl_g1[x] = -1;
    } else {
      s.vl_g0[x] = (a - c.dmin) / 8;
      s.vl_g1[x] = (b - c.dmin) / 8;
    }
  }
  s.span_stripe = stripe;
}

/// Inputs of the two passes of a dense row (pointers into the scratch and the frame).
struct LaneRowArgs {
  int width, r, w, dp, dmin, rev_pad, rp, rb_stride;
  bool running, slide;
  const int* g0;  // per column: groups held
  const int* g1;
  float* vl;
  const float* l_in;  // rows y + r and y - r - 1 of L, and of the mirrored R
  const float* l_out;
  const float* r_in;
  const float* r_out;
  const float* const* l_rows;  // the w rows of the window (afresh)
  const float* const* r_rows;
  const int* elo;  // effective ranges (empty: lo > hi)
  const int* ehi;
  const float* act;
  const float* mean_l;
  const float* inv_l;
  const float* srr;  // mirrored right statistics, trackers
  const float* irr;
  float* rbv;
  float* rbd;
  float* h;     // dp + 16
  float* prof;  // dp + 24, index k at prof[k] (prof[-1] valid)
  float *best, *best_d, *best_l, *best_r, *second;
};

/// v[k] += li * ri[k] - lo * ro[k] for k < n (a multiple of 8): one row in and one out of a
/// column's vertical sums, the group count fixed at compile time where byGroups can.
ES_INLINE void laneRunning(int n, float* __restrict v, V8f li, V8f lo, const float* __restrict ri,
                           const float* __restrict ro) {
  byGroups(n, [&](auto groups) __attribute__((always_inline)) {
    constexpr int kG = decltype(groups)::value;
    const int m = kG > 0 ? 8 * kG : n;
    for (int k = 0; k < m; k += 8) {
      store8(v + k, load8(v + k) + (li * load8(ri + k) - lo * load8(ro + k)));
    }
  });
}

/// Pass 1: the vertical sums of every column for the row, one row in and one out, or afresh.
ES_KERNEL void lanePass1(const LaneRowArgs& a) {
  const int W = a.width, dp = a.dp;
  for (int x = 0; x < W; ++x) {
    const int g0 = a.g0[x], g1 = a.g1[x];
    if (g0 > g1) continue;
    const int k0 = 8 * g0, n = 8 * (g1 - g0 + 1);
    // rf_rev(y', rev_pad + W - 1 - x') = rf(y', x'): R(y', x - d_k) = rf_rev(y', base + k).
    const int base = a.rev_pad + W - 1 - x + a.dmin + k0;
    float* __restrict v = a.vl + static_cast<size_t>(x) * dp + k0;
    if (a.running) {
      const V8f li = splat8(a.l_in[x]), lo = splat8(a.l_out[x]);
      laneRunning(n, v, li, lo, a.r_in + base, a.r_out + base);
    } else {
      const V8f l0 = splat8(a.l_rows[0][x]);
      for (int k = 0; k < n; k += 8) store8(v + k, l0 * load8(a.r_rows[0] + base + k));
      for (int j = 1; j < a.w; ++j) {
        const V8f lj = splat8(a.l_rows[j][x]);
        const float* __restrict rr = a.r_rows[j] + base;
        for (int k = 0; k < n; k += 8) store8(v + k, load8(v + k) + lj * load8(rr + k));
      }
    }
  }
}

/// Pass 2: profiles, peak analysis of the active pixels, right-to-left offers. Peaks follow the
/// rules of scanProfile exactly (first index of the highest interior maximum; the highest other
/// interior maximum and rising range ends compete).
ES_KERNEL void lanePass2(const LaneRowArgs& a) {
  const int W = a.width, r = a.r, dp = a.dp, ng = dp / 8;
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8f lane_f = {0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f};
  const V8f vninf = splat8(kNegInf);
  float* __restrict h = a.h;
  float* __restrict prof = a.prof;
  if (a.slide) {
    for (int g = 0; g < ng; ++g) {
      V8f acc = load8(a.vl + 8 * g);
      for (int x = 1; x <= 2 * r; ++x) acc += load8(a.vl + static_cast<size_t>(x) * dp + 8 * g);
      store8(h + 8 * g, acc);
    }
  }
  for (int x = r; x <= W - 1 - r; ++x) {
    if (a.slide && x > r) {
      const float* __restrict in = a.vl + static_cast<size_t>(x + r) * dp;
      const float* __restrict out = a.vl + static_cast<size_t>(x - r - 1) * dp;
      addSubGroups(dp, h, in, out);  // the window slid by one column
    }
    const int lo = a.elo[x], hi = a.ehi[x];
    if (lo > hi) continue;
    const int klo = lo - a.dmin, khi = hi - a.dmin;
    const int g0 = klo >> 3, g1 = khi >> 3;  // klo, khi >= 0 (lo >= dmin)
    if (!a.slide) {
      for (int g = g0; g <= g1; ++g) {
        const float* col = a.vl + static_cast<size_t>(x - r) * dp + 8 * g;
        V8f acc = load8(col);
        for (int j = 1; j < a.w; ++j) acc += load8(col + static_cast<size_t>(j) * dp);
        store8(h + 8 * g, acc);
      }
    }
    // Mirrored index of right column x - d_k: m + k. The trackers come in 8 copies, one per
    // x mod 8: consecutive pixels address them one lane apart, and a load overlapping the
    // previous pixel's stores by all but one lane would stall (no store forwarding); within a
    // copy the offsets differ by whole vectors. The copies are merged after the row.
    const int m = a.rp + W - 1 - x + a.dmin;
    float* __restrict rbv = a.rbv + static_cast<size_t>(x & 7) * a.rb_stride;
    float* __restrict rbd = a.rbd + static_cast<size_t>(x & 7) * a.rb_stride;
    const V8f ml = splat8(a.mean_l[x]), il = splat8(a.inv_l[x]);
    const V8i vklo = V8i{klo, klo, klo, klo, klo, klo, klo, klo};
    const V8i vkhi = V8i{khi, khi, khi, khi, khi, khi, khi, khi};
    const float dk0 = static_cast<float>(a.dmin + 8 * g0);
    const V8f dv0 = lane_f + V8f{dk0, dk0, dk0, dk0, dk0, dk0, dk0, dk0};
    const V8i kk0 = lane + V8i{8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0};
    const float* srr = a.srr + m;
    const float* irr = a.irr + m;
    float* rbvm = rbv + m;
    float* rbdm = rbd + m;
    // Only the first and the last group can hold lanes outside the range. A pixel with the
    // whole range (most of them in a full search) takes the same steps with the group count
    // fixed at compile time: the loops unroll.
    V8f bv = vninf, sv = vninf;
    V8i bk = V8i{0, 0, 0, 0, 0, 0, 0, 0};
    const bool act = a.act[x] > 0.f;
    if (g1 - g0 == 7) {
      pixelGroups<8>(g0, g1, kk0, dv0, vklo, vkhi, ml, il, h, srr, irr, prof, rbvm, rbdm, act, bv,
                     sv, bk);
    } else {
      pixelGroups<0>(g0, g1, kk0, dv0, vklo, vkhi, ml, il, h, srr, irr, prof, rbvm, rbdm, act, bv,
                     sv, bk);
    }
    if (!act) continue;
    // The highest maximum at its smallest index (lanes hold distinct indices); every other
    // maximum competes for second.
    const V8f bmax = hmax8(bv);
    const float b = bmax[0];
    float sec = kNegInf;
    if (b != kNegInf) {
      const int big = std::numeric_limits<int>::max();
      const V8i cand = bv == bmax ? bk : V8i{big, big, big, big, big, big, big, big};
      const int bi = hmin8(cand)[0];
      const V8i sel = bk == V8i{bi, bi, bi, bi, bi, bi, bi, bi};
      sec = hmax8(sel ? sv : bv)[0];
      a.best_d[x] = static_cast<float>(a.dmin + bi);
      a.best_l[x] = prof[bi - 1];
      a.best_r[x] = prof[bi + 1];
    }
    if (prof[klo] > prof[klo + 1]) sec = std::max(sec, prof[klo]);
    if (prof[khi] > prof[khi - 1]) sec = std::max(sec, prof[khi]);
    a.best[x] = b;
    a.second[x] = sec;
  }
}

/// Merge the 8 tracker copies into the first: the highest value, ties to the smallest d (the
/// order-free form of "strict >, disparities in increasing order").
ES_KERNEL void laneMergeTrackers(float* __restrict rbv, float* __restrict rbd, int stride, int n) {
  for (int c = 1; c < 8; ++c) {
    const float* __restrict v = rbv + static_cast<size_t>(c) * stride;
    const float* __restrict d = rbd + static_cast<size_t>(c) * stride;
    int i = 0;
    for (; i + 8 <= n; i += 8) {  // eight lanes, the same rule lane by lane
      const V8f vi = load8(v + i), bi = load8(rbv + i), di = load8(d + i), ci = load8(rbd + i);
      const V8i up = (vi > bi) | ((vi == bi) & (di < ci));
      store8(rbv + i, up ? vi : bi);
      store8(rbd + i, up ? di : ci);
    }
    for (; i < n; ++i) {
      const bool up = v[i] > rbv[i] || (v[i] == rbv[i] && d[i] < rbd[i]);
      rbv[i] = up ? v[i] : rbv[i];
      rbd[i] = up ? d[i] : rbd[i];
    }
  }
}

/// One dense row: every pixel with an effective range gets its profile (active pixels also
/// their peak analysis) and offers it to the right-to-left trackers; s.rb_d receives the
/// right-to-left best disparity of every right pixel.
void denseLanesRow(const LevelContext& c, Scratch& s, int y) {
  const int W = c.width, r = c.r, w = c.w;
  const int dp = s.dpad, ng = dp / 8;
  const int stripe = y / kStripeRows;
  if (s.span_stripe != stripe) {
    if (c.uniform_ranges) {
      std::fill(s.vl_g0.begin(), s.vl_g0.end(), 0);
      std::fill(s.vl_g1.begin(), s.vl_g1.end(), ng - 1);
      s.span_stripe = stripe;
    } else {
      stripeSpans(c, s, stripe);
    }
    s.vl_row = -10;
  }
  const bool running = s.vl_row == y - 1;
  const cv::Mat& lf = c.im->lf;
  const cv::Mat& rr = c.im->rf_rev;
  const float* l_rows[33];
  const float* r_rows[33];
  for (int j = 0; j < w; ++j) {
    l_rows[j] = lf.ptr<float>(y - r + j);
    r_rows[j] = rr.ptr<float>(y - r + j);
  }
  // Mirrored right statistics and trackers of this row (zero / empty outside the border).
  const int rp = s.rpad;
  std::fill(s.srr.begin(), s.srr.end(), 0.f);
  std::fill(s.irr.begin(), s.irr.end(), 0.f);
  const int used = rp + W + 16, stride = s.rb_stride;
  float* const rbv = s.rb_buf.data();
  float* const rbd = rbv + s.rb_d_off;
  for (int c = 0; c < 8; ++c) {
    std::fill_n(rbv + static_cast<size_t>(c) * stride, used, kNegInf);
    std::fill_n(rbd + static_cast<size_t>(c) * stride, used, 0.f);
  }
  for (int q = r; q <= W - 1 - r; ++q) {
    s.srr[rp + W - 1 - q] = s.maps.sum_r[q];
    s.irr[rp + W - 1 - q] = s.maps.inv_r[q];
  }
  LaneRowArgs a;
  a.width = W;
  a.r = r;
  a.w = w;
  a.dp = dp;
  a.dmin = c.dmin;
  a.rev_pad = c.im->rev_pad;
  a.rp = rp;
  a.rb_stride = stride;
  a.running = running;
  a.slide = c.uniform_ranges;
  a.g0 = s.vl_g0.data();
  a.g1 = s.vl_g1.data();
  a.vl = s.vl.data();
  a.l_in = lf.ptr<float>(y + r);
  a.r_in = rr.ptr<float>(y + r);
  a.l_out = running ? lf.ptr<float>(y - r - 1) : nullptr;
  a.r_out = running ? rr.ptr<float>(y - r - 1) : nullptr;
  a.l_rows = l_rows;
  a.r_rows = r_rows;
  a.elo = s.elo_i.data();
  a.ehi = s.ehi_i.data();
  a.act = s.act.data();
  a.mean_l = s.maps.mean_l.data();
  a.inv_l = s.maps.inv_l.data();
  a.srr = s.srr.data();
  a.irr = s.irr.data();
  a.rbv = rbv;
  a.rbd = rbd;
  a.h = s.hrow.data();
  a.prof = s.lprof.data() + 8;
  a.best = s.best.data();
  a.best_d = s.best_d.data();
  a.best_l = s.best_l.data();
  a.best_r = s.best_r.data();
  a.second = s.second.data();
  lanePass1(a);
  s.vl_row = y;
  lanePass2(a);
  laneMergeTrackers(rbv, rbd, stride, used);
  for (int q = 0; q < W; ++q) s.rb_d[q] = rbd[rp + W - 1 - q];
}

/// Profiles of the active pixels of row y (phase A), from per-column sums.
/// Per-pixel ranges: the disparity indices each column of the run of active pixels
/// s.active[i..j] must hold, the union of the effective ranges of the run's pixels whose windows
/// contain it (the column sums feed only these pixels' profiles; the right-to-left profiles have
/// their own sums), cached for columnRequest.
void runRequests(const LevelContext& c, Scratch& s, size_t i, size_t j) {
  const int r = c.r;
  const int a = s.active[i], b = s.active[j];
  int* lo = s.run_lo.data();  // index x - a
  int* hi = s.run_hi.data();
  std::fill(lo, lo + (b - a + 1), kEmptyLo);
  std::fill(hi, hi + (b - a + 1), kEmptyHi);
  for (size_t t = i; t <= j; ++t) {
    const int x = s.active[t];
    int el, eh;
    if (effectiveRange(c, s, x, &el, &eh)) {
      lo[x - a] = el;
      hi[x - a] = eh;
    }
  }
  // Column x = a - r + t reads the pixels [t - 2r, t] of the run (index x - a): a sliding minimum
  // and maximum over 2r + 1 values, three passes whatever the window (van Herk / Gil-Werman).
  const int m = b - a + 1, k = 2 * r + 1, len = m + 4 * r;
  const int len_pad = (len + k - 1) / k * k;
  int* pl = s.vh_lo.data();
  int* ph = s.vh_hi.data();
  int* gl = s.vh_glo.data();
  int* gh = s.vh_ghi.data();
  for (int j = 0; j < len_pad; ++j) {
    const int i = j - 2 * r;
    const bool in = (i >= 0) & (i < m);
    pl[j] = in ? lo[in ? i : 0] : kEmptyLo;
    ph[j] = in ? hi[in ? i : 0] : kEmptyHi;
  }
  for (int j0 = 0; j0 < len_pad; j0 += k) {
    gl[j0] = pl[j0];
    gh[j0] = ph[j0];
    for (int j = j0 + 1; j < j0 + k; ++j) {  // prefix within the block
      gl[j] = std::min(gl[j - 1], pl[j]);
      gh[j] = std::max(gh[j - 1], ph[j]);
    }
    for (int j = j0 + k - 2; j >= j0; --j) {  // suffix within the block, in place
      pl[j] = std::min(pl[j], pl[j + 1]);
      ph[j] = std::max(ph[j], ph[j + 1]);
    }
  }
  for (int x = a - r; x <= b + r; ++x) {
    const int t = x - (a - r);
    int l = std::min(pl[t], gl[t + k - 1]);
    int h = std::max(ph[t], gh[t + k - 1]);
    if (l > h) l = h = c.dmin;
    s.req_stamp[x] = s.stamp;
    s.req_k0[x] = (l - c.dmin) & ~7;  // whole groups (l, h >= dmin)
    s.req_k1[x] = std::min(s.dpad - 1, (h - c.dmin) | 7);
  }
}

void sparseProfiles(const LevelContext& c, Scratch& s, int y) {
  const int r = c.r;
  const int dp = s.dpad;
  const size_t na = s.active.size();
  size_t i = 0;
  while (i < na) {
    // A run of active pixels whose windows overlap: the horizontal sum slides along it.
    size_t j = i;
    while (j + 1 < na && s.active[j + 1] <= s.active[j] + c.w) ++j;
    const int a = s.active[i], b = s.active[j];
    if (!c.uniform_ranges) {
      runRequests(c, s, i, j);
      // The right statistics the run's profiles read (columns x - d), row-wide at once.
      int dlo = c.dmax, dhi = c.dmin;
      for (size_t t = i; t <= j; ++t) {
        int el, eh;
        if (effectiveRange(c, s, s.active[t], &el, &eh)) {
          dlo = std::min(dlo, el);
          dhi = std::max(dhi, eh);
        }
      }
      if (dlo <= dhi) rowMapsR(c, s, y, std::max(r, a - dhi), std::min(c.width - 1 - r, b - dlo));
      // The run's own left statistics, at once.
      ensureMapsL(c, s, y, a, b);
    }
    // Lanes the run's profiles read: the union of its columns' requests (every column of a
    // pixel's window holds that pixel's range).
    int k0 = dp, k1 = -1;
    for (int x = a - r; x <= b + r; ++x) {
      ensureColumn(c, s, x, y);
      k0 = std::min(k0, s.req_k0[x]);
      k1 = std::max(k1, s.req_k1[x]);
    }
    const int nk = k1 - k0 + 1;
    float* h = s.hvec.data();
    const float* cs0 = s.colsum.data() + k0;
    std::memcpy(h + k0, cs0 + static_cast<size_t>(a - r) * dp, sizeof(float) * nk);
    for (int x = a - r + 1; x <= a + r; ++x) vecAdd(nk, h + k0, cs0 + static_cast<size_t>(x) * dp);
    size_t next = i;
    for (int x = a; x <= b; ++x) {
      if (next <= j && s.active[next] == x) {
        ++next;
        int lo = 0, hi = -1;
        effectiveRange(c, s, x, &lo, &hi);
        // Statistics at hand: row-wide for uniform rows, computed for the run above with
        // per-pixel ranges (left, and right mirrored: x - d for d = lo .. hi).
        const int m = c.width - 1 - x + lo;  // mirrored index of x - lo
        nccProfile(hi - lo + 1, h + (lo - c.dmin), s.maps.mean_l[x], s.maps.inv_l[x],
                   s.maps.sum_r_rev.data() + m, s.maps.inv_r_rev.data() + m, s.prof0);
        scanProfile(s.prof0, hi - lo + 1, lo, &s.best[x], &s.best_d[x], &s.best_l[x],
                    &s.best_r[x], &s.second[x]);
      }
      if (x < b) {
        vecAddSub(nk, h + k0, cs0 + static_cast<size_t>(x + r + 1) * dp,
                  cs0 + static_cast<size_t>(x - r) * dp);
      }
    }
    i = j + 1;
  }
}

ES_KERNEL void nccSpan(int n, const float* __restrict h, const float* __restrict mean_l,
                       const float* __restrict inv_l, float sum_r, float inv_r,
                       float* __restrict out) {
  for (int i = 0; i < n; ++i) out[i] = (h[i] - mean_l[i] * sum_r) * inv_l[i] * inv_r;
}

/// Index of the first greatest of v[0..n) (n >= 1, no NaN); v[n .. n + 7] is overwritten (the
/// profile buffer is padded).
ES_KERNEL int firstMax(float* __restrict v, int n) {
  for (int i = n; i < n + 8; ++i) v[i] = kNegInf;
  V8f m = splat8(kNegInf);
  for (int i = 0; i < n; i += 8) m = max8(m, load8(v + i));
  const V8f best = hmax8(m);
  int i = 0;
  while (!anyLane(load8(v + i) == best)) i += 8;
  while (v[i] != best[0]) ++i;
  return i;
}

/// v[i] := -inf where ok[i] is 0 (only the disparities a left pixel searches compete).
ES_KERNEL void maskOut(int n, float* __restrict v, const int* __restrict ok) {
  for (int i = 0; i < n; ++i) v[i] = ok[i] ? v[i] : kNegInf;
}

/// Right-to-left profile of right pixel q (phase B): the best d of S(q + d, d) over the left
/// pixels q + d whose effective range holds d. Ties keep the smallest d, as in the dense engine.
void sparseRightToLeft(const LevelContext& c, Scratch& s, int q, int y) {
  const int r = c.r;
  // Disparities whose left pixel q + d has d in its range: all of them inside the border with a
  // full search; with per-pixel ranges (narrow) usually a few, and only their columns are needed.
  int dv0 = std::max(c.dmin, r - q), dv1 = std::min(c.dmax, c.width - 1 - r - q);
  int first_ok = 0;  // per-pixel ranges: index in s.rl_ok of dv0 after the cut below
  if (!c.uniform_ranges) {
    // The disparities d whose left pixel q + d holds d in its effective range, listed once.
    // q is inside the border and q + d is too (dv0, dv1), so pixel q + d's effective range holds
    // d exactly when its requested range does.
    // A mask over [dv0, dv1] (index d - dv0), then the span from the first to the last one.
    const int n = std::max(0, dv1 - dv0 + 1);
    s.rl_ok.resize(static_cast<size_t>(n) + 8);
    int* ok = s.rl_ok.data();
    const int* rl = s.rlo_row + q + dv0;
    const int* rh = s.rhi_row + q + dv0;
    for (int i = 0; i < n; ++i) ok[i] = ((rl[i] <= dv0 + i) & (dv0 + i <= rh[i])) ? -1 : 0;
    int first = 0, last = n - 1;
    while (first < n && !ok[first]) ++first;
    while (last >= first && !ok[last]) --last;
    if (first > last) {
      dv0 = 1;
      dv1 = 0;
    } else {
      first_ok = first;
      dv1 = dv0 + last;
      dv0 = dv0 + first;
    }
  }
  if (dv0 > dv1) {
    s.rb_v[q] = kNegInf;
    s.rb_d[q] = 0.f;
    return;
  }
  // S_RL(q, d) sums the right-indexed columns q - r .. q + r at entry d (q is inside the border:
  // it is x - d of a pixel whose right window fits).
  const int k0 = (dv0 - c.dmin) & ~7;  // whole groups (dv0, dv1 >= dmin)
  const int k1 = std::min(s.dpad - 1, (dv1 - c.dmin) | 7);
  float* h;
  const float* cs0 = s.colsum_r.data() + k0;
  const size_t dp = static_cast<size_t>(s.dpad);
  if (c.uniform_ranges && s.rl_stamp == s.stamp && s.rl_q == q - 1 && s.rl_k0 == k0 &&
      s.rl_k1 == k1) {
    // The previous right pixel's sums, slid by one column (its other columns are valid for this
    // row on these disparities already). Exact: integer-valued sums.
    ensureColumnR(c, s, q + r, y, k0, k1);
    h = s.hr.data();
    vecAddSub(k1 - k0 + 1, h + k0, cs0 + static_cast<size_t>(q + r) * dp,
              cs0 + static_cast<size_t>(q - r - 1) * dp);
  } else {
    for (int qq = q - r; qq <= q + r; ++qq) ensureColumnR(c, s, qq, y, k0, k1);
    h = s.hr.data();
    std::memcpy(h + k0, cs0 + static_cast<size_t>(q - r) * dp, sizeof(float) * (k1 - k0 + 1));
    for (int qq = q - r + 1; qq <= q + r; ++qq) vecAdd(k1 - k0 + 1, h + k0, cs0 + qq * dp);
  }
  if (c.uniform_ranges) {
    s.rl_stamp = s.stamp;
    s.rl_q = q;
    s.rl_k0 = k0;
    s.rl_k1 = k1;
  }
  const float sr = s.maps.sum_r[q], ir = s.maps.inv_r[q];
  // Left pixels inside the border: q + d in [r, W - 1 - r].
  const int d0 = std::max(c.dmin, r - q), d1 = std::min(c.dmax, c.width - 1 - r - q);
  float rv = kNegInf, rd = 0.f;
  if (!c.uniform_ranges) {
    needMapR(c, s, q, y);
    // The left statistics of the pixels q + dv0 .. q + dv1, vectorised, then the profile over
    // that span in one pass; only the listed disparities compete.
    ensureMapsL(c, s, y, q + dv0, q + dv1);
    float* v = s.prof0;
    const int n = dv1 - dv0 + 1;
    nccSpan(n, h + (dv0 - c.dmin), s.maps.mean_l.data() + q + dv0, s.maps.inv_l.data() + q + dv0,
            s.maps.sum_r[q], s.maps.inv_r[q], v);
    maskOut(n, v, s.rl_ok.data() + first_ok);
    const int i = firstMax(v, n);  // the first valid disparity is valid: a finite value
    rv = v[i];
    rd = static_cast<float>(dv0 + i);
  } else if (d0 <= d1) {
    float* v = s.prof0;
    const int n = d1 - d0 + 1;
    nccSpan(n, h + (d0 - c.dmin), s.maps.mean_l.data() + q + d0, s.maps.inv_l.data() + q + d0,
            sr, ir, v);
    // With a full search every left pixel inside the border has d in its range: the highest
    // value, at its smallest d (what "strict >, d increasing" keeps).
    const int i = firstMax(v, n);
    rv = v[i];
    rd = static_cast<float>(d0 + i);
  }
  s.rb_v[q] = rv;
  s.rb_d[q] = rd;
}

// ---------------------------------------------------------------------------------------------
// One row at one window size.
// ---------------------------------------------------------------------------------------------

/// Inputs of the decisions of a dense row (see processRow).
struct DecideArgs {
  int x0, x1;  // columns [x0, x1)
  const float* act;
  const float *best, *second, *best_d, *best_l, *best_r;
  const float *gamma_r, *rb_d;  // indexed by the right pixel q = x - best_d
  const int *rlo, *rhi;
  int dmin, dmax, level;
  float gmin, delta_min, min_ncc_full, min_ncc_narrow, eps;
  bool subpixel;
  uint8_t *code, *stw, *widx;
  float *disp, *conf;
};

/// The decisions of a dense row, eight columns at a time: the expressions of processRow's
/// per-pixel loop lane by lane (the same IEEE operations, so the same values), the two
/// right-pixel values gathered, and every output written through a select that keeps the old
/// value outside the active pixels. Columns from x0 + 8 * floor((x1 - x0) / 8) on are left to
/// the caller.
ES_KERNEL int decideDense(const DecideArgs& a) {
  const V8f vzero = splat8(0.f), vone = splat8(1.f), vninf = splat8(kNegInf);
  const V8f vgmin = splat8(a.gmin), vdelta = splat8(a.delta_min), veps = splat8(a.eps);
  const V8f vfull = splat8(a.min_ncc_full), vnarrow = splat8(a.min_ncc_narrow);
  const V8i vdmin = V8i{} + a.dmin, vdmax = V8i{} + a.dmax;
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i c_nopeak = V8i{} + static_cast<int>(kCodeNoPeak);
  const V8i c_struct = V8i{} + static_cast<int>(kCodeRejectStructure);
  const V8i c_gap = V8i{} + static_cast<int>(kCodeRejectPeakGap);
  const V8i c_lr = V8i{} + static_cast<int>(kCodeRejectLeftRight);
  const V8i c_acc = V8i{} + (static_cast<int>(kCodeAcceptedBase) + a.level);
  const V8u8 v_level8 = V8u8{} + static_cast<uint8_t>(a.level), v_one8 = V8u8{} + 1;
  int x = a.x0;
  for (; x + 8 <= a.x1; x += 8) {
    const V8i active = load8(a.act + x) > vzero;
    if (!anyLane(active)) continue;
    const V8f b = load8(a.best + x);
    const V8f bdf = load8(a.best_d + x);
    const V8i bd = __builtin_convertvector(bdf, V8i);
    const V8i q = (lane + x) - bd;
    V8f gr, rbd;
    for (int i = 0; i < 8; ++i) {
      gr[i] = a.gamma_r[q[i]];
      rbd[i] = a.rb_d[q[i]];
    }
    const V8f sec = load8(a.second + x);
    const V8f comp = sec == vninf ? splat8(-1.f) : sec;
    const V8f delta = b - comp;
    V8i rl, rh;
    std::memcpy(&rl, a.rlo + x, sizeof(rl));
    std::memcpy(&rh, a.rhi + x, sizeof(rh));
    const V8f min_ncc = ((rl > vdmin) | (rh < vdmax)) ? vnarrow : vfull;
    const V8i no_peak = b == vninf;
    const V8i flat = ~(gr > vgmin);
    const V8i gap = ~(delta > vdelta) | (b < min_ncc);
    const V8f diff = __builtin_convertvector(bd, V8f) - rbd;
    const V8f adiff = diff < vzero ? -diff : diff;
    const V8i lr = ~(adiff < veps);
    const V8i cd = no_peak ? c_nopeak : (flat ? c_struct : (gap ? c_gap : (lr ? c_lr : c_acc)));
    // Byte outputs selected as bytes (the masks narrowed once, not every byte row widened).
    V8u8 cb;
    std::memcpy(&cb, a.code + x, 8);
    const V8s8 active8 = __builtin_convertvector(active, V8s8);
    const V8u8 new_code = active8 ? __builtin_convertvector(cd, V8u8) : cb;
    std::memcpy(a.code + x, &new_code, 8);
    const V8i acc = active & (cd == c_acc);
    if (!anyLane(acc)) continue;
    V8f sub = vzero;
    if (a.subpixel) {
      const V8f bl = load8(a.best_l + x), br = load8(a.best_r + x);
      const V8f den = bl - 2.f * b + br;
      V8f t = (0.5f * (bl - br)) / den;
      t = t < splat8(-0.5f) ? splat8(-0.5f) : t;
      t = splat8(0.5f) < t ? splat8(0.5f) : t;
      sub = den < vzero ? t : vzero;
    }
    const V8f dv = __builtin_convertvector(bd, V8f) + sub;
    V8f cf = delta < vzero ? vzero : delta;
    cf = vone < cf ? vone : cf;
    store8(a.disp + x, acc ? dv : load8(a.disp + x));
    store8(a.conf + x, acc ? cf : load8(a.conf + x));
    V8u8 sb, wb;
    std::memcpy(&sb, a.stw + x, 8);
    std::memcpy(&wb, a.widx + x, 8);
    const V8s8 acc8 = __builtin_convertvector(acc, V8s8);
    const V8u8 ns = acc8 ? v_one8 : sb;
    const V8u8 nw = acc8 ? v_level8 : wb;
    std::memcpy(a.stw + x, &ns, 8);
    std::memcpy(a.widx + x, &nw, 8);
  }
  return x;
}

/// Effective range of each pixel of a dense row at one window size: its requested range
/// [rlo, rhi], cut so that both windows lie inside the images (empty - kEmptyLo > kEmptyHi, and
/// 1e9 > -1e9 as floats - outside [r, W - r) or when nothing is left). Branch-free (vectorised).
ES_KERNEL void denseRanges(int W, int r, const int* __restrict rlo, const int* __restrict rhi,
                           int* __restrict elo_i, int* __restrict ehi_i, float* __restrict elo,
                           float* __restrict ehi) {
  for (int x = 0; x < W; ++x) {
    const bool inside = (x >= r) & (x < W - r);
    int lo = std::max(rlo[x], x - (W - 1 - r));
    int hi = std::min(rhi[x], x - r);
    const bool ok = inside & (lo <= hi);
    lo = ok ? lo : kEmptyLo;
    hi = ok ? hi : kEmptyHi;
    elo_i[x] = lo;
    ehi_i[x] = hi;
    elo[x] = ok ? static_cast<float>(lo) : 1e9f;
    ehi[x] = ok ? static_cast<float>(hi) : -1e9f;
  }
}

/// The open pixels of a row at its first sparse window size, in column order into out (returns
/// how many): columns of [x0, x1) with a requested range (lo <= hi), not accepted yet (st == 0)
/// and, when capped (window_max_narrowed_px), the full range [dmin, dmax]. Eight columns at a
/// time; a group without an open pixel is skipped (with priors most pixels are narrowed).
ES_KERNEL int openColumns(int x0, int x1, const int* __restrict rlo, const int* __restrict rhi,
                          const uint8_t* __restrict st, bool capped, int dmin, int dmax,
                          int* __restrict out) {
  using namespace simd;
  const V8i vmin = {dmin, dmin, dmin, dmin, dmin, dmin, dmin, dmin};
  const V8i vmax = {dmax, dmax, dmax, dmax, dmax, dmax, dmax, dmax};
  const V8i vcap = capped ? V8i{-1, -1, -1, -1, -1, -1, -1, -1} : V8i{0, 0, 0, 0, 0, 0, 0, 0};
  int n = 0, x = x0;
  for (; x + 8 <= x1; x += 8) {
    V8i lo, hi;
    std::memcpy(&lo, rlo + x, sizeof(lo));
    std::memcpy(&hi, rhi + x, sizeof(hi));
    const V8i sv = {st[x], st[x + 1], st[x + 2], st[x + 3],
                    st[x + 4], st[x + 5], st[x + 6], st[x + 7]};
    const V8i m = (lo <= hi) & (sv == 0) & (~vcap | ((lo <= vmin) & (hi >= vmax)));
    if (!anyLane(m)) continue;
    for (int i = 0; i < 8; ++i) {
      out[n] = x + i;
      n += m[i] != 0;
    }
  }
  for (; x < x1; ++x) {
    out[n] = x;
    const bool full = (rlo[x] <= dmin) & (rhi[x] >= dmax);
    n += (rlo[x] <= rhi[x]) & (st[x] == 0) & (full | !capped);
  }
  return n;
}

/// The active pixels of a dense row (open at this window size: inside [r, W - r), a requested
/// range, not accepted yet; an effective range of at least 3 values; a left patch with
/// structure): act[x] = 1 (else 0); the open pixels that fail get their code. Returns how many
/// are active. Branch-free over the whole row.
ES_KERNEL int denseActive(int W, int r, const int* __restrict rlo, const int* __restrict rhi,
                          const uint8_t* __restrict st, const int* __restrict elo_i,
                          const int* __restrict ehi_i, const float* __restrict gl, float gmin,
                          uint8_t* __restrict code, float* __restrict act) {
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i vr = V8i{} + r, vend = V8i{} + (W - r), two = V8i{} + 2;
  const V8f vgmin = splat8(gmin), vone = splat8(1.f), vzero = splat8(0.f);
  const V8u8 c_nopeak = V8u8{} + static_cast<uint8_t>(kCodeNoPeak);
  const V8u8 c_struct = V8u8{} + static_cast<uint8_t>(kCodeRejectStructure);
  V8i count = V8i{};
  int x = 0;
  // Eight columns at a time: the expressions of the loop below lane by lane, byte outputs
  // selected as bytes.
  for (; x + 8 <= W; x += 8) {
    V8i rl, rh, lo, hi;
    std::memcpy(&rl, rlo + x, sizeof(rl));
    std::memcpy(&rh, rhi + x, sizeof(rh));
    std::memcpy(&lo, elo_i + x, sizeof(lo));
    std::memcpy(&hi, ehi_i + x, sizeof(hi));
    V8u8 sb, cb;
    std::memcpy(&sb, st + x, 8);
    std::memcpy(&cb, code + x, 8);
    const V8i xs = lane + x;
    const V8i unaccepted = __builtin_convertvector(sb == V8u8{}, V8i);
    const V8i searched = (xs >= vr) & (xs < vend) & (rl <= rh) & unaccepted & (lo <= hi);
    const V8i narrow = (hi - lo) < two;
    const V8i flat = ~(load8(gl + x) > vgmin);
    const V8s8 s8 = __builtin_convertvector(searched, V8s8);
    const V8s8 n8 = __builtin_convertvector(narrow, V8s8);
    const V8s8 f8 = __builtin_convertvector(flat, V8s8);
    const V8u8 nc = s8 ? (n8 ? c_nopeak : (f8 ? c_struct : cb)) : cb;
    std::memcpy(code + x, &nc, 8);
    const V8i a = searched & ~narrow & ~flat;
    store8(act + x, a ? vone : vzero);
    count -= a;  // -1 in active lanes
  }
  int na = 0;
  for (int i = 0; i < 8; ++i) na += count[i];
  for (; x < W; ++x) {
    const bool is_open = (x >= r) & (x < W - r) & (rlo[x] <= rhi[x]) & (st[x] == 0);
    const int lo = elo_i[x], hi = ehi_i[x];
    const bool searched = is_open & (lo <= hi);  // else outside the matchable area: code stays
    const bool narrow = hi - lo < 2;
    const bool flat = !(gl[x] > gmin);
    const uint8_t keep = code[x];
    code[x] = !searched ? keep
                        : (narrow ? uint8_t{kCodeNoPeak}
                                  : (flat ? uint8_t{kCodeRejectStructure} : keep));
    const bool a = searched & !narrow & !flat;
    act[x] = a ? 1.f : 0.f;
    na += a;
  }
  return na;
}

/// Match the active pixels of row y at one window size; writes only row y of the outputs.
void processRow(const LevelContext& c, int y, Scratch& s) {
  const int W = c.width;
  const int r = c.r;
  const int nd = c.dmax - c.dmin + 1;
  if (y < r || y >= c.height - r) return;
  ++s.stamp;

  const int range_row = c.uniform_ranges ? 0 : y;
  const int* rlo = c.im->range_lo.ptr<int>(range_row);
  const int* rhi = c.im->range_hi.ptr<int>(range_row);
  s.rlo_row = rlo;
  s.rhi_row = rhi;
  const uint8_t* st = c.state->ptr<uint8_t>(y);
  uint8_t* code = c.out->code.ptr<uint8_t>(y);
  const float gmin = static_cast<float>(c.mp->gamma_min);

  // Pixel x is open at this level when it lies inside the window's border, has a requested
  // range and was not accepted with a smaller window. Dense when most of the row is open (the
  // first window): every column's range and statistics are then needed and computed row-wide,
  // and openness is tested row-wide too (below). Sparse rows compute them where needed and keep
  // the open pixels as a list: built from the row at the row's first sparse level, then filtered
  // from level to level (a row never turns dense again: its open pixels only get fewer). The
  // first window counts the requested pixels and builds no list.
  std::vector<int>& open = (*c.open_rows)[y];
  int& open_level = (*c.open_level)[y];
  int n_open = 0;
  // Above window_max_narrowed_px only pixels with the full range stay open (the first window
  // is always tried; without per-pixel ranges no pixel is narrowed).
  const int cap_w = c.mp->window_max_narrowed_px;
  const bool capped = !c.uniform_ranges && c.level > 0 && cap_w > 0 && c.w > cap_w;
  const int dmin = c.dmin, dmax = c.dmax;
  // A per-pixel range narrower than [dmin, dmax] (the test behind min_ncc_narrowed too).
  auto narrowed = [&](int x) { return (rlo[x] > dmin) | (rhi[x] < dmax); };
  auto mayOpen = [&](int x) { return !capped | !narrowed(x); };
  if (c.level == 0) {
    for (int x = r; x < W - r; ++x) n_open += rlo[x] <= rhi[x];
    (*c.n_req_rows)[y] = n_open;
  } else if (open_level == c.level - 1) {
    // Drop the pixels accepted with the smaller windows and those the larger window's border
    // excludes (it only grows).
    size_t kept = 0;
    for (const int x : open) {
      open[kept] = x;
      kept += (st[x] == 0) & (x >= r) & (x < W - r) & mayOpen(x);
    }
    open.resize(kept);
    open_level = c.level;
    n_open = static_cast<int>(kept);
  } else {
    open.resize(W);
    n_open = openColumns(r, W - r, rlo, rhi, st, capped, dmin, dmax, open.data());
    open.resize(n_open);
  }
  // The engine choice only decides speed: both give the same values.
  // (The dense engines activate pixels row-wide, without the list: not with the cap.)
  const bool dense = n_open > 0 && 2 * n_open >= (*c.n_req_rows)[y] && !capped;
  if (!dense && c.level > 0) open_level = c.level;  // the list just built or filtered
  if (n_open == 0) return;
  if (dense) {
    // Effective range of each pixel at this window: its requested range, cut so that both
    // windows lie inside the images (empty outside [r, W - r)), also for pixels that are not
    // matched themselves (their ranges bound the right-to-left profiles).
    denseRanges(W, r, rlo, rhi, s.elo_i.data(), s.ehi_i.data(), s.elo.data(), s.ehi.data());
    computeRowMaps(c, s, y);
  } else {
    // The NCC statistics of the columns any open pixel's profiles or right-to-left checks can
    // touch (within the disparity span of an open pixel), vectorised; structure values lazily.
    // With per-pixel ranges (narrow: priors) few columns are touched: computed lazily instead.
    if (c.uniform_ranges) {
      // Open pixel x reads right statistics at x - d and, through the right-to-left profile of
      // x - d, left statistics at x - d + d' (d, d' in the range): columns x + lo_off .. x + hi_off.
      // Merged over the open pixels, so gaps between clusters of open pixels are skipped.
      const int lo_off = std::min({0, -c.dmax, c.dmin - c.dmax});
      const int hi_off = std::max({0, -c.dmin, c.dmax - c.dmin});
      int ia = -1, ib = -2;
      for (const int x : open) {
        const int a = x + lo_off, b = x + hi_off;
        if (a > ib + 1) {
          if (ia <= ib) computeRowMaps(c, s, y, false, std::max(r, ia), std::min(W - 1 - r, ib));
          ia = a;
        }
        ib = std::max(ib, b);
      }
      if (ia <= ib) computeRowMaps(c, s, y, false, std::max(r, ia), std::min(W - 1 - r, ib));
    }
  }
  // Active = open, effective range of at least 3 values (an interior maximum needs two
  // neighbours), left patch with structure. The other open pixels get their code here.
  s.active.clear();
  if (dense) {
    // Branch-free over the whole row: the effective ranges and structure values are all at
    // hand. act[x] = 1 marks the active pixels (the dense engines' list).
    const int na = denseActive(W, r, rlo, rhi, st, s.elo_i.data(), s.ehi_i.data(),
                               s.maps.gamma_l.data(), gmin, code, s.act.data());
    if (na == 0) return;
    std::fill(s.best.begin(), s.best.begin() + W, kNegInf);
    std::fill(s.second.begin(), s.second.begin() + W, kNegInf);
    std::fill(s.best_d.begin(), s.best_d.begin() + W, 0.f);
    std::fill(s.best_l.begin(), s.best_l.begin() + W, 0.f);
    std::fill(s.best_r.begin(), s.best_r.begin() + W, 0.f);
  } else {
    for (const int x : open) {
      int lo, hi;
      if (!effectiveRange(c, s, x, &lo, &hi)) continue;
      if (hi - lo < 2) {
        code[x] = kCodeNoPeak;
        continue;
      }
      needGammaL(c, s, x, y);
      if (!(s.maps.gamma_l[x] > gmin)) {
        code[x] = kCodeRejectStructure;
        continue;
      }
      s.active.push_back(x);
    }
    if (s.active.empty()) return;
    for (int x : s.active) {
      s.best[x] = s.second[x] = kNegInf;
      s.best_d[x] = s.best_l[x] = s.best_r[x] = 0.f;
    }
  }

  const float delta_min = static_cast<float>(c.mp->delta_min);
  const float min_ncc_full = static_cast<float>(c.mp->min_ncc);
  const float min_ncc_narrow = std::max(min_ncc_full, static_cast<float>(c.mp->min_ncc_narrowed));
  // A pixel whose per-pixel range narrows the search has lost the competitors outside it, so its
  // best peak must be stronger (min_ncc_narrowed): a prior must not weaken the criteria.
  auto minNcc = [&](int x) { return narrowed(x) ? min_ncc_narrow : min_ncc_full; };
  // The discrimination test: best peak above min_ncc and clear of the second by more than
  // delta_min (a single peak is measured against the lowest NCC, -1).
  auto peakGap = [&](int x) {
    const float comp = s.second[x] == kNegInf ? -1.f : s.second[x];
    return s.best[x] - comp;
  };
  if (dense) {
    if (c.uniform_ranges) {
      // The lanes engine keeps its own trackers and writes every rb_d (p1, p2, rb_v: unused).
      denseLanesRow(c, s, y);
    } else {
      // The slices' streaming trackers start empty.
      std::fill(s.p1.begin(), s.p1.begin() + W, kNegInf);
      std::fill(s.p2.begin(), s.p2.begin() + W, kNegInf);
      std::fill(s.rb_v.begin(), s.rb_v.begin() + W, kNegInf);
      std::fill(s.rb_d.begin(), s.rb_d.begin() + W, 0.f);
      s.pick.resize(W);
      int np = 0;
      for (int x = r; x < W - r; ++x) {
        s.pick[np] = x;
        np += s.elo_i[x] <= s.ehi_i[x];
      }
      s.pick.resize(np);
      buildIntervals(c, s, s.pick);
      for (int k = 0; k < nd; ++k) {
        denseSlices(c, s, k, y, s.ivs.data() + s.iv_start[k], s.iv_start[k + 1] - s.iv_start[k]);
      }
    }
  } else {
    updateHotColumns(c, s, y);
    updateHotColumnsR(c, s, y);
    sparseProfiles(c, s, y);
    // Right-to-left profiles only where a pixel passes everything but the left-right check.
    s.cand_q.clear();
    for (int x : s.active) {
      if (s.best[x] == kNegInf) continue;
      const int q = x - static_cast<int>(s.best_d[x]);
      needGammaR(c, s, q, y);
      if (!(s.maps.gamma_r[q] > gmin) || !(peakGap(x) > delta_min) || s.best[x] < minNcc(x)) {
        continue;
      }
      s.cand_q.push_back(q);
    }
    std::sort(s.cand_q.begin(), s.cand_q.end());
    s.cand_q.erase(std::unique(s.cand_q.begin(), s.cand_q.end()), s.cand_q.end());
    for (int q : s.cand_q) sparseRightToLeft(c, s, q, y);
  }

  // Decide each active pixel, criteria in the paper's order.
  float* disp = c.out->disparity.ptr<float>(y);
  float* conf = c.out->confidence.ptr<float>(y);
  uint8_t* stw = c.state->ptr<uint8_t>(y);
  uint8_t* widx = c.window_idx->ptr<uint8_t>(y);
  const float eps = static_cast<float>(c.mp->epsilon_px);
  // Without branches on the criteria. Every value a decision depends on is at hand: dense rows
  // computed the whole row, sparse rows the structure values of every peak's right pixel and the
  // right-to-left profiles of every pixel that passes all but the left-right check. Other reads
  // (the right pixel of a pixel without a peak - best_d 0, so inside the row -, a right-to-left
  // value behind a failed criterion) cannot change the code, which takes the first failure.
  const uint8_t accepted = static_cast<uint8_t>(kCodeAcceptedBase + c.level);
  const bool subpixel = c.mp->subpixel;
  auto decide = [&](int x) {
    const float b = s.best[x];
    const int bd = static_cast<int>(s.best_d[x]);
    const int q = x - bd;
    const float delta = peakGap(x);
    const bool no_peak = b == kNegInf;
    const bool flat = !(s.maps.gamma_r[q] > gmin);
    const bool gap = !(delta > delta_min) || b < minNcc(x);
    const bool lr = !(std::fabs(static_cast<float>(bd) - s.rb_d[q]) < eps);
    const uint8_t cd = no_peak ? uint8_t{kCodeNoPeak}
                       : flat  ? uint8_t{kCodeRejectStructure}
                       : gap   ? uint8_t{kCodeRejectPeakGap}
                       : lr    ? uint8_t{kCodeRejectLeftRight}
                               : accepted;
    code[x] = cd;
    if (cd != accepted) return;
    float sub = 0.f;
    if (subpixel) {
      const float den = s.best_l[x] - 2.f * b + s.best_r[x];
      if (den < 0.f) sub = std::clamp(0.5f * (s.best_l[x] - s.best_r[x]) / den, -0.5f, 0.5f);
    }
    disp[x] = static_cast<float>(bd) + sub;
    conf[x] = std::clamp(delta, 0.f, 1.f);
    stw[x] = 1;
    widx[x] = static_cast<uint8_t>(c.level);
  };
  if (dense) {
    // The active pixels span the row: eight columns at a time, the rest one by one.
    DecideArgs g;
    g.x0 = r;
    g.x1 = W - r;
    g.act = s.act.data();
    g.best = s.best.data();
    g.second = s.second.data();
    g.best_d = s.best_d.data();
    g.best_l = s.best_l.data();
    g.best_r = s.best_r.data();
    g.gamma_r = s.maps.gamma_r.data();
    g.rb_d = s.rb_d.data();
    g.rlo = rlo;
    g.rhi = rhi;
    g.dmin = c.dmin;
    g.dmax = c.dmax;
    g.level = c.level;
    g.gmin = gmin;
    g.delta_min = delta_min;
    g.min_ncc_full = min_ncc_full;
    g.min_ncc_narrow = min_ncc_narrow;
    g.eps = eps;
    g.subpixel = subpixel;
    g.code = code;
    g.stw = stw;
    g.widx = widx;
    g.disp = disp;
    g.conf = conf;
    const int done = decideDense(g);
    for (int x = done; x < W - r; ++x) {
      if (s.act[x] > 0.f) decide(x);
    }
  } else {
    for (const int x : s.active) decide(x);
  }
}

/// Bytes of p[0..n) equal to v: 32 byte counters (each at most 255 between reductions), then
/// the lanes summed.
ES_KERNEL int64_t countEqual(const uint8_t* __restrict p, int n, int v) {
  typedef uint8_t V32u8 __attribute__((vector_size(32)));
  const uint8_t b = static_cast<uint8_t>(v);
  V32u8 vb;
  for (int i = 0; i < 32; ++i) vb[i] = b;
  int64_t total = 0;
  int x = 0;
  while (x + 32 <= n) {
    V32u8 acc = {};
    for (int k = 0; k < 255 && x + 32 <= n; ++k, x += 32) {
      V32u8 e;
      std::memcpy(&e, p + x, 32);
      acc -= reinterpret_cast<V32u8>(e == vb);  // a match is 0xff: -(-1) = +1
    }
    int sum = 0;
    for (int i = 0; i < 32; ++i) sum += acc[i];
    total += sum;
  }
  for (; x < n; ++x) total += p[x] == b;
  return total;
}

/// The valid pixels of a row (accepted or filled), counted; the confidence of every rejected
/// pixel (not filled) set to 0.
ES_KERNEL int64_t countValidZeroRejected(const uint8_t* __restrict cd, float* __restrict cf, int n) {
  int c = 0;
  for (int x = 0; x < n; ++x) {
    const bool filled = cd[x] == kCodeFilled;
    const bool rejected = (cd[x] < kNumRejectCodes) & !filled;
    cf[x] = rejected ? 0.f : cf[x];
    c += (cd[x] >= kCodeAcceptedBase) | filled;
  }
  return c;
}

class ThreadCountGuard {
 public:
  explicit ThreadCountGuard(int n) : old_(cv::getNumThreads()), active_(n > 0) {
    if (active_) cv::setNumThreads(n);
  }
  ~ThreadCountGuard() {
    if (active_) cv::setNumThreads(old_);
  }

 private:
  int old_;
  bool active_;
};

}  // namespace

void RobustMatcher::compute(const cv::Mat& left, const cv::Mat& right, MatchResult& out,
                            const SearchRange* range) {
  if (left.empty()) throw std::invalid_argument("RobustMatcher::compute: left image is empty");
  if (right.empty()) throw std::invalid_argument("RobustMatcher::compute: right image is empty");
  if (left.type() != CV_8UC1) {
    throw std::invalid_argument("RobustMatcher::compute: left image must be CV_8UC1 (gray)");
  }
  if (right.type() != CV_8UC1) {
    throw std::invalid_argument("RobustMatcher::compute: right image must be CV_8UC1 (gray)");
  }
  if (left.size() != right.size()) {
    throw std::invalid_argument("RobustMatcher::compute: left and right image sizes differ");
  }
  if (range && !range->empty()) {
    if (range->lo.type() != CV_16SC1 || range->hi.type() != CV_16SC1) {
      throw std::invalid_argument("RobustMatcher::compute: range.lo and range.hi must be CV_16SC1");
    }
    if (range->lo.size() != left.size() || range->hi.size() != left.size()) {
      throw std::invalid_argument(
          "RobustMatcher::compute: range.lo and range.hi must have the image size");
    }
  }
  const auto t0 = std::chrono::steady_clock::now();
  const MatcherParams& mp = matcher_params_;
  Impl& im = *impl_;
  ThreadCountGuard thread_guard(mp.num_threads);
  const int W = left.cols, H = left.rows;
  const int nd = mp.max_disparity - mp.min_disparity + 1;

  // Whole-image loops run over fixed blocks of rows in parallel; counts are summed per block
  // and then over blocks (integers: the totals do not depend on the split).
  const int num_blocks = (H + kStripeRows - 1) / kStripeRows;
  auto forRowBlocks = [&](const std::function<void(int, int, int)>& fn) {
    cv::parallel_for_(
        cv::Range(0, num_blocks),
        [&](const cv::Range& rg) {
          for (int b = rg.start; b < rg.end; ++b) {
            fn(b, b * kStripeRows, std::min(H, (b + 1) * kStripeRows));
          }
        },
        num_blocks);
  };
  out.disparity.create(H, W, CV_32FC1);
  out.code.create(H, W, CV_8UC1);
  out.confidence.create(H, W, CV_32FC1);
  im.state.create(H, W, CV_8UC1);
  im.window_idx.create(H, W, CV_8UC1);
  forRowBlocks([&](int, int y0, int y1) {
    const cv::Range rows(y0, y1);
    out.disparity.rowRange(rows).setTo(std::numeric_limits<float>::quiet_NaN());
    out.code.rowRange(rows).setTo(kCodeNotSearched);
    out.confidence.rowRange(rows).setTo(0.f);
    im.state.rowRange(rows).setTo(0);
    im.window_idx.rowRange(rows).setTo(0);
  });
  out.stats = MatchStats{};
  out.stats.total_pixels = static_cast<int64_t>(W) * H;

  // The two views are prepared in parallel (two fixed tasks: the result does not depend on the
  // thread count). Intensities as value - 128 (float, exact products); the right view mirrored
  // and padded so that every disparity of the range can be read for every column (sparse and
  // dense engines), the left view padded for the right-indexed column sums (the padding is
  // zero; those disparities are outside the ranges); integral images of the views, of their
  // squares, of the 3x3 Laplacian and of its square (window statistics and structure).
  im.rev_pad = std::max(0, -mp.min_disparity);
  im.l_pad = std::max(0, -mp.min_disparity);
  const int dpad = (nd + 7) / 8 * 8;
  const int pad_w = std::max(0, mp.min_disparity + dpad) + 8;
  cv::parallel_for_(
      cv::Range(0, 2),
      [&](const cv::Range& views) {
        for (int v = views.start; v < views.end; ++v) {
          if (v == 0) {
            // The left view converted straight into its padded buffer (lf is a view of it):
            // only the padding columns are cleared, and no second copy is written.
            im.lf_pad.create(H, im.l_pad + W + pad_w, CV_32F);
            if (im.l_pad > 0) im.lf_pad.colRange(0, im.l_pad).setTo(0.f);
            im.lf_pad.colRange(im.l_pad + W, im.lf_pad.cols).setTo(0.f);
            im.lf = im.lf_pad(cv::Rect(im.l_pad, 0, W, H));
            left.convertTo(im.lf, CV_32F, 1.0, -128.0);
            cv::Laplacian(left, im.lap_l, CV_16S, 1);
            wrappedIntegrals(left, im.lap_l, im.int_l, im.sq_l, im.int_lap_l, im.sq_lap_l);
          } else {
            right.convertTo(im.rf, CV_32F, 1.0, -128.0);
            im.rf_rev.create(H, im.rev_pad + W + pad_w, CV_32F);
            if (im.rev_pad > 0) im.rf_rev.colRange(0, im.rev_pad).setTo(0.f);
            im.rf_rev.colRange(im.rev_pad + W, im.rf_rev.cols).setTo(0.f);
            cv::flip(im.rf, im.rf_rev(cv::Rect(im.rev_pad, 0, W, H)), 1);
            cv::Laplacian(right, im.lap_r, CV_16S, 1);
            wrappedIntegrals(right, im.lap_r, im.int_r, im.sq_r, im.int_lap_r, im.sq_lap_r);
          }
        }
      },
      2);

  int64_t prior_pixels = 0;
  if (range && !range->empty()) {
    im.range_lo.create(H, W, CV_32S);
    im.range_hi.create(H, W, CV_32S);
    std::vector<int64_t> block_prior(num_blocks, 0);
    forRowBlocks([&](int b, int y0, int y1) {
      // Locals (not the captured references) so that the stores cannot alias them: vectorises.
      const int w = W, dmin = mp.min_disparity, dmax = mp.max_disparity;
      int64_t n = 0;
      for (int y = y0; y < y1; ++y) {
        const int16_t* __restrict lo = range->lo.ptr<int16_t>(y);
        const int16_t* __restrict hi = range->hi.ptr<int16_t>(y);
        int* __restrict olo = im.range_lo.ptr<int>(y);
        int* __restrict ohi = im.range_hi.ptr<int>(y);
        int row_n = 0;
        for (int x = 0; x < w; ++x) {
          const int l = std::max<int>(lo[x], dmin), h = std::min<int>(hi[x], dmax);
          olo[x] = l;
          ohi[x] = h;
          row_n += (lo[x] <= hi[x]) & (l <= h) & ((l > dmin) | (h < dmax));
        }
        n += row_n;
      }
      block_prior[b] = n;
    });
    for (const int64_t n : block_prior) prior_pixels += n;
  } else {
    im.range_lo.create(1, W, CV_32S);
    im.range_hi.create(1, W, CV_32S);
    im.range_lo.setTo(mp.min_disparity);
    im.range_hi.setTo(mp.max_disparity);
  }
  out.stats.prior_pixels = prior_pixels;
  const bool uniform = !(range && !range->empty());
  const auto t_prepared = std::chrono::steady_clock::now();

  const int num_levels = (mp.window_max_px - mp.window_min_px) / mp.window_step_px + 1;
  im.open_rows.resize(H);
  im.open_level.assign(H, -1);
  im.n_req_rows.assign(H, 0);
  const int num_stripes = (H + kStripeRows - 1) / kStripeRows;
  std::vector<LevelContext> levels;
  for (int level = 0; level < num_levels; ++level) {
    const int w = mp.window_min_px + level * mp.window_step_px;
    if (w > W || w > H) break;
    levels.push_back(LevelContext{&mp, &im, uniform, level, w, w / 2, W, H, mp.min_disparity,
                                  mp.max_disparity, &im.state, &im.window_idx, &im.open_rows,
                                  &im.open_level, &im.n_req_rows, &out});
  }
  // A row's window sizes depend only on that row (its open pixels, its requested ranges and the
  // images), so each stripe runs through all window sizes on its own: no barrier between window
  // sizes, and the stripes' uneven costs (highlights and instrument edges need the larger
  // windows) even out over the whole frame. Same rows, same order per row: same output.
  cv::parallel_for_(
      cv::Range(0, num_stripes),
      [&](const cv::Range& rg) {
        std::unique_ptr<Scratch> s = im.acquire();
        s->ensure(W, nd);
        for (int stripe = rg.start; stripe < rg.end; ++stripe) {
          const int y_end = std::min(H, (stripe + 1) * kStripeRows);
          for (const LevelContext& c : levels) {
            s->resetSums();
            for (int y = stripe * kStripeRows; y < y_end; ++y) processRow(c, y, *s);
          }
        }
        im.release(std::move(s));
      },
      num_stripes);
  const auto t_matched = std::chrono::steady_clock::now();
  if (mp.edge_disparity_jump_px > 0.0 || mp.edge_window_max_px > 0) {
    rejectEdgeStraddlers(mp, left, right, num_levels, im.window_idx, out, im.tmp1, im.tmp2,
                         im.tmp3, im.tmp4, im.tmp5);
  }
  const auto t1 = std::chrono::steady_clock::now();

  // Per block: accepted per window size (before the post-filters), then rejections and valid
  // pixels (after); summed over blocks.
  std::vector<MatchStats> block_stats(num_blocks);
  const int n_levels = static_cast<int>(levels.size());
  forRowBlocks([&](int b, int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const uint8_t* cd = out.code.ptr<uint8_t>(y);
      for (int l = 0; l < n_levels; ++l) {
        block_stats[b].accepted_per_window[l] += countEqual(cd, W, kCodeAcceptedBase + l);
      }
    }
  });

  const PostFilterParams& fp = filter_params_;
  if (fp.remove_outliers) removeIsolatedOutliers(out.disparity, out.code, fp);
  if (fp.fill_holes) {
    out.code.copyTo(im.code_before);
    fillSmallHoles(out.disparity, out.code, fp);
    // A filled pixel gets the lowest confidence of the measured neighbours it was filled from
    // (reads accepted pixels' confidence only, writes filled pixels' only: blocks are independent).
    forRowBlocks([&](int, int y0, int y1) {
      for (int y = y0; y < y1; ++y) {
        const uint8_t* cd = out.code.ptr<uint8_t>(y);
        const uint8_t* cb0 = im.code_before.ptr<uint8_t>(y);
        for (int x = 0; x < W; ++x) {
          if (cd[x] != kCodeFilled || cb0[x] == kCodeFilled) continue;
          float cmin = 1.f;
          for (int yy = std::max(0, y - 1); yy <= std::min(H - 1, y + 1); ++yy) {
            const uint8_t* cb = im.code_before.ptr<uint8_t>(yy);
            const float* cf = out.confidence.ptr<float>(yy);
            for (int xx = std::max(0, x - 1); xx <= std::min(W - 1, x + 1); ++xx) {
              if (cb[xx] >= kCodeAcceptedBase) cmin = std::min(cmin, cf[xx]);
            }
          }
          out.confidence.ptr<float>(y)[x] = cmin;
        }
      }
    });
  }
  forRowBlocks([&](int b, int y0, int y1) {
    MatchStats& st = block_stats[b];
    for (int y = y0; y < y1; ++y) {
      const uint8_t* cd = out.code.ptr<uint8_t>(y);
      for (int i = 0; i < kNumRejectCodes; ++i) st.rejected[i] += countEqual(cd, W, i);
      st.valid_pixels += countValidZeroRejected(cd, out.confidence.ptr<float>(y), W);
    }
  });
  for (const MatchStats& st : block_stats) {
    for (size_t i = 0; i < st.rejected.size(); ++i) out.stats.rejected[i] += st.rejected[i];
    for (size_t i = 0; i < st.accepted_per_window.size(); ++i) {
      out.stats.accepted_per_window[i] += st.accepted_per_window[i];
    }
    out.stats.valid_pixels += st.valid_pixels;
  }
  const auto t2 = std::chrono::steady_clock::now();
  out.stats.match_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  out.stats.filter_ms = std::chrono::duration<double, std::milli>(t2 - t1).count();
  out.stats.prepare_ms = std::chrono::duration<double, std::milli>(t_prepared - t0).count();
  out.stats.edge_ms = std::chrono::duration<double, std::milli>(t1 - t_matched).count();
}

}  // namespace endo_stereo
