// Scoring against ground truth and the Middlebury loader.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <limits>

#include "endo_stereo/core/evaluation.hpp"

namespace endo_stereo {
namespace {

const float kNaN = std::numeric_limits<float>::quiet_NaN();

TEST(ScoreDisparity, CountsErrorsAmongOutputPixelsAndDensityAmongGroundTruth) {
  cv::Mat gt(1, 6, CV_32FC1, cv::Scalar(10.f));
  gt.at<float>(0, 5) = kNaN;  // unknown ground truth: counted nowhere
  cv::Mat d = (cv::Mat_<float>(1, 6) << 10.5f, 11.5f, 12.5f, kNaN,
               std::numeric_limits<float>::infinity(), 3.f);
  const DisparityScore s = scoreDisparity(d, gt);
  EXPECT_EQ(s.n_gt, 5);
  EXPECT_EQ(s.n_out, 3);
  EXPECT_EQ(s.n_bad1, 2);  // errors 0.5, 1.5, 2.5
  EXPECT_EQ(s.n_bad2, 1);
  EXPECT_DOUBLE_EQ(s.bad1, 2.0 / 3.0);
  EXPECT_DOUBLE_EQ(s.bad2, 1.0 / 3.0);
  EXPECT_DOUBLE_EQ(s.density, 3.0 / 5.0);
  EXPECT_NEAR(s.mean_abs_error, 1.5, 1e-6);
}

TEST(ScoreDisparity, ErrorExactlyAtThresholdIsNotBad) {
  cv::Mat gt(1, 2, CV_32FC1, cv::Scalar(10.f));
  cv::Mat d = (cv::Mat_<float>(1, 2) << 11.f, 12.f);
  const DisparityScore s = scoreDisparity(d, gt);
  EXPECT_EQ(s.n_bad1, 1);
  EXPECT_EQ(s.n_bad2, 0);
}

TEST(ScoreDisparity, MaskRestrictsBothCounts) {
  cv::Mat gt(2, 2, CV_32FC1, cv::Scalar(5.f));
  cv::Mat d(2, 2, CV_32FC1, cv::Scalar(9.f));
  d.at<float>(0, 0) = 5.f;
  cv::Mat mask = (cv::Mat_<uint8_t>(2, 2) << 255, 0, 0, 0);
  const DisparityScore s = scoreDisparity(d, gt, mask);
  EXPECT_EQ(s.n_gt, 1);
  EXPECT_EQ(s.n_out, 1);
  EXPECT_EQ(s.n_bad2, 0);
  EXPECT_DOUBLE_EQ(s.density, 1.0);
}

TEST(ScoreDisparity, RejectsMismatchedInputs) {
  cv::Mat gt(2, 2, CV_32FC1, cv::Scalar(5.f));
  EXPECT_THROW(scoreDisparity(cv::Mat(2, 2, CV_64FC1), gt), std::invalid_argument);
  EXPECT_THROW(scoreDisparity(cv::Mat(2, 3, CV_32FC1), gt), std::invalid_argument);
  EXPECT_THROW(scoreDisparity(gt, gt, cv::Mat(2, 2, CV_32FC1)), std::invalid_argument);
}

TEST(MiddleburyScene, LoadsVenusWithScaleAndMasks) {
  const std::string dir = std::string(ES_SHARED_DATA_DIR) + "/middlebury/venus";
  // Only a missing scene is a skip; with the data present, any loader error is a failure.
  if (!std::ifstream(dir + "/info.txt").good()) {
    GTEST_SKIP() << "absent: " << dir << " (../shared/data beside the repository)";
  }
  MiddleburyScene s;
  ASSERT_NO_THROW(s = loadMiddleburyScene(dir));
  EXPECT_EQ(s.name, "venus");
  EXPECT_EQ(s.left.type(), CV_8UC1);
  EXPECT_EQ(s.left.size(), cv::Size(434, 383));
  EXPECT_EQ(s.scale, 8);
  EXPECT_EQ(s.max_disp, 19);
  double lo, hi;
  cv::minMaxLoc(s.gt, &lo, &hi, nullptr, nullptr, s.all);
  EXPECT_GE(lo, 0.0);
  EXPECT_LE(hi, s.max_disp + 1.0);  // info.txt rounds: venus reaches 19.125
  // The masks nest: disc within nonocc within all.
  EXPECT_EQ(cv::countNonZero(s.disc & ~s.nonocc), 0);
  EXPECT_EQ(cv::countNonZero(s.nonocc & ~s.all), 0);
  EXPECT_GT(cv::countNonZero(s.nonocc), s.left.total() / 2);
  // Ground truth scored against itself: no error, full density.
  const DisparityScore self = scoreDisparity(s.gt, s.gt, s.nonocc);
  EXPECT_EQ(self.n_bad1, 0);
  EXPECT_DOUBLE_EQ(self.density, 1.0);
}

TEST(MiddleburyScene, MissingFolderThrowsNamingTheFile) {
  try {
    loadMiddleburyScene("/nonexistent/scene");
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("info.txt"), std::string::npos);
  }
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
