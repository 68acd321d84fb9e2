// dynamic_reconfigure <-> PipelineParams. See reconfigure.hpp.
#include "endo_stereo/ros/reconfigure.hpp"

#include <cstdio>

#include <dynamic_reconfigure/Config.h>

#include "endo_stereo/core/params_io.hpp"

namespace endo_stereo {
namespace {

template <typename Entry>
std::string valueText(const Entry& e) {
  return std::to_string(e.value);
}
template <>
std::string valueText(const dynamic_reconfigure::BoolParameter& e) {
  return e.value ? "true" : "false";
}
template <>
std::string valueText(const dynamic_reconfigure::DoubleParameter& e) {
  // to_string keeps 6 decimals only; params_io parses any precision.
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.17g", e.value);
  return buf;
}
template <>
std::string valueText(const dynamic_reconfigure::StrParameter& e) {
  return e.value;
}

template <typename Entries>
std::string applyEntries(const Entries& entries, PipelineParams& p) {
  for (const auto& e : entries) {
    const std::string key = pipelineKeyForConfigName(e.name);
    if (key.empty()) return "reconfigure parameter '" + e.name + "' names no pipeline section";
    const std::string why = setPipelineParam(p, key, valueText(e));
    if (!why.empty()) return "reconfigure parameter '" + e.name + "': " + why;
  }
  return {};
}

}  // namespace

std::string pipelineKeyForConfigName(const std::string& name) {
  for (const std::string& section : pipelineParamSections()) {
    if (name.size() > section.size() + 1 && name.compare(0, section.size(), section) == 0 &&
        name[section.size()] == '_') {
      return section + "." + name.substr(section.size() + 1);
    }
  }
  return {};
}

std::string paramsFromConfig(const EndoStereoConfig& config, const PipelineParams& base,
                             PipelineParams* out) {
  dynamic_reconfigure::Config msg;
  config.__toMessage__(msg);
  PipelineParams p = base;
  std::string e = applyEntries(msg.bools, p);
  if (e.empty()) e = applyEntries(msg.ints, p);
  if (e.empty()) e = applyEntries(msg.doubles, p);
  if (e.empty()) e = applyEntries(msg.strs, p);
  if (!e.empty()) return e;
  *out = p;
  return {};
}

EndoStereoConfig configFromParams(const PipelineParams& params, const EndoStereoConfig& base) {
  dynamic_reconfigure::Config msg;
  base.__toMessage__(msg);
  std::string text;
  for (auto& e : msg.bools) {
    if (getPipelineParam(params, pipelineKeyForConfigName(e.name), &text)) e.value = text == "true";
  }
  for (auto& e : msg.ints) {
    if (getPipelineParam(params, pipelineKeyForConfigName(e.name), &text)) e.value = std::stoi(text);
  }
  for (auto& e : msg.doubles) {
    if (getPipelineParam(params, pipelineKeyForConfigName(e.name), &text)) e.value = std::stod(text);
  }
  for (auto& e : msg.strs) {
    if (getPipelineParam(params, pipelineKeyForConfigName(e.name), &text)) e.value = text;
  }
  EndoStereoConfig config = base;
  config.__fromMessage__(msg);
  return config;
}

}  // namespace endo_stereo
