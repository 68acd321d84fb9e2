/**
 * @file reconstruction.hpp
 * @brief The ROS side of endo_stereo: synchronise a stereo pair, run the core Pipeline, publish
 * disparity, points2 and the optional outputs, with diagnostics.
 *
 * Topics (relative to the node handle given; remap as usual):
 * - In, by RectifyParams::mode: calibrated: `left/image_raw`, `right/image_raw`,
 *   `left/camera_info`, `right/camera_info`; pass_through (already rectified): `left/image_rect`,
 *   `right/image_rect` and the two camera_info (used for f and T; optional when
 *   rectify.focal_px and rectify.baseline_m are set); uncalibrated: the two image_raw only.
 *   Images come through image_transport (`~image_transport`), paired by ExactTime or
 *   ApproximateTime synchronisation (`~approximate_sync`, `~sync_tolerance_s`); camera_info is
 *   taken as the latest one received per side, so a missing camera_info is reported instead of
 *   silently stalling a four-way synchroniser.
 * - Out: `disparity` (stereo_msgs/DisparityImage), `points2` (sensor_msgs/PointCloud2,
 *   organized), `disparity_color` (bgr8 picture of the disparity for rviz and people, colour
 *   scale = the search range, invalid black), `confidence` (32FC1, [0, 1]), `disparity_fused`
 *   (DisparityImage), `coverage` (16UC1, longest run of frames without an update), and, where the
 *   node rectifies (calibrated and uncalibrated modes), `left/image_rect_color` (bgr8) and
 *   `right/image_rect` (mono8); and /diagnostics.
 * - Out, RGB-D (names as an RGB-D camera publishes them), where the geometry is metric and not
 *   polar: `depth/image_rect` (32FC1, metres, Z = f T / d of `disparity`, NaN where there is no
 *   value) with `depth/camera_info` (the left rectified view: K and P, R identity, no distortion,
 *   the depth image's size), `rgb/image_rect_color` (bgr8, the left rectified colour image, pixel
 *   for pixel aligned with the depth) with `rgb/camera_info` (the same), and
 *   `depth_fused/image_rect` with `depth_fused/camera_info` (from `disparity_fused`). All in the
 *   left rectified optical frame, stamped as the pair, at the size of `disparity` (after
 *   downsampling).
 * - No topic is both an input and an output: pass_through mode, whose inputs are the rectified
 *   images, publishes no rectified images (they would be its own input), and an output whose
 *   resolved name equals an input's (after remapping) is not advertised, with a warning.
 *
 * Behaviour:
 * - Lazy: the inputs are subscribed only while some output has a subscriber.
 * - Silence is reported: while an output has subscribers and no image has arrived on either
 *   input for `~no_input_warn_s`, a warning (log, throttled, and diagnostics WARN) names the
 *   topics listened to and the likely fix (e.g. `rectify_mode:=pass_through` when `image_rect`
 *   topics are published in the namespace).
 * - Bounded: one processing thread takes the pairs from a backlog of at most `~backlog_pairs`.
 *   While it keeps up with the input (median processing time of the last 8 pairs below the
 *   median interval between pairs; always for the first 10 pairs) it takes them in order, so a
 *   short stall such as the first frame's full-range search is caught up without loss; a pair
 *   that waited longer than `~backlog_max_age_s` is skipped. When frames come faster than they
 *   are processed it takes the newest and skips the others. Pairs pushed out of a full backlog
 *   or skipped are counted as dropped. Nothing queues without limit. This policy, its counters,
 *   the stamp order and the silence and unpaired-image reports are FrameScheduler's
 *   (core/frame_scheduler.hpp), which this class drives under one mutex.
 * - Bad input (sizes, encodings, camera_info, stamps) is reported by a throttled error naming the
 *   problem, counted as rejected, and the next good pair is processed.
 * - A frozen camera (a view whose image is bit-identical to its previous one for
 *   `~freeze_frames` consecutive pairs) stops the output: its pairs are withheld and counted, a
 *   WARN (log, throttled, and diagnostics) names the camera, and the first pair whose view changed
 *   again is matched after a reset of the temporal state (frozen_views.hpp).
 * - Views out of step (two capture cards a frame apart): at start, after every temporal reset
 *   and every `~step_check_period_frames` pairs, consecutive pairs are checked for whether left
 *   frame t matches right frame t-1, t or t+1 best (FrameOffsetDetector, on downsampled images);
 *   another offset than 0 is a WARN (log, and diagnostics while it holds) with the offset in
 *   frames. A still scene gives no verdict.
 * - A new camera_info (values or size) or a new image size mid-stream rebuilds the rectification
 *   and resets the temporal state (priors, fusion, coverage) before the first pair of the new
 *   geometry, logged once per change; each output is computed from one geometry. camera_info is
 *   the latest received per side: a pair whose images and camera_info disagree in size is refused.
 * - New pipeline parameters (dynamic_reconfigure) are validated when given and swapped in between
 *   two frames.
 *
 * Thread safety: setPipelineParams(), pipelineParams() and counters() may be called from any
 * thread; the class owns one processing thread and ROS callbacks run on the caller's callback
 * queues.
 *
 * Sources, one per concern: reconstruction.cpp (construction, the callbacks, the processing
 * thread), reconstruction_inputs.cpp (lazy subscription, camera_info, the checks of a pair),
 * reconstruction_outputs.cpp (advertising and publishing), reconstruction_diagnostics.cpp
 * (/diagnostics and the silence explanation), reconstruction_step_check.cpp (views out of step).
 */
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <image_transport/subscriber_filter.h>
#include <message_filters/sync_policies/approximate_time.h>
#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include "endo_stereo/core/frame_offset_detector.hpp"
#include "endo_stereo/core/frame_scheduler.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/core/view_offset.hpp"
#include "endo_stereo/ros/frozen_views.hpp"
#include "endo_stereo/ros/ros_params.hpp"

