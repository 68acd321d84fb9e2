// The inputs of the ROS side: lazy subscription, the camera_info a pair needs, and the checks of
// a pair before it is matched. See reconstruction.hpp.
#include "endo_stereo/ros/reconstruction.hpp"

#include <chrono>
#include <sstream>

#include <boost/bind/bind.hpp>

#include "endo_stereo/ros/conversions.hpp"

namespace endo_stereo {

bool Reconstruction::usesCameraInfo() const { return mode_ != RectifyMode::kUncalibrated; }

bool Reconstruction::needsCameraInfo() const {
  if (mode_ == RectifyMode::kCalibrated) return true;
  if (mode_ == RectifyMode::kPassThrough) {
    std::lock_guard<std::mutex> lock(params_mutex_);
    return !(params_.rectify.focal_px > 0.0 && params_.rectify.baseline_m > 0.0);
  }
  return false;
}

// ------------------------------------------------------------------------------------------------
// Lazy subscription
// ------------------------------------------------------------------------------------------------

void Reconstruction::connectCb() {
  std::lock_guard<std::mutex> lock(connect_mutex_);
  const uint32_t n = pub_disparity_.getNumSubscribers() + pub_points_.getNumSubscribers() +
                     pub_fused_.getNumSubscribers() + pub_confidence_.getNumSubscribers() +
                     pub_disparity_color_.getNumSubscribers() +
                     pub_coverage_.getNumSubscribers() + pub_left_rect_.getNumSubscribers() +
                     pub_right_rect_.getNumSubscribers() + pub_depth_.getNumSubscribers() +
                     pub_rgb_.getNumSubscribers() + pub_depth_fused_.getNumSubscribers();
  if (n == 0 && subscribed_) {
    unsubscribeInputs();
  } else if (n > 0 && !subscribed_) {
    subscribeInputs();
  }
}

void Reconstruction::subscribeInputs() {
  const std::string& left_topic = left_topic_;
  const std::string& right_topic = right_topic_;
  const image_transport::TransportHints hints(ros_params_.image_transport, ros::TransportHints(),
                                              pnh_);
  try {
    left_sub_.subscribe(it_, left_topic, ros_params_.queue_size, hints);
    right_sub_.subscribe(it_, right_topic, ros_params_.queue_size, hints);
  } catch (const image_transport::TransportLoadException& ex) {
    ROS_ERROR("%s: cannot subscribe with image_transport '%s': %s", name_.c_str(),
              ros_params_.image_transport.c_str(), ex.what());
    left_sub_.unsubscribe();
    right_sub_.unsubscribe();
    return;
  }
  if (usesCameraInfo()) {
    left_info_sub_ = nh_.subscribe<sensor_msgs::CameraInfo>(
        "left/camera_info", ros_params_.queue_size,
        boost::bind(&Reconstruction::infoCb, this, true, boost::placeholders::_1));
    right_info_sub_ = nh_.subscribe<sensor_msgs::CameraInfo>(
        "right/camera_info", ros_params_.queue_size,
        boost::bind(&Reconstruction::infoCb, this, false, boost::placeholders::_1));
  }
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    scheduler_.inputsSubscribed(ros::WallTime::now().toSec());
  }
  subscribed_ = true;
  restartStepCheck(true);  // a new stream
  ROS_DEBUG("%s: subscribed to %s and %s", name_.c_str(), nh_.resolveName(left_topic).c_str(),
            nh_.resolveName(right_topic).c_str());
}

void Reconstruction::unsubscribeInputs() {
  left_sub_.unsubscribe();
  right_sub_.unsubscribe();
  left_info_sub_.shutdown();
  right_info_sub_.shutdown();
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    scheduler_.inputsUnsubscribed();
  }
  subscribed_ = false;
}

bool Reconstruction::inputsSubscribed() const {
  std::lock_guard<std::mutex> lock(connect_mutex_);
  return subscribed_;
}

// ------------------------------------------------------------------------------------------------
// camera_info and the checks of a pair
// ------------------------------------------------------------------------------------------------

void Reconstruction::awaitCameraInfo(Pair& pair) {
  // The calibration of a rig does not change from frame to frame, so the first camera_info to
  // arrive serves a pair that came before it; checkPair still judges what it holds.
  std::unique_lock<std::mutex> lock(info_mutex_);
  info_cv_.wait_for(lock, std::chrono::duration<double>(ros_params_.camera_info_wait_s),
                    [this] { return info_stopping_ || (left_info_ && right_info_); });
  if (!pair.left_info) pair.left_info = left_info_;
  if (!pair.right_info) pair.right_info = right_info_;
}

