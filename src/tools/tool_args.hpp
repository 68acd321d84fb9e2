/**
 * @file tool_args.hpp
 * @brief The command-line tools' argument reading: flags one by one, values checked as they are
 * read. A value that is not wholly a number of the expected kind, or out of its range, is a usage
 * error whose message names the flag and the text given (exit status kExitUsage). The flags
 * several tools share (input frames, pipeline parameters, search range, threads, --out, --quiet)
 * have one reader, readSharedOption, with each tool's ranges; runTool turns a tool's errors into
 * its messages and exit statuses.
 */
#pragma once

#include <climits>
#include <cstdint>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "frame_sources.hpp"

namespace endo_stereo {
namespace tools {

/// Every tool's exit status for bad usage (unknown flag, missing or bad value).
constexpr int kExitUsage = 2;
/// Every tool's exit status for an input that cannot be read or processed, or an output that
/// cannot be written.
constexpr int kExitInput = 1;

/// Bad usage; what() is the message to print after the tool's name.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// An input that cannot be read or processed, or an output that cannot be written (kExitInput);
/// message is printed after the tool's name.
struct InputError {
  std::string message;
};

/// Runs a tool's @p body and returns its exit status. A UsageError it throws is printed on stderr
/// as "TOOL: message" and gives kExitUsage, an InputError the same way kExitInput, any other
/// std::exception "TOOL: unexpected error: what()" and kExitInput.
int runTool(const char* tool, const std::function<int()>& body);

/// @p text wholly a base-10 integer in [INT_MIN, INT_MAX] ("12", "-3", "+4"); false for "",
/// "1x", "abc", "1e3", " 5", or a value out of range. @p out is set only on success.
bool parseInt(const std::string& text, int* out);
/// As parseInt, for 64-bit integers.
bool parseInt64(const std::string& text, int64_t* out);
/// @p text wholly a finite number ("0.5", "-2", "1e-3"); false for "", "1.5x", "nan", "inf", or
/// a value that overflows a double ("1e999"). @p out is set only on success.
bool parseDouble(const std::string& text, double* out);

/// Splits @p s at @p sep, dropping empty items ("a,,b" -> a, b).
std::vector<std::string> splitList(const std::string& s, char sep);

/// Walks a tool's arguments: `while (args.next()) { if (args.is("--count")) n = args.integer(1);
/// ... else args.unknown(); }`. Every problem throws UsageError.
class ArgReader {
 public:
  ArgReader(int argc, char** argv) : argc_(argc), argv_(argv) {}

  /// Moves to the next argument; false after the last.
  bool next();
  /// The current argument (a flag).
  const std::string& flag() const { return flag_; }
  bool is(const char* name) const { return flag_ == name; }

  /// The value after the flag. @throws UsageError "FLAG needs a value".
  std::string text();
  /// An integer value in [lo, hi]. @throws UsageError "FLAG: expected an integer[ range], got 'V'".
  int integer(int lo = INT_MIN, int hi = INT_MAX);
  /// A 64-bit integer value in [lo, hi].
  int64_t integer64(int64_t lo = INT64_MIN, int64_t hi = INT64_MAX);
  /// A finite number in [lo, hi]. @throws UsageError "FLAG: expected a number[ range], got 'V'".
  double number(double lo = -std::numeric_limits<double>::max(),
                double hi = std::numeric_limits<double>::max());
  /// A finite number > 0. @throws UsageError "FLAG: expected a number > 0, got 'V'".
  double positive();

  /// @throws UsageError "unknown argument 'FLAG' (see --help)".
  [[noreturn]] void unknown() const;

 private:
  [[noreturn]] void bad(const std::string& expected, const std::string& value) const;

  int argc_;
  char** argv_;
  int i_ = 0;
  std::string flag_;
};

/// The flags several tools share, in groups; a tool takes the groups it names in
/// SharedOptions::flags (a bitwise or of these).
enum SharedFlag : unsigned {
  kFlagLeftRight = 1u << 0,       ///< --left PATH, --right PATH
  kFlagFirst = 1u << 1,           ///< --first N
  kFlagCount = 1u << 2,           ///< --count N (>= 1)
  kFlagFps = 1u << 3,             ///< --fps F
  kFlagBag = 1u << 4,             ///< --bag FILE, --namespace NS
  kFlagParams = 1u << 5,          ///< --params FILE, --set KEY=VALUE (repeatable), --calib SPEC
  kFlagDisparityRange = 1u << 6,  ///< --min-disparity N, --max-disparity N
  kFlagThreads = 1u << 7,         ///< --threads N
  kFlagOutDir = 1u << 8,          ///< --out DIR
  kFlagQuiet = 1u << 9,           ///< --quiet
};

/// The lower bounds a tool's shared flags keep (the upper bounds are INT_MAX, DBL_MAX).
struct SharedRanges {
  int first_min = 0;            ///< --first
  int threads_min = 0;          ///< --threads
  int disparity_min = INT_MIN;  ///< --min-disparity, --max-disparity
  bool fps_positive = true;     ///< --fps: a number > 0, else any finite number
};

/// The values of the shared flags, as given (a tool checks how they go together). A tool's own
/// options derive from it: `struct Options : SharedOptions { Options() : SharedOptions(kFlag...) {}
/// ... }`.
struct SharedOptions {
  explicit SharedOptions(unsigned flags_taken, SharedRanges value_ranges = SharedRanges())
      : flags(flags_taken), ranges(value_ranges) {}

  unsigned flags;  ///< the SharedFlag groups the tool takes
  SharedRanges ranges;

  std::string left, right;
  bool has_first = false;
  int first = 0;
  int count = -1;  ///< -1: not given
  double fps = 25.0;
  std::string bag, ns = "/endoscope";  ///< ns as given (a tool normalizes its slashes)
  std::string params_file, calib;
  std::vector<std::string> overrides;  ///< --set, in order
  bool has_min = false, has_max = false;
  int min_disparity = 0, max_disparity = 0;
  bool has_threads = false;
  int threads = 0;
  std::string out_dir;
  bool quiet = false;
};

/// Reads the current flag of @p args into @p o when it is a shared flag of a group in o.flags,
/// consuming and checking its value: "--first: expected an integer >= 0, got 'x'" and the like.
/// @return true when it did, false for any other flag (nothing consumed).
/// @throws UsageError for a missing or bad value.
bool readSharedOption(ArgReader& args, SharedOptions& o);

/// Reads a tool's arguments: --help or -h prints @p usage to stdout and exits with status 0; a
/// shared flag goes to @p o (readSharedOption), any other to @p read_own, which reads it and
/// returns true when it is one of the tool's own flags. @throws UsageError for an unknown flag
/// ("unknown argument 'FLAG' (see --help)") or a missing or bad value.
void readArguments(int argc, char** argv, const char* usage, SharedOptions& o,
                   const std::function<bool(ArgReader&)>& read_own);

/// The frame source settings for the input flags of @p o (files, first, count, fps, bag and
/// namespace); the rest keeps FrameSourceSettings' defaults. A source keeps a reference to its
/// settings: hold the result in a variable that outlives the source.
FrameSourceSettings frameSourceSettings(const SharedOptions& o);

}  // namespace tools
}  // namespace endo_stereo
