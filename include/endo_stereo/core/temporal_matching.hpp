/**
 * @file temporal_matching.hpp
 * @brief The matching passes of one video frame with temporal priors (docs/method.md sections 4
 * and 5.3): priors that add to the full search's result and never take from it.
 *
 * Per frame, between TemporalTracker::beginFrame() and endFrame():
 * 1. no usable prior (the first frame, after a reset or a scene change): the full range, so the
 *    frame's output is exactly a full search's;
 * 2. the narrowed pass: every pixel its range (narrowed around a prior, full, or deferred), every
 *    window size in each (a pixel that fails with one window goes on with the next);
 * 3. a scene change (TemporalTracker::rejectPriors()): the frame again over the full range;
 * 4. the post-filter (isolated outliers, small holes) once, on the frame's map, exactly as
 *    RobustMatcher::compute() runs it after its single pass.
 * With priors off the result equals a single RobustMatcher::compute() with the same range.
 *
 * Use (what Pipeline does per frame):
 * @code
 *   const endo_stereo::SearchRange* range = temporal.beginFrame(info, &reason);
 *   matcher.compute(left, right, temporal, range, result, &report);
 *   temporal.endFrame(result.disparity, want_fused, want_coverage);
 * @endcode
 *
 * Not thread-safe: one instance per processing thread. ROS-free: OpenCV only.
 */
#pragma once

#include <cstdint>

#include <opencv2/core.hpp>

#include "endo_stereo/core/matcher.hpp"
#include "endo_stereo/core/temporal.hpp"

namespace endo_stereo {

/// What TemporalMatcher::compute() did for one frame.
struct TemporalMatchReport {
  bool priors_used = false;      ///< the output comes from narrowed ranges (with any fallback)
  bool priors_rejected = false;  ///< a scene change: the frame was matched again
};

/// RobustMatcher's post-filter (outlier removal, hole filling, confidence of filled pixels, the
/// per-code counters and the valid count) on a result matched with the post-filter off.
void applyPostFilter(MatchResult& result, const PostFilterParams& params);

class TemporalMatcher {
 public:
  /// @throws std::invalid_argument when the params fail validate().
  TemporalMatcher(const MatcherParams& matcher_params, const PostFilterParams& filter_params);
  /// @throws std::invalid_argument when invalid (old ones kept).
  void setParams(const MatcherParams& matcher_params, const PostFilterParams& filter_params);

  /**
   * Match one frame as the file comment says.
   * @param temporal the tracker, between beginFrame() (which returned @p range) and endFrame().
   * @param range    beginFrame()'s result (nullptr = full range).
   * @param out      disparity, codes, confidence and stats (match_ms covers all passes).
   * @throws std::invalid_argument as RobustMatcher::compute().
   */
  void compute(const cv::Mat& left, const cv::Mat& right, TemporalTracker& temporal,
               const SearchRange* range, MatchResult& out, TemporalMatchReport* report = nullptr);

 private:
  // Milliseconds summed over a frame's passes.
  struct PassTimes {
    double match_ms = 0.0, prepare_ms = 0.0, edge_ms = 0.0;
  };
  void matchPass(const cv::Mat& left, const cv::Mat& right, const SearchRange* range,
                 MatchResult& out, PassTimes& times);

  MatcherParams matcher_params_;
  PostFilterParams filter_params_;
  RobustMatcher matcher_;  // the passes only match: edge test and post-filter run on the result
  cv::Mat window_idx_;   // the merged map's accepting window indices (depth-edge measure)
  cv::Mat edge_tmp_[5];  // the depth-edge measure's scratch
};

}  // namespace endo_stereo
