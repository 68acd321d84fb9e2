/**
 * @file freeze_detector.hpp
 * @brief Tells a frozen view from a live one: a capture card that keeps sending the same image
 * under new stamps.
 *
 * A live camera never delivers two bit-identical images: sensor noise changes some pixels from
 * frame to frame even when the scene stands still. A view whose image is byte for byte the one
 * before it, pair after pair, comes from a dead capture (a frozen grabber, a stalled video
 * pipeline re-sending its last frame). Matching a frozen view against a live one gives a surface
 * that is wrong and looks confident, so the caller withholds the output while a view is frozen.
 *
 * Use: one detector per view, update() once per stereo pair with that view's image.
 * @code
 *   endo_stereo::FreezeDetector right(10);
 *   if (right.update(image)) { ... frozen: do not match this pair ... }
 * @endcode
 * The view is frozen once its image was identical to the previous one for `freeze_frames`
 * consecutive updates, and live again on the first image that differs (in any byte, in size or
 * in type).
 *
 * Cost: one memcmp that stops at the first differing byte (a live image differs within its first
 * rows), and a copy of the image when it changed. The detector keeps its own copy, so the caller's
 * buffer may be reused or freed after update().
 *
 * Thread safety: not thread-safe; one instance per view, used by one thread at a time.
 */
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace endo_stereo {

class FreezeDetector {
 public:
  /// @param freeze_frames consecutive identical images after which the view is frozen; 0 = never
  /// (the detector then keeps no copy). @throws std::invalid_argument when negative.
  explicit FreezeDetector(int freeze_frames = 10);

  /// Change the threshold; the current run of identical images is kept.
  /// @throws std::invalid_argument when negative.
  void setFreezeFrames(int freeze_frames);
  int freezeFrames() const { return freeze_frames_; }

  /// The view's image for one more pair (any size and type, continuous or not; an empty image
  /// counts as an image like any other). @return frozen() after this image.
  bool update(const cv::Mat& image);

  /// Whether the view is frozen now.
  bool frozen() const { return frozen_; }
  /// Consecutive updates whose image equalled the previous one (0 after a changed image).
  int unchangedRun() const { return run_; }
  /// Forget the previous image (the next update() starts a new run).
  void reset();

  /// Same size, same type and the same bytes in every row.
  static bool identical(const cv::Mat& a, const cv::Mat& b);

 private:
  int freeze_frames_;
  cv::Mat previous_;
  bool has_previous_ = false;
  int run_ = 0;
  bool frozen_ = false;
};

}  // namespace endo_stereo
