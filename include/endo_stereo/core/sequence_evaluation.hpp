/**
 * @file sequence_evaluation.hpp
 * @brief What a user sees on a recording without ground truth: density per frame, temporal
 * stability (disparity jumps between consecutive frames, raw and motion-compensated) and coverage
 * (how often each central pixel gets a value), for any matcher's disparity stream; and OpenCV's
 * StereoBM / StereoSGBM with the fixed settings every comparison in this package uses.
 *
 * Definitions (one disparity map per frame, CV_32FC1, non-finite = no value):
 *  - density of a frame: pixels with a value / all pixels;
 *  - jump share: among pixels with a value in two consecutive frames, the share whose disparity
 *    changed by more than jump_px (default 2 px); pooled over every consecutive pair of frames
 *    (jumps summed / compared pixels summed). On tissue that moves slowly such a jump is almost
 *    always an error in one of the two frames;
 *  - flicker share (motion-compensated jumps): for a pixel with a value in two consecutive
 *    frames, its change d_t - d_{t-1} minus the mean change of the pixels with a value in both
 *    frames within the flicker_window_px square (default 17 x 17) centred on it, the pixel itself
 *    included (the square is cut at the image border); the share of compared pixels where the
 *    absolute value exceeds jump_px, pooled over every consecutive pair as the jump share (same
 *    compared pixels). Motion that moves a neighbourhood together cancels; a pixel that changes
 *    alone does not (a pixel alone in its square cannot flicker);
 *  - central pixels: the middle half of the image in each direction (a rectangle of width/2 by
 *    height/2 in the centre, a quarter of the pixels);
 *  - coverage: the share of central pixels that have a value in every window of window_frames
 *    consecutive frames (their longest run of frames without a value, counting the runs at the
 *    start and at the end of the sequence, is shorter than window_frames; a sequence shorter than
 *    the window counts as one window: the pixel needs a value once); "never" is the share of
 *    central pixels without a value in any frame.
 *
 * Use:
 * @code
 *   endo_stereo::SequenceMetrics metrics;  // 2 px jumps, 17 x 17 flicker square, 10 frames
 *   for (...) metrics.addFrame(disparity);             // in frame order
 *   endo_stereo::SequenceSummary s = metrics.summary();
 *   printf("density %.1f%% jumps %.2f%% flicker %.2f%% covered %.1f%%\n",
 *          100 * s.density_median, 100 * s.jump_share, 100 * s.flicker_share,
 *          100 * s.coverage_every_window);
 * @endcode
 *
 * ROS-free: OpenCV only. SequenceMetrics is not thread-safe (one per stream); the free functions
 * are.
 */
#pragma once

#include <cstdint>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <vector>

namespace endo_stereo {

/// Thresholds of the sequence metrics.
struct SequenceMetricsParams {
  /// A change larger than this between consecutive frames is a jump, and a change that differs by
  /// more than this from its neighbourhood's mean change is a flicker, px.
  double jump_px = 2.0;
  int flicker_window_px = 17;  ///< side of the flicker's neighbourhood square, px (odd, >= 3)
  int window_frames = 10;      ///< coverage window, frames (>= 1)
};

/// The figures of one disparity stream.
struct SequenceSummary {
  int frames = 0;
  double density_median = 0.0;  ///< median over frames of the per-frame density, [0, 1]
  double density_mean = 0.0;    ///< mean over frames of the per-frame density, [0, 1]
  double jump_share = 0.0;      ///< pooled: jump_pixels / compared_pixels, [0, 1] (0 if none)
  int64_t jump_pixels = 0;      ///< over all consecutive pairs
  int64_t compared_pixels = 0;  ///< pixels with a value in both frames, over all pairs
  double flicker_share = 0.0;   ///< pooled: flicker_pixels / compared_pixels, [0, 1] (0 if none)
  int64_t flicker_pixels = 0;   ///< motion-compensated jumps, over all consecutive pairs
  double coverage_every_window = 0.0;  ///< share of central pixels with a value in every window
  double coverage_never = 0.0;         ///< share of central pixels never with a value
  int window_frames = 0;               ///< the window used (min(window_frames, frames))
  cv::Rect central;                    ///< the central region the coverage counts
};

/// The middle half of an image of @p size in each direction.
cv::Rect centralHalf(cv::Size size);

/// Accumulates the figures of one disparity stream, frame by frame.
class SequenceMetrics {
 public:
  /// @throws std::invalid_argument when window_frames < 1, jump_px < 0, or flicker_window_px is
  /// even or < 3.
  explicit SequenceMetrics(const SequenceMetricsParams& params = SequenceMetricsParams());