namespace endo_stereo {

/// Running totals since start (all counters monotonic).
struct ReconstructionCounters {
  int64_t left_images = 0;      ///< left images received
  int64_t right_images = 0;     ///< right images received
  int64_t pairs_received = 0;   ///< pairs formed by the synchroniser
  int64_t pairs_processed = 0;  ///< pairs processed and published
  int64_t pairs_dropped = 0;    ///< pairs pushed out of the backlog or skipped as stale (overload)
  int64_t pairs_rejected = 0;   ///< pairs refused (bad input, pipeline error, out of order)
  int64_t restarts = 0;         ///< stream restarts (time jumped back more than restart_jump_back_s)
  int64_t tf_failures = 0;      ///< clouds not published for lack of the target_frame transform
  int64_t pairs_frozen = 0;     ///< pairs withheld because a view was frozen (~freeze_frames)
  int64_t geometry_changes = 0; ///< new camera_info or image size mid-stream (maps rebuilt)
  int64_t temporal_resets = 0;  ///< frames whose temporal state was reset first (any reason)
};

class Reconstruction {
 public:
  /**
   * @param nh      namespace of the topics (the stereo namespace).
   * @param pnh     private namespace (diagnostics, transport hints).
   * @param name    name used in log messages (the nodelet's name).
   * @throws std::invalid_argument when either params struct fails validate().
   */
  Reconstruction(const ros::NodeHandle& nh, const ros::NodeHandle& pnh, const std::string& name,
                 const RosParams& ros_params, const PipelineParams& params);
  ~Reconstruction();
  Reconstruction(const Reconstruction&) = delete;
  Reconstruction& operator=(const Reconstruction&) = delete;

  /// Validate @p params and, when valid, use them from the next frame on.
  /// @return "" when accepted, else the validation message (current parameters kept).
  /// A change of rectify.mode is refused here (it changes the input topics): restart the nodelet.
  std::string setPipelineParams(const PipelineParams& params);
  /// The parameters in use (or pending for the next frame).
  PipelineParams pipelineParams() const;
  const RosParams& rosParams() const { return ros_params_; }
  ReconstructionCounters counters() const;
  /// Whether the inputs are currently subscribed (lazy subscription).
  bool inputsSubscribed() const;
  /// One line for the start-up log: input topics, rectify mode, synchronisation, disparity range
  /// and the outputs advertised.
  std::string describe() const;

 private:
  struct Pair {
    sensor_msgs::ImageConstPtr left, right;
    sensor_msgs::CameraInfoConstPtr left_info, right_info;
    ros::WallTime arrival;
  };
  /// Throttle period of input error messages, s: often enough to notice, rare enough for a flood.
  static constexpr double kThrottleS = 5.0;

