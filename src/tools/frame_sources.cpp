// Image-file frame sources of the tools (frame_sources.hpp); the bag source is
// frame_source_bag.cpp.
#include <sys/stat.h>

#include <cctype>
#include <cmath>
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "frame_sources.hpp"

namespace endo_stereo {
namespace tools {

bool fileExists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode);
}

std::string formatPattern(const std::string& pattern, int index) {
  std::vector<char> buf(pattern.size() + 32);
  std::snprintf(buf.data(), buf.size(), pattern.c_str(), index);
  return std::string(buf.data());
}

bool isPattern(const std::string& s) { return s.find('%') != std::string::npos; }

bool validPattern(const std::string& s) {
  int conversions = 0;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] != '%') continue;
    if (i + 1 < s.size() && s[i + 1] == '%') {
      ++i;
      continue;
    }
    size_t j = i + 1;
    while (j < s.size() && std::isdigit(static_cast<unsigned char>(s[j]))) ++j;
    if (j >= s.size() || (s[j] != 'd' && s[j] != 'i')) return false;
    ++conversions;
    i = j;
  }
  return conversions == 1;
}

bool readImage(const std::string& path, cv::Mat& image, std::string& encoding, std::string* error) {
  if (!fileExists(path)) {
    *error = "cannot read image '" + path + "': no such file";
    return false;
  }
  image = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (image.empty()) {
    *error = "cannot read image '" + path + "': not an image format OpenCV reads";
    return false;
  }
  const int depth = image.depth(), channels = image.channels();
  if (depth == CV_16U && channels > 1) {
    image.convertTo(image, CV_8U, 1.0 / 257.0);
  } else if (depth != CV_8U && depth != CV_16U) {
    *error = "image '" + path + "': unsupported pixel depth (8- or 16-bit images only)";
    return false;
  }
  switch (image.type()) {
    case CV_8UC1:
      encoding = "mono8";
      return true;
    case CV_16UC1:
      encoding = "mono16";
      return true;
    case CV_8UC3:
      encoding = "bgr8";
      return true;
    case CV_8UC4:
      encoding = "bgra8";
      return true;
    default:
      *error = "image '" + path + "': unsupported channel count " + std::to_string(channels);
      return false;
  }
}

namespace {

class FileSource : public FrameSource {
 public:
  explicit FileSource(const FrameSourceSettings& o) : o_(o) {
    sequence_ = isPattern(o.left);
    first_ = o.first;
    if (sequence_ && !o.has_first && !fileExists(formatPattern(o.left, 0)) &&
        fileExists(formatPattern(o.left, 1))) {
      first_ = 1;
    }
    if (sequence_) {
      count_ = o.count;
      if (count_ < 0) {
        count_ = 0;
        while (fileExists(formatPattern(o.left, first_ + count_))) ++count_;
      }
    } else {
      count_ = o.repeat > 0 ? o.repeat : o.pan > 0 ? o.pan : 1;
    }
  }
  int size() const override { return count_; }
  std::string emptyReason() const override {
    return count_ > 0 ? "" : "'" + formatPattern(o_.left, first_) + "' does not exist";
  }
  std::string describe() const override {
    std::string d = sequence_
                        ? o_.left + " and " + o_.right + ", frames " + std::to_string(first_) +
                              ".." + std::to_string(first_ + count_ - 1)
                        : o_.left + " and " + o_.right;
    if (o_.repeat > 0) d += ", the same pair " + std::to_string(o_.repeat) + " times";
    if (o_.pan > 0) {
      d += ", " + std::to_string(o_.pan) + " frames of a " + std::to_string(o_.crop.width) + "x" +
           std::to_string(o_.crop.height) + " crop window moving on a circle of radius " +
           std::to_string(o_.pan_radius) + " px, one turn every " + std::to_string(o_.pan_period) +
           " frames";
    } else if (o_.crop.area() > 0) {
      d += ", centre " + std::to_string(o_.crop.width) + "x" + std::to_string(o_.crop.height) +
           " crop";
    }
    return d;
  }
  bool next(Frame& f, std::string* error) override {
    if (n_ >= count_) return false;
    const int index = first_ + (sequence_ ? n_ : 0);
    const std::string lp = sequence_ ? formatPattern(o_.left, index) : o_.left;
    const std::string rp = sequence_ ? formatPattern(o_.right, index) : o_.right;
    if (sequence_ || left_.empty()) {
      if (!readImage(lp, left_, left_enc_, error) || !readImage(rp, right_, right_enc_, error)) {
        return false;
      }
      if (left_.size() != right_.size()) {
        *error = "size mismatch: '" + lp + "' is " + std::to_string(left_.cols) + "x" +
                 std::to_string(left_.rows) + ", '" + rp + "' is " + std::to_string(right_.cols) +
                 "x" + std::to_string(right_.rows);
        return false;
      }
    }
    cv::Point offset(0, 0);
    if (o_.pan > 0) {
      const double t = 2.0 * CV_PI * n_ / o_.pan_period;
      offset = cv::Point(static_cast<int>(std::lround(o_.pan_radius * std::cos(t))),
                         static_cast<int>(std::lround(o_.pan_radius * std::sin(t))));
    }
    if (o_.crop.area() > 0) {
      const cv::Rect roi((left_.cols - o_.crop.width) / 2 + offset.x,
                         (left_.rows - o_.crop.height) / 2 + offset.y, o_.crop.width,
                         o_.crop.height);
      if ((roi & cv::Rect(0, 0, left_.cols, left_.rows)) != roi) {
        *error = "--crop " + std::to_string(o_.crop.width) + "x" + std::to_string(o_.crop.height) +
                 (o_.pan > 0 ? " moved by the pan" : "") + " does not fit the " +
                 std::to_string(left_.cols) + "x" + std::to_string(left_.rows) + " image";
        return false;
      }
      f.input.left = left_(roi).clone();
      f.input.right = right_(roi).clone();
    } else {
      f.input.left = left_.clone();
      f.input.right = right_.clone();
    }
    f.input.left_encoding = left_enc_;
    f.input.right_encoding = right_enc_;
    f.input.stamp_s = (sequence_ ? index : n_) / o_.fps;
    f.name = lp;
    f.index = index;
    f.left_path = lp;
    f.right_path = rp;
    ++n_;
    return true;
  }

 private:
  const FrameSourceSettings& o_;
  bool sequence_ = false;
  int first_ = 0, count_ = 0, n_ = 0;
  cv::Mat left_, right_;
  std::string left_enc_, right_enc_;
};

}  // namespace

std::unique_ptr<FrameSource> makeFileFrameSource(const FrameSourceSettings& settings) {
  return std::make_unique<FileSource>(settings);
}

}  // namespace tools
}  // namespace endo_stereo
