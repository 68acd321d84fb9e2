// The table of pipeline parameters (private to the params library): one entry per field of the
// params structs, with its key, type, range, meaning and origin, and how to read and write it as
// text. params_io.cpp loads, overrides, lists and writes through it; docs/method.md explains the
// method each parameter belongs to. See params_io.hpp for the public view (ParamInfo).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "endo_stereo/core/params_io.hpp"

namespace endo_stereo {
namespace detail {

struct ParamEntry {
  std::string section;
  std::string field;
  ParamType type = ParamType::kString;
  std::vector<std::string> choices;
  ParamOrigin origin = ParamOrigin::kSetting;
  ParamBounds bounds;
  std::string range;    // as written in the tables ("[0, 2]", "> 0", "odd, >= 3", ...)
  std::string meaning;  // one line
  std::function<std::string(const PipelineParams&)> get;
  // Returns "" or what is wrong with the text (without the key, which the caller adds).
  std::function<std::string(PipelineParams&, const std::string&)> set;
};

/// Every parameter, by section (pipelineParamSections() order), then in the structs' order.
const std::vector<ParamEntry>& paramTable();

/// The entry of "section.field", or nullptr.
const ParamEntry* findParamEntry(const std::string& key);

/// Whitespace trimmed from both ends.
std::string trimText(const std::string& s);

}  // namespace detail
}  // namespace endo_stereo
