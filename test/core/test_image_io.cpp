// PFM round trips (Middlebury convention) and the disparity colour map.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <opencv2/core.hpp>
#include <string>

#include "endo_stereo/core/image_io.hpp"

namespace {

using endo_stereo::colorizeDisparity;
using endo_stereo::readPfm;
using endo_stereo::writePfm;

std::string tempPath(const std::string& name) {
  const char* dir = std::getenv("TMPDIR");
  return std::string(dir ? dir : "/tmp") + "/es_test_image_io_" + std::to_string(::getpid()) + "_" +
         name;
}

cv::Mat rampWithHoles() {
  cv::Mat d(7, 11, CV_32FC1);
  for (int y = 0; y < d.rows; ++y)
    for (int x = 0; x < d.cols; ++x) d.at<float>(y, x) = 0.25f * x + 10.0f * y - 3.5f;
  d.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  d.at<float>(6, 10) = std::numeric_limits<float>::quiet_NaN();
  d.at<float>(3, 4) = std::numeric_limits<float>::quiet_NaN();
  return d;
}

TEST(Pfm, RoundTripIsBitExactWithNaNForInvalid) {
  const cv::Mat d = rampWithHoles();
  const std::string path = tempPath("roundtrip.pfm");
  std::string error;
  ASSERT_TRUE(writePfm(path, d, &error)) << error;
  const cv::Mat back = readPfm(path, &error);
  ASSERT_FALSE(back.empty()) << error;
  ASSERT_EQ(back.type(), CV_32FC1);
  ASSERT_EQ(back.size(), d.size());
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const float a = d.at<float>(y, x), b = back.at<float>(y, x);
      if (std::isnan(a)) {
        EXPECT_TRUE(std::isnan(b)) << y << "," << x;
      } else {
        EXPECT_EQ(a, b) << y << "," << x;  // float32 written and read unchanged: exact
      }
    }
  }
  std::remove(path.c_str());
}

TEST(Pfm, WritesMiddleburyLayoutBottomRowFirstAndInfForInvalid) {
  cv::Mat d(2, 3, CV_32FC1);
  d.at<float>(0, 0) = 1.f;
  d.at<float>(0, 1) = 2.f;
  d.at<float>(0, 2) = 3.f;
  d.at<float>(1, 0) = 4.f;
  d.at<float>(1, 1) = std::numeric_limits<float>::quiet_NaN();
  d.at<float>(1, 2) = 6.f;
  const std::string path = tempPath("layout.pfm");
  ASSERT_TRUE(writePfm(path, d));
  std::ifstream in(path, std::ios::binary);
  std::string magic, scale;
  int w = 0, h = 0;
  in >> magic >> w >> h >> scale;
  in.get();  // the single separator after the header
  EXPECT_EQ(magic, "Pf");
  EXPECT_EQ(w, 3);
  EXPECT_EQ(h, 2);
  EXPECT_EQ(scale, "-1.0");  // little-endian on this (x86/ARM little-endian) machine
  float data[6];
  in.read(reinterpret_cast<char*>(data), sizeof(data));
  ASSERT_TRUE(in);
  EXPECT_EQ(data[0], 4.f);  // first stored row is the image's bottom row
  EXPECT_TRUE(std::isinf(data[1]) && data[1] > 0);
  EXPECT_EQ(data[2], 6.f);
  EXPECT_EQ(data[3], 1.f);
  std::remove(path.c_str());
}

TEST(Pfm, ReadsBigEndianFiles) {
  const std::string path = tempPath("big.pfm");
  {
    std::ofstream out(path, std::ios::binary);
    out << "Pf\n2 1\n1.0\n";
    const float values[2] = {1.5f, -2.25f};
    for (float v : values) {
      unsigned char b[4];
      std::memcpy(b, &v, 4);
      const unsigned char swapped[4] = {b[3], b[2], b[1], b[0]};
      out.write(reinterpret_cast<const char*>(swapped), 4);
    }
  }
  std::string error;
  const cv::Mat m = readPfm(path, &error);
  ASSERT_FALSE(m.empty()) << error;
  EXPECT_EQ(m.at<float>(0, 0), 1.5f);
  EXPECT_EQ(m.at<float>(0, 1), -2.25f);
  std::remove(path.c_str());
}

