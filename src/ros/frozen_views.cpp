// Frozen-camera watch of the nodelet. See frozen_views.hpp.
#include "endo_stereo/ros/frozen_views.hpp"

#include <sstream>

#include <ros/console.h>

namespace endo_stereo {
namespace {

// Repeat of the frozen-view warning while the view stays frozen, s (the other input errors use
// the same period).
constexpr double kWarnPeriodS = 5.0;

// The message's bytes as an image for the detector, without a copy: rows of `step` bytes when
// the data holds them (the padding is compared too: a frozen card repeats it), else one row.
cv::Mat bytesOf(const sensor_msgs::Image& m) {
  uint8_t* data = const_cast<uint8_t*>(m.data.data());  // only read: FreezeDetector copies
  if (m.data.empty()) return cv::Mat();
  if (m.step > 0 && m.height > 0 && static_cast<size_t>(m.step) * m.height == m.data.size()) {
    return cv::Mat(static_cast<int>(m.height), static_cast<int>(m.step), CV_8UC1, data);
  }
  return cv::Mat(1, static_cast<int>(m.data.size()), CV_8UC1, data);
}

}  // namespace

FrozenViews::FrozenViews(int freeze_frames, const std::string& node_name,
                         const std::string& left_topic, const std::string& right_topic)
    : node_name_(node_name),
      left_topic_(left_topic),
      right_topic_(right_topic),
      left_(freeze_frames),
      right_(freeze_frames) {}

std::string FrozenViews::describeLocked() const {
  std::ostringstream m;
  const bool l = left_.frozen(), r = right_.frozen();
  if (!l && !r) return {};
  if (l && r) {
    m << "both cameras frozen: " << left_topic_ << " and " << right_topic_
      << " have each sent the same image for " << std::min(left_.unchangedRun(), right_.unchangedRun())
      << " pairs";
  } else {
    m << (l ? "left" : "right") << " camera frozen: " << (l ? left_topic_ : right_topic_)
      << " has sent the same image for " << (l ? left_ : right_).unchangedRun() << " pairs";
  }
  m << "; no disparity until it changes (pairs withheld so far: " << withheld_in_freeze_ << ")";
  return m.str();
}

FrozenViews::Verdict FrozenViews::check(const sensor_msgs::Image& left,
                                        const sensor_msgs::Image& right) {
  Verdict v;
  std::string warn, info;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (left_.freezeFrames() == 0) return v;
    const bool l = left_.update(bytesOf(left));
    const bool r = right_.update(bytesOf(right));
    const bool frozen = l || r;
    const ros::WallTime now = ros::WallTime::now();
    if (frozen) {
      ++withheld_in_freeze_;
      v.withhold = true;
      if (!frozen_ || last_warned_.isZero() || (now - last_warned_).toSec() >= kWarnPeriodS) {
        warn = describeLocked();
        last_warned_ = now;
      }
    } else if (frozen_) {
      v.resumed = true;
      std::ostringstream m;
      m << "cameras live again after " << withheld_in_freeze_
        << " withheld pairs: disparities resume, temporal state reset";
      info = m.str();
      withheld_in_freeze_ = 0;
      last_warned_ = ros::WallTime();
    }
    frozen_ = frozen;
  }
  if (!warn.empty()) ROS_WARN("%s: %s", node_name_.c_str(), warn.c_str());
  if (!info.empty()) ROS_INFO("%s: %s", node_name_.c_str(), info.c_str());
  return v;
}

std::string FrozenViews::message() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return describeLocked();
}

int FrozenViews::unchangedRun(bool left) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return (left ? left_ : right_).unchangedRun();
}

}  // namespace endo_stereo
