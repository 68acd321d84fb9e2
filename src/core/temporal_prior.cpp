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
using detail::kStripeRows;
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
  failures_.release();
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
    reset();
    size_ = size;
    min_disparity_ = min_disparity;
    max_disparity_ = max_disparity;
    last_disparity_.create(size, CV_32FC1);
    last_disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.create(size, CV_16UC1);
    age_.setTo(kAgeNone);
    failures_ = cv::Mat::zeros(size, CV_8UC1);
  }
  narrowed_.create(size, CV_8UC1);  // every pixel written below
  lo_f_.create(size, CV_32FC1);
  hi_f_.create(size, CV_32FC1);

  const int max_failures = params_.max_prior_failures;
  const int max_age = params_.max_prior_age_frames;
  // The edge zone (wide: 33 x 33 by default) is a min / max filter over kEdgeBlock^2 blocks first
  // (below, with the first pass: a stripe holds whole block rows), then over the blocks within
  // ceil(e / kEdgeBlock) blocks. A pixel's zone then covers at least e px around it (up to
  // e + 2 * kEdgeBlock - 1), at a fraction of a full-resolution filter's cost.
  const int e = params_.prior_edge_zone_px;
  const bool edge_zone = e > params_.prior_neighbourhood_px;
  static_assert(kStripeRows % kEdgeBlock == 0, "a stripe must hold whole block rows");
  const cv::Size blocks((size.width + kEdgeBlock - 1) / kEdgeBlock,
                        (size.height + kEdgeBlock - 1) / kEdgeBlock);
  if (edge_zone) {
    lo_e_.create(blocks, CV_32FC1);
    hi_e_.create(blocks, CV_32FC1);
  }
  const std::array<int64_t, 2> pass1 =
      forRowStripes<2>(size.height, [&](int y_begin, int y_end, std::array<int64_t, 2>& c) {
        for (int y = y_begin; y < y_end; ++y) {
          const float* d = last_disparity_.ptr<float>(y);
          const uint16_t* age = age_.ptr<uint16_t>(y);
          const uint8_t* fail = failures_.ptr<uint8_t>(y);
          float* lo = lo_f_.ptr<float>(y);
          float* hi = hi_f_.ptr<float>(y);
          int row_usable = 0, row_fresh = 0;
          for (int x = 0; x < size.width; ++x) {
            const bool fresh = finite(d[x]) & (int(age[x]) < max_age);
            const bool use = fresh & (int(fail[x]) < max_failures);
            lo[x] = use ? d[x] : kNoPriorLo;
            hi[x] = use ? d[x] : kNoPriorHi;
            row_usable += use;
            row_fresh += fresh;
          }
          c[0] += row_usable;
          // A pixel with a fresh prior that was dropped for failing: it falls back.
          c[1] += row_fresh - row_usable;
        }
        if (!edge_zone) return;
        // Block min / max of this stripe's block rows: vertical over the block's rows into one
        // row, then horizontal over the block's columns. (Column buffers per worker thread:
        // kept from frame to frame.)
        thread_local std::vector<float> col_lo, col_hi;
        col_lo.resize(size_t(size.width));
        col_hi.resize(size_t(size.width));
        for (int y0 = y_begin; y0 < y_end; y0 += kEdgeBlock) {
          const int y1 = std::min(y_end, y0 + kEdgeBlock);
          float* clo = col_lo.data();
          float* chi = col_hi.data();
          std::copy_n(lo_f_.ptr<float>(y0), size.width, clo);
          std::copy_n(hi_f_.ptr<float>(y0), size.width, chi);
          for (int y = y0 + 1; y < y1; ++y) {
            const float* lo = lo_f_.ptr<float>(y);
            const float* hi = hi_f_.ptr<float>(y);
            for (int x = 0; x < size.width; ++x) {
              clo[x] = std::min(clo[x], lo[x]);
              chi[x] = std::max(chi[x], hi[x]);
            }
          }
          float* blo = lo_e_.ptr<float>(y0 / kEdgeBlock);
          float* bhi = hi_e_.ptr<float>(y0 / kEdgeBlock);
          for (int bx = 0; bx < blocks.width; ++bx) {
            const int x0 = bx * kEdgeBlock, x1 = std::min(size.width, x0 + kEdgeBlock);
            float mn = clo[x0], mx = chi[x0];
            for (int x = x0 + 1; x < x1; ++x) {
              mn = std::min(mn, clo[x]);
              mx = std::max(mx, chi[x]);
            }
            blo[bx] = mn;
            bhi[bx] = mx;
          }
        }
      });
  const int64_t usable = pass1[0];
  stats_.fallback_pixels = pass1[1];
  if (usable == 0) {
    narrowed_.setTo(0);
    range.lo.release();
    range.hi.release();
    stats_.full_range_pixels = int64_t(size.area());
    return false;
  }

  // Min / max filters spread each prior over a neighbourhood; the default border values of
  // erode / dilate (+inf / -inf) leave image borders neutral.
  if (edge_zone) {
    const int eb = (e + kEdgeBlock - 1) / kEdgeBlock;
    const cv::Mat kernel =
        cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * eb + 1, 2 * eb + 1));
    cv::erode(lo_e_, lo_e_, kernel);
    cv::dilate(hi_e_, hi_e_, kernel);
  }
  const int k = params_.prior_neighbourhood_px;
  if (k > 0) {
    const cv::Mat kernel =
        cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * k + 1, 2 * k + 1));
    cv::erode(lo_f_, lo_f_, kernel);
    cv::dilate(hi_f_, hi_f_, kernel);
  }
  const float edge_jump = 2.0f * float(params_.prior_radius_px);

  range.lo.create(size, CV_16SC1);
  range.hi.create(size, CV_16SC1);
  const float r = float(params_.prior_radius_px);
  const int full_period = params_.full_range_period_frames;
  const int full_phase = int(frame_count_ % full_period);
  // Deferred pixels get lo > hi even after the matcher clamps to [min, max].
  const int16_t none_lo = int16_t(max_disparity + 1), none_hi = int16_t(min_disparity - 1);
  enum { kFull, kEdge, kNarrowed, kWidth, kDeferred, kCounters };
  const std::array<int64_t, kCounters> counts = forRowStripes<kCounters>(
      size.height, [&](int y_begin, int y_end, std::array<int64_t, kCounters>& c) {
        // The block grid expanded to full columns once per block row (the rows below read it as an
        // ordinary row, which keeps the pixel loop free of divisions and gathers).
        std::vector<float> row_lo_e(edge_zone ? size.width : 0),
            row_hi_e(edge_zone ? size.width : 0);
        int expanded_block_row = -1;
        for (int y = y_begin; y < y_end; ++y) {
          int16_t* lo = range.lo.ptr<int16_t>(y);
          int16_t* hi = range.hi.ptr<int16_t>(y);
          uint8_t* narrowed = narrowed_.ptr<uint8_t>(y);
          const float* lo_f = lo_f_.ptr<float>(y);
          const float* hi_f = hi_f_.ptr<float>(y);
          // Without an edge zone jump is +inf: the edge test below is false everywhere.
          const float* lo_e = lo_f;
          const float* hi_e = hi_f;
          float jump = std::numeric_limits<float>::infinity();
          if (edge_zone) {
            if (y / kEdgeBlock != expanded_block_row) {
              expanded_block_row = y / kEdgeBlock;
              const float* blo = lo_e_.ptr<float>(expanded_block_row);
              const float* bhi = hi_e_.ptr<float>(expanded_block_row);
              for (int x = 0; x < size.width; ++x) {
                row_lo_e[x] = blo[x / kEdgeBlock];
                row_hi_e[x] = bhi[x / kEdgeBlock];
              }
            }
            lo_e = row_lo_e.data();
            hi_e = row_hi_e.data();
            jump = edge_jump;
          }
          // In a row whose stripe does not have its turn, full-range pixels are deferred.
          const bool defer_row = (y / kFullRangeStripeRows) % full_period != full_phase;
          int row_edge = 0, row_narrowed = 0, row_deferred = 0;
          int64_t row_width = 0;
          int x = 0;
#if CV_SIMD128
          {
            // Four pixels at a time, the same arithmetic as the scalar loop below (v_floor / v_ceil
            // are exact for these magnitudes); the compiler does not vectorise the mixed-width loop
            // itself.
            const cv::v_float32x4 v_r = cv::v_setall_f32(r);
            const cv::v_float32x4 v_none = cv::v_setall_f32(0.5f * kNoPriorLo);
            const cv::v_float32x4 v_jump = cv::v_setall_f32(jump);
            const cv::v_int32x4 v_min = cv::v_setall_s32(min_disparity);
            const cv::v_int32x4 v_max = cv::v_setall_s32(max_disparity);
            const cv::v_int32x4 v_one = cv::v_setall_s32(1);
            const cv::v_int32x4 v_zero = cv::v_setzero_s32();
            const cv::v_int32x4 v_none_lo = cv::v_setall_s32(none_lo);
            const cv::v_int32x4 v_none_hi = cv::v_setall_s32(none_hi);
            const cv::v_int32x4 v_two = cv::v_setall_s32(2);
            const cv::v_int32x4 v_defer_row = cv::v_setall_s32(defer_row ? -1 : 0);
            cv::v_int32x4 n_edge = v_zero, n_narrowed = v_zero, n_width = v_zero,
                          n_deferred = v_zero;
            for (; x <= size.width - 4; x += 4) {
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
            row_edge += cv::v_reduce_sum(n_edge);
            row_narrowed += cv::v_reduce_sum(n_narrowed);
            row_width += cv::v_reduce_sum(n_width);
            row_deferred += cv::v_reduce_sum(n_deferred);
          }
#endif
          for (; x < size.width; ++x) {
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
          c[kEdge] += row_edge;
          c[kNarrowed] += row_narrowed;
          c[kDeferred] += row_deferred;
          c[kFull] += size.width - row_narrowed - row_deferred;
          c[kWidth] += row_width;
        }
      });
  stats_.full_range_pixels = counts[kFull];
  stats_.deferred_pixels = counts[kDeferred];
  stats_.edge_zone_pixels = counts[kEdge];
  stats_.narrowed_pixels = counts[kNarrowed];
  const int64_t width_sum = counts[kWidth];
  if (stats_.narrowed_pixels > 0) {
    stats_.mean_narrowed_width_px = double(width_sum) / double(stats_.narrowed_pixels);
  }
  return stats_.narrowed_pixels > 0;
}

void TemporalPrior::update(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalPrior::update");
  if (last_disparity_.empty()) {
    // update() without a buildRange(): start the state at this size, full range unknown.
    size_ = disparity.size();
    last_disparity_.create(size_, CV_32FC1);
    last_disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.create(size_, CV_16UC1);
    age_.setTo(kAgeNone);
    failures_ = cv::Mat::zeros(size_, CV_8UC1);
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
          uint8_t* fail = failures_.ptr<uint8_t>(y);
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
              // Saturating adds: kAgeNone + 1 stays kAgeNone, 255 failures + 1 stay 255 (v_pack).
              const cv::v_uint16x8 aged = cv::v_select(keep, cv::v_load(age + x) + v_one, v_none);
              cv::v_store(age + x, cv::v_select(ok, v_zero, aged));
              const cv::v_uint16x8 f = cv::v_load_expand(fail + x);
              const cv::v_uint16x8 failed =
                  cv::v_select(ok, v_zero, cv::v_select(nar, f + v_one, f));
              cv::v_store_low(fail + x, cv::v_pack(failed, failed));
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
            // Invalid after a full-range search: whatever the prior said is not confirmed, so it is dropped (a wrong prior
            // cannot outlive a full-range search). Invalid after a narrowed search only: the prior ages and
            // counts a failure. Not searched (deferred): the prior ages.
            const float kept = keep ? d[x] : nan;
            const uint16_t aged = keep ? saturatingIncrement(age[x]) : kAgeNone;
            const uint8_t failed = was_narrowed ? uint8_t(fail[x] + (fail[x] < 255)) : fail[x];
            d[x] = valid ? in[x] : kept;
            age[x] = valid ? uint16_t(0) : aged;
            fail[x] = valid ? uint8_t(0) : failed;
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
    failures_.setTo(0);
  }
  if (!narrowed_.empty()) narrowed_.setTo(0);
  stats_.scene_change = true;
}

}  // namespace endo_stereo
