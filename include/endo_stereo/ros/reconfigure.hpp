/**
 * @file reconfigure.hpp
 * @brief dynamic_reconfigure (config/EndoStereo.cfg) <-> PipelineParams.
 *
 * A reconfigure name is a pipeline key with its first '.' written '_' (`matcher_delta_min` is
 * `matcher.delta_min`); values go through params_io's setPipelineParam(), so a reconfigure
 * request means exactly what the same key means in a YAML preset.
 *
 * Reentrant.
 */
#pragma once

#include <string>

#include <endo_stereo/EndoStereoConfig.h>

#include "endo_stereo/core/pipeline.hpp"

namespace endo_stereo {

/// "matcher_delta_min" -> "matcher.delta_min"; "" when the name has no known section prefix.
std::string pipelineKeyForConfigName(const std::string& name);

/**
 * A whole new PipelineParams: @p base with every value of @p config applied.
 * @return "" on success (then @p out holds the result; call validate() on it), else a message
 *         naming the parameter.
 */
std::string paramsFromConfig(const EndoStereoConfig& config, const PipelineParams& base,
                             PipelineParams* out);

/// The reconfigure values that describe @p params (starting from @p base for anything else).
EndoStereoConfig configFromParams(const PipelineParams& params,
                                  const EndoStereoConfig& base = EndoStereoConfig::__getDefault__());

}  // namespace endo_stereo
