// Names of the rectification modes and methods, and the validation of RectifyParams.

#include <sstream>
#include <string>

#include "endo_stereo/core/rectification.hpp"
#include "enum_names.hpp"

namespace endo_stereo {

namespace {

const detail::EnumName<RectifyMode> kRectifyModes[] = {
    {RectifyMode::kCalibrated, "calibrated"},
    {RectifyMode::kUncalibrated, "uncalibrated"},
    {RectifyMode::kPassThrough, "pass_through"},
    {RectifyMode::kPassThrough, "passthrough"},
    {RectifyMode::kPassThrough, "none"},
};

const detail::EnumName<UncalibratedMethod> kUncalibratedMethods[] = {
    {UncalibratedMethod::kAuto, "auto"},
    {UncalibratedMethod::kHomography, "homography"},
    {UncalibratedMethod::kPolar, "polar"},
};

}  // namespace

std::string toString(RectifyMode mode) {
  return detail::nameOf(kRectifyModes, mode, "calibrated");
}

bool parseRectifyMode(const std::string& t, RectifyMode* m) {
  return detail::valueOf(kRectifyModes, t, m);
}

std::string toString(UncalibratedMethod m) {
  return detail::nameOf(kUncalibratedMethods, m, "auto");
}

bool parseUncalibratedMethod(const std::string& t, UncalibratedMethod* m) {
  return detail::valueOf(kUncalibratedMethods, t, m);
}

std::string RectifyParams::validate() const {
  std::ostringstream m;
  auto bad = [&](const char* field, const char* range, double v) {
    m << "rectify." << field << ": must be " << range << ", got " << v;
    return m.str();
  };
  if (!(alpha == -1.0 || (alpha >= 0.0 && alpha <= 1.0)))
    return bad("alpha", "-1 or in [0, 1]", alpha);
  if (output_width_px < 0 || output_width_px > 32768) {
    return bad("output_width_px", "in [0, 32768]", output_width_px);
  }
  if (output_height_px < 0 || output_height_px > 32768) {
    return bad("output_height_px", "in [0, 32768]", output_height_px);
  }
  if (!(output_scale_x > 0.0 && output_scale_x <= 4.0))
    return bad("output_scale_x", "in (0, 4]", output_scale_x);
  if (!(output_scale_y > 0.0 && output_scale_y <= 4.0))
    return bad("output_scale_y", "in (0, 4]", output_scale_y);
  if (sift_features < 0) return bad("sift_features", ">= 0", sift_features);
  if (!(ratio_test > 0.0 && ratio_test < 1.0)) return bad("ratio_test", "in (0, 1)", ratio_test);
  if (!(ransac_threshold_px > 0.0)) return bad("ransac_threshold_px", "> 0", ransac_threshold_px);
  if (!(ransac_confidence > 0.0 && ransac_confidence < 1.0)) {
    return bad("ransac_confidence", "in (0, 1)", ransac_confidence);
  }
  if (min_inliers < 8) return bad("min_inliers", ">= 8", min_inliers);
  if (estimation_frames < 1) return bad("estimation_frames", ">= 1", estimation_frames);
  if (!(reestimate_threshold_px >= 0.0))
    return bad("reestimate_threshold_px", ">= 0", reestimate_threshold_px);
  if (reestimate_after < 1) return bad("reestimate_after", ">= 1", reestimate_after);
  if (!(polar_auto_distance > 0.0)) return bad("polar_auto_distance", "> 0", polar_auto_distance);
  if (!(focal_px >= 0.0) || !std::isfinite(focal_px))
    return bad("focal_px", ">= 0 (0 = unknown)", focal_px);
  if (!(baseline_m >= 0.0) || !std::isfinite(baseline_m))
    return bad("baseline_m", ">= 0 (0 = unknown)", baseline_m);
  if (quality_stride < 0) return bad("quality_stride", ">= 0 (0 = never)", quality_stride);
  if (!(quality_warn_px > 0.0)) return bad("quality_warn_px", "> 0", quality_warn_px);
  if (quality_max_features < 0) return bad("quality_max_features", ">= 0", quality_max_features);
  if (!(row_correction_min_px >= 0.0) || !std::isfinite(row_correction_min_px)) {
    return bad("row_correction_min_px", ">= 0", row_correction_min_px);
  }
  if (row_correction_min_matches < 3) {
    return bad("row_correction_min_matches", ">= 3", row_correction_min_matches);
  }
  return {};
}

}  // namespace endo_stereo
