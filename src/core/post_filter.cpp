// Post-processing of the robust matcher (METHOD.md section 3): isolated-outlier removal and the
// filling of holes one or two pixels wide. Both functions decide every pixel from the input map
// alone (never from pixels changed in the same pass), so the result does not depend on the order
// in which pixels are visited.
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {

std::string PostFilterParams::validate() const {
  std::ostringstream msg;
  if (outlier_window_px < 3 || outlier_window_px % 2 == 0 || outlier_window_px > 31) {
    msg << "filter.outlier_window_px = " << outlier_window_px << " must be odd and in [3, 31]";
  } else if (!(outlier_disparity_tol_px > 0.0) || !std::isfinite(outlier_disparity_tol_px)) {
    msg << "filter.outlier_disparity_tol_px = " << outlier_disparity_tol_px
        << " must be finite and > 0";
  } else if (!(outlier_min_share >= 0.0 && outlier_min_share <= 1.0)) {
    msg << "filter.outlier_min_share = " << outlier_min_share << " must be in [0, 1]";
  } else if (fill_max_hole_px < 1 || fill_max_hole_px > 2) {
    msg << "filter.fill_max_hole_px = " << fill_max_hole_px << " must be in [1, 2]";
  }
  return msg.str();
}

namespace {

void checkMaps(const cv::Mat& disparity, const cv::Mat& code, const char* fn) {
  if (disparity.type() != CV_32FC1) {
    throw std::invalid_argument(std::string(fn) + ": disparity must be CV_32FC1");
  }
  if (!code.empty() && (code.type() != CV_8UC1 || code.size() != disparity.size())) {
    throw std::invalid_argument(std::string(fn) +
                                ": code must be empty or CV_8UC1 of the disparity's size");
  }
}

}  // namespace

int64_t removeIsolatedOutliers(cv::Mat& disparity, cv::Mat& code, const PostFilterParams& params) {
  checkMaps(disparity, code, "removeIsolatedOutliers");
  const std::string err = params.validate();
  if (!err.empty()) throw std::invalid_argument("removeIsolatedOutliers: " + err);
  const int rows = disparity.rows, cols = disparity.cols;
  const int half = params.outlier_window_px / 2;
  const float tol = static_cast<float>(params.outlier_disparity_tol_px);
  // N / window^2 < mu, with N counting the agreeing neighbours (the pixel itself excluded) and the
  // denominator fixed at window^2 also at the image border, as METHOD.md writes it.
  const double need =
      params.outlier_min_share * params.outlier_window_px * params.outlier_window_px;
  const cv::Mat src = disparity.clone();
  std::vector<int> agree(cols);
  int64_t removed = 0;
  for (int y = 0; y < rows; ++y) {
    const float* s = src.ptr<float>(y);
    std::fill(agree.begin(), agree.end(), 0);
    // One neighbour offset at a time over the whole row: a vectorisable compare-and-count.
    // NaN (unmatched) never compares below the tolerance, so it never agrees.
    for (int yy = std::max(0, y - half); yy <= std::min(rows - 1, y + half); ++yy) {
      const float* n = src.ptr<float>(yy);
      for (int dx = -half; dx <= half; ++dx) {
        if (yy == y && dx == 0) continue;
        const int x0 = std::max(0, -dx), x1 = std::min(cols, cols - dx);
        int* ag = agree.data();
        for (int x = x0; x < x1; ++x) ag[x] += std::fabs(n[x + dx] - s[x]) < tol ? 1 : 0;
      }
    }
    float* dst = disparity.ptr<float>(y);
    for (int x = 0; x < cols; ++x) {
      if (std::isnan(s[x]) || agree[x] >= need) continue;
      dst[x] = std::numeric_limits<float>::quiet_NaN();
      if (!code.empty()) code.at<uint8_t>(y, x) = kCodeRejectOutlier;
      ++removed;
    }
  }
  return removed;
}

int64_t fillSmallHoles(cv::Mat& disparity, cv::Mat& code, const PostFilterParams& params) {
  checkMaps(disparity, code, "fillSmallHoles");
  const std::string err = params.validate();
  if (!err.empty()) throw std::invalid_argument("fillSmallHoles: " + err);
  const int rows = disparity.rows, cols = disparity.cols;
  const int max_hole = params.fill_max_hole_px;
  const cv::Mat src = disparity.clone();
  auto valid = [&](int y, int x) { return !std::isnan(src.ptr<float>(y)[x]); };
  // A hole pixel is an invalid pixel inside a horizontal or a vertical run of at most max_hole
  // invalid pixels bounded by valid pixels at both ends. Runs touching the image border are not
  // bounded and are left alone, as is anything wider: later frames fill those.
  cv::Mat hole(rows, cols, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < rows; ++y) {
    int x = 0;
    while (x < cols) {
      if (valid(y, x)) {
        ++x;
        continue;
      }
      int end = x;
      while (end < cols && !valid(y, end)) ++end;
      if (x > 0 && end < cols && end - x <= max_hole) {
        for (int i = x; i < end; ++i) hole.at<uint8_t>(y, i) = 1;
      }
      x = end;
    }
  }
  for (int x = 0; x < cols; ++x) {
    int y = 0;
    while (y < rows) {
      if (valid(y, x)) {
        ++y;
        continue;
      }
      int end = y;
      while (end < rows && !valid(end, x)) ++end;
      if (y > 0 && end < rows && end - y <= max_hole) {
        for (int i = y; i < end; ++i) hole.at<uint8_t>(i, x) = 1;
      }
      y = end;
    }
  }
  // The fill value: the median of the valid disparities among the 8 neighbours. With an even count
  // the lower of the two middle values is taken, so the fill is always a disparity that was
  // measured (at a depth edge the hole takes one side's value, never an invented one in between).
  int64_t filled = 0;
  std::vector<float> vals;
  vals.reserve(8);
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      if (!hole.at<uint8_t>(y, x)) continue;
      vals.clear();
      for (int yy = std::max(0, y - 1); yy <= std::min(rows - 1, y + 1); ++yy) {
        for (int xx = std::max(0, x - 1); xx <= std::min(cols - 1, x + 1); ++xx) {
          const float v = src.at<float>(yy, xx);
          if (!std::isnan(v)) vals.push_back(v);
        }
      }
      if (vals.empty()) continue;  // cannot happen for a bounded run; kept for safety
      const size_t mid = (vals.size() - 1) / 2;
      std::nth_element(vals.begin(), vals.begin() + mid, vals.end());
      disparity.at<float>(y, x) = vals[mid];
      if (!code.empty()) code.at<uint8_t>(y, x) = kCodeFilled;
      ++filled;
    }
  }
  return filled;
}

}  // namespace endo_stereo
