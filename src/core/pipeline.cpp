// The per-frame job shared by the nodelet and the command-line tools. See pipeline.hpp.
#include "endo_stereo/core/pipeline.hpp"

#include <chrono>
#include <exception>
#include <stdexcept>

#include "endo_stereo/core/temporal_matching.hpp"

namespace endo_stereo {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// An empty encoding means "as the matrix type suggests", so callers holding plain cv::Mats (the
// CLI reading image files) need not spell it out.
std::string encodingOrDefault(const std::string& encoding, const cv::Mat& image) {
  if (!encoding.empty()) return encoding;
  switch (image.type()) {
    case CV_8UC1:
      return "mono8";
    case CV_16UC1:
      return "mono16";
    case CV_8UC3:
      return "bgr8";
    case CV_8UC4:
      return "bgra8";
    default:
      return "";
  }
}

std::string sizeText(const cv::Size& s) {
  return std::to_string(s.width) + "x" + std::to_string(s.height);
}

void setError(std::string* error, const std::string& message) {
  if (error) *error = message;
}

}  // namespace

std::string PipelineParams::validate() const {
  // Each component's message names its field; the section prefix says which struct it is in,
  // in the same words as the YAML keys (params_io.hpp).
  const std::pair<const char*, std::string> checks[] = {
      {"preprocess", preprocess.validate()}, {"rectify", rectify.validate()},
      {"matcher", matcher.validate()},       {"filter", filter.validate()},
      {"temporal", temporal.validate()},     {"output", output.validate()},
  };
  for (const auto& c : checks) {
    if (c.second.empty()) continue;
    const std::string section = c.first;
    if (c.second.find(section + ".") != std::string::npos) return c.second;
    return section + ": " + c.second;
  }
  return {};
}

struct Pipeline::Impl {
  Impl(const PipelineParams& p)
      : matcher(p.matcher, p.filter), rectifier(p.rectify), temporal(p.temporal) {
    rectifier.setQualityDisparityRange(p.matcher.min_disparity, p.matcher.max_disparity);
  }

  TemporalMatcher matcher;  // the frame's matching passes with the temporal priors
  StereoRectifier rectifier;
  TemporalTracker temporal;
  StereoCalibration calibration;  // as given, before scaling for pre-processing
  bool has_calibration = false;
  int64_t frames_done = 0;
  bool color_wanted = true;  // setColorOutput()
  // Scratch reused between frames.
  cv::Mat left_gray, right_gray, left_bgr;
};

Pipeline::Pipeline(const PipelineParams& params) : params_(params) {
  const std::string err = params.validate();
  if (!err.empty()) throw std::invalid_argument(err);
  impl_ = std::make_unique<Impl>(params);
}

Pipeline::~Pipeline() = default;

void Pipeline::setParams(const PipelineParams& params) {
  const std::string err = params.validate();
  if (!err.empty()) throw std::invalid_argument(err);
  // All checks passed above, so none of the setters below can throw and leave a mixed state.
  impl_->matcher.setParams(params.matcher, params.filter);
  impl_->rectifier.setParams(params.rectify);
  impl_->rectifier.setQualityDisparityRange(params.matcher.min_disparity,
                                            params.matcher.max_disparity);
  impl_->temporal.setParams(params.temporal);
  const bool rescale = params.preprocess.factorX() != params_.preprocess.factorX() ||
                       params.preprocess.factorY() != params_.preprocess.factorY() ||
                       params.preprocess.interlace != params_.preprocess.interlace ||
                       params.preprocess.field_parity != params_.preprocess.field_parity;
  params_ = params;
  if (rescale && impl_->has_calibration) {
    // The pre-processed images change size: the rectifier needs the calibration of the new
    // images. Its generation then advances and the temporal state resets on the next frame.
    impl_->rectifier.setCalibration(scaleCalibration(impl_->calibration, params_.preprocess));
  }
}

std::string Pipeline::setCalibration(const StereoCalibration& calibration) {
  const std::string err = calibration.validate();
  if (!err.empty()) return err;
  const std::string rect_err =
      impl_->rectifier.setCalibration(scaleCalibration(calibration, params_.preprocess));
  if (!rect_err.empty()) return rect_err;
  impl_->calibration = calibration;
  impl_->has_calibration = true;
  return {};
}

void Pipeline::reset() {
  // Only the temporal state: an uncalibrated rectification estimate stays valid for the same
  // camera and is costly to rebuild (several frames of SIFT).
  impl_->temporal.reset();
}

void Pipeline::setColorOutput(bool wanted) { impl_->color_wanted = wanted; }

void Pipeline::setAsyncRectificationQuality(bool async) { impl_->rectifier.setAsyncQuality(async); }

const TemporalTracker& Pipeline::temporal() const { return impl_->temporal; }
const StereoRectifier& Pipeline::rectifier() const { return impl_->rectifier; }