TEST(Pfm, RejectsMissingTruncatedAndForeignFilesWithAMessage) {
  std::string error;
  EXPECT_TRUE(readPfm(tempPath("does_not_exist.pfm"), &error).empty());
  EXPECT_NE(error.find("cannot open"), std::string::npos) << error;

  const std::string truncated = tempPath("truncated.pfm");
  {
    std::ofstream out(truncated, std::ios::binary);
    out << "Pf\n4 4\n-1.0\n";
    const float v = 1.f;
    out.write(reinterpret_cast<const char*>(&v), 4);
  }
  error.clear();
  EXPECT_TRUE(readPfm(truncated, &error).empty());
  EXPECT_NE(error.find("truncated"), std::string::npos) << error;

  const std::string png = tempPath("not_a.pfm");
  {
    std::ofstream out(png, std::ios::binary);
    out << "\x89PNG\r\n";
  }
  error.clear();
  EXPECT_TRUE(readPfm(png, &error).empty());
  EXPECT_NE(error.find("not a PFM"), std::string::npos) << error;

  const std::string color = tempPath("color.pfm");
  {
    std::ofstream out(color, std::ios::binary);
    out << "PF\n1 1\n-1.0\n";
    const float v[3] = {1.f, 2.f, 3.f};
    out.write(reinterpret_cast<const char*>(v), sizeof(v));
  }
  error.clear();
  EXPECT_TRUE(readPfm(color, &error).empty());
  EXPECT_NE(error.find("3-channel"), std::string::npos) << error;
  std::remove(truncated.c_str());
  std::remove(png.c_str());
  std::remove(color.c_str());
}

TEST(Pfm, RefusesWrongTypeAndUnwritablePath) {
  std::string error;
  EXPECT_FALSE(writePfm(tempPath("u8.pfm"), cv::Mat(2, 2, CV_8UC1, cv::Scalar(1)), &error));
  EXPECT_NE(error.find("CV_32FC1"), std::string::npos) << error;
  error.clear();
  EXPECT_FALSE(
      writePfm("/nonexistent_dir_es/x.pfm", cv::Mat(2, 2, CV_32FC1, cv::Scalar(1)), &error));
  EXPECT_NE(error.find("cannot open"), std::string::npos) << error;
}

TEST(ColorizeDisparity, PaintsInvalidBlackAndValidNeverBlack) {
  const cv::Mat d = rampWithHoles();
  const cv::Mat c = colorizeDisparity(d, 0.0, 0.0);
  ASSERT_EQ(c.type(), CV_8UC3);
  ASSERT_EQ(c.size(), d.size());
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const cv::Vec3b p = c.at<cv::Vec3b>(y, x);
      if (std::isnan(d.at<float>(y, x))) {
        EXPECT_EQ(p, cv::Vec3b(0, 0, 0));
      } else {
        EXPECT_GT(p[0] + p[1] + p[2], 60) << "valid pixel too dark to tell from invalid";
      }
    }
  }
}

TEST(ColorizeDisparity, MapsRangeEndsToDifferentColoursAndClampsOutside) {
  cv::Mat d(1, 4, CV_32FC1);
  d.at<float>(0, 0) = 10.f;    // d_min
  d.at<float>(0, 1) = 50.f;    // d_max
  d.at<float>(0, 2) = -100.f;  // below the range: same colour as d_min
  d.at<float>(0, 3) = 900.f;   // above: same colour as d_max
  const cv::Mat c = colorizeDisparity(d, 10.0, 50.0);
  EXPECT_NE(c.at<cv::Vec3b>(0, 0), c.at<cv::Vec3b>(0, 1));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 0), c.at<cv::Vec3b>(0, 2));
  EXPECT_EQ(c.at<cv::Vec3b>(0, 1), c.at<cv::Vec3b>(0, 3));
  // Large disparity (near) is the warm end: more red than blue.
  EXPECT_GT(c.at<cv::Vec3b>(0, 1)[2], c.at<cv::Vec3b>(0, 1)[0]);
}

TEST(ColorizeDisparity, HandlesAllInvalidAndConstantImages) {
  cv::Mat nan_image(3, 3, CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  const cv::Mat c = colorizeDisparity(nan_image);
  EXPECT_EQ(cv::countNonZero(c.reshape(1)), 0);
  cv::Mat constant(3, 3, CV_32FC1, cv::Scalar(7.0));
  const cv::Mat k = colorizeDisparity(constant);
  EXPECT_EQ(cv::countNonZero(k.reshape(1)) > 0, true);
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
