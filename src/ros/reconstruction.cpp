// The ROS side of endo_stereo. See reconstruction.hpp for topics and behaviour.
#include "endo_stereo/ros/reconstruction.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

#include <boost/bind/bind.hpp>
#include <boost/make_shared.hpp>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/image_encodings.h>
#include <stereo_msgs/DisparityImage.h>
#include <tf2_eigen/tf2_eigen.h>

#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/ros/conversions.hpp"

namespace endo_stereo {
namespace {

namespace enc = sensor_msgs::image_encodings;

// Latencies kept for the median / p90 in the diagnostics (about 10 s at 25 fps).
constexpr size_t kLatencyWindow = 250;
// Throttle period of input error messages, s: often enough to notice, rare enough for a flood.
constexpr double kThrottleS = 5.0;
// The backlog's overload test compares the medians of the last kRateWindow processing times and
// pair intervals, once kRateGrace pairs have been processed (the first frames after start-up
// are slower: the first searches the full range, the next ones fill their priors).
constexpr size_t kRateWindow = 8;
constexpr int64_t kRateGrace = 10;
// Repeat of an out-of-step warning that later checks confirm, s.
constexpr double kStepWarnRepeatS = 30.0;

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return std::nan("");
  const size_t k = static_cast<size_t>(std::round(q * (v.size() - 1)));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

// Median of one of the backlog's rate windows (at most kRateWindow values, not empty), the same
// element percentile(v, 0.5) picks, without copying into a vector on every pair.
double windowMedian(const std::deque<double>& d) {
  std::array<double, kRateWindow> v{};
  const size_t n = std::min(d.size(), kRateWindow);
  std::copy_n(d.begin(), n, v.begin());
  const size_t k = static_cast<size_t>(std::round(0.5 * (n - 1)));
  std::nth_element(v.begin(), v.begin() + k, v.begin() + n);
  return v[k];
}

// Messages are published through shared pointers: a subscriber in the same nodelet manager then
// gets the message itself (no serialisation, no copy), and remote ones are served as before.
template <typename M>
boost::shared_ptr<M> shared(M&& message) {
  return boost::make_shared<M>(std::move(message));
}

// Applies a rigid transform to the xyz of a PointCloud2 written by ros_conv::toPointCloud2
// (x y z float32 at offsets 0, 4, 8); NaN points stay NaN.
void transformCloud(sensor_msgs::PointCloud2& msg, const Eigen::Isometry3d& T) {
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  for (uint32_t r = 0; r < msg.height; ++r) {
    uint8_t* row = msg.data.data() + static_cast<size_t>(r) * msg.row_step;
    for (uint32_t c = 0; c < msg.width; ++c) {
      float* p = reinterpret_cast<float*>(row + static_cast<size_t>(c) * msg.point_step);
      if (!std::isfinite(p[0])) continue;
      const Eigen::Vector3f q = R * Eigen::Vector3f(p[0], p[1], p[2]) + t;
      p[0] = q.x();
      p[1] = q.y();
      p[2] = q.z();
    }
  }
}

}  // namespace

Reconstruction::Reconstruction(const ros::NodeHandle& nh, const ros::NodeHandle& pnh,
                               const std::string& name, const RosParams& ros_params,
                               const PipelineParams& params)
    : nh_(nh),
      pnh_(pnh),
      name_(name),
      ros_params_(ros_params),
      mode_(params.rectify.mode),
      left_topic_(mode_ == RectifyMode::kPassThrough ? "left/image_rect" : "left/image_raw"),
      right_topic_(mode_ == RectifyMode::kPassThrough ? "right/image_rect" : "right/image_raw"),
      it_(nh),
      params_(params),
      updater_(nh, pnh, name) {
  std::string e = ros_params_.validate();
  if (!e.empty()) throw std::invalid_argument(e);
  e = params.validate();
  if (!e.empty()) throw std::invalid_argument(e);
  pipeline_ = std::make_unique<Pipeline>(params);
  // The rectification residual (a patch search every quality_stride frames, about 13 ms of one
  // core at 960x540) is a diagnostic: measured beside the processing at the lowest priority, not
  // inside a frame. (Uncalibrated mode still matches SIFT inline while it pools an estimate.)
  pipeline_->setAsyncRectificationQuality(true);
  frozen_views_ = std::make_unique<FrozenViews>(ros_params_.freeze_frames, name_,
                                                nh_.resolveName(left_topic_),
                                                nh_.resolveName(right_topic_));
  if (ros_params_.step_check_period_frames > 0) {
    FrameOffsetParams sp;
    sp.period_frames = std::max(sp.window_frames, ros_params_.step_check_period_frames);
    step_ = std::make_unique<FrameOffsetDetector>(params.matcher.min_disparity,
                                                  params.matcher.max_disparity, sp);
  }

  if (!ros_params_.target_frame.empty()) {
    tf_buffer_ = std::make_unique<tf2_ros::Buffer>();
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_, nh_);
  }

