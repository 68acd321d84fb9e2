// Temporal search-range priors (docs/method.md section 4): per pixel the disparity range the
// matcher searches, from the previous frames' valid disparities. See temporal.hpp.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "endo_stereo/core/temporal.hpp"
#include "temporal_internal.hpp"

namespace endo_stereo {

using detail::checkDisparity;
using detail::finite;
using detail::forRowStripes;
using detail::kTemporalStripeRows;
using detail::saturatingIncrement;
#if CV_SIMD128
using detail::countMask;
using detail::finiteMask8;
using detail::widenMask;
#endif

namespace {

// Sentinel of "no prior" in the min/max filtered images: far outside any disparity, but finite so
// that arithmetic on it stays well defined.
constexpr float kNoPriorLo = 1e9f;
constexpr float kNoPriorHi = -1e9f;

// Block size of the coarse min / max grid behind the edge zone, px.
constexpr int kEdgeBlock = 4;
static_assert(kTemporalStripeRows % kEdgeBlock == 0, "a stripe must hold whole block rows");

// floor / ceil of a float to int without a libm call or a branch: truncate, then step once
// towards -inf / +inf when the truncation went the other way. Exact for |x| < 2^31 (floats of
// magnitude >= 2^23 are integers already); the priors and sentinels stay far inside that.
inline int floorToInt(float x) {
  const int t = int(x);
  return t - int(float(t) > x);
}
inline int ceilToInt(float x) {
  const int t = int(x);
  return t + int(float(t) < x);
}

// The per-pixel state of a new stream: no prior anywhere.
void startState(cv::Size size, cv::Mat& last_disparity, cv::Mat& age) {
  last_disparity.create(size, CV_32FC1);
  last_disparity.setTo(std::numeric_limits<float>::quiet_NaN());
  age.create(size, CV_16UC1);
  age.setTo(kAgeNone);
}

// What the steps of TemporalPrior::buildRange share: the prior state (read only), the images
// they fill and the frame's settings.
struct RangeBuild {
  const cv::Mat& last_disparity;  // CV_32FC1, NaN = none
  const cv::Mat& age;             // CV_16UC1
  // CV_32FC1: the usable priors (sentinels elsewhere), then spread over the neighbourhood.
  cv::Mat& lo_f;
  cv::Mat& hi_f;
  // CV_32FC1 on the block grid: the blocks' min / max, then spread over the edge zone.
  cv::Mat& lo_e;
  cv::Mat& hi_e;
  cv::Mat& narrowed;  // CV_8UC1: 1 narrowed, 2 deferred, 0 full range
  cv::Size size;
  cv::Size blocks;  // the block grid of the edge zone
  bool edge_zone;   // prior_edge_zone_px > prior_neighbourhood_px
  int max_age;      // max_prior_age_frames
};

cv::Size edgeBlockGrid(cv::Size size) {
  return cv::Size((size.width + kEdgeBlock - 1) / kEdgeBlock,
                  (size.height + kEdgeBlock - 1) / kEdgeBlock);
}

void allocateScratch(const RangeBuild& b) {
  b.narrowed.create(b.size, CV_8UC1);  // every pixel written by the range building
  b.lo_f.create(b.size, CV_32FC1);
  b.hi_f.create(b.size, CV_32FC1);
  if (b.edge_zone) {
    b.lo_e.create(b.blocks, CV_32FC1);
    b.hi_e.create(b.blocks, CV_32FC1);
  }
}

// A stripe's rows: a pixel's prior is usable when it is finite and younger than max_age frames
// (a failed search does not refresh it, so the age alone bounds how long a failing prior is
// tried); lo_f / hi_f get it, the sentinels elsewhere. c[0] counts the usable priors.
void selectUsablePriors(const RangeBuild& b, int y_begin, int y_end, std::array<int64_t, 1>& c) {
  const int width = b.size.width;
  const int max_age = b.max_age;
  for (int y = y_begin; y < y_end; ++y) {
    const float* d = b.last_disparity.ptr<float>(y);
    const uint16_t* age = b.age.ptr<uint16_t>(y);
    float* lo = b.lo_f.ptr<float>(y);
    float* hi = b.hi_f.ptr<float>(y);
    int row_usable = 0;
    for (int x = 0; x < width; ++x) {
      const bool use = finite(d[x]) & (int(age[x]) < max_age);
      lo[x] = use ? d[x] : kNoPriorLo;
      hi[x] = use ? d[x] : kNoPriorHi;
      row_usable += use;
    }
    c[0] += row_usable;
  }
}

// The edge zone (wide: 33 x 33 by default) is a min / max filter over kEdgeBlock^2 blocks first
// (here, in the first pass: a stripe holds whole block rows), then over the blocks within
// ceil(e / kEdgeBlock) blocks (spreadPriors). A pixel's zone then covers at least e px around it
// (up to e + 2 * kEdgeBlock - 1), at a fraction of a full-resolution filter's cost.
//
// Block min / max of a stripe's block rows: vertical over the block's rows into one row, then
// horizontal over the block's columns.
void blockExtremes(const RangeBuild& b, int y_begin, int y_end) {
  const int width = b.size.width;
  // Column buffers per worker thread: kept from frame to frame.
  thread_local std::vector<float> col_lo, col_hi;
  col_lo.resize(size_t(width));
  col_hi.resize(size_t(width));
  for (int y0 = y_begin; y0 < y_end; y0 += kEdgeBlock) {
    const int y1 = std::min(y_end, y0 + kEdgeBlock);
    float* clo = col_lo.data();
    float* chi = col_hi.data();
    std::copy_n(b.lo_f.ptr<float>(y0), width, clo);
    std::copy_n(b.hi_f.ptr<float>(y0), width, chi);
    for (int y = y0 + 1; y < y1; ++y) {
      const float* lo = b.lo_f.ptr<float>(y);
      const float* hi = b.hi_f.ptr<float>(y);
      for (int x = 0; x < width; ++x) {
        clo[x] = std::min(clo[x], lo[x]);
        chi[x] = std::max(chi[x], hi[x]);
      }
    }
    float* blo = b.lo_e.ptr<float>(y0 / kEdgeBlock);
    float* bhi = b.hi_e.ptr<float>(y0 / kEdgeBlock);
    for (int bx = 0; bx < b.blocks.width; ++bx) {
      const int x0 = bx * kEdgeBlock, x1 = std::min(width, x0 + kEdgeBlock);
      float mn = clo[x0], mx = chi[x0];
      for (int x = x0 + 1; x < x1; ++x) {
        mn = std::min(mn, clo[x]);
        mx = std::max(mx, chi[x]);
      }
      blo[bx] = mn;
      bhi[bx] = mx;
    }
  }
}

// First pass over the image: the usable priors and, with an edge zone, their block grid.
// @return the number of usable priors.
int64_t firstPass(const RangeBuild& b) {
  return forRowStripes<1>(b.size.height, [&](int y_begin, int y_end, std::array<int64_t, 1>& c) {
    selectUsablePriors(b, y_begin, y_end, c);
    if (b.edge_zone) blockExtremes(b, y_begin, y_end);
  })[0];
}

// No usable prior anywhere: every pixel searches the full range (range cleared).
void searchFullRangeEverywhere(const RangeBuild& b, SearchRange& range, TemporalPriorStats& stats) {
  b.narrowed.setTo(0);
  range.lo.release();
  range.hi.release();
  stats.full_range_pixels = int64_t(b.size.area());
}

// Min / max filters spread each prior over a neighbourhood; the default border values of
// erode / dilate (+inf / -inf) leave image borders neutral.
void spreadPriors(const RangeBuild& b, const TemporalParams& params) {
  if (b.edge_zone) {
    const int e = params.prior_edge_zone_px;
    const int eb = (e + kEdgeBlock - 1) / kEdgeBlock;
    const cv::Mat kernel =
        cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * eb + 1, 2 * eb + 1));
    cv::erode(b.lo_e, b.lo_e, kernel);
    cv::dilate(b.hi_e, b.hi_e, kernel);
  }
  const int k = params.prior_neighbourhood_px;
  if (k > 0) {
    const cv::Mat kernel =
        cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * k + 1, 2 * k + 1));
    cv::erode(b.lo_f, b.lo_f, kernel);
    cv::dilate(b.hi_f, b.hi_f, kernel);
  }
}

