// stereo_image_proc's parameter names. See stereo_image_proc_params.hpp.
#include "endo_stereo/ros/stereo_image_proc_params.hpp"

#include <XmlRpcValue.h>

namespace endo_stereo {
namespace {

// An integer parameter: false when absent; "" in @p error, or a message naming it.
bool readInt(const ros::NodeHandle& pnh, const std::string& name, int* out, std::string* error) {
  XmlRpc::XmlRpcValue v;
  if (!pnh.getParam(name, v)) return false;
  if (v.getType() != XmlRpc::XmlRpcValue::TypeInt) {
    *error = "parameter " + pnh.resolveName(name) + ": expected an integer (stereo_image_proc's " +
             name + ")";
    return false;
  }
  *out = static_cast<int>(v);
  return true;
}

}  // namespace

const std::vector<StereoImageProcParam>& stereoImageProcParams() {
  static const std::vector<StereoImageProcParam> params = {
      {"min_disparity", "matcher/min_disparity",
       "the smallest disparity searched (without disparity_range the range keeps its width)"},
      {"disparity_range", "matcher/max_disparity",
       "max_disparity = min_disparity + disparity_range - 1"},
      {"approximate_sync", "approximate_sync",
       "same name and meaning; a pair's stamps must lie within ~sync_tolerance_s"},
      {"queue_size", "queue_size", "same name and meaning"},
      {"stereo_algorithm", "",
       "there is one matcher, zero-mean NCC with an adaptive window and three confidence "
       "criteria (no block matching / SGBM choice)"},
      {"prefilter_size", "",
       "no pre-filter: zero-mean NCC is insensitive to brightness and contrast differences"},
      {"prefilter_cap", "",
       "no pre-filter: zero-mean NCC is insensitive to brightness and contrast differences"},
      {"correlation_window_size", "",
       "the window adapts per pixel from ~matcher/window_min_px to ~matcher/window_max_px in "
       "steps of ~matcher/window_step_px"},
      {"uniqueness_ratio", "",
       "a peak is accepted when its NCC exceeds the second peak's by ~matcher/delta_min"},
      {"texture_threshold", "",
       "pixels with too little structure (~matcher/gamma_min, the local Laplacian's spread) are "
       "left out"},
      {"speckle_size", "",
       "isolated outliers are removed by ~filter/remove_outliers (~filter/outlier_window_px, "
       "~filter/outlier_disparity_tol_px, ~filter/outlier_min_share)"},
      {"speckle_range", "",
       "isolated outliers are removed by ~filter/remove_outliers (~filter/outlier_window_px, "
       "~filter/outlier_disparity_tol_px, ~filter/outlier_min_share)"},
      {"fullDP", "", "no smoothness term (SGBM): each pixel is matched on its own"},
      {"P1", "", "no smoothness term (SGBM): each pixel is matched on its own"},
      {"P2", "", "no smoothness term (SGBM): each pixel is matched on its own"},
      {"disp12MaxDiff", "",
       "the left-right consistency check accepts differences up to ~matcher/epsilon_px"},
      {"downsampling_factor", "",
       "~preprocess/downsample matches at a lower resolution, and the outputs stay at that "
       "resolution (no upsampling)"},
  };
  return params;
}

std::string applyStereoImageProcParams(const ros::NodeHandle& pnh, PipelineParams& params,
                                       StereoImageProcReport* report) {
  PipelineParams p = params;
  StereoImageProcReport r;
  std::string e;
  int min_d = 0, range = 0;
  const bool has_min = readInt(pnh, "min_disparity", &min_d, &e);
  if (!e.empty()) return e;
  const bool has_range = readInt(pnh, "disparity_range", &range, &e);
  if (!e.empty()) return e;
  if (has_range && range < 1) {
    return "parameter " + pnh.resolveName("disparity_range") + ": must be >= 1, got " +
           std::to_string(range);
  }
  if (has_min || has_range) {
    const int width = p.matcher.max_disparity - p.matcher.min_disparity + 1;
    if (has_min) p.matcher.min_disparity = min_d;
    p.matcher.max_disparity = p.matcher.min_disparity + (has_range ? range : width) - 1;
    std::string line = "stereo_image_proc's";
    if (has_min) line += " ~min_disparity " + std::to_string(min_d);
    if (has_min && has_range) line += " and";
    if (has_range) line += " ~disparity_range " + std::to_string(range);
    line += ": search range " + std::to_string(p.matcher.min_disparity) + ".." +
            std::to_string(p.matcher.max_disparity) +
            " (taken over ~matcher/min_disparity and ~matcher/max_disparity)";
    r.mapped.push_back(line);
  }
  for (const StereoImageProcParam& sip : stereoImageProcParams()) {
    if (!sip.ours.empty() || !pnh.hasParam(sip.name)) continue;
    r.ignored.push_back("stereo_image_proc's ~" + sip.name + " has no equivalent here and is " +
                        "ignored: " + sip.instead);
  }
  params = p;
  if (report) *report = r;
  return {};
}

void storeStereoImageProcParams(const ros::NodeHandle& pnh, const PipelineParams& params) {
  if (pnh.hasParam("min_disparity")) pnh.setParam("min_disparity", params.matcher.min_disparity);
  if (pnh.hasParam("disparity_range")) {
    pnh.setParam("disparity_range", params.matcher.max_disparity - params.matcher.min_disparity + 1);
  }
}

}  // namespace endo_stereo
