// Coverage over time (the paper's Fig. 6; docs/method.md section 4): per pixel the longest run of
// frames without a valid disparity. See temporal.hpp.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "endo_stereo/core/temporal.hpp"
#include "temporal_internal.hpp"

namespace endo_stereo {

using detail::checkDisparity;
using detail::finite;
using detail::forRowStripes;
using detail::rangeMessage;
using detail::saturatingIncrement;
#if CV_SIMD128
using detail::finiteMask8;
#endif

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

}  // namespace endo_stereo
