// rostest (test/ros/rgbd.test): the nodelet's RGB-D outputs as an RGB-D consumer reads them. A
// real manager runs the real nodelets; this node publishes stereo pairs and subscribes like a
// SLAM or registration node would: depth/image_rect with depth/camera_info, back-projected
// through image_geometry's PinholeCameraModel (a consumer's own code, not ours), must give the
// points of points2, pixel for pixel; depth must be f T / d of the disparity message, NaN where
// that is invalid; rgb/image_rect_color must be the colour of those points; sizes, encodings,
// frames and stamps must agree, with and without downsampling, with points2 in the optical frame
// or in a target_frame, and in pass_through mode with verged principal points and non-square
// pixels. Without metric geometry nothing of the set is published.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <geometry_msgs/TransformStamped.h>
#include <gtest/gtest.h>
#include <image_geometry/pinhole_camera_model.h>
#include <opencv2/core.hpp>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/image_encodings.h>
#include <stereo_msgs/DisparityImage.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include "endo_stereo/ros/conversions.hpp"
#include "ros_test_utils.hpp"
#include "surgical_scene.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;
namespace enc = sensor_msgs::image_encodings;

// Tolerances. Every value compared below is computed once in double and stored as float32
// (depth, cloud xyz, the DisparityImage's f, T and d), so two honest computations differ by a
// few float roundings: a few times 6e-8 relative. 1e-5 relative (the bar the RGB-D consumers are
// held to) leaves a margin of two orders of magnitude and still catches every convention
// mistake: a principal point off by one pixel moves x by 1/f of z (>= 1e-3 relative here), a
// doffs applied twice changes z by doffs/d (>= 0.1), a focal length off by one pixel by 1/f.
constexpr double kRel = 1e-5;

// The scene: test::calibratedScene() (ros_test_utils.hpp), tissue about 80 mm away.

using Scene = test::CalibratedScene;
const Scene& scene() { return test::calibratedScene(); }

ros::Time nextStamp() {
  static ros::Time t(1700000000, 0);
  t += ros::Duration(0.04);
  return t;
}

/// Stereo input of one namespace: raw images (or rectified ones in pass_through mode) and latched
/// camera_info.
struct Input {
  ros::Publisher left, right, left_info, right_info;
  Input(const std::string& ns, bool rectified) {
    ros::NodeHandle nh(ns);
    const std::string image = rectified ? "image_rect" : "image_raw";
    left = nh.advertise<sensor_msgs::Image>("left/" + image, 5);
    right = nh.advertise<sensor_msgs::Image>("right/" + image, 5);
    left_info = nh.advertise<sensor_msgs::CameraInfo>("left/camera_info", 1, true);
    right_info = nh.advertise<sensor_msgs::CameraInfo>("right/camera_info", 1, true);
  }
  bool subscribed() const { return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0; }
  void info(const sensor_msgs::CameraInfo& l, const sensor_msgs::CameraInfo& r) {
    left_info.publish(l);
    right_info.publish(r);
  }
  void pair(const cv::Mat& l, const cv::Mat& r, const std::string& encoding, const ros::Time& t,
            const std::string& lf, const std::string& rf) {
    left.publish(test::imageMsg(l, encoding, t, lf));
    right.publish(test::imageMsg(r, encoding, t, rf));
  }
};

/// Everything the nodelet of one namespace publishes for one pair, by the pair's stamp.
struct Outputs {
  ros::NodeHandle nh;
  Collector<sensor_msgs::Image> depth, rgb, depth_fused;
  Collector<sensor_msgs::CameraInfo> depth_info, rgb_info;
  Collector<stereo_msgs::DisparityImage> disparity, disparity_fused;
  Collector<sensor_msgs::PointCloud2> points;
  explicit Outputs(const std::string& ns)
      : nh(ns),
        depth(nh, "depth/image_rect"),
        rgb(nh, "rgb/image_rect_color"),
        depth_fused(nh, "depth_fused/image_rect"),
        depth_info(nh, "depth/camera_info"),
        rgb_info(nh, "rgb/camera_info"),
        disparity(nh, "disparity"),
        disparity_fused(nh, "disparity_fused"),
        points(nh, "points2") {}
};

