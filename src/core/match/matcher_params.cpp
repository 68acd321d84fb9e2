// Validation of the matcher's parameters (MatcherParams); PostFilterParams::validate lives with
// the post-filters in post_filter.cpp.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <sstream>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {

std::string MatcherParams::validate() const {
  std::ostringstream msg;
  // 64-bit arithmetic: any int (INT_MIN included) is judged without overflow.
  const int64_t dmin = min_disparity, dmax = max_disparity;
  if (dmin < -16383 || dmin > 16383 || dmax < -16383 || dmax > 16383) {
    msg << "matcher.min_disparity/max_disparity = " << min_disparity << "/" << max_disparity
        << " must lie in [-16383, 16383] and span at most 4096 values";
  } else if (max_disparity < min_disparity) {
    msg << "matcher.max_disparity = " << max_disparity
        << " must be >= matcher.min_disparity = " << min_disparity;
  } else if (dmax - dmin > 4095) {
    msg << "matcher.min_disparity/max_disparity = " << min_disparity << "/" << max_disparity
        << " must lie in [-16383, 16383] and span at most 4096 values";
  } else if (window_min_px < 3 || window_min_px % 2 == 0) {
    msg << "matcher.window_min_px = " << window_min_px << " must be odd and >= 3";
  } else if (window_step_px < 2 || window_step_px % 2 != 0) {
    msg << "matcher.window_step_px = " << window_step_px << " must be even and >= 2";
  } else if (window_max_px < window_min_px || window_max_px > 32) {
    // Up to 32 x 32 the window sums are exact in float (see the top of matcher.cpp).
    msg << "matcher.window_max_px = " << window_max_px
        << " must be in [window_min_px = " << window_min_px << ", 32]";
  } else if ((window_max_px - window_min_px) / window_step_px + 1 > 16) {
    msg << "matcher.window_max_px = " << window_max_px << " allows more than 16 window sizes";
  } else if (!(gamma_min >= 0.0) || !std::isfinite(gamma_min)) {
    msg << "matcher.gamma_min = " << gamma_min << " must be finite and >= 0";
  } else if (!(delta_min >= 0.0 && delta_min <= 2.0)) {
    msg << "matcher.delta_min = " << delta_min << " must be in [0, 2]";
  } else if (!(min_ncc >= -1.0 && min_ncc <= 1.0)) {
    msg << "matcher.min_ncc = " << min_ncc << " must be in [-1, 1] (-1 = off)";
  } else if (!(min_ncc_narrowed >= -1.0 && min_ncc_narrowed <= 1.0)) {
    msg << "matcher.min_ncc_narrowed = " << min_ncc_narrowed << " must be in [-1, 1] (-1 = off)";
  } else if (!(epsilon_px > 0.0) || !std::isfinite(epsilon_px)) {
    msg << "matcher.epsilon_px = " << epsilon_px << " must be finite and > 0";
  } else if (num_threads < 0 || num_threads > kMaxNumThreads) {
    // Bounded above: oneTBB (behind cv::setNumThreads) crashes when the count goes back down
    // from more than 65536 (found by fuzzing), and a huge arena costs memory for nothing.
    msg << "matcher.num_threads = " << num_threads << " must be in [0, " << kMaxNumThreads
        << "] (0 = OpenCV's default)";
  } else if (!(edge_disparity_jump_px >= 0.0) || !std::isfinite(edge_disparity_jump_px)) {
    msg << "matcher.edge_disparity_jump_px = " << edge_disparity_jump_px
        << " must be finite and >= 0 (0 = off)";
  } else if (!(edge_disparity_jump_above_px >= 0.0) ||
             !std::isfinite(edge_disparity_jump_above_px)) {
    msg << "matcher.edge_disparity_jump_above_px = " << edge_disparity_jump_above_px
        << " must be finite and >= 0 (0 = same as edge_disparity_jump_px)";
  } else if (edge_margin_px < 0 || edge_margin_px > 16) {
    msg << "matcher.edge_margin_px = " << edge_margin_px << " must be in [0, 16]";
  } else if (edge_verify_radius_px < 0 || edge_verify_radius_px > 6) {
    msg << "matcher.edge_verify_radius_px = " << edge_verify_radius_px
        << " must be in [0, 6] (0 = off)";
  } else if (!(edge_verify_min_ncc >= -1.0 && edge_verify_min_ncc <= 1.0)) {
    msg << "matcher.edge_verify_min_ncc = " << edge_verify_min_ncc << " must be in [-1, 1]";
  } else if (!(edge_support_share >= 0.0 && edge_support_share <= 1.0)) {
    msg << "matcher.edge_support_share = " << edge_support_share << " must be in [0, 1] (0 = off)";
  } else if (edge_support_radius_px < 1 || edge_support_radius_px > 8) {
    msg << "matcher.edge_support_radius_px = " << edge_support_radius_px << " must be in [1, 8]";
  }
  return msg.str();
}

}  // namespace endo_stereo
