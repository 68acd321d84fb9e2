/**
 * @file tool_args.hpp
 * @brief The command-line tools' argument reading: flags one by one, values checked as they are
 * read. A value that is not wholly a number of the expected kind, or out of its range, is a usage
 * error whose message names the flag and the text given (exit status kExitUsage).
 */
#pragma once

#include <climits>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace endo_stereo {
namespace tools {

/// Every tool's exit status for bad usage (unknown flag, missing or bad value).
constexpr int kExitUsage = 2;

/// Bad usage; what() is the message to print after the tool's name.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

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

}  // namespace tools
}  // namespace endo_stereo
