// The ROS side of endo_stereo: construction, the input callbacks and the processing thread.
// See reconstruction.hpp for topics, behaviour and the other sources.
#include "endo_stereo/ros/reconstruction.hpp"

#include <algorithm>
#include <sstream>
#include <stdexcept>

#include <boost/bind/bind.hpp>

namespace endo_stereo {
namespace {

// The scheduler's parameters; a RosParams that fails validate() throws its message (the first
// invalid ROS parameter, as before the scheduler was built).
FrameSchedulerParams schedulerParams(const RosParams& p) {
  const std::string e = p.validate();
  if (!e.empty()) throw std::invalid_argument(e);
  return p.scheduler();
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
      scheduler_(schedulerParams(ros_params)),
      params_(params),
      view_offset_(ros_params.right_frame_offset),
      updater_(nh, pnh, name) {
  const std::string e = params.validate();
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
    std::lock_guard<std::mutex> lock(sched_mutex_);
    shutdown_ = true;
  }
  sched_cv_.notify_all();
  {
    std::lock_guard<std::mutex> lock(info_mutex_);
    info_stopping_ = true;
  }
  info_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
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
  UnpairedReport r;
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    r = scheduler_.imageArrived(left ? StereoSide::kLeft : StereoSide::kRight,
                                msg->header.stamp.toSec(), now.toSec());
  }
  if (r.kind == UnpairedReport::Kind::kNone) return;
  std::ostringstream m;
  m.precision(6);
  m << std::fixed;
  if (r.kind == UnpairedReport::Kind::kPartnerMissing) {
    m << (left ? "left" : "right") << " images arrive without a " << (left ? "right" : "left")
      << " image for " << r.waiting_s << " s: check the "
      << nh_.resolveName(left ? right_topic_ : left_topic_) << " topic";
  } else {
    m << "left and right images arrive but do not pair (last stamps: left " << r.left_stamp_s
      << ", right " << r.right_stamp_s << "); "
      << (ros_params_.approximate_sync
              ? "their stamps differ by more than ~sync_tolerance_s"
              : "exact synchronisation needs equal stamps (or set ~approximate_sync true)");
  }
  ROS_ERROR_THROTTLE(kThrottleS, "%s: %s", name_.c_str(), m.str().c_str());
  std::lock_guard<std::mutex> lock(stats_mutex_);
  last_error_ = m.str();
  last_error_time_ = now;
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
  }
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    scheduler_.pairFormed();
  }
  if (!compensateOffset(pair)) return;
  checkStep(pair);
  if (withholdFrozen(pair)) return;
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    const double arrival_s = pair.arrival.toSec();
    scheduler_.push(std::move(pair), arrival_s);
  }
  sched_cv_.notify_one();
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
  ReconstructionCounters c;
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    const FrameSchedulerCounters s = scheduler_.counters();
    c.left_images = s.left_images;
    c.right_images = s.right_images;
    c.pairs_received = s.pairs_received;
    c.pairs_processed = s.pairs_processed;
    c.pairs_dropped = s.pairs_dropped;
    c.pairs_rejected = s.pairs_rejected;
    c.restarts = s.restarts;
    c.pairs_frozen = s.pairs_withheld;
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  c.tf_failures = tf_failures_;
  c.geometry_changes = geometry_changes_;
  c.temporal_resets = temporal_resets_;
  return c;
}

// ------------------------------------------------------------------------------------------------
// Processing thread
// ------------------------------------------------------------------------------------------------

void Reconstruction::workerLoop() {
  for (;;) {
    Pair pair;
    {
      // The scheduler picks the pair: the oldest while the node keeps up, the newest when frames
      // come faster than they are processed (frame_scheduler.hpp).
      std::unique_lock<std::mutex> lock(sched_mutex_);
      sched_cv_.wait(lock, [this] { return shutdown_ || scheduler_.waiting() > 0; });
      if (shutdown_) return;
      scheduler_.next(ros::WallTime::now().toSec(), &pair);
    }
    try {
      if (needsCameraInfo() && (!pair.left_info || !pair.right_info)) awaitCameraInfo(pair);
      const ros::WallTime t0 = ros::WallTime::now();
      const bool processed = processPair(pair);
      const double busy_s = (ros::WallTime::now() - t0).toSec();
      std::lock_guard<std::mutex> lock(sched_mutex_);
      scheduler_.finished(processed ? PairOutcome::kProcessed : PairOutcome::kRejected, busy_s);
    } catch (const std::exception& ex) {
      // The pipeline promises not to throw on bad input; this is the last line of defence that
      // keeps the nodelet (and the manager's other nodelets) alive if something does.
      reject("pair", std::string("unexpected exception: ") + ex.what());
      std::lock_guard<std::mutex> lock(sched_mutex_);
      scheduler_.failed();
    }
  }
}