// The frame's rule for a pixel's range.
struct RangeRule {
  float r;          // prior_radius_px
  float edge_jump;  // priors in the edge zone spanning more than this: a depth edge
  int min_disparity, max_disparity;
  // Deferred pixels get lo > hi even after the matcher clamps to [min, max].
  int16_t none_lo, none_hi;
  int full_period, full_phase;  // the row stripes' turn at the full range
};

RangeRule rangeRule(const TemporalParams& params, int64_t frame_count, int min_disparity,
                    int max_disparity) {
  RangeRule rule;
  rule.r = float(params.prior_radius_px);
  rule.edge_jump = 2.0f * float(params.prior_radius_px);
  rule.min_disparity = min_disparity;
  rule.max_disparity = max_disparity;
  rule.none_lo = int16_t(max_disparity + 1);
  rule.none_hi = int16_t(min_disparity - 1);
  rule.full_period = params.full_range_period_frames;
  rule.full_phase = int(frame_count % rule.full_period);
  return rule;
}

// One row of the range building: its inputs and outputs.
struct RangeRow {
  const float* lo_f;  // priors over the pixel's neighbourhood (kNoPriorLo / Hi: none)
  const float* hi_f;
  const float* lo_e;  // priors over its edge zone (lo_f / hi_f without an edge zone)
  const float* hi_e;
  // RangeRule::edge_jump; +inf without an edge zone (the edge test is false everywhere).
  float jump;
  // The row's stripe does not have its turn at the full range: full-range pixels are deferred.
  bool defer_row;
  int width;
  int16_t* lo;  // the range, inclusive
  int16_t* hi;
  uint8_t* narrowed;  // 1 narrowed, 2 deferred, 0 full range
};