bool Pipeline::process(const StereoInput& input, PipelineOutput& out, std::string* error) {
  const auto t_start = Clock::now();
  out.priors_used = false;
  out.priors_rejected = false;
  out.priors_reset = false;
  out.reset_reason.clear();
  out.prior_stats = TemporalPriorStats();
  out.preprocess_ms = out.rectify_ms = out.match_ms = out.temporal_ms = out.cloud_ms = 0.0;
  out.frame_index = impl_->frames_done;

  if (input.left.empty() || input.right.empty()) {
    setError(error, std::string("empty ") + (input.left.empty() ? "left" : "right") + " image");
    return false;
  }
  if (input.left.size() != input.right.size()) {
    setError(error, "image size mismatch: left " + sizeText(input.left.size()) + ", right " +
                        sizeText(input.right.size()));
    return false;
  }
  const std::string left_enc = encodingOrDefault(input.left_encoding, input.left);
  const std::string right_enc = encodingOrDefault(input.right_encoding, input.right);

  try {
    // --- pre-processing: gray for matching, colour (left only) for the cloud.
    auto t = Clock::now();
    std::string err;
    // Colour only where something uses it: it costs a conversion and a 3-channel remap.
    const bool color = params_.output.point_cloud || impl_->color_wanted;
    if (!color) impl_->left_bgr.release();
    if (!preprocessImage(input.left, left_enc, params_.preprocess, impl_->left_gray,
                         color ? &impl_->left_bgr : nullptr, &err)) {
      setError(error, "left image: " + err);
      return false;
    }
    if (!preprocessImage(input.right, right_enc, params_.preprocess, impl_->right_gray, nullptr,
                         &err)) {
      setError(error, "right image: " + err);
      return false;
    }
    out.preprocess_ms = msSince(t);

    // --- rectification (any mode; pass-through copies and supplies the geometry).
    t = Clock::now();
    if (!impl_->rectifier.rectify(impl_->left_gray, impl_->right_gray, impl_->left_bgr,
                                  out.left_rect_gray, out.right_rect_gray, out.left_rect_color,
                                  &err)) {
      setError(error, "rectification: " + err);
      return false;
    }
    out.geometry = impl_->rectifier.geometry();
    out.rect_quality = impl_->rectifier.quality();
    out.rectify_ms = msSince(t);

    // --- priors: the temporal stage decides (time, gap, size, range, calibration generation).
    t = Clock::now();
    TemporalFrameInfo info;
    info.size = out.left_rect_gray.size();
    info.stamp_s = input.stamp_s;
    info.calibration_generation = impl_->rectifier.generation();
    info.min_disparity = params_.matcher.min_disparity;
    info.max_disparity = params_.matcher.max_disparity;
    std::string reason;
    const SearchRange* range = impl_->temporal.beginFrame(info, &reason);
    out.priors_reset = !reason.empty();
    out.reset_reason = reason;
    out.temporal_ms = msSince(t);

    // --- matching and post-filtering: the narrowed pass (the full range where no prior is
    // usable), the same-frame fallback for narrowed misses, and a scene change's second go
    // (temporal_matching.hpp).
    t = Clock::now();
    TemporalMatchReport report;
    impl_->matcher.compute(out.left_rect_gray, out.right_rect_gray, impl_->temporal, range,
                           out.match, &report);
    out.priors_used = report.priors_used;
    out.priors_rejected = report.priors_rejected;
    out.match_ms = msSince(t);

    // --- priors for the next frame, fusion, coverage.
    t = Clock::now();
    impl_->temporal.endFrame(out.match.disparity, params_.output.fused, params_.output.coverage);
    out.prior_stats = impl_->temporal.prior().stats();
    if (params_.output.fused) {
      // Copies into the caller's buffers: the tracker overwrites its own on the next frame.
      impl_->temporal.fusion().disparity().copyTo(out.fused_disparity);
      impl_->temporal.fusion().age().copyTo(out.fused_age);
    } else {
      out.fused_disparity.release();
      out.fused_age.release();
    }
    if (params_.output.coverage) {
      impl_->temporal.coverage().longestRun().copyTo(out.coverage);
    } else {
      out.coverage.release();
    }
    out.temporal_ms += msSince(t);

    // --- point cloud.
    if (params_.output.point_cloud) {
      t = Clock::now();
      disparityToCloud(out.match.disparity, out.left_rect_color, out.geometry, out.cloud);
      out.cloud_ms = msSince(t);
    } else {
      out.cloud = OrganizedCloud();
    }
  } catch (const std::exception& ex) {
    // The components throw only on contract violations (type/size); report, stay usable.
    setError(error, std::string("processing failed: ") + ex.what());
    return false;
  }
  ++impl_->frames_done;
  out.total_ms = msSince(t_start);
  return true;
}

}  // namespace endo_stereo