template <class M>
boost::shared_ptr<const M> withStamp(Collector<M>& c, const ros::Time& t) {
  for (const auto& m : c.all()) {
    if (m->header.stamp == t) return m;
  }
  return nullptr;
}

/// One pair's complete output set (null members until all arrived).
struct Frame {
  sensor_msgs::ImageConstPtr depth, rgb, depth_fused;
  sensor_msgs::CameraInfoConstPtr depth_info, rgb_info;
  stereo_msgs::DisparityImageConstPtr disparity, disparity_fused;
  sensor_msgs::PointCloud2ConstPtr points;
};

/// The outputs of the stamp @p t, once all arrived (the fused pair only when @p fused).
bool complete(Outputs& o, const ros::Time& t, bool fused, Frame* f) {
  f->depth = withStamp(o.depth, t);
  f->rgb = withStamp(o.rgb, t);
  f->depth_info = withStamp(o.depth_info, t);
  f->rgb_info = withStamp(o.rgb_info, t);
  f->disparity = withStamp(o.disparity, t);
  f->points = withStamp(o.points, t);
  f->depth_fused = fused ? withStamp(o.depth_fused, t) : nullptr;
  f->disparity_fused = fused ? withStamp(o.disparity_fused, t) : nullptr;
  return f->depth && f->rgb && f->depth_info && f->rgb_info && f->disparity && f->points &&
         (!fused || (f->depth_fused && f->disparity_fused));
}

/// Publish pairs until one stamp has its complete output set. Several pairs are sent when the
/// first is lost to a subscription still connecting or a camera_info that came late.
bool publishUntilComplete(Outputs& o, bool fused, const std::function<void(const ros::Time&)>& send,
                          Frame* f) {
  ros::Time last;
  std::vector<ros::Time> sent;
  return test::publishUntil(
      [&] {
        last = nextStamp();
        sent.push_back(last);
        send(last);
      },
      [&] {
        for (const ros::Time& t : sent) {
          if (complete(o, t, fused, f)) return true;
        }
        return false;
      },
      90.0, 2.0, 30);
}

float pixel(const sensor_msgs::Image& m, int r, int c) {
  float v;
  std::memcpy(&v, m.data.data() + r * m.step + c * sizeof(float), sizeof(float));
  return v;
}

float pixel(const stereo_msgs::DisparityImage& m, int r, int c) { return pixel(m.image, r, c); }

/// depth/camera_info and rgb/camera_info: the same left rectified view at the depth's size.
void expectCameraInfo(const Frame& f) {
  const sensor_msgs::CameraInfo& di = *f.depth_info;
  const sensor_msgs::CameraInfo& ri = *f.rgb_info;
  EXPECT_EQ(di.width, f.depth->width);
  EXPECT_EQ(di.height, f.depth->height);
  EXPECT_EQ(di.binning_x, 0u);
  EXPECT_EQ(di.binning_y, 0u);
  EXPECT_EQ(di.roi.width, 0u);
  EXPECT_EQ(di.header.frame_id, f.depth->header.frame_id);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(di.R[i], (i % 4 == 0) ? 1.0 : 0.0) << "R[" << i << "]";
  for (double d : di.D) EXPECT_EQ(d, 0.0);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) EXPECT_EQ(di.K[3 * r + c], di.P[4 * r + c]) << "K vs P " << r << c;
    EXPECT_EQ(di.P[4 * r + 3], 0.0) << "P(" << r << ",3): the left view has no offset";
  }
  // The DisparityImage's f (float32) is the same focal length.
  EXPECT_NEAR(di.K[0], f.disparity->f, kRel * di.K[0]);
  // rgb/camera_info is depth/camera_info.
  EXPECT_EQ(ri.width, di.width);
  EXPECT_EQ(ri.height, di.height);
  EXPECT_EQ(ri.header.frame_id, di.header.frame_id);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(ri.K[i], di.K[i]);
  for (int i = 0; i < 12; ++i) EXPECT_EQ(ri.P[i], di.P[i]);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(ri.R[i], di.R[i]);
  EXPECT_EQ(ri.D, di.D);
}

