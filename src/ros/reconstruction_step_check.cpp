// Views out of step on the ROS side: every formed pair feeds the FrameOffsetDetector; a verdict
// that changed is logged. See reconstruction.hpp.
#include "endo_stereo/ros/reconstruction.hpp"

#include <algorithm>
#include <cstdlib>
#include <sstream>

#include "endo_stereo/ros/conversions.hpp"

namespace endo_stereo {
namespace {

// Repeat of an out-of-step warning that later checks confirm, s.
constexpr double kStepWarnRepeatS = 30.0;

}  // namespace

void Reconstruction::restartStepCheck(bool forget) {
  std::lock_guard<std::mutex> lock(step_mutex_);
  if (!step_) return;
  if (forget) {
    step_->restart();
    step_warned_offset_ = 0;
    step_warned_ = ros::WallTime();
  } else {
    step_->recheck();
  }
}

void Reconstruction::checkStep(const Pair& pair) {
  if (!step_) return;
  int min_d = 0, max_d = 0;
  {
    std::lock_guard<std::mutex> lock(params_mutex_);
    min_d = params_.matcher.min_disparity;
    max_d = params_.matcher.max_disparity;
  }
  cv::Mat left, right;
  std::string error;
  // Views of the message data (the detector keeps downsampled copies only); a pair that does
  // not convert is refused later by the processing thread, with its message.
  if (!ros_conv::imageToMat(*pair.left, left, &error, false) ||
      !ros_conv::imageToMat(*pair.right, right, &error, false)) {
    return;
  }
  std::string warn, info;
  {
    std::lock_guard<std::mutex> lock(step_mutex_);
    step_->setDisparityRange(min_d, max_d);
    if (!step_->update(left, right, pair.left->header.stamp.toSec())) return;
    const int offset = step_->offset();
    const ros::WallTime now = ros::WallTime::now();
    // A new offset is warned at once; the same one, confirmed by a later check, at most every
    // 30 s (a check every 10 s by default; temporal resets start more).
    const bool repeat = offset == step_warned_offset_ && !step_warned_.isZero() &&
                        (now - step_warned_).toSec() < kStepWarnRepeatS;
    if (offset != 0 && !repeat) {
      step_warned_ = now;
      std::ostringstream m;
      m << "views out of step: " << nh_.resolveName(right_topic_) << " is "
        << std::abs(offset) << " frame" << (std::abs(offset) > 1 ? "s " : " ")
        << (offset > 0 ? "late" : "early") << " against " << nh_.resolveName(left_topic_)
        << " (offset " << (offset > 0 ? "+" : "") << offset << ": left frame t matches right frame t"
        << (offset > 0 ? "+" : "") << offset << " best); disparities on a moving scene are "
        << "wrong: check the capture cards' synchronisation, or set ~right_frame_offset to "
        << view_offset_.offset() + offset << " to compensate";
      warn = m.str();
    } else if (offset == 0 && step_warned_offset_ != 0) {
      info = "views in step again (left frame t matches right frame t best)";
      step_warned_ = ros::WallTime();
    }
    step_warned_offset_ = offset;
  }
  if (!warn.empty()) ROS_WARN("%s: %s", name_.c_str(), warn.c_str());
  if (!info.empty()) ROS_INFO("%s: %s", name_.c_str(), info.c_str());
}

}  // namespace endo_stereo
