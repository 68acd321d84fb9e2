// The narrowed-range search engine (see search_narrowed.hpp): dense rows with per-pixel search
// ranges. The row is cut into chunks of 8 columns; a chunk's band is the union of its pixels'
// effective ranges (chunkBands). For each disparity the columns that the chunks searching it
// read are gathered into intervals (intervalsOfRow) and their vertical window sums made valid for
// the row (ensureV: kept, one row in and one row out, or afresh). Then each chunk runs through
// its band in increasing d (chunkSearch): the horizontal window sums of its 8 pixels, the NCC
// S(., d), each pixel's streaming peak tracker in registers, and the right-to-left tracker of
// each right pixel x - d.

#include "search_narrowed.hpp"

#include <algorithm>
#include <cstring>

#include "ncc_kernels.hpp"
#include "search_full_range.hpp"
#include "simd.hpp"

namespace endo_stereo {
namespace detail {

namespace {

using namespace simd;

// Right-to-left tracker copies (see chunkSearchImpl), one per disparity index mod kCopies.
constexpr int kCopies = 4;

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

// Vertical sums, eight columns per vector and the last up to 7 one by one (the intervals are
// short, tens of columns at a stripe's first row: a wider vector would leave a long scalar tail).
ES_KERNEL void vRunning(int n, float* __restrict v, const float* __restrict l_in,
                        const float* __restrict r_in, const float* __restrict l_out,
                        const float* __restrict r_out) {
  int i = 0;
  for (; i + 8 <= n; i += 8) {
    store8(v + i, load8(v + i) + (load8(l_in + i) * load8(r_in + i) -
                                  load8(l_out + i) * load8(r_out + i)));
  }
  for (; i < n; ++i) v[i] += l_in[i] * r_in[i] - l_out[i] * r_out[i];
}

/// n columns of vertical window sums afresh: v[i] = sum over the w rows of l[j][i] * r[j][i]
/// (rows given as pointers; exact, so the order of additions cannot matter).
ES_KERNEL void vFresh(int n, int w, float* __restrict v, const float* const* l,
                      const float* const* r) {
  int i = 0;
  for (; i + 8 <= n; i += 8) {
    V8f acc = load8(l[0] + i) * load8(r[0] + i);
    for (int j = 1; j < w; ++j) acc += load8(l[j] + i) * load8(r[j] + i);
    store8(v + i, acc);
  }
  for (; i < n; ++i) {
    float acc = l[0][i] * r[0][i];
    for (int j = 1; j < w; ++j) acc += l[j][i] * r[j][i];
    v[i] = acc;
  }
}

/// Inputs of chunkSearch for one row (pointers into the scratch and the row's arrays).
struct ChunkArgs {
  int w, r, dmin, nd;
  int num_chunks;
  const int* band_lo;  // per chunk, disparity indices (lo > hi: empty)
  const int* band_hi;
  const float* v;  // vertical sums of disparity index 0, column 0; rows v_stride apart
  int v_stride;
  const float* eff_lo_f;
  const float* eff_hi_f;
  const float* act;
  const float* mean_l;
  const float* inv_l;
  const float* sum_r_q;  // right statistics, index x - k + nd + 7
  const float* inv_r_q;
  float* rl_v;  // copy 0 of the right-to-left trackers, same index
  float* rl_d;
  int rl_copy_stride;
  float *best, *best_d, *best_l, *best_r, *second;
};

// The streaming peak tracker of the 8 pixels of a chunk, in registers. At disparity d a pixel
// knows S(d-2), S(d-1) (p2, p1) and S(d): d-1 is an interior local maximum when S(d-1) > S(d-2)
// and S(d-1) >= S(d) with d-2 inside its range. The highest interior maximum is the best (its
// neighbours kept for the parabola); every other maximum, and a range end where the profile rises
// towards it (the true peak may lie beyond), competes for the peak gap. Local maxima are never
// adjacent, so "outside +-1 px of the best" holds by construction (the peak rule of
// ncc_kernels.hpp in streaming form). A lane takes part only at the disparities of its own range
// (own); the other lanes of the band compute values that no decision reads.
//
// The right-to-left trackers come in kCopies copies, one per disparity index mod kCopies:
// consecutive disparities of a chunk address right pixels one lane apart, and a load overlapping
// the previous disparity's stores by all but one lane would stall (no store forwarding); within a
// copy the stores of one chunk lie kCopies lanes apart, four disparities back, long written to
// the cache (4 copies measured no slower in this kernel than 8, with half the clearing and
// merging), and the next chunk's land on whole vectors of them. Each right pixel receives its
// offers in increasing d (chunks in increasing x, each in increasing d), so strict > keeps the
// smallest d within a copy; the copies are merged with ties to the smallest d
// (mergeTrackerCopies): the same value and disparity as one tracker offered every d in
// increasing order.
template <int kW>
ES_INLINE void chunkSearchImpl(const ChunkArgs& g) {
  // Every argument in a local: the stores (through memcpy) may alias anything, so the fields of
  // g would be read again after each one.
  const int w = kW > 0 ? kW : g.w;
  const int num_chunks = g.num_chunks, r = g.r, nd = g.nd;
  const size_t v_stride = static_cast<size_t>(g.v_stride);
  const size_t rl_stride = static_cast<size_t>(g.rl_copy_stride);
  const float dmin_f = static_cast<float>(g.dmin);
  const int* const band_lo = g.band_lo;
  const int* const band_hi = g.band_hi;
  const float* const v = g.v;
  const float* const eff_lo_f = g.eff_lo_f;
  const float* const eff_hi_f = g.eff_hi_f;
  const float* const act_f = g.act;
  const float* const mean_l = g.mean_l;
  const float* const inv_l = g.inv_l;
  const float* const sum_r_q = g.sum_r_q;
  const float* const inv_r_q = g.inv_r_q;
  float* const rl_v = g.rl_v;
  float* const rl_d = g.rl_d;
  float* const best_out = g.best;
  float* const best_d_out = g.best_d;
  float* const best_l_out = g.best_l;
  float* const best_r_out = g.best_r;
  float* const second_out = g.second;
  const V8f vninf = splat8(kNegInf), vzero = splat8(0.f);
  const V8f one = splat8(1.f), two = splat8(2.f);
  size_t copy_off[8];
  for (int c = 0; c < 8; ++c) copy_off[c] = static_cast<size_t>(c % kCopies) * rl_stride;
  for (int j = 0; j < num_chunks; ++j) {
    const int k0 = band_lo[j], k1 = band_hi[j];
    if (k0 > k1) continue;
    const int x0 = 8 * j;
    const V8f lo = load8(eff_lo_f + x0), hi = load8(eff_hi_f + x0);
    const V8f lo1 = lo + one, lo2 = lo + two;
    const V8i act = load8(act_f + x0) > vzero;
    const V8f ml = load8(mean_l + x0), il = load8(inv_l + x0);
    V8f p1 = vninf, p2 = vninf, best = vninf, second = vninf;
    V8f best_d = vzero, best_l = vzero, best_r = vzero;
    const float* vs = v + static_cast<size_t>(k0) * v_stride + x0 - r;
    // Right pixel x0 - d_k at index qi; it moves one lane down per disparity.
    const float* srq = sum_r_q + (x0 + nd + 7 - k0);
    const float* irq = inv_r_q + (x0 + nd + 7 - k0);
    float* rvq = rl_v + (x0 + nd + 7 - k0);
    float* rdq = rl_d + (x0 + nd + 7 - k0);
    V8f vd = splat8(dmin_f + static_cast<float>(k0));  // exact: small integers
    for (int k = k0; k <= k1; ++k, vs += v_stride, --srq, --irq, --rvq, --rdq, vd += one) {
      const V8f hs = boxSum8(vs, w);
      const V8f s = (hs - ml * load8(srq)) * il * load8(irq);
      const V8i inr = (lo <= vd) & (vd <= hi);
      const V8i own = inr & act;
      const V8i is_max = own & (vd >= lo2) & (p1 > p2) & (p1 >= s);
      const V8i new_best = is_max & (p1 > best);
      V8f cand = new_best ? best : (is_max ? p1 : vninf);
      const V8i lo_end = own & (vd == lo1) & (p1 > s);
      const V8i hi_end = own & (vd == hi) & (s > p1);
      cand = max8(cand, lo_end ? p1 : vninf);
      cand = max8(cand, hi_end ? s : vninf);
      second = max8(second, cand);
      best = new_best ? p1 : best;
      best_d = new_best ? vd - one : best_d;
      best_l = new_best ? p2 : best_l;
      best_r = new_best ? s : best_r;
      p2 = own ? p1 : p2;
      p1 = own ? s : p1;
      // Right-to-left: S_RL(x - d, d) = S_LR(x, d), in copy k mod 8.
      const size_t copy = copy_off[k & 7];  // k mod kCopies
      float* rv_p = rvq + copy;
      float* rd_p = rdq + copy;
      const V8f rv = load8(rv_p);
      const V8i up = inr & (s > rv);
      store8(rv_p, up ? s : rv);
      store8(rd_p, up ? vd : load8(rd_p));
    }
    store8(best_out + x0, best);
    store8(best_d_out + x0, best_d);
    store8(best_l_out + x0, best_l);
    store8(best_r_out + x0, best_r);
    store8(second_out + x0, second);
  }
}

ES_KERNEL void chunkSearch(const ChunkArgs& g) { chunkSearchImpl<0>(g); }
// The window widths of the presets' first window (9: default, 7: paper), where nearly all
// narrowed pixels are decided: the horizontal sums unroll.
ES_KERNEL void chunkSearchWidth9(const ChunkArgs& g) { chunkSearchImpl<9>(g); }
ES_KERNEL void chunkSearchWidth7(const ChunkArgs& g) { chunkSearchImpl<7>(g); }

/// The right-to-left tracker copies emptied on n entries: value -inf, disparity 0.
ES_KERNEL void clearTrackers(float* __restrict rl_v, float* __restrict rl_d, int stride, int n) {
  const V8f ninf = splat8(kNegInf), zero = splat8(0.f);
  for (int c = 0; c < kCopies; ++c) {
    float* __restrict v = rl_v + static_cast<size_t>(c) * stride;
    float* __restrict d = rl_d + static_cast<size_t>(c) * stride;
    int i = 0;
    for (; i + 8 <= n; i += 8) {
      store8(v + i, ninf);
      store8(d + i, zero);
    }
    for (; i < n; ++i) {
      v[i] = kNegInf;
      d[i] = 0.f;
    }
  }
}

/// Make the vertical window sums of disparity index k valid on the columns need[0 .. count)
/// (sorted, disjoint intervals) of row y: columns already computed for row y are kept, columns
/// valid for row y - 1 are updated by one row in and one row out, the rest are summed afresh
/// over the window's rows. All exact, so the three ways give identical values.
void ensureV(const WindowLevel& c, NarrowedScratch& e, int k, int y, const Interval* need,
             int count) {
  const int d = c.dmin + k;
  const int r = c.r;
  const cv::Mat& lf = c.im->lf;
  const cv::Mat& rf = c.im->rf;
  VValidity& vv = e.valid[k];
  if (vv.cur_row != y) {
    if (vv.cur_row == y - 1) {
      std::swap(vv.prev, vv.cur);
    } else {
      vv.prev.clear();
    }
    vv.cur.clear();
    vv.cur_row = y;
  }
  float* v = e.v.data() + static_cast<size_t>(k) * e.v_stride + e.v_pad;
  // The common case: the same intervals as on the previous row (smooth ranges move their
  // chunks' bands only now and then).
  if (vv.cur.empty() && vv.prev.size() == static_cast<size_t>(count) &&
      std::equal(need, need + count, vv.prev.begin(),
                 [](const Interval& p, const Interval& q) { return p.a == q.a && p.b == q.b; })) {
    for (int i = 0; i < count; ++i) {
      const int ra = need[i].a, n = need[i].b - ra + 1;
      vRunning(n, v + ra, lf.ptr<float>(y + r) + ra, rf.ptr<float>(y + r) + ra - d,
               lf.ptr<float>(y - r - 1) + ra, rf.ptr<float>(y - r - 1) + ra - d);
    }
    vv.cur.assign(need, need + count);
    return;
  }
  // pieces := need minus cur.
  e.pieces.clear();
  size_t ci = 0;
  for (int i = 0; i < count; ++i) {
    const Interval& nv = need[i];
    int x = nv.a;
    while (ci < vv.cur.size() && vv.cur[ci].b < x) ++ci;
    for (size_t j = ci; j < vv.cur.size() && vv.cur[j].a <= nv.b; ++j) {
      if (vv.cur[j].a > x) e.pieces.push_back({x, vv.cur[j].a - 1});
      x = std::max(x, vv.cur[j].b + 1);
    }
    if (x <= nv.b) e.pieces.push_back({x, nv.b});
  }
  if (e.pieces.empty()) return;
  const float* l_rows[33];
  const float* r_rows[33];
  auto fresh = [&](int fa, int fb) {
    for (int j = 0; j < c.w; ++j) {
      l_rows[j] = lf.ptr<float>(y - r + j) + fa;
      r_rows[j] = rf.ptr<float>(y - r + j) + fa - d;
    }
    vFresh(fb - fa + 1, c.w, v + fa, l_rows, r_rows);
  };
  size_t pi = 0;
  for (const Interval& p : e.pieces) {
    int px = p.a;
    while (pi < vv.prev.size() && vv.prev[pi].b < px) ++pi;
    for (size_t j = pi; j < vv.prev.size() && vv.prev[j].a <= p.b; ++j) {
      const Interval& iv = vv.prev[j];
      if (iv.a > px) fresh(px, iv.a - 1);
      const int ra = std::max(px, iv.a), end = std::min(p.b, iv.b);
      // prev is only set when row y - 1 was computed, so y - r - 1 >= 0 here.
      vRunning(end - ra + 1, v + ra, lf.ptr<float>(y + r) + ra, rf.ptr<float>(y + r) + ra - d,
               lf.ptr<float>(y - r - 1) + ra, rf.ptr<float>(y - r - 1) + ra - d);
      px = end + 1;
      if (px > p.b) break;
    }
    if (px <= p.b) fresh(px, p.b);
  }
  // cur := cur U pieces (both sorted and disjoint).
  e.merged.clear();
  size_t i = 0, j = 0;
  while (i < vv.cur.size() || j < e.pieces.size()) {
    const Interval next =
        (j >= e.pieces.size() || (i < vv.cur.size() && vv.cur[i].a < e.pieces[j].a))
            ? vv.cur[i++]
            : e.pieces[j++];
    if (!e.merged.empty() && next.a <= e.merged.back().b + 1) {
      e.merged.back().b = std::max(e.merged.back().b, next.b);
    } else {
      e.merged.push_back(next);
    }
  }
  std::swap(vv.cur, e.merged);
}

/// Each chunk's band: the least and greatest disparity index of its 8 pixels' effective ranges
/// (empty: 0 > -1), from the float ranges (empty: 1e9 > -1e9; readable up to 8 num_chunks).
/// @return the number of chunks with a band.
ES_KERNEL int chunkBands(const float* __restrict eff_lo_f, const float* __restrict eff_hi_f,
                         int num_chunks, float dmin, int* __restrict band_lo,
                         int* __restrict band_hi) {
  int n = 0;
  for (int j = 0; j < num_chunks; ++j) {
    const V8f lo = load8(eff_lo_f + 8 * j), hi = load8(eff_hi_f + 8 * j);
    const float a = -hmax8(-lo)[0], b = hmax8(hi)[0];
    const bool any = a <= b;
    // Exact: small integers.
    band_lo[j] = any ? static_cast<int>(a - dmin) : 0;
    band_hi[j] = any ? static_cast<int>(b - dmin) : -1;
    n += any;
  }
  return n;
}

/// For each disparity index k, the columns whose vertical sums the chunks with k in their band
/// read ([8 j - r, 8 j + 7 + r] for chunk j), clipped to the columns where the sums exist
/// (both images), as sorted intervals; runs of chunks closer than a window width are merged
/// (their sums overlap anyway). Bands change little from chunk to chunk, so the runs are found
/// from the bands' differences: O(chunks + band changes), not O(chunks x band width).
void intervalsOfRow(const WindowLevel& c, NarrowedScratch& e, int num_chunks) {
  const int W = c.width, r = c.r, nd = c.dmax - c.dmin + 1;
  std::fill(e.iv_count.begin(), e.iv_count.begin() + nd, 0);
  auto close = [&](int k, int j_end) {
    const int d = c.dmin + k;
    const int a = std::max({8 * e.run_from[k] - r, 0, d});
    const int b = std::min({8 * j_end + 7 + r, W - 1, W - 1 + d});
    if (a > b) return;
    Interval* list = e.iv_by_k.data() + static_cast<size_t>(k) * e.iv_cap;
    int& n = e.iv_count[k];
    if (n > 0 && list[n - 1].b + c.w >= a) {
      list[n - 1].b = b;
    } else {
      list[n++] = {a, b};
    }
  };
  int pa = 0, pb = -1;  // the previous chunk's band
  for (int j = 0; j < num_chunks; ++j) {
    const int a = e.band_lo[j], b = e.band_hi[j];
    if (a == pa && b == pb) continue;
    // Runs ending at chunk j - 1: the previous band minus this one.
    for (int k = pa; k <= std::min(pb, a - 1); ++k) close(k, j - 1);
    for (int k = std::max(pa, b + 1); k <= pb; ++k) close(k, j - 1);
    // Runs starting here: this band minus the previous one.
    for (int k = a; k <= std::min(b, pa - 1); ++k) e.run_from[k] = j;
    for (int k = std::max(a, pb + 1); k <= b; ++k) e.run_from[k] = j;
    pa = a;
    pb = b;
  }
  for (int k = pa; k <= pb; ++k) close(k, num_chunks - 1);
}

}  // namespace

void NarrowedScratch::ensure(int w, int nd) {
  // Box sums of a chunk read columns 8 j - r .. 8 j + 7 + r, j < ceil(W / 8): within
  // [-16, W + 24) for windows up to 33 px.
  v_pad = 32;
  v_stride = w + 2 * v_pad + 8;
  v.assign(static_cast<size_t>(nd) * v_stride, 0.f);
  valid.assign(nd, VValidity{});
  const int nc = (w + 7) / 8;
  band_lo.assign(nc, 0);
  band_hi.assign(nc, -1);
  run_from.assign(nd, 0);
  iv_count.assign(nd, 0);
  iv_cap = nc + 1;
  iv_by_k.assign(static_cast<size_t>(nd) * iv_cap, Interval{0, -1});
  // Index x - k + nd + 7 for 0 <= x < 8 nc, 0 <= k < nd: within [8, 8 nc + nd + 7), whole
  // vectors from there.
  q_len = 8 * nc + nd + 16;
  sum_r_q.assign(q_len, 0.f);
  inv_r_q.assign(q_len, 0.f);
  layoutTrackers(q_len, &rl_copy_stride, &rl_d_offset);
  rl_trackers.assign(static_cast<size_t>(rl_d_offset) + 8 * static_cast<size_t>(rl_copy_stride),
                     0.f);
}

void NarrowedScratch::resetSums() {
  for (auto& vv : valid) {
    vv.cur_row = -10;
    vv.cur.clear();
    vv.prev.clear();
  }
}

void narrowedRow(const WindowLevel& c, RowScratch& s, NarrowedScratch& e, int y) {
  const int W = c.width, nd = c.dmax - c.dmin + 1;
  const int nc = (W + 7) / 8;
  // The last chunk's lanes past the row have no range.
  for (int x = W; x < 8 * nc; ++x) {
    s.eff_lo_f[x] = 1e9f;
    s.eff_hi_f[x] = -1e9f;
    s.act[x] = 0.f;
  }
  if (chunkBands(s.eff_lo_f.data(), s.eff_hi_f.data(), nc, static_cast<float>(c.dmin),
                 e.band_lo.data(), e.band_hi.data()) == 0) {
    std::fill(s.rl_best_d.begin(), s.rl_best_d.begin() + W, 0.f);
    return;
  }
  intervalsOfRow(c, e, nc);
  for (int k = 0; k < nd; ++k) {
    if (e.iv_count[k] > 0) {
      ensureV(c, e, k, y, e.iv_by_k.data() + static_cast<size_t>(k) * e.iv_cap, e.iv_count[k]);
    }
  }
  // The span of right-pixel indices the chunks touch (chunk j, band [k0, k1]: 8 j + nd + 7 - k1
  // .. 8 j + nd + 14 - k0), whole vectors.
  int i0 = e.q_len, i1 = 0;
  for (int j = 0; j < nc; ++j) {
    if (e.band_lo[j] > e.band_hi[j]) continue;
    i0 = std::min(i0, 8 * j + nd + 7 - e.band_hi[j]);
    i1 = std::max(i1, 8 * j + nd + 15 - e.band_lo[j]);
  }
  i1 = std::min(e.q_len, i0 + (i1 - i0 + 7) / 8 * 8);
  const int n_idx = i1 - i0;
  // Right statistics of right pixel q at index q + q_off (zero where there is none).
  const int q_off = c.dmin + nd + 7;
  {
    const int a = std::min(std::max(i0, q_off), i1), b = std::max(std::min(i1, W + q_off), a);
    std::fill(e.sum_r_q.begin() + i0, e.sum_r_q.begin() + a, 0.f);
    std::fill(e.inv_r_q.begin() + i0, e.inv_r_q.begin() + a, 0.f);
    std::memcpy(e.sum_r_q.data() + a, s.maps.sum_r.data() + (a - q_off), sizeof(float) * (b - a));
    std::memcpy(e.inv_r_q.data() + a, s.maps.inv_r.data() + (a - q_off), sizeof(float) * (b - a));
    std::fill(e.sum_r_q.begin() + b, e.sum_r_q.begin() + i1, 0.f);
    std::fill(e.inv_r_q.begin() + b, e.inv_r_q.begin() + i1, 0.f);
  }
  float* const rl_v = e.rl_trackers.data();
  float* const rl_d = rl_v + e.rl_d_offset;
  clearTrackers(rl_v + i0, rl_d + i0, e.rl_copy_stride, n_idx);
  ChunkArgs g;
  g.w = c.w;
  g.r = c.r;
  g.dmin = c.dmin;
  g.nd = nd;
  g.num_chunks = nc;
  g.band_lo = e.band_lo.data();
  g.band_hi = e.band_hi.data();
  g.v = e.v.data() + e.v_pad;
  g.v_stride = e.v_stride;
  g.eff_lo_f = s.eff_lo_f.data();
  g.eff_hi_f = s.eff_hi_f.data();
  g.act = s.act.data();
  g.mean_l = s.maps.mean_l.data();
  g.inv_l = s.maps.inv_l.data();
  g.sum_r_q = e.sum_r_q.data();
  g.inv_r_q = e.inv_r_q.data();
  g.rl_v = rl_v;
  g.rl_d = rl_d;
  g.rl_copy_stride = e.rl_copy_stride;
  g.best = s.best.data();
  g.best_d = s.best_d.data();
  g.best_l = s.best_l.data();
  g.best_r = s.best_r.data();
  g.second = s.second.data();
  if (c.w == 9) {
    chunkSearchWidth9(g);
  } else if (c.w == 7) {
    chunkSearchWidth7(g);
  } else {
    chunkSearch(g);
  }
  mergeTrackerCopies(rl_v + i0, rl_d + i0, e.rl_copy_stride, n_idx, kCopies);
  // Right pixels outside the span received no offer: disparity 0, as an empty tracker holds.
  const int a = std::min(std::max(0, i0 - q_off), W), b = std::max(std::min(W, i1 - q_off), a);
  std::fill(s.rl_best_d.begin(), s.rl_best_d.begin() + a, 0.f);
  std::memcpy(s.rl_best_d.data() + a, rl_d + a + q_off, sizeof(float) * (b - a));
  std::fill(s.rl_best_d.begin() + b, s.rl_best_d.begin() + W, 0.f);
}

}  // namespace detail
}  // namespace endo_stereo
