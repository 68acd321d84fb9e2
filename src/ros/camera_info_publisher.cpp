// endo_stereo_camera_info_publisher: publishes the calibration of a stereo rig from two
// camera_info YAML files (`~left_url`, `~right_url`: file:///path, package://pkg/path or a plain
// path) on `left/camera_info` and `right/camera_info`, latched and then once a second. For
// drivers that publish images only (a frame grabber on a da Vinci's video outputs). The
// reconstruction nodelet uses the latest camera_info of each side, so the stamps need not match
// the images'.
#include <ros/package.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/ros/conversions.hpp"

namespace {

// file:// and package:// URLs as camera_info_manager understands them, or a plain path.
std::string resolveUrl(const std::string& url) {
  const std::string file = "file://", package = "package://";
  if (url.compare(0, file.size(), file) == 0) return url.substr(file.size());
  if (url.compare(0, package.size(), package) == 0) {
    const std::string rest = url.substr(package.size());
    const size_t slash = rest.find('/');
    if (slash == std::string::npos) return {};
    const std::string dir = ros::package::getPath(rest.substr(0, slash));
    return dir.empty() ? std::string() : dir + rest.substr(slash);
  }
  return url;
}

bool load(const std::string& url, const std::string& side, sensor_msgs::CameraInfo* info) {
  const std::string path = resolveUrl(url);
  endo_stereo::CameraCalibration c;
  std::string error;
  if (path.empty() || !endo_stereo::loadCameraInfoYaml(path, c, &error)) {
    ROS_FATAL("~%s_url '%s': %s", side.c_str(), url.c_str(),
              path.empty() ? "cannot resolve the URL" : error.c_str());
    return false;
  }
  *info = endo_stereo::ros_conv::toCameraInfo(c);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "endo_stereo_camera_info_publisher");
  ros::NodeHandle nh, pnh("~");
  std::string left_url, right_url, left_frame, right_frame;
  pnh.param("left_url", left_url, std::string());
  pnh.param("right_url", right_url, std::string());
  pnh.param("left_frame_id", left_frame, std::string());
  pnh.param("right_frame_id", right_frame, std::string());
  sensor_msgs::CameraInfo left, right;
  if (!load(left_url, "left", &left) || !load(right_url, "right", &right)) return 1;
  if (!left_frame.empty()) left.header.frame_id = left_frame;
  if (!right_frame.empty()) right.header.frame_id = right_frame;
  ros::Publisher pl = nh.advertise<sensor_msgs::CameraInfo>("left/camera_info", 1, true);
  ros::Publisher pr = nh.advertise<sensor_msgs::CameraInfo>("right/camera_info", 1, true);
  ros::Rate rate(1.0);
  while (ros::ok()) {
    left.header.stamp = right.header.stamp = ros::Time::now();
    pl.publish(left);
    pr.publish(right);
    ros::spinOnce();
    rate.sleep();
  }
  return 0;
}
