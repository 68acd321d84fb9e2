/**
 * @file pipeline.hpp
 * @brief The whole per-frame job, ROS-free: pre-process, rectify, match with temporal priors,
 * post-filter, fuse over time, track coverage, and build the point cloud.
 *
 * The nodelet and the command-line tools both run this class, so what is tuned and measured
 * offline is what runs live: one code path (docs/method.md, section 4, lists the steps it runs).
 *
 * Use:
 * @code
 *   endo_stereo::PipelineParams params;               // or loadPipelineParams("config/default.yaml")
 *   endo_stereo::Pipeline pipeline(params);
 *   pipeline.setCalibration(calib);                   // calibrated mode only
 *   endo_stereo::StereoInput in{left, right, "bgr8", "bgr8", stamp_s};
 *   endo_stereo::PipelineOutput out;
 *   std::string error;
 *   if (!pipeline.process(in, out, &error)) { ... report error, keep running ... }
 * @endcode
 *
 * Thread safety: not thread-safe; one instance per processing thread. setParams() must not run
 * concurrently with process() (the nodelet swaps parameters between frames under its own mutex).
 */
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "endo_stereo/core/matcher.hpp"
#include "endo_stereo/core/point_cloud.hpp"
#include "endo_stereo/core/preprocess.hpp"
#include "endo_stereo/core/rectification.hpp"
#include "endo_stereo/core/stereo_geometry.hpp"
#include "endo_stereo/core/temporal.hpp"

namespace endo_stereo {

/// Which optional outputs to compute (the mandatory ones: disparity, codes, confidence).
struct OutputParams {
  bool point_cloud = true;     ///< organized XYZRGB cloud (needs metric geometry for metres)
  bool fused = false;          ///< temporally fused disparity and its age
  bool coverage = false;       ///< per-pixel longest run of frames without an update
  std::string validate() const { return {}; }
};

/// Every component's parameters: one params struct per component.
struct PipelineParams {
  PreprocessParams preprocess;
  RectifyParams rectify;
  MatcherParams matcher;
  PostFilterParams filter;
  TemporalParams temporal;
  OutputParams output;
  /// @return empty when all components are valid, else the first component's message.
  std::string validate() const;
};

/// One stereo pair as it arrives (raw, possibly interlaced, distorted, colour).
struct StereoInput {
  cv::Mat left;                ///< raw left image, layout given by left_encoding
  cv::Mat right;               ///< raw right image
  std::string left_encoding;   ///< ROS encoding names: mono8, mono16, bgr8, rgb8, bgra8, rgba8, yuv422
  std::string right_encoding;
  double stamp_s = 0.0;        ///< capture time, seconds (monotonic within a stream)
};

/// What one process() call produced. Buffers are reused between frames.
struct PipelineOutput {
  cv::Mat left_rect_gray;      ///< CV_8UC1 rectified left
  cv::Mat right_rect_gray;     ///< CV_8UC1 rectified right
  cv::Mat left_rect_color;     ///< CV_8UC3 BGR rectified left (for colouring the cloud)
  MatchResult match;           ///< disparity (NaN invalid), codes, confidence, stats
  cv::Mat fused_disparity;     ///< CV_32FC1, NaN where no recent valid value (when enabled)
  cv::Mat fused_age;           ///< CV_16UC1, frames since the fused value was measured
  cv::Mat coverage;            ///< CV_16UC1 longest run without update so far (when enabled)
  OrganizedCloud cloud;        ///< organized cloud in the left rectified optical frame, metres
  RectifiedGeometry geometry;  ///< of the rectified pair
  RectificationQuality rect_quality;  ///< latest vertical-offset residual of the rectification
  bool priors_used = false;    ///< this frame's output comes from narrowed ranges (with the
                               ///< same-frame fallback for their misses, temporal_matching.hpp)
  /// The narrowed search found too few matches (TemporalParams::min_prior_hit_share: a scene
  /// change), so the priors were dropped and the frame matched again over the full range
  /// (match_ms covers both passes).
  bool priors_rejected = false;
  bool priors_reset = false;   ///< the temporal state was reset before this frame (and why below)
  std::string reset_reason;
  TemporalPriorStats prior_stats;  ///< narrowed / full-range pixels, prior hits and misses
  int64_t frame_index = 0;     ///< process() calls that succeeded before this one
  /// Wall times of the stages, ms. match_ms includes post-filtering (see match.stats for the
  /// split); temporal_ms covers priors, fusion and coverage; total_ms the whole call.
  double preprocess_ms = 0.0, rectify_ms = 0.0, match_ms = 0.0, temporal_ms = 0.0,
         cloud_ms = 0.0, total_ms = 0.0;
};

class Pipeline {
 public:
  /// @throws std::invalid_argument when params are invalid (message names the field).
  explicit Pipeline(const PipelineParams& params);
  ~Pipeline();

  /// Replace the parameters; temporal state is kept unless the search range changed.
  /// @throws std::invalid_argument when invalid (old parameters kept).
  void setParams(const PipelineParams& params);
  const PipelineParams& params() const { return params_; }

  /// Calibrated mode: set or replace the calibration (rectification maps are rebuilt only when it
  /// changes; temporal state resets when it changes). @return empty or an error naming the field.
  std::string setCalibration(const StereoCalibration& calibration);

  /// Process one pair. @return false with a message in @p error (never throws for bad input);
  /// the pipeline stays usable and the next good pair is processed.
  bool process(const StereoInput& input, PipelineOutput& out, std::string* error);

  /// Forget the temporal state (priors, fusion, coverage).
  void reset();

  /// The temporal stage (coverage figures and colour image, fused state). Valid for the lifetime
  /// of this object; read it between process() calls only.
  /**
   * Whether PipelineOutput::left_rect_color is wanted on frames without a point cloud (default
   * true). A caller that shows no rectified colour image (the nodelet while nobody subscribes to
   * it) turns it off to skip the left image's colour conversion and colour remap; left_rect_color
   * is then empty. The point cloud, when computed, is coloured either way.
   */
  void setColorOutput(bool wanted);

  /// Measure the rectification quality on a background thread (StereoRectifier::
  /// setAsyncQuality(); default false). PipelineOutput::rect_quality then lags by a few frames.
  void setAsyncRectificationQuality(bool async);

  const TemporalTracker& temporal() const;
  /// The rectifier (quality, geometry, mapping between raw and rectified images). Same rules.
  const StereoRectifier& rectifier() const;

 private:
  PipelineParams params_;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace endo_stereo
