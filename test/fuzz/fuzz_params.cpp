// libFuzzer harness: the parameter file loader (params_io.hpp) on any YAML text, and `--set`
// overrides, then what a loaded parameter set does downstream.
//
// Contract checked: loading never throws and fails with a message naming the problem, leaving the
// struct unchanged; what loads is written back by pipelineParamsToYaml() and reads back to the same
// text (the header's round-trip promise); a set that validates constructs a Pipeline, a set that
// does not is refused by the constructor with std::invalid_argument.
#include <stdexcept>

#include "fuzz_common.hpp"

using namespace endo_stereo;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // An optional override line first ("section.field=value\n"), then the YAML document.
  std::string text(reinterpret_cast<const char*>(data), size);
  std::string override_line;
  if (!text.empty() && text[0] == '!') {
    const size_t nl = text.find('\n');
    override_line = text.substr(1, nl == std::string::npos ? std::string::npos : nl - 1);
    text = nl == std::string::npos ? std::string() : text.substr(nl + 1);
  }

  PipelineParams params;
  const std::string before = pipelineParamsToYaml(params);
  std::string error;
  ES_FUZZ_NO_THROW(error = loadPipelineParamsFromString(text, params, "fuzz"), "loadPipelineParamsFromString");
  if (!error.empty()) {
    ES_FUZZ_CHECK(pipelineParamsToYaml(params) == before, "a failed load changed the params");
    return 0;
  }
  if (!override_line.empty()) {
    const std::string prior = pipelineParamsToYaml(params);
    std::string oerr;
    ES_FUZZ_NO_THROW(oerr = applyParamOverride(params, override_line), "applyParamOverride");
    if (!oerr.empty()) {
      ES_FUZZ_CHECK(pipelineParamsToYaml(params) == prior, "a failed override changed the params");
    }
  }

  // Round trip: write, load into defaults, write again: the same text.
  const std::string yaml = pipelineParamsToYaml(params);
  PipelineParams reloaded;
  const std::string rerr = loadPipelineParamsFromString(yaml, reloaded, "round trip");
  ES_FUZZ_CHECK(rerr.empty(), "written params do not load back: " + rerr + "\n" + yaml);
  ES_FUZZ_CHECK(pipelineParamsToYaml(reloaded) == yaml, "round trip changed a value:\n" + yaml);
  for (const ParamInfo& info : listPipelineParams(params)) {
    std::string value;
    ES_FUZZ_CHECK(getPipelineParam(params, info.key, &value) && value == info.value,
                  "getPipelineParam disagrees with listPipelineParams for " + info.key);
  }

  const std::string invalid = params.validate();
  try {
    Pipeline pipeline(params);
    ES_FUZZ_CHECK(invalid.empty(), "Pipeline accepted invalid params: " + invalid);
  } catch (const std::invalid_argument& ex) {
    ES_FUZZ_CHECK(!invalid.empty(), std::string("Pipeline refused valid params: ") + ex.what());
  }
  return 0;
}
