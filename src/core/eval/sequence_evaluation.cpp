#include "endo_stereo/core/sequence_evaluation.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace endo_stereo {

cv::Rect centralHalf(cv::Size size) {
  const int w = size.width / 2, h = size.height / 2;
  return cv::Rect((size.width - w) / 2, (size.height - h) / 2, w, h);
}

SequenceMetrics::SequenceMetrics(const SequenceMetricsParams& params) : params_(params) {
  if (params.window_frames < 1) {
    throw std::invalid_argument("SequenceMetrics: window_frames must be >= 1");
  }
  if (!(params.jump_px >= 0.0))
    throw std::invalid_argument("SequenceMetrics: jump_px must be >= 0");
  if (params.flicker_window_px < 3 || params.flicker_window_px % 2 == 0) {
    throw std::invalid_argument("SequenceMetrics: flicker_window_px must be odd and >= 3");
  }
}

void SequenceMetrics::reset() {
  frames_ = 0;
  previous_.release();
  current_gap_.release();
  longest_gap_.release();
  jump_map_.release();
  flicker_map_.release();
  change_.release();
  both_.release();
  change_sum_.release();
  both_sum_.release();
  densities_.clear();
  jump_counts_.clear();
  compared_counts_.clear();
  flicker_counts_.clear();
}

void SequenceMetrics::addFrame(const cv::Mat& disparity) {
  if (disparity.type() != CV_32FC1 || disparity.empty()) {
    throw std::invalid_argument("SequenceMetrics::addFrame: disparity must be non-empty CV_32FC1");
  }
  if (frames_ > 0 && disparity.size() != previous_.size()) {
    throw std::invalid_argument("SequenceMetrics::addFrame: frame size differs from the first");
  }
  if (frames_ == 0) {
    current_gap_ = cv::Mat::zeros(disparity.size(), CV_16UC1);
    longest_gap_ = cv::Mat::zeros(disparity.size(), CV_16UC1);
  }
  jump_map_.create(disparity.size(), CV_8UC1);
  change_.create(disparity.size(), CV_64FC1);
  both_.create(disparity.size(), CV_64FC1);
  const float jump = static_cast<float>(params_.jump_px);
  int64_t valid = 0, jumps = 0, compared = 0;
  for (int y = 0; y < disparity.rows; ++y) {
    const float* d = disparity.ptr<float>(y);
    const float* p = frames_ > 0 ? previous_.ptr<float>(y) : nullptr;
    uint16_t* cur = current_gap_.ptr<uint16_t>(y);
    uint16_t* lng = longest_gap_.ptr<uint16_t>(y);
    uint8_t* jm = jump_map_.ptr<uint8_t>(y);
    double* ch = change_.ptr<double>(y);
    double* bo = both_.ptr<double>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      const bool has = std::isfinite(d[x]);
      valid += has;
      uint8_t j = 0;
      ch[x] = 0.0;
      bo[x] = 0.0;
      if (has && p && std::isfinite(p[x])) {
        ++compared;
        // |a - b| > t, in float as the maps are stored (a 2.0 px change is not a jump).
        const bool jumped = std::fabs(d[x] - p[x]) > jump;
        jumps += jumped;
        j = jumped ? 2 : 1;
        // In double the difference of two floats is exact (unless one is over 2^28 times the
        // other): no rounding before the sums.
        ch[x] = static_cast<double>(d[x]) - static_cast<double>(p[x]);
        bo[x] = 1.0;
      }
      jm[x] = j;
      if (has) {
        cur[x] = 0;
      } else if (cur[x] < std::numeric_limits<uint16_t>::max()) {
        ++cur[x];
        lng[x] = std::max(lng[x], cur[x]);
      }
    }
  }
  densities_.push_back(static_cast<double>(valid) / disparity.total());
  if (frames_ == 0) {
    flicker_map_ = cv::Mat::zeros(disparity.size(), CV_8UC1);  // the first frame compares nothing
  } else {
    const int64_t flicker = flickerMap();
    jump_counts_.push_back(jumps);
    compared_counts_.push_back(compared);
    flicker_counts_.push_back(flicker);
  }
  disparity.copyTo(previous_);
  ++frames_;
}

