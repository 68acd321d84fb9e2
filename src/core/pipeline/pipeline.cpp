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

  // The steps of process(), in order.
  bool preprocess(const StereoInput& input, const PipelineParams& params, PipelineOutput& out,
                  std::string* error);
  bool rectify(PipelineOutput& out, std::string* error);
  const SearchRange* beginPriors(double stamp_s, const MatcherParams& mp, PipelineOutput& out);
  void match(const SearchRange* range, PipelineOutput& out);
  void endTemporal(const OutputParams& want, PipelineOutput& out);
  void cloud(bool wanted, PipelineOutput& out);
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

// --- the steps of a frame (docs/method.md: sections 1 to 4 in order) ---------------------------

namespace {

void resetFrameOutput(PipelineOutput& out, int64_t frame_index) {
  out.priors_used = false;
  out.priors_rejected = false;
  out.priors_reset = false;
  out.reset_reason.clear();
  out.prior_stats = TemporalPriorStats();
  out.preprocess_ms = out.rectify_ms = out.match_ms = out.temporal_ms = out.cloud_ms = 0.0;
  out.frame_index = frame_index;
}

// Both images present and of one size; "" or what is wrong.
std::string inputProblem(const StereoInput& input) {
  if (input.left.empty() || input.right.empty()) {
    return std::string("empty ") + (input.left.empty() ? "left" : "right") + " image";
  }
  if (input.left.size() != input.right.size()) {
    return "image size mismatch: left " + sizeText(input.left.size()) + ", right " +
           sizeText(input.right.size());
  }
  return {};
}

}  // namespace

// Section 1: gray for matching, colour (left only) for the cloud, only where something uses it
// (it costs a conversion and a 3-channel remap).
bool Pipeline::Impl::preprocess(const StereoInput& input, const PipelineParams& params,
                                PipelineOutput& out, std::string* error) {
  const auto t = Clock::now();
  const std::string left_enc = encodingOrDefault(input.left_encoding, input.left);
  const std::string right_enc = encodingOrDefault(input.right_encoding, input.right);
  const bool color = params.output.point_cloud || color_wanted;
  if (!color) left_bgr.release();
  std::string err;
  if (!preprocessImage(input.left, left_enc, params.preprocess, left_gray,
                       color ? &left_bgr : nullptr, &err)) {
    setError(error, "left image: " + err);
    return false;
  }
  if (!preprocessImage(input.right, right_enc, params.preprocess, right_gray, nullptr, &err)) {
    setError(error, "right image: " + err);
    return false;
  }
  out.preprocess_ms = msSince(t);
  return true;
}

// Section 1: rectification in any mode (pass-through copies and supplies the geometry).
bool Pipeline::Impl::rectify(PipelineOutput& out, std::string* error) {
  const auto t = Clock::now();
  std::string err;
  if (!rectifier.rectify(left_gray, right_gray, left_bgr, out.left_rect_gray, out.right_rect_gray,
                         out.left_rect_color, &err)) {
    setError(error, "rectification: " + err);
    return false;
  }
  out.geometry = rectifier.geometry();
  out.rect_quality = rectifier.quality();
  out.rectify_ms = msSince(t);
  return true;
}

// Section 4: the temporal stage decides whether the priors still hold (time, gap, size, range,
// calibration generation) and gives the frame's search ranges, or nullptr for a full search.
const SearchRange* Pipeline::Impl::beginPriors(double stamp_s, const MatcherParams& mp,
                                               PipelineOutput& out) {
  const auto t = Clock::now();
  TemporalFrameInfo info;
  info.size = out.left_rect_gray.size();
  info.stamp_s = stamp_s;
  info.calibration_generation = rectifier.generation();
  info.min_disparity = mp.min_disparity;
  info.max_disparity = mp.max_disparity;
  std::string reason;
  const SearchRange* range = temporal.beginFrame(info, &reason);
  out.priors_reset = !reason.empty();
  out.reset_reason = reason;
  out.temporal_ms = msSince(t);
  return range;
}

// Sections 2 and 3: matching and post-filtering: the narrowed pass (the full range where no prior
// is usable), the same-frame fallback for narrowed misses, and a scene change's second go
// (temporal_matching.hpp).
void Pipeline::Impl::match(const SearchRange* range, PipelineOutput& out) {
  const auto t = Clock::now();
  TemporalMatchReport report;
  matcher.compute(out.left_rect_gray, out.right_rect_gray, temporal, range, out.match, &report);
  out.priors_used = report.priors_used;
  out.priors_rejected = report.priors_rejected;
  out.match_ms = msSince(t);
}

// Section 4: the priors of the next frame, fusion and coverage; copies into the caller's buffers
// (the tracker overwrites its own on the next frame).
void Pipeline::Impl::endTemporal(const OutputParams& want, PipelineOutput& out) {
  const auto t = Clock::now();
  temporal.endFrame(out.match.disparity, want.fused, want.coverage);
  out.prior_stats = temporal.prior().stats();
  if (want.fused) {
    temporal.fusion().disparity().copyTo(out.fused_disparity);
    temporal.fusion().age().copyTo(out.fused_age);
  } else {
    out.fused_disparity.release();
    out.fused_age.release();
  }
  if (want.coverage) {
    temporal.coverage().longestRun().copyTo(out.coverage);
  } else {
    out.coverage.release();
  }
  out.temporal_ms += msSince(t);
}

void Pipeline::Impl::cloud(bool wanted, PipelineOutput& out) {
  if (!wanted) {
    out.cloud = OrganizedCloud();
    return;
  }
  const auto t = Clock::now();
  disparityToCloud(out.match.disparity, out.left_rect_color, out.geometry, out.cloud);
  out.cloud_ms = msSince(t);
}

bool Pipeline::process(const StereoInput& input, PipelineOutput& out, std::string* error) {
  const auto t_start = Clock::now();
  resetFrameOutput(out, impl_->frames_done);
  const std::string problem = inputProblem(input);
  if (!problem.empty()) {
    setError(error, problem);
    return false;
  }
  try {
    if (!impl_->preprocess(input, params_, out, error)) return false;
    if (!impl_->rectify(out, error)) return false;
    const SearchRange* range = impl_->beginPriors(input.stamp_s, params_.matcher, out);
    impl_->match(range, out);
    impl_->endTemporal(params_.output, out);
    impl_->cloud(params_.output.point_cloud, out);
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
