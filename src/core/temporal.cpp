// Temporal priors, fusion and coverage (docs/method.md section 4). See temporal.hpp.
#include "endo_stereo/core/temporal.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace endo_stereo {

namespace {

std::string rangeMessage(const char* field, const std::string& range, double value) {
  std::ostringstream os;
  os << "temporal." << field << " must be in " << range << " (got " << value << ")";
  return os.str();
}

// Sentinel of "no prior" in the min/max filtered images: far outside any disparity, but finite so
// that arithmetic on it stays well defined.
constexpr float kNoPriorLo = 1e9f;
constexpr float kNoPriorHi = -1e9f;

// Block size of the coarse min / max grid behind the edge zone, px.
constexpr int kEdgeBlock = 4;

inline uint16_t saturatingIncrement(uint16_t v) { return uint16_t(v + (v != kAgeNone)); }

// isfinite as one ordered compare: false for NaN (unordered) and +-inf. Written this way so the
// row loops below vectorise (std::isfinite is a library call at -O2/-O3 without fast-math).
inline bool finite(float v) { return std::fabs(v) <= std::numeric_limits<float>::max(); }

// floor / ceil of a float to int without a libm call or a branch: truncate, then step once
// towards -inf / +inf when the truncation went the other way. Exact for |x| < 2^31 (floats of
// magnitude >= 2^23 are integers already); the priors and sentinels stay far inside that.
#if CV_SIMD128
// Validity (finite) of in[0..7] as one 16-bit mask per pixel (all ones = finite), and per half as
// 32-bit masks for float selects.
inline cv::v_uint16x8 finiteMask8(const float* in, cv::v_float32x4* in0, cv::v_float32x4* in1,
                                  cv::v_float32x4* m0, cv::v_float32x4* m1) {
  const cv::v_float32x4 big = cv::v_setall_f32(std::numeric_limits<float>::max());
  *in0 = cv::v_load(in);
  *in1 = cv::v_load(in + 4);
  *m0 = cv::v_abs(*in0) <= big;
  *m1 = cv::v_abs(*in1) <= big;
  return cv::v_reinterpret_as_u16(
      cv::v_pack(cv::v_reinterpret_as_s32(*m0), cv::v_reinterpret_as_s32(*m1)));
}

// A 16-bit lane mask widened to two 32-bit float masks (sign extension keeps all ones).
inline void widenMask(const cv::v_uint16x8& m, cv::v_float32x4* m0, cv::v_float32x4* m1) {
  cv::v_int32x4 a, b;
  cv::v_expand(cv::v_reinterpret_as_s16(m), a, b);
  *m0 = cv::v_reinterpret_as_f32(a);
  *m1 = cv::v_reinterpret_as_f32(b);
}

inline int countMask(const cv::v_uint16x8& m) {
  cv::v_uint32x4 a, b;
  cv::v_expand(m & cv::v_setall_u16(1), a, b);
  return int(cv::v_reduce_sum(a + b));
}
#endif

// Rows are processed in fixed stripes (a multiple of kEdgeBlock rows) that cv::parallel_for_ may
// run on any number of threads. Per-stripe counters are summed in stripe order afterwards, and
// every pixel's output depends only on its inputs, so results do not depend on the thread count.
constexpr int kStripeRows = 32;

template <size_t N, typename Body>
std::array<int64_t, N> forRowStripes(int rows, const Body& body) {
  const int stripes = (rows + kStripeRows - 1) / kStripeRows;
  std::vector<std::array<int64_t, N>> counts(size_t(stripes), std::array<int64_t, N>{});
  cv::parallel_for_(cv::Range(0, stripes), [&](const cv::Range& range) {
    for (int s = range.start; s < range.end; ++s) {
      body(s * kStripeRows, std::min(rows, (s + 1) * kStripeRows), counts[size_t(s)]);
    }
  });
  std::array<int64_t, N> total{};
  for (const auto& c : counts) {
    for (size_t i = 0; i < N; ++i) total[i] += c[i];
  }
  return total;
}

inline int floorToInt(float x) {
  const int t = int(x);
  return t - int(float(t) > x);
}
inline int ceilToInt(float x) {
  const int t = int(x);
  return t + int(float(t) < x);
}

void checkDisparity(const cv::Mat& disparity, const char* who) {
  if (disparity.empty() || disparity.type() != CV_32FC1) {
    throw std::invalid_argument(std::string(who) + ": disparity must be a non-empty CV_32FC1");
  }
}

}  // namespace

