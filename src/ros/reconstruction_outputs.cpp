// The outputs of the ROS side: advertising them (none that is also an input) and publishing a
// processed pair. See reconstruction.hpp for the topics.
#include "endo_stereo/ros/reconstruction.hpp"

#include <algorithm>
#include <cmath>

#include <boost/bind/bind.hpp>
#include <boost/make_shared.hpp>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/image_encodings.h>
#include <stereo_msgs/DisparityImage.h>
#include <tf2_eigen/tf2_eigen.h>

#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/ros/conversions.hpp"

namespace endo_stereo {
namespace {

namespace enc = sensor_msgs::image_encodings;

// Messages are published through shared pointers: a subscriber in the same nodelet manager then
// gets the message itself (no serialisation, no copy), and remote ones are served as before.
template <typename M>
boost::shared_ptr<M> shared(M&& message) {
  return boost::make_shared<M>(std::move(message));
}

// Applies a rigid transform to the xyz of a PointCloud2 written by ros_conv::toPointCloud2
// (x y z float32 at offsets 0, 4, 8); NaN points stay NaN.
void transformCloud(sensor_msgs::PointCloud2& msg, const Eigen::Isometry3d& T) {
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  for (uint32_t r = 0; r < msg.height; ++r) {
    uint8_t* row = msg.data.data() + static_cast<size_t>(r) * msg.row_step;
    for (uint32_t c = 0; c < msg.width; ++c) {
      float* p = reinterpret_cast<float*>(row + static_cast<size_t>(c) * msg.point_step);
      if (!std::isfinite(p[0])) continue;
      const Eigen::Vector3f q = R * Eigen::Vector3f(p[0], p[1], p[2]) + t;
      p[0] = q.x();
      p[1] = q.y();
      p[2] = q.z();
    }
  }
}

}  // namespace

void Reconstruction::advertiseOutputs() {
  // The resolved input names (remappings applied): no output may take one of them, or the node
  // would feed itself (its own subscription keeping it subscribed, its images counted as input).
  std::vector<std::string> inputs = {nh_.resolveName(left_topic_), nh_.resolveName(right_topic_)};
  if (usesCameraInfo()) {
    inputs.push_back(nh_.resolveName("left/camera_info"));
    inputs.push_back(nh_.resolveName("right/camera_info"));
  }
  std::vector<std::string> refused;
  auto allowed = [&](const std::string& name) {
    if (std::find(inputs.begin(), inputs.end(), nh_.resolveName(name)) == inputs.end()) {
      outputs_.push_back(name);
      return true;
    }
    refused.push_back(name);
    ROS_WARN("%s: output %s is not advertised: %s is also an input (check the remappings)",
             name_.c_str(), name.c_str(), nh_.resolveName(name).c_str());
    return false;
  };
  // Advertise under the connect mutex: a connect callback fired by the first advertise must not
  // look at publishers that are not assigned yet (stereo_image_proc does the same).
  std::lock_guard<std::mutex> lock(connect_mutex_);
  ros::SubscriberStatusCallback cb = boost::bind(&Reconstruction::connectCb, this);
  image_transport::SubscriberStatusCallback icb = boost::bind(&Reconstruction::connectCb, this);
  if (allowed("disparity")) {
    pub_disparity_ = nh_.advertise<stereo_msgs::DisparityImage>("disparity", 1, cb, cb);
  }
  if (allowed("points2")) {
    pub_points_ = nh_.advertise<sensor_msgs::PointCloud2>("points2", 1, cb, cb);
  }
  if (allowed("disparity_fused")) {
    pub_fused_ = nh_.advertise<stereo_msgs::DisparityImage>("disparity_fused", 1, cb, cb);
  }
  if (allowed("disparity_color")) pub_disparity_color_ = it_.advertise("disparity_color", 1, icb, icb);
  if (allowed("confidence")) pub_confidence_ = it_.advertise("confidence", 1, icb, icb);
  if (allowed("coverage")) pub_coverage_ = it_.advertise("coverage", 1, icb, icb);
  // The RGB-D outputs: image and camera_info advertised together (image_transport's camera
  // publisher: <ns>/image_rect and <ns>/camera_info), both names checked against the inputs.
  auto camera = [&](const std::string& ns, const std::string& image,
                    image_transport::CameraPublisher& pub) {
    const bool image_ok = allowed(ns + "/" + image);
    const bool info_ok = allowed(ns + "/camera_info");
    if (image_ok && info_ok) pub = it_.advertiseCamera(ns + "/" + image, 1, icb, icb, cb, cb);
  };
  camera("depth", "image_rect", pub_depth_);
  camera("rgb", "image_rect_color", pub_rgb_);
  camera("depth_fused", "image_rect", pub_depth_fused_);
  if (mode_ == RectifyMode::kPassThrough) {
    // The input is the rectified pair: a rectified-image output would repeat it, under the very
    // name of the right input (right/image_rect).
    outputs_note_ = "no rectified images: the input is already rectified";
  } else {
    if (allowed("left/image_rect_color")) {
      pub_left_rect_ = it_.advertise("left/image_rect_color", 1, icb, icb);
    }
    if (allowed("right/image_rect")) pub_right_rect_ = it_.advertise("right/image_rect", 1, icb, icb);
  }
  for (const std::string& r : refused) {
    outputs_note_ += (outputs_note_.empty() ? "" : "; ") + r + " not advertised (an input)";
  }
}

void Reconstruction::selectOutputs() {
  // Fused and coverage outputs are computed while configured or while someone listens; the
  // cloud (8 MB at 960x540) only while configured and someone listens to points2, and the left
  // colour image (conversion + 3-channel remap) only for the cloud, left/image_rect_color or
  // rgb/image_rect_color.
  OutputParams configured;
  {
    std::lock_guard<std::mutex> lock(params_mutex_);
    configured = params_.output;
  }
  PipelineParams p = pipeline_->params();
  const bool want_fused = configured.fused || pub_fused_.getNumSubscribers() > 0 ||
                          pub_depth_fused_.getNumSubscribers() > 0;
  const bool want_cov = configured.coverage || pub_coverage_.getNumSubscribers() > 0;
  const bool want_cloud = configured.point_cloud && pub_points_.getNumSubscribers() > 0;
  if (p.output.fused != want_fused || p.output.coverage != want_cov ||
      p.output.point_cloud != want_cloud) {
    p.output.fused = want_fused;
    p.output.coverage = want_cov;
    p.output.point_cloud = want_cloud;
    pipeline_->setParams(p);
  }
  pipeline_->setColorOutput(pub_left_rect_.getNumSubscribers() > 0 ||
                            pub_rgb_.getNumSubscribers() > 0);
}

void Reconstruction::publishOutputs(const Pair& pair, const PipelineOutput& out) {
  std_msgs::Header header;
  header.stamp = pair.left->header.stamp;
  if (!ros_params_.frame_id.empty()) {
    header.frame_id = ros_params_.frame_id;
  } else if (!out.geometry.frame_id.empty()) {
    header.frame_id = out.geometry.frame_id;
  } else {
    header.frame_id = pair.left->header.frame_id;
  }
  const PipelineParams& p = pipeline_->params();

  // Depth from disparity needs a metric, non-polar geometry; otherwise f and T are written as 0
  // so no consumer mistakes the disparity for one it can triangulate.
  RectifiedGeometry g = out.geometry;
  const bool depth_ok = g.metric && !g.polar && g.f_px > 0.0 && g.baseline_m > 0.0;
  if (!depth_ok) {
    if (g.polar) g.f_px = 0.0;
    g.baseline_m = 0.0;
  }
  ros_conv::DisparityRange range;
  range.min_disparity = p.matcher.min_disparity;
  range.max_disparity = p.matcher.max_disparity;
  range.delta_d = p.matcher.subpixel ? ros_params_.subpixel_delta_d : 1.0;

  if (pub_disparity_.getNumSubscribers() > 0) {
    pub_disparity_.publish(
        shared(ros_conv::toDisparityImage(out.match.disparity, g, range, header)));
  }
  if (pub_disparity_color_.getNumSubscribers() > 0) {
    // A fixed colour scale (the search range) keeps colours comparable from frame to frame.
    pub_disparity_color_.publish(shared(ros_conv::matToImage(
        colorizeDisparity(out.match.disparity, range.min_disparity, range.max_disparity),
        enc::BGR8, header)));
  }
  if (pub_fused_.getNumSubscribers() > 0 && !out.fused_disparity.empty()) {
    pub_fused_.publish(shared(ros_conv::toDisparityImage(out.fused_disparity, g, range, header)));
  }
  if (pub_confidence_.getNumSubscribers() > 0 && !out.match.confidence.empty()) {
    pub_confidence_.publish(
        shared(ros_conv::matToImage(out.match.confidence, enc::TYPE_32FC1, header)));
  }
  if (pub_coverage_.getNumSubscribers() > 0 && !out.coverage.empty()) {
    pub_coverage_.publish(shared(ros_conv::matToImage(out.coverage, enc::MONO16, header)));
  }
  if (pub_left_rect_.getNumSubscribers() > 0 && !out.left_rect_color.empty()) {
    pub_left_rect_.publish(shared(ros_conv::matToImage(out.left_rect_color, enc::BGR8, header)));
  }
  if (pub_right_rect_.getNumSubscribers() > 0 && !out.right_rect_gray.empty()) {
    pub_right_rect_.publish(shared(ros_conv::matToImage(out.right_rect_gray, enc::MONO8, header)));
  }
  publishRgbd(header, out, g, depth_ok);
  if (pub_points_.getNumSubscribers() == 0 || out.cloud.xyz.empty()) return;
  if (!depth_ok || !out.cloud.metric) {
    if (!warned_not_metric_) {
      ROS_WARN("%s: points2 is not published: the geometry is not metric (uncalibrated input "
               "without rectify.focal_px and rectify.baseline_m, or a polar rectification)",
               name_.c_str());
      warned_not_metric_ = true;
    }
    return;
  }
  const auto cloud_msg = shared(ros_conv::toPointCloud2(out.cloud, header));
  sensor_msgs::PointCloud2& cloud = *cloud_msg;
  if (tf_buffer_ && ros_params_.target_frame != header.frame_id) {
    try {
      const geometry_msgs::TransformStamped t = tf_buffer_->lookupTransform(
          ros_params_.target_frame, header.frame_id, header.stamp,
          ros::Duration(ros_params_.tf_timeout_s));
      transformCloud(cloud, tf2::transformToEigen(t));
      cloud.header.frame_id = ros_params_.target_frame;
    } catch (const tf2::TransformException& ex) {
      ROS_WARN_THROTTLE(kThrottleS, "%s: points2 not published: no transform %s <- %s at %.6f: %s",
                        name_.c_str(), ros_params_.target_frame.c_str(), header.frame_id.c_str(),
                        header.stamp.toSec(), ex.what());
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++tf_failures_;
      return;
    }
  }
  pub_points_.publish(cloud_msg);
}

void Reconstruction::publishRgbd(const std_msgs::Header& header, const PipelineOutput& out,
                                 const RectifiedGeometry& g, bool depth_ok) {
  const bool depth = pub_depth_.getNumSubscribers() > 0;
  const bool rgb = pub_rgb_.getNumSubscribers() > 0;
  const bool fused = pub_depth_fused_.getNumSubscribers() > 0 && !out.fused_disparity.empty();
  if (!depth && !rgb && !fused) return;
  if (!depth_ok) {
    // An RGB-D consumer takes depth in metres and a camera_info it can trust: neither exists
    // without a metric, non-polar geometry, so the whole set is withheld (said once).
    if (!warned_no_depth_) {
      ROS_WARN("%s: depth/*, depth_fused/* and rgb/* are not published: the geometry is not "
               "metric (uncalibrated input without rectify.focal_px and rectify.baseline_m, or a "
               "polar rectification)", name_.c_str());
      warned_no_depth_ = true;
    }
    return;
  }
  // One camera_info for the three: they share the left rectified view and the disparity's size.
  const cv::Size size = out.match.disparity.size();
  const auto info =
      shared(ros_conv::rectifiedCameraInfo(g, size.width, size.height, header));
  if (depth) {
    disparityToDepth(out.match.disparity, g, depth_);
    pub_depth_.publish(shared(ros_conv::matToImage(depth_, enc::TYPE_32FC1, header)), info);
  }
  if (rgb && out.left_rect_color.size() == size) {
    pub_rgb_.publish(shared(ros_conv::matToImage(out.left_rect_color, enc::BGR8, header)), info);
  }
  if (fused && out.fused_disparity.size() == size) {
    disparityToDepth(out.fused_disparity, g, depth_);
    pub_depth_fused_.publish(shared(ros_conv::matToImage(depth_, enc::TYPE_32FC1, header)), info);
  }
}

}  // namespace endo_stereo
