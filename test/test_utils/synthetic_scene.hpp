/**
 * @file synthetic_scene.hpp
 * @brief Basic synthetic rectified stereo pairs with exact ground truth, for the matcher tests and
 * the speed benchmark.
 *
 * A background surface (plane, slanted plane or paraboloid, disparity given as a function of the
 * left pixel) carries a random texture attached to the surface; optional patches on it are
 * textureless, saturated (a specular-like flat white), or a repetitive stripe pattern; an optional
 * fronto-parallel rectangular occluder with its own texture stands in front. The left view shows
 * the texture in left coordinates; the right view is rendered by solving x_r = x_l - d(x_l, y)
 * for every right pixel and sampling the texture there (bicubic), the nearest surface winning.
 * Ground truth is the disparity of the surface each left pixel sees, and a mask marks the left
 * pixels the right camera cannot see (occluded by the occluder, or outside the right image).
 *
 * Use:
 * @code
 *   endo_stereo::SyntheticSceneParams p;
 *   p.base_disparity_px = 12; p.slope_x = 0.05;
 *   endo_stereo::SyntheticScene s = endo_stereo::makeSyntheticScene(p);
 *   // s.left, s.right (CV_8UC1), s.disparity (CV_32FC1, px), s.occluded (CV_8UC1, 255 = occluded)
 * @endcode
 *
 * Deterministic for a given seed. Thread-safe (no shared state).
 */
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>

namespace endo_stereo {

/// Parameters of a synthetic scene. Disparities in px (x_left - x_right), intensities 0..255.
struct SyntheticSceneParams {
  int width = 320;    ///< image width, px, >= 16
  int height = 240;   ///< image height, px, >= 16
  uint32_t seed = 1;  ///< random texture and noise seed
  /// Background disparity d(x, y) = base + slope_x (x - cx) + slope_y (y - cy)
  ///   + curvature ((x - cx)^2 + (y - cy)^2), centre (cx, cy) = image centre.
  double base_disparity_px = 10.0;
  double slope_x = 0.0;          ///< px of disparity per px along x, |slope_x| < 0.5
  double slope_y = 0.0;          ///< px of disparity per px along y
  double curvature = 0.0;        ///< px of disparity per px^2
  double texture_stdev = 40.0;   ///< contrast of the random texture (before clipping to 0..255)
  double texture_blur_px = 1.0;  ///< Gaussian sigma of the texture, px (0 = white noise)
  double noise_stdev = 0.0;      ///< Gaussian sensor noise added to each view independently
  cv::Rect occluder;             ///< in left pixels; empty = none
  double occluder_disparity_px = 30.0;  ///< constant disparity of the occluder
  cv::Rect textureless;                 ///< region of the background (left pixels) with no texture
  double textureless_value = 120.0;     ///< its intensity
  cv::Rect saturated;                   ///< region of the background saturated at 255
  cv::Rect repetitive;                  ///< region of the background with vertical stripes
  double repetitive_period_px = 8.0;    ///< stripe period, px
};

/// A rendered pair with its ground truth.
struct SyntheticScene {
  cv::Mat left;       ///< CV_8UC1 rectified left view
  cv::Mat right;      ///< CV_8UC1 rectified right view
  cv::Mat disparity;  ///< CV_32FC1 ground-truth disparity of the left view, px
  cv::Mat occluded;   ///< CV_8UC1, 255 = left pixel not visible in the right view, else 0
  cv::Mat surface;    ///< CV_8UC1, 0 = background, 1 = occluder (left view)
};

/// Background disparity of left pixel (x, y) (the formula above).
double backgroundDisparity(const SyntheticSceneParams& p, double x, double y);

/// Render a scene. @throws std::invalid_argument on a size below 16 or |slope_x| >= 0.5.
SyntheticScene makeSyntheticScene(const SyntheticSceneParams& p);

}  // namespace endo_stereo
