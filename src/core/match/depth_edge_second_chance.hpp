// Private to the core: the second chance of the depth-edge filter (depth_edge_filter.cpp).
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {
namespace detail {

/// One pixel flagged by the map test, waiting for its second chance.
struct Flagged {
  int x, y;
  int half;  ///< half width of the neighbourhood its test looked at, px
};

/// The second chance (MatcherParams::edge_verify_radius_px) of the @p flagged pixels (reordered
/// in place, tile by tile): keep[i] = 1 when every window of width 2 r + 1 containing flagged[i]
/// gives its own disparity a ZNCC >= edge_verify_min_ncc and a higher ZNCC than every competitor
/// (the rounded disparities, +-1 px, of the neighbours that flagged it: more than @p below under
/// or @p above over its own). Reads the images (CV_8UC1) and @p disparity, the map before the
/// step. @p lo and @p hi (CV_32F / CV_32S, (H + 2 pad) x (W + 2 pad + 8)) receive the map
/// framed in NaN and its competitor slots; @p reject is memory for the window caches, kept by
/// the caller from call to call. Same result for any thread count.
void secondChance(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                  const cv::Mat& disparity, int pad, float below, float above,
                  std::vector<Flagged>& flagged, cv::Mat& lo, cv::Mat& hi, cv::Mat& reject,
                  std::vector<uint8_t>& keep);

}  // namespace detail
}  // namespace endo_stereo
