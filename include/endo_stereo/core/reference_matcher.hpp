/**
 * @file reference_matcher.hpp
 * @brief The matching step of Bernhardt et al. (2012) written plainly: one pixel at a time, every
 * window sum computed afresh, no streaming, no vectors, no threads (docs/method.md section 2).
 *
 * It is the readable statement of what RobustMatcher computes, and the yardstick the tests hold
 * RobustMatcher to: for the same input and parameters, the codes, disparities and confidences are
 * identical, bit for bit (test_matcher). To make that a fair requirement it uses the same
 * arithmetic: window sums of products are exact integers, and the NCC is normalised in float with
 * the same expressions (see referenceNcc), so a near-tie between two peaks falls the same way in
 * both. It is slow (O(w^2) per pixel and disparity): for tests and for reading, not for video.
 *
 * Not covered: the depth-edge filter (MatcherParams::edge_*) and the post-filters, which run after
 * matching (post_filter.hpp); MatcherParams::num_threads is ignored.
 *
 * ROS-free: depends on OpenCV only.
 */
#pragma once

#include <opencv2/core.hpp>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {

/// S(d) of the left window centred on (x, y) against the right window centred on (x - d, y),
/// both of width 2 r + 1 and inside the images, as RobustMatcher computes it: zero-mean NCC from
/// exact integer window sums, normalised in float. 0 when either window is flat (n sum v^2 -
/// (sum v)^2 <= 0.5).
float referenceNcc(const cv::Mat& left, const cv::Mat& right, int x, int y, int d, int r);

/// Match a rectified pair (CV_8UC1, same size) with the paper's criteria and adaptive window, one
/// pixel at a time. @p range: optional per-pixel search range, as for RobustMatcher::compute.
/// Fills out.disparity (NaN = none), out.code and out.confidence; out.stats only partly (total
/// and prior pixels).
/// @throws std::invalid_argument on invalid params or input, as RobustMatcher does.
void referenceMatch(const cv::Mat& left, const cv::Mat& right, const MatcherParams& params,
                    const SearchRange* range, MatchResult& out);

}  // namespace endo_stereo
