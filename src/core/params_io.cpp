// YAML presets and key=value overrides for PipelineParams. See params_io.hpp.
//
// One table lists every field once, as a pair of member pointers (component, field), so loading,
// overriding, listing and writing cannot disagree about a name or a type. Adding a field to a
// params struct means adding one line here; test_params_io checks that every key round-trips.
#include "endo_stereo/core/params_io.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <sstream>
#include <utility>

namespace endo_stereo {
namespace {

struct Entry {
  std::string section;
  std::string field;
  ParamType type;
  std::vector<std::string> choices;
  std::function<std::string(const PipelineParams&)> get;
  // Returns "" or what is wrong with the text (without the key, which the caller adds).
  std::function<std::string(PipelineParams&, const std::string&)> set;
};

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string trim(const std::string& s) {
  size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return s.substr(b, e - b);
}

// --- text <-> value, one overload per supported field type -------------------------------------

std::string toText(bool v) { return v ? "true" : "false"; }
std::string toText(int v) { return std::to_string(v); }
std::string toText(double v) {
  // Shortest text that reads back to the same double.
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof(buf), v);
  std::string s(buf, res.ptr);
  // Keep a decimal point so a YAML reader sees a float, not an int.
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}
[[maybe_unused]] std::string toText(const std::string& v) { return v; }

std::string fromText(const std::string& text, bool& out) {
  const std::string t = lower(trim(text));
  if (t == "true" || t == "yes" || t == "on" || t == "1") {
    out = true;
    return {};
  }
  if (t == "false" || t == "no" || t == "off" || t == "0") {
    out = false;
    return {};
  }
  return "expected a boolean (true/false), got '" + text + "'";
}

std::string fromText(const std::string& text, int& out) {
  std::string t = trim(text);
  if (!t.empty() && t[0] == '+') t.erase(0, 1);
  int v = 0;
  const auto res = std::from_chars(t.data(), t.data() + t.size(), v);
  if (t.empty() || res.ec != std::errc() || res.ptr != t.data() + t.size()) {
    return "expected an integer, got '" + text + "'";
  }
  out = v;
  return {};
}

std::string fromText(const std::string& text, double& out) {
  std::string t = trim(text);
  if (!t.empty() && t[0] == '+') t.erase(0, 1);
  double v = 0.0;
  const auto res = std::from_chars(t.data(), t.data() + t.size(), v);
  if (t.empty() || res.ec != std::errc() || res.ptr != t.data() + t.size()) {
    return "expected a number, got '" + text + "'";
  }
  if (!std::isfinite(v)) return "expected a finite number, got '" + text + "'";
  out = v;
  return {};
}

[[maybe_unused]] std::string fromText(const std::string& text, std::string& out) {
  out = text;
  return {};
}

template <typename T>
constexpr ParamType typeOf() {
  if constexpr (std::is_same_v<T, bool>) return ParamType::kBool;
  if constexpr (std::is_same_v<T, int>) return ParamType::kInt;
  if constexpr (std::is_same_v<T, double>) return ParamType::kDouble;
  return ParamType::kString;
}

// A plain field: bool, int, double or std::string.
template <typename Component, typename T>
Entry field(const char* section, const char* name, Component PipelineParams::*component,
            T Component::*member) {
  Entry e;
  e.section = section;
  e.field = name;
  e.type = typeOf<T>();
  e.get = [component, member](const PipelineParams& p) { return toText(p.*component.*member); };
  e.set = [component, member](PipelineParams& p, const std::string& text) {
    T value{};
    std::string err = fromText(text, value);
    if (err.empty()) p.*component.*member = value;
    return err;
  };
  return e;
}

// An enumeration, written as one of its names.
template <typename Component, typename E>
Entry enumField(const char* section, const char* name, Component PipelineParams::*component,
                E Component::*member, std::vector<std::pair<std::string, E>> names) {
  Entry e;
  e.section = section;
  e.field = name;
  e.type = ParamType::kString;
  for (const auto& n : names) e.choices.push_back(n.first);
  e.get = [component, member, names](const PipelineParams& p) {
    for (const auto& n : names)
      if (n.second == p.*component.*member) return n.first;
    return std::string("?");
  };
  e.set = [component, member, names](PipelineParams& p, const std::string& text) {
    const std::string t = lower(trim(text));
    for (const auto& n : names) {
      if (n.first == t) {
        p.*component.*member = n.second;
        return std::string();
      }
    }
    std::string msg = "expected one of";
    for (const auto& n : names) msg += " '" + n.first + "'";
    return msg + ", got '" + text + "'";
  };
  return e;
}

const std::vector<Entry>& table() {
  using PP = PipelineParams;
  static const std::vector<Entry> entries = [] {
    std::vector<Entry> t;
    // --- matcher ---------------------------------------------------------------------------------
    t.push_back(field("matcher", "min_disparity", &PP::matcher, &MatcherParams::min_disparity));
    t.push_back(field("matcher", "max_disparity", &PP::matcher, &MatcherParams::max_disparity));
    t.push_back(field("matcher", "window_min_px", &PP::matcher, &MatcherParams::window_min_px));
    t.push_back(field("matcher", "window_step_px", &PP::matcher, &MatcherParams::window_step_px));
    t.push_back(field("matcher", "window_max_px", &PP::matcher, &MatcherParams::window_max_px));
    t.push_back(field("matcher", "gamma_min", &PP::matcher, &MatcherParams::gamma_min));
    t.push_back(field("matcher", "delta_min", &PP::matcher, &MatcherParams::delta_min));
    t.push_back(field("matcher", "epsilon_px", &PP::matcher, &MatcherParams::epsilon_px));
    t.push_back(field("matcher", "min_ncc", &PP::matcher, &MatcherParams::min_ncc));
    t.push_back(
        field("matcher", "min_ncc_narrowed", &PP::matcher, &MatcherParams::min_ncc_narrowed));
    t.push_back(field("matcher", "window_max_narrowed_px", &PP::matcher,
                      &MatcherParams::window_max_narrowed_px));
    t.push_back(field("matcher", "subpixel", &PP::matcher, &MatcherParams::subpixel));
    t.push_back(field("matcher", "num_threads", &PP::matcher, &MatcherParams::num_threads));
    t.push_back(field("matcher", "edge_disparity_jump_px", &PP::matcher,
                      &MatcherParams::edge_disparity_jump_px));
    t.push_back(field("matcher", "edge_disparity_jump_above_px", &PP::matcher,
                      &MatcherParams::edge_disparity_jump_above_px));
    t.push_back(field("matcher", "edge_margin_px", &PP::matcher, &MatcherParams::edge_margin_px));
    t.push_back(field("matcher", "edge_verify_radius_px", &PP::matcher,
                      &MatcherParams::edge_verify_radius_px));
    t.push_back(field("matcher", "edge_verify_min_ncc", &PP::matcher,
                      &MatcherParams::edge_verify_min_ncc));
    t.push_back(field("matcher", "edge_support_share", &PP::matcher, &MatcherParams::edge_support_share));
    t.push_back(field("matcher", "edge_support_radius_px", &PP::matcher,
                      &MatcherParams::edge_support_radius_px));
    t.push_back(field("matcher", "edge_slope_tolerant", &PP::matcher,
                      &MatcherParams::edge_slope_tolerant));
    // --- filter ----------------------------------------------------------------------------------
    t.push_back(
        field("filter", "remove_outliers", &PP::filter, &PostFilterParams::remove_outliers));
    t.push_back(
        field("filter", "outlier_window_px", &PP::filter, &PostFilterParams::outlier_window_px));
    t.push_back(field("filter", "outlier_disparity_tol_px", &PP::filter,
                      &PostFilterParams::outlier_disparity_tol_px));
    t.push_back(
        field("filter", "outlier_min_share", &PP::filter, &PostFilterParams::outlier_min_share));
    t.push_back(field("filter", "fill_holes", &PP::filter, &PostFilterParams::fill_holes));
    t.push_back(
        field("filter", "fill_max_hole_px", &PP::filter, &PostFilterParams::fill_max_hole_px));
    // --- preprocess ------------------------------------------------------------------------------
    t.push_back(field("preprocess", "downsample", &PP::preprocess, &PreprocessParams::downsample));
    t.push_back(enumField("preprocess", "interlace", &PP::preprocess, &PreprocessParams::interlace,
                          {{"none", InterlaceMode::kNone},
                           {"downsample", InterlaceMode::kDownsample},
                           {"field", InterlaceMode::kField}}));
    t.push_back(
        field("preprocess", "field_parity", &PP::preprocess, &PreprocessParams::field_parity));
    t.push_back(
        field("preprocess", "mono16_bits", &PP::preprocess, &PreprocessParams::mono16_bits));
    // --- rectify ---------------------------------------------------------------------------------
    t.push_back(enumField("rectify", "mode", &PP::rectify, &RectifyParams::mode,
                          {{"calibrated", RectifyMode::kCalibrated},
                           {"uncalibrated", RectifyMode::kUncalibrated},
                           {"pass_through", RectifyMode::kPassThrough}}));
    t.push_back(field("rectify", "alpha", &PP::rectify, &RectifyParams::alpha));
    t.push_back(field("rectify", "zero_disparity", &PP::rectify, &RectifyParams::zero_disparity));
    t.push_back(field("rectify", "output_width_px", &PP::rectify, &RectifyParams::output_width_px));
    t.push_back(
        field("rectify", "output_height_px", &PP::rectify, &RectifyParams::output_height_px));
    t.push_back(field("rectify", "output_scale_x", &PP::rectify, &RectifyParams::output_scale_x));
    t.push_back(field("rectify", "output_scale_y", &PP::rectify, &RectifyParams::output_scale_y));
    t.push_back(
        field("rectify", "fixed_point_maps", &PP::rectify, &RectifyParams::fixed_point_maps));
    t.push_back(enumField("rectify", "method", &PP::rectify, &RectifyParams::method,
                          {{"auto", UncalibratedMethod::kAuto},
                           {"homography", UncalibratedMethod::kHomography},
                           {"polar", UncalibratedMethod::kPolar}}));
    t.push_back(field("rectify", "sift_features", &PP::rectify, &RectifyParams::sift_features));
    t.push_back(field("rectify", "ratio_test", &PP::rectify, &RectifyParams::ratio_test));
    t.push_back(
        field("rectify", "ransac_threshold_px", &PP::rectify, &RectifyParams::ransac_threshold_px));
    t.push_back(
        field("rectify", "ransac_confidence", &PP::rectify, &RectifyParams::ransac_confidence));
    t.push_back(field("rectify", "min_inliers", &PP::rectify, &RectifyParams::min_inliers));
    t.push_back(
        field("rectify", "estimation_frames", &PP::rectify, &RectifyParams::estimation_frames));
    t.push_back(field("rectify", "reestimate_threshold_px", &PP::rectify,
                      &RectifyParams::reestimate_threshold_px));
    t.push_back(
        field("rectify", "reestimate_after", &PP::rectify, &RectifyParams::reestimate_after));
    t.push_back(
        field("rectify", "polar_auto_distance", &PP::rectify, &RectifyParams::polar_auto_distance));
    t.push_back(field("rectify", "focal_px", &PP::rectify, &RectifyParams::focal_px));
    t.push_back(field("rectify", "baseline_m", &PP::rectify, &RectifyParams::baseline_m));
    t.push_back(field("rectify", "quality_stride", &PP::rectify, &RectifyParams::quality_stride));
    t.push_back(field("rectify", "quality_warn_px", &PP::rectify, &RectifyParams::quality_warn_px));
    t.push_back(field("rectify", "quality_max_features", &PP::rectify,
                      &RectifyParams::quality_max_features));
    t.push_back(field("rectify", "row_correction", &PP::rectify, &RectifyParams::row_correction));
    t.push_back(field("rectify", "row_correction_min_matches", &PP::rectify,
                      &RectifyParams::row_correction_min_matches));
    t.push_back(field("rectify", "row_correction_min_px", &PP::rectify,
                      &RectifyParams::row_correction_min_px));
    // --- temporal --------------------------------------------------------------------------------
    t.push_back(field("temporal", "enabled", &PP::temporal, &TemporalParams::enabled));
    t.push_back(
        field("temporal", "prior_radius_px", &PP::temporal, &TemporalParams::prior_radius_px));
    t.push_back(field("temporal", "prior_neighbourhood_px", &PP::temporal,
                      &TemporalParams::prior_neighbourhood_px));
    t.push_back(field("temporal", "prior_edge_zone_px", &PP::temporal,
                      &TemporalParams::prior_edge_zone_px));
    t.push_back(field("temporal", "max_prior_age_frames", &PP::temporal,
                      &TemporalParams::max_prior_age_frames));
    t.push_back(field("temporal", "max_prior_failures", &PP::temporal,
                      &TemporalParams::max_prior_failures));
    t.push_back(field("temporal", "full_range_period_frames", &PP::temporal,
                      &TemporalParams::full_range_period_frames));
    t.push_back(field("temporal", "fallback_larger_windows", &PP::temporal,
                      &TemporalParams::fallback_larger_windows));
    t.push_back(field("temporal", "min_prior_hit_share", &PP::temporal,
                      &TemporalParams::min_prior_hit_share));
    t.push_back(field("temporal", "max_gap_s", &PP::temporal, &TemporalParams::max_gap_s));
    t.push_back(field("temporal", "fused_max_age_frames", &PP::temporal,
                      &TemporalParams::fused_max_age_frames));
    t.push_back(field("temporal", "coverage_within_frames", &PP::temporal,
                      &TemporalParams::coverage_within_frames));
    // --- output ----------------------------------------------------------------------------------
    t.push_back(field("output", "point_cloud", &PP::output, &OutputParams::point_cloud));
    t.push_back(field("output", "fused", &PP::output, &OutputParams::fused));
    t.push_back(field("output", "coverage", &PP::output, &OutputParams::coverage));
    return t;
  }();
  return entries;
}

const Entry* findEntry(const std::string& key) {
  for (const Entry& e : table()) {
    if (key == e.section + "." + e.field) return &e;
  }
  return nullptr;
}

std::string unknownKeyMessage(const std::string& key) {
  const std::string section = key.substr(0, key.find('.'));
  std::string known;
  for (const Entry& e : table()) {
    if (e.section == section) known += (known.empty() ? "" : ", ") + e.field;
  }
  if (known.empty()) {
    std::string sections;
    for (const auto& s : pipelineParamSections()) sections += (sections.empty() ? "" : ", ") + s;
    return "unknown parameter '" + key + "' (sections: " + sections + ")";
  }
  return "unknown parameter '" + key + "' (known in " + section + ": " + known + ")";
}

}  // namespace