/// depth == f T / d of @p disparity per pixel, NaN exactly where there is no positive valid
/// disparity. @return the number of valid depth pixels.
int expectDepthIsFTOverD(const sensor_msgs::Image& depth, const stereo_msgs::DisparityImage& disp) {
  EXPECT_EQ(depth.encoding, enc::TYPE_32FC1);
  EXPECT_EQ(depth.width, disp.image.width);
  EXPECT_EQ(depth.height, disp.image.height);
  EXPECT_EQ(depth.header.stamp, disp.header.stamp);
  EXPECT_EQ(depth.header.frame_id, disp.header.frame_id);
  EXPECT_GT(disp.f, 0.f);
  EXPECT_GT(disp.T, 0.f);
  int valid = 0, mismatched = 0, wrong_nan = 0;
  for (uint32_t r = 0; r < depth.height; ++r) {
    for (uint32_t c = 0; c < depth.width; ++c) {
      const float z = pixel(depth, r, c), d = pixel(disp, r, c);
      // DisparityImage: a value below min_disparity (or not finite) is invalid; Z = f T / d
      // needs d > 0 (d <= 0 is a point at or beyond infinity).
      const bool has = std::isfinite(d) && d >= disp.min_disparity && d > 0.f;
      if (!has) {
        wrong_nan += !std::isnan(z);
        continue;
      }
      const double expected = double(disp.f) * disp.T / d;
      if (!(std::abs(z - expected) <= kRel * expected)) ++mismatched;
      ++valid;
    }
  }
  EXPECT_EQ(wrong_nan, 0) << "depth values where the disparity is invalid";
  EXPECT_EQ(mismatched, 0) << "depth != f T / d (of " << valid << " valid pixels)";
  return valid;
}

/// depth/image_rect back-projected with depth/camera_info through PinholeCameraModel, moved by
/// @p to_cloud (the points2 frame <- depth frame), is points2: the same valid pixels and the same
/// points; the colour of each point is the rgb pixel. @return the number of valid points.
int expectBackProjectionIsPoints2(const Frame& f, const Eigen::Isometry3d& to_cloud) {
  image_geometry::PinholeCameraModel model;
  EXPECT_TRUE(model.fromCameraInfo(*f.depth_info));
  OrganizedCloud cloud;
  std::string error;
  EXPECT_TRUE(ros_conv::fromPointCloud2(*f.points, cloud, &error)) << error;
  if (cloud.xyz.empty()) return 0;
  EXPECT_EQ(cloud.xyz.cols, static_cast<int>(f.depth->width));
  EXPECT_EQ(cloud.xyz.rows, static_cast<int>(f.depth->height));
  if (cloud.xyz.cols != static_cast<int>(f.depth->width) ||
      cloud.xyz.rows != static_cast<int>(f.depth->height)) {
    return 0;
  }
  cv::Mat rgb;
  EXPECT_TRUE(ros_conv::imageToMat(*f.rgb, rgb, &error)) << error;
  int valid = 0, validity_differs = 0, point_differs = 0, colour_differs = 0;
  double worst = 0.0;
  for (int v = 0; v < cloud.xyz.rows; ++v) {
    for (int u = 0; u < cloud.xyz.cols; ++u) {
      const float z = pixel(*f.depth, v, u);
      const cv::Vec3f q = cloud.xyz.at<cv::Vec3f>(v, u);
      if (std::isfinite(z) != std::isfinite(q[2])) {
        ++validity_differs;
        continue;
      }
      if (!std::isfinite(z)) continue;
      ++valid;
      const cv::Point3d ray = model.projectPixelTo3dRay(cv::Point2d(u, v));  // ray.z == 1
      const Eigen::Vector3d p = to_cloud * (Eigen::Vector3d(ray.x, ray.y, ray.z) * double(z));
      const Eigen::Vector3d qd(q[0], q[1], q[2]);
      const double rel = (p - qd).norm() / qd.norm();
      worst = std::max(worst, rel);
      point_differs += !(rel < kRel);
      if (!rgb.empty() && rgb.at<cv::Vec3b>(v, u) != cloud.bgr.at<cv::Vec3b>(v, u)) ++colour_differs;
    }
  }
  std::printf("[ INFO     ] %s: %d points, largest relative difference %.2g\n",
              f.depth->header.frame_id.c_str(), valid, worst);
  EXPECT_EQ(validity_differs, 0) << "pixels valid in depth/image_rect but not in points2 or back";
  EXPECT_EQ(point_differs, 0) << "back-projected points differ from points2 (worst " << worst << ")";
  EXPECT_EQ(colour_differs, 0) << "rgb/image_rect_color is not the colour of the points";
  return valid;
}

