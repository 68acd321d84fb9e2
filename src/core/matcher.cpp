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
constexpr int kStripeRows = 16;  // fixed, so the work split never depends on the thread count

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

/// Scratch of one worker, reused between rows, stripes and frames.
struct Scratch {
  int width = 0;
  int num_d = 0;
  std::vector<float> v;          // vertical window sums, num_d rows of width
  std::vector<int> v_row;        // per d: the image row v holds, or -1
  std::vector<int> v_a, v_b;     // per d: columns [a, b] of v that are valid
  std::vector<float> tmp_a, tmp_b, hsum;
  std::vector<float> elo, ehi;   // effective range of this row (float for branch-free compares)
  std::vector<int> elo_i, ehi_i;
  std::vector<int> first_x, last_x, link;
  std::vector<float> p1, p2, best, best_d, best_l, best_r, second;
  std::vector<float> rb_v, rb_d;
  std::vector<uint8_t> act;

  void ensure(int w, int nd) {
    if (w == width && nd == num_d) return;
    width = w;
    num_d = nd;
    v.assign(static_cast<size_t>(nd) * w, 0.f);
    v_row.assign(nd, -1);
    v_a.assign(nd, 0);
    v_b.assign(nd, -1);
    for (auto* vec : {&tmp_a, &tmp_b, &hsum, &elo, &ehi, &p1, &p2, &best, &best_d, &best_l,
                      &best_r, &second, &rb_v, &rb_d}) {
      vec->assign(w + 64, 0.f);
    }
    elo_i.assign(w, 0);
    ehi_i.assign(w, 0);
    act.assign(w, 0);
    first_x.assign(nd + 1, 0);
    last_x.assign(nd + 1, 0);
    link.assign(nd + 2, 0);
  }
};

/// out[i] = sum_{j < w} in[i + j] for i in [0, n): sums of 2, 4, 8, 16 neighbours built by
/// doubling, so the cost is O(n log w) with vectorisable passes. Exact on the integer-valued data.
void boxSumRow(const float* in, int n, int w, float* out, float* ta, float* tb) {
  // cur holds sums of `span` consecutive inputs, valid for indices [0, len).
  const float* cur = in;
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
        for (int i = 0; i < n; ++i) out[i] = cur[i + offset];
        first = false;
      } else {
        for (int i = 0; i < n; ++i) out[i] += cur[i + offset];
      }
      offset += span;
    }
    rest >>= 1;
    if (!rest) break;
    float* nxt = bufs[which];
    which ^= 1;
    const int nlen = len - span;
    for (int i = 0; i < nlen; ++i) nxt[i] = cur[i] + cur[i + span];
    cur = nxt;
    len = nlen;
    span *= 2;
  }
}

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
  cv::Mat tmp1, tmp2, tmp3;

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

// Find with path halving in the "next unassigned disparity" links.
inline int findNext(std::vector<int>& link, int i) {
  while (link[i] != i) {
    link[i] = link[link[i]];
    i = link[i];
  }
  return i;
}