  // The two image filters feed the synchroniser; their own callbacks only count arrivals, so a
  // side that never finds a partner can be reported.
  left_sub_.registerCallback(
      boost::bind(&Reconstruction::imageCb, this, true, boost::placeholders::_1));
  right_sub_.registerCallback(
      boost::bind(&Reconstruction::imageCb, this, false, boost::placeholders::_1));
  if (ros_params_.approximate_sync) {
    approx_sync_ = std::make_unique<message_filters::Synchronizer<ApproxPolicy>>(
        ApproxPolicy(ros_params_.queue_size), left_sub_, right_sub_);
    approx_sync_->setMaxIntervalDuration(ros::Duration(ros_params_.sync_tolerance_s));
    approx_sync_->registerCallback(
        boost::bind(&Reconstruction::pairCb, this, boost::placeholders::_1,
                    boost::placeholders::_2));
  } else {
    exact_sync_ = std::make_unique<message_filters::Synchronizer<ExactPolicy>>(
        ExactPolicy(ros_params_.queue_size), left_sub_, right_sub_);
    exact_sync_->registerCallback(
        boost::bind(&Reconstruction::pairCb, this, boost::placeholders::_1,
                    boost::placeholders::_2));
  }

  worker_ = std::thread(&Reconstruction::workerLoop, this);

  updater_.setHardwareID("endo_stereo");
  updater_.add("reconstruction", this, &Reconstruction::diagnose);
  diag_prev_time_ = ros::WallTime::now();
  diag_timer_ = nh_.createWallTimer(ros::WallDuration(ros_params_.diagnostics_period_s),
                                    [this](const ros::WallTimerEvent&) { updater_.force_update(); });

  advertiseOutputs();
}

void Reconstruction::advertiseOutputs() {
  // The resolved input names (remappings applied): no output may take one of them, or the node
  // would feed itself (its own subscription keeping it subscribed, its images counted as input).
  std::vector<std::string> inputs = {nh_.resolveName(left_topic_), nh_.resolveName(right_topic_)};
  if (usesCameraInfo()) {
    inputs.push_back(nh_.resolveName("left/camera_info"));
    inputs.push_back(nh_.resolveName("right/camera_info"));
  }
  std::vector<std::string> refused;
  auto allowed = [&](const std::string& name) {
    if (std::find(inputs.begin(), inputs.end(), nh_.resolveName(name)) == inputs.end()) {
      outputs_.push_back(name);
      return true;
    }
    refused.push_back(name);
    ROS_WARN("%s: output %s is not advertised: %s is also an input (check the remappings)",
             name_.c_str(), name.c_str(), nh_.resolveName(name).c_str());
    return false;
  };
  // Advertise under the connect mutex: a connect callback fired by the first advertise must not
  // look at publishers that are not assigned yet (stereo_image_proc does the same).
  std::lock_guard<std::mutex> lock(connect_mutex_);
  ros::SubscriberStatusCallback cb = boost::bind(&Reconstruction::connectCb, this);
  image_transport::SubscriberStatusCallback icb = boost::bind(&Reconstruction::connectCb, this);
  if (allowed("disparity")) {
    pub_disparity_ = nh_.advertise<stereo_msgs::DisparityImage>("disparity", 1, cb, cb);
  }
  if (allowed("points2")) {
    pub_points_ = nh_.advertise<sensor_msgs::PointCloud2>("points2", 1, cb, cb);
  }
  if (allowed("disparity_fused")) {
    pub_fused_ = nh_.advertise<stereo_msgs::DisparityImage>("disparity_fused", 1, cb, cb);
  }
  if (allowed("disparity_color")) pub_disparity_color_ = it_.advertise("disparity_color", 1, icb, icb);
  if (allowed("confidence")) pub_confidence_ = it_.advertise("confidence", 1, icb, icb);
  if (allowed("coverage")) pub_coverage_ = it_.advertise("coverage", 1, icb, icb);
  // The RGB-D outputs: image and camera_info advertised together (image_transport's camera
  // publisher: <ns>/image_rect and <ns>/camera_info), both names checked against the inputs.
  auto camera = [&](const std::string& ns, const std::string& image,
                    image_transport::CameraPublisher& pub) {
    const bool image_ok = allowed(ns + "/" + image);
    const bool info_ok = allowed(ns + "/camera_info");
    if (image_ok && info_ok) pub = it_.advertiseCamera(ns + "/" + image, 1, icb, icb, cb, cb);
  };
  camera("depth", "image_rect", pub_depth_);
  camera("rgb", "image_rect_color", pub_rgb_);
  camera("depth_fused", "image_rect", pub_depth_fused_);
  if (mode_ == RectifyMode::kPassThrough) {
    // The input is the rectified pair: a rectified-image output would repeat it, under the very
    // name of the right input (right/image_rect).
    outputs_note_ = "no rectified images: the input is already rectified";
  } else {
    if (allowed("left/image_rect_color")) {
      pub_left_rect_ = it_.advertise("left/image_rect_color", 1, icb, icb);
    }
    if (allowed("right/image_rect")) pub_right_rect_ = it_.advertise("right/image_rect", 1, icb, icb);
  }
  for (const std::string& r : refused) {
    outputs_note_ += (outputs_note_.empty() ? "" : "; ") + r + " not advertised (an input)";
  }
}