std::string TemporalParams::validate() const {
  if (prior_radius_px < 1 || prior_radius_px > 64)
    return rangeMessage("prior_radius_px", "[1, 64]", prior_radius_px);
  if (prior_neighbourhood_px < 0 || prior_neighbourhood_px > 16)
    return rangeMessage("prior_neighbourhood_px", "[0, 16]", prior_neighbourhood_px);
  if (prior_edge_zone_px < 0 || prior_edge_zone_px > 64)
    return rangeMessage("prior_edge_zone_px", "[0, 64]", prior_edge_zone_px);
  if (max_prior_age_frames < 1 || max_prior_age_frames > 1000)
    return rangeMessage("max_prior_age_frames", "[1, 1000]", max_prior_age_frames);
  if (max_prior_failures < 1 || max_prior_failures > 1000)
    return rangeMessage("max_prior_failures", "[1, 1000]", max_prior_failures);
  if (full_range_period_frames < 1 || full_range_period_frames > 1000)
    return rangeMessage("full_range_period_frames", "[1, 1000]", full_range_period_frames);
  if (!(min_prior_hit_share >= 0.0 && min_prior_hit_share <= 1.0))
    return rangeMessage("min_prior_hit_share", "[0, 1]", min_prior_hit_share);
  if (!(max_gap_s > 0.0) || !std::isfinite(max_gap_s))
    return rangeMessage("max_gap_s", "(0, inf)", max_gap_s);
  if (fused_max_age_frames < 0 || fused_max_age_frames > 65534)
    return rangeMessage("fused_max_age_frames", "[0, 65534]", fused_max_age_frames);
  if (coverage_within_frames < 1 || coverage_within_frames > 65534)
    return rangeMessage("coverage_within_frames", "[1, 65534]", coverage_within_frames);
  return {};
}

// ------------------------------------------------------------------------------------------------
std::string TemporalResetDetector::check(const TemporalFrameInfo& info) {
  std::ostringstream reason;
  if (has_previous_) {
    const TemporalFrameInfo& p = previous_;
    if (info.size != p.size) {
      reason << "image size changed from " << p.size.width << "x" << p.size.height << " to "
             << info.size.width << "x" << info.size.height;
    } else if (info.min_disparity != p.min_disparity || info.max_disparity != p.max_disparity) {
      reason << "disparity range changed from [" << p.min_disparity << ", " << p.max_disparity
             << "] to [" << info.min_disparity << ", " << info.max_disparity << "]";
    } else if (info.calibration_generation != p.calibration_generation) {
      reason << "calibration changed";
    } else if (std::isfinite(info.stamp_s) && std::isfinite(p.stamp_s)) {
      const double dt = info.stamp_s - p.stamp_s;
      if (dt < 0.0) {
        reason << "time went back by " << -dt << " s";
      } else if (dt > max_gap_s_) {
        reason << "gap of " << dt << " s > max_gap_s " << max_gap_s_;
      }
    }
  }
  previous_ = info;
  has_previous_ = true;
  return reason.str();
}

// ------------------------------------------------------------------------------------------------
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

// ------------------------------------------------------------------------------------------------
TemporalFusion::TemporalFusion(int max_age_frames) { setMaxAge(max_age_frames); }

