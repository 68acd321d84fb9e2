// The robust matcher of Bernhardt, Abi-Nahed and Abugharbieh (2012), METHOD.md sections 2 and 3.
//
// How the work is organised (why it is fast and exact):
// - Intensities are stored as float (value - 128), so every product lies in [-16384, 16384] and
//   every window sum of products of a window up to 32 x 32 stays below 2^24: the box sums are exact
//   integers in float arithmetic. Running sums, fresh sums and any order of summation therefore give
//   bit-identical values, so the output cannot depend on the number of threads or on where a stripe
//   of rows starts.
// - For one window size, rows are processed in fixed stripes (cv::parallel_for_ over stripe
//   indices; the stripes do not depend on the thread count). Within a row the disparities are
//   streamed in increasing order; for each disparity d the vertical window sums of
//   L(x, y') * R(x - d, y') are kept per column from the previous row (one row of them per d) and
//   the horizontal window sum is built by doubling (sums of 2, 4, 8, 16 neighbours), so one NCC
//   slice costs O(width) per row whatever the window size.
// - Nothing but the per-pixel peak state is kept: the best interior local maximum with its two
//   neighbours (for the parabola), the highest other maximum (for the peak gap), and for every
//   right pixel q the best disparity of its right-to-left profile S_RL(q, d) = S_LR(q + d, d), which
//   is the left-right check without a second correlation pass.
// - Only the pixels that failed at one window size are matched again with the next one; a row
//   without such pixels is skipped, and within a row only the columns whose NCC values can matter
//   (the failed pixels' profiles and the right-to-left profiles of the right pixels they may match)
//   are computed.
#include "endo_stereo/core/matcher.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <atomic>
#include <cstdio>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <vector>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

namespace endo_stereo {

std::string MatcherParams::validate() const {
  std::ostringstream msg;
  if (max_disparity < min_disparity) {
    msg << "matcher.max_disparity = " << max_disparity << " must be >= matcher.min_disparity = "
        << min_disparity;
  } else if (max_disparity - min_disparity > 4095 || std::abs(min_disparity) > 16383 ||
             std::abs(max_disparity) > 16383) {
    msg << "matcher.min_disparity/max_disparity = " << min_disparity << "/" << max_disparity
        << " must lie in [-16383, 16383] and span at most 4096 values";
  } else if (window_min_px < 3 || window_min_px % 2 == 0) {
    msg << "matcher.window_min_px = " << window_min_px << " must be odd and >= 3";
  } else if (window_step_px < 2 || window_step_px % 2 != 0) {
    msg << "matcher.window_step_px = " << window_step_px << " must be even and >= 2";
  } else if (window_max_px < window_min_px || window_max_px > 32) {
    // Up to 32 x 32 the window sums are exact in float (see the top of matcher.cpp).
    msg << "matcher.window_max_px = " << window_max_px << " must be in [window_min_px = "
        << window_min_px << ", 32]";
  } else if ((window_max_px - window_min_px) / window_step_px + 1 > 16) {
    msg << "matcher.window_max_px = " << window_max_px << " allows more than 16 window sizes";
  } else if (!(gamma_min >= 0.0) || !std::isfinite(gamma_min)) {
    msg << "matcher.gamma_min = " << gamma_min << " must be finite and >= 0";
  } else if (!(delta_min >= 0.0 && delta_min <= 2.0)) {
    msg << "matcher.delta_min = " << delta_min << " must be in [0, 2]";
  } else if (!(min_ncc >= -1.0 && min_ncc <= 1.0)) {
    msg << "matcher.min_ncc = " << min_ncc << " must be in [-1, 1] (-1 = off)";
  } else if (!(epsilon_px > 0.0) || !std::isfinite(epsilon_px)) {
    msg << "matcher.epsilon_px = " << epsilon_px << " must be finite and > 0";
  } else if (num_threads < 0) {
    msg << "matcher.num_threads = " << num_threads << " must be >= 0 (0 = OpenCV's default)";
  } else if (edge_window_max_px < 0) {
    msg << "matcher.edge_window_max_px = " << edge_window_max_px << " must be >= 0 (0 = off)";
  } else if (!(edge_disparity_jump_px >= 0.0) || !std::isfinite(edge_disparity_jump_px)) {
    msg << "matcher.edge_disparity_jump_px = " << edge_disparity_jump_px
        << " must be finite and >= 0 (0 = off)";
  }
  return msg.str();
}

namespace {

constexpr float kNegInf = -std::numeric_limits<float>::infinity();
// Fixed stripes of rows, so the work split never depends on the thread count.
constexpr int kStripeRows = 32;
// Column blocks used to find, per disparity, the column intervals worth computing.
constexpr int kBlock = 32;

// Sentinel of an empty effective range.
constexpr int kEmptyLo = std::numeric_limits<int>::max() / 2;
constexpr int kEmptyHi = std::numeric_limits<int>::min() / 2;

/// Per-window-size maps over the whole image.
struct LevelMaps {
  cv::Mat mean_l;   ///< CV_32F window mean of the left (value - 128)
  cv::Mat inv_l;    ///< CV_32F sqrt(n / (n * sum(L^2) - sum(L)^2)), 0 where flat
  cv::Mat sum_r;    ///< CV_32F window sum of the right (value - 128)
  cv::Mat inv_r;    ///< CV_32F as inv_l for the right view
  cv::Mat gamma_l;  ///< CV_32F stdev of the Laplacian over the window, left
  cv::Mat gamma_r;  ///< CV_32F same, right
};

struct Interval {
  int a, b;  // inclusive
};

/// Columns of the vertical window sums of one disparity that hold valid values, for the row
/// computed last (`cur_row`) and the row before it (`prev`), as sorted disjoint intervals.
struct VValidity {
  int cur_row = -10;
  std::vector<Interval> cur, prev;
};

/// Scratch of one worker, reused between rows, stripes, levels and frames.
struct Scratch {
  int width = 0;
  int num_d = 0;
  std::vector<float> v;            // vertical window sums, num_d rows of width
  std::vector<VValidity> valid;    // per disparity
  std::vector<float> tmp_a, tmp_b, hsum;
  std::vector<float> elo, ehi, act;  // effective range and activity of this row, as float
  std::vector<int> elo_i, ehi_i;
  std::vector<float> p1, p2, best, best_d, best_l, best_r, second;
  std::vector<float> rb_v, rb_d;
  std::vector<int> cover;          // per block, per disparity: pixels whose range holds it
  std::vector<int> iv_start;       // per disparity: first index into ivs
  std::vector<Interval> ivs;       // the intervals of all disparities, grouped by disparity
  std::vector<Interval> pieces, merged, need, runs, out_ivs;
  std::vector<uint8_t> cand;       // per right pixel: a candidate of phase B
  std::vector<int> block_a, block_b;  // per block: first and last selected column
  std::vector<int> blocks, active, pick, cand_q;