std::string Reconstruction::describe() const {
  std::ostringstream m;
  m << "input " << nh_.resolveName(left_topic_) << " and " << nh_.resolveName(right_topic_);
  if (ros_params_.image_transport != "raw") m << " (transport " << ros_params_.image_transport << ")";
  if (usesCameraInfo()) {
    m << (needsCameraInfo() ? " with " : " with optional ") << nh_.resolveName("left/camera_info")
      << " and " << nh_.resolveName("right/camera_info");
  }
  m << "; rectify mode " << toString(mode_) << ", "
    << (ros_params_.approximate_sync ? "approximate" : "exact") << " sync";
  if (ros_params_.approximate_sync) m << " within " << ros_params_.sync_tolerance_s << " s";
  m << ", queue " << ros_params_.queue_size;
  {
    std::lock_guard<std::mutex> lock(params_mutex_);
    m << "; disparity range " << params_.matcher.min_disparity << ".."
      << params_.matcher.max_disparity << " ("
      << params_.matcher.max_disparity - params_.matcher.min_disparity + 1 << " values)";
    m << "; outputs";
    for (size_t i = 0; i < outputs_.size(); ++i) {
      const std::string& o = outputs_[i];
      m << (i ? ", " : " ") << o;
      if (o == "points2" && !params_.output.point_cloud) m << " (off: output/point_cloud false)";
    }
  }
  if (!outputs_note_.empty()) m << " (" << outputs_note_ << ")";
  return m.str();
}

Reconstruction::~Reconstruction() {
  diag_timer_.stop();
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    unsubscribeInputs();
  }
  {
    std::lock_guard<std::mutex> lock(backlog_mutex_);
    shutdown_ = true;
  }
  backlog_cv_.notify_all();
  {
    std::lock_guard<std::mutex> lock(info_mutex_);
    info_stopping_ = true;
  }
  info_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

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
  {
    std::lock_guard<std::mutex> lock(info_mutex_);
    left_unpaired_since_ = ros::WallTime();
    right_unpaired_since_ = ros::WallTime();
  }
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
    std::lock_guard<std::mutex> lock(info_mutex_);
    subscribed_since_ = ros::WallTime::now();
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
  subscribed_ = false;
}

bool Reconstruction::inputsSubscribed() const {
  std::lock_guard<std::mutex> lock(connect_mutex_);
  return subscribed_;
}

// ------------------------------------------------------------------------------------------------
// Input callbacks (ROS callback threads)
// ------------------------------------------------------------------------------------------------

void Reconstruction::infoCb(bool left, const sensor_msgs::CameraInfoConstPtr& msg) {
  {
    std::lock_guard<std::mutex> lock(info_mutex_);
    (left ? left_info_ : right_info_) = msg;
  }
  info_cv_.notify_all();
}

void Reconstruction::imageCb(bool left, const sensor_msgs::ImageConstPtr& msg) {
  const ros::WallTime now = ros::WallTime::now();
  std::string problem;
  {
    std::lock_guard<std::mutex> lock(info_mutex_);
    (left ? last_left_arrival_ : last_right_arrival_) = now;
    (left ? last_left_stamp_ : last_right_stamp_) = msg->header.stamp;
    ros::WallTime& waiting_since = left ? left_unpaired_since_ : right_unpaired_since_;
    if (waiting_since.isZero()) waiting_since = now;
    // A side that keeps arriving while no pair forms: the other side is missing, or the stamps
    // never match (exact sync with offset stamps, or offsets above the tolerance).
    if ((now - waiting_since).toSec() > ros_params_.unpaired_timeout_s) {
      const ros::WallTime& other = left ? last_right_arrival_ : last_left_arrival_;
      std::ostringstream m;
      m.precision(6);
      m << std::fixed;
      if (other.isZero() || (now - other).toSec() > ros_params_.unpaired_timeout_s) {
        m << (left ? "left" : "right") << " images arrive without a " << (left ? "right" : "left")
          << " image for " << (now - waiting_since).toSec() << " s: check the "
          << nh_.resolveName(left ? right_topic_ : left_topic_) << " topic";
      } else {
        m << "left and right images arrive but do not pair (last stamps: left "
          << last_left_stamp_.toSec() << ", right " << last_right_stamp_.toSec() << "); "
          << (ros_params_.approximate_sync
                  ? "their stamps differ by more than ~sync_tolerance_s"
                  : "exact synchronisation needs equal stamps (or set ~approximate_sync true)");
      }
      problem = m.str();
    }
  }
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++(left ? counters_.left_images : counters_.right_images);
  }
  if (!problem.empty()) {
    ROS_ERROR_THROTTLE(kThrottleS, "%s: %s", name_.c_str(), problem.c_str());
    std::lock_guard<std::mutex> lock(stats_mutex_);
    last_error_ = problem;
    last_error_time_ = now;
  }
}