void TemporalFusion::setMaxAge(int max_age_frames) {
  if (max_age_frames < 0 || max_age_frames > 65534) {
    throw std::invalid_argument(rangeMessage("fused_max_age_frames", "[0, 65534]", max_age_frames));
  }
  max_age_frames_ = max_age_frames;
}

void TemporalFusion::reset() {
  disparity_.release();
  age_.release();
}

void TemporalFusion::update(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalFusion::update");
  if (disparity_.size() != disparity.size()) {
    disparity_.create(disparity.size(), CV_32FC1);
    disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.create(disparity.size(), CV_16UC1);
    age_.setTo(kAgeNone);
  }
  const int max_age = max_age_frames_;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  forRowStripes<1>(disparity.rows, [&](int y_begin, int y_end, std::array<int64_t, 1>&) {
    for (int y = y_begin; y < y_end; ++y) {
      const float* in = disparity.ptr<float>(y);
      float* d = disparity_.ptr<float>(y);
      uint16_t* age = age_.ptr<uint16_t>(y);
      int x = 0;
#if CV_SIMD128
      {
        const cv::v_uint16x8 v_zero = cv::v_setzero_u16(), v_one = cv::v_setall_u16(1);
        const cv::v_uint16x8 v_none = cv::v_setall_u16(kAgeNone);
        const cv::v_uint16x8 v_max_age = cv::v_setall_u16(uint16_t(max_age));
        const cv::v_float32x4 v_nan = cv::v_setall_f32(nan);
        for (; x <= disparity.cols - 8; x += 8) {
          cv::v_float32x4 in0, in1, ok0, ok1, ex0, ex1;
          const cv::v_uint16x8 ok = finiteMask8(in + x, &in0, &in1, &ok0, &ok1);
          const cv::v_uint16x8 a = cv::v_load(age + x);
          const cv::v_uint16x8 held = a != v_none;
          const cv::v_uint16x8 expired = held & (a >= v_max_age);  // a + 1 > max_age
          const cv::v_uint16x8 older = cv::v_select(expired, v_none, a + (held & v_one));
          cv::v_store(age + x, cv::v_select(ok, v_zero, older));
          widenMask(expired, &ex0, &ex1);
          const cv::v_float32x4 kept0 = cv::v_select(ex0, v_nan, cv::v_load(d + x));
          const cv::v_float32x4 kept1 = cv::v_select(ex1, v_nan, cv::v_load(d + x + 4));
          cv::v_store(d + x, cv::v_select(ok0, in0, kept0));
          cv::v_store(d + x + 4, cv::v_select(ok1, in1, kept1));
        }
      }
#endif
      for (; x < disparity.cols; ++x) {
        const bool valid = finite(in[x]);
        const int a = age[x];
        // A held value one frame older; past the maximum age it is forgotten. A pixel with no
        // value (kAgeNone) stays as it is.
        const bool held = a != kAgeNone;
        const bool expired = held & (a + 1 > max_age);
        const uint16_t older = expired ? kAgeNone : uint16_t(a + held);
        const float kept = expired ? nan : d[x];
        d[x] = valid ? in[x] : kept;
        age[x] = valid ? uint16_t(0) : older;
      }
    }
  });
}

// ------------------------------------------------------------------------------------------------
CoverageTracker::CoverageTracker(int within_frames) { setWithinFrames(within_frames); }

void CoverageTracker::setWithinFrames(int within_frames) {
  if (within_frames < 1 || within_frames > 65534) {
    throw std::invalid_argument(
        rangeMessage("coverage_within_frames", "[1, 65534]", within_frames));
  }
  within_frames_ = within_frames;
}

void CoverageTracker::reset() {
  frames_ = 0;
  current_.release();
  longest_.release();
  ever_.release();
}

