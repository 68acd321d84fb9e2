/**
 * @file point_cloud.hpp
 * @brief Organized XYZRGB cloud and depth image from a disparity map and the rectified geometry,
 * and PLY output.
 *
 * Frame: the left rectified optical frame (ROS convention: x right, y down, z forward), metres.
 * For pixel (u, v) with disparity d (= x_left - x_right, px):
 *   Z = f_px * baseline_m / (d - doffs),  X = (u - cx_left) * Z / f_px,  Y = (v - cy) * Z / fy_px
 * with doffs = cx_left - cx_right applied once (stereo_image_proc applies it twice for verged
 * principal points). Pixels with NaN disparity, d <= doffs, or a polar geometry get NaN xyz.
 * Non-metric geometry (RectifiedGeometry::metric == false) gives a cloud in units of the
 * baseline (baseline_m = 1) with an assumed focal length; OrganizedCloud::metric says so.
 * Reentrant.
 */
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {

/// An organized cloud: one point per pixel of the left rectified image.
struct OrganizedCloud {
  cv::Mat xyz;          ///< CV_32FC3, metres (or baseline units), NaN = invalid
  cv::Mat bgr;          ///< CV_8UC3 colour of each point (from the left rectified image)
  bool metric = false;  ///< xyz in metres; false: units of the baseline, assumed focal length
  /// Number of points with finite xyz.
  int countValid() const;
};

/**
 * Build the organized cloud.
 * @param disparity     CV_32FC1, px, NaN (or any non-finite value) = invalid.
 * @param left_rect_bgr CV_8UC3 of the same size for colour (CV_8UC1 is accepted and replicated),
 *                      or empty (then out.bgr is left empty).
 * @param g             geometry of the rectified pair (f_px > 0 required).
 * @param out           reallocated on size change; out.xyz all NaN when g.polar or f_px <= 0.
 * @throws std::invalid_argument on a type or size mismatch (message names it).
 */
void disparityToCloud(const cv::Mat& disparity, const cv::Mat& left_rect_bgr,
                      const RectifiedGeometry& g, OrganizedCloud& out);

/**
 * The depth image of a disparity map: Z = f_px * baseline_m / (d - doffs) per pixel, computed as
 * disparityToCloud() computes its z (double division, stored as float), so a depth image
 * back-projected through the left rectified camera (fx = f_px, fy = fyOrF(), cx = cx_left,
 * cy) gives the points of the cloud.
 * @param disparity CV_32FC1, px, NaN (or any non-finite value) = invalid.
 * @param g         geometry of the rectified pair.
 * @param depth     CV_32FC1 of the disparity's size (reallocated on size change), metres (units of
 *                  the baseline when not metric); NaN where the disparity is invalid or
 *                  d <= doffs, and everywhere where disparityToCloud() gives no points (g.polar,
 *                  f_px <= 0, baseline_m <= 0).
 * @throws std::invalid_argument when the disparity is not CV_32FC1.
 */
void disparityToDepth(const cv::Mat& disparity, const RectifiedGeometry& g, cv::Mat& depth);

/**
 * Write the valid points (finite xyz) as PLY with x y z (float) and red green blue (uchar) when
 * colour is present. @param binary true: binary_little_endian, false: ascii.
 * @return false with a message on I/O failure or an empty cloud matrix.
 */
bool writePly(const std::string& path, const OrganizedCloud& cloud, bool binary,
              std::string* error);

}  // namespace endo_stereo
