// Organized cloud from disparity (doffs applied once, NaN for invalid) and PLY output.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>

#include "endo_stereo/core/point_cloud.hpp"

namespace endo_stereo {
namespace {

RectifiedGeometry vergedGeometry() {
  RectifiedGeometry g;
  g.width = 8;
  g.height = 6;
  g.f_px = 500;
  g.fy_px = 500;
  g.cx_left = 4.0;
  g.cx_right = -16.0;  // doffs = 20 px
  g.cy = 2.5;
  g.baseline_m = 0.005;
  g.metric = true;
  return g;
}

TEST(PointCloud, RecoversKnownPointsWithVergedPrincipalPoints) {
  const RectifiedGeometry g = vergedGeometry();
  // Points X in the left rectified frame project to u = f X/Z + cx_l, and to the right view at
  // u_r = f (X - B)/Z + cx_r, so the measured disparity is u - u_r = f B / Z + doffs.
  cv::Mat disp(g.height, g.width, CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  cv::Mat bgr(g.height, g.width, CV_8UC3, cv::Scalar(10, 20, 30));
  struct P {
    int u, v;
    double z;
  } pts[] = {{1, 1, 0.05}, {6, 4, 0.09}, {3, 5, 0.15}};
  for (const P& p : pts) disp.at<float>(p.v, p.u) = float(g.f_px * g.baseline_m / p.z + g.doffs());
  OrganizedCloud cloud;
  disparityToCloud(disp, bgr, g, cloud);
  ASSERT_EQ(cloud.xyz.type(), CV_32FC3);
  ASSERT_EQ(cloud.xyz.size(), disp.size());
  EXPECT_TRUE(cloud.metric);
  EXPECT_EQ(cloud.countValid(), 3);
  for (const P& p : pts) {
    const cv::Vec3f X = cloud.xyz.at<cv::Vec3f>(p.v, p.u);
    // float storage: 1e-6 relative.
    EXPECT_NEAR(X[2], p.z, 1e-6 * p.z);
    EXPECT_NEAR(X[0], (p.u - g.cx_left) * p.z / g.f_px, 1e-7);
    EXPECT_NEAR(X[1], (p.v - g.cy) * p.z / g.fy_px, 1e-7);
    // stereo_image_proc's double application would put the point far away (or behind).
    const double z_twice = g.f_px * g.baseline_m / (disp.at<float>(p.v, p.u) - 2 * g.doffs());
    EXPECT_GT(std::abs(z_twice - p.z) / p.z, 0.1);
    EXPECT_EQ(cloud.bgr.at<cv::Vec3b>(p.v, p.u), cv::Vec3b(10, 20, 30));
  }
  EXPECT_TRUE(std::isnan(cloud.xyz.at<cv::Vec3f>(0, 0)[0]));
}

TEST(PointCloud, InvalidDisparitiesGiveNan) {
  RectifiedGeometry g = vergedGeometry();
  cv::Mat disp(2, 3, CV_32FC1);
  disp.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  disp.at<float>(0, 1) = std::numeric_limits<float>::infinity();
  disp.at<float>(0, 2) = float(g.doffs());        // point at infinity
  disp.at<float>(1, 0) = float(g.doffs() - 1.0);  // behind the cameras
  disp.at<float>(1, 1) = float(g.doffs() + 25.0);
  disp.at<float>(1, 2) = -3.f;
  OrganizedCloud cloud;
  disparityToCloud(disp, cv::Mat(), g, cloud);
  EXPECT_EQ(cloud.countValid(), 1);
  EXPECT_TRUE(cloud.bgr.empty());
  // A polar geometry has no depth: everything NaN.
  g.polar = true;
  disparityToCloud(disp, cv::Mat(), g, cloud);
  EXPECT_EQ(cloud.countValid(), 0);
}

TEST(PointCloud, NonMetricGeometryIsFlagged) {
  RectifiedGeometry g = vergedGeometry();
  g.metric = false;
  g.baseline_m = 1.0;
  cv::Mat disp(1, 1, CV_32FC1, cv::Scalar(g.doffs() + 10.0));
  OrganizedCloud cloud;
  disparityToCloud(disp, cv::Mat(), g, cloud);
  EXPECT_FALSE(cloud.metric);
  EXPECT_NEAR(cloud.xyz.at<cv::Vec3f>(0, 0)[2], 50.0, 1e-4);  // f * 1 / 10, in baselines
}

TEST(PointCloud, RejectsWrongTypes) {
  OrganizedCloud cloud;
  const RectifiedGeometry g = vergedGeometry();
  EXPECT_THROW(disparityToCloud(cv::Mat(2, 2, CV_16SC1), cv::Mat(), g, cloud),
               std::invalid_argument);
  EXPECT_THROW(disparityToCloud(cv::Mat(2, 2, CV_32FC1), cv::Mat(3, 2, CV_8UC3), g, cloud),
               std::invalid_argument);
}

// The depth image is the cloud's z, pixel for pixel and to the bit (the same arithmetic), so a
// consumer back-projecting it gets the cloud's points; NaN exactly where the cloud has none.
TEST(DepthImage, IsTheCloudsZWithNanWhereNoPoint) {
  RectifiedGeometry g = vergedGeometry();
  cv::Mat disp(g.height, g.width, CV_32FC1);
  cv::RNG rng(11);
  rng.fill(disp, cv::RNG::UNIFORM, g.doffs() - 5.0, g.doffs() + 60.0);  // some behind the rig
  disp.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  disp.at<float>(1, 1) = std::numeric_limits<float>::infinity();
  disp.at<float>(2, 2) = float(g.doffs());  // at infinity
  OrganizedCloud cloud;
  disparityToCloud(disp, cv::Mat(), g, cloud);
  cv::Mat depth;
  disparityToDepth(disp, g, depth);
  ASSERT_EQ(depth.type(), CV_32FC1);
  ASSERT_EQ(depth.size(), disp.size());
  int valid = 0;
  for (int v = 0; v < disp.rows; ++v) {
    for (int u = 0; u < disp.cols; ++u) {
      const float z = depth.at<float>(v, u), cz = cloud.xyz.at<cv::Vec3f>(v, u)[2];
      ASSERT_EQ(std::isfinite(z), std::isfinite(cz)) << "pixel " << u << ", " << v;
      if (!std::isfinite(z)) {
        EXPECT_TRUE(std::isnan(z));
        continue;
      }
      EXPECT_EQ(z, cz);
      ++valid;
    }
  }
  EXPECT_GT(valid, 20);  // most of the 48 pixels lie in front of the rig
  EXPECT_LT(valid, 48);
  g.polar = true;
  disparityToDepth(disp, g, depth);
  EXPECT_EQ(cv::countNonZero(depth == depth), 0);  // NaN != NaN: no pixel equals itself
  EXPECT_THROW(disparityToDepth(cv::Mat(2, 2, CV_16SC1), g, depth), std::invalid_argument);
}

std::string readAll(const std::string& p) {
  std::ifstream is(p, std::ios::binary);
  std::stringstream ss;
  ss << is.rdbuf();
  return ss.str();
}

TEST(PointCloud, WritesAsciiAndBinaryPlyWithValidPointsOnly) {
  const RectifiedGeometry g = vergedGeometry();
  cv::Mat disp(g.height, g.width, CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  disp.at<float>(1, 2) = 45.f;
  disp.at<float>(3, 3) = 60.f;
  cv::Mat bgr(g.height, g.width, CV_8UC3, cv::Scalar(1, 2, 3));
  OrganizedCloud cloud;
  disparityToCloud(disp, bgr, g, cloud);
  const std::string base = "/tmp/es_ply_" + std::to_string(::getpid());
  std::string err;
  ASSERT_TRUE(writePly(base + "_a.ply", cloud, false, &err)) << err;
  ASSERT_TRUE(writePly(base + "_b.ply", cloud, true, &err)) << err;
  const std::string a = readAll(base + "_a.ply"), b = readAll(base + "_b.ply");
  std::remove((base + "_a.ply").c_str());
  std::remove((base + "_b.ply").c_str());
  EXPECT_NE(a.find("format ascii 1.0"), std::string::npos);
  EXPECT_NE(a.find("element vertex 2\n"), std::string::npos);
  EXPECT_NE(a.find("property uchar red"), std::string::npos);
  EXPECT_NE(a.find("metres"), std::string::npos);
  // ASCII body: two lines, colour as R G B.
  const std::string body = a.substr(a.find("end_header\n") + 11);
  EXPECT_EQ(std::count(body.begin(), body.end(), '\n'), 2);
  EXPECT_NE(body.find(" 3 2 1\n"), std::string::npos);
  EXPECT_NE(b.find("format binary_little_endian 1.0"), std::string::npos);
  const size_t header_end = b.find("end_header\n") + 11;
  EXPECT_EQ(b.size() - header_end, 2u * 15u);  // 3 floats + 3 bytes per vertex
  float z;
  std::memcpy(&z, b.data() + header_end + 8, 4);
  EXPECT_NEAR(z, g.f_px * g.baseline_m / (45.0 - g.doffs()), 1e-6);
  EXPECT_FALSE(writePly("/nonexistent/dir/x.ply", cloud, true, &err));
  EXPECT_NE(err.find("/nonexistent/dir/x.ply"), std::string::npos);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