struct RowCounts {
  int edge = 0, narrowed = 0, deferred = 0;
  int64_t width = 0;  // sum of hi - lo + 1 over the narrowed pixels
};

#if CV_SIMD128
// Four pixels at a time, the same arithmetic as rangeRowScalar() (v_floor / v_ceil are exact for
// these magnitudes); the compiler does not vectorise the mixed-width loop itself.
// @return the first pixel left to rangeRowScalar().
int rangeRowSimd(const RangeRule& rule, const RangeRow& row, RowCounts& n) {
  const float* lo_f = row.lo_f;
  const float* hi_f = row.hi_f;
  const float* lo_e = row.lo_e;
  const float* hi_e = row.hi_e;
  int16_t* lo = row.lo;
  int16_t* hi = row.hi;
  uint8_t* narrowed = row.narrowed;
  const int width = row.width;
  const cv::v_float32x4 v_r = cv::v_setall_f32(rule.r);
  const cv::v_float32x4 v_none = cv::v_setall_f32(0.5f * kNoPriorLo);
  const cv::v_float32x4 v_jump = cv::v_setall_f32(row.jump);
  const cv::v_int32x4 v_min = cv::v_setall_s32(rule.min_disparity);
  const cv::v_int32x4 v_max = cv::v_setall_s32(rule.max_disparity);
  const cv::v_int32x4 v_one = cv::v_setall_s32(1);
  const cv::v_int32x4 v_zero = cv::v_setzero_s32();
  const cv::v_int32x4 v_none_lo = cv::v_setall_s32(rule.none_lo);
  const cv::v_int32x4 v_none_hi = cv::v_setall_s32(rule.none_hi);
  const cv::v_int32x4 v_two = cv::v_setall_s32(2);
  const cv::v_int32x4 v_defer_row = cv::v_setall_s32(row.defer_row ? -1 : 0);
  cv::v_int32x4 n_edge = v_zero, n_narrowed = v_zero, n_width = v_zero, n_deferred = v_zero;
  int x = 0;
  for (; x <= width - 4; x += 4) {
    const cv::v_float32x4 lf = cv::v_load(lo_f + x), hf = cv::v_load(hi_f + x);
    const cv::v_float32x4 le = cv::v_load(lo_e + x), he = cv::v_load(hi_e + x);
    const cv::v_int32x4 prior = cv::v_reinterpret_as_s32(lf < v_none);
    const cv::v_int32x4 edge = prior & cv::v_reinterpret_as_s32((he - le) > v_jump);
    const cv::v_float32x4 edge_f = cv::v_reinterpret_as_f32(edge);
    const cv::v_float32x4 lo_d = cv::v_select(edge_f, le, lf);
    const cv::v_float32x4 hi_d = cv::v_select(edge_f, he, hf);
    cv::v_int32x4 a = cv::v_max(v_min, cv::v_floor(lo_d - v_r));
    cv::v_int32x4 b = cv::v_min(v_max, cv::v_ceil(hi_d + v_r));
    const cv::v_int32x4 full = ~prior | (a > b);
    const cv::v_int32x4 nar = ~full & ((a > v_min) | (b < v_max));
    const cv::v_int32x4 dfr = full & v_defer_row;
    a = cv::v_select(dfr, v_none_lo, cv::v_select(full, v_min, a));
    b = cv::v_select(dfr, v_none_hi, cv::v_select(full, v_max, b));
    cv::v_store_low(lo + x, cv::v_pack(a, a));
    cv::v_store_low(hi + x, cv::v_pack(b, b));
    const cv::v_int32x4 flag = cv::v_select(dfr, v_two, nar & v_one);
    const cv::v_int16x8 nar16 = cv::v_pack(flag, flag);
    const unsigned nar8 = cv::v_reinterpret_as_u32(cv::v_pack_u(nar16, nar16)).get0();
    std::memcpy(narrowed + x, &nar8, 4);
    n_edge -= edge;
    n_narrowed -= nar;
    n_width += (b - a + v_one) & nar;
    n_deferred -= dfr;
  }
  n.edge += cv::v_reduce_sum(n_edge);
  n.narrowed += cv::v_reduce_sum(n_narrowed);
  n.width += cv::v_reduce_sum(n_width);
  n.deferred += cv::v_reduce_sum(n_deferred);
  return x;
}
#endif