  /// Forget every frame.
  void reset();

  /// The next frame's disparity: CV_32FC1, non-finite = no value. Every frame has the size of the
  /// first. @throws std::invalid_argument on another type or size.
  void addFrame(const cv::Mat& disparity);

  SequenceSummary summary() const;
  int frames() const { return frames_; }
  /// Per-frame density, in frame order.
  const std::vector<double>& densities() const { return densities_; }
  /// Per consecutive pair (frame k against frame k-1, k >= 1): jumps and compared pixels.
  const std::vector<int64_t>& jumpCounts() const { return jump_counts_; }
  const std::vector<int64_t>& comparedCounts() const { return compared_counts_; }
  /// Per consecutive pair: motion-compensated jumps (flicker); out of comparedCounts().
  const std::vector<int64_t>& flickerCounts() const { return flicker_counts_; }
  /// The latest frame's comparison with the one before: CV_8UC1, 0 = not compared (no value in
  /// one of the two frames, or the first frame), 1 = compared and stable, 2 = jumped.
  const cv::Mat& lastJumpMap() const { return jump_map_; }
  /// As lastJumpMap(), for the motion-compensated change: 2 = flickered.
  const cv::Mat& lastFlickerMap() const { return flicker_map_; }
  /// CV_16UC1: per pixel the longest run of frames without a value so far, the run still open at
  /// the latest frame included (frames() where never a value; saturates at 65535).
  cv::Mat longestGap() const;

 private:
  /// From change_ and both_ (the pair just compared): fills flicker_map_; returns its flickers.
  int64_t flickerMap();

  SequenceMetricsParams params_;
  int frames_ = 0;
  cv::Mat previous_;                   // CV_32FC1, last frame
  cv::Mat current_gap_, longest_gap_;  // CV_16UC1
  cv::Mat jump_map_, flicker_map_;     // CV_8UC1
  cv::Mat change_, both_;              // CV_64FC1: d - previous where both have a value (else 0),
                                       // 1 where both have a value (else 0)
  cv::Mat change_sum_, both_sum_;      // CV_64FC1: their sums over the flicker square
  std::vector<double> densities_;
  std::vector<int64_t> jump_counts_, compared_counts_, flicker_counts_;
};

/// Pictures of the metrics (BGR, the size of the maps).
/// Jumps over @p background (CV_8UC1 or CV_8UC3, may be empty): dimmed where not compared, green
/// where stable, red where the disparity jumped. Draws a flicker map the same way.
cv::Mat jumpMapImage(const cv::Mat& jump_map, const cv::Mat& background);
/// Coverage from SequenceMetrics::longestGap(): green = a value in every window of @p window
/// frames, yellow to red = the longer the longest gap, dark red = never; outside the central
/// region dimmed, the region outlined in white.
cv::Mat coverageMapImage(const cv::Mat& longest_gap, int frames, int window);

/// OpenCV's matchers as every comparison in this package runs them, on 8-bit gray rectified
/// pairs. The range [min_disparity, min_disparity + numDisparities(...) - 1].
/// StereoBM: blockSize 15, uniquenessRatio 15, every other setting OpenCV's default.
cv::Ptr<cv::StereoBM> makeReferenceBm(int min_disparity, int num_disparities);
/// StereoSGBM (MODE_SGBM): blockSize 5, P1 200, P2 800, uniquenessRatio 10, every other setting
/// OpenCV's default.
cv::Ptr<cv::StereoSGBM> makeReferenceSgbm(int min_disparity, int num_disparities);
/// The number of disparities OpenCV needs (a multiple of 16) to cover min..max inclusive.
int referenceNumDisparities(int min_disparity, int max_disparity);
/// OpenCV's CV_16SC1 fixed-point disparity (1/16 px) as CV_32FC1 px, NaN where there is none
/// (OpenCV writes (min_disparity - 1) * 16 there).
cv::Mat referenceDisparityToFloat(const cv::Mat& fixed_point, int min_disparity);

}  // namespace endo_stereo
