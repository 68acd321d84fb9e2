// The command-line tools' argument reading (tool_args.hpp).
#include "tool_args.hpp"

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
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

}  // namespace tools
}  // namespace endo_stereo
