/**
 * @file json_writer.hpp
 * @brief A minimal streaming JSON writer for the command-line tools' result files
 * (no dependency beyond the standard library). Not thread-safe.
 *
 * @code
 *   JsonWriter j;
 *   j.beginObject();
 *   j.key("density").value(0.83);
 *   j.key("frames").beginArray(); j.value(1); j.endArray();
 *   j.endObject();
 *   std::string text = j.str();
 * @endcode
 */
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

namespace endo_stereo {
namespace tools {

class JsonWriter {
 public:
  JsonWriter& beginObject() {
    open('{');
    return *this;
  }
  JsonWriter& endObject() {
    close('}');
    return *this;
  }
  JsonWriter& beginArray() {
    open('[');
    return *this;
  }
  JsonWriter& endArray() {
    close(']');
    return *this;
  }

  /// Name the next value inside an object.
  JsonWriter& key(const std::string& name) {
    separate();
    newline();
    writeString(name);
    out_ << ": ";
    after_key_ = true;
    return *this;
  }

  JsonWriter& value(const std::string& v) {
    prefix();
    writeString(v);
    return *this;
  }
  JsonWriter& value(const char* v) { return value(std::string(v)); }
  JsonWriter& value(bool v) {
    prefix();
    out_ << (v ? "true" : "false");
    return *this;
  }
  JsonWriter& value(int v) {
    prefix();
    out_ << v;
    return *this;
  }
  JsonWriter& value(int64_t v) {
    prefix();
    out_ << v;
    return *this;
  }
  JsonWriter& value(uint64_t v) {
    prefix();
    out_ << v;
    return *this;
  }
  /// Non-finite numbers have no JSON form: written as null.
  JsonWriter& value(double v) {
    prefix();
    if (!std::isfinite(v)) {
      out_ << "null";
    } else {
      char buf[32];
      std::snprintf(buf, sizeof(buf), "%.6g", v);
      out_ << buf;
    }
    return *this;
  }
  JsonWriter& null() {
    prefix();
    out_ << "null";
    return *this;
  }

  std::string str() const { return out_.str() + "\n"; }

 private:
  void open(char c) {
    prefix();
    out_ << c;
    first_.push_back(true);
  }
  void close(char c) {
    const bool empty = first_.back();
    first_.pop_back();
    if (!empty) newline();
    out_ << c;
  }
  // Before a value: a comma and a line break inside arrays; nothing right after a key.
  void prefix() {
    if (after_key_) {
      after_key_ = false;
      return;
    }
    if (!first_.empty()) {
      separate();
      newline();
    }
  }
  void separate() {
    if (first_.empty()) return;
    if (!first_.back()) out_ << ",";
    first_.back() = false;
  }
  void newline() {
    out_ << "\n";
    for (size_t i = 0; i < first_.size(); ++i) out_ << "  ";
  }
  void writeString(const std::string& s) {
    out_ << '"';
    for (unsigned char c : s) {
      switch (c) {
        case '"':
          out_ << "\\\"";
          break;
        case '\\':
          out_ << "\\\\";
          break;
        case '\n':
          out_ << "\\n";
          break;
        case '\t':
          out_ << "\\t";
          break;
        case '\r':
          out_ << "\\r";
          break;
        default:
          if (c < 0x20) {
            char buf[8];
            std::snprintf(buf, sizeof(buf), "\\u%04x", c);
            out_ << buf;
          } else {
            out_ << static_cast<char>(c);
          }
      }
    }
    out_ << '"';
  }

  std::ostringstream out_;
  std::vector<bool> first_;
  bool after_key_ = false;
};

}  // namespace tools
}  // namespace endo_stereo
