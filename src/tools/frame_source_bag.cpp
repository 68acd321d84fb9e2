// The ROS bag frame source of endo_stereo_evaluate (frame_sources.hpp); links rosbag.
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <algorithm>
#include <cstdio>
#include <map>
#include <vector>

#include "endo_stereo/ros/conversions.hpp"
#include "frame_sources.hpp"

namespace endo_stereo {
namespace tools {

namespace {

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
  return makeFileFrameSource(settings);
}

}  // namespace tools
}  // namespace endo_stereo