int64_t SequenceMetrics::flickerMap() {
  // Sums over the square by box filters (O(1) per pixel whatever its size); outside the image
  // counts as no value (constant border 0: neither change nor a pixel). In double: the mask sums
  // are exact integers, and the change sums are exact wherever the changes are multiples of a
  // common power of two within a few dozen bits of range (OpenCV's 1/16 px, the hand-made maps
  // of the tests); then a change shared by the whole square gives a mean equal to it and a
  // residual of exactly 0. Elsewhere the sums round at about 1e-16 of their size.
  const int w = params_.flicker_window_px;
  cv::boxFilter(change_, change_sum_, CV_64F, cv::Size(w, w), cv::Point(-1, -1),
                /*normalize=*/false, cv::BORDER_CONSTANT);
  cv::boxFilter(both_, both_sum_, CV_64F, cv::Size(w, w), cv::Point(-1, -1), /*normalize=*/false,
                cv::BORDER_CONSTANT);
  flicker_map_.create(change_.size(), CV_8UC1);
  int64_t flicker = 0;
  for (int y = 0; y < change_.rows; ++y) {
    const double* ch = change_.ptr<double>(y);
    const double* bo = both_.ptr<double>(y);
    const double* cs = change_sum_.ptr<double>(y);
    const double* bs = both_sum_.ptr<double>(y);
    uint8_t* fm = flicker_map_.ptr<uint8_t>(y);
    for (int x = 0; x < change_.cols; ++x) {
      if (bo[x] == 0.0) {
        fm[x] = 0;
        continue;
      }
      // bs[x] >= 1: the pixel itself is in its square.
      const bool flickered = std::fabs(ch[x] - cs[x] / bs[x]) > params_.jump_px;
      flicker += flickered;
      fm[x] = flickered ? 2 : 1;
    }
  }
  return flicker;
}

cv::Mat SequenceMetrics::longestGap() const { return longest_gap_.clone(); }

SequenceSummary SequenceMetrics::summary() const {
  SequenceSummary s;
  s.frames = frames_;
  if (frames_ == 0) return s;
  std::vector<double> sorted = densities_;
  std::sort(sorted.begin(), sorted.end());
  const size_t n = sorted.size();
  s.density_median = n % 2 ? sorted[n / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]);
  double sum = 0.0;
  for (double v : densities_) sum += v;
  s.density_mean = sum / n;
  for (size_t i = 0; i < jump_counts_.size(); ++i) {
    s.jump_pixels += jump_counts_[i];
    s.compared_pixels += compared_counts_[i];
  }
  for (int64_t f : flicker_counts_) s.flicker_pixels += f;
  s.jump_share = s.compared_pixels > 0 ? double(s.jump_pixels) / s.compared_pixels : 0.0;
  s.flicker_share = s.compared_pixels > 0 ? double(s.flicker_pixels) / s.compared_pixels : 0.0;
  s.window_frames = std::min(params_.window_frames, frames_);
  s.central = centralHalf(longest_gap_.size());
  int64_t every = 0, never = 0;
  for (int y = s.central.y; y < s.central.y + s.central.height; ++y) {
    const uint16_t* lng = longest_gap_.ptr<uint16_t>(y);
    for (int x = s.central.x; x < s.central.x + s.central.width; ++x) {
      // Every window of W consecutive frames holds a value <=> no run without one reaches W.
      every += lng[x] < s.window_frames;
      never += lng[x] >= frames_;
    }
  }
  const double area = static_cast<double>(s.central.area());
  s.coverage_every_window = area > 0 ? every / area : 0.0;
  s.coverage_never = area > 0 ? never / area : 0.0;
  return s;
}

