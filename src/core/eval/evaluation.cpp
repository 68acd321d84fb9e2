#include "endo_stereo/core/evaluation.hpp"

#include <cmath>
#include <fstream>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace endo_stereo {

DisparityScore scoreDisparity(const cv::Mat& disparity, const cv::Mat& gt, const cv::Mat& mask) {
  if (disparity.type() != CV_32FC1) {
    throw std::invalid_argument("scoreDisparity: disparity must be CV_32FC1");
  }
  if (gt.type() != CV_32FC1) throw std::invalid_argument("scoreDisparity: gt must be CV_32FC1");
  if (gt.size() != disparity.size()) {
    throw std::invalid_argument("scoreDisparity: gt and disparity sizes differ");
  }
  if (!mask.empty() && (mask.type() != CV_8UC1 || mask.size() != disparity.size())) {
    throw std::invalid_argument("scoreDisparity: mask must be empty or CV_8UC1 of the same size");
  }
  DisparityScore s;
  double abs_sum = 0.0;
  for (int y = 0; y < gt.rows; ++y) {
    const float* d = disparity.ptr<float>(y);
    const float* g = gt.ptr<float>(y);
    const uint8_t* m = mask.empty() ? nullptr : mask.ptr<uint8_t>(y);
    for (int x = 0; x < gt.cols; ++x) {
      if ((m && !m[x]) || !std::isfinite(g[x])) continue;
      ++s.n_gt;
      if (!std::isfinite(d[x])) continue;
      ++s.n_out;
      const double e = std::fabs(static_cast<double>(d[x]) - g[x]);
      abs_sum += e;
      if (e > 1.0) ++s.n_bad1;
      if (e > 2.0) ++s.n_bad2;
    }
  }
  if (s.n_out > 0) {
    s.bad1 = static_cast<double>(s.n_bad1) / s.n_out;
    s.bad2 = static_cast<double>(s.n_bad2) / s.n_out;
    s.mean_abs_error = abs_sum / s.n_out;
  }
  if (s.n_gt > 0) s.density = static_cast<double>(s.n_out) / s.n_gt;
  return s;
}

namespace {

cv::Mat readGray(const std::string& dir, const std::string& file) {
  const std::string path = dir + "/" + file;
  cv::Mat m = cv::imread(path, cv::IMREAD_GRAYSCALE);
  if (m.empty()) throw std::runtime_error("loadMiddleburyScene: cannot read " + path);
  return m;
}

cv::Mat readMask(const std::string& dir, const std::string& file, const cv::Size& size) {
  cv::Mat m = readGray(dir, file);
  if (m.size() != size) {
    throw std::runtime_error("loadMiddleburyScene: " + dir + "/" + file + " has another size");
  }
  // White (255) is in the mask. disc.png also holds grey (128) for non-occluded pixels away from
  // discontinuities, which must not count as "near a discontinuity".
  cv::Mat out;
  cv::threshold(m, out, 191, 255, cv::THRESH_BINARY);
  return out;
}

}  // namespace

MiddleburyScene loadMiddleburyScene(const std::string& dir) {
  MiddleburyScene s;
  const size_t slash = dir.find_last_not_of('/');
  const std::string trimmed = dir.substr(0, slash == std::string::npos ? 0 : slash + 1);
  s.name = trimmed.substr(
      trimmed.find_last_of('/') == std::string::npos ? 0 : trimmed.find_last_of('/') + 1);
  std::ifstream info(dir + "/info.txt");
  if (!info || !(info >> s.scale >> s.max_disp) || s.scale <= 0 || s.max_disp < 0) {
    throw std::runtime_error("loadMiddleburyScene: cannot read scale and max disparity from " +
                             dir + "/info.txt");
  }
  s.left = readGray(dir, "imL.png");
  s.right = readGray(dir, "imR.png");
  if (s.right.size() != s.left.size()) {
    throw std::runtime_error("loadMiddleburyScene: imL.png and imR.png sizes differ in " + dir);
  }
  const cv::Mat g = readGray(dir, "groundtruth.png");
  if (g.size() != s.left.size()) {
    throw std::runtime_error("loadMiddleburyScene: groundtruth.png has another size in " + dir);
  }
  s.gt.create(g.size(), CV_32FC1);
  for (int y = 0; y < g.rows; ++y) {
    const uint8_t* gp = g.ptr<uint8_t>(y);
    float* o = s.gt.ptr<float>(y);
    for (int x = 0; x < g.cols; ++x) {
      o[x] = gp[x] == 0 ? std::numeric_limits<float>::quiet_NaN()
                        : static_cast<float>(gp[x]) / static_cast<float>(s.scale);
    }
  }
  s.nonocc = readMask(dir, "nonocc.png", s.left.size());
  s.disc = readMask(dir, "disc.png", s.left.size());
  s.all = readMask(dir, "all.png", s.left.size());
  return s;
}

}  // namespace endo_stereo