/// The checks common to every metric namespace. @return the number of valid depth pixels.
int expectConsistent(const Frame& f, const Eigen::Isometry3d& to_cloud) {
  const sensor_msgs::Image& depth = *f.depth;
  EXPECT_EQ(f.rgb->encoding, enc::BGR8);
  EXPECT_EQ(f.rgb->width, depth.width);
  EXPECT_EQ(f.rgb->height, depth.height);
  EXPECT_EQ(f.points->width, depth.width);
  EXPECT_EQ(f.points->height, depth.height);
  // Left rectified optical frame, the pair's stamp, for all of them (points2 may be elsewhere).
  EXPECT_EQ(f.rgb->header.frame_id, depth.header.frame_id);
  EXPECT_EQ(f.disparity->header.frame_id, depth.header.frame_id);
  EXPECT_EQ(f.rgb->header.stamp, depth.header.stamp);
  EXPECT_EQ(f.depth_info->header.stamp, depth.header.stamp);
  EXPECT_EQ(f.rgb_info->header.stamp, depth.header.stamp);
  expectCameraInfo(f);
  const int valid = expectDepthIsFTOverD(depth, *f.disparity);
  // Not a vacuous pass: the synthetic tissue is mostly matched.
  EXPECT_GT(valid, static_cast<int>(0.3 * depth.width * depth.height));
  EXPECT_EQ(expectBackProjectionIsPoints2(f, to_cloud), valid);
  return valid;
}

// ------------------------------------------------------------------------------------------------

TEST(Rgbd, LazyDepthOnlySubscriptionStartsTheInputs) {
  Input in("/rgbd", false);
  // Nobody listens yet: the inputs stay unsubscribed (absence observed for 1.5 s, several
  // connection round trips on a loaded machine).
  EXPECT_FALSE(waitUntil([&] { return in.left.getNumSubscribers() > 0; }, 1.5));
  {
    ros::NodeHandle nh;
    Collector<sensor_msgs::Image> depth(nh, "/rgbd/depth/image_rect");
    EXPECT_TRUE(waitUntil([&] { return in.subscribed(); }, 20.0))
        << "a subscriber to depth/image_rect alone did not start the inputs";
  }
  EXPECT_TRUE(waitUntil([&] { return in.left.getNumSubscribers() == 0; }, 20.0))
      << "the inputs stayed subscribed after the depth subscriber left";
  {
    ros::NodeHandle nh;
    Collector<sensor_msgs::CameraInfo> info(nh, "/rgbd/rgb/camera_info");
    EXPECT_TRUE(waitUntil([&] { return in.subscribed(); }, 20.0))
        << "a subscriber to rgb/camera_info alone did not start the inputs";
  }
}

/// The calibrated scene's camera_info and pair sent to the nodelet in @p ns until a complete
/// output set (with disparity_fused when @p fused) is in @p f.
bool calibratedSet(const std::string& ns, bool fused, Frame* f) {
  const Scene& s = scene();
  Input in(ns, false);
  Outputs out(ns);
  if (!waitUntil([&] { return in.subscribed(); }, 20.0)) return false;
  in.info(s.left_info, s.right_info);
  return publishUntilComplete(out, fused, [&](const ros::Time& t) {
    in.pair(s.frame.left, s.frame.right, "bgr8", t, s.left_info.header.frame_id,
            s.right_info.header.frame_id);
  }, f);
}