// Pixels x_begin.. of a row, one at a time.
void rangeRowScalar(const RangeRule& rule, const RangeRow& row, int x_begin, RowCounts& n) {
  const float* lo_f = row.lo_f;
  const float* hi_f = row.hi_f;
  const float* lo_e = row.lo_e;
  const float* hi_e = row.hi_e;
  int16_t* lo = row.lo;
  int16_t* hi = row.hi;
  uint8_t* narrowed = row.narrowed;
  const float jump = row.jump;
  const bool defer_row = row.defer_row;
  const float r = rule.r;
  const int min_disparity = rule.min_disparity, max_disparity = rule.max_disparity;
  const int16_t none_lo = rule.none_lo, none_hi = rule.none_hi;
  int row_edge = 0, row_narrowed = 0, row_deferred = 0;
  int64_t row_width = 0;
  for (int x = x_begin; x < row.width; ++x) {
    // A pixel with a prior of its own neighbourhood.
    const bool prior = lo_f[x] < 0.5f * kNoPriorLo;
    // Near a depth edge in the priors, the span of both sides (the edge may have moved).
    const bool edge = prior & (hi_e[x] - lo_e[x] > jump);
    const float lo_d = edge ? lo_e[x] : lo_f[x];
    const float hi_d = edge ? hi_e[x] : hi_f[x];
    int a = std::max(min_disparity, floorToInt(lo_d - r));
    int b = std::min(max_disparity, ceilToInt(hi_d + r));
    // No prior, or a prior (sub-pixel) just outside the full range that leaves nothing:
    // search it all. Sentinels give a > b here by construction (lo 1e9, hi -1e9).
    const bool full = !prior | (a > b);
    const bool nar = ((a > min_disparity) | (b < max_disparity)) && !full;
    const bool dfr = full && defer_row;
    a = dfr ? none_lo : full ? min_disparity : a;
    b = dfr ? none_hi : full ? max_disparity : b;
    lo[x] = int16_t(a);
    hi[x] = int16_t(b);
    narrowed[x] = dfr ? 2 : uint8_t(nar);
    row_edge += edge;
    row_narrowed += nar;
    row_width += nar ? b - a + 1 : 0;
    row_deferred += dfr;
  }
  n.edge += row_edge;
  n.narrowed += row_narrowed;
  n.width += row_width;
  n.deferred += row_deferred;
}

