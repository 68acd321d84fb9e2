// Private parameters the nodelet does not read. See unknown_params.hpp.
#include "endo_stereo/ros/unknown_params.hpp"

#include <algorithm>

#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/ros/ros_params.hpp"
#include "endo_stereo/ros/stereo_image_proc_params.hpp"
#include "endo_stereo/EndoStereoConfig.h"

namespace endo_stereo {
namespace {

std::string normalised(std::string s) {
  std::replace(s.begin(), s.end(), '/', '_');
  std::transform(s.begin(), s.end(), s.begin(), ::tolower);
  return s;
}

size_t editDistance(const std::string& a, const std::string& b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diag = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diag = up;
    }
  }
  return row[b.size()];
}

}  // namespace

std::vector<std::string> knownPrivateParams() {
  std::vector<std::string> names = {"config_file"};
  for (const std::string& n : rosParamNames()) {
    names.push_back(n);
    names.push_back("ros/" + n);
  }
  for (const ParamInfo& info : listPipelineParams(PipelineParams{})) {
    names.push_back(info.section + "/" + info.field);
  }
  for (const StereoImageProcParam& sip : stereoImageProcParams()) names.push_back(sip.name);
  // dynamic_reconfigure's server keeps its values as private parameters of the same node.
  for (const auto& d : EndoStereoConfig::__getParamDescriptions__()) names.push_back(d->name);
  std::sort(names.begin(), names.end());
  names.erase(std::unique(names.begin(), names.end()), names.end());
  return names;
}

std::string closestParamName(const std::string& name, const std::vector<std::string>& known) {
  const std::string n = normalised(name);
  std::string best;
  size_t best_d = std::string::npos;
  for (const std::string& k : known) {
    const std::string whole = normalised(k);
    const size_t slash = k.rfind('/');
    const std::string last = normalised(slash == std::string::npos ? k : k.substr(slash + 1));
    const size_t d = std::min(editDistance(n, whole), editDistance(n, last));
    if (d < best_d) {
      best_d = d;
      best = k;
    }
  }
  return best_d * 3 <= n.size() ? best : std::string();
}

std::vector<UnknownParam> unknownPrivateParams(const ros::NodeHandle& pnh,
                                               const std::vector<std::string>& known) {
  std::vector<std::string> all;
  pnh.getParamNames(all);
  const std::string prefix = pnh.getNamespace() + "/";
  std::vector<std::string> sections = pipelineParamSections();
  sections.push_back("ros");
  std::vector<UnknownParam> out;
  for (const std::string& full : all) {
    if (full.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string rel = full.substr(prefix.size());
    if (std::binary_search(known.begin(), known.end(), rel)) continue;
    const std::string head = rel.substr(0, rel.find('/'));
    // Under a pipeline section, the loader refuses an unknown key by name (a fatal error).
    if (rel.find('/') != std::string::npos &&
        std::find(sections.begin(), sections.end(), head) != sections.end() && head != "ros") {
      continue;
    }
    out.push_back({rel, closestParamName(rel, known)});
  }
  return out;
}

}  // namespace endo_stereo
