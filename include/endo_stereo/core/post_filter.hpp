/**
 * @file post_filter.hpp
 * @brief Post-processing of the robust matcher (Bernhardt et al. 2012): isolated-outlier removal
 * and the filling of holes one or two pixels wide. RobustMatcher::compute runs both after
 * matching, as PostFilterParams says; they can also be run on their own on any disparity map.
 *
 * ROS-free: depends on OpenCV only.
 */
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>

namespace endo_stereo {

/// Parameters of the post-processing stage (docs/method.md section 3).
struct PostFilterParams {
  /// Remove isolated outliers.
  bool remove_outliers = true;
  /// Neighbourhood width for the outlier test (paper: Delta w = 5), odd, >= 3.
  int outlier_window_px = 5;
  /// Neighbours agree when their disparity differs by less than this (paper: Delta d = 4), px, > 0.
  double outlier_disparity_tol_px = 4.0;
  /// Remove a pixel when agreeing neighbours / window^2 < this (paper: mu = 0.4), [0, 1].
  double outlier_min_share = 0.4;
  /// Fill holes up to fill_max_hole_px wide with the median of surrounding valid disparities.
  bool fill_holes = true;
  /// Widest hole filled, px, in [1, 2] (the paper fills nothing larger).
  int fill_max_hole_px = 2;

  /// @return an empty string when valid, otherwise a message naming the bad field and its range.
  std::string validate() const;
};

/// Isolated-outlier removal (docs/method.md section 3) in place on a CV_32FC1 disparity (NaN
/// invalid); marks removed pixels kCodeRejectOutlier (matcher.hpp) in @p code (CV_8UC1) when not
/// empty.
/// @return the number of pixels removed.
int64_t removeIsolatedOutliers(cv::Mat& disparity, cv::Mat& code, const PostFilterParams& params);

/// Fill holes at most params.fill_max_hole_px wide (horizontally or vertically) with the median of
/// the surrounding valid disparities; marks them kCodeFilled in @p code when not empty.
/// @return the number of pixels filled.
int64_t fillSmallHoles(cv::Mat& disparity, cv::Mat& code, const PostFilterParams& params);

/// The confidence (CV_32FC1) of the pixels fillSmallHoles() filled (kCodeFilled in @p code, not
/// in @p code_before, the codes before filling): the lowest confidence of the measured (accepted)
/// pixels in its 3x3 square, the ones it was filled from. Rows [y_begin, y_end) only: it reads
/// accepted pixels' confidence and writes filled pixels', so row ranges may run in parallel.
void setFilledConfidenceRows(const cv::Mat& code, const cv::Mat& code_before, cv::Mat& confidence,
                             int y_begin, int y_end);

}  // namespace endo_stereo
