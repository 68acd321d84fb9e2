// Temporal fusion (docs/method.md section 4): the most recent valid disparity per pixel, with its
// age. See temporal.hpp.
#include <array>
#include <cstdint>
#include <limits>
#include <stdexcept>

#include "endo_stereo/core/temporal.hpp"
#include "temporal_internal.hpp"

namespace endo_stereo {

using detail::checkDisparity;
using detail::finite;
using detail::forRowStripes;
using detail::rangeMessage;
#if CV_SIMD128
using detail::finiteMask8;
using detail::widenMask;
#endif

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

}  // namespace endo_stereo
