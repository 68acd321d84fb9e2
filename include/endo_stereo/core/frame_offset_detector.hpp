/**
 * @file frame_offset_detector.hpp
 * @brief Tells whether the two views of a stereo stream are out of step: the right image paired
 * with left frame t was taken at t-1 or t+1 (two capture cards a frame apart).
 *
 * On a moving scene a left image matches the right image taken at the same instant better than
 * the right images of the frames before and after it: those show the scene moved. The detector
 * keeps the last few pairs, downsampled to about `target_width` pixels across and high-pass
 * filtered (the views' brightness difference drops out), and for the middle left frame t measures
 * how well each of right(t-1), right(t), right(t+1) matches it: the mean, over the image, of the
 * lowest 5x5 SAD over the (downsampled) disparity range. The offset whose cost is lowest by a
 * clear margin (`clear_margin` of the best cost below the runner-up) is one vote; `min_votes`
 * votes of which `agreement` name the same offset give the verdict. Offset k: left(t) matches
 * right(t+k); +1 = the right view is one frame late.
 *
 * A still scene gives no verdict: the three right images differ by sensor noise only, so no
 * offset wins by a margin. So does a scene that only moves sideways as a whole (the shift is a
 * disparity change). A check runs at start, after restart() and recheck() for at most
 * `window_frames` pairs, then again every `period_frames` pairs; a verdict stays until a later
 * check gives another or restart() is called.
 *
 * Cost: during a check, per pair, a resize and a filter of each view, and on every other pair
 * 3 x (disparities / scale) SADs on the ~160-pixel-wide images (about 6 ms of one core at 160x120
 * with 33 disparities, on the development machine); between checks nothing but a counter.
 *
 * Thread safety: not thread-safe; one instance, used by one thread at a time.
 */
#pragma once

#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace endo_stereo {

struct FrameOffsetParams {
  int target_width = 160;     ///< downsampled width, px (scale = max(1, round(width / this)))
  int max_offset = 1;         ///< offsets tried: -max_offset .. +max_offset frames, in [1, 3]
  int window_frames = 50;     ///< pairs a check lasts at most without a verdict (2 s at 25 fps)
  int period_frames = 250;    ///< pairs from the start of one check to the next (10 s at 25 fps)
  int min_votes = 4;          ///< clear evaluations a verdict needs
  double agreement = 0.75;    ///< share of the votes that must name the verdict's offset
  /// An evaluation is clear when the runner-up's cost exceeds the best one's by this share of it.
  /// A still scene's costs differ by well under 5 % (fresh noise on each frame, averaged over
  /// thousands of pixels: test_frame_offset_detector measures it); 0.15 keeps a factor 3 margin.
  double clear_margin = 0.15;
  /// A stamp interval more than this many times the median of the last ones is a gap (a pair
  /// lost): the history restarts, so that frames t-1, t, t+1 are consecutive.
  double gap_factor = 1.8;

  /// "" when valid, else the field and its range.
  std::string validate() const;
};

class FrameOffsetDetector {
 public:
  /// @param min_disparity, max_disparity  the full-resolution search range of the stream, px.
  /// @throws std::invalid_argument on invalid parameters or min > max.
  FrameOffsetDetector(int min_disparity, int max_disparity,
                      const FrameOffsetParams& params = FrameOffsetParams());

  /// One pair, in stream order (8-bit grey, BGR or BGRA, or 16-bit grey; both of one size).
  /// Pairs between checks cost nothing. @return true when this pair completed a check with a
  /// verdict (verdictKnown() then holds; the offset may be 0).
  bool update(const cv::Mat& left, const cv::Mat& right, double stamp_s);

  /// Forget the history and any verdict; a check starts with the next pair (a new stream).
  void restart();
  /// Start a check with the next pair, keeping the verdict until the check gives one (a reset
  /// of the pipeline, a new geometry: the same stream, perhaps re-synchronised).
  void recheck();
  /// A new disparity range (takes effect with the next pair; the history is kept).
  void setDisparityRange(int min_disparity, int max_disparity);

  bool verdictKnown() const { return known_; }
  /// The offset of the last verdict (0 = in step; +1 = left(t) matches right(t+1): the right view
  /// is a frame late). 0 while no verdict is known.
  int offset() const { return known_ ? offset_ : 0; }
  /// A check is running (pairs are being evaluated).
  bool checking() const { return checking_; }
  /// Checks that ended without a verdict since restart() (a still scene).
  int undecidedChecks() const { return undecided_; }
  /// Per offset -max..+max, the last evaluation's mean costs (empty before the first).
  const std::vector<double>& lastCosts() const { return last_costs_; }
  /// One line: the verdict, or why there is none yet.
  std::string describe() const;

  /// Mean over the image of the lowest 5x5 SAD over disparities [dmin, dmax] between two
  /// prepared (downsampled, high-passed, CV_32F) images; a left pixel x is paired with right x-d.
  static double matchCost(const cv::Mat& left, const cv::Mat& right, int dmin, int dmax);

 private:
  cv::Mat prepare(const cv::Mat& image) const;
  void evaluate();

  FrameOffsetParams p_;
  int min_d_, max_d_;
  int dmin_s_ = 0, dmax_s_ = 0;       // the range at the downsampled scale
  std::deque<cv::Mat> left_, right_;  // prepared images, oldest first (at most 2 max_offset + 1)
  std::deque<double> intervals_;
  double last_stamp_ = 0.0;
  bool has_stamp_ = false;
  int64_t frames_ = 0;           // pairs since restart()
  int64_t check_started_ = 0;    // frames_ at the start of the current / last check
  bool checking_ = true;
  int evaluations_ = 0;          // in the current check
  std::vector<int> votes_;       // per offset, in the current check
  bool known_ = false;
  int offset_ = 0;
  int undecided_ = 0;
  std::vector<double> last_costs_;
};

}  // namespace endo_stereo
