// Round trips of the message <-> core conversions and of the reconfigure <-> params bridge.
// No ROS master needed.
#include <cmath>
#include <limits>
#include <map>
#include <set>

#include <gtest/gtest.h>
#include <sensor_msgs/image_encodings.h>

#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/ros/conversions.hpp"
#include "endo_stereo/ros/reconfigure.hpp"

namespace endo_stereo {
namespace {

namespace enc = sensor_msgs::image_encodings;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

CameraCalibration sampleCalibration() {
  CameraCalibration c;
  c.width = 640;
  c.height = 480;
  c.distortion_model = "plumb_bob";
  c.D = {-0.2, 0.05, 0.001, -0.002, 0.01};
  c.K = cv::Matx33d(500.5, 0, 321.25, 0, 499.75, 239.5, 0, 0, 1);
  c.R = cv::Matx33d(0.9998, -0.0175, 0.0087, 0.0175, 0.9998, 0.0, -0.0087, 0.0002, 0.99995);
  c.P = cv::Matx34d(480, 0, 320, -480 * 0.0045, 0, 480, 240, 0, 0, 0, 1, 0);
  c.binning_x = 2;
  c.binning_y = 2;
  c.roi = cv::Rect(10, 20, 600, 440);
  c.frame_id = "endoscope_right_optical";
  return c;
}

TEST(CameraInfoConversion, RoundTripKeepsEveryField) {
  const CameraCalibration c = sampleCalibration();
  const CameraCalibration back = ros_conv::fromCameraInfo(ros_conv::toCameraInfo(c));
  EXPECT_TRUE(back == c);
  EXPECT_EQ(back.frame_id, c.frame_id);
  EXPECT_EQ(back.roi, c.roi);
}

TEST(CameraInfoConversion, ZeroRoiMeansFullImage) {
  sensor_msgs::CameraInfo info = ros_conv::toCameraInfo(sampleCalibration());
  info.roi = sensor_msgs::RegionOfInterest();
  EXPECT_TRUE(ros_conv::fromCameraInfo(info).roi.empty());
}

// The rectified left view as an RGB-D camera_info: K and P from the geometry (fy kept apart from
// fx, the left principal point even with verged ones), R identity, zero distortion, the size
// given, and a message checkCameraInfo accepts for an image of that size.
TEST(CameraInfoConversion, RectifiedLeftViewForDepth) {
  RectifiedGeometry g;
  g.f_px = 685.5;
  g.fy_px = 342.75;  // a single field: half the vertical focal length
  g.cx_left = 159.5;
  g.cx_right = 151.0;
  g.cy = 60.25;
  g.baseline_m = 0.0045;
  g.metric = true;
  std_msgs::Header h;
  h.stamp = ros::Time(1700000000, 40000000);
  h.frame_id = "endoscope_left_optical";
  const sensor_msgs::CameraInfo info = ros_conv::rectifiedCameraInfo(g, 320, 120, h);
  EXPECT_EQ(info.header.stamp, h.stamp);
  EXPECT_EQ(info.header.frame_id, h.frame_id);
  EXPECT_EQ(info.width, 320u);
  EXPECT_EQ(info.height, 120u);
  const boost::array<double, 9> K = {685.5, 0, 159.5, 0, 342.75, 60.25, 0, 0, 1};
  const boost::array<double, 12> P = {685.5, 0, 159.5, 0, 0, 342.75, 60.25, 0, 0, 0, 1, 0};
  const boost::array<double, 9> R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  EXPECT_EQ(info.K, K);
  EXPECT_EQ(info.P, P);
  EXPECT_EQ(info.R, R);
  EXPECT_EQ(info.distortion_model, "plumb_bob");
  EXPECT_EQ(info.D, std::vector<double>(5, 0.0));
  EXPECT_EQ(info.binning_x, 0u);
  EXPECT_EQ(info.roi.width, 0u);
  EXPECT_EQ(ros_conv::checkCameraInfo(info, "depth/camera_info", 320, 120), "");
}

TEST(CameraInfoCheck, NamesTheProblem) {
  sensor_msgs::CameraInfo good = ros_conv::toCameraInfo(sampleCalibration());
  // Binned ROI: 600x440 / 2 = 300x220.
  EXPECT_EQ(ros_conv::checkCameraInfo(good, "left/camera_info", 300, 220), "");
  EXPECT_NE(ros_conv::checkCameraInfo(good, "left/camera_info", 640, 480).find("300x220"),
            std::string::npos);

  sensor_msgs::CameraInfo zero;  // what an uncalibrated driver publishes
  const std::string e = ros_conv::checkCameraInfo(zero, "left/camera_info");
  EXPECT_NE(e.find("left/camera_info"), std::string::npos) << e;
  EXPECT_NE(e.find("width/height"), std::string::npos) << e;

  sensor_msgs::CameraInfo zero_k = good;
  zero_k.K.fill(0.0);
  EXPECT_NE(ros_conv::checkCameraInfo(zero_k, "right/camera_info").find("fx"), std::string::npos);

  sensor_msgs::CameraInfo nan_p = good;
  nan_p.P[2] = std::nan("");
  EXPECT_NE(ros_conv::checkCameraInfo(nan_p, "right/camera_info").find("NaN"), std::string::npos);
}

TEST(ImageConversion, RoundTripForEveryEncoding) {
  const std::pair<const char*, int> cases[] = {{"mono8", CV_8UC1},  {"mono16", CV_16UC1},
                                               {"bgr8", CV_8UC3},   {"rgb8", CV_8UC3},
                                               {"bgra8", CV_8UC4},  {"rgba8", CV_8UC4},
                                               {"yuv422", CV_8UC2}};
  cv::RNG rng(3);
  for (const auto& [encoding, type] : cases) {
    cv::Mat m(7, 5, type);
    rng.fill(m, cv::RNG::UNIFORM, 0, 255);
    std_msgs::Header h;
    h.frame_id = "f";
    const sensor_msgs::Image msg = ros_conv::matToImage(m, encoding, h);
    cv::Mat back;
    std::string error;
    ASSERT_TRUE(ros_conv::imageToMat(msg, back, &error)) << encoding << ": " << error;
    ASSERT_EQ(back.type(), type) << encoding;
    EXPECT_EQ(cv::norm(m, back, cv::NORM_INF), 0.0) << encoding;
  }
}

TEST(ImageConversion, RefusesBadImages) {
  std_msgs::Header h;
  sensor_msgs::Image msg = ros_conv::matToImage(cv::Mat(4, 4, CV_8UC3, cv::Scalar::all(9)), "bgr8", h);
  cv::Mat out;
  std::string error;

  sensor_msgs::Image bayer = msg;
  bayer.encoding = "bayer_rggb8";
  EXPECT_FALSE(ros_conv::imageToMat(bayer, out, &error));
  EXPECT_NE(error.find("unsupported encoding 'bayer_rggb8'"), std::string::npos) << error;

  sensor_msgs::Image short_data = msg;
  short_data.data.resize(10);
  EXPECT_FALSE(ros_conv::imageToMat(short_data, out, &error));

  sensor_msgs::Image empty = msg;
  empty.width = 0;
  EXPECT_FALSE(ros_conv::imageToMat(empty, out, &error));
  EXPECT_NE(error.find("empty"), std::string::npos) << error;
}

TEST(ImageConversion, Mono16BigEndianIsSwapped) {
  std_msgs::Header h;
  cv::Mat m(2, 2, CV_16UC1, cv::Scalar(0x1234));
  sensor_msgs::Image msg = ros_conv::matToImage(m, "mono16", h);
  for (size_t i = 0; i + 1 < msg.data.size(); i += 2) std::swap(msg.data[i], msg.data[i + 1]);
  msg.is_bigendian = 1;
  cv::Mat out;
  std::string error;
  ASSERT_TRUE(ros_conv::imageToMat(msg, out, &error)) << error;
  EXPECT_EQ(out.at<uint16_t>(1, 1), 0x1234);
}

RectifiedGeometry sampleGeometry(double doffs) {
  RectifiedGeometry g;
  g.width = 8;
  g.height = 6;
  g.f_px = 400.0;
  g.cx_left = 4.0 + doffs;
  g.cx_right = 4.0;
  g.cy = 3.0;
  g.baseline_m = 0.005;
  g.metric = true;
  g.frame_id = "left_optical";
  return g;
}

cv::Mat sampleDisparity() {
  cv::Mat d(6, 8, CV_32FC1, cv::Scalar(kNaN));
  d.at<float>(1, 2) = 10.25f;
  d.at<float>(4, 6) = 20.5f;
  d.at<float>(2, 3) = 0.0f;  // zero is a valid disparity (min_disparity 0)
  return d;
}

TEST(DisparityConversion, FieldsFollowTheConventions) {
  const cv::Mat d = sampleDisparity();
  ros_conv::DisparityRange range{0, 31, 0.1};
  std_msgs::Header h;
  h.frame_id = "left_optical";
  h.stamp = ros::Time(12, 34);
  const stereo_msgs::DisparityImage msg =
      ros_conv::toDisparityImage(d, sampleGeometry(0.0), range, h);
  EXPECT_EQ(msg.image.encoding, "32FC1");
  EXPECT_FLOAT_EQ(msg.f, 400.0f);
  EXPECT_FLOAT_EQ(msg.T, 0.005f);
  EXPECT_FLOAT_EQ(msg.min_disparity, 0.0f);
  EXPECT_FLOAT_EQ(msg.max_disparity, 31.0f);
  EXPECT_FLOAT_EQ(msg.delta_d, 0.1f);
  EXPECT_EQ(msg.header.stamp, h.stamp);
  EXPECT_EQ(msg.image.header.frame_id, "left_optical");
  // Bounding box of the valid pixels (2..6 x 1..4), inside the image.
  EXPECT_EQ(msg.valid_window.x_offset, 2u);
  EXPECT_EQ(msg.valid_window.y_offset, 1u);
  EXPECT_EQ(msg.valid_window.width, 5u);
  EXPECT_EQ(msg.valid_window.height, 4u);
  // Invalid pixels hold min_disparity - 1, never NaN.
  const float* p = reinterpret_cast<const float*>(msg.image.data.data());
  EXPECT_FLOAT_EQ(p[0], -1.0f);
  for (size_t i = 0; i < 48; ++i) EXPECT_TRUE(std::isfinite(p[i]));
}

TEST(DisparityConversion, NothingValidGivesAnEmptyWindow) {
  const cv::Mat d(6, 8, CV_32FC1, cv::Scalar(kNaN));
  const stereo_msgs::DisparityImage msg =
      ros_conv::toDisparityImage(d, sampleGeometry(0.0), {0, 15, 1.0}, std_msgs::Header());
  EXPECT_EQ(msg.valid_window.width, 0u);
  EXPECT_EQ(msg.valid_window.height, 0u);
}

TEST(DisparityConversion, RoundTripWithVergedPrincipalPoints) {
  // doffs = 3: the message holds d - 3 so that Z = f T / d_msg; the inverse adds it back.
  const double doffs = 3.0;
  const cv::Mat d = sampleDisparity();
  const stereo_msgs::DisparityImage msg =
      ros_conv::toDisparityImage(d, sampleGeometry(doffs), {0, 31, 1.0}, std_msgs::Header());
  EXPECT_FLOAT_EQ(msg.min_disparity, -3.0f);
  const float* p = reinterpret_cast<const float*>(msg.image.data.data());
  EXPECT_FLOAT_EQ(p[1 * 8 + 2], 7.25f);
  // Z from the message alone equals the core's depth (f B / (d - doffs)).
  EXPECT_NEAR(msg.f * msg.T / p[1 * 8 + 2], sampleGeometry(doffs).depthFromDisparity(10.25), 1e-6);
  std::string error;
  const cv::Mat back = ros_conv::fromDisparityImage(msg, doffs, &error);
  ASSERT_FALSE(back.empty()) << error;
  for (int r = 0; r < d.rows; ++r) {
    for (int c = 0; c < d.cols; ++c) {
      const float a = d.at<float>(r, c), b = back.at<float>(r, c);
      if (std::isnan(a)) {
        EXPECT_TRUE(std::isnan(b)) << r << "," << c;
      } else {
        EXPECT_FLOAT_EQ(a, b) << r << "," << c;
      }
    }
  }
}

TEST(PointCloudConversion, OrganizedLayoutAndRoundTrip) {
  OrganizedCloud cloud;
  cloud.xyz.create(3, 4, CV_32FC3);
  cloud.bgr.create(3, 4, CV_8UC3);
  cv::RNG rng(5);
  rng.fill(cloud.xyz, cv::RNG::UNIFORM, -0.1, 0.1);
  rng.fill(cloud.bgr, cv::RNG::UNIFORM, 0, 255);
  cloud.xyz.at<cv::Vec3f>(1, 2) = cv::Vec3f(kNaN, kNaN, kNaN);
  cloud.metric = true;
  std_msgs::Header h;
  h.frame_id = "left_optical";
  const sensor_msgs::PointCloud2 msg = ros_conv::toPointCloud2(cloud, h);
  EXPECT_EQ(msg.height, 3u);
  EXPECT_EQ(msg.width, 4u);
  EXPECT_FALSE(msg.is_dense);
  ASSERT_EQ(msg.fields.size(), 4u);
  EXPECT_EQ(msg.fields[3].name, "rgb");
  EXPECT_EQ(msg.header.frame_id, "left_optical");
  // The packed colour is 0x00RRGGBB (PCL's PointXYZRGB).
  uint32_t rgb;
  std::memcpy(&rgb, msg.data.data() + 12, 4);
  const cv::Vec3b bgr = cloud.bgr.at<cv::Vec3b>(0, 0);
  EXPECT_EQ(rgb, (uint32_t(bgr[2]) << 16) | (uint32_t(bgr[1]) << 8) | bgr[0]);

  OrganizedCloud back;
  std::string error;
  ASSERT_TRUE(ros_conv::fromPointCloud2(msg, back, &error)) << error;
  EXPECT_TRUE(std::isnan(back.xyz.at<cv::Vec3f>(1, 2)[0]));
  cv::Mat a = cloud.xyz.clone(), b = back.xyz.clone();
  a.at<cv::Vec3f>(1, 2) = b.at<cv::Vec3f>(1, 2) = cv::Vec3f(0, 0, 0);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(cloud.bgr, back.bgr, cv::NORM_INF), 0.0);
}

TEST(PointCloudConversion, RefusesCloudWithoutXyz) {
  sensor_msgs::PointCloud2 msg;
  msg.height = 1;
  msg.width = 1;
  OrganizedCloud cloud;
  std::string error;
  EXPECT_FALSE(ros_conv::fromPointCloud2(msg, cloud, &error));
  EXPECT_NE(error.find("'x'"), std::string::npos) << error;
}

// ---- dynamic_reconfigure bridge ---------------------------------------------------------------

TEST(Reconfigure, EveryNameIsAPipelineKeyAndDefaultsMatchTheStructs) {
  // The .cfg repeats the structs' defaults (dynamic_reconfigure needs them at generation time);
  // this catches the two drifting apart.
  dynamic_reconfigure::Config msg;
  EndoStereoConfig::__getDefault__().__toMessage__(msg);
  const PipelineParams defaults;
  auto check = [&](const std::string& name, const std::string& cfg_value) {
    const std::string key = pipelineKeyForConfigName(name);
    ASSERT_FALSE(key.empty()) << name;
    std::string struct_value;
    ASSERT_TRUE(getPipelineParam(defaults, key, &struct_value)) << key;
    PipelineParams a, b;
    ASSERT_EQ(setPipelineParam(a, key, cfg_value), "") << key;
    ASSERT_EQ(setPipelineParam(b, key, struct_value), "") << key;
    EXPECT_EQ(pipelineParamsToYaml(a), pipelineParamsToYaml(b)) << key << ": cfg default "
                                                                << cfg_value << " vs struct "
                                                                << struct_value;
  };
  for (const auto& e : msg.bools) check(e.name, e.value ? "true" : "false");
  for (const auto& e : msg.ints) check(e.name, std::to_string(e.value));
  for (const auto& e : msg.doubles) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.17g", e.value);
    check(e.name, buf);
  }
  EXPECT_GE(msg.bools.size() + msg.ints.size() + msg.doubles.size(), 25u);
}

