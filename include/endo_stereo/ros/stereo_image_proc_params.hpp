/**
 * @file stereo_image_proc_params.hpp
 * @brief stereo_image_proc's parameter names, understood by the nodelet: those with a clear
 * meaning here are mapped onto ours, the others are named in a warning that says what endo_stereo
 * does instead, so a stereo_image_proc user's command line is never ignored silently.
 *
 * Mapped (private parameters, read after the preset and the `~section/field` parameters, and
 * taking precedence over them, since a user types them on purpose):
 * - `~min_disparity` (int): the smallest disparity searched, `matcher/min_disparity`. Without
 *   `~disparity_range` the width of the range is kept.
 * - `~disparity_range` (int, >= 1): the number of disparities searched:
 *   `matcher/max_disparity = min_disparity + disparity_range - 1`, the range stereo_image_proc
 *   searches and writes into its DisparityImage (min 20, range 96: 20..115).
 * - `~approximate_sync`, `~queue_size`: the same names and meanings as ours (ros_params.hpp);
 *   approximate pairs must lie within `~sync_tolerance_s`.
 * Named in a warning (stereoImageProcParams() lists what we do instead): `stereo_algorithm`,
 * `prefilter_size`, `prefilter_cap`, `correlation_window_size`, `uniqueness_ratio`,
 * `texture_threshold`, `speckle_size`, `speckle_range`, `fullDP`, `P1`, `P2`, `disp12MaxDiff`,
 * `downsampling_factor`.
 *
 * Reentrant: the functions read or write the parameter server only.
 */
#pragma once

#include <string>
#include <vector>

#include <ros/node_handle.h>

#include "endo_stereo/core/pipeline.hpp"

namespace endo_stereo {

/// One stereo_image_proc parameter and what it means here.
struct StereoImageProcParam {
  std::string name;     ///< stereo_image_proc's name (a private parameter of its nodelets)
  std::string ours;     ///< our parameter(s) it maps to, "" when it is not mapped
  std::string instead;  ///< what endo_stereo does (the warning's text, or the mapping's rule)
};

/// Every stereo_image_proc parameter the nodelet knows of, mapped or not, in a fixed order.
const std::vector<StereoImageProcParam>& stereoImageProcParams();

/// What applyStereoImageProcParams() did, for the log.
struct StereoImageProcReport {
  std::vector<std::string> mapped;   ///< one line per mapped parameter that was set
  std::vector<std::string> ignored;  ///< one line per unmapped parameter that was set
};

/**
 * Apply `~min_disparity` and `~disparity_range` of @p pnh (when present) to @p params, and list
 * in @p report the stereo_image_proc parameters found with no equivalent here.
 * @return "" on success, else a message naming the parameter (wrong type, range < 1); @p params
 *         unchanged on error. Does not call validate().
 */
std::string applyStereoImageProcParams(const ros::NodeHandle& pnh, PipelineParams& params,
                                       StereoImageProcReport* report);

/// Where `~min_disparity` / `~disparity_range` are on the parameter server, rewrite them to
/// describe @p params (after a reconfigure), so that they never contradict the range in use.
void storeStereoImageProcParams(const ros::NodeHandle& pnh, const PipelineParams& params);

}  // namespace endo_stereo