void Reconstruction::reject(const std::string& what, const std::string& error) {
  ROS_ERROR_THROTTLE(kThrottleS, "%s: %s rejected: %s", name_.c_str(), what.c_str(),
                     error.c_str());
  std::lock_guard<std::mutex> lock(stats_mutex_);
  last_error_ = error;
  last_error_time_ = ros::WallTime::now();
}

void Reconstruction::noteTemporalReset(const ros::Time& stamp) {
  // A geometry change (new camera_info, or new image size) is said once, with what the pipeline
  // did about it; time-based resets (gaps, a stream restart) are counted only.
  const bool size_changed = out_.reset_reason.find("size changed") != std::string::npos;
  if (!geometry_change_.empty() || size_changed) {
    const std::string what = !geometry_change_.empty() ? geometry_change_ : "images changed size";
    ROS_INFO("%s: %s: rectification rebuilt, temporal state reset (%s); outputs from %.6f s on "
             "use the new geometry only",
             name_.c_str(), what.c_str(), out_.reset_reason.c_str(), stamp.toSec());
    geometry_change_.clear();
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++geometry_changes_;
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++temporal_resets_;
  last_reset_reason_ = out_.reset_reason;
}

bool Reconstruction::compensateOffset(Pair& pair) {
  if (view_offset_.offset() == 0) return true;
  View left{pair.left, pair.left_info}, right{pair.right, pair.right_info};
  bool ready = false;
  {
    std::lock_guard<std::mutex> lock(offset_mutex_);
    ready = view_offset_.push(pair.left->header.stamp.toSec(), left, right);
  }
  if (!ready) {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    scheduler_.withhold();
    return false;
  }
  pair.left = left.image;
  pair.left_info = left.info;
  pair.right = right.image;
  pair.right_info = right.info;
  return true;
}

bool Reconstruction::withholdFrozen(const Pair& pair) {
  const FrozenViews::Verdict v = frozen_views_->check(*pair.left, *pair.right);
  if (v.resumed) temporal_reset_pending_ = true;
  if (!v.withhold) return false;
  std::lock_guard<std::mutex> lock(sched_mutex_);
  scheduler_.withhold();
  return true;
}

void Reconstruction::resetTemporalState() {
  pipeline_->reset();
  restartStepCheck(false);
  std::lock_guard<std::mutex> lock(stats_mutex_);
  frames_since_reset_ = 0;
}

void Reconstruction::applyPendingParams() {
  std::lock_guard<std::mutex> lock(params_mutex_);
  if (!params_pending_) return;
  params_pending_ = false;
  try {
    pipeline_->setParams(params_);
  } catch (const std::invalid_argument& ex) {
    ROS_ERROR("%s: new parameters refused by the pipeline: %s", name_.c_str(), ex.what());
  }
}

void Reconstruction::noteProcessed(const ros::Time& stamp) {
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    scheduler_.stampProcessed(stamp.toSec());
  }
  if (!out_.priors_reset) return;
  noteTemporalReset(stamp);
  // A new geometry or a stream that went back in time may come with re-synchronised views:
  // check again. A gap between processed frames (pairs dropped here, a stall) is not news about
  // the views' synchronisation.
  if (out_.reset_reason.find("gap of") == std::string::npos) restartStepCheck(false);
}

bool Reconstruction::processPair(const Pair& pair) {
  // A frozen view came back: what was matched before the freeze was found paired a stale view.
  if (temporal_reset_pending_.exchange(false)) resetTemporalState();
  applyPendingParams();  // parameters change only here, between two frames
  selectOutputs();
  const ros::Time stamp = pair.left->header.stamp;
  if (!checkStampOrder(stamp)) return false;
  std::string error;
  if (!checkPair(pair, &error)) {
    reject("pair", error);
    return false;
  }
  if (!applyCalibration(pair)) return false;
  StereoInput in;
  if (!stereoInput(pair, &in)) return false;
  const ros::WallTime t_process = ros::WallTime::now();
  if (!pipeline_->process(in, out_, &error)) {
    reject("pair", error);
    return false;
  }
  noteProcessed(stamp);
  const ros::WallTime t_publish = ros::WallTime::now();
  publishOutputs(pair, out_);
  const ros::WallTime t_done = ros::WallTime::now();
  recordFigures(pair, t_process, t_publish, t_done);
  return true;
}

}  // namespace endo_stereo
