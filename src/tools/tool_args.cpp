// The command-line tools' argument reading (tool_args.hpp).
#include "tool_args.hpp"

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <sstream>

namespace endo_stereo {
namespace tools {

namespace {

// "" for the whole range of T, else " >= lo", " <= hi" or " from lo to hi".
template <typename T>
std::string rangeText(T lo, T hi) {
  const bool has_lo = lo != std::numeric_limits<T>::lowest();
  const bool has_hi = hi != std::numeric_limits<T>::max();
  std::ostringstream s;
  if (has_lo && has_hi) {
    s << " from " << lo << " to " << hi;
  } else if (has_lo) {
    s << " >= " << lo;
  } else if (has_hi) {
    s << " <= " << hi;
  }
  return s.str();
}

// strtoll over the whole text, base 10, no leading space.
bool parseWholeInteger(const std::string& text, long long* out) {
  if (text.empty() || std::isspace(static_cast<unsigned char>(text[0]))) return false;
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(text.c_str(), &end, 10);
  if (*end != '\0' || errno == ERANGE) return false;
  *out = v;
  return true;
}

}  // namespace

bool parseInt(const std::string& text, int* out) {
  long long v = 0;
  if (!parseWholeInteger(text, &v) || v < INT_MIN || v > INT_MAX) return false;
  *out = static_cast<int>(v);
  return true;
}

bool parseInt64(const std::string& text, int64_t* out) {
  long long v = 0;
  if (!parseWholeInteger(text, &v)) return false;
  *out = static_cast<int64_t>(v);
  return true;
}

bool parseDouble(const std::string& text, double* out) {
  if (text.empty() || std::isspace(static_cast<unsigned char>(text[0]))) return false;
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (*end != '\0' || !std::isfinite(v)) return false;
  *out = v;
  return true;
}

std::vector<std::string> splitList(const std::string& s, char sep) {
  std::vector<std::string> out;
  size_t start = 0;
  while (start <= s.size()) {
    const size_t e = s.find(sep, start);
    const std::string item =
        s.substr(start, e == std::string::npos ? std::string::npos : e - start);
    if (!item.empty()) out.push_back(item);
    if (e == std::string::npos) break;
    start = e + 1;
  }
  return out;
}

bool ArgReader::next() {
  if (i_ + 1 >= argc_) return false;
  flag_ = argv_[++i_];
  return true;
}

std::string ArgReader::text() {
  if (i_ + 1 >= argc_) throw UsageError(flag_ + " needs a value");
  return argv_[++i_];
}

int ArgReader::integer(int lo, int hi) {
  const std::string v = text();
  int out = 0;
  if (!parseInt(v, &out) || out < lo || out > hi) bad("an integer" + rangeText(lo, hi), v);
  return out;
}

int64_t ArgReader::integer64(int64_t lo, int64_t hi) {
  const std::string v = text();
  int64_t out = 0;
  if (!parseInt64(v, &out) || out < lo || out > hi) bad("an integer" + rangeText(lo, hi), v);
  return out;
}

double ArgReader::number(double lo, double hi) {
  const std::string v = text();
  double out = 0;
  if (!parseDouble(v, &out) || out < lo || out > hi) bad("a number" + rangeText(lo, hi), v);
  return out;
}

double ArgReader::positive() {
  const std::string v = text();
  double out = 0;
  if (!parseDouble(v, &out) || out <= 0) bad("a number > 0", v);
  return out;
}

void ArgReader::unknown() const {
  throw UsageError("unknown argument '" + flag_ + "' (see --help)");
}

void ArgReader::bad(const std::string& expected, const std::string& value) const {
  throw UsageError(flag_ + ": expected " + expected + ", got '" + value + "'");
}

int runTool(const char* tool, const std::function<int()>& body) {
  try {
    return body();
  } catch (const UsageError& e) {
    std::cerr << tool << ": " << e.what() << "\n";
    return kExitUsage;
  } catch (const InputError& e) {
    std::cerr << tool << ": " << e.message << "\n";
    return kExitInput;
  } catch (const std::exception& e) {
    std::cerr << tool << ": unexpected error: " << e.what() << "\n";
    return kExitInput;
  }
}

namespace {

// The current flag is @p name, of a group @p o takes.
bool takes(const ArgReader& args, const SharedOptions& o, SharedFlag group, const char* name) {
  return (o.flags & group) != 0 && args.is(name);
}

// --left, --right, --first, --count, --fps, --bag, --namespace.
bool readInputOption(ArgReader& args, SharedOptions& o) {
  if (takes(args, o, kFlagLeftRight, "--left")) {
    o.left = args.text();
  } else if (takes(args, o, kFlagLeftRight, "--right")) {
    o.right = args.text();
  } else if (takes(args, o, kFlagFirst, "--first")) {
    o.first = args.integer(o.ranges.first_min);
    o.has_first = true;
  } else if (takes(args, o, kFlagCount, "--count")) {
    o.count = args.integer(1);
  } else if (takes(args, o, kFlagFps, "--fps")) {
    o.fps = o.ranges.fps_positive ? args.positive() : args.number();
  } else if (takes(args, o, kFlagBag, "--bag")) {
    o.bag = args.text();
  } else if (takes(args, o, kFlagBag, "--namespace")) {
    o.ns = args.text();
  } else {
    return false;
  }
  return true;
}

// --params, --set, --calib, --min-disparity, --max-disparity, --threads.
bool readPipelineOption(ArgReader& args, SharedOptions& o) {
  if (takes(args, o, kFlagParams, "--params")) {
    o.params_file = args.text();
  } else if (takes(args, o, kFlagParams, "--set")) {
    o.overrides.push_back(args.text());
  } else if (takes(args, o, kFlagParams, "--calib")) {
    o.calib = args.text();
  } else if (takes(args, o, kFlagDisparityRange, "--min-disparity")) {
    o.min_disparity = args.integer(o.ranges.disparity_min);
    o.has_min = true;
  } else if (takes(args, o, kFlagDisparityRange, "--max-disparity")) {
    o.max_disparity = args.integer(o.ranges.disparity_min);
    o.has_max = true;
  } else if (takes(args, o, kFlagThreads, "--threads")) {
    o.threads = args.integer(o.ranges.threads_min);
    o.has_threads = true;
  } else {
    return false;
  }
  return true;
}

// --out, --quiet.
bool readOutputOption(ArgReader& args, SharedOptions& o) {
  if (takes(args, o, kFlagOutDir, "--out")) {
    o.out_dir = args.text();
  } else if (takes(args, o, kFlagQuiet, "--quiet")) {
    o.quiet = true;
  } else {
    return false;
  }
  return true;
}

}  // namespace

bool readSharedOption(ArgReader& args, SharedOptions& o) {
  return readInputOption(args, o) || readPipelineOption(args, o) || readOutputOption(args, o);
}

void readArguments(int argc, char** argv, const char* usage, SharedOptions& o,
                   const std::function<bool(ArgReader&)>& read_own) {
  ArgReader args(argc, argv);
  while (args.next()) {
    if (args.is("--help") || args.is("-h")) {
      std::cout << usage;
      std::exit(0);
    }
    if (!readSharedOption(args, o) && !read_own(args)) args.unknown();
  }
}

FrameSourceSettings frameSourceSettings(const SharedOptions& o) {
  FrameSourceSettings s;
  s.left = o.left;
  s.right = o.right;
  s.has_first = o.has_first;
  s.first = o.first;
  s.count = o.count;
  s.fps = o.fps;
  s.bag_path = o.bag;
  s.ns = o.ns;
  return s;
}

}  // namespace tools
}  // namespace endo_stereo
