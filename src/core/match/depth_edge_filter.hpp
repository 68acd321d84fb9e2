// Private to the core: the depth-edge (anti-fattening) test of the robust matcher.
#pragma once

#include <opencv2/core.hpp>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {

/// Reject (code kCodeRejectEdge, disparity NaN, confidence 0) pixels whose accepting window
/// straddles a depth edge. A pixel accepted with a window of width w is flagged when its window,
/// widened by mp.edge_margin_px, holds accepted disparities more than mp.edge_disparity_jump_px
/// below its own or more than mp.edge_disparity_jump_above_px above it. With
/// mp.edge_verify_radius_px > 0 a flagged pixel gets a second chance and is kept when every
/// window of width 2 r + 1 containing it prefers its disparity (ZNCC on @p left / @p right, the
/// matched 8-bit images, CV_8UC1) to the disparities of the neighbours that flagged it. Judged on
/// the map before the step (order-independent; output independent of the thread count).
/// @p window_idx holds each accepted pixel's window index; @p num_levels the number of window
/// sizes; the remaining Mats are scratch, best kept by the caller from call to call: their
/// memory is reused (@p lo, @p hi: the erosion / dilation of the map, then the padded map and
/// its competitor slots; @p reject: the window cache of the second chance, about 26 MiB per
/// thread with 64 disparities, touched as needed).
void rejectEdgeStraddlers(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                          int num_levels, const cv::Mat& window_idx, MatchResult& out,
                          cv::Mat& lo_src, cv::Mat& hi_src, cv::Mat& lo, cv::Mat& hi,
                          cv::Mat& reject);

}  // namespace endo_stereo
