#include "synthetic_scene.hpp"

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace endo_stereo {

double backgroundDisparity(const SyntheticSceneParams& p, double x, double y) {
  const double cx = 0.5 * (p.width - 1), cy = 0.5 * (p.height - 1);
  const double dx = x - cx, dy = y - cy;
  return p.base_disparity_px + p.slope_x * dx + p.slope_y * dy + p.curvature * (dx * dx + dy * dy);
}

namespace {

// A random texture in left-view coordinates with a margin on both sides, so the right view can
// sample texture that lies outside the left image.
cv::Mat randomTexture(int rows, int cols, double stdev, double blur, cv::RNG& rng) {
  cv::Mat t(rows, cols, CV_32F);
  rng.fill(t, cv::RNG::NORMAL, 0.0, 1.0);
  if (blur > 0.0) cv::GaussianBlur(t, t, cv::Size(0, 0), blur, blur, cv::BORDER_REFLECT);
  cv::Scalar mean, sd;
  cv::meanStdDev(t, mean, sd);
  t = (t - mean[0]) * (stdev / std::max(1e-9, sd[0])) + 128.0;
  return t;
}

// Bicubic sample of row y of t at real column u (Catmull-Rom), clamped at the ends.
float sampleRow(const cv::Mat& t, int y, double u) {
  const float* row = t.ptr<float>(y);
  const int n = t.cols;
  const int i = static_cast<int>(std::floor(u));
  const double f = u - i;
  auto at = [&](int k) { return row[std::min(std::max(k, 0), n - 1)]; };
  const double p0 = at(i - 1), p1 = at(i), p2 = at(i + 1), p3 = at(i + 2);
  const double a = -0.5 * p0 + 1.5 * p1 - 1.5 * p2 + 0.5 * p3;
  const double b = p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3;
  const double c = -0.5 * p0 + 0.5 * p2;
  return static_cast<float>(((a * f + b) * f + c) * f + p1);
}

}  // namespace

SyntheticScene makeSyntheticScene(const SyntheticSceneParams& p) {
  if (p.width < 16 || p.height < 16) {
    throw std::invalid_argument("makeSyntheticScene: width and height must be >= 16");
  }
  if (!(std::fabs(p.slope_x) < 0.5)) {
    throw std::invalid_argument("makeSyntheticScene: |slope_x| must be < 0.5");
  }
  const int W = p.width, H = p.height;
  cv::RNG rng(p.seed);
  // Texture columns cover left x in [-margin, W + margin).
  const int margin = 256;
  cv::Mat bg = randomTexture(H, W + 2 * margin, p.texture_stdev, p.texture_blur_px, rng);
  cv::Mat fg = randomTexture(H, W + 2 * margin, p.texture_stdev, p.texture_blur_px, rng);
  // Surface-attached patches of the background, in left coordinates (shifted by the margin).
  auto inRect = [](const cv::Rect& r, double x, int y) {
    return !r.empty() && y >= r.y && y < r.y + r.height && x >= r.x && x < r.x + r.width;
  };
  for (int y = 0; y < H; ++y) {
    float* row = bg.ptr<float>(y);
    for (int c = 0; c < bg.cols; ++c) {
      const double x = c - margin;
      if (inRect(p.textureless, x, y)) row[c] = static_cast<float>(p.textureless_value);
      if (inRect(p.saturated, x, y)) row[c] = 255.f + 100.f;  // clipped to 255 below
      if (inRect(p.repetitive, x, y)) {
        row[c] =
            static_cast<float>(128.0 + 60.0 * std::sin(2.0 * CV_PI * x / p.repetitive_period_px));
      }
    }
  }
  auto onOccluder = [&](double x, int y) { return inRect(p.occluder, x, y); };

  SyntheticScene s;
  cv::Mat lf(H, W, CV_32F), rf(H, W, CV_32F);
  s.disparity.create(H, W, CV_32F);
  s.occluded.create(H, W, CV_8U);
  s.surface.create(H, W, CV_8U);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const bool occ = onOccluder(x, y);
      const double d = occ ? p.occluder_disparity_px : backgroundDisparity(p, x, y);
      lf.at<float>(y, x) = (occ ? fg : bg).at<float>(y, x + margin);
      s.disparity.at<float>(y, x) = static_cast<float>(d);
      s.surface.at<uint8_t>(y, x) = occ ? 1 : 0;
      // Visible in the right view when its right position is inside the image and no nearer
      // surface covers that position there.
      const double xr = x - d;
      bool hidden = xr < -0.5 || xr > W - 0.5;
      if (!occ && !hidden && !p.occluder.empty()) {
        hidden = onOccluder(xr + p.occluder_disparity_px, y) && p.occluder_disparity_px > d;
      }
      s.occluded.at<uint8_t>(y, x) = hidden ? 255 : 0;
    }
    for (int xr = 0; xr < W; ++xr) {
      // The occluder (constant disparity) is in front wherever it covers.
      const double xo = xr + p.occluder_disparity_px;
      if (onOccluder(xo, y)) {
        rf.at<float>(y, xr) = sampleRow(fg, y, xo + margin);
        continue;
      }
      // Background: solve xl - d(xl, y) = xr by fixed-point iteration (|dd/dx| < 0.5 converges).
      double xl = xr + backgroundDisparity(p, xr, y);
      for (int it = 0; it < 60; ++it) {
        const double nx = xr + backgroundDisparity(p, xl, y);
        if (std::fabs(nx - xl) < 1e-9) {
          xl = nx;
          break;
        }
        xl = nx;
      }
      rf.at<float>(y, xr) = sampleRow(bg, y, xl + margin);
    }
  }
  if (p.noise_stdev > 0.0) {
    cv::Mat n(H, W, CV_32F);
    rng.fill(n, cv::RNG::NORMAL, 0.0, p.noise_stdev);
    lf += n;
    rng.fill(n, cv::RNG::NORMAL, 0.0, p.noise_stdev);
    rf += n;
  }
  lf.convertTo(s.left, CV_8U);  // saturate_cast rounds and clips to 0..255
  rf.convertTo(s.right, CV_8U);
  return s;
}

}  // namespace endo_stereo
