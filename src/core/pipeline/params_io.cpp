// YAML presets and key=value overrides for PipelineParams. See params_io.hpp. Every key, its type,
// range and meaning come from the one table of parameters (param_table.cpp).
#include "endo_stereo/core/params_io.hpp"

#include "param_table.hpp"

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

using detail::ParamEntry;
using detail::paramTable;

std::string unknownKeyMessage(const std::string& key) {
  const std::string section = key.substr(0, key.find('.'));
  std::string known;
  for (const ParamEntry& e : paramTable()) {
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

std::string paramOriginName(ParamOrigin origin) {
  switch (origin) {
    case ParamOrigin::kPaper:
      return "paper";
    case ParamOrigin::kOurs:
      return "ours";
    case ParamOrigin::kSetting:
      return "setting";
  }
  return "?";
}

std::string paramTableMarkdown() {
  std::ostringstream out;
  out << "| key | default | range | origin | meaning |\n|---|---|---|---|---|\n";
  for (const ParamInfo& p : listPipelineParams(PipelineParams{})) {
    out << "| `" << p.key << "` | " << p.default_value << " | " << p.range << " | "
        << paramOriginName(p.origin) << " | " << p.meaning << " |\n";
  }
  return out.str();
}

std::vector<ParamInfo> listPipelineParams(const PipelineParams& params) {
  std::vector<ParamInfo> out;
  const PipelineParams defaults;
  for (const std::string& section : pipelineParamSections()) {
    for (const ParamEntry& e : paramTable()) {
      if (e.section != section) continue;
      ParamInfo info;
      info.key = e.section + "." + e.field;
      info.section = e.section;
      info.field = e.field;
      info.type = e.type;
      info.value = e.get(params);
      info.default_value = e.get(defaults);
      info.choices = e.choices;
      info.origin = e.origin;
      info.bounds = e.bounds;
      info.range = e.range;
      info.meaning = e.meaning;
      out.push_back(std::move(info));
    }
  }
  return out;
}

std::string setPipelineParam(PipelineParams& params, const std::string& key,
                             const std::string& value) {
  const ParamEntry* e = detail::findParamEntry(key);
  if (!e) return unknownKeyMessage(key);
  PipelineParams candidate = params;
  const std::string err = e->set(candidate, value);
  if (!err.empty()) return key + ": " + err;
  params = candidate;
  return {};
}

bool getPipelineParam(const PipelineParams& params, const std::string& key, std::string* value) {
  const ParamEntry* e = detail::findParamEntry(key);
  if (!e) return false;
  if (value) *value = e->get(params);
  return true;
}

std::string applyParamOverride(PipelineParams& params, const std::string& assignment) {
  const size_t eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0) {
    return "malformed override '" + assignment + "' (expected section.field=value)";
  }
  return setPipelineParam(params, detail::trimText(assignment.substr(0, eq)), assignment.substr(eq + 1));
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