void CoverageTracker::update(const cv::Mat& disparity) {
  checkDisparity(disparity, "CoverageTracker::update");
  if (current_.size() != disparity.size()) {
    reset();
    current_ = cv::Mat::zeros(disparity.size(), CV_16UC1);
    longest_ = cv::Mat::zeros(disparity.size(), CV_16UC1);
    ever_ = cv::Mat::zeros(disparity.size(), CV_8UC1);
  }
  forRowStripes<1>(disparity.rows, [&](int y_begin, int y_end, std::array<int64_t, 1>&) {
    for (int y = y_begin; y < y_end; ++y) {
      const float* in = disparity.ptr<float>(y);
      uint16_t* cur = current_.ptr<uint16_t>(y);
      uint16_t* lng = longest_.ptr<uint16_t>(y);
      uint8_t* ever = ever_.ptr<uint8_t>(y);
      int x = 0;
#if CV_SIMD128
      {
        const cv::v_uint16x8 v_zero = cv::v_setzero_u16(), v_one = cv::v_setall_u16(1);
        for (; x <= disparity.cols - 8; x += 8) {
          cv::v_float32x4 in0, in1, ok0, ok1;
          const cv::v_uint16x8 ok = finiteMask8(in + x, &in0, &in1, &ok0, &ok1);
          const cv::v_uint16x8 run = cv::v_load(cur + x) + v_one;  // saturating at kAgeNone
          cv::v_store(cur + x, cv::v_select(ok, v_zero, run));
          const cv::v_uint16x8 lng_old = cv::v_load(lng + x);
          cv::v_store(lng + x, cv::v_select(ok, lng_old, cv::v_max(lng_old, run)));
          const cv::v_uint16x8 ev = cv::v_select(ok, v_one, cv::v_load_expand(ever + x));
          cv::v_store_low(ever + x, cv::v_pack(ev, ev));
        }
      }
#endif
      for (; x < disparity.cols; ++x) {
        const bool valid = finite(in[x]);
        const uint16_t run = saturatingIncrement(cur[x]);
        cur[x] = valid ? uint16_t(0) : run;
        lng[x] = valid ? lng[x] : std::max(lng[x], run);
        ever[x] = valid ? uint8_t(1) : ever[x];
      }
    }
  });
  ++frames_;
}

cv::Rect CoverageTracker::centralRegion(cv::Size size) {
  const double s = 1.0 / std::sqrt(2.0);
  const int w = int(std::lround(size.width * s));
  const int h = int(std::lround(size.height * s));
  return cv::Rect((size.width - w) / 2, (size.height - h) / 2, w, h);
}

CoverageStats CoverageTracker::stats() const {
  CoverageStats s;
  s.frames = frames_;
  s.within_frames = within_frames_;
  if (longest_.empty()) return s;
  s.central_region = centralRegion(longest_.size());
  auto share = [&](const cv::Rect& roi, double* within, double* never) {
    int64_t n_within = 0, n_never = 0;
    for (int y = roi.y; y < roi.y + roi.height; ++y) {
      const uint16_t* lng = longest_.ptr<uint16_t>(y);
      const uint8_t* ever = ever_.ptr<uint8_t>(y);
      for (int x = roi.x; x < roi.x + roi.width; ++x) {
        // A pixel never updated was not updated within N frames, however short the sequence.
        n_within += ever[x] != 0 && lng[x] < within_frames_;
        n_never += ever[x] == 0;
      }
    }
    const double n = double(roi.area());
    *within = n > 0 ? double(n_within) / n : 0.0;
    *never = n > 0 ? double(n_never) / n : 0.0;
  };
  share(s.central_region, &s.central_share, &s.central_never);
  share(cv::Rect(cv::Point(0, 0), longest_.size()), &s.overall_share, &s.overall_never);
  return s;
}

cv::Mat CoverageTracker::colorImage() const {
  if (longest_.empty()) return cv::Mat();
  // Longest run mapped linearly onto 0..2N; at N the colour map is half way (green/yellow).
  const double top = 2.0 * within_frames_;
  cv::Mat scaled;
  longest_.convertTo(scaled, CV_8UC1, 255.0 / top);  // saturates above 2N
  cv::Mat color;
  cv::applyColorMap(scaled, color, cv::COLORMAP_TURBO);
  color.setTo(cv::Scalar::all(0), ever_ == 0);
  cv::rectangle(color, centralRegion(longest_.size()), cv::Scalar::all(255), 1);
  return color;
}