  void connectCb();
  void subscribeInputs();
  void unsubscribeInputs();
  void imageCb(bool left, const sensor_msgs::ImageConstPtr& msg);
  void pairCb(const sensor_msgs::ImageConstPtr& left, const sensor_msgs::ImageConstPtr& right);
  void infoCb(bool left, const sensor_msgs::CameraInfoConstPtr& msg);
  void workerLoop();
  /// @return true when the pair was processed and published, false when it was rejected.
  bool processPair(const Pair& pair);
  /// A new temporal state: the pipeline's reset, the out-of-step check restarted, the frame count.
  void resetTemporalState();
  /// Hands parameters set since the last frame (setPipelineParams) to the pipeline.
  void applyPendingParams();
  /// Turns the pipeline's optional outputs on or off by configuration and subscribers.
  void selectOutputs();
  /// Outputs go in stamp order: @return false (rejected) for a pair not after the last processed
  /// one; time that went back far enough is a new stream (temporal state reset).
  bool checkStampOrder(const ros::Time& stamp);
  /// Hands a pair's calibration (camera_info) to the pipeline when it is new; @return false
  /// (rejected) when the pipeline refuses it.
  bool applyCalibration(const Pair& pair);
  /// The pipeline's input: views of the pair's images; @return false (rejected) when one cannot
  /// be read.
  bool stereoInput(const Pair& pair, StereoInput* in);
  /// After a processed pair stamped @p stamp: its stamp to the scheduler, a reset noted.
  void noteProcessed(const ros::Time& stamp);
  /// The figures of a processed pair for the diagnostics (latency, density, quality, priors), and
  /// the first pair's timings to the log.
  void recordFigures(const Pair& pair, const ros::WallTime& t_process,
                     const ros::WallTime& t_publish, const ros::WallTime& t_done);
  /// ~right_frame_offset: re-pairs the views (view_offset_); @return false when the pair is held
  /// (counted as withheld), true with @p pair holding the views to match.
  bool compensateOffset(Pair& pair);
  /// Checks a formed pair for a frozen view (frozen_views_); @return true when it is withheld.
  bool withholdFrozen(const Pair& pair);
  /// Feeds a formed pair to the out-of-step check (step_); logs a verdict that changed.
  void checkStep(const Pair& pair);
  /// A new stream (@p forget: the verdict too) or a reset temporal state (the verdict holds until
  /// the new check gives one): the out-of-step check starts again.
  void restartStepCheck(bool forget);
  /// After a frame (stamped @p stamp) whose temporal state was reset: count it, and log a
  /// geometry change once.
  void noteTemporalReset(const ros::Time& stamp);
  static std::string describeCalibrationChange(const StereoCalibration& before,
                                               const StereoCalibration& after);
  bool checkPair(const Pair& pair, std::string* error);
  void publishOutputs(const Pair& pair, const PipelineOutput& out);
  /// depth/*, rgb/*, depth_fused/* (only with subscribers; withheld with a warning when
  /// @p depth_ok is false).
  void publishRgbd(const std_msgs::Header& header, const PipelineOutput& out,
                   const RectifiedGeometry& g, bool depth_ok);
  /// Logs (throttled) and keeps as the last error a refused pair; the caller counts it.
  void reject(const std::string& what, const std::string& error);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);
  bool needsCameraInfo() const;
  /// Fills a pair's missing camera_info with the latest one, waiting up to camera_info_wait_s.
  void awaitCameraInfo(Pair& pair);
  bool usesCameraInfo() const;
  /// Advertises the outputs, leaving out those that would be an input (see the file comment).
  void advertiseOutputs();
  /// Why nothing arrives (diagnose(), no image for no_input_warn_s): the topics listened to and
  /// a likely fix from the topics published in the namespace (asks the master).
  std::string explainSilence(double silent_s) const;

  ros::NodeHandle nh_, pnh_;
  std::string name_;
  const RosParams ros_params_;
  RectifyMode mode_;  // fixed at construction (decides the input topics)
  std::string left_topic_, right_topic_;

  // --- Inputs (guarded by connect_mutex_ for (un)subscription).
  image_transport::ImageTransport it_;
  image_transport::SubscriberFilter left_sub_, right_sub_;
  ros::Subscriber left_info_sub_, right_info_sub_;
  using ExactPolicy =
      message_filters::sync_policies::ExactTime<sensor_msgs::Image, sensor_msgs::Image>;
  using ApproxPolicy =
      message_filters::sync_policies::ApproximateTime<sensor_msgs::Image, sensor_msgs::Image>;
  std::unique_ptr<message_filters::Synchronizer<ExactPolicy>> exact_sync_;
  std::unique_ptr<message_filters::Synchronizer<ApproxPolicy>> approx_sync_;
  mutable std::mutex connect_mutex_;
  std::atomic<bool> subscribed_{false};  // written under connect_mutex_, read by diagnostics

