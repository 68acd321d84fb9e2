// The full-range search engine (see search_full_range.hpp): dense rows, every pixel searching
// [dmin, dmax]. For each column x the vertical window sums of L(x, y') R(x - d, y') are held for
// all the disparities it feeds, contiguous in d (the right view is read mirrored), and carried
// from row to row by one row in and one row out (sumColumnsForRow). A pixel's window sums are
// then slid along the row, its profile S(x, d) is formed 8 disparities at a time and analysed by
// the peak rule of ncc_kernels.hpp, and offered to the right-to-left tracker of every right pixel
// x - d, held mirrored so that it too is contiguous in d (profilesForRow). Pixels are visited in
// increasing x, so each right pixel sees its disparities in increasing order: strict > keeps the
// smallest d.

#include "search_full_range.hpp"

#include <algorithm>
#include <cstring>
#include <limits>

#include "ncc_kernels.hpp"
#include "simd.hpp"

namespace endo_stereo {
namespace detail {

namespace {

/// One 8-lane group of a dense pixel's profile: S for the lanes k .. k + 7, stored to prof, and
/// the right-to-left offers; with kMasked only the lanes inside [klo, khi] offer.
template <bool kMasked>
ES_INLINE void profileGroup(int k, V8i kk, V8f dv, V8i vklo, V8i vkhi, V8f ml, V8f il,
                            const float* __restrict h, const float* __restrict sum_r_mirror,
                            const float* __restrict inv_r_mirror, float* __restrict prof,
                            float* __restrict rl_v, float* __restrict rl_d) {
  const V8f sv = (load8(h + k) - ml * load8(sum_r_mirror + k)) * il * load8(inv_r_mirror + k);
  store8(prof + k, sv);
  const V8f rv = load8(rl_v + k);
  V8i up = sv > rv;
  if (kMasked) up &= (kk >= vklo) & (kk <= vkhi);
  store8(rl_v + k, up ? sv : rv);
  store8(rl_d + k, up ? dv : load8(rl_d + k));
}

/// The groups g0 .. g1 of one dense pixel (profilesForRow): its profile S formed and offered to the
/// right-to-left trackers (profileGroup), then, for an active pixel, the peak trackers folded over
/// it with each group's neighbours in registers (peakGroupReg; whole vector loads, forwarded from
/// the stores just made; the lanes whose neighbour lies outside g0 .. g1 are masked: range
/// ends). kNG > 0: g1 - g0 + 1 == kNG, known at compile time.
template <int kNG>
ES_INLINE void pixelProfile(int g0, int g1, V8i kk0, V8f dv0, V8i vklo, V8i vkhi, V8f ml, V8f il,
                            const float* __restrict h, const float* __restrict sum_r_mirror,
                            const float* __restrict inv_r_mirror, float* __restrict prof,
                            float* __restrict rl_vm, float* __restrict rl_dm, bool act, V8f& bv,
                            V8f& sv, V8i& bk) {
  const V8f eight_f = splat8(8.f);
  const V8i eight_i = {8, 8, 8, 8, 8, 8, 8, 8};
  const int n = kNG > 0 ? kNG : g1 - g0 + 1;
  profileGroup<true>(8 * g0, kk0, dv0, vklo, vkhi, ml, il, h, sum_r_mirror, inv_r_mirror, prof,
                     rl_vm, rl_dm);
  {
    V8f dv = dv0 + eight_f;
    V8i kk = kk0 + eight_i;
    for (int j = 1; j < n - 1; ++j, dv += eight_f, kk += eight_i) {
      profileGroup<false>(8 * (g0 + j), kk, dv, vklo, vkhi, ml, il, h, sum_r_mirror, inv_r_mirror,
                          prof, rl_vm, rl_dm);
    }
    if (n > 1)
      profileGroup<true>(8 * g1, kk, dv, vklo, vkhi, ml, il, h, sum_r_mirror, inv_r_mirror, prof,
                         rl_vm, rl_dm);
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

/// Per-column groups for a stripe with per-pixel ranges: the union of the requested ranges of the
/// stripe's pixels whose windows contain the column (a superset of what the column feeds).
void stripeSpans(const WindowLevel& c, FullRangeScratch& e, int stripe) {
  const int W = c.width, r = c.r;
  const int y0 = std::max(r, stripe * kStripeRows);
  const int y1 = std::min(c.height - r, (stripe + 1) * kStripeRows);
  std::vector<int>& lo = e.span_lo;  // per column: min lo / max hi over the stripe's rows
  std::vector<int>& hi = e.span_hi;
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
      e.vsum_g0[x] = 0;
      e.vsum_g1[x] = -1;
    } else {
      e.vsum_g0[x] = (a - c.dmin) / 8;
      e.vsum_g1[x] = (b - c.dmin) / 8;
    }
  }
  e.span_stripe = stripe;
}

/// Inputs of the two passes of a dense row (pointers into the scratch and the frame).
struct FullRangeRowArgs {
  int width, r, w, dp, dmin, rev_pad, rp, rl_copy_stride;
  bool running, slide;
  const int* g0;  // per column: groups held
  const int* g1;
  float* vsums;
  const float* l_in;  // rows y + r and y - r - 1 of L, and of the mirrored R
  const float* l_out;
  const float* r_in;
  const float* r_out;
  const float* const* l_rows;  // the w rows of the window (afresh)
  const float* const* r_rows;
  const int* eff_lo;  // effective ranges (empty: lo > hi)
  const int* eff_hi;
  const float* act;
  const float* mean_l;
  const float* inv_l;
  const float* sum_r_mirror;  // mirrored right statistics, trackers
  const float* inv_r_mirror;
  float* rl_v;
  float* rl_d;
  float* h;     // dp + 16
  float* prof;  // dp + 24, index k at prof[k] (prof[-1] valid)
  float *best, *best_d, *best_l, *best_r, *second;
};

/// v[k] += li * ri[k] - lo * ro[k] for k < n (a multiple of 8): one row in and one out of a
/// column's vertical sums, the group count fixed at compile time where byGroups can.
ES_INLINE void addRowRemoveRow(int n, float* __restrict v, V8f li, V8f lo,
                               const float* __restrict ri, const float* __restrict ro) {
  byGroups(
      n, [&](auto groups) __attribute__((always_inline)) {
        constexpr int kG = decltype(groups)::value;
        const int m = kG > 0 ? 8 * kG : n;
        for (int k = 0; k < m; k += 8) {
          store8(v + k, load8(v + k) + (li * load8(ri + k) - lo * load8(ro + k)));
        }
      });
}

/// Pass 1: the vertical sums of every column for the row, one row in and one out, or afresh.
ES_KERNEL void sumColumnsForRow(const FullRangeRowArgs& a) {
  const int W = a.width, dp = a.dp;
  for (int x = 0; x < W; ++x) {
    const int g0 = a.g0[x], g1 = a.g1[x];
    if (g0 > g1) continue;
    const int k0 = 8 * g0, n = 8 * (g1 - g0 + 1);
    // rf_rev(y', rev_pad + W - 1 - x') = rf(y', x'): R(y', x - d_k) = rf_rev(y', base + k).
    const int base = a.rev_pad + W - 1 - x + a.dmin + k0;
    float* __restrict v = a.vsums + static_cast<size_t>(x) * dp + k0;
    if (a.running) {
      const V8f li = splat8(a.l_in[x]), lo = splat8(a.l_out[x]);
      addRowRemoveRow(n, v, li, lo, a.r_in + base, a.r_out + base);
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
ES_KERNEL void profilesForRow(const FullRangeRowArgs& a) {
  const int W = a.width, r = a.r, dp = a.dp, ng = dp / 8;
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8f lane_f = {0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f};
  const V8f vninf = splat8(kNegInf);
  float* __restrict h = a.h;
  float* __restrict prof = a.prof;
  if (a.slide) {
    for (int g = 0; g < ng; ++g) {
      V8f acc = load8(a.vsums + 8 * g);
      for (int x = 1; x <= 2 * r; ++x) acc += load8(a.vsums + static_cast<size_t>(x) * dp + 8 * g);
      store8(h + 8 * g, acc);
    }
  }
  for (int x = r; x <= W - 1 - r; ++x) {
    if (a.slide && x > r) {
      const float* __restrict in = a.vsums + static_cast<size_t>(x + r) * dp;
      const float* __restrict out = a.vsums + static_cast<size_t>(x - r - 1) * dp;
      addSubGroups(dp, h, in, out);  // the window slid by one column
    }
    const int lo = a.eff_lo[x], hi = a.eff_hi[x];
    if (lo > hi) continue;
    const int klo = lo - a.dmin, khi = hi - a.dmin;
    const int g0 = klo >> 3, g1 = khi >> 3;  // klo, khi >= 0 (lo >= dmin)
    if (!a.slide) {
      for (int g = g0; g <= g1; ++g) {
        const float* col = a.vsums + static_cast<size_t>(x - r) * dp + 8 * g;
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
    float* __restrict rl_v = a.rl_v + static_cast<size_t>(x & 7) * a.rl_copy_stride;
    float* __restrict rl_d = a.rl_d + static_cast<size_t>(x & 7) * a.rl_copy_stride;
    const V8f ml = splat8(a.mean_l[x]), il = splat8(a.inv_l[x]);
    const V8i vklo = V8i{klo, klo, klo, klo, klo, klo, klo, klo};
    const V8i vkhi = V8i{khi, khi, khi, khi, khi, khi, khi, khi};
    const float dk0 = static_cast<float>(a.dmin + 8 * g0);
    const V8f dv0 = lane_f + V8f{dk0, dk0, dk0, dk0, dk0, dk0, dk0, dk0};
    const V8i kk0 = lane + V8i{8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0, 8 * g0};
    const float* sum_r_mirror = a.sum_r_mirror + m;
    const float* inv_r_mirror = a.inv_r_mirror + m;
    float* rl_vm = rl_v + m;
    float* rl_dm = rl_d + m;
    // Only the first and the last group can hold lanes outside the range. A pixel with the
    // whole range (most of them in a full search) takes the same steps with the group count
    // fixed at compile time: the loops unroll.
    V8f bv = vninf, sv = vninf;
    V8i bk = V8i{0, 0, 0, 0, 0, 0, 0, 0};
    const bool act = a.act[x] > 0.f;
    if (g1 - g0 == 7) {
      pixelProfile<8>(g0, g1, kk0, dv0, vklo, vkhi, ml, il, h, sum_r_mirror, inv_r_mirror, prof,
                      rl_vm, rl_dm, act, bv, sv, bk);
    } else {
      pixelProfile<0>(g0, g1, kk0, dv0, vklo, vkhi, ml, il, h, sum_r_mirror, inv_r_mirror, prof,
                      rl_vm, rl_dm, act, bv, sv, bk);
    }
    if (!act) continue;
    pickPeak(bv, sv, bk, prof, klo, khi, a.dmin, &a.best[x], &a.best_d[x], &a.best_l[x],
             &a.best_r[x], &a.second[x]);
  }
}

/// Merge the first @p copies tracker copies into the first: the highest value, ties to the
/// smallest d (the order-free form of "strict >, disparities in increasing order").
ES_KERNEL void mergeCopies(float* __restrict rl_v, float* __restrict rl_d, int stride, int n,
                           int copies) {
  for (int c = 1; c < copies; ++c) {
    const float* __restrict v = rl_v + static_cast<size_t>(c) * stride;
    const float* __restrict d = rl_d + static_cast<size_t>(c) * stride;
    int i = 0;
    for (; i + 8 <= n; i += 8) {  // eight lanes, the same rule lane by lane
      const V8f vi = load8(v + i), bi = load8(rl_v + i), di = load8(d + i), ci = load8(rl_d + i);
      const V8i up = (vi > bi) | ((vi == bi) & (di < ci));
      store8(rl_v + i, up ? vi : bi);
      store8(rl_d + i, up ? di : ci);
    }
    for (; i < n; ++i) {
      const bool up = v[i] > rl_v[i] || (v[i] == rl_v[i] && d[i] < rl_d[i]);
      rl_v[i] = up ? v[i] : rl_v[i];
      rl_d[i] = up ? d[i] : rl_d[i];
    }
  }
}

}  // namespace

/// Layout of the right-to-left trackers (profilesForRow; the narrowed engine's copies, one per
/// disparity index mod 4, step the same way: the next disparity uses the next copy 4 bytes
/// lower), 8 copies of `used` floats
/// for the values and 8 for the disparities, chosen against 4K aliasing: a load whose address
/// matches an earlier, still pending store's in the low 12 bits waits as if it depended on it.
/// A pixel's tracker groups span up to 288 bytes of its copy; the next pixel uses the next copy
/// 4 bytes lower. The copy stride is 1028 bytes mod 4 KiB, so the next 3 pixels' copies lie 1, 2
/// and 3 KiB away (mod 4 KiB) from this one's; the disparities lie 512 bytes (mod 4 KiB) after
/// the values, so no copy within 3 pixels overlaps another's stores there either. Layout only:
/// the values computed are the same.
void layoutTrackers(int used, int* stride, int* d_off) {
  *stride = (used / 1024) * 1024 + 257;
  if (*stride < used) *stride += 1024;
  const int values = 8 * *stride;
  *d_off = (values / 1024) * 1024 + 128;
  if (*d_off < values) *d_off += 1024;
}

void mergeTrackerCopies(float* rl_v, float* rl_d, int stride, int n, int copies) {
  mergeCopies(rl_v, rl_d, stride, n, copies);
}

void FullRangeScratch::ensure(int w, int dpad) {
  vsums.assign(static_cast<size_t>(w) * dpad + 8, 0.f);
  // Reads of the mirrored arrays stay within [rpad - 7, rpad + W + 6] (effective ranges lie
  // inside the image, groups round them by at most 7).
  rpad = 8;
  for (auto* vec : {&sum_r_mirror, &inv_r_mirror}) vec->assign(rpad + w + 16, 0.f);
  layoutTrackers(rpad + w + 16, &rl_copy_stride, &rl_d_offset);
  rl_trackers.assign(static_cast<size_t>(rl_d_offset) + 8 * static_cast<size_t>(rl_copy_stride),
                     0.f);
  vsum_g0.assign(w, 0);
  vsum_g1.assign(w, -1);
  span_lo.assign(w, 0);
  span_hi.assign(w, 0);
  win_sums.assign(dpad + 16, 0.f);
  profile_buf.assign(dpad + 24, 0.f);
}

void FullRangeScratch::resetSums() {
  vsum_row = -10;
  span_stripe = -1;
}

/// One dense row: every pixel with an effective range gets its profile (active pixels also
/// their peak analysis) and offers it to the right-to-left trackers; s.rl_best_d receives the
/// right-to-left best disparity of every right pixel.
void fullRangeRow(const WindowLevel& c, RowScratch& s, FullRangeScratch& e, int y) {
  const int W = c.width, r = c.r, w = c.w;
  const int dp = s.dpad, ng = dp / 8;
  const int stripe = y / kStripeRows;
  if (e.span_stripe != stripe) {
    if (c.uniform_ranges) {
      std::fill(e.vsum_g0.begin(), e.vsum_g0.end(), 0);
      std::fill(e.vsum_g1.begin(), e.vsum_g1.end(), ng - 1);
      e.span_stripe = stripe;
    } else {
      stripeSpans(c, e, stripe);
    }
    e.vsum_row = -10;
  }
  const bool running = e.vsum_row == y - 1;
  const cv::Mat& lf = c.im->lf;
  const cv::Mat& rr = c.im->rf_rev;
  const float* l_rows[33];
  const float* r_rows[33];
  for (int j = 0; j < w; ++j) {
    l_rows[j] = lf.ptr<float>(y - r + j);
    r_rows[j] = rr.ptr<float>(y - r + j);
  }
  // Mirrored right statistics and trackers of this row (zero / empty outside the border).
  const int rp = e.rpad;
  std::fill(e.sum_r_mirror.begin(), e.sum_r_mirror.end(), 0.f);
  std::fill(e.inv_r_mirror.begin(), e.inv_r_mirror.end(), 0.f);
  const int used = rp + W + 16, stride = e.rl_copy_stride;
  float* const rl_v = e.rl_trackers.data();
  float* const rl_d = rl_v + e.rl_d_offset;
  for (int c = 0; c < 8; ++c) {
    std::fill_n(rl_v + static_cast<size_t>(c) * stride, used, kNegInf);
    std::fill_n(rl_d + static_cast<size_t>(c) * stride, used, 0.f);
  }
  for (int q = r; q <= W - 1 - r; ++q) {
    e.sum_r_mirror[rp + W - 1 - q] = s.maps.sum_r[q];
    e.inv_r_mirror[rp + W - 1 - q] = s.maps.inv_r[q];
  }
  FullRangeRowArgs a;
  a.width = W;
  a.r = r;
  a.w = w;
  a.dp = dp;
  a.dmin = c.dmin;
  a.rev_pad = c.im->rev_pad;
  a.rp = rp;
  a.rl_copy_stride = stride;
  a.running = running;
  a.slide = c.uniform_ranges;
  a.g0 = e.vsum_g0.data();
  a.g1 = e.vsum_g1.data();
  a.vsums = e.vsums.data();
  a.l_in = lf.ptr<float>(y + r);
  a.r_in = rr.ptr<float>(y + r);
  a.l_out = running ? lf.ptr<float>(y - r - 1) : nullptr;
  a.r_out = running ? rr.ptr<float>(y - r - 1) : nullptr;
  a.l_rows = l_rows;
  a.r_rows = r_rows;
  a.eff_lo = s.eff_lo.data();
  a.eff_hi = s.eff_hi.data();
  a.act = s.act.data();
  a.mean_l = s.maps.mean_l.data();
  a.inv_l = s.maps.inv_l.data();
  a.sum_r_mirror = e.sum_r_mirror.data();
  a.inv_r_mirror = e.inv_r_mirror.data();
  a.rl_v = rl_v;
  a.rl_d = rl_d;
  a.h = e.win_sums.data();
  a.prof = e.profile_buf.data() + 8;
  a.best = s.best.data();
  a.best_d = s.best_d.data();
  a.best_l = s.best_l.data();
  a.best_r = s.best_r.data();
  a.second = s.second.data();
  sumColumnsForRow(a);
  e.vsum_row = y;
  profilesForRow(a);
  mergeCopies(rl_v, rl_d, stride, used, 8);
  for (int q = 0; q < W; ++q) s.rl_best_d[q] = rl_d[rp + W - 1 - q];
}

}  // namespace detail
}  // namespace endo_stereo