const std::vector<std::string>& pipelineParamSections() {
  static const std::vector<std::string> sections = {"matcher", "filter",   "preprocess",
                                                    "rectify", "temporal", "output"};
  return sections;
}

std::string paramTypeName(ParamType type) {
  switch (type) {
    case ParamType::kBool:
      return "bool";
    case ParamType::kInt:
      return "int";
    case ParamType::kDouble:
      return "double";
    case ParamType::kString:
      return "string";
  }
  return "?";
}

std::vector<ParamInfo> listPipelineParams(const PipelineParams& params) {
  std::vector<ParamInfo> out;
  for (const std::string& section : pipelineParamSections()) {
    for (const Entry& e : table()) {
      if (e.section != section) continue;
      ParamInfo info;
      info.key = e.section + "." + e.field;
      info.section = e.section;
      info.field = e.field;
      info.type = e.type;
      info.value = e.get(params);
      info.choices = e.choices;
      out.push_back(std::move(info));
    }
  }
  return out;
}

std::string setPipelineParam(PipelineParams& params, const std::string& key,
                             const std::string& value) {
  const Entry* e = findEntry(key);
  if (!e) return unknownKeyMessage(key);
  PipelineParams candidate = params;
  const std::string err = e->set(candidate, value);
  if (!err.empty()) return key + ": " + err;
  params = candidate;
  return {};
}

