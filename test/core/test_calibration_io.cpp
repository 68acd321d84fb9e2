// Calibration loading/saving and validation: camera_info YAML, OpenCV stereo YAML, the dataset
// formats, and bad calibrations refused with a message naming the field.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/rectification.hpp"

#ifndef ES_SHARED_DATA
#define ES_SHARED_DATA "../shared/data"
#endif

namespace endo_stereo {
namespace {

std::string tempPath(const std::string& name) {
  const char* tmp = std::getenv("TMPDIR");
  return std::string(tmp ? tmp : "/tmp") + "/es_calib_io_" + std::to_string(::getpid()) + "_" +
         name;
}

bool fileExists(const std::string& p) { return std::ifstream(p).good(); }

std::string replaceFirst(std::string text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

/// A valid pair with P (as camera_calibration writes it): 640x480, f 500, baseline 5 mm.
StereoCalibration goodPair() {
  StereoCalibration s;
  for (CameraCalibration* c : {&s.left, &s.right}) {
    c->width = 640;
    c->height = 480;
    c->K = cv::Matx33d(500, 0, 320, 0, 501, 240, 0, 0, 1);
    c->distortion_model = "plumb_bob";
    c->D = {-0.1, 0.01, 0.001, -0.001, 0.0};
    c->P = cv::Matx34d(480, 0, 310, 0, 0, 480, 238, 0, 0, 0, 1, 0);
  }
  s.right.P(0, 3) = -480 * 0.005;
  s.left.frame_id = "left_optical";
  return s;
}

const char* kCameraInfoYaml = R"(image_width: 640
image_height: 480
camera_name: left
camera_matrix:
  rows: 3
  cols: 3
  data: [500, 0, 320, 0, 501, 240, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.1, 0.01, 0.001, -0.001, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [480, 0, 310, 0, 0, 480, 238, 0, 0, 0, 1, 0]
)";

TEST(CalibrationIo, ParsesCameraInfoYaml) {
  CameraCalibration c;
  std::string err;
  ASSERT_TRUE(parseCameraInfoYaml(kCameraInfoYaml, c, &err)) << err;
  EXPECT_EQ(c.width, 640);
  EXPECT_EQ(c.height, 480);
  EXPECT_EQ(c.frame_id, "left");
  EXPECT_DOUBLE_EQ(c.K(1, 1), 501);
  EXPECT_EQ(c.D.size(), 5u);
  EXPECT_DOUBLE_EQ(c.P(0, 2), 310);
  EXPECT_TRUE(c.hasProjection());
}

TEST(CalibrationIo, CameraInfoYamlRoundTrips) {
  const StereoCalibration s = goodPair();
  CameraCalibration with_binning = s.right;
  with_binning.binning_x = 2;
  with_binning.binning_y = 2;
  with_binning.roi = cv::Rect(10, 4, 600, 460);
  const std::string path = tempPath("right.yaml");
  std::string err;
  ASSERT_TRUE(saveCameraInfoYaml(path, with_binning, "right", &err)) << err;
  CameraCalibration back;
  ASSERT_TRUE(loadCameraInfoYaml(path, back, &err)) << err;
  std::remove(path.c_str());
  back.frame_id = with_binning.frame_id;  // camera_name is stored in frame_id on load
  EXPECT_TRUE(back == with_binning);
  EXPECT_EQ(back.roi, with_binning.roi);
  EXPECT_DOUBLE_EQ(back.P(0, 3), with_binning.P(0, 3));
}

TEST(CalibrationIo, LoadsAStereoPairOfCameraInfoFiles) {
  const StereoCalibration s = goodPair();
  const std::string l = tempPath("l.yaml"), r = tempPath("r.yaml");
  std::string err;
  ASSERT_TRUE(saveCameraInfoYaml(l, s.left, "left", &err)) << err;
  ASSERT_TRUE(saveCameraInfoYaml(r, s.right, "right", &err)) << err;
  StereoCalibration out;
  ASSERT_TRUE(loadStereoCalibration(l + "," + r, out, &err)) << err;
  std::remove(l.c_str());
  std::remove(r.c_str());
  EXPECT_DOUBLE_EQ(-out.right.P(0, 3) / out.right.P(0, 0), 0.005);
}

TEST(CalibrationIo, CameraInfoErrorsNameTheField) {
  CameraCalibration c;
  std::string err;
  std::string text = kCameraInfoYaml;
  // Wrong matrix size.
  std::string bad =
      replaceFirst(text, "rows: 3\n  cols: 3\n  data: [500", "rows: 2\n  cols: 3\n  data: [500");
  EXPECT_FALSE(parseCameraInfoYaml(bad, c, &err));
  EXPECT_NE(err.find("camera_matrix"), std::string::npos) << err;
  // Missing key.
  bad = text.substr(0, text.find("camera_matrix")) + text.substr(text.find("distortion_model"));
  EXPECT_FALSE(parseCameraInfoYaml(bad, c, &err));
  EXPECT_NE(err.find("camera_matrix: missing"), std::string::npos) << err;
  // Zero focal length.
  bad = replaceFirst(text, "[500,", "[0,");
  EXPECT_FALSE(parseCameraInfoYaml(bad, c, &err));
  EXPECT_NE(err.find("K: fx must be > 0"), std::string::npos) << err;
  // NaN.
  bad = replaceFirst(text, "501", ".nan");
  EXPECT_FALSE(parseCameraInfoYaml(bad, c, &err));
  EXPECT_NE(err.find("K: contains NaN"), std::string::npos) << err;
  // Not YAML at all.
  EXPECT_FALSE(parseCameraInfoYaml("{ [ :", c, &err));
  EXPECT_FALSE(err.empty());
  EXPECT_FALSE(loadCameraInfoYaml("/nonexistent/x.yaml", c, &err));
  EXPECT_NE(err.find("/nonexistent/x.yaml"), std::string::npos) << err;
}

TEST(CalibrationIo, LoadsOpenCvStereoYamlWithAndWithoutRectification) {
  const cv::Matx33d K(500, 0, 320, 0, 500, 240, 0, 0, 1);
  const cv::Mat D = (cv::Mat_<double>(1, 5) << -0.1, 0.01, 0, 0, 0);
  const cv::Matx33d R = cv::Matx33d::eye();
  const cv::Mat T = (cv::Mat_<double>(3, 1) << -5.0, 0.0, 0.0);  // mm, as many tools write it
  for (bool with_p : {false, true}) {
    const std::string path = tempPath(with_p ? "stereo_p.yml" : "stereo.yml");
    {
      cv::FileStorage fs(path, cv::FileStorage::WRITE);
      fs << "image_width" << 640 << "image_height" << 480;
      fs << "M1" << cv::Mat(K) << "D1" << D << "M2" << cv::Mat(K) << "D2" << D;
      fs << "R" << cv::Mat(R) << "T" << T;
      if (with_p) {
        const cv::Mat P1 = (cv::Mat_<double>(3, 4) << 480, 0, 310, 0, 0, 480, 238, 0, 0, 0, 1, 0);
        cv::Mat P2 = P1.clone();
        P2.at<double>(0, 3) = -480 * 5.0;
        fs << "R1" << cv::Mat(R) << "R2" << cv::Mat(R) << "P1" << P1 << "P2" << P2;
      }
    }
    StereoCalibration s;
    std::string err;
    ASSERT_TRUE(loadOpenCvStereoYaml(path, s, &err, 1e-3)) << err;
    std::remove(path.c_str());
    EXPECT_TRUE(s.has_extrinsics);
    EXPECT_EQ(s.left.width, 640);
    EXPECT_NEAR(s.T_right_left[0], -0.005, 1e-12);
    EXPECT_EQ(s.left.hasProjection(), with_p);
    if (with_p) {
      EXPECT_NEAR(-s.right.P(0, 3) / s.right.P(0, 0), 0.005, 1e-12);
    }
    // Rectifiable either way.
    StereoRectifier rect{RectifyParams()};
    EXPECT_EQ(rect.setCalibration(s), "");
    EXPECT_NEAR(rect.geometry().baseline_m, 0.005, 1e-9);
  }
}

TEST(CalibrationIo, OpenCvStereoYamlErrorsNameTheField) {
  const std::string path = tempPath("bad.yml");
  {
    cv::FileStorage fs(path, cv::FileStorage::WRITE);
    fs << "M1" << cv::Mat::eye(2, 2, CV_64F) << "M2" << cv::Mat::eye(3, 3, CV_64F);
    fs << "R" << cv::Mat::eye(3, 3, CV_64F) << "T" << cv::Mat::zeros(3, 1, CV_64F);
  }
  StereoCalibration s;
  std::string err;
  EXPECT_FALSE(loadOpenCvStereoYaml(path, s, &err));
  EXPECT_NE(err.find("M1: must be 3x3"), std::string::npos) << err;
  {
    cv::FileStorage fs(path, cv::FileStorage::WRITE);
    fs << "M1" << cv::Mat(cv::Matx33d(500, 0, 320, 0, 500, 240, 0, 0, 1));
    fs << "M2" << cv::Mat(cv::Matx33d(500, 0, 320, 0, 500, 240, 0, 0, 1));
    fs << "R" << cv::Mat::eye(3, 3, CV_64F) << "T" << cv::Mat::zeros(3, 1, CV_64F);
  }
  EXPECT_FALSE(loadOpenCvStereoYaml(path, s, &err));
  EXPECT_NE(err.find("T_right_left: baseline must be > 0"), std::string::npos) << err;
  std::remove(path.c_str());
}

// ------------------------------------------------------------------ validation

TEST(CalibrationValidation, AcceptsAGoodPair) { EXPECT_EQ(goodPair().validate(), ""); }

TEST(CalibrationValidation, RefusesBadCalibrationsNamingTheField) {
  struct Case {
    const char* what;
    void (*mutate)(StereoCalibration&);
    const char* expect;
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  static double s_nan;
  s_nan = nan;
  const Case cases[] = {
      {"zero focal length", [](StereoCalibration& s) { s.left.K(0, 0) = 0; },
       "left.K: fx must be > 0"},
      {"zero fy", [](StereoCalibration& s) { s.right.K(1, 1) = 0; }, "right.K: fy must be > 0"},
      {"NaN in K", [](StereoCalibration& s) { s.right.K(0, 2) = s_nan; }, "right.K: contains NaN"},
      {"NaN in D", [](StereoCalibration& s) { s.left.D[1] = s_nan; }, "left.D: contains NaN"},
      {"NaN in P", [](StereoCalibration& s) { s.right.P(1, 2) = s_nan; }, "right.P: contains NaN"},
      {"zero baseline", [](StereoCalibration& s) { s.right.P(0, 3) = 0; }, "right.P: baseline"},
      {"swapped cameras", [](StereoCalibration& s) { s.right.P(0, 3) = 2.4; }, "swapped"},
      {"wrong D size", [](StereoCalibration& s) { s.left.D.resize(3); }, "left.D: plumb_bob needs"},
      {"mismatched sizes", [](StereoCalibration& s) { s.right.width = 320; }, "right.width/height"},
      {"unknown model", [](StereoCalibration& s) { s.left.distortion_model = "kannala"; },
       "left.distortion_model"},
      {"not a rotation", [](StereoCalibration& s) { s.left.R(0, 0) = 2; },
       "left.R: not a rotation"},
      {"rows misaligned", [](StereoCalibration& s) { s.right.P(1, 2) += 3; }, "right.P: cy"},
      {"P for one camera", [](StereoCalibration& s) { s.right.P = cv::Matx34d::zeros(); },
       "given for one camera only"},
      {"negative size",
       [](StereoCalibration& s) {
         s.left.width = -1;
         s.right.width = -1;
       },
       "left.width/height"},
  };
  for (const Case& c : cases) {
    StereoCalibration s = goodPair();
    c.mutate(s);
    const std::string msg = s.validate();
    EXPECT_NE(msg.find(c.expect), std::string::npos) << c.what << ": got '" << msg << "'";
    StereoRectifier rect{RectifyParams()};
    EXPECT_EQ(rect.setCalibration(s), msg) << c.what;
    EXPECT_FALSE(rect.hasCalibration()) << c.what;
  }
  // Extrinsics path: zero baseline and a non-rotation.
  StereoCalibration s = goodPair();
  s.left.P = s.right.P = cv::Matx34d::zeros();
  s.has_extrinsics = true;
  EXPECT_NE(s.validate().find("T_right_left: baseline must be > 0"), std::string::npos)
      << s.validate();
  s.T_right_left = cv::Vec3d(-0.005, 0, 0);
  EXPECT_EQ(s.validate(), "");
  s.R_right_left(1, 1) = nan;
  EXPECT_NE(s.validate().find("R_right_left"), std::string::npos) << s.validate();
  s.R_right_left = cv::Matx33d::eye();
  s.has_extrinsics = false;
  EXPECT_NE(s.validate().find("no projection matrices (P) and no extrinsics"), std::string::npos);
}

// ------------------------------------------------------------------ dataset formats

TEST(CalibrationIo, LoadsUclXmlBlocksThatFileStorageRejects) {
  const std::string dir = std::string(ES_SHARED_DATA) + "/ucl_rectify_golden";
  if (!fileExists(dir + "/calib.left.intrinsic.xml")) {
    GTEST_SKIP() << "absent: " << dir << " (../shared/data beside the repository)";
  }
  cv::Mat m;
  std::string err;
  ASSERT_TRUE(loadOpenCvXmlMatrix(dir + "/calib.left.intrinsic.xml", m, &err)) << err;
  EXPECT_EQ(m.rows, 3);
  EXPECT_NEAR(m.at<double>(0, 0), 1938.28040666091, 1e-9);
  StereoCalibration s;
  ASSERT_TRUE(loadSksurgeryXmlCalibration(dir, 1920, 540, s, &err)) << err;
  EXPECT_EQ(s.left.D.size(), 4u);
  EXPECT_NEAR(s.T_right_left[0], -3.98904833843092e-3, 1e-12);  // mm -> m
  EXPECT_FALSE(loadOpenCvXmlMatrix(dir + "/README.txt", m, &err));
  EXPECT_NE(err.find("<rows>"), std::string::npos) << err;
}

TEST(CalibrationIo, LoadsHamlynTextCalibration) {
  const std::string dir = std::string(ES_SHARED_DATA) + "/hamlyn_heart_phantom";
  if (!fileExists(dir + "/calib.l2r.4x4")) {
    GTEST_SKIP() << "absent: " << dir << " (../shared/data beside the repository)";
  }
  StereoCalibration s;
  std::string err;
  ASSERT_TRUE(loadTextStereoCalibration(dir, 360, 288, s, &err)) << err;
  EXPECT_NEAR(s.left.K(0, 0), 391.656525, 1e-9);
  EXPECT_NEAR(cv::norm(s.T_right_left), 0.00552, 1e-4);  // about 5.5 mm
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
