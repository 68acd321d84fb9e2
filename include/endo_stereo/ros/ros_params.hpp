/**
 * @file ros_params.hpp
 * @brief The nodelet's own settings (RosParams) and the one path config/<preset>.yaml -> ROS parameters
 * -> core structs (one path from YAML to the structs).
 *
 * Pipeline parameters live under the node's private namespace with the keys of params_io.hpp,
 * `section.field` written as `~section/field` (`~matcher/delta_min`), which is what
 * `<rosparam command="load" file="config/default.yaml"/>` produces from a preset. A YAML preset
 * can also be named by `~config_file` (loaded first, then the individual parameters on top).
 * The nodelet's own settings are `~<name>` (`~queue_size`, `~approximate_sync`, as stereo_image_proc names them); a
 * preset's `ros:` section (`~ros/<name>`) is read too, with `~<name>` taking precedence.
 *
 * Thread safety: the functions are reentrant; they read the parameter server only.
 */
#pragma once

#include <string>
#include <vector>

#include <ros/node_handle.h>

#include "endo_stereo/core/frame_scheduler.hpp"
#include "endo_stereo/core/pipeline.hpp"

namespace endo_stereo {

/// Settings of the ROS layer (not pipeline parameters). Defaults in the struct.
struct RosParams {
  /// Subscriber and synchroniser queue length, messages, in [1, 100]. Bounds memory: a late
  /// image is dropped by the synchroniser, never queued without limit.
  int queue_size = 5;
  /// Pairs waiting for the processing thread, in [1, 100]. A pair arriving while this many wait
  /// pushes out the oldest (counted as dropped). 1 = only the newest pair waits; more lets a short
  /// stall (the first frame, which searches the full disparity range, takes two to three frame
  /// periods) be caught up instead of losing the pairs that came during it. While frames come
  /// faster than they are processed only the newest is taken whatever this is (reconstruction.hpp).
  int backlog_pairs = 3;
  /// A waiting pair older than this (since it was paired) is skipped, counted as dropped, when a
  /// newer pair waits too: the most latency a catch-up may add. s, in (0, 10]. At 25 fps a
  /// backlog of 3 already bounds the wait at about 4 frame periods (160 ms); 0.25 s lets it
  /// catch up the start-up stall without skipping pairs, and bounds the wait of slower streams.
  /// (0.15 s skipped 2 pairs in 2 of 4 30-frame runs at 25 fps, where the wait reached 150 ms.)
  double backlog_max_age_s = 0.25;
  /// Pair images by ApproximateTime (true) or ExactTime (false) synchronisation.
  bool approximate_sync = false;
  /// ApproximateTime only: largest stamp difference accepted within a pair, s, in (0, 1].
  double sync_tolerance_s = 0.01;
  /// image_transport transport of the inputs ("raw", "compressed", ...).
  std::string image_transport = "raw";
  /// Publish points2 in this frame (tf2 lookup at the pair's stamp); "" = the left rectified
  /// optical frame.
  std::string target_frame;
  /// Longest wait for the target_frame transform, s, in [0, 10].
  double tf_timeout_s = 0.05;
  /// Frame of the outputs when the input has none (uncalibrated input, empty frame_id); also
  /// overrides the camera_info frame when not empty.
  std::string frame_id;
  /// Diagnostics period, s, in [0.05, 60].
  double diagnostics_period_s = 1.0;
  /// Report images of one side arriving without a partner after this long, s, in (0, 60].
  double unpaired_timeout_s = 1.0;
  /// Calibrated input: a pair that finds no camera_info of one side yet waits this long for it
  /// before it is refused, s, in [0, 10]. At start-up the image connections can come up before
  /// the camera_info ones (rosbag play, a driver starting its publishers one by one).
  double camera_info_wait_s = 0.5;
  /// A pair whose stamp is older than the last processed one by less than this is dropped as
  /// out of order; a larger jump back (a looping bag, a restarted driver) restarts the stream.
  /// s, in [0, 3600].
  double restart_jump_back_s = 1.0;
  /// Disparity resolution written to DisparityImage::delta_d when sub-pixel refinement is on, px,
  /// in (0, 1]; with it off, delta_d is 1 (integer peaks). The parabola fit gives continuous
  /// values, so what can be defended is its precision: on the synthetic surgical scene at
  /// endoscope scale (test_nodelet_synthetic) |d - d_true| of the accepted, non-bad pixels was
  /// median 0.05-0.06 px, RMS 0.09-0.16 px across matcher versions; 0.1 px is that precision,
  /// not a quantisation step (SGBM's 1/16 px is one). The test fails if the RMS exceeds 2 x this.
  double subpixel_delta_d = 0.1;
  /// While an output has subscribers and no image has arrived on either input for this long, a
  /// warning (log and diagnostics) names the topics listened to and the likely fix, s, in (0, 3600].
  double no_input_warn_s = 5.0;
  /// A view whose image is bit-identical to its previous one for this many consecutive pairs is
  /// frozen (a capture card re-sending its last frame under new stamps): its pairs are not
  /// matched, with a warning naming the camera, until its image changes again. A live camera
  /// never repeats an image exactly (sensor noise), even on a still scene. In [0, 1000];
  /// 0 = off. 10 = 0.4 s at 25 fps.
  int freeze_frames = 10;
  /// Pairs between two checks that the views are in step (left frame t matches right frame t
  /// better than right t-1 or t+1 on a moving scene; frame_offset_detector.hpp); a check also runs
  /// at start and after every temporal reset, and lasts up to 50 pairs. A view found out of step
  /// is warned about (log and diagnostics) with its offset in frames. In [0, 100000]; 0 = off;
  /// values below 50 mean 50. 250 = 10 s at 25 fps.
  int step_check_period_frames = 250;
  /// Compensation of views out of step by a constant number of frames (view_offset.hpp): the
  /// left image of each pair is matched with the right image that arrives this many pairs later
  /// (< 0: earlier). Set it to the offset the out-of-step check reports. The output keeps the
  /// left image's stamp. In [-5, 5]; 0 = off.
  int right_frame_offset = 0;
  /// Name of the preset the parameters came from, for the start-up line only (the launch files
  /// set it to the YAML file they load; "" = none named).
  std::string preset;

  /// @return "" when valid, else a message naming the field and its accepted range.
  std::string validate() const;
  /// The frame scheduler's share of these settings (backlog, stamp order, unpaired, silence).
  FrameSchedulerParams scheduler() const;
};

/**
 * Fill @p params from the private namespace of @p pnh: `~config_file` (a YAML preset, loaded on
 * top of what @p params holds), then every `~section/field` present. Unknown keys under a
 * pipeline section (`~matcher/typo`) are errors, so a misspelt parameter is not ignored silently.
 * @return "" on success, else a message naming the parameter; @p params unchanged on error.
 * Does not call validate().
 */
std::string loadPipelineParamsFromRos(const ros::NodeHandle& pnh, PipelineParams& params);

/// Fill @p params from `~ros/<name>` then `~<name>`. @return "" or a message naming the parameter.
std::string loadRosParams(const ros::NodeHandle& pnh, RosParams& params);

/// The names loadRosParams() reads (each as `~<name>` and `~ros/<name>`), in a fixed order.
std::vector<std::string> rosParamNames();

/// Write @p params into the private namespace as `~section/field` (so `rosparam get` shows the
/// parameters in use): every one, or with @p previous only those that differ from it (after a
/// reconfigure).
void storePipelineParamsToRos(const ros::NodeHandle& pnh, const PipelineParams& params,
                              const PipelineParams* previous = nullptr);

}  // namespace endo_stereo