TEST(Rgbd, CalibratedDepthBackProjectsToPoints2) {
  const Scene& s = scene();
  Frame f;
  ASSERT_TRUE(calibratedSet("/rgbd", true, &f)) << "no complete output set";
  EXPECT_EQ(f.depth->width, 320u);
  EXPECT_EQ(f.depth->height, 240u);
  // Points2 in the optical frame (target_frame unset): no transform between them.
  EXPECT_EQ(f.points->header.frame_id, f.depth->header.frame_id);
  expectConsistent(f, Eigen::Isometry3d::Identity());
  // The projection is the rectified left view of the camera_info given (R and P of the
  // calibration are used as they are), bit for bit.
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) EXPECT_EQ(f.depth_info->K[3 * r + c], s.left_info.P[4 * r + c]);
  }
  // depth_fused is f T / d of disparity_fused.
  const int fused_valid = expectDepthIsFTOverD(*f.depth_fused, *f.disparity_fused);
  EXPECT_GT(fused_valid, static_cast<int>(0.3 * 320 * 240));
}

TEST(Rgbd, TargetFrameMovesPoints2AndNotTheDepth) {
  const Scene& s = scene();
  // A pose with a rotation and a translation: rgbd_world <- left optical frame.
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(-0.2, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.01, -0.02, 0.03);
  geometry_msgs::TransformStamped tf = tf2::eigenToTransform(T);
  tf.header.stamp = ros::Time(0);
  tf.header.frame_id = "rgbd_world";
  tf.child_frame_id = s.left_info.header.frame_id;
  tf2_ros::StaticTransformBroadcaster broadcaster;
  broadcaster.sendTransform(tf);

  Frame f;
  ASSERT_TRUE(calibratedSet("/rgbd_tf", false, &f)) << "no complete output set";
  EXPECT_EQ(f.points->header.frame_id, "rgbd_world");
  // The depth image stays in the optical frame of its camera_info, as an RGB-D camera's does.
  EXPECT_EQ(f.depth->header.frame_id, s.left_info.header.frame_id);
  // A consumer moves the back-projected points with the transform tf2 gives it.
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  geometry_msgs::TransformStamped got;
  ASSERT_TRUE(waitUntil([&] {
    try {
      got = buffer.lookupTransform("rgbd_world", f.depth->header.frame_id, f.depth->header.stamp);
      return true;
    } catch (const tf2::TransformException&) {
      return false;
    }
  }, 10.0));
  // The nodelet applies it in float: a rounding of 6e-8 relative to the 3 cm translation and the
  // 8 cm points, well inside kRel of points about 0.1 m from the origin.
  expectConsistent(f, tf2::transformToEigen(got));
}

TEST(Rgbd, DownsamplingKeepsTheFourConsistent) {
  const Scene& s = scene();
  Frame f;
  ASSERT_TRUE(calibratedSet("/rgbd_down", false, &f)) << "no complete output set";
  EXPECT_EQ(f.depth->width, 160u);
  EXPECT_EQ(f.depth->height, 120u);
  expectConsistent(f, Eigen::Isometry3d::Identity());
  // The intrinsics of the half-size view: the calibration's P divided by 2 (CameraInfo binning
  // semantics, cx' = cx / 2); a division by two is exact in binary.
  EXPECT_EQ(f.depth_info->K[0], s.left_info.P[0] / 2);
  EXPECT_EQ(f.depth_info->K[2], s.left_info.P[2] / 2);
  EXPECT_EQ(f.depth_info->K[4], s.left_info.P[5] / 2);
  EXPECT_EQ(f.depth_info->K[5], s.left_info.P[6] / 2);
}

