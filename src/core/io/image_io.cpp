// PFM reading/writing and disparity pictures. See image_io.hpp.
#include "endo_stereo/core/image_io.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>

namespace endo_stereo {
namespace {

void setError(std::string* error, const std::string& message) {
  if (error) *error = message;
}

bool hostIsLittleEndian() {
  const uint16_t probe = 1;
  uint8_t first = 0;
  std::memcpy(&first, &probe, 1);
  return first == 1;
}

void swapBytes(float* values, size_t count) {
  for (size_t i = 0; i < count; ++i) {
    uint8_t b[4];
    std::memcpy(b, &values[i], 4);
    std::swap(b[0], b[3]);
    std::swap(b[1], b[2]);
    std::memcpy(&values[i], b, 4);
  }
}

// Reads one whitespace-delimited header token; PFM headers are plain ASCII separated by any
// whitespace (most writers use newlines, some use spaces).
bool readToken(std::istream& in, std::string& token) {
  token.clear();
  int c = in.get();
  while (c != EOF && std::isspace(c)) c = in.get();
  while (c != EOF && !std::isspace(c)) {
    token.push_back(static_cast<char>(c));
    if (token.size() > 64) return false;
    c = in.get();
  }
  // The single whitespace character after the scale token separates the header from the data;
  // it has been consumed here, as the format requires.
  return !token.empty();
}

}  // namespace

bool writePfm(const std::string& path, const cv::Mat& disparity, std::string* error) {
  if (disparity.empty() || disparity.type() != CV_32FC1) {
    setError(error, "writePfm: " + path + ": expected a non-empty CV_32FC1 image");
    return false;
  }
  std::ofstream out(path, std::ios::binary);
  if (!out) {
    setError(error, "writePfm: cannot open '" + path + "' for writing");
    return false;
  }
  const bool little = hostIsLittleEndian();
  // A negative scale declares little-endian data; the magnitude carries no meaning for disparity.
  out << "Pf\n"
      << disparity.cols << " " << disparity.rows << "\n"
      << (little ? "-1.0" : "1.0") << "\n";
  const float inf = std::numeric_limits<float>::infinity();
  std::vector<float> row(disparity.cols);
  // PFM stores rows bottom to top.
  for (int y = disparity.rows - 1; y >= 0; --y) {
    const float* src = disparity.ptr<float>(y);
    for (int x = 0; x < disparity.cols; ++x) row[x] = std::isnan(src[x]) ? inf : src[x];
    out.write(reinterpret_cast<const char*>(row.data()),
              static_cast<std::streamsize>(row.size() * sizeof(float)));
  }
  out.flush();
  if (!out) {
    setError(error, "writePfm: write to '" + path + "' failed");
    return false;
  }
  return true;
}

cv::Mat readPfm(const std::string& path, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    setError(error, "readPfm: cannot open '" + path + "'");
    return cv::Mat();
  }
  std::string magic, w_token, h_token, scale_token;
  if (!readToken(in, magic) || (magic != "Pf" && magic != "PF")) {
    setError(error, "readPfm: '" + path + "' is not a PFM file (no Pf/PF header)");
    return cv::Mat();
  }
  if (magic == "PF") {
    setError(error,
             "readPfm: '" + path + "' is a 3-channel PFM; a disparity must have one channel");
    return cv::Mat();
  }
  if (!readToken(in, w_token) || !readToken(in, h_token) || !readToken(in, scale_token)) {
    setError(error, "readPfm: '" + path + "': truncated header");
    return cv::Mat();
  }
  long width = 0, height = 0;
  double scale = 0.0;
  try {
    size_t used = 0;
    width = std::stol(w_token, &used);
    if (used != w_token.size()) throw std::invalid_argument("w");
    height = std::stol(h_token, &used);
    if (used != h_token.size()) throw std::invalid_argument("h");
    scale = std::stod(scale_token, &used);
    if (used != scale_token.size()) throw std::invalid_argument("s");
  } catch (const std::exception&) {
    setError(error, "readPfm: '" + path + "': malformed header (size or scale is not a number)");
    return cv::Mat();
  }
  constexpr long kMaxSide = 1 << 16;
  if (width <= 0 || height <= 0 || width > kMaxSide || height > kMaxSide || scale == 0.0 ||
      !std::isfinite(scale)) {
    setError(error, "readPfm: '" + path + "': bad size " + w_token + "x" + h_token + " or scale " +
                        scale_token);
    return cv::Mat();
  }
  cv::Mat image(static_cast<int>(height), static_cast<int>(width), CV_32FC1);
  const bool file_little = scale < 0.0;
  const bool swap = file_little != hostIsLittleEndian();
  for (int y = image.rows - 1; y >= 0; --y) {
    float* dst = image.ptr<float>(y);
    in.read(reinterpret_cast<char*>(dst), static_cast<std::streamsize>(width * sizeof(float)));
    if (!in) {
      setError(error, "readPfm: '" + path + "': truncated data (expected " + std::to_string(width) +
                          "x" + std::to_string(height) + " floats)");
      return cv::Mat();
    }
    if (swap) swapBytes(dst, static_cast<size_t>(width));
    for (long x = 0; x < width; ++x) {
      if (!std::isfinite(dst[x])) dst[x] = std::numeric_limits<float>::quiet_NaN();
    }
  }
  return image;
}

cv::Mat colorizeDisparity(const cv::Mat& disparity, double d_min, double d_max) {
  CV_Assert(disparity.type() == CV_32FC1);
  if (d_min >= d_max) {
    d_min = std::numeric_limits<double>::infinity();
    d_max = -std::numeric_limits<double>::infinity();
    for (int y = 0; y < disparity.rows; ++y) {
      const float* row = disparity.ptr<float>(y);
      for (int x = 0; x < disparity.cols; ++x) {
        if (std::isfinite(row[x])) {
          d_min = std::min(d_min, static_cast<double>(row[x]));
          d_max = std::max(d_max, static_cast<double>(row[x]));
        }
      }
    }
    if (!(d_min < d_max)) {  // no finite value, or a constant image: any non-empty span works
      if (!std::isfinite(d_min)) d_min = 0.0;
      d_max = d_min + 1.0;
    }
  }
  cv::Mat levels(disparity.size(), CV_8UC1);
  cv::Mat invalid(disparity.size(), CV_8UC1);
  const double scale = 255.0 / (d_max - d_min);
  for (int y = 0; y < disparity.rows; ++y) {
    const float* src = disparity.ptr<float>(y);
    uint8_t* lvl = levels.ptr<uint8_t>(y);
    uint8_t* bad = invalid.ptr<uint8_t>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      const bool ok = std::isfinite(src[x]);
      bad[x] = ok ? 0 : 255;
      const double v = ok ? (src[x] - d_min) * scale : 0.0;
      lvl[x] = cv::saturate_cast<uint8_t>(std::min(255.0, std::max(0.0, v)));
    }
  }
  // Turbo (Mikhailov 2019): a rainbow made perceptually smooth, with no black in it, so invalid
  // pixels painted black cannot be confused with any disparity. Near (large disparity) is red.
  cv::Mat color;
  cv::applyColorMap(levels, color, cv::COLORMAP_TURBO);
  color.setTo(cv::Scalar(0, 0, 0), invalid);
  return color;
}

}  // namespace endo_stereo
