// Frame sources of endo_stereo_evaluate (frame_sources.hpp).
#include "frame_sources.hpp"

#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "endo_stereo/ros/conversions.hpp"

namespace endo_stereo {
namespace tools {

namespace {

bool fileExists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode);
}

std::string formatPattern(const std::string& pattern, int index) {
  std::vector<char> buf(pattern.size() + 32);
  std::snprintf(buf.data(), buf.size(), pattern.c_str(), index);
  return std::string(buf.data());
}

}  // namespace

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

namespace {

// Reads an image as stored and names its ROS encoding (16-bit colour scaled to 8 bit).
bool readImage(const std::string& path, cv::Mat& image, std::string& encoding, std::string* error) {
  image = fileExists(path) ? cv::imread(path, cv::IMREAD_UNCHANGED) : cv::Mat();
  if (image.empty()) {
    *error = "cannot read image '" + path + "'";
    return false;
  }
  if (image.depth() == CV_16U && image.channels() > 1) image.convertTo(image, CV_8U, 1.0 / 257.0);
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
      *error = "image '" + path + "': unsupported pixel type (8/16-bit, 1, 3 or 4 channels)";
      return false;
  }
}

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
        *error = "size mismatch between '" + lp + "' and '" + rp + "'";
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

class BagSource : public FrameSource {
 public:
  BagSource(const FrameSourceSettings& o) : o_(o) {
    bag_.open(o.bag_path, rosbag::bagmode::Read);  // throws rosbag::BagException
    left_topic_ = o.ns + "/left/image_raw";
    right_topic_ = o.ns + "/right/image_raw";
    // Count the pairs (left and right images with the same stamp) and read the camera_info.
    std::map<double, int> sides;
    rosbag::View all(bag_, rosbag::TopicQuery(std::vector<std::string>{
                               left_topic_, right_topic_, o.ns + "/left/camera_info",
                               o.ns + "/right/camera_info"}));
    sensor_msgs::CameraInfo::ConstPtr li, ri;
    for (const rosbag::MessageInstance& m : all) {
      if (m.getTopic() == left_topic_ || m.getTopic() == right_topic_) {
        auto img = m.instantiate<sensor_msgs::Image>();
        if (img) sides[img->header.stamp.toSec()] |= m.getTopic() == left_topic_ ? 1 : 2;
      } else if (m.getTopic() == o.ns + "/left/camera_info" && !li) {
        li = m.instantiate<sensor_msgs::CameraInfo>();
      } else if (m.getTopic() == o.ns + "/right/camera_info" && !ri) {
        ri = m.instantiate<sensor_msgs::CameraInfo>();
      }
    }
    for (const auto& kv : sides) pairs_ += kv.second == 3;
    if (o.count > 0) pairs_ = std::min(pairs_, o.count);
    if (li && ri && li->P[0] != 0.0 && ri->P[0] != 0.0) {
      calibration_ = endo_stereo::ros_conv::stereoFromCameraInfo(*li, *ri);
      has_calibration_ = true;
    }
    view_ = std::make_unique<rosbag::View>(
        bag_, rosbag::TopicQuery(std::vector<std::string>{left_topic_, right_topic_}));
    it_ = view_->begin();
  }
  int size() const override { return pairs_; }
  std::string describe() const override {
    return o_.bag_path + " (" + left_topic_ + ", " + right_topic_ + "; " +
           (has_calibration_ ? "rectified with its camera_info"
                             : "no camera_info: taken as rectified") +
           ")";
  }
  bool calibration(endo_stereo::StereoCalibration* c) const override {
    if (has_calibration_) *c = calibration_;
    return has_calibration_;
  }
  bool next(Frame& f, std::string* error) override {
    if (given_ >= pairs_) return false;
    for (; it_ != view_->end(); ++it_) {
      auto img = it_->instantiate<sensor_msgs::Image>();
      if (!img) continue;
      const bool is_left = it_->getTopic() == left_topic_;
      const double stamp = img->header.stamp.toSec();
      auto& mine = is_left ? pending_left_ : pending_right_;
      auto& other = is_left ? pending_right_ : pending_left_;
      mine[stamp] = img;
      auto match = other.find(stamp);
      if (match == other.end()) continue;
      const sensor_msgs::Image::ConstPtr l = is_left ? img : match->second;
      const sensor_msgs::Image::ConstPtr r = is_left ? match->second : img;
      // Older unmatched images are dropped (their partner never came).
      pending_left_.erase(pending_left_.begin(), pending_left_.upper_bound(stamp));
      pending_right_.erase(pending_right_.begin(), pending_right_.upper_bound(stamp));
      ++it_;
      if (!endo_stereo::ros_conv::imageToMat(*l, f.input.left, error) ||
          !endo_stereo::ros_conv::imageToMat(*r, f.input.right, error)) {
        return false;
      }
      f.input.left_encoding = l->encoding;
      f.input.right_encoding = r->encoding;
      f.input.stamp_s = stamp;
      char name[64];
      std::snprintf(name, sizeof(name), "stamp %.6f", stamp);
      f.name = name;
      ++given_;
      return true;
    }
    return false;
  }

 private:
  const FrameSourceSettings& o_;
  rosbag::Bag bag_;
  std::string left_topic_, right_topic_;
  int pairs_ = 0, given_ = 0;
  endo_stereo::StereoCalibration calibration_;
  bool has_calibration_ = false;
  std::unique_ptr<rosbag::View> view_;
  rosbag::View::iterator it_;
  std::map<double, sensor_msgs::Image::ConstPtr> pending_left_, pending_right_;
};

}  // namespace

std::unique_ptr<FrameSource> makeFrameSource(const FrameSourceSettings& settings) {
  if (!settings.bag_path.empty()) return std::make_unique<BagSource>(settings);
  return std::make_unique<FileSource>(settings);
}

}  // namespace tools
}  // namespace endo_stereo