void Reconstruction::pairCb(const sensor_msgs::ImageConstPtr& left,
                            const sensor_msgs::ImageConstPtr& right) {
  Pair pair;
  pair.left = left;
  pair.right = right;
  pair.arrival = ros::WallTime::now();
  {
    std::lock_guard<std::mutex> lock(info_mutex_);
    pair.left_info = left_info_;
    pair.right_info = right_info_;
    left_unpaired_since_ = ros::WallTime();
    right_unpaired_since_ = ros::WallTime();
  }
  checkStep(pair);
  if (withholdFrozen(pair)) return;
  int64_t dropped = 0;
  {
    std::lock_guard<std::mutex> lock(backlog_mutex_);
    if (!last_pair_arrival_.isZero()) {
      pair_intervals_ms_.push_back((pair.arrival - last_pair_arrival_).toSec() * 1e3);
      if (pair_intervals_ms_.size() > kRateWindow) pair_intervals_ms_.pop_front();
    }
    last_pair_arrival_ = pair.arrival;
    backlog_.push_back(std::move(pair));
    while (backlog_.size() > static_cast<size_t>(ros_params_.backlog_pairs)) {
      backlog_.pop_front();  // the oldest waiting pair makes room for the newest
      ++dropped;
    }
  }
  backlog_cv_.notify_one();
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++counters_.pairs_received;
  counters_.pairs_dropped += dropped;
}

// ------------------------------------------------------------------------------------------------
// Parameters
// ------------------------------------------------------------------------------------------------

std::string Reconstruction::setPipelineParams(const PipelineParams& params) {
  std::string e = params.validate();
  if (!e.empty()) return e;
  if (params.rectify.mode != mode_) {
    return "rectify.mode: cannot change from '" + toString(mode_) + "' to '" +
           toString(params.rectify.mode) + "' while running (it selects the input topics)";
  }
  std::lock_guard<std::mutex> lock(params_mutex_);
  params_ = params;
  params_pending_ = true;
  return {};
}

PipelineParams Reconstruction::pipelineParams() const {
  std::lock_guard<std::mutex> lock(params_mutex_);
  return params_;
}

ReconstructionCounters Reconstruction::counters() const {
  std::lock_guard<std::mutex> lock(stats_mutex_);
  return counters_;
}

// ------------------------------------------------------------------------------------------------
// Processing thread
// ------------------------------------------------------------------------------------------------

void Reconstruction::workerLoop() {
  for (;;) {
    Pair pair;
    int64_t stale = 0;
    {
      std::unique_lock<std::mutex> lock(backlog_mutex_);
      backlog_cv_.wait(lock, [this] { return shutdown_ || !backlog_.empty(); });
      if (shutdown_) return;
      // Frames come faster than they are processed (the medians of the last few processing
      // times and pair intervals): only the newest pair is worth processing. Otherwise the
      // waiting pairs are caught up in order, except those that waited too long.
      const bool overloaded =
          processed_since_start_ >= kRateGrace && busy_ms_.size() >= kRateWindow &&
          pair_intervals_ms_.size() >= kRateWindow &&
          windowMedian(busy_ms_) > windowMedian(pair_intervals_ms_);
      const ros::WallTime now = ros::WallTime::now();
      while (backlog_.size() > 1 &&
             (overloaded ||
              (now - backlog_.front().arrival).toSec() > ros_params_.backlog_max_age_s)) {
        backlog_.pop_front();
        ++stale;
      }
      pair = std::move(backlog_.front());
      backlog_.pop_front();
    }
    if (stale > 0) {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      counters_.pairs_dropped += stale;
    }
    try {
      if (needsCameraInfo() && (!pair.left_info || !pair.right_info)) awaitCameraInfo(pair);
      const ros::WallTime t0 = ros::WallTime::now();
      processPair(pair);
      busy_ms_.push_back((ros::WallTime::now() - t0).toSec() * 1e3);
      if (busy_ms_.size() > kRateWindow) busy_ms_.pop_front();
      ++processed_since_start_;
    } catch (const std::exception& ex) {
      // The pipeline promises not to throw on bad input; this is the last line of defence that
      // keeps the nodelet (and the manager's other nodelets) alive if something does.
      reject("pair", std::string("unexpected exception: ") + ex.what());
    }
  }
}

void Reconstruction::awaitCameraInfo(Pair& pair) {
  // The calibration of a rig does not change from frame to frame, so the first camera_info to
  // arrive serves a pair that came before it; checkPair still judges what it holds.
  std::unique_lock<std::mutex> lock(info_mutex_);
  info_cv_.wait_for(lock, std::chrono::duration<double>(ros_params_.camera_info_wait_s),
                    [this] { return info_stopping_ || (left_info_ && right_info_); });
  if (!pair.left_info) pair.left_info = left_info_;
  if (!pair.right_info) pair.right_info = right_info_;
}

