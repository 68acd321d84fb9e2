/**
 * @file unknown_params.hpp
 * @brief Private parameters the nodelet does not read, named at start-up with the closest name it
 * does read, so that `_rectify_mode:=pass_through` (for `~rectify/mode`) or `_max_disparty:=99`
 * is a warning at once, not a silent default.
 *
 * The known names are derived from the lists the nodelet reads from (ros_params.hpp's
 * rosParamNames(), params_io's listPipelineParams(), stereoImageProcParams(), the
 * dynamic_reconfigure descriptions), never written out a second time.
 */
#pragma once

#include <string>
#include <vector>

#include <ros/node_handle.h>

namespace endo_stereo {

/// One private parameter the nodelet does not read, and the known name closest to it.
struct UnknownParam {
  std::string name;     ///< relative to the private namespace, e.g. "rectify_mode"
  std::string closest;  ///< e.g. "rectify/mode"; "" when nothing is close
};

/// Every private parameter name the nodelet reads (relative, '/'-separated), sorted.
std::vector<std::string> knownPrivateParams();

/**
 * The known name closest to @p name: the smallest edit distance, '/' and '_' counted as equal,
 * to either the whole known name or its last part (so `max_disparty` finds
 * `matcher/max_disparity`). "" when even the closest differs in more than a third of the letters.
 */
std::string closestParamName(const std::string& name, const std::vector<std::string>& known);

/// The parameters under @p pnh's private namespace that are not in @p known (a parameter under a
/// known map, `~matcher/...`, is judged by the loader itself and not listed), with the closest
/// known name of each.
std::vector<UnknownParam> unknownPrivateParams(const ros::NodeHandle& pnh,
                                               const std::vector<std::string>& known);

}  // namespace endo_stereo
