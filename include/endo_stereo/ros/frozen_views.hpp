/**
 * @file frozen_views.hpp
 * @brief The nodelet's watch on frozen cameras: one FreezeDetector (core) per view, fed every
 * pair the synchroniser forms, with the log and diagnostics wording.
 *
 * A view whose image is bit-identical to its previous one for `~freeze_frames` consecutive pairs
 * is frozen; while either view is frozen its pairs are withheld (not matched, not published, and
 * counted), a WARN names the camera (once when it freezes, then at most every 5 s while it stays
 * frozen) and check() says so. The first pair whose frozen view changed again is matched, after a
 * reset of the temporal state (the pairs matched before the freeze was detected paired a stale
 * view with a live one; their priors and fused values are dropped), and an INFO says so.
 *
 * Thread safety: every method may be called from any thread.
 */
#pragma once

#include <cstdint>
#include <mutex>
#include <string>

#include <ros/time.h>
#include <sensor_msgs/Image.h>

#include "endo_stereo/core/freeze_detector.hpp"

namespace endo_stereo {

class FrozenViews {
 public:
  /// @param freeze_frames  `~freeze_frames` (0 = off: check() never withholds a pair).
  /// @param node_name      the nodelet's name, for log lines.
  /// @param left_topic, right_topic  resolved input topics, naming the cameras in messages.
  FrozenViews(int freeze_frames, const std::string& node_name, const std::string& left_topic,
              const std::string& right_topic);

  struct Verdict {
    bool withhold = false;  ///< a view is frozen: do not match this pair
    bool resumed = false;   ///< this pair ends a freeze: reset the temporal state, then match it
  };
  /// One pair, as formed by the synchroniser (the image data is compared byte for byte).
  Verdict check(const sensor_msgs::Image& left, const sensor_msgs::Image& right);

  /// "" while both views are live, else a sentence naming the frozen camera(s).
  std::string message() const;
  /// Consecutive pairs in which the view's image equalled the previous one.
  int unchangedRun(bool left) const;

 private:
  std::string describeLocked() const;

  const std::string node_name_, left_topic_, right_topic_;
  mutable std::mutex mutex_;
  FreezeDetector left_, right_;
  bool frozen_ = false;             // either view frozen at the last pair
  int64_t withheld_in_freeze_ = 0;  // pairs withheld since the current freeze began
  ros::WallTime last_warned_;
};

}  // namespace endo_stereo
