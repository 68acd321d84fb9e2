/**
 * @file params_io.hpp
 * @brief PipelineParams from YAML presets and `key=value` overrides, with one list of key names
 * shared by the command-line tools and the ROS layer.
 *
 * Keys are the params structs' field names grouped by component, written `section.field`:
 * `matcher.delta_min`, `filter.outlier_window_px`, `preprocess.downsample`, `rectify.mode`,
 * `temporal.prior_radius_px`, `output.point_cloud`, ... In a YAML file each section is a map:
 * @code
 *   matcher:
 *     delta_min: 0.2
 *     window_max_px: 23
 *   filter:
 *     fill_holes: true
 * @endcode
 * A section or key that is absent keeps its current value, so presets can be layered (defaults,
 * then a file, then overrides). An unknown section or key, a value of the wrong type, or a value
 * that is not a plain scalar is an error naming the key. A top-level `ros:` section is skipped: it
 * holds the nodelet's own settings (queue size, synchronisation), which are not pipeline params.
 *
 * The ROS layer uses listPipelineParams() for the names (as `~matcher/delta_min`) and types and
 * setPipelineParam() to store what it read, so a key means the same thing everywhere.
 *
 * ROS-free (yaml-cpp). Functions are reentrant; they touch only the struct passed in.
 */
#pragma once

#include <limits>
#include <string>
#include <vector>

#include "endo_stereo/core/pipeline.hpp"

namespace endo_stereo {

/// Type of a parameter's value.
enum class ParamType {
  kBool,    ///< true/false (also yes/no, on/off, 1/0; case-insensitive)
  kInt,     ///< a decimal integer
  kDouble,  ///< a finite decimal number
  kString,  ///< free text, or one of ParamInfo::choices when that list is not empty
};

/// Where a parameter comes from: the paper's method, our additions to it (docs/method.md section
/// 5), or a setting of the input, output or machine that does not change the method.
enum class ParamOrigin { kPaper, kOurs, kSetting };

/// The values validate() accepts for a number, where they are a plain interval: lo .. hi, each
/// end included unless open (infinite = unbounded). exact = false where the accepted values are
/// not a plain interval (odd widths, a bound set by another field, a list): then
/// ParamInfo::range says what they are and lo / hi are only outer limits.
struct ParamBounds {
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  bool lo_open = false;
  bool hi_open = false;
  bool exact = false;
};

/// One pipeline parameter, as the one table of parameters describes it (src/core/pipeline/param_table.cpp).
struct ParamInfo {
  std::string key;      ///< "section.field", e.g. "matcher.delta_min"
  std::string section;  ///< "matcher", "filter", "preprocess", "rectify", "temporal", "output"
  std::string field;    ///< the struct field name, e.g. "delta_min"
  ParamType type = ParamType::kString;
  std::string value;                 ///< current value as text (parses back to the same value)
  std::string default_value;         ///< the struct default (= config/default.yaml) as text
  std::vector<std::string> choices;  ///< accepted values of an enumeration; empty otherwise
  ParamOrigin origin = ParamOrigin::kSetting;
  ParamBounds bounds;
  std::string range;    ///< accepted values in words: "[0, 2]", "> 0", "odd, >= 3"; "" for bools
  std::string meaning;  ///< what it does, one sentence
};

/// The sections, in the order they are listed and written.
const std::vector<std::string>& pipelineParamSections();

/// Every parameter of @p params with its current value, in a fixed order (by section, then in
/// the structs' declaration order).
std::vector<ParamInfo> listPipelineParams(const PipelineParams& params);

/// Human-readable name of a type ("bool", "int", "double", "string").
std::string paramTypeName(ParamType type);

/// "paper", "ours" or "setting".
std::string paramOriginName(ParamOrigin origin);

/// The parameter table as Markdown (key, default, range, origin, meaning; one row per key), as
/// README.md shows it between its `params-table` markers (`endo_stereo_cli --list-params
/// --markdown` prints it; test_params_io checks the README against it).
std::string paramTableMarkdown();

/**
 * Set one parameter from text.
 * @param key "section.field"; an unknown key is an error.
 * @param value text parsed per the key's type (ints reject fractions, doubles reject NaN/inf,
 *        enumerations accept only their choices).
 * @return empty on success, else a message naming the key and what was wrong; @p params is left
 *         unchanged on error. Ranges are not checked here: call PipelineParams::validate().
 */
std::string setPipelineParam(PipelineParams& params, const std::string& key,
                             const std::string& value);

/// Read one parameter as text. @return false when the key is unknown.
bool getPipelineParam(const PipelineParams& params, const std::string& key, std::string* value);

/// Apply an override written `section.field=value` (as given to `--set`).
/// @return empty on success, else a message naming the key (or the malformed override).
std::string applyParamOverride(PipelineParams& params, const std::string& assignment);

/**
 * Load a YAML preset on top of @p params (absent keys keep their values).
 * @return empty on success, else a message naming the file and the offending key; on error
 *         @p params is left unchanged. Ranges are not checked here: call validate().
 */
std::string loadPipelineParams(const std::string& path, PipelineParams& params);

/// Same as loadPipelineParams() but from YAML text; @p source names it in messages.
std::string loadPipelineParamsFromString(const std::string& yaml_text, PipelineParams& params,
                                         const std::string& source = "<string>");

/// Write every parameter as a YAML document, one map per section (loads back to the same values).
std::string pipelineParamsToYaml(const PipelineParams& params);

}  // namespace endo_stereo
