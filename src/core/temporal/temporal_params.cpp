// Temporal parameters and reset detection (docs/method.md section 4). See temporal.hpp.
#include <cmath>
#include <sstream>
#include <string>

#include "endo_stereo/core/temporal.hpp"
#include "temporal_internal.hpp"

namespace endo_stereo {

using detail::rangeMessage;

std::string TemporalParams::validate() const {
  if (prior_radius_px < 1 || prior_radius_px > 64)
    return rangeMessage("prior_radius_px", "[1, 64]", prior_radius_px);
  if (prior_neighbourhood_px < 0 || prior_neighbourhood_px > 16)
    return rangeMessage("prior_neighbourhood_px", "[0, 16]", prior_neighbourhood_px);
  if (prior_edge_zone_px < 0 || prior_edge_zone_px > 64)
    return rangeMessage("prior_edge_zone_px", "[0, 64]", prior_edge_zone_px);
  if (max_prior_age_frames < 1 || max_prior_age_frames > 1000)
    return rangeMessage("max_prior_age_frames", "[1, 1000]", max_prior_age_frames);
  if (full_range_period_frames < 1 || full_range_period_frames > 1000)
    return rangeMessage("full_range_period_frames", "[1, 1000]", full_range_period_frames);
  if (!(min_prior_hit_share >= 0.0 && min_prior_hit_share <= 1.0))
    return rangeMessage("min_prior_hit_share", "[0, 1]", min_prior_hit_share);
  if (!(max_gap_s > 0.0) || !std::isfinite(max_gap_s))
    return rangeMessage("max_gap_s", "(0, inf)", max_gap_s);
  if (fused_max_age_frames < 0 || fused_max_age_frames > 65534)
    return rangeMessage("fused_max_age_frames", "[0, 65534]", fused_max_age_frames);
  if (coverage_within_frames < 1 || coverage_within_frames > 65534)
    return rangeMessage("coverage_within_frames", "[1, 65534]", coverage_within_frames);
  return {};
}

// ------------------------------------------------------------------------------------------------
std::string TemporalResetDetector::check(const TemporalFrameInfo& info) {
  std::ostringstream reason;
  if (has_previous_) {
    const TemporalFrameInfo& p = previous_;
    if (info.size != p.size) {
      reason << "image size changed from " << p.size.width << "x" << p.size.height << " to "
             << info.size.width << "x" << info.size.height;
    } else if (info.min_disparity != p.min_disparity || info.max_disparity != p.max_disparity) {
      reason << "disparity range changed from [" << p.min_disparity << ", " << p.max_disparity
             << "] to [" << info.min_disparity << ", " << info.max_disparity << "]";
    } else if (info.calibration_generation != p.calibration_generation) {
      reason << "calibration changed";
    } else if (std::isfinite(info.stamp_s) && std::isfinite(p.stamp_s)) {
      const double dt = info.stamp_s - p.stamp_s;
      if (dt < 0.0) {
        reason << "time went back by " << -dt << " s";
      } else if (dt > max_gap_s_) {
        reason << "gap of " << dt << " s > max_gap_s " << max_gap_s_;
      }
    }
  }
  previous_ = info;
  has_previous_ = true;
  return reason.str();
}

}  // namespace endo_stereo