/// Match the active pixels of row y at one window size; writes only row y of the outputs.
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
  // lie inside the images. Active = not accepted yet, range of at least 3 values (an interior
  // maximum needs two neighbours), left patch with structure.
  bool any_active = false;
  int q_a = W, q_b = -1;
  for (int x = 0; x < W; ++x) {
    int lo = kEmptyLo, hi = kEmptyHi;
    if (x >= r && x < W - r && rlo[x] <= rhi[x]) {
      lo = std::max(rlo[x], x - (W - 1 - r));
      hi = std::min(rhi[x], x - r);
      if (lo > hi) { lo = kEmptyLo; hi = kEmptyHi; }
    }
    s.elo_i[x] = lo;
    s.ehi_i[x] = hi;
    s.elo[x] = static_cast<float>(std::max(lo, -1000000));
    s.ehi[x] = static_cast<float>(std::min(hi, 1000000));
    uint8_t a = 0;
    if (st[x] == 0 && lo <= hi) {
      if (hi - lo < 2) {
        code[x] = kCodeNoPeak;
      } else if (!(gl[x] > gmin)) {
        code[x] = kCodeRejectStructure;
      } else {
        a = 1;
        any_active = true;
        q_a = std::min(q_a, x - hi);
        q_b = std::max(q_b, x - lo);
      }
    }
    s.act[x] = a;
  }
  if (!any_active) return;

  // first_x[k], last_x[k]: the first and last column whose effective range holds d = dmin + k.
  // Assigned with "next unassigned" links so the cost is O(W + nd), not O(W * nd).
  for (int k = 0; k <= nd; ++k) s.link[k] = k;
  for (int k = 0; k < nd; ++k) { s.first_x[k] = W; s.last_x[k] = -1; }
  for (int x = 0; x < W; ++x) {
    if (s.elo_i[x] > s.ehi_i[x]) continue;
    int k = findNext(s.link, s.elo_i[x] - c.dmin);
    while (k <= s.ehi_i[x] - c.dmin) {
      s.first_x[k] = x;
      s.link[k] = k + 1;
      k = findNext(s.link, k + 1);
    }
  }
  for (int k = 0; k <= nd; ++k) s.link[k] = k;
  for (int x = W - 1; x >= 0; --x) {
    if (s.elo_i[x] > s.ehi_i[x]) continue;
    int k = findNext(s.link, s.elo_i[x] - c.dmin);
    while (k <= s.ehi_i[x] - c.dmin) {
      s.last_x[k] = x;
      s.link[k] = k + 1;
      k = findNext(s.link, k + 1);
    }
  }

  float* p1 = s.p1.data();
  float* p2 = s.p2.data();
  float* best = s.best.data();
  float* best_d = s.best_d.data();
  float* best_l = s.best_l.data();
  float* best_r = s.best_r.data();
  float* second = s.second.data();
  float* rb_v = s.rb_v.data();
  float* rb_d = s.rb_d.data();
  const float* elo = s.elo.data();
  const float* ehi = s.ehi.data();
  const uint8_t* act = s.act.data();
  for (int x = 0; x < W; ++x) {
    p1[x] = p2[x] = kNegInf;
    best[x] = second[x] = kNegInf;
    best_d[x] = best_l[x] = best_r[x] = 0.f;
    rb_v[x] = kNegInf;
    rb_d[x] = 0.f;
  }

  const float* mean_l = c.maps->mean_l.ptr<float>(y);
  const float* inv_l = c.maps->inv_l.ptr<float>(y);
  const float* sum_r = c.maps->sum_r.ptr<float>(y);
  const float* inv_r = c.maps->inv_r.ptr<float>(y);
  const int w = c.w;

  for (int k = 0; k < nd; ++k) {
    const int d = c.dmin + k;
    // Columns whose S(x, d) can matter: d in their range, and x - d a right pixel some active pixel
    // may match (its own profile, or a right-to-left profile it needs for the consistency check).
    const int na = std::max(s.first_x[k], q_a + d);
    const int nb = std::min(s.last_x[k], q_b + d);
    if (na > nb) {
      s.v_row[k] = -1;
      continue;
    }
    // Vertical window sums for columns [na - r, nb + r]; reuse the previous row's where valid.
    float* v = s.v.data() + static_cast<size_t>(k) * W;
    const int ca = na - r, cb = nb + r;
    const bool have_prev = s.v_row[k] == y - 1;
    const int pa = have_prev ? std::max(ca, s.v_a[k]) : 1;
    const int pb = have_prev ? std::min(cb, s.v_b[k]) : 0;
    auto fresh = [&](int a, int b) {
      if (a > b) return;
      for (int x = a; x <= b; ++x) v[x] = 0.f;
      for (int yy = y - r; yy <= y + r; ++yy) {
        const float* lr = c.lf->ptr<float>(yy);
        const float* rr = c.rf->ptr<float>(yy) - d;
        for (int x = a; x <= b; ++x) v[x] += lr[x] * rr[x];
      }
    };
    if (pa <= pb) {
      const float* l_in = c.lf->ptr<float>(y + r);
      const float* r_in = c.rf->ptr<float>(y + r) - d;
      const float* l_out = c.lf->ptr<float>(y - r - 1);
      const float* r_out = c.rf->ptr<float>(y - r - 1) - d;
      for (int x = pa; x <= pb; ++x) v[x] += l_in[x] * r_in[x] - l_out[x] * r_out[x];
      fresh(ca, pa - 1);
      fresh(pb + 1, cb);
    } else {
      fresh(ca, cb);
    }
    s.v_row[k] = y;
    s.v_a[k] = ca;
    s.v_b[k] = cb;

    const int n = nb - na + 1;
    float* h = s.hsum.data();
    boxSumRow(v + ca, n, w, h, s.tmp_a.data(), s.tmp_b.data());

    const float df = static_cast<float>(d);
    const float dm1 = static_cast<float>(d - 1);
    const float* sr = sum_r - d;
    const float* ir = inv_r - d;
    float* rbv = rb_v - d;
    float* rbd = rb_d - d;
    for (int i = 0; i < n; ++i) {
      const int x = na + i;
      const bool valid = elo[x] <= df && df <= ehi[x];
      if (!valid) continue;
      const float sv = (h[i] - mean_l[x] * sr[x]) * inv_l[x] * ir[x];
      if (act[x]) {
        const float a1 = p1[x], a2 = p2[x];
        if (df >= elo[x] + 2.f) {
          if (a1 > a2 && a1 >= sv) {  // interior local maximum at d - 1
            if (a1 > best[x]) {
              second[x] = std::max(second[x], best[x]);
              best[x] = a1;
              best_d[x] = dm1;
              best_l[x] = a2;
              best_r[x] = sv;
            } else {
              second[x] = std::max(second[x], a1);
            }
          }
        } else if (df == elo[x] + 1.f && a1 > sv) {
          // The range starts falling: a maximum at its lower end. Never the best (the true peak
          // may lie outside the range), but it counts as a competitor for the peak gap.
          second[x] = std::max(second[x], a1);
        }
        if (df == ehi[x] && sv > a1) second[x] = std::max(second[x], sv);  // rising at the end
        p2[x] = a1;
        p1[x] = sv;
      }
      if (sv > rbv[x]) {
        rbv[x] = sv;
        rbd[x] = df;
      }
    }
  }

  // Decide each active pixel.
  const float* gr = c.maps->gamma_r.ptr<float>(y);
  float* disp = c.out->disparity.ptr<float>(y);
  float* conf = c.out->confidence.ptr<float>(y);
  uint8_t* stw = c.state->ptr<uint8_t>(y);
  uint8_t* widx = c.window_idx->ptr<uint8_t>(y);
  const float delta_min = static_cast<float>(c.mp->delta_min);
  const float eps = static_cast<float>(c.mp->epsilon_px);
  for (int x = 0; x < W; ++x) {
    if (!act[x]) continue;
    if (best[x] == kNegInf) {
      code[x] = kCodeNoPeak;
      continue;
    }
    const int bd = static_cast<int>(best_d[x]);
    const int q = x - bd;
    if (!(gr[q] > gmin)) {
      code[x] = kCodeRejectStructure;
      continue;
    }
    // A single peak has no competitor: its gap is measured to the lowest possible NCC, -1.
    const float comp = second[x] == kNegInf ? -1.f : second[x];
    const float delta = best[x] - comp;
    if (!(delta > delta_min)) {
      code[x] = kCodeRejectPeakGap;
      continue;
    }
    const float d_rl = rb_d[q];
    if (!(std::fabs(static_cast<float>(bd) - d_rl) < eps)) {
      code[x] = kCodeRejectLeftRight;
      continue;
    }
    float sub = 0.f;
    if (c.mp->subpixel) {
      const float den = best_l[x] - 2.f * best[x] + best_r[x];
      if (den < 0.f) sub = std::clamp(0.5f * (best_l[x] - best_r[x]) / den, -0.5f, 0.5f);
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

// Small-window cost of left pixel (x, y) at integer disparity d: mean |L - R| over a (2k+1)^2
// window (k = half), or NCC. Returns +inf when the window leaves the image.
float smallCost(const cv::Mat& lf, const cv::Mat& rf, int x, int y, int d, int k, bool ncc) {
  if (x - k < 0 || x + k >= lf.cols || x - d - k < 0 || x - d + k >= lf.cols || y - k < 0 ||
      y + k >= lf.rows) {
    return std::numeric_limits<float>::infinity();
  }
  double sad = 0, sl = 0, sr = 0, sll = 0, srr = 0, slr = 0;
  for (int yy = y - k; yy <= y + k; ++yy) {
    const float* l = lf.ptr<float>(yy);
    const float* r = rf.ptr<float>(yy) - d;
    for (int xx = x - k; xx <= x + k; ++xx) {
      sad += std::fabs(l[xx] - r[xx]);
      sl += l[xx]; sr += r[xx]; sll += l[xx] * l[xx]; srr += r[xx] * r[xx]; slr += l[xx] * r[xx];
    }
  }
  const double n = (2 * k + 1) * (2 * k + 1);
  if (!ncc) return static_cast<float>(sad / n);
  const double a = n * sll - sl * sl, b = n * srr - sr * sr;
  if (a <= 0 || b <= 0) return 1.f;
  return static_cast<float>(1.0 - (n * slr - sl * sr) / std::sqrt(a * b));
}

// Removes connected regions (4-neighbours whose disparities differ by at most tol) smaller than
// max_area pixels. Returns the number removed.
int64_t removeSpeckles(cv::Mat& disp, cv::Mat& code, int max_area, float tol, uint8_t mark) {
  const int H = disp.rows, W = disp.cols;
  std::vector<int> label(static_cast<size_t>(H) * W, -1);
  std::vector<int> stack, members;
  int64_t removed = 0;
  for (int start = 0; start < H * W; ++start) {
    if (label[start] >= 0 || std::isnan(disp.ptr<float>()[start])) continue;
    members.clear();
    stack.push_back(start);
    label[start] = start;
    while (!stack.empty()) {
      const int i = stack.back();
      stack.pop_back();
      members.push_back(i);
      const int y = i / W, x = i % W;
      const float d = disp.ptr<float>()[i];
      const int nb[4] = {x > 0 ? i - 1 : -1, x < W - 1 ? i + 1 : -1, y > 0 ? i - W : -1,
                         y < H - 1 ? i + W : -1};
      for (int j : nb) {
        if (j < 0 || label[j] >= 0) continue;
        const float e = disp.ptr<float>()[j];
        if (std::isnan(e) || std::fabs(e - d) > tol) continue;
        label[j] = start;
        stack.push_back(j);
      }
    }
    if (static_cast<int>(members.size()) < max_area) {
      for (int i : members) {
        disp.ptr<float>()[i] = std::numeric_limits<float>::quiet_NaN();
        code.ptr<uint8_t>()[i] = mark;
      }
      removed += static_cast<int64_t>(members.size());
    }
  }
  return removed;
}

void rejectEdgeStraddlers(const MatcherParams& mp, const cv::Mat& window_idx, const cv::Mat& lf,
                          const cv::Mat& rf, MatchResult& out) {
  const cv::Mat src = out.disparity.clone();
  const int H = src.rows, W = src.cols;
  const float jump = static_cast<float>(mp.edge_disparity_jump_px);
  static const int kK = getenv("ES_K") ? atoi(getenv("ES_K")) : -1;
  static const float kM = getenv("ES_M") ? atof(getenv("ES_M")) : 0.0f;
  static const bool kNcc = getenv("ES_NCC") != nullptr;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float d = src.at<float>(y, x);
      if (std::isnan(d)) continue;
      const int r = (mp.window_min_px + window_idx.at<uint8_t>(y, x) * mp.window_step_px) / 2;
      float lo = d, hi = d;
      int nlo = 0, nhi = 0, nvalid = 0;
      static const float kC = getenv("ES_C") ? atof(getenv("ES_C")) : 0.f;
      static const float kS = getenv("ES_S") ? atof(getenv("ES_S")) : 0.f;
      for (int yy = std::max(0, y - r); yy <= std::min(H - 1, y + r); ++yy) {
        const float* row = src.ptr<float>(yy);
        for (int xx = std::max(0, x - r); xx <= std::min(W - 1, x + r); ++xx) {
          if (std::isnan(row[xx])) continue;
          ++nvalid;
          const float tol = jump + kS * std::max(std::abs(xx - x), std::abs(yy - y));
          if (row[xx] < d - tol) { ++nlo; lo = std::min(lo, row[xx]); }
          if (row[xx] > d + tol) { ++nhi; hi = std::max(hi, row[xx]); }
        }
      }
      const int need = std::max(1, static_cast<int>(std::ceil(kC * (2 * r + 1) * (2 * r + 1))));
      if (nlo < need) lo = d;
      if (nhi < need) hi = d;
      bool reject = false;
      if (d - lo > 0 || hi - d > 0) {
        reject = true;
        if (kK >= 0) {
          const int di = static_cast<int>(std::lround(d));
          const float own = smallCost(lf, rf, x, y, di, kK, kNcc);
          bool ok = std::isfinite(own);
          if (ok && d - lo > jump) {
            ok = own * (1.f + kM) < smallCost(lf, rf, x, y, static_cast<int>(std::lround(lo)), kK, kNcc);
          }
          if (ok && hi - d > jump) {
            ok = own * (1.f + kM) < smallCost(lf, rf, x, y, static_cast<int>(std::lround(hi)), kK, kNcc);
          }
          reject = !ok;
        }
      }
      if (reject) {
        out.disparity.at<float>(y, x) = std::numeric_limits<float>::quiet_NaN();
        out.confidence.at<float>(y, x) = 0.f;
        out.code.at<uint8_t>(y, x) = kCodeRejectEdge;
      }
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
    computeLevelMaps(im.lf, im.rf, im.lap_l, im.lap_l2, im.lap_r, im.lap_r2, w, im.maps, im.tmp1,
                     im.tmp2);
    LevelContext c{&mp, level, w, w / 2, W, H, mp.min_disparity, mp.max_disparity,
                   &im.lf, &im.rf, &im.range_lo, &im.range_hi, &im.maps, &im.state,
                   &im.window_idx, &out};
    cv::parallel_for_(cv::Range(0, num_stripes), [&](const cv::Range& rg) {
      std::unique_ptr<Scratch> s = im.acquire();
      s->ensure(W, nd);
      for (int stripe = rg.start; stripe < rg.end; ++stripe) {
        std::fill(s->v_row.begin(), s->v_row.end(), -1);
        const int y_end = std::min(H, (stripe + 1) * kStripeRows);
        for (int y = stripe * kStripeRows; y < y_end; ++y) processRow(c, y, *s);
      }
      im.release(std::move(s));
    });
  }
  static const int kSpeckle = getenv("ES_SP") ? atoi(getenv("ES_SP")) : 0;
  static const float kSpeckleTol = getenv("ES_SPT") ? atof(getenv("ES_SPT")) : 1.f;
  if (kSpeckle > 0) removeSpeckles(out.disparity, out.code, kSpeckle, kSpeckleTol, kCodeRejectOutlier);
  static const bool kOutFirst = getenv("ES_ORDER") != nullptr;
  if (kOutFirst && filter_params_.remove_outliers) removeIsolatedOutliers(out.disparity, out.code, filter_params_);
  if (mp.edge_disparity_jump_px > 0.0) rejectEdgeStraddlers(mp, im.window_idx, im.lf, im.rf, out);
  const auto t1 = std::chrono::steady_clock::now();

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