TEST(Rgbd, PassThroughWithVergedPrincipalPointsAndNonSquarePixels) {
  // A textured fronto-parallel plane: the right view is the left shifted by 14 px. The camera_info
  // puts the right principal point 6 px left of the left one (doffs = 6 px), so the message's
  // disparity is 14 - 6 = 8 px and Z = f T / 8; fy differs from fx.
  constexpr int kW = 200, kH = 150, kShift = 14;
  cv::Mat l(kH, kW, CV_8UC3), r = cv::Mat::zeros(kH, kW, CV_8UC3);
  cv::RNG rng(5);
  rng.fill(l, cv::RNG::UNIFORM, 0, 256);
  l.colRange(kShift, kW).copyTo(r.colRange(0, kW - kShift));
  const double fx = 400.0, fy = 380.0, cxl = 101.0, cxr = 95.0, cy = 73.5, B = 0.005;
  sensor_msgs::CameraInfo li, ri;
  for (sensor_msgs::CameraInfo* i : {&li, &ri}) {
    const double cx = i == &li ? cxl : cxr;
    i->width = kW;
    i->height = kH;
    i->K = {fx, 0, cx, 0, fy, cy, 0, 0, 1};
    i->R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    i->P = {fx, 0, cx, i == &li ? 0.0 : -fx * B, 0, fy, cy, 0, 0, 0, 1, 0};
    i->header.frame_id = i == &li ? "pt_left_optical" : "pt_right_optical";
  }
  Input in("/rgbd_pt", true);
  Outputs out("/rgbd_pt");
  ASSERT_TRUE(waitUntil([&] { return in.subscribed(); }, 20.0));
  in.info(li, ri);
  Frame f;
  ASSERT_TRUE(publishUntilComplete(out, false, [&](const ros::Time& t) {
    in.pair(l, r, "bgr8", t, li.header.frame_id, ri.header.frame_id);
  }, &f)) << "no complete output set";
  EXPECT_EQ(f.depth->header.frame_id, "pt_left_optical");
  EXPECT_EQ(f.depth_info->K[0], fx);
  EXPECT_EQ(f.depth_info->K[2], cxl);
  EXPECT_EQ(f.depth_info->K[4], fy);
  EXPECT_EQ(f.depth_info->K[5], cy);
  expectConsistent(f, Eigen::Isometry3d::Identity());
  // The plane's depth, where matched: f B / (14 - 6), not f B / 14 (doffs ignored) nor
  // f B / (14 - 12) (doffs applied twice). A pixel counts as on the plane within 0.05 px of
  // disparity (0.05 / 8 relative depth): sub-pixel matching of a noise texture shifted by a whole
  // number of pixels lands much closer (the median is printed), and the wrong conventions are
  // 6 px away.
  const double plane = fx * B / (kShift - (cxl - cxr));
  int on_plane = 0, valid = 0;
  std::vector<double> dev;
  for (uint32_t v = 0; v < f.depth->height; ++v) {
    for (uint32_t u = 0; u < f.depth->width; ++u) {
      const float z = pixel(*f.depth, v, u);
      if (!std::isfinite(z)) continue;
      ++valid;
      on_plane += std::abs(z - plane) <= 0.05 / 8 * plane;
      dev.push_back(std::abs(z - plane) / plane * 8);  // in px of disparity
    }
  }
  ASSERT_FALSE(dev.empty());
  std::nth_element(dev.begin(), dev.begin() + dev.size() / 2, dev.end());
  std::printf("[ INFO     ] plane: %d of %d valid pixels within 0.05 px, median deviation %.2g px\n",
              on_plane, valid, dev[dev.size() / 2]);
  EXPECT_GT(on_plane, 0.95 * valid) << "of " << valid << " valid pixels";
}

TEST(Rgbd, NothingWithoutMetricGeometry) {
  // Uncalibrated without rectify.focal_px and rectify.baseline_m: the disparity comes, but there
  // is no depth in metres and no trustworthy camera_info, so no part of the set is published.
  const Scene& s = scene();
  Input in("/rgbd_unc", false);
  Outputs out("/rgbd_unc");
  ASSERT_TRUE(waitUntil([&] { return in.subscribed(); }, 20.0));
  ASSERT_TRUE(test::publishUntil(
      [&] {
        in.pair(s.frame.left, s.frame.right, "bgr8", nextStamp(), s.left_info.header.frame_id,
                s.right_info.header.frame_id);
      },
      [&] { return out.disparity.count() >= 3; }, 90.0, 2.0));
  // The set would have been published with those disparities; absence is watched for 1 s more
  // (the same machine, already connected subscribers: milliseconds would do).
  EXPECT_FALSE(waitUntil([&] {
    return out.depth.count() + out.depth_info.count() + out.rgb.count() + out.rgb_info.count() > 0;
  }, 1.0));
  EXPECT_EQ(out.depth.count(), 0u);
  EXPECT_EQ(out.depth_info.count(), 0u);
  EXPECT_EQ(out.rgb.count(), 0u);
  EXPECT_EQ(out.rgb_info.count(), 0u);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_rgbd");
}