// The .cfg's slider limits lie within the ranges of the table of parameters (a slider may stop
// short of an unbounded range, never go past a bound that validate() refuses).
TEST(Reconfigure, SliderLimitsLieWithinTheParameterTable) {
  dynamic_reconfigure::Config lo_msg, hi_msg;
  EndoStereoConfig::__getMin__().__toMessage__(lo_msg);
  EndoStereoConfig::__getMax__().__toMessage__(hi_msg);
  std::map<std::string, ParamInfo> table;
  for (const ParamInfo& info : listPipelineParams(PipelineParams())) table[info.key] = info;
  int checked = 0;
  auto check = [&](const std::string& name, double lo, double hi) {
    const std::string key = pipelineKeyForConfigName(name);
    ASSERT_EQ(table.count(key), 1u) << name;
    const ParamBounds& b = table[key].bounds;
    EXPECT_TRUE(b.lo_open ? lo > b.lo : lo >= b.lo) << name << " slider min " << lo;
    EXPECT_TRUE(b.hi_open ? hi < b.hi : hi <= b.hi) << name << " slider max " << hi;
    ++checked;
  };
  for (size_t i = 0; i < lo_msg.ints.size(); ++i)
    check(lo_msg.ints[i].name, lo_msg.ints[i].value, hi_msg.ints[i].value);
  for (size_t i = 0; i < lo_msg.doubles.size(); ++i)
    check(lo_msg.doubles[i].name, lo_msg.doubles[i].value, hi_msg.doubles[i].value);
  EXPECT_GE(checked, 20);
}