  // --- Outputs (a publisher left unadvertised publishes nothing and has no subscribers).
  ros::Publisher pub_disparity_, pub_points_, pub_fused_;
  image_transport::Publisher pub_disparity_color_, pub_confidence_, pub_coverage_, pub_left_rect_, pub_right_rect_;
  image_transport::CameraPublisher pub_depth_, pub_rgb_, pub_depth_fused_;  // image + camera_info
  std::vector<std::string> outputs_;  // the outputs advertised (relative names), for describe()
  std::string outputs_note_;          // why some were not advertised ("" when all were)

  // --- Latest camera_info per side (info_mutex_).
  mutable std::mutex info_mutex_;
  std::condition_variable info_cv_;  // a camera_info arrived, or shutting down
  bool info_stopping_ = false;
  sensor_msgs::CameraInfoConstPtr left_info_, right_info_;

  // --- The scheduler (sched_mutex_): image arrivals, the bounded backlog between the callbacks
  // and the processing thread, the drop policy and its counters, stamp order, silence.
  mutable std::mutex sched_mutex_;
  std::condition_variable sched_cv_;  // a pair waits, or shutting down
  FrameScheduler<Pair> scheduler_;
  bool shutdown_ = false;
  std::thread worker_;

  // --- Parameters (params_mutex_): current and pending (swapped in between frames).
  mutable std::mutex params_mutex_;
  PipelineParams params_;
  bool params_pending_ = false;

  // --- Processing state (worker thread only).
  std::unique_ptr<Pipeline> pipeline_;
  PipelineOutput out_;
  StereoCalibration calibration_;
  bool has_calibration_ = false;
  bool warned_not_metric_ = false;
  bool warned_no_depth_ = false;  // the RGB-D outputs were withheld (geometry not metric)
  cv::Mat depth_;                 // depth image buffer, reused between frames
  bool first_pair_logged_ = false;  // the first pair's timings went to the log
  std::string geometry_change_;     // a camera_info change not yet logged (describeCalibrationChange)

  // --- Figures (stats_mutex_); the pair counts are the scheduler's.
  mutable std::mutex stats_mutex_;
  int64_t tf_failures_ = 0, geometry_changes_ = 0, temporal_resets_ = 0;
  std::deque<double> latencies_ms_;  // latest latencies, arrival -> published
  std::deque<double> pipeline_ms_;   // latest Pipeline::process() times
  double last_density_ = 0.0;
  RectificationQuality last_quality_;
  bool last_priors_used_ = false;
  int64_t frames_since_reset_ = 0;       // frames matched since the temporal state began (start or reset)
  TemporalPriorStats last_prior_stats_;  // the last processed frame's search ranges
  std::string last_error_;
  std::string last_reset_reason_;  // why the temporal state was last reset
  ros::WallTime last_error_time_;
  ReconstructionCounters diag_prev_;
  ros::WallTime diag_prev_time_;
  // Silence (diagnostics thread only): the last explanation (FrameScheduler says when it is due).
  std::string silence_message_;

  // --- Frozen cameras: checked on every pair formed (callback threads); a freeze that ended asks
  // the processing thread for a temporal reset before its next pair.
  std::unique_ptr<FrozenViews> frozen_views_;
  /// One view of a pair, as ~right_frame_offset re-pairs them.
  struct View {
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CameraInfoConstPtr info;
  };
  std::mutex offset_mutex_;  // guards view_offset_ (pair callbacks)
  ViewOffset<View> view_offset_;
  std::atomic<bool> temporal_reset_pending_{false};

  // --- Views out of step: every formed pair goes to the check (callback threads; step_mutex_),
  // which evaluates consecutive pairs only while a check runs. Null when off.
  mutable std::mutex step_mutex_;
  std::unique_ptr<FrameOffsetDetector> step_;
  int step_warned_offset_ = 0;  // the offset last warned about (0: none, or back in step)
  ros::WallTime step_warned_;   // when (a confirmed offset is warned again at most every 30 s)

  // --- tf2 (only with a target_frame).
  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;

  // --- Diagnostics.
  diagnostic_updater::Updater updater_;
  ros::WallTimer diag_timer_;
};

}  // namespace endo_stereo