bool getPipelineParam(const PipelineParams& params, const std::string& key, std::string* value) {
  const Entry* e = findEntry(key);
  if (!e) return false;
  if (value) *value = e->get(params);
  return true;
}

std::string applyParamOverride(PipelineParams& params, const std::string& assignment) {
  const size_t eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0) {
    return "malformed override '" + assignment + "' (expected section.field=value)";
  }
  return setPipelineParam(params, trim(assignment.substr(0, eq)), assignment.substr(eq + 1));
}

std::string loadPipelineParamsFromString(const std::string& yaml_text, PipelineParams& params,
                                         const std::string& source) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& ex) {
    return source + ": not valid YAML: " + ex.what();
  }
  if (root.IsNull()) return {};  // an empty file changes nothing
  if (!root.IsMap()) return source + ": expected a map of sections (matcher:, filter:, ...)";
  PipelineParams candidate = params;
  // yaml-cpp throws on keys that are not scalars (a map as a key, found by fuzzing): refused
  // with a message like every other malformed file.
  try {
  for (const auto& section_node : root) {
    const std::string section = section_node.first.as<std::string>();
    if (section == "ros") continue;  // the nodelet's own settings (see params_io.hpp)
    const auto& sections = pipelineParamSections();
    if (std::find(sections.begin(), sections.end(), section) == sections.end()) {
      return source + ": " + unknownKeyMessage(section);
    }
    const YAML::Node& body = section_node.second;
    if (body.IsNull()) continue;
    if (!body.IsMap()) return source + ": section '" + section + "' must be a map of field: value";
    for (const auto& kv : body) {
      const std::string key = section + "." + kv.first.as<std::string>();
      if (!kv.second.IsScalar()) {
        return source + ": " + key + ": expected a single value, got a " +
               (kv.second.IsNull() ? std::string("null") : std::string("list or map"));
      }
      const std::string err = setPipelineParam(candidate, key, kv.second.Scalar());
      if (!err.empty()) return source + ": " + err;
    }
  }
  } catch (const YAML::Exception& ex) {
    return source + ": malformed parameter file: " + ex.what();
  }
  params = candidate;
  return {};
}

std::string loadPipelineParams(const std::string& path, PipelineParams& params) {
  std::ifstream in(path);
  if (!in) return "cannot read parameter file '" + path + "'";
  std::stringstream buffer;
  buffer << in.rdbuf();
  return loadPipelineParamsFromString(buffer.str(), params, path);
}

std::string pipelineParamsToYaml(const PipelineParams& params) {
  std::ostringstream out;
  out << "# endo_stereo pipeline parameters (keys: params_io.hpp)\n";
  std::string current;
  for (const ParamInfo& p : listPipelineParams(params)) {
    if (p.section != current) {
      out << p.section << ":\n";
      current = p.section;
    }
    std::string value = p.value;
    if (p.type == ParamType::kString) {
      // Quote so that text like "on" or "" stays a string.
      std::string escaped;
      for (char c : value) {
        if (c == '"' || c == '\\') escaped.push_back('\\');
        escaped.push_back(c);
      }
      value = "\"" + escaped + "\"";
    }
    out << "  " << p.field << ": " << value << "\n";
  }
  return out.str();
}

}  // namespace endo_stereo