// ------------------------------------------------------------------------------------------------
TemporalTracker::TemporalTracker(const TemporalParams& params)
    : params_(params),
      detector_(params.max_gap_s),
      prior_(params),
      fusion_(params.fused_max_age_frames),
      coverage_(params.coverage_within_frames) {}

void TemporalTracker::setParams(const TemporalParams& params) {
  const std::string error = params.validate();
  if (!error.empty()) throw std::invalid_argument(error);
  params_ = params;
  detector_.setMaxGap(params.max_gap_s);
  prior_.setParams(params);
  fusion_.setMaxAge(params.fused_max_age_frames);
  coverage_.setWithinFrames(params.coverage_within_frames);
  if (!params.enabled) prior_.reset();
}

void TemporalTracker::reset() {
  pending_reason_.clear();
  detector_.reset();
  prior_.reset();
  fusion_.reset();
  coverage_.reset();
  range_.lo.release();
  range_.hi.release();
  priors_used_ = false;
  frame_open_ = false;
}

const SearchRange* TemporalTracker::beginFrame(const TemporalFrameInfo& info,
                                               std::string* reset_reason) {
  std::string reason = detector_.check(info);
  if (!reason.empty()) {
    prior_.reset();
    fusion_.reset();
    coverage_.reset();
  } else {
    reason = pending_reason_;
  }
  pending_reason_.clear();
  if (reset_reason) *reset_reason = reason;
  frame_open_ = true;
  priors_used_ = false;
  if (!params_.enabled) {
    range_.lo.release();
    range_.hi.release();
    return nullptr;
  }
  priors_used_ =
      prior_.buildRange(info.size, info.min_disparity, info.max_disparity, range_);
  return priors_used_ ? &range_ : nullptr;
}

bool TemporalTracker::rejectPriors(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalTracker::rejectPriors");
  if (!params_.enabled || !priors_used_ || !frame_open_) return false;
  if (!(params_.min_prior_hit_share > 0.0)) return false;
  // The same test as TemporalPrior::sceneChanged(), from one pass over the image.
  const double reference = prior_.referenceHitShare();
  int64_t judged = 0;
  const double share = prior_.hitShare(disparity, &judged);
  if (!prior_.isSceneChange(std::llround(share * double(judged)), judged,
                            int64_t(disparity.total()))) {
    return false;
  }
  std::ostringstream os;
  os << "scene change: " << std::lround(100.0 * share) << "% of " << judged
     << " narrowed searches found a disparity (< " << params_.min_prior_hit_share << " x "
     << std::lround(100.0 * reference)
     << "% in the previous frame); priors and fused disparities dropped, frame matched again";
  pending_reason_ = os.str();
  prior_.dropAll();
  fusion_.reset();
  priors_used_ = false;
  return true;
}

void TemporalTracker::endFrame(const cv::Mat& disparity, bool fuse, bool track_coverage) {
  checkDisparity(disparity, "TemporalTracker::endFrame");
  if (params_.enabled && frame_open_) {
    prior_.update(disparity);
    const TemporalPriorStats& s = prior_.stats();
    if (s.scene_change && pending_reason_.empty()) {
      std::ostringstream os;
      os << "scene change: " << s.prior_hits << " of " << (s.prior_hits + s.prior_misses)
         << " narrowed searches found a disparity (< " << params_.min_prior_hit_share
         << " x the previous frame's share); priors and fused disparities dropped";
      pending_reason_ = os.str();
      fusion_.reset();
    }
  }
  if (fuse) fusion_.update(disparity);
  if (track_coverage) coverage_.update(disparity);
  frame_open_ = false;
}

}  // namespace endo_stereo