bool Reconstruction::checkPair(const Pair& p, std::string* error) {
  const sensor_msgs::Image& l = *p.left;
  const sensor_msgs::Image& r = *p.right;
  std::ostringstream m;
  if (l.width != r.width || l.height != r.height) {
    m << "image sizes differ: left " << l.width << "x" << l.height << ", right " << r.width << "x"
      << r.height;
    *error = m.str();
    return false;
  }
  if (l.encoding != r.encoding) {
    // The core converts each side on its own, so mixed encodings would work, but a stereo
    // camera never produces them: it means two topics from different sources.
    m << "encodings differ: left '" << l.encoding << "', right '" << r.encoding << "'";
    *error = m.str();
    return false;
  }
  if (!needsCameraInfo() && !(usesCameraInfo() && p.left_info && p.right_info)) return true;
  if (!p.left_info || !p.right_info) {
    m << "no camera_info received yet on "
      << nh_.resolveName(!p.left_info ? "left/camera_info" : "right/camera_info")
      << " (calibrated input needs both; or set rectify.mode uncalibrated)";
    *error = m.str();
    return false;
  }
  std::string e = ros_conv::checkCameraInfo(*p.left_info, "left/camera_info",
                                            static_cast<int>(l.width), static_cast<int>(l.height));
  if (e.empty()) {
    e = ros_conv::checkCameraInfo(*p.right_info, "right/camera_info", static_cast<int>(r.width),
                                  static_cast<int>(r.height));
  }
  if (e.empty()) e = ros_conv::stereoFromCameraInfo(*p.left_info, *p.right_info).validate();
  if (!e.empty()) {
    *error = e;
    return false;
  }
  return true;
}

bool Reconstruction::checkStampOrder(const ros::Time& stamp) {
  // Outputs go in stamp order: a pair not after the last processed one is refused, unless time
  // went back far enough to be a new stream (frame_scheduler.hpp).
  StampCheck order;
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    order = scheduler_.checkStamp(stamp.toSec());
  }
  if (order.verdict == StampCheck::Verdict::kRestart) {
    ROS_WARN_THROTTLE(kThrottleS, "%s: time went back by %.3f s (a looping bag or a restarted "
                      "driver): temporal state reset", name_.c_str(), order.back_s);
    resetTemporalState();
  } else if (order.verdict == StampCheck::Verdict::kOutOfOrder) {
    std::ostringstream m;
    m.precision(6);
    m << std::fixed << "out-of-order pair: stamp " << stamp.toSec()
      << " s is not after the last processed " << order.last_stamp_s << " s";
    reject("pair", m.str());
    return false;
  }
  return true;
}

bool Reconstruction::applyCalibration(const Pair& pair) {
  if (!(pair.left_info && pair.right_info && usesCameraInfo())) return true;
  const StereoCalibration calib = ros_conv::stereoFromCameraInfo(*pair.left_info, *pair.right_info);
  if (has_calibration_ && calib == calibration_) return true;
  const std::string error = pipeline_->setCalibration(calib);
  if (!error.empty()) {
    reject("camera_info", error);
    return false;
  }
  if (has_calibration_) geometry_change_ = describeCalibrationChange(calibration_, calib);
  calibration_ = calib;
  has_calibration_ = true;
  return true;
}

bool Reconstruction::stereoInput(const Pair& pair, StereoInput* in) {
  // Views of the message data, no copies: the pair holds the messages until processing ends and
  // the pipeline only reads its input.
  std::string error;
  if (!ros_conv::imageToMat(*pair.left, in->left, &error, false)) {
    reject("left image", error);
    return false;
  }
  if (!ros_conv::imageToMat(*pair.right, in->right, &error, false)) {
    reject("right image", error);
    return false;
  }
  in->left_encoding = pair.left->encoding;
  in->right_encoding = pair.right->encoding;
  in->stamp_s = pair.left->header.stamp.toSec();
  return true;
}

std::string Reconstruction::describeCalibrationChange(const StereoCalibration& before,
                                                      const StereoCalibration& after) {
  std::ostringstream m;
  m << "camera_info changed mid-stream (";
  const cv::Size a = before.left.binnedSize(), b = after.left.binnedSize();
  if (a != b) {
    m << "image size " << a.width << "x" << a.height << " -> " << b.width << "x" << b.height;
  } else {
    m << "new calibration values, " << b.width << "x" << b.height;
  }
  m << ")";
  return m.str();
}

}  // namespace endo_stereo