cv::Mat jumpMapImage(const cv::Mat& jump_map, const cv::Mat& background) {
  CV_Assert(jump_map.type() == CV_8UC1);
  cv::Mat out;
  if (background.empty()) {
    out = cv::Mat(jump_map.size(), CV_8UC3, cv::Scalar::all(0));
  } else if (background.channels() == 1) {
    cv::cvtColor(background, out, cv::COLOR_GRAY2BGR);
  } else {
    out = background.clone();
  }
  CV_Assert(out.size() == jump_map.size() && out.type() == CV_8UC3);
  for (int y = 0; y < out.rows; ++y) {
    const uint8_t* j = jump_map.ptr<uint8_t>(y);
    cv::Vec3b* o = out.ptr<cv::Vec3b>(y);
    for (int x = 0; x < out.cols; ++x) {
      if (j[x] == 2) {
        o[x] = cv::Vec3b(0, 0, 255);
      } else if (j[x] == 1) {
        o[x] = cv::Vec3b(o[x][0] / 3, static_cast<uint8_t>(110 + o[x][1] / 3), o[x][2] / 3);
      } else {
        o[x] = cv::Vec3b(o[x][0] / 4, o[x][1] / 4, o[x][2] / 4);
      }
    }
  }
  return out;
}

cv::Mat coverageMapImage(const cv::Mat& longest_gap, int frames, int window) {
  CV_Assert(longest_gap.type() == CV_16UC1);
  const int w = std::max(1, std::min(window, frames));
  cv::Mat out(longest_gap.size(), CV_8UC3);
  const cv::Rect central = centralHalf(longest_gap.size());
  for (int y = 0; y < out.rows; ++y) {
    const uint16_t* g = longest_gap.ptr<uint16_t>(y);
    cv::Vec3b* o = out.ptr<cv::Vec3b>(y);
    for (int x = 0; x < out.cols; ++x) {
      cv::Vec3b c;
      if (frames > 0 && g[x] >= frames) {
        c = cv::Vec3b(0, 0, 110);  // never a value
      } else if (g[x] < w) {
        c = cv::Vec3b(0, 200, 0);  // a value in every window
      } else {
        // Yellow (gap just reaching the window) to red (gap of the whole sequence).
        const double t = frames > w ? std::min(1.0, double(g[x] - w) / (frames - w)) : 1.0;
        c = cv::Vec3b(0, static_cast<uint8_t>(230 * (1.0 - t)), 255);
      }
      if (!central.contains(cv::Point(x, y))) c = cv::Vec3b(c[0] / 3, c[1] / 3, c[2] / 3);
      o[x] = c;
    }
  }
  cv::rectangle(out, central, cv::Scalar::all(255), 1);
  return out;
}

cv::Ptr<cv::StereoBM> makeReferenceBm(int min_disparity, int num_disparities) {
  cv::Ptr<cv::StereoBM> bm = cv::StereoBM::create(num_disparities, 15);
  bm->setMinDisparity(min_disparity);
  bm->setUniquenessRatio(15);
  return bm;
}

cv::Ptr<cv::StereoSGBM> makeReferenceSgbm(int min_disparity, int num_disparities) {
  return cv::StereoSGBM::create(min_disparity, num_disparities, /*blockSize=*/5, /*P1=*/200,
                                /*P2=*/800, /*disp12MaxDiff=*/0, /*preFilterCap=*/0,
                                /*uniquenessRatio=*/10);
}

int referenceNumDisparities(int min_disparity, int max_disparity) {
  const int n = std::max(1, max_disparity - min_disparity + 1);
  return (n + 15) / 16 * 16;
}

cv::Mat referenceDisparityToFloat(const cv::Mat& fixed_point, int min_disparity) {
  CV_Assert(fixed_point.type() == CV_16SC1);
  cv::Mat out(fixed_point.size(), CV_32FC1);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < fixed_point.rows; ++y) {
    const int16_t* s = fixed_point.ptr<int16_t>(y);
    float* d = out.ptr<float>(y);
    for (int x = 0; x < fixed_point.cols; ++x) {
      d[x] = s[x] < min_disparity * 16 ? nan : s[x] / 16.0f;
    }
  }
  return out;
}

}  // namespace endo_stereo