// The edge zone's block row expanded to full columns (the rows below read it as an ordinary row,
// which keeps the pixel loop free of divisions and gathers).
void expandBlockRow(const RangeBuild& b, int block_row, float* row_lo_e, float* row_hi_e) {
  const float* blo = b.lo_e.ptr<float>(block_row);
  const float* bhi = b.hi_e.ptr<float>(block_row);
  for (int x = 0; x < b.size.width; ++x) {
    row_lo_e[x] = blo[x / kEdgeBlock];
    row_hi_e[x] = bhi[x / kEdgeBlock];
  }
}

enum { kFull, kEdge, kNarrowed, kWidth, kDeferred, kCounters };
using RangeCounts = std::array<int64_t, kCounters>;

// A stripe's rows: every pixel's range and narrowed flag, and the stripe's counters.
void buildStripeRanges(const RangeBuild& b, const RangeRule& rule, SearchRange& range, int y_begin,
                       int y_end, RangeCounts& c) {
  // The block grid expanded to full columns once per block row.
  std::vector<float> row_lo_e(b.edge_zone ? b.size.width : 0),
      row_hi_e(b.edge_zone ? b.size.width : 0);
  int expanded_block_row = -1;
  for (int y = y_begin; y < y_end; ++y) {
    RangeRow row;
    row.lo_f = b.lo_f.ptr<float>(y);
    row.hi_f = b.hi_f.ptr<float>(y);
    row.lo_e = row.lo_f;
    row.hi_e = row.hi_f;
    row.jump = std::numeric_limits<float>::infinity();
    if (b.edge_zone) {
      if (y / kEdgeBlock != expanded_block_row) {
        expanded_block_row = y / kEdgeBlock;
        expandBlockRow(b, expanded_block_row, row_lo_e.data(), row_hi_e.data());
      }
      row.lo_e = row_lo_e.data();
      row.hi_e = row_hi_e.data();
      row.jump = rule.edge_jump;
    }
    row.defer_row = (y / kFullRangeStripeRows) % rule.full_period != rule.full_phase;
    row.width = b.size.width;
    row.lo = range.lo.ptr<int16_t>(y);
    row.hi = range.hi.ptr<int16_t>(y);
    row.narrowed = b.narrowed.ptr<uint8_t>(y);
    RowCounts n;
    int x = 0;
#if CV_SIMD128
    x = rangeRowSimd(rule, row, n);
#endif
    rangeRowScalar(rule, row, x, n);
    c[kEdge] += n.edge;
    c[kNarrowed] += n.narrowed;
    c[kDeferred] += n.deferred;
    c[kFull] += b.size.width - n.narrowed - n.deferred;
    c[kWidth] += n.width;
  }
}

// Every pixel's range into range.lo / hi (CV_16SC1) and its flag into narrowed, with the
// frame's counters.
RangeCounts buildRanges(const RangeBuild& b, const RangeRule& rule, SearchRange& range) {
  range.lo.create(b.size, CV_16SC1);
  range.hi.create(b.size, CV_16SC1);
  return forRowStripes<kCounters>(b.size.height, [&](int y_begin, int y_end, RangeCounts& c) {
    buildStripeRanges(b, rule, range, y_begin, y_end, c);
  });
}

void storeRangeCounts(const RangeCounts& counts, TemporalPriorStats& stats) {
  stats.full_range_pixels = counts[kFull];
  stats.deferred_pixels = counts[kDeferred];
  stats.edge_zone_pixels = counts[kEdge];
  stats.narrowed_pixels = counts[kNarrowed];
  if (stats.narrowed_pixels > 0) {
    stats.mean_narrowed_width_px = double(counts[kWidth]) / double(stats.narrowed_pixels);
  }
}

}  // namespace

TemporalPrior::TemporalPrior(const TemporalParams& params) { setParams(params); }

void TemporalPrior::setParams(const TemporalParams& params) {
  const std::string error = params.validate();
  if (!error.empty()) throw std::invalid_argument(error);
  params_ = params;
}

void TemporalPrior::reset() {
  size_ = cv::Size();
  min_disparity_ = 0;
  max_disparity_ = -1;
  last_disparity_.release();
  age_.release();
  narrowed_.release();
  frame_count_ = 0;
  reference_hit_share_ = -1.0;
  stats_ = TemporalPriorStats();
}

