// The command-line tools' parameter path: a preset file, then `--set` overrides, in that order
// (the same keys as config/*.yaml and the nodelet's ~section/field parameters).
#pragma once

#include <string>
#include <vector>

#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"

namespace endo_stereo {
namespace tools {

/// Loads @p params_file (when not empty) onto @p params, then applies each `section.field=value`
/// of @p overrides. @return "" on success, else "--params: <why>" or "--set: <why>".
inline std::string applyPresetAndOverrides(const std::string& params_file,
                                           const std::vector<std::string>& overrides,
                                           PipelineParams& params) {
  if (!params_file.empty()) {
    const std::string err = loadPipelineParams(params_file, params);
    if (!err.empty()) return "--params: " + err;
  }
  for (const std::string& s : overrides) {
    const std::string err = applyParamOverride(params, s);
    if (!err.empty()) return "--set: " + err;
  }
  return "";
}

}  // namespace tools
}  // namespace endo_stereo