  void ensure(int w, int nd) {
    if (w != width || nd != num_d) {
      width = w;
      num_d = nd;
      v.assign(static_cast<size_t>(nd) * w, 0.f);
      valid.assign(nd, VValidity{});
      for (auto* vec : {&tmp_a, &tmp_b, &hsum, &elo, &ehi, &act, &p1, &p2, &best, &best_d,
                        &best_l, &best_r, &second, &rb_v, &rb_d}) {
        vec->assign(w + 64, 0.f);
      }
      elo_i.assign(w, 0);
      ehi_i.assign(w, 0);
      const int nb = (w + kBlock - 1) / kBlock;
      cover.assign(static_cast<size_t>(nb) * (nd + 1), 0);
      iv_start.assign(nd + 1, 0);
      ivs.reserve(static_cast<size_t>(nb) * nd);
      cand.assign(w, 0);
      block_a.assign(nb, 0);
      block_b.assign(nb, 0);
    }
  }
  /// Forget all vertical sums (new level or new frame).
  void resetV() {
    for (auto& vv : valid) {
      vv.cur_row = -10;
      vv.cur.clear();
      vv.prev.clear();
    }
  }
};

// --- Vectorisable kernels. Built for AVX2 and for the baseline, chosen at load time, so the
// library runs on any x86-64 and uses AVX2 where the CPU has it. ---------------------------------
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#define ES_KERNEL __attribute__((target_clones("avx2", "default")))
#else
#define ES_KERNEL
#endif

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

/// Inputs of the per-disparity update of one row interval. Pointers are offset so that index i
/// is column x = a + i (left quantities) or right column x - d (right quantities, rb_*).
struct SliceArgs {
  int n;
  float d;
  const float* h;       // window sums of L * R(x - d)
  const float* mean_l;
  const float* inv_l;
  const float* sum_r;   // at x - d
  const float* inv_r;   // at x - d
  const float* elo;
  const float* ehi;
  const float* act;
  float *p1, *p2, *best, *best_d, *best_l, *best_r, *second;
  float *rb_v, *rb_d;   // at x - d
};

// The streaming peak tracker. At disparity d a pixel knows S(d-2), S(d-1) (p2, p1) and S(d):
// d-1 is an interior local maximum when S(d-1) > S(d-2) and S(d-1) >= S(d) with d-2 inside its
// range. The highest interior maximum is the best (its neighbours kept for the parabola); every
// other maximum, and a range end where the profile rises towards it (the true peak may lie
// beyond), competes for the peak gap. Local maxima are never adjacent, so "outside +-1 px of the
// best" holds by construction.
//
// Written once on GCC vector types (8 lanes; AVX2 in the avx2 clone, two SSE halves otherwise)
// for the body and once in scalar form for the tail; both compute the same thing lane by lane.
typedef float V8f __attribute__((vector_size(32)));
typedef int V8i __attribute__((vector_size(32)));

__attribute__((always_inline)) inline V8f load8(const float* p) {
  V8f v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
__attribute__((always_inline)) inline void store8(float* p, V8f v) { std::memcpy(p, &v, sizeof(v)); }
__attribute__((always_inline)) inline V8f max8(V8f a, V8f b) { return a > b ? a : b; }

template <bool kOwn, bool kRl>
__attribute__((always_inline)) inline void sliceUpdate(const SliceArgs& g) {
  const float d = g.d, dm1 = g.d - 1.f;
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
  int i = 0;
  const V8f vd = {d, d, d, d, d, d, d, d};
  const V8f vdm1 = vd - 1.f;
  const V8f vninf = {kNegInf, kNegInf, kNegInf, kNegInf, kNegInf, kNegInf, kNegInf, kNegInf};
  const V8f vzero = {0, 0, 0, 0, 0, 0, 0, 0};
  for (; i + 8 <= g.n; i += 8) {
    const V8f s = (load8(h + i) - load8(mean_l + i) * load8(sum_r + i)) * load8(inv_l + i) *
                  load8(inv_r + i);
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
      store8(best + i, new_best ? a1 : bb);
      store8(best_d + i, new_best ? vdm1 : load8(best_d + i));
      store8(best_l + i, new_best ? a2 : load8(best_l + i));
      store8(best_r + i, new_best ? s : load8(best_r + i));
      store8(p2 + i, own ? a1 : a2);
      store8(p1 + i, own ? s : a1);
    }
    if (kRl) {
      // Right-to-left profile of right pixel x - d: S_RL(x - d, d) = S_LR(x, d). Strict > keeps
      // the smallest disparity among equal values, whatever the order of the intervals.
      const V8f rv = load8(rb_v + i);
      const V8i up = inr & (s > rv);
      store8(rb_v + i, up ? s : rv);
      store8(rb_d + i, up ? vd : load8(rb_d + i));
    }
  }
  for (; i < g.n; ++i) {
    const float s = (h[i] - mean_l[i] * sum_r[i]) * inv_l[i] * inv_r[i];
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

ES_KERNEL void sliceOwnAndRl(const SliceArgs& g) { sliceUpdate<true, true>(g); }
ES_KERNEL void sliceOwn(const SliceArgs& g) { sliceUpdate<true, false>(g); }
ES_KERNEL void sliceRl(const SliceArgs& g) { sliceUpdate<false, true>(g); }

}  // namespace

struct RobustMatcher::Impl {
  // Per-frame images.
  cv::Mat lf, rf;        // CV_32F value - 128
  cv::Mat lap_l, lap_r;  // CV_32F 3x3 Laplacian on 0..255
  cv::Mat lap_l2, lap_r2;
  cv::Mat range_lo, range_hi;  // CV_32S requested range per pixel (clamped), lo > hi = none
  cv::Mat state;         // CV_8U: 0 = undecided/failed so far, 1 = accepted
  cv::Mat window_idx;    // CV_8U window index that accepted
  LevelMaps maps;
  cv::Mat tmp1, tmp2, tmp3, tmp4, code_before;

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
  int level;
  int w, r;
  int width, height;
  int dmin, dmax;
  const cv::Mat* lf;
  const cv::Mat* rf;
  const cv::Mat* range_lo;
  const cv::Mat* range_hi;
  const LevelMaps* maps;
  cv::Mat* state;       // 1 = accepted earlier
  cv::Mat* window_idx;
  MatchResult* out;
};

/// Make the vertical window sums of disparity index k valid on the columns @p need (sorted,
/// disjoint intervals) of row y: columns already computed for row y are kept, columns valid for
/// row y - 1 are updated by one row in and one row out, the rest are summed afresh over the
/// window's rows. All exact (integers in float), so the three ways give identical values.
void ensureV(const LevelContext& c, Scratch& s, int k, int y, const std::vector<Interval>& need) {
  const int d = c.dmin + k;
  const int r = c.r;
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
  const float* l_in = c.lf->ptr<float>(std::min(y + r, c.height - 1));
  const float* r_in = c.rf->ptr<float>(std::min(y + r, c.height - 1)) - d;
  const float* l_out = c.lf->ptr<float>(std::max(y - r - 1, 0));
  const float* r_out = c.rf->ptr<float>(std::max(y - r - 1, 0)) - d;
  auto fresh = [&](int fa, int fb) {
    const int n = fb - fa + 1;
    vSet(n, v + fa, c.lf->ptr<float>(y - r) + fa, c.rf->ptr<float>(y - r) + fa - d);
    for (int yy = y - r + 1; yy <= y + r; ++yy) {
      vAdd(n, v + fa, c.lf->ptr<float>(yy) + fa, c.rf->ptr<float>(yy) + fa - d);
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
      vRunning(e - ra + 1, v + ra, l_in + ra, r_in + ra, l_out + ra, r_out + ra);
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
/// kBlock columns, of the pixels selected by @p pick, for the blocks where one of them has the
/// disparity in its effective range; intervals closer than a window width are merged (their
/// vertical sums overlap anyway). Clipped to the columns where both windows fit. Results in
/// s.ivs / s.iv_start. Cost O(W + blocks * disparities).
void buildIntervals(const LevelContext& c, Scratch& s, const std::vector<int>& cols) {
  const int W = c.width, nd = c.dmax - c.dmin + 1, r = c.r;
  const int nb = (W + kBlock - 1) / kBlock;
  // Blocks holding a selected column, in increasing order.
  s.blocks.clear();
  for (int x : cols) {
    const int b = x / kBlock;
    if (s.blocks.empty() || s.blocks.back() != b) {
      s.blocks.push_back(b);
      std::fill(s.cover.begin() + static_cast<size_t>(b) * (nd + 1),
                s.cover.begin() + static_cast<size_t>(b + 1) * (nd + 1), 0);
      s.block_a[b] = x;
    }
    int* cv = s.cover.data() + static_cast<size_t>(b) * (nd + 1);
    ++cv[s.elo_i[x] - c.dmin];
    --cv[s.ehi_i[x] - c.dmin + 1];
    s.block_b[b] = x;
  }
  (void)nb;
  for (int b : s.blocks) {
    int* cv = s.cover.data() + static_cast<size_t>(b) * (nd + 1);
    for (int k = 1; k < nd; ++k) cv[k] += cv[k - 1];
  }
  s.ivs.clear();
  for (int k = 0; k < nd; ++k) {
    s.iv_start[k] = static_cast<int>(s.ivs.size());
    const int d = c.dmin + k;
    const int lo = std::max(r, d + r), hi = std::min(W - 1 - r, d + W - 1 - r);
    for (int b : s.blocks) {
      if (s.cover[static_cast<size_t>(b) * (nd + 1) + k] <= 0) continue;
      const int a = std::max(lo, s.block_a[b]), e = std::min(hi, s.block_b[b]);
      if (a > e) continue;
      if (s.ivs.size() > static_cast<size_t>(s.iv_start[k]) && s.ivs.back().b + c.w >= a) {
        s.ivs.back().b = e;
      } else {
        s.ivs.push_back({a, e});
      }
    }
  }
  s.iv_start[nd] = static_cast<int>(s.ivs.size());
}

struct DbgCounters { std::atomic<long> dense_el{0}, own_el{0}, rl_el{0}, rows_dense{0}, rows_sparse{0}; ~DbgCounters(){ if(getenv("ES_DBG")) fprintf(stderr,"dense %ld own %ld rl %ld rows d %ld s %ld\n",dense_el.load(),own_el.load(),rl_el.load(),rows_dense.load(),rows_sparse.load()); } };
DbgCounters g_dbg;
/// NCC slices of disparity index k over the column intervals @p out_ivs (sorted, disjoint) of
/// row y, fed to the peak tracker.
template <bool kOwn, bool kRl>
void runSlices(const LevelContext& c, Scratch& s, int k, int y, const Interval* out_ivs, int count) {
  if (count <= 0) return;
  const int d = c.dmin + k;
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
  for (int i = 0; i < count; ++i) {
    const int a = out_ivs[i].a;
    const int n = out_ivs[i].b - a + 1;
    if (kOwn && kRl) g_dbg.dense_el += n; else if (kOwn) g_dbg.own_el += n; else g_dbg.rl_el += n;
    boxSumRow(v + a - r, n, c.w, s.hsum.data(), s.tmp_a.data(), s.tmp_b.data());
    SliceArgs g;
    g.n = n;
    g.d = static_cast<float>(d);
    g.h = s.hsum.data();
    g.mean_l = c.maps->mean_l.ptr<float>(y) + a;
    g.inv_l = c.maps->inv_l.ptr<float>(y) + a;
    g.sum_r = c.maps->sum_r.ptr<float>(y) + a - d;
    g.inv_r = c.maps->inv_r.ptr<float>(y) + a - d;
    g.elo = s.elo.data() + a;
    g.ehi = s.ehi.data() + a;
    g.act = s.act.data() + a;
    g.p1 = s.p1.data() + a;
    g.p2 = s.p2.data() + a;
    g.best = s.best.data() + a;
    g.best_d = s.best_d.data() + a;
    g.best_l = s.best_l.data() + a;
    g.best_r = s.best_r.data() + a;
    g.second = s.second.data() + a;
    g.rb_v = s.rb_v.data() + a - d;
    g.rb_d = s.rb_d.data() + a - d;
    if (kOwn && kRl) {
      sliceOwnAndRl(g);
    } else if (kOwn) {
      sliceOwn(g);
    } else {
      sliceRl(g);
    }
  }
}

/// Match the active pixels of row y at one window size; writes only row y of the outputs.
///
/// Dense rows (most pixels still undecided, always the case at the first window) are matched in
/// one pass: every NCC value of the row feeds both the pixel's own profile and the right-to-left
/// profile of its right pixel. Sparse rows (larger windows, where only failed pixels remain) are
/// matched in two passes, so the work follows the failed pixels instead of the image width:
/// (A) the profiles of the active pixels only, which give each its best disparity; (B) for the
/// right pixels q those bests point at, the right-to-left profiles S(q + d, d) over all d.
void processRow(const LevelContext& c, int y, Scratch& s) {
  const int W = c.width;
  const int r = c.r;
  const int nd = c.dmax - c.dmin + 1;
  if (y < r || y >= c.height - r) return;

  const int* rlo = c.range_lo->ptr<int>(y);
  const int* rhi = c.range_hi->ptr<int>(y);
  const uint8_t* st = c.state->ptr<uint8_t>(y);
  uint8_t* code = c.out->code.ptr<uint8_t>(y);
  const float* gl = c.maps->gamma_l.ptr<float>(y);
  const float gmin = static_cast<float>(c.mp->gamma_min);

  // Effective range of each pixel at this window: its requested range, cut so that both windows
  // lie inside the images (empty outside [r, W - r)). Computed for every column, since the
  // right-to-left profiles need the ranges of pixels that are not matched themselves.
  int* elo_i = s.elo_i.data();
  int* ehi_i = s.ehi_i.data();
  float* elo = s.elo.data();
  float* ehi = s.ehi.data();
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
  // Active = not accepted yet, range of at least 3 values (an interior maximum needs two
  // neighbours), left patch with structure. The others that are still open get their code.
  s.active.clear();
  int n_valid = 0;
  for (int x = r; x < W - r; ++x) {
    if (elo_i[x] > ehi_i[x]) continue;
    ++n_valid;
    if (st[x] != 0) continue;
    if (ehi_i[x] - elo_i[x] < 2) {
      code[x] = kCodeNoPeak;
    } else if (!(gl[x] > gmin)) {
      code[x] = kCodeRejectStructure;
    } else {
      s.active.push_back(x);
    }
  }
  if (s.active.empty()) return;
  std::fill(s.act.begin(), s.act.begin() + W, 0.f);
  for (int x : s.active) {
    s.act[x] = 1.f;
    s.p1[x] = s.p2[x] = kNegInf;
    s.best[x] = s.second[x] = kNegInf;
    s.best_d[x] = s.best_l[x] = s.best_r[x] = 0.f;
  }
  std::fill(s.rb_v.begin(), s.rb_v.begin() + W, kNegInf);
  std::fill(s.rb_d.begin(), s.rb_d.begin() + W, 0.f);

  const int n_active = static_cast<int>(s.active.size());
  const bool dense = 2 * n_active >= n_valid;
  if (dense) g_dbg.rows_dense++; else g_dbg.rows_sparse++;
  const float* gr = c.maps->gamma_r.ptr<float>(y);
  const float delta_min = static_cast<float>(c.mp->delta_min);
  const float min_ncc = static_cast<float>(c.mp->min_ncc);
  // The discrimination test, shared by both paths: best peak above min_ncc and clear of the
  // second by more than delta_min (a single peak is measured against the lowest NCC, -1).
  auto peakGap = [&](int x) {
    const float comp = s.second[x] == kNegInf ? -1.f : s.second[x];
    return s.best[x] - comp;
  };
  if (dense) {
    s.pick.clear();
    for (int x = r; x < W - r; ++x) {
      if (elo_i[x] <= ehi_i[x]) s.pick.push_back(x);
    }
    buildIntervals(c, s, s.pick);
    for (int k = 0; k < nd; ++k) {
      runSlices<true, true>(c, s, k, y, s.ivs.data() + s.iv_start[k],
                            s.iv_start[k + 1] - s.iv_start[k]);
    }
  } else {
    buildIntervals(c, s, s.active);
    for (int k = 0; k < nd; ++k) {
      runSlices<true, false>(c, s, k, y, s.ivs.data() + s.iv_start[k],
                             s.iv_start[k + 1] - s.iv_start[k]);
    }
    // Phase B only for pixels that pass everything but the left-right check.
    s.cand_q.clear();
    for (int x : s.active) {
      if (s.best[x] == kNegInf) continue;
      const int q = x - static_cast<int>(s.best_d[x]);
      if (!(gr[q] > gmin) || !(peakGap(x) > delta_min) || s.best[x] < min_ncc) continue;
      s.cand_q.push_back(q);
    }
    if (!s.cand_q.empty()) {
      std::sort(s.cand_q.begin(), s.cand_q.end());
      // Runs of candidate right pixels (gaps shorter than a window merged: the vertical sums of
      // the gap are needed anyway for the horizontal window sums).
      s.runs.clear();
      for (int q : s.cand_q) {
        if (!s.runs.empty() && q <= s.runs.back().b + c.w) {
          s.runs.back().b = std::max(s.runs.back().b, q);
        } else {
          s.runs.push_back({q, q});
        }
      }
      for (int k = 0; k < nd; ++k) {
        const int d = c.dmin + k;
        const int lo = std::max(r, d + r), hi = std::min(W - 1 - r, d + W - 1 - r);
        s.out_ivs.clear();
        for (const Interval& run : s.runs) {
          const int a = std::max(lo, run.a + d), b = std::min(hi, run.b + d);
          if (a <= b) s.out_ivs.push_back({a, b});
        }
        runSlices<false, true>(c, s, k, y, s.out_ivs.data(), static_cast<int>(s.out_ivs.size()));
      }
    }
  }

  // Decide each active pixel.
  float* disp = c.out->disparity.ptr<float>(y);
  float* conf = c.out->confidence.ptr<float>(y);
  uint8_t* stw = c.state->ptr<uint8_t>(y);
  uint8_t* widx = c.window_idx->ptr<uint8_t>(y);
  const float eps = static_cast<float>(c.mp->epsilon_px);
  for (int x : s.active) {
    if (s.best[x] == kNegInf) {
      code[x] = kCodeNoPeak;
      continue;
    }
    const int bd = static_cast<int>(s.best_d[x]);
    const int q = x - bd;
    if (!(gr[q] > gmin)) {
      code[x] = kCodeRejectStructure;
      continue;
    }
    const float delta = peakGap(x);
    if (!(delta > delta_min) || s.best[x] < min_ncc) {
      code[x] = kCodeRejectPeakGap;
      continue;
    }
    const float d_rl = s.rb_d[q];
    if (!(std::fabs(static_cast<float>(bd) - d_rl) < eps)) {
      code[x] = kCodeRejectLeftRight;
      continue;
    }
    float sub = 0.f;
    if (c.mp->subpixel) {
      const float den = s.best_l[x] - 2.f * s.best[x] + s.best_r[x];
      if (den < 0.f) sub = std::clamp(0.5f * (s.best_l[x] - s.best_r[x]) / den, -0.5f, 0.5f);
    }
    disp[x] = static_cast<float>(bd) + sub;
    conf[x] = std::clamp(delta, 0.f, 1.f);
    code[x] = static_cast<uint8_t>(kCodeAcceptedBase + c.level);
    stw[x] = 1;
    widx[x] = static_cast<uint8_t>(c.level);
  }
}

void computeLevelMaps(const cv::Mat& lf, const cv::Mat& rf, const cv::Mat& lap_l,
                      const cv::Mat& lap_l2, const cv::Mat& lap_r, const cv::Mat& lap_r2, int w,
                      LevelMaps& m, cv::Mat& t1, cv::Mat& t2) {
  const cv::Size ks(w, w);
  const double n = static_cast<double>(w) * w;
  auto side = [&](const cv::Mat& img, cv::Mat& mean_or_sum, cv::Mat& inv, bool as_mean) {
    cv::boxFilter(img, t1, CV_32F, ks, cv::Point(-1, -1), false, cv::BORDER_REPLICATE);
    cv::sqrBoxFilter(img, t2, CV_32F, ks, cv::Point(-1, -1), false, cv::BORDER_REPLICATE);
    mean_or_sum.create(img.size(), CV_32F);
    inv.create(img.size(), CV_32F);
    for (int y = 0; y < img.rows; ++y) {
      const float* s1 = t1.ptr<float>(y);
      const float* s2 = t2.ptr<float>(y);
      float* o = mean_or_sum.ptr<float>(y);
      float* iv = inv.ptr<float>(y);
      for (int x = 0; x < img.cols; ++x) {
        // Both sums are exact integers: n * sum2 - sum^2 is exact in double.
        const double a = n * static_cast<double>(s2[x]) -
                         static_cast<double>(s1[x]) * static_cast<double>(s1[x]);
        iv[x] = a > 0.5 ? static_cast<float>(std::sqrt(n / a)) : 0.f;
        o[x] = as_mean ? static_cast<float>(s1[x] / n) : s1[x];
      }
    }
  };
  side(lf, m.mean_l, m.inv_l, true);
  side(rf, m.sum_r, m.inv_r, false);
  auto gamma = [&](const cv::Mat& lap, const cv::Mat& lap2, cv::Mat& g) {
    cv::boxFilter(lap, t1, CV_32F, ks, cv::Point(-1, -1), true, cv::BORDER_REPLICATE);
    cv::boxFilter(lap2, t2, CV_32F, ks, cv::Point(-1, -1), true, cv::BORDER_REPLICATE);
    g.create(lap.size(), CV_32F);
    for (int y = 0; y < lap.rows; ++y) {
      const float* a = t1.ptr<float>(y);
      const float* b = t2.ptr<float>(y);
      float* o = g.ptr<float>(y);
      for (int x = 0; x < lap.cols; ++x) o[x] = std::sqrt(std::max(0.f, b[x] - a[x] * a[x]));
    }
  };
  gamma(lap_l, lap_l2, m.gamma_l);
  gamma(lap_r, lap_r2, m.gamma_r);
}

// Our measure against foreground fattening (see the block comment at the top of this file and
// notes/matcher_design.md): a pixel accepted with a window of width w is rejected when the accepted
// disparities inside that same window (judged on the map before this step) reach more than
// edge_disparity_jump_px away from its own disparity, i.e. when its window straddles a depth edge.
// Pixels accepted with a window wider than edge_window_max_px are also rejected when their w_min
// window straddles an edge. Min and max over each window size are grey-level erosions/dilations of
// the map (invalid pixels neutral), so the step costs O(pixels) per window size.
void rejectEdgeStraddlers(const MatcherParams& mp, int num_levels, const cv::Mat& window_idx,
                          MatchResult& out, cv::Mat& lo_src, cv::Mat& hi_src, cv::Mat& lo,
                          cv::Mat& hi) {
  const int H = out.disparity.rows, W = out.disparity.cols;
  const float inf = std::numeric_limits<float>::infinity();
  lo_src.create(H, W, CV_32F);
  hi_src.create(H, W, CV_32F);
  for (int y = 0; y < H; ++y) {
    const float* d = out.disparity.ptr<float>(y);
    float* a = lo_src.ptr<float>(y);
    float* b = hi_src.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const bool v = !std::isnan(d[x]);
      a[x] = v ? d[x] : inf;
      b[x] = v ? d[x] : -inf;
    }
  }
  const float jump = static_cast<float>(mp.edge_disparity_jump_px);
  const int limit_w = mp.edge_window_max_px;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // Rejections are applied after all levels are judged, so every test sees the original map.
  cv::Mat reject(H, W, CV_8U, cv::Scalar(0));
  for (int level = 0; level < num_levels; ++level) {
    const int w = mp.window_min_px + level * mp.window_step_px;
    bool any = level == 0 && limit_w > 0;
    for (int y = 0; y < H && !any; ++y) {
      const uint8_t* c = out.code.ptr<uint8_t>(y);
      const uint8_t* k = window_idx.ptr<uint8_t>(y);
      for (int x = 0; x < W; ++x) {
        if (c[x] >= kCodeAcceptedBase && k[x] == level) { any = true; break; }
      }
    }
    if (!any) continue;
    const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(w, w));
    cv::erode(lo_src, lo, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(inf));
    cv::dilate(hi_src, hi, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(-inf));
    for (int y = 0; y < H; ++y) {
      const float* d = out.disparity.ptr<float>(y);
      const uint8_t* c = out.code.ptr<uint8_t>(y);
      const uint8_t* k = window_idx.ptr<uint8_t>(y);
      const float* a = lo.ptr<float>(y);
      const float* b = hi.ptr<float>(y);
      uint8_t* rj = reject.ptr<uint8_t>(y);
      for (int x = 0; x < W; ++x) {
        if (c[x] < kCodeAcceptedBase) continue;
        const bool straddles = d[x] - a[x] > jump || b[x] - d[x] > jump;
        if (!straddles) continue;
        if (jump > 0.f && k[x] == level) rj[x] = 1;
        // Near an edge (its w_min window straddles it), only windows up to limit_w may accept.
        if (level == 0 && limit_w > 0 && mp.window_min_px + k[x] * mp.window_step_px > limit_w) {
          rj[x] = 1;
        }
      }
    }
  }
  for (int y = 0; y < H; ++y) {
    const uint8_t* rj = reject.ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) {
      if (!rj[x]) continue;
      out.disparity.at<float>(y, x) = nan;
      out.confidence.at<float>(y, x) = 0.f;
      out.code.at<uint8_t>(y, x) = kCodeRejectEdge;
    }
  }
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

  out.disparity.create(H, W, CV_32FC1);
  out.disparity.setTo(std::numeric_limits<float>::quiet_NaN());
  out.code.create(H, W, CV_8UC1);
  out.code.setTo(kCodeNotSearched);
  out.confidence.create(H, W, CV_32FC1);
  out.confidence.setTo(0.f);
  out.stats = MatchStats{};
  out.stats.total_pixels = static_cast<int64_t>(W) * H;

  left.convertTo(im.lf, CV_32F, 1.0, -128.0);
  right.convertTo(im.rf, CV_32F, 1.0, -128.0);
  cv::Laplacian(left, im.lap_l, CV_32F, 1);
  cv::Laplacian(right, im.lap_r, CV_32F, 1);
  cv::multiply(im.lap_l, im.lap_l, im.lap_l2);
  cv::multiply(im.lap_r, im.lap_r, im.lap_r2);

  im.range_lo.create(H, W, CV_32S);
  im.range_hi.create(H, W, CV_32S);
  int64_t prior_pixels = 0;
  if (range && !range->empty()) {
    for (int y = 0; y < H; ++y) {
      const int16_t* lo = range->lo.ptr<int16_t>(y);
      const int16_t* hi = range->hi.ptr<int16_t>(y);
      int* olo = im.range_lo.ptr<int>(y);
      int* ohi = im.range_hi.ptr<int>(y);
      for (int x = 0; x < W; ++x) {
        olo[x] = std::max<int>(lo[x], mp.min_disparity);
        ohi[x] = std::min<int>(hi[x], mp.max_disparity);
        if (lo[x] <= hi[x] && olo[x] <= ohi[x] &&
            (olo[x] > mp.min_disparity || ohi[x] < mp.max_disparity)) {
          ++prior_pixels;
        }
      }
    }
  } else {
    im.range_lo.setTo(mp.min_disparity);
    im.range_hi.setTo(mp.max_disparity);
  }
  out.stats.prior_pixels = prior_pixels;

  im.state.create(H, W, CV_8UC1);
  im.state.setTo(0);
  im.window_idx.create(H, W, CV_8UC1);
  im.window_idx.setTo(0);

  const int num_levels = (mp.window_max_px - mp.window_min_px) / mp.window_step_px + 1;
  const int nd = mp.max_disparity - mp.min_disparity + 1;
  const int num_stripes = (H + kStripeRows - 1) / kStripeRows;
  for (int level = 0; level < num_levels; ++level) {
    const int w = mp.window_min_px + level * mp.window_step_px;
    if (w > W || w > H) break;
    const auto tl0 = std::chrono::steady_clock::now();
    computeLevelMaps(im.lf, im.rf, im.lap_l, im.lap_l2, im.lap_r, im.lap_r2, w, im.maps, im.tmp1,
                     im.tmp2);
    const auto tl1 = std::chrono::steady_clock::now();
    LevelContext c{&mp, level, w, w / 2, W, H, mp.min_disparity, mp.max_disparity,
                   &im.lf, &im.rf, &im.range_lo, &im.range_hi, &im.maps, &im.state,
                   &im.window_idx, &out};
    cv::parallel_for_(cv::Range(0, num_stripes), [&](const cv::Range& rg) {
      std::unique_ptr<Scratch> s = im.acquire();
      s->ensure(W, nd);
      for (int stripe = rg.start; stripe < rg.end; ++stripe) {
        s->resetV();
        const int y_end = std::min(H, (stripe + 1) * kStripeRows);
        for (int y = stripe * kStripeRows; y < y_end; ++y) processRow(c, y, *s);
      }
      im.release(std::move(s));
    });
    if (getenv("ES_DBG")) fprintf(stderr, "level %d maps %.1f ms match %.1f ms\n", level,
      std::chrono::duration<double, std::milli>(tl1 - tl0).count(),
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - tl1).count());
  }
  const auto te0 = std::chrono::steady_clock::now();
  if (mp.edge_disparity_jump_px > 0.0 || mp.edge_window_max_px > 0) {
    rejectEdgeStraddlers(mp, num_levels, im.window_idx, out, im.tmp1, im.tmp2, im.tmp3, im.tmp4);
  }
  const auto t1 = std::chrono::steady_clock::now();
  if (getenv("ES_DBG")) fprintf(stderr, "edge %.1f ms\n", std::chrono::duration<double, std::milli>(t1 - te0).count());

  for (int y = 0; y < H; ++y) {
    const uint8_t* cd = out.code.ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) {
      if (cd[x] >= kCodeAcceptedBase) ++out.stats.accepted_per_window[cd[x] - kCodeAcceptedBase];
    }
  }

