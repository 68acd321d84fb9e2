// The sparse search engine (see search_sparse.hpp): the rows where few pixels are left open,
// i.e. the larger windows. Column sums are kept per column for the disparities its pixels need
// and carried down the stripe by running sums while they keep being used ("hot" columns); a
// run of active pixels whose windows overlap slides its window sums along the run; each active
// pixel's profile is analysed by the peak rule of ncc_kernels.hpp (scanProfile). The right-to-left
// profiles come from sums indexed by the right column, only for the right pixels the surviving
// peaks point at.

#include "search_sparse.hpp"

#include <algorithm>
#include <cstring>
#include <limits>

#include "ncc_kernels.hpp"
#include "simd.hpp"
#include "window_statistics.hpp"

namespace endo_stereo {
namespace detail {

namespace {

// Column sums of the sparse engine (r read mirrored, so that disparities are contiguous). Their
// counts n are whole 8-lane groups (the requests are rounded out to groups: columnRequest), so
// the kernels run over groups, and for up to 8 groups (64 disparities: a full search of 64, or
// the few groups of a narrowed range) with the group count fixed at compile time: the loops
// unroll, and colFresh keeps its sums in registers across the rows. The same operations in the
// same order: the same values.

/// the rows summed in increasing order (one call instead of one per row); n whole groups.
ES_KERNEL void colFresh(int n, float* __restrict cs, const float* __restrict l, size_t l_step,
                        const float* __restrict r, size_t r_step, int rows) {
  byGroups(
      n, [&](auto groups) __attribute__((always_inline)) {
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
  byGroups(
      n, [&](auto groups) __attribute__((always_inline)) {
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
  byGroups(
      n, [&](auto groups) __attribute__((always_inline)) {
        constexpr int kG = decltype(groups)::value;
        const int m = kG > 0 ? 8 * kG : n;
        for (int k = 0; k < m; k += 8) store8(h + k, load8(h + k) + load8(a + k));
      });
}
/// h[k] += a[k] - b[k]; n whole groups (the full-range engine slides its windows with addSubGroups,
/// ncc_kernels.hpp).
ES_KERNEL void vecAddSub(int n, float* __restrict h, const float* __restrict a,
                         const float* __restrict b) {
  addSubGroups(n, h, a, b);
}

/// The disparity indices [k0, k1] column x's sums must hold at row y: the union of the effective
/// ranges of the pixels whose windows contain the column (the only NCC values it feeds), widened
/// to whole 8-lane groups. Cached per row.
inline void columnRequest(const WindowLevel& c, RowScratch& s, SparseScratch& e, int x, int* k0,
                          int* k1) {
  if (e.req_stamp[x] == s.stamp) {
    *k0 = e.req_k0[x];
    *k1 = e.req_k1[x];
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
  e.req_stamp[x] = s.stamp;
  e.req_k0[x] = *k0;
  e.req_k1[x] = *k1;
}

/// Running update of column x's sums from row y - 1 to row y, over its held window.
inline void columnRunning(const WindowLevel& c, RowScratch& s, SparseScratch& e, int x, int y) {
  const int r = c.r;
  const int k0 = e.col_k0[x], n = e.col_k1[x] - k0 + 1;
  float* cs = e.colsum.data() + static_cast<size_t>(x) * s.dpad + k0;
  // rf_rev(y', rev_pad + W - 1 - x') = rf(y', x'), so R(y', x - d) = rf_rev(y', base + k).
  const int base = c.im->rev_pad + c.width - 1 - x + c.dmin + k0;
  colRunning(n, cs, c.im->lf.ptr<float>(y + r)[x], c.im->rf_rev.ptr<float>(y + r) + base,
             c.im->lf.ptr<float>(y - r - 1)[x], c.im->rf_rev.ptr<float>(y - r - 1) + base);
  e.col_row[x] = y;
}

/// Make column x's vertical window sums valid for row y on the disparities it is asked for:
/// running update from row y - 1 when that is what it holds, else summed afresh. The right image
/// is read mirrored, so R(y', x - d) for increasing d is contiguous. A column computed afresh
/// joins the stripe's hot columns, which are carried down by running sums while they keep being
/// used (see updateHotColumns), so a failed region spanning many rows costs one row in and one
/// row out per row, not a whole window.
inline void ensureColumn(const WindowLevel& c, RowScratch& s, SparseScratch& e, int x, int y) {
  if (e.col_done[x] == s.stamp) return;  // already made valid for this row's request
  e.col_done[x] = s.stamp;
  int k0, k1;
  columnRequest(c, s, e, x, &k0, &k1);
  e.col_used[x] = y;
  const bool covers = e.col_k0[x] <= k0 && k1 <= e.col_k1[x];
  if (e.col_row[x] == y && covers) return;
  if (e.col_row[x] == y - 1 && covers) {
    columnRunning(c, s, e, x, y);
    return;
  }
  if (e.col_row[x] == y || e.col_row[x] == y - 1) {
    k0 = std::min(k0, e.col_k0[x]);
    k1 = std::max(k1, e.col_k1[x]);
  }
  const int r = c.r;
  const int n = k1 - k0 + 1;
  float* cs = e.colsum.data() + static_cast<size_t>(x) * s.dpad + k0;
  const cv::Mat& lf = c.im->lf;
  const cv::Mat& rr = c.im->rf_rev;
  const int base = c.im->rev_pad + c.width - 1 - x + c.dmin + k0;
  colFresh(n, cs, lf.ptr<float>(y - r) + x, lf.step1(), rr.ptr<float>(y - r) + base, rr.step1(),
           c.w);
  e.col_k0[x] = k0;
  e.col_k1[x] = k1;
  if (e.col_row[x] < y - 1) e.hot.push_back(x);
  e.col_row[x] = y;
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
void carryHotColumns(const WindowLevel& c, int y, std::vector<int>& hot, std::vector<int>& row,
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
void updateHotColumns(const WindowLevel& c, RowScratch& s, SparseScratch& e, int y) {
  carryHotColumns(c, y, e.hot, e.col_row, e.col_used, e.col_k0, e.col_k1, e.colsum, s.dpad,
                  c.im->lf, c.im->rf_rev, c.im->rev_pad + c.width - 1 + c.dmin, -1);
}

// Right-indexed column sums (see SparseScratch::colsum_r): the same three ways to make a column
// valid (kept, one row in and one out, afresh), the same hot-column carrying. R(y', q) is the
// scalar, L(y', q + d) for increasing d the contiguous run (lf_pad).
void updateHotColumnsR(const WindowLevel& c, RowScratch& s, SparseScratch& e, int y) {
  carryHotColumns(c, y, e.hot_r, e.colr_row, e.colr_used, e.colr_k0, e.colr_k1, e.colsum_r, s.dpad,
                  c.im->rf, c.im->lf_pad, c.im->l_pad + c.dmin, +1);
}

/// Make right column q's sums valid for row y on disparity indices [k0, k1] (whole 8-lane groups).
inline void ensureColumnR(const WindowLevel& c, RowScratch& s, SparseScratch& e, int q, int y,
                          int k0, int k1) {
  e.colr_used[q] = y;
  const bool covers = e.colr_k0[q] <= k0 && k1 <= e.colr_k1[q];
  if (e.colr_row[q] == y && covers) return;
  const int r = c.r;
  const cv::Mat& lp = c.im->lf_pad;
  const cv::Mat& rf = c.im->rf;
  if (e.colr_row[q] == y - 1 && covers) {
    const int a = e.colr_k0[q], n = e.colr_k1[q] - a + 1;
    const int base = c.im->l_pad + q + c.dmin + a;
    colRunning(n, e.colsum_r.data() + static_cast<size_t>(q) * s.dpad + a, rf.ptr<float>(y + r)[q],
               lp.ptr<float>(y + r) + base, rf.ptr<float>(y - r - 1)[q],
               lp.ptr<float>(y - r - 1) + base);
    e.colr_row[q] = y;
    return;
  }
  if (e.colr_row[q] == y || e.colr_row[q] == y - 1) {
    k0 = std::min(k0, e.colr_k0[q]);
    k1 = std::max(k1, e.colr_k1[q]);
  }
  const int n = k1 - k0 + 1;
  float* cs = e.colsum_r.data() + static_cast<size_t>(q) * s.dpad + k0;
  const int base = c.im->l_pad + q + c.dmin + k0;
  colFresh(n, cs, rf.ptr<float>(y - r) + q, rf.step1(), lp.ptr<float>(y - r) + base, lp.step1(),
           c.w);
  e.colr_k0[q] = k0;
  e.colr_k1[q] = k1;
  if (e.colr_row[q] < y - 1) e.hot_r.push_back(q);
  e.colr_row[q] = y;
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

/// Peak analysis of one complete profile prof[0..n) (disparities lo..lo+n-1, n >= 3), the same
/// rules as the other engines (ncc_kernels.hpp): per lane the best interior maximum (first of equal
/// values), its index and the lane's best other maximum, then butterfly reductions. prof[-1] and
/// whole groups past n must be readable (masked).
ES_KERNEL void scanProfile(const float* __restrict prof, int n, int lo, float* best, float* best_d,
                           float* best_l, float* best_r, float* second) {
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
  pickPeak(bv, sv, bk, prof, 0, khi, lo, best, best_d, best_l, best_r, second);
}

/// Profiles of the active pixels of row y (phase A), from per-column sums.
/// Per-pixel ranges: the disparity indices each column of the run of active pixels
/// s.active[i..j] must hold, the union of the effective ranges of the run's pixels whose windows
/// contain it (the column sums feed only these pixels' profiles; the right-to-left profiles have
/// their own sums), cached for columnRequest.
void runRequests(const WindowLevel& c, RowScratch& s, SparseScratch& e, size_t i, size_t j) {
  const int r = c.r;
  const int a = s.active[i], b = s.active[j];
  int* lo = e.run_lo.data();  // index x - a
  int* hi = e.run_hi.data();
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
  int* pl = e.vh_lo.data();
  int* ph = e.vh_hi.data();
  int* gl = e.vh_glo.data();
  int* gh = e.vh_ghi.data();
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
    e.req_stamp[x] = s.stamp;
    e.req_k0[x] = (l - c.dmin) & ~7;  // whole groups (l, h >= dmin)
    e.req_k1[x] = std::min(s.dpad - 1, (h - c.dmin) | 7);
  }
}

void sparseProfiles(const WindowLevel& c, RowScratch& s, SparseScratch& e, int y) {
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
      runRequests(c, s, e, i, j);
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
      ensureColumn(c, s, e, x, y);
      k0 = std::min(k0, e.req_k0[x]);
      k1 = std::max(k1, e.req_k1[x]);
    }
    const int nk = k1 - k0 + 1;
    float* h = e.hvec.data();
    const float* cs0 = e.colsum.data() + k0;
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
                   s.maps.sum_r_rev.data() + m, s.maps.inv_r_rev.data() + m, e.prof0);
        scanProfile(e.prof0, hi - lo + 1, lo, &s.best[x], &s.best_d[x], &s.best_l[x], &s.best_r[x],
                    &s.second[x]);
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

}  // namespace

void SparseScratch::ensure(int w, int nd, int dpad) {
  (void)nd;
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
  hvec.assign(dpad + 8, 0.f);
  hr.assign(dpad + 8, 0.f);
  rl_stamp = -1;
  // 8 floats before (prof0[-1] is read, masked) and 16 after (whole groups past the end).
  prof.assign(dpad + 24, 0.f);
  prof0 = prof.data() + 8;
}

void SparseScratch::resetSums() {
  std::fill(col_row.begin(), col_row.end(), -10);
  hot.clear();
  std::fill(colr_row.begin(), colr_row.end(), -10);
  hot_r.clear();
}

void sparseRow(const WindowLevel& c, RowScratch& s, SparseScratch& e, int y) {
  updateHotColumns(c, s, e, y);
  updateHotColumnsR(c, s, e, y);
  sparseProfiles(c, s, e, y);
}

/// Right-to-left profile of right pixel q (phase B): the best d of S(q + d, d) over the left
/// pixels q + d whose effective range holds d. Ties keep the smallest d, as in the other engines.
void sparseRightToLeft(const WindowLevel& c, RowScratch& s, SparseScratch& e, int q, int y) {
  const int r = c.r;
  // Disparities whose left pixel q + d has d in its range: all of them inside the border with a
  // full search; with per-pixel ranges (narrow) usually a few, and only their columns are needed.
  int dv0 = std::max(c.dmin, r - q), dv1 = std::min(c.dmax, c.width - 1 - r - q);
  int first_ok = 0;  // per-pixel ranges: index in e.rl_ok of dv0 after the cut below
  if (!c.uniform_ranges) {
    // The disparities d whose left pixel q + d holds d in its effective range, listed once.
    // q is inside the border and q + d is too (dv0, dv1), so pixel q + d's effective range holds
    // d exactly when its requested range does.
    // A mask over [dv0, dv1] (index d - dv0), then the span from the first to the last one.
    const int n = std::max(0, dv1 - dv0 + 1);
    e.rl_ok.resize(static_cast<size_t>(n) + 8);
    int* ok = e.rl_ok.data();
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
    s.rl_best_v[q] = kNegInf;
    s.rl_best_d[q] = 0.f;
    return;
  }
  // S_RL(q, d) sums the right-indexed columns q - r .. q + r at entry d (q is inside the border:
  // it is x - d of a pixel whose right window fits).
  const int k0 = (dv0 - c.dmin) & ~7;  // whole groups (dv0, dv1 >= dmin)
  const int k1 = std::min(s.dpad - 1, (dv1 - c.dmin) | 7);
  float* h;
  const float* cs0 = e.colsum_r.data() + k0;
  const size_t dp = static_cast<size_t>(s.dpad);
  if (c.uniform_ranges && e.rl_stamp == s.stamp && e.rl_q == q - 1 && e.rl_k0 == k0 &&
      e.rl_k1 == k1) {
    // The previous right pixel's sums, slid by one column (its other columns are valid for this
    // row on these disparities already). Exact: integer-valued sums.
    ensureColumnR(c, s, e, q + r, y, k0, k1);
    h = e.hr.data();
    vecAddSub(k1 - k0 + 1, h + k0, cs0 + static_cast<size_t>(q + r) * dp,
              cs0 + static_cast<size_t>(q - r - 1) * dp);
  } else {
    for (int qq = q - r; qq <= q + r; ++qq) ensureColumnR(c, s, e, qq, y, k0, k1);
    h = e.hr.data();
    std::memcpy(h + k0, cs0 + static_cast<size_t>(q - r) * dp, sizeof(float) * (k1 - k0 + 1));
    for (int qq = q - r + 1; qq <= q + r; ++qq) vecAdd(k1 - k0 + 1, h + k0, cs0 + qq * dp);
  }
  if (c.uniform_ranges) {
    e.rl_stamp = s.stamp;
    e.rl_q = q;
    e.rl_k0 = k0;
    e.rl_k1 = k1;
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
    float* v = e.prof0;
    const int n = dv1 - dv0 + 1;
    nccSpan(n, h + (dv0 - c.dmin), s.maps.mean_l.data() + q + dv0, s.maps.inv_l.data() + q + dv0,
            s.maps.sum_r[q], s.maps.inv_r[q], v);
    maskOut(n, v, e.rl_ok.data() + first_ok);
    const int i = firstMax(v, n);  // the first valid disparity is valid: a finite value
    rv = v[i];
    rd = static_cast<float>(dv0 + i);
  } else if (d0 <= d1) {
    float* v = e.prof0;
    const int n = d1 - d0 + 1;
    nccSpan(n, h + (d0 - c.dmin), s.maps.mean_l.data() + q + d0, s.maps.inv_l.data() + q + d0, sr,
            ir, v);
    // With a full search every left pixel inside the border has d in its range: the highest
    // value, at its smallest d (what "strict >, d increasing" keeps).
    const int i = firstMax(v, n);
    rv = v[i];
    rd = static_cast<float>(d0 + i);
  }
  s.rl_best_v[q] = rv;
  s.rl_best_d[q] = rd;
}

}  // namespace detail
}  // namespace endo_stereo
