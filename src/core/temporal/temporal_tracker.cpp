// The temporal stage as the pipeline runs it (docs/method.md section 4): reset detection, priors,
// fusion and coverage behind beginFrame() / endFrame(). See temporal.hpp.
#include <cmath>
#include <cstdint>
#include <sstream>
#include <stdexcept>
#include <string>

#include "endo_stereo/core/temporal.hpp"
#include "temporal_internal.hpp"

namespace endo_stereo {

using detail::checkDisparity;

TemporalTracker::TemporalTracker(const TemporalParams& params)
    : params_(params),
      detector_(params.max_gap_s),
      prior_(params),
      fusion_(params.fused_max_age_frames),
      coverage_(params.coverage_within_frames) {}

void TemporalTracker::setParams(const TemporalParams& params) {
  const std::string error = params.validate();
  if (!error.empty()) throw std::invalid_argument(error);
  params_ = params;
  detector_.setMaxGap(params.max_gap_s);
  prior_.setParams(params);
  fusion_.setMaxAge(params.fused_max_age_frames);
  coverage_.setWithinFrames(params.coverage_within_frames);
  if (!params.enabled) prior_.reset();
}

void TemporalTracker::reset() {
  pending_reason_.clear();
  detector_.reset();
  prior_.reset();
  fusion_.reset();
  coverage_.reset();
  range_.lo.release();
  range_.hi.release();
  priors_used_ = false;
  frame_open_ = false;
}

const SearchRange* TemporalTracker::beginFrame(const TemporalFrameInfo& info,
                                               std::string* reset_reason) {
  std::string reason = detector_.check(info);
  if (!reason.empty()) {
    prior_.reset();
    fusion_.reset();
    coverage_.reset();
  } else {
    reason = pending_reason_;
  }
  pending_reason_.clear();
  if (reset_reason) *reset_reason = reason;
  frame_open_ = true;
  priors_used_ = false;
  if (!params_.enabled) {
    range_.lo.release();
    range_.hi.release();
    return nullptr;
  }
  priors_used_ = prior_.buildRange(info.size, info.min_disparity, info.max_disparity, range_);
  return priors_used_ ? &range_ : nullptr;
}

bool TemporalTracker::rejectPriors(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalTracker::rejectPriors");
  if (!params_.enabled || !priors_used_ || !frame_open_) return false;
  if (!(params_.min_prior_hit_share > 0.0)) return false;
  // The same test as TemporalPrior::sceneChanged(), from one pass over the image.
  const double reference = prior_.referenceHitShare();
  int64_t judged = 0;
  const double share = prior_.hitShare(disparity, &judged);
  if (!prior_.isSceneChange(std::llround(share * double(judged)), judged,
                            int64_t(disparity.total()))) {
    return false;
  }
  std::ostringstream os;
  os << "scene change: " << std::lround(100.0 * share) << "% of " << judged
     << " narrowed searches found a disparity (< " << params_.min_prior_hit_share << " x "
     << std::lround(100.0 * reference)
     << "% in the previous frame); priors and fused disparities dropped, frame matched again";
  pending_reason_ = os.str();
  prior_.dropAll();
  fusion_.reset();
  priors_used_ = false;
  return true;
}

void TemporalTracker::endFrame(const cv::Mat& disparity, bool fuse, bool track_coverage) {
  checkDisparity(disparity, "TemporalTracker::endFrame");
  if (params_.enabled && frame_open_) {
    prior_.update(disparity);
    const TemporalPriorStats& s = prior_.stats();
    if (s.scene_change && pending_reason_.empty()) {
      std::ostringstream os;
      os << "scene change: " << s.prior_hits << " of " << (s.prior_hits + s.prior_misses)
         << " narrowed searches found a disparity (< " << params_.min_prior_hit_share
         << " x the previous frame's share); priors and fused disparities dropped";
      pending_reason_ = os.str();
      fusion_.reset();
    }
  }
  if (fuse) fusion_.update(disparity);
  if (track_coverage) coverage_.update(disparity);
  frame_open_ = false;
}

}  // namespace endo_stereo