  const PostFilterParams& fp = filter_params_;
  if (fp.remove_outliers) removeIsolatedOutliers(out.disparity, out.code, fp);
  if (fp.fill_holes) {
    cv::Mat before = out.code.clone();
    fillSmallHoles(out.disparity, out.code, fp);
    // A filled pixel gets the lowest confidence of the measured neighbours it was filled from.
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        if (out.code.at<uint8_t>(y, x) != kCodeFilled || before.at<uint8_t>(y, x) == kCodeFilled) {
          continue;
        }
        float cmin = 1.f;
        for (int yy = std::max(0, y - 1); yy <= std::min(H - 1, y + 1); ++yy) {
          for (int xx = std::max(0, x - 1); xx <= std::min(W - 1, x + 1); ++xx) {
            if (before.at<uint8_t>(yy, xx) >= kCodeAcceptedBase) {
              cmin = std::min(cmin, out.confidence.at<float>(yy, xx));
            }
          }
        }
        out.confidence.at<float>(y, x) = cmin;
      }
    }
  }
  for (int y = 0; y < H; ++y) {
    const uint8_t* cd = out.code.ptr<uint8_t>(y);
    float* cf = out.confidence.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      if (cd[x] < kNumRejectCodes) {
        ++out.stats.rejected[cd[x]];
        if (cd[x] != kCodeFilled) cf[x] = 0.f;
      }
      if (cd[x] >= kCodeAcceptedBase || cd[x] == kCodeFilled) ++out.stats.valid_pixels;
    }
  }
  const auto t2 = std::chrono::steady_clock::now();
  out.stats.match_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  out.stats.filter_ms = std::chrono::duration<double, std::milli>(t2 - t1).count();
}

}  // namespace endo_stereo