void Reconstruction::reject(const std::string& what, const std::string& error) {
  ROS_ERROR_THROTTLE(kThrottleS, "%s: %s rejected: %s", name_.c_str(), what.c_str(),
                     error.c_str());
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++counters_.pairs_rejected;
  last_error_ = error;
  last_error_time_ = ros::WallTime::now();
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

void Reconstruction::noteTemporalReset() {
  // A geometry change (new camera_info, or new image size) is said once, with what the pipeline
  // did about it; time-based resets (gaps, a stream restart) are counted only.
  const bool size_changed = out_.reset_reason.find("size changed") != std::string::npos;
  if (!geometry_change_.empty() || size_changed) {
    const std::string what = !geometry_change_.empty() ? geometry_change_ : "images changed size";
    ROS_INFO("%s: %s: rectification rebuilt, temporal state reset (%s); outputs from %.6f s on "
             "use the new geometry only",
             name_.c_str(), what.c_str(), out_.reset_reason.c_str(), last_stamp_.toSec());
    geometry_change_.clear();
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++counters_.geometry_changes;
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++counters_.temporal_resets;
  last_reset_reason_ = out_.reset_reason;
}

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
        << "wrong: check the capture cards' synchronisation";
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

bool Reconstruction::withholdFrozen(const Pair& pair) {
  const FrozenViews::Verdict v = frozen_views_->check(*pair.left, *pair.right);
  if (v.resumed) temporal_reset_pending_ = true;
  if (!v.withhold) return false;
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++counters_.pairs_received;
  ++counters_.pairs_frozen;
  return true;
}

void Reconstruction::processPair(const Pair& pair) {
  // A frozen view came back: what was matched before the freeze was found paired a stale view.
  if (temporal_reset_pending_.exchange(false)) {
    pipeline_->reset();
    restartStepCheck(false);
    std::lock_guard<std::mutex> lock(stats_mutex_);
    frames_since_reset_ = 0;
  }
  // Parameters change only here, between two frames.
  {
    std::lock_guard<std::mutex> lock(params_mutex_);
    if (params_pending_) {
      params_pending_ = false;
      try {
        pipeline_->setParams(params_);
      } catch (const std::invalid_argument& ex) {
        ROS_ERROR("%s: new parameters refused by the pipeline: %s", name_.c_str(), ex.what());
      }
    }
  }
  // Fused and coverage outputs are computed while configured or while someone listens; the
  // cloud (8 MB at 960x540) only while configured and someone listens to points2, and the left
  // colour image (conversion + 3-channel remap) only for the cloud, left/image_rect_color or
  // rgb/image_rect_color.
  {
    OutputParams configured;
    {
      std::lock_guard<std::mutex> lock(params_mutex_);
      configured = params_.output;
    }
    PipelineParams p = pipeline_->params();
    const bool want_fused = configured.fused || pub_fused_.getNumSubscribers() > 0 ||
                            pub_depth_fused_.getNumSubscribers() > 0;
    const bool want_cov = configured.coverage || pub_coverage_.getNumSubscribers() > 0;
    const bool want_cloud = configured.point_cloud && pub_points_.getNumSubscribers() > 0;
    if (p.output.fused != want_fused || p.output.coverage != want_cov ||
        p.output.point_cloud != want_cloud) {
      p.output.fused = want_fused;
      p.output.coverage = want_cov;
      p.output.point_cloud = want_cloud;
      pipeline_->setParams(p);
    }
    pipeline_->setColorOutput(pub_left_rect_.getNumSubscribers() > 0 ||
                              pub_rgb_.getNumSubscribers() > 0);
  }

  const ros::Time stamp = pair.left->header.stamp;
  if (!last_stamp_.isZero() && stamp <= last_stamp_) {
    const double back = (last_stamp_ - stamp).toSec();
    if (back > ros_params_.restart_jump_back_s) {
      ROS_WARN_THROTTLE(kThrottleS, "%s: time went back by %.3f s (a looping bag or a restarted "
                        "driver): temporal state reset", name_.c_str(), back);
      pipeline_->reset();
      restartStepCheck(false);
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++counters_.restarts;
      frames_since_reset_ = 0;
    } else {
      std::ostringstream m;
      m.precision(6);
      m << std::fixed << "out-of-order pair: stamp " << stamp.toSec()
        << " s is not after the last processed " << last_stamp_.toSec() << " s";
      reject("pair", m.str());
      return;
    }
  }

  std::string error;
  if (!checkPair(pair, &error)) {
    reject("pair", error);
    return;
  }
  if (pair.left_info && pair.right_info && usesCameraInfo()) {
    const StereoCalibration calib = ros_conv::stereoFromCameraInfo(*pair.left_info, *pair.right_info);
    if (!has_calibration_ || calib != calibration_) {
      error = pipeline_->setCalibration(calib);
      if (!error.empty()) {
        reject("camera_info", error);
        return;
      }
      if (has_calibration_) geometry_change_ = describeCalibrationChange(calibration_, calib);
      calibration_ = calib;
      has_calibration_ = true;
    }
  }

  // Views of the message data, no copies: the pair holds the messages until processing ends and
  // the pipeline only reads its input.
  StereoInput in;
  if (!ros_conv::imageToMat(*pair.left, in.left, &error, false)) {
    reject("left image", error);
    return;
  }
  if (!ros_conv::imageToMat(*pair.right, in.right, &error, false)) {
    reject("right image", error);
    return;
  }
  in.left_encoding = pair.left->encoding;
  in.right_encoding = pair.right->encoding;
  in.stamp_s = stamp.toSec();
  const ros::WallTime t_process = ros::WallTime::now();
  if (!pipeline_->process(in, out_, &error)) {
    reject("pair", error);
    return;
  }
  last_stamp_ = stamp;
  if (out_.priors_reset) {
    noteTemporalReset();
    // A new geometry or a stream that went back in time may come with re-synchronised views:
    // check again. A gap between processed frames (pairs dropped here, a stall) is not news about
    // the views' synchronisation.
    if (out_.reset_reason.find("gap of") == std::string::npos) restartStepCheck(false);
  }
  const ros::WallTime t_publish = ros::WallTime::now();
  publishOutputs(pair, out_);
  const ros::WallTime t_done = ros::WallTime::now();

  const double latency_ms = (t_done - pair.arrival).toSec() * 1e3;
  if (!first_pair_logged_) {
    // The first pair is the slowest (full-range search, fresh buffers, threads started): say
    // where its time went, once, since the pairs behind it wait for it.
    first_pair_logged_ = true;
    ROS_INFO("%s: first pair out %.1f ms after it arrived: waited %.1f, pipeline %.1f "
             "(preprocess %.1f, rectify %.1f, match %.1f, temporal %.1f, cloud %.1f), "
             "publishing %.1f ms; later pairs are faster",
             name_.c_str(), latency_ms, (t_process - pair.arrival).toSec() * 1e3,
             out_.total_ms, out_.preprocess_ms, out_.rectify_ms, out_.match_ms, out_.temporal_ms,
             out_.cloud_ms, (t_done - t_publish).toSec() * 1e3);
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++counters_.pairs_processed;
  latencies_ms_.push_back(latency_ms);
  if (latencies_ms_.size() > kLatencyWindow) latencies_ms_.pop_front();
  pipeline_ms_.push_back(out_.total_ms);
  if (pipeline_ms_.size() > kLatencyWindow) pipeline_ms_.pop_front();
  last_density_ = out_.match.stats.density();
  if (out_.rect_quality.valid || out_.rect_quality.misaligned) last_quality_ = out_.rect_quality;
  last_priors_used_ = out_.priors_used;
  last_prior_stats_ = out_.prior_stats;
  // The temporal state a frame used: a reset before it (any reason) starts a new run at 1.
  frames_since_reset_ = out_.priors_reset ? 1 : frames_since_reset_ + 1;
}

void Reconstruction::publishOutputs(const Pair& pair, const PipelineOutput& out) {
  std_msgs::Header header;
  header.stamp = pair.left->header.stamp;
  if (!ros_params_.frame_id.empty()) {
    header.frame_id = ros_params_.frame_id;
  } else if (!out.geometry.frame_id.empty()) {
    header.frame_id = out.geometry.frame_id;
  } else {
    header.frame_id = pair.left->header.frame_id;
  }
  const PipelineParams& p = pipeline_->params();

  // Depth from disparity needs a metric, non-polar geometry; otherwise f and T are written as 0
  // so no consumer mistakes the disparity for one it can triangulate.
  RectifiedGeometry g = out.geometry;
  const bool depth_ok = g.metric && !g.polar && g.f_px > 0.0 && g.baseline_m > 0.0;
  if (!depth_ok) {
    if (g.polar) g.f_px = 0.0;
    g.baseline_m = 0.0;
  }
  ros_conv::DisparityRange range;
  range.min_disparity = p.matcher.min_disparity;
  range.max_disparity = p.matcher.max_disparity;
  range.delta_d = p.matcher.subpixel ? ros_params_.subpixel_delta_d : 1.0;

  if (pub_disparity_.getNumSubscribers() > 0) {
    pub_disparity_.publish(
        shared(ros_conv::toDisparityImage(out.match.disparity, g, range, header)));
  }
  if (pub_disparity_color_.getNumSubscribers() > 0) {
    // A fixed colour scale (the search range) keeps colours comparable from frame to frame.
    pub_disparity_color_.publish(shared(ros_conv::matToImage(
        colorizeDisparity(out.match.disparity, range.min_disparity, range.max_disparity),
        enc::BGR8, header)));
  }
  if (pub_fused_.getNumSubscribers() > 0 && !out.fused_disparity.empty()) {
    pub_fused_.publish(shared(ros_conv::toDisparityImage(out.fused_disparity, g, range, header)));
  }
  if (pub_confidence_.getNumSubscribers() > 0 && !out.match.confidence.empty()) {
    pub_confidence_.publish(
        shared(ros_conv::matToImage(out.match.confidence, enc::TYPE_32FC1, header)));
  }
  if (pub_coverage_.getNumSubscribers() > 0 && !out.coverage.empty()) {
    pub_coverage_.publish(shared(ros_conv::matToImage(out.coverage, enc::MONO16, header)));
  }
  if (pub_left_rect_.getNumSubscribers() > 0 && !out.left_rect_color.empty()) {
    pub_left_rect_.publish(shared(ros_conv::matToImage(out.left_rect_color, enc::BGR8, header)));
  }
  if (pub_right_rect_.getNumSubscribers() > 0 && !out.right_rect_gray.empty()) {
    pub_right_rect_.publish(shared(ros_conv::matToImage(out.right_rect_gray, enc::MONO8, header)));
  }
  publishRgbd(header, out, g, depth_ok);
  if (pub_points_.getNumSubscribers() == 0 || out.cloud.xyz.empty()) return;
  if (!depth_ok || !out.cloud.metric) {
    if (!warned_not_metric_) {
      ROS_WARN("%s: points2 is not published: the geometry is not metric (uncalibrated input "
               "without rectify.focal_px and rectify.baseline_m, or a polar rectification)",
               name_.c_str());
      warned_not_metric_ = true;
    }
    return;
  }
  const auto cloud_msg = shared(ros_conv::toPointCloud2(out.cloud, header));
  sensor_msgs::PointCloud2& cloud = *cloud_msg;
  if (tf_buffer_ && ros_params_.target_frame != header.frame_id) {
    try {
      const geometry_msgs::TransformStamped t = tf_buffer_->lookupTransform(
          ros_params_.target_frame, header.frame_id, header.stamp,
          ros::Duration(ros_params_.tf_timeout_s));
      transformCloud(cloud, tf2::transformToEigen(t));
      cloud.header.frame_id = ros_params_.target_frame;
    } catch (const tf2::TransformException& ex) {
      ROS_WARN_THROTTLE(kThrottleS, "%s: points2 not published: no transform %s <- %s at %.6f: %s",
                        name_.c_str(), ros_params_.target_frame.c_str(), header.frame_id.c_str(),
                        header.stamp.toSec(), ex.what());
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++counters_.tf_failures;
      return;
    }
  }
  pub_points_.publish(cloud_msg);
}

void Reconstruction::publishRgbd(const std_msgs::Header& header, const PipelineOutput& out,
                                 const RectifiedGeometry& g, bool depth_ok) {
  const bool depth = pub_depth_.getNumSubscribers() > 0;
  const bool rgb = pub_rgb_.getNumSubscribers() > 0;
  const bool fused = pub_depth_fused_.getNumSubscribers() > 0 && !out.fused_disparity.empty();
  if (!depth && !rgb && !fused) return;
  if (!depth_ok) {
    // An RGB-D consumer takes depth in metres and a camera_info it can trust: neither exists
    // without a metric, non-polar geometry, so the whole set is withheld (said once).
    if (!warned_no_depth_) {
      ROS_WARN("%s: depth/*, depth_fused/* and rgb/* are not published: the geometry is not "
               "metric (uncalibrated input without rectify.focal_px and rectify.baseline_m, or a "
               "polar rectification)", name_.c_str());
      warned_no_depth_ = true;
    }
    return;
  }
  // One camera_info for the three: they share the left rectified view and the disparity's size.
  const cv::Size size = out.match.disparity.size();
  const auto info =
      shared(ros_conv::rectifiedCameraInfo(g, size.width, size.height, header));
  if (depth) {
    disparityToDepth(out.match.disparity, g, depth_);
    pub_depth_.publish(shared(ros_conv::matToImage(depth_, enc::TYPE_32FC1, header)), info);
  }
  if (rgb && out.left_rect_color.size() == size) {
    pub_rgb_.publish(shared(ros_conv::matToImage(out.left_rect_color, enc::BGR8, header)), info);
  }
  if (fused && out.fused_disparity.size() == size) {
    disparityToDepth(out.fused_disparity, g, depth_);
    pub_depth_fused_.publish(shared(ros_conv::matToImage(depth_, enc::TYPE_32FC1, header)), info);
  }
}

// ------------------------------------------------------------------------------------------------
// Diagnostics
// ------------------------------------------------------------------------------------------------

std::string Reconstruction::explainSilence(double silent_s) const {
  std::string left = nh_.resolveName(left_topic_), right = nh_.resolveName(right_topic_);
  if (ros_params_.image_transport != "raw") {
    left += " (transport " + ros_params_.image_transport + ")";
    right += " (transport " + ros_params_.image_transport + ")";
  }
  std::ostringstream m;
  m.precision(1);
  m << std::fixed << "no image on " << left << " or " << right << " for " << silent_s
    << " s although outputs have subscribers (rectify mode " << toString(mode_) << ")";
  ros::master::V_TopicInfo topics;
  if (!ros::master::getTopics(topics)) return m.str();
  auto published = [&](const std::string& relative) {
    const std::string name = nh_.resolveName(relative);
    for (const auto& t : topics) {
      if (t.name == name) return true;
    }
    return false;
  };
  const bool ours = published(left_topic_) || published(right_topic_);
  if (mode_ != RectifyMode::kPassThrough &&
      (published("left/image_rect") || published("left/image_rect_color"))) {
    m << "; " << nh_.resolveName(published("left/image_rect") ? "left/image_rect"
                                                              : "left/image_rect_color")
      << " is published: for rectified input set rectify_mode:=pass_through (~rectify/mode "
         "pass_through)";
  } else if (mode_ == RectifyMode::kPassThrough && published("left/image_raw")) {
    m << "; " << nh_.resolveName("left/image_raw")
      << " is published: for raw input set rectify_mode:=calibrated (with camera_info) or "
         "uncalibrated";
  } else if (ours) {
    m << "; the topics are advertised but send nothing: is the source paused (rosbag play "
         "--pause, a stopped /clock) or on another image_transport (~image_transport "
      << ros_params_.image_transport << ")?";
  } else {
    m << "; nothing publishes them: remap " << left_topic_ << " and " << right_topic_
      << " to the camera's topics (endo_stereo.launch: left_image:=..., right_image:=...)";
  }
  return m.str();
}

void Reconstruction::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  const ros::WallTime now = ros::WallTime::now();
  // Silence: subscribed, and no image on either side for no_input_warn_s.
  double silent_s = 0.0;
  {
    std::lock_guard<std::mutex> lock(info_mutex_);
    const ros::WallTime last =
        std::max(subscribed_since_, std::max(last_left_arrival_, last_right_arrival_));
    if (subscribed_.load() && !last.isZero()) silent_s = (now - last).toSec();
  }
  const bool silent = silent_s > ros_params_.no_input_warn_s;
  if (silent) {
    // The explanation asks the master: at most every 5 s; the log repeats every 30 s.
    if (silence_message_.empty() || (now - silence_explained_).toSec() > 5.0) {
      silence_message_ = explainSilence(silent_s);
      silence_explained_ = now;
    }
    if (silence_logged_.isZero() || (now - silence_logged_).toSec() > 30.0) {
      ROS_WARN("%s: %s", name_.c_str(), silence_message_.c_str());
      silence_logged_ = now;
    }
  } else {
    silence_message_.clear();
    silence_logged_ = ros::WallTime();
  }
  size_t waiting = 0;
  {
    std::lock_guard<std::mutex> backlog_lock(backlog_mutex_);
    waiting = backlog_.size();
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  const ReconstructionCounters& c = counters_;
  const double dt = std::max(1e-6, (now - diag_prev_time_).toSec());
  const double in_rate = (c.pairs_received - diag_prev_.pairs_received) / dt;
  const double out_rate = (c.pairs_processed - diag_prev_.pairs_processed) / dt;
  const int64_t new_drops = c.pairs_dropped - diag_prev_.pairs_dropped;
  const int64_t new_rejects = c.pairs_rejected - diag_prev_.pairs_rejected;
  const std::vector<double> lat(latencies_ms_.begin(), latencies_ms_.end());
  const std::vector<double> pipe(pipeline_ms_.begin(), pipeline_ms_.end());
  const bool subscribed = subscribed_.load();
  const std::string frozen = frozen_views_->message();
  std::string step_state = "off (~step_check_period_frames 0)", step_offset = "unknown";
  bool out_of_step = false;
  {
    std::lock_guard<std::mutex> step_lock(step_mutex_);
    if (step_) {
      step_state = step_->describe();
      if (step_->verdictKnown()) {
        step_offset = std::to_string(step_->offset());
        out_of_step = step_->offset() != 0;
      }
    }
  }

  if (!subscribed) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "idle: no subscribers to the outputs");
  } else if (new_rejects > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "input rejected: " + last_error_);
  } else if (!frozen.empty()) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, frozen);
  } else if (out_of_step) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "views " + step_state);
  } else if (silent) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no input: " + silence_message_);
  } else if (new_drops > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 "overloaded: " + std::to_string(new_drops) + " pairs dropped");
  } else if (last_quality_.valid && last_quality_.warning) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "rectification residual high");
  } else if (last_quality_.misaligned) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 "rectification: no row alignment found: " + last_quality_.message);
  } else if (c.pairs_received == diag_prev_.pairs_received &&
             (c.left_images != diag_prev_.left_images || c.right_images != diag_prev_.right_images)) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "images do not pair: " + last_error_);
  } else {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "ok");
  }
  stat.add("inputs subscribed", subscribed);
  stat.add("seconds without input", silent_s);
  stat.add("input pair rate (Hz)", in_rate);
  stat.add("output rate (Hz)", out_rate);
  stat.add("left images", c.left_images);
  stat.add("right images", c.right_images);
  stat.add("pairs received", c.pairs_received);
  stat.add("pairs processed", c.pairs_processed);
  stat.add("pairs dropped", c.pairs_dropped);
  stat.add("pairs rejected", c.pairs_rejected);
  stat.add("pairs waiting", static_cast<int>(waiting));
  stat.add("stream restarts", c.restarts);
  stat.add("tf failures", c.tf_failures);
  stat.add("pairs withheld (frozen view)", c.pairs_frozen);
  stat.add("geometry changes", c.geometry_changes);
  stat.add("temporal resets", c.temporal_resets);
  stat.add("last temporal reset", last_reset_reason_);
  stat.add("frames since temporal reset", frames_since_reset_);
  stat.add("left view unchanged (pairs)", frozen_views_->unchangedRun(true));
  stat.add("right view unchanged (pairs)", frozen_views_->unchangedRun(false));
  stat.add("right frame offset", step_offset);
  stat.add("views in step", step_state);
  stat.add("latency median (ms)", percentile(lat, 0.5));
  stat.add("latency p90 (ms)", percentile(lat, 0.9));
  // The core's share of the latency (Pipeline::process); the rest is waiting in the backlog,
  // conversions and publishing.
  stat.add("pipeline median (ms)", percentile(pipe, 0.5));
  stat.add("density", last_density_);
  stat.add("priors used", last_priors_used_);
  {
    // What the last frame searched: narrowed around priors, the full range, or nothing yet
    // (deferred: TemporalParams::full_range_period_frames).
    const TemporalPriorStats& ps = last_prior_stats_;
    const double n = double(ps.narrowed_pixels + ps.full_range_pixels + ps.deferred_pixels);
    stat.add("pixels narrowed by priors (share)", n > 0 ? double(ps.narrowed_pixels) / n : 0.0);
    stat.add("pixels deferred (share)", n > 0 ? double(ps.deferred_pixels) / n : 0.0);
  }
  stat.add("rectification residual median (px)",
           last_quality_.valid ? last_quality_.median_offset_px : std::nan(""));
  stat.add("rectification residual p90 (px)",
           last_quality_.valid ? last_quality_.p90_offset_px : std::nan(""));
  stat.add("last error", last_error_);
  diag_prev_ = c;
  diag_prev_time_ = now;
}

}  // namespace endo_stereo