bool TemporalPrior::buildRange(cv::Size size, int min_disparity, int max_disparity,
                               SearchRange& range) {
  stats_ = TemporalPriorStats();
  if (size != size_ || min_disparity != min_disparity_ || max_disparity != max_disparity_ ||
      last_disparity_.empty()) {
    // Another image size or full range, or the first frame: start without priors.
    reset();
    size_ = size;
    min_disparity_ = min_disparity;
    max_disparity_ = max_disparity;
    startState(size, last_disparity_, age_);
  }
  const bool edge_zone = params_.prior_edge_zone_px > params_.prior_neighbourhood_px;
  const int max_age = params_.max_prior_age_frames;
  const RangeBuild b{last_disparity_,     age_,      lo_f_,  hi_f_, lo_e_, hi_e_, narrowed_, size,
                     edgeBlockGrid(size), edge_zone, max_age};
  allocateScratch(b);
  if (firstPass(b) == 0) {
    searchFullRangeEverywhere(b, range, stats_);
    return false;
  }
  spreadPriors(b, params_);
  const RangeCounts counts =
      buildRanges(b, rangeRule(params_, frame_count_, min_disparity, max_disparity), range);
  storeRangeCounts(counts, stats_);
  return stats_.narrowed_pixels > 0;
}

void TemporalPrior::update(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalPrior::update");
  if (last_disparity_.empty()) {
    // update() without a buildRange(): start the state at this size, full range unknown.
    size_ = disparity.size();
    startState(size_, last_disparity_, age_);
  }
  if (disparity.size() != size_) {
    throw std::invalid_argument("TemporalPrior::update: disparity size differs from the range's");
  }
  const bool have_narrowed = !narrowed_.empty() && narrowed_.size() == size_;
  if (!have_narrowed) zero_row_.assign(size_.width, 0);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::array<int64_t, 2> judged_counts =
      forRowStripes<2>(size_.height, [&](int y_begin, int y_end, std::array<int64_t, 2>& c) {
        for (int y = y_begin; y < y_end; ++y) {
          const float* in = disparity.ptr<float>(y);
          float* d = last_disparity_.ptr<float>(y);
          uint16_t* age = age_.ptr<uint16_t>(y);
          // The narrowed flags are consumed here and cleared in the same pass.
          uint8_t* narrowed = have_narrowed ? narrowed_.ptr<uint8_t>(y) : zero_row_.data();
          int row_hits = 0, row_misses = 0;
          int x = 0;
#if CV_SIMD128
          {
            const cv::v_uint16x8 v_zero = cv::v_setzero_u16(), v_one = cv::v_setall_u16(1);
            const cv::v_uint16x8 v_two = cv::v_setall_u16(2);
            const cv::v_uint16x8 v_none = cv::v_setall_u16(kAgeNone);
            const cv::v_float32x4 v_nan = cv::v_setall_f32(nan);
            for (; x <= size_.width - 8; x += 8) {
              cv::v_float32x4 in0, in1, ok0, ok1, nar0, nar1;
              const cv::v_uint16x8 ok = finiteMask8(in + x, &in0, &in1, &ok0, &ok1);
              const cv::v_uint16x8 flag = cv::v_load_expand(narrowed + x);
              const cv::v_uint16x8 nar = flag == v_one;
              const cv::v_uint16x8 keep = nar | (flag == v_two);  // narrowed or deferred
              widenMask(keep, &nar0, &nar1);
              const cv::v_float32x4 kept0 = cv::v_select(nar0, cv::v_load(d + x), v_nan);
              const cv::v_float32x4 kept1 = cv::v_select(nar1, cv::v_load(d + x + 4), v_nan);
              cv::v_store(d + x, cv::v_select(ok0, in0, kept0));
              cv::v_store(d + x + 4, cv::v_select(ok1, in1, kept1));
              // Saturating add: kAgeNone + 1 stays kAgeNone.
              const cv::v_uint16x8 aged = cv::v_select(keep, cv::v_load(age + x) + v_one, v_none);
              cv::v_store(age + x, cv::v_select(ok, v_zero, aged));
              cv::v_store_low(narrowed + x, cv::v_setzero_u8());
              row_hits += countMask(ok & nar);
              row_misses += countMask(~ok & nar);
            }
          }
#endif
          for (; x < size_.width; ++x) {
            const bool valid = finite(in[x]);
            const bool was_narrowed = narrowed[x] == 1;
            const bool keep = was_narrowed | (narrowed[x] == 2);
            // Invalid after a full-range search: whatever the prior said is not confirmed, so it is
            // dropped (a wrong prior cannot outlive a full-range search). Invalid after a narrowed
            // search, or not searched (deferred): the prior ages, and once max_prior_age_frames
            // old it is no longer used.
            const float kept = keep ? d[x] : nan;
            const uint16_t aged = keep ? saturatingIncrement(age[x]) : kAgeNone;
            d[x] = valid ? in[x] : kept;
            age[x] = valid ? uint16_t(0) : aged;
            row_hits += valid & was_narrowed;
            row_misses += !valid & was_narrowed;
            narrowed[x] = 0;
          }
          c[0] += row_hits;
          c[1] += row_misses;
        }
      });
  const int64_t hits = judged_counts[0], misses = judged_counts[1];
  stats_.prior_hits = hits;
  stats_.prior_misses = misses;
  ++frame_count_;
  // Most narrowed searches failing means the priors describe another scene: whatever a few of them
  // accepted is suspect too, so all are dropped rather than left to fail pixel by pixel.
  const int64_t judged = hits + misses;
  if (isSceneChange(hits, judged, int64_t(size_.area()))) {
    dropAll();
  } else if (judged > 0 && judged >= int64_t(size_.area()) / 20) {
    reference_hit_share_ = double(hits) / double(judged);
  }
}

