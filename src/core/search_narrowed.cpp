// The narrowed-range search engine (see search_narrowed.hpp): dense rows with per-pixel search
// ranges. For each disparity d (in increasing order) only the column intervals whose pixels
// search d are computed (buildIntervals); their vertical window sums are made valid for the row
// (ensureV: kept, one row in and one out, or afresh), summed horizontally and turned into the NCC
// slice S(., d), which feeds each pixel's streaming peak tracker and the right-to-left tracker of
// each right pixel x - d (trackSliceImpl).

#include "search_narrowed.hpp"

#include <algorithm>
#include <cstring>

#include "ncc_kernels.hpp"
#include "simd.hpp"

namespace endo_stereo {
namespace detail {

namespace {

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

/// Inputs of the per-disparity update of one row interval. Pointers are offset so
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
  const float* eff_lo_f;
  const float* eff_hi_f;
  const float* act;
  float *p1, *p2, *best, *best_d, *best_l, *best_r, *second;
  float *rl_best_v, *rl_best_d;  // at x - d
};

// The streaming peak tracker. At disparity d a pixel knows S(d-2), S(d-1) (p2, p1) and S(d):
// d-1 is an interior local maximum when S(d-1) > S(d-2) and S(d-1) >= S(d) with d-2 inside its
// range. The highest interior maximum is the best (its neighbours kept for the parabola); every
// other maximum, and a range end where the profile rises towards it (the true peak may lie
// beyond), competes for the peak gap. Local maxima are never adjacent, so "outside +-1 px of the
// best" holds by construction. Written once on GCC vector types (8 lanes: AVX2 in the avx2 clone,
// two SSE halves otherwise) for the body, once in scalar form for the tail; the same lane by lane.
template <bool kOwn, bool kRl, int kW>
ES_INLINE void trackSliceImpl(const SliceArgs& g) {
  const float d = g.d, dm1 = g.d - 1.f;
  const float* __restrict vs = g.v;
  const float* __restrict h = g.h;
  const float* __restrict mean_l = g.mean_l;
  const float* __restrict inv_l = g.inv_l;
  const float* __restrict sum_r = g.sum_r;
  const float* __restrict inv_r = g.inv_r;
  const float* __restrict eff_lo_f = g.eff_lo_f;
  const float* __restrict eff_hi_f = g.eff_hi_f;
  const float* __restrict act = g.act;
  float* __restrict p1 = g.p1;
  float* __restrict p2 = g.p2;
  float* __restrict best = g.best;
  float* __restrict best_d = g.best_d;
  float* __restrict best_l = g.best_l;
  float* __restrict best_r = g.best_r;
  float* __restrict second = g.second;
  float* __restrict rl_best_v = g.rl_best_v;
  float* __restrict rl_best_d = g.rl_best_d;
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
    const V8f lo = load8(eff_lo_f + i), hi = load8(eff_hi_f + i);
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
      const V8f rv = load8(rl_best_v + i);
      const V8i up = inr & (s > rv);
      store8(rl_best_v + i, up ? s : rv);
      store8(rl_best_d + i, up ? vd : load8(rl_best_d + i));
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
    const bool inr = (eff_lo_f[i] <= d) & (d <= eff_hi_f[i]);
    if (kOwn) {
      const bool own = inr & (act[i] > 0.f);
      const float a1 = p1[i], a2 = p2[i], bb = best[i];
      const bool is_max = own & (d >= eff_lo_f[i] + 2.f) & (a1 > a2) & (a1 >= s);
      const bool new_best = is_max & (a1 > bb);
      float cand = new_best ? bb : (is_max ? a1 : kNegInf);
      const bool lo_end = own & (d == eff_lo_f[i] + 1.f) & (a1 > s);
      const bool hi_end = own & (d == eff_hi_f[i]) & (s > a1);
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
      const float rv = rl_best_v[i];
      const bool up = inr & (s > rv);
      rl_best_v[i] = up ? s : rv;
      rl_best_d[i] = up ? d : rl_best_d[i];
    }
  }
}

ES_KERNEL void trackSlice(const SliceArgs& g) { trackSliceImpl<true, true, 0>(g); }
ES_KERNEL void trackSliceWidth7(const SliceArgs& g) { trackSliceImpl<true, true, 7>(g); }

/// Make the vertical window sums of disparity index k valid on the columns @p need (sorted,
/// disjoint intervals) of row y: columns already computed for row y are kept, columns valid for
/// row y - 1 are updated by one row in and one row out, the rest are summed afresh over the
/// window's rows. All exact, so the three ways give identical values.
void ensureV(const WindowLevel& c, NarrowedScratch& e, int k, int y,
             const std::vector<Interval>& need) {
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
  float* v = e.v.data() + static_cast<size_t>(k) * c.width;
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
  e.pieces.clear();
  size_t ci = 0;
  for (const Interval& nv : need) {
    int x = nv.a;
    while (ci < vv.cur.size() && vv.cur[ci].b < x) ++ci;
    for (size_t j = ci; j < vv.cur.size() && vv.cur[j].a <= nv.b; ++j) {
      if (vv.cur[j].a > x) e.pieces.push_back({x, vv.cur[j].a - 1});
      x = std::max(x, vv.cur[j].b + 1);
    }
    if (x <= nv.b) e.pieces.push_back({x, nv.b});
  }
  if (e.pieces.empty()) return;
  auto fresh = [&](int fa, int fb) {
    const int n = fb - fa + 1;
    vSet(n, v + fa, lf.ptr<float>(y - r) + fa, rf.ptr<float>(y - r) + fa - d);
    for (int yy = y - r + 1; yy <= y + r; ++yy) {
      vAdd(n, v + fa, lf.ptr<float>(yy) + fa, rf.ptr<float>(yy) + fa - d);
    }
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

/// For each disparity, the column intervals worth computing: the hull, within each block of
/// kBlock columns, of the columns @p cols (sorted), for the blocks where one of them has the
/// disparity in its effective range; intervals closer than a window width are merged (their
/// vertical sums overlap anyway). Clipped to the columns where both windows fit. Results in
/// e.ivs / e.iv_start. Cost O(columns + blocks * disparities).
void buildIntervals(const WindowLevel& c, RowScratch& s, NarrowedScratch& e,
                    const std::vector<int>& cols) {
  const int W = c.width, nd = c.dmax - c.dmin + 1, r = c.r;
  const int nb = static_cast<int>(e.block_a.size());
  // Coverage per block as a difference array over the disparity indices (kept all zero between
  // calls: only the indices a block touched are cleared again below), and the span it touches.
  // Only coverage > 0 matters, so a pixel with the same range as the pixel before it in its
  // block adds nothing (the common case: neighbours' ranges are alike), and skipping it also
  // spares the chain of increments of one counter, each waiting for the one before.
  e.blocks.clear();
  int last_k0 = -1, last_k1 = -1, cur_b = -1;
  const int* __restrict eff_lo_f = s.eff_lo.data();
  const int* __restrict eff_hi_f = s.eff_hi.data();
  int* __restrict block_a = e.block_a.data();
  int* __restrict block_b = e.block_b.data();
  int* __restrict block_k0 = e.block_k0.data();
  int* __restrict block_k1 = e.block_k1.data();
  int* __restrict cover = e.cover.data();
  const int dmin = c.dmin;
  for (const int x : cols) {
    const int b = x / kBlock;  // x >= 0
    const int k0 = eff_lo_f[x] - dmin, k1 = eff_hi_f[x] - dmin;
    if (b != cur_b) {
      cur_b = b;
      e.blocks.push_back(b);
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
  std::fill(e.iv_count.begin(), e.iv_count.begin() + nd, 0);
  for (int b : e.blocks) {
    int* cv = e.cover.data() + static_cast<size_t>(b) * (nd + 1);
    const int k0 = e.block_k0[b], k1 = e.block_k1[b];
    int count = 0;
    for (int k = k0; k <= k1; ++k) {
      count += cv[k];
      cv[k] = 0;
      if (count <= 0) continue;
      const int d = c.dmin + k;
      const int lo = std::max(r, d + r), hi = std::min(W - 1 - r, d + W - 1 - r);
      const int a = std::max(lo, e.block_a[b]), end = std::min(hi, e.block_b[b]);
      if (a > end) continue;
      Interval* list = e.iv_by_k.data() + static_cast<size_t>(k) * nb;
      int& n = e.iv_count[k];
      if (n > 0 && list[n - 1].b + c.w >= a) {
        list[n - 1].b = end;
      } else {
        list[n++] = {a, end};
      }
    }
    cv[k1 + 1] = 0;
  }
  e.ivs.clear();
  for (int k = 0; k < nd; ++k) {
    e.iv_start[k] = static_cast<int>(e.ivs.size());
    const Interval* list = e.iv_by_k.data() + static_cast<size_t>(k) * nb;
    e.ivs.insert(e.ivs.end(), list, list + e.iv_count[k]);
  }
  e.iv_start[nd] = static_cast<int>(e.ivs.size());
}

/// NCC slice of disparity index k over columns [a, b] of row y, fed to the peak tracker (own
/// profiles and right-to-left profiles); the vertical sums v (of disparity k) must be valid on
/// [a - r, b + r].
void sliceRange(const WindowLevel& c, RowScratch& s, NarrowedScratch& e, int k, int a, int b,
                const float* v) {
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
      boxSumRow(v + ra - r, n, c.w, e.hsum.data(), e.box_tmp_a.data(), e.box_tmp_b.data());
      g.v = nullptr;
      g.h = e.hsum.data();
    }
    g.mean_l = s.maps.mean_l.data() + ra;
    g.inv_l = s.maps.inv_l.data() + ra;
    g.sum_r = s.maps.sum_r.data() + ra - d;
    g.inv_r = s.maps.inv_r.data() + ra - d;
    g.eff_lo_f = s.eff_lo_f.data() + ra;
    g.eff_hi_f = s.eff_hi_f.data() + ra;
    g.act = s.act.data() + ra;
    g.p1 = e.p1.data() + ra;
    g.p2 = e.p2.data() + ra;
    g.best = s.best.data() + ra;
    g.best_d = s.best_d.data() + ra;
    g.best_l = s.best_l.data() + ra;
    g.best_r = s.best_r.data() + ra;
    g.second = s.second.data() + ra;
    g.rl_best_v = s.rl_best_v.data() + ra - d;
    g.rl_best_d = s.rl_best_d.data() + ra - d;
    if (direct && c.w == 7) {
      trackSliceWidth7(g);
    } else {
      trackSlice(g);
    }
  }
}

/// NCC slices of disparity index k over the column intervals @p out_ivs (sorted, disjoint) of
/// row y (per-pixel ranges).
void narrowedSlices(const WindowLevel& c, RowScratch& s, NarrowedScratch& e, int k, int y,
                    const Interval* out_ivs, int count) {
  if (count <= 0) return;
  const int r = c.r;
  e.need.clear();
  for (int i = 0; i < count; ++i) {
    const int a = out_ivs[i].a - r, b = out_ivs[i].b + r;
    if (!e.need.empty() && a <= e.need.back().b + 1) {
      e.need.back().b = std::max(e.need.back().b, b);
    } else {
      e.need.push_back({a, b});
    }
  }
  ensureV(c, e, k, y, e.need);
  const float* v = e.v.data() + static_cast<size_t>(k) * c.width;
  for (int i = 0; i < count; ++i) sliceRange(c, s, e, k, out_ivs[i].a, out_ivs[i].b, v);
}

}  // namespace

void NarrowedScratch::ensure(int w, int nd) {
  v.assign(static_cast<size_t>(nd) * w, 0.f);
  valid.assign(nd, VValidity{});
  for (auto* vec : {&box_tmp_a, &box_tmp_b, &hsum, &p1, &p2}) vec->assign(w + 64, 0.f);
  const int nb = (w + kBlock - 1) / kBlock;
  cover.assign(static_cast<size_t>(nb) * (nd + 1), 0);
  iv_start.assign(nd + 1, 0);
  block_a.assign(nb, 0);
  block_b.assign(nb, 0);
  block_k0.assign(nb, 0);
  block_k1.assign(nb, -1);
  iv_count.assign(nd, 0);
  iv_by_k.assign(static_cast<size_t>(nd) * nb, Interval{0, -1});
}

void NarrowedScratch::resetSums() {
  for (auto& vv : valid) {
    vv.cur_row = -10;
    vv.cur.clear();
    vv.prev.clear();
  }
}

void narrowedRow(const WindowLevel& c, RowScratch& s, NarrowedScratch& e, int y) {
  const int W = c.width, r = c.r, nd = c.dmax - c.dmin + 1;
  // The streaming trackers start empty.
  std::fill(e.p1.begin(), e.p1.begin() + W, kNegInf);
  std::fill(e.p2.begin(), e.p2.begin() + W, kNegInf);
  std::fill(s.rl_best_v.begin(), s.rl_best_v.begin() + W, kNegInf);
  std::fill(s.rl_best_d.begin(), s.rl_best_d.begin() + W, 0.f);
  // Every pixel with an effective range takes part (its range bounds the right-to-left
  // profiles), active or not.
  e.pick.resize(W);
  int np = 0;
  for (int x = r; x < W - r; ++x) {
    e.pick[np] = x;
    np += s.eff_lo[x] <= s.eff_hi[x];
  }
  e.pick.resize(np);
  buildIntervals(c, s, e, e.pick);
  for (int k = 0; k < nd; ++k) {
    narrowedSlices(c, s, e, k, y, e.ivs.data() + e.iv_start[k], e.iv_start[k + 1] - e.iv_start[k]);
  }
}

}  // namespace detail
}  // namespace endo_stereo