TEST(Reconfigure, CoversEveryMatcherFilterTemporalAndOutputKey) {
  // Requirement: matcher thresholds, search range, priors and outputs are reconfigurable. A field
  // added to one of these structs without a .cfg entry fails here. num_threads is left out on
  // purpose: it does not change results and is set per machine.
  dynamic_reconfigure::Config msg;
  EndoStereoConfig::__getDefault__().__toMessage__(msg);
  std::set<std::string> keys;
  for (const auto& e : msg.bools) keys.insert(pipelineKeyForConfigName(e.name));
  for (const auto& e : msg.ints) keys.insert(pipelineKeyForConfigName(e.name));
  for (const auto& e : msg.doubles) keys.insert(pipelineKeyForConfigName(e.name));
  for (const ParamInfo& info : listPipelineParams(PipelineParams())) {
    if (info.section != "matcher" && info.section != "filter" && info.section != "temporal" &&
        info.section != "output") {
      continue;
    }
    if (info.key == "matcher.num_threads") continue;
    EXPECT_EQ(keys.count(info.key), 1u) << info.key << " has no entry in config/EndoStereo.cfg";
  }
}

TEST(Reconfigure, ParamsRoundTripThroughConfig) {
  PipelineParams p;
  p.matcher.max_disparity = 47;
  p.matcher.delta_min = 0.3;
  p.matcher.subpixel = false;
  p.filter.outlier_min_share = 0.55;
  p.temporal.prior_radius_px = 6;
  p.output.coverage = true;
  const EndoStereoConfig config = configFromParams(p);
  EXPECT_EQ(config.matcher_max_disparity, 47);
  EXPECT_DOUBLE_EQ(config.matcher_delta_min, 0.3);
  PipelineParams back;
  ASSERT_EQ(paramsFromConfig(config, PipelineParams(), &back), "");
  EXPECT_EQ(pipelineParamsToYaml(back), pipelineParamsToYaml(p));
}

TEST(Reconfigure, KeyMapping) {
  EXPECT_EQ(pipelineKeyForConfigName("matcher_delta_min"), "matcher.delta_min");
  EXPECT_EQ(pipelineKeyForConfigName("temporal_max_gap_s"), "temporal.max_gap_s");
  EXPECT_EQ(pipelineKeyForConfigName("nosection_x"), "");
  EXPECT_EQ(pipelineKeyForConfigName("matcher"), "");
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