bool TemporalPrior::isSceneChange(int64_t hits, int64_t judged, int64_t total) const {
  return params_.min_prior_hit_share > 0.0 && reference_hit_share_ > 0.0 && judged > 0 &&
         judged >= total / 20 &&
         double(hits) < params_.min_prior_hit_share * reference_hit_share_ * double(judged);
}

double TemporalPrior::hitShare(const cv::Mat& disparity, int64_t* judged) const {
  checkDisparity(disparity, "TemporalPrior::hitShare");
  int64_t n = 0, hits = 0;
  if (!narrowed_.empty() && narrowed_.size() == disparity.size()) {
    for (int y = 0; y < disparity.rows; ++y) {
      const float* d = disparity.ptr<float>(y);
      const uint8_t* narrowed = narrowed_.ptr<uint8_t>(y);
      int row_n = 0, row_hits = 0;
      int x = 0;
#if CV_SIMD128
      for (; x <= disparity.cols - 8; x += 8) {
        cv::v_float32x4 in0, in1, ok0, ok1;
        const cv::v_uint16x8 ok = finiteMask8(d + x, &in0, &in1, &ok0, &ok1);
        const cv::v_uint16x8 flag = cv::v_load_expand(narrowed + x);
        const cv::v_uint16x8 nar = flag == cv::v_setall_u16(1);
        row_n += countMask(nar);
        row_hits += countMask(nar & ok);
      }
#endif
      for (; x < disparity.cols; ++x) {
        const bool nar = narrowed[x] == 1;
        row_n += nar;
        row_hits += nar & finite(d[x]);
      }
      n += row_n;
      hits += row_hits;
    }
  }
  if (judged) *judged = n;
  return n ? double(hits) / double(n) : 1.0;
}

bool TemporalPrior::sceneChanged(const cv::Mat& disparity) const {
  if (!(params_.min_prior_hit_share > 0.0) || !(reference_hit_share_ > 0.0)) return false;
  int64_t judged = 0;
  const double share = hitShare(disparity, &judged);
  return isSceneChange(std::llround(share * double(judged)), judged, int64_t(disparity.total()));
}

void TemporalPrior::dropAll() {
  reference_hit_share_ = -1.0;
  if (!last_disparity_.empty()) {
    last_disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.setTo(kAgeNone);
  }
  if (!narrowed_.empty()) narrowed_.setTo(0);
  stats_.scene_change = true;
}

}  // namespace endo_stereo
