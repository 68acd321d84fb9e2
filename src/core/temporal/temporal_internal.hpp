// Private to the core: the helpers the temporal stage's files share (not installed, not part of
// the API). The stage (docs/method.md section 4, temporal.hpp) is split by class:
//   temporal_params.cpp    TemporalParams::validate, TemporalResetDetector;
//   temporal_prior.cpp     TemporalPrior (search-range priors);
//   temporal_fusion.cpp    TemporalFusion;
//   coverage_tracker.cpp   CoverageTracker;
//   temporal_tracker.cpp   TemporalTracker (the four behind beginFrame() / endFrame()).
// Their per-pixel loops run over fixed row stripes (forRowStripes) and test validity with
// finite() / finiteMask8(), written so that the loops vectorise.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/core/utility.hpp>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "endo_stereo/core/temporal.hpp"

namespace endo_stereo {
namespace detail {

inline std::string rangeMessage(const char* field, const std::string& range, double value) {
  std::ostringstream os;
  os << "temporal." << field << " must be in " << range << " (got " << value << ")";
  return os.str();
}

inline void checkDisparity(const cv::Mat& disparity, const char* who) {
  if (disparity.empty() || disparity.type() != CV_32FC1) {
    throw std::invalid_argument(std::string(who) + ": disparity must be a non-empty CV_32FC1");
  }
}

inline uint16_t saturatingIncrement(uint16_t v) { return uint16_t(v + (v != kAgeNone)); }

// isfinite as one ordered compare: false for NaN (unordered) and +-inf. Written this way so the
// row loops vectorise (std::isfinite is a library call at -O2/-O3 without fast-math).
inline bool finite(float v) { return std::fabs(v) <= std::numeric_limits<float>::max(); }

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

// Rows are processed in fixed stripes (a multiple of the edge zone's block rows) that
// cv::parallel_for_ may run on any number of threads. Per-stripe counters are summed in stripe
// order afterwards, and every pixel's output depends only on its inputs, so results do not depend
// on the thread count.
constexpr int kTemporalStripeRows = 32;

template <size_t N, typename Body>
std::array<int64_t, N> forRowStripes(int rows, const Body& body) {
  const int stripes = (rows + kTemporalStripeRows - 1) / kTemporalStripeRows;
  std::vector<std::array<int64_t, N>> counts(size_t(stripes), std::array<int64_t, N>{});
  cv::parallel_for_(cv::Range(0, stripes), [&](const cv::Range& range) {
    for (int s = range.start; s < range.end; ++s) {
      body(s * kTemporalStripeRows, std::min(rows, (s + 1) * kTemporalStripeRows),
           counts[size_t(s)]);
    }
  });
  std::array<int64_t, N> total{};
  for (const auto& c : counts) {
    for (size_t i = 0; i < N; ++i) total[i] += c[i];
  }
  return total;
}

}  // namespace detail
}  // namespace endo_stereo
