// What the benchmark tools record about the machine a figure was measured on (Linux /proc).
#pragma once

#include <fstream>
#include <string>

namespace endo_stereo {
namespace tools {

/// The CPU's model name from /proc/cpuinfo, "unknown" when it cannot be read.
inline std::string cpuModel() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) == 0) {
      const size_t colon = line.find(':');
      if (colon != std::string::npos) return line.substr(colon + 2);
    }
  }
  return "unknown";
}

/// The 1, 5 and 15 minute load averages from /proc/loadavg, as "a b c".
inline std::string loadAverage() {
  std::ifstream in("/proc/loadavg");
  std::string a, b, c;
  in >> a >> b >> c;
  return a + " " + b + " " + c;
}

}  // namespace tools
}  // namespace endo_stereo
