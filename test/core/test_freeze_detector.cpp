// FreezeDetector on synthetic images: a frozen view is found after exactly freeze_frames
// identical images, a live view (sensor noise on a still scene, down to one changed byte) never
// is, and the view is live again on the first image that differs.
#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "endo_stereo/core/freeze_detector.hpp"

namespace endo_stereo {
namespace {

cv::Mat texture(int seed, int type = CV_8UC3, cv::Size size = cv::Size(64, 48)) {
  cv::Mat m(size, type);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, 256);
  return m;
}

TEST(FreezeDetector, FrozenAfterExactlyFreezeFramesIdenticalImages) {
  FreezeDetector d(3);
  const cv::Mat still = texture(1);
  EXPECT_FALSE(d.update(still));  // the first image has nothing to equal
  EXPECT_FALSE(d.update(still.clone()));
  EXPECT_EQ(d.unchangedRun(), 1);
  EXPECT_FALSE(d.update(still.clone()));
  EXPECT_TRUE(d.update(still.clone())) << "3 identical images after the first: frozen";
  EXPECT_TRUE(d.frozen());
  EXPECT_EQ(d.unchangedRun(), 3);
  EXPECT_TRUE(d.update(still.clone()));
  EXPECT_EQ(d.unchangedRun(), 4);
}

TEST(FreezeDetector, LiveAgainOnTheFirstChangedImage) {
  FreezeDetector d(2);
  const cv::Mat still = texture(2);
  for (int i = 0; i < 10; ++i) d.update(still);
  ASSERT_TRUE(d.frozen());
  EXPECT_FALSE(d.update(texture(3))) << "a changed image is live at once";
  EXPECT_EQ(d.unchangedRun(), 0);
  // And the new image is the reference from now on.
  EXPECT_FALSE(d.update(texture(3)));
  EXPECT_TRUE(d.update(texture(3)));
}

TEST(FreezeDetector, StillSceneWithSensorNoiseIsNeverFrozen) {
  // A still scene seen by a live camera: the same picture plus fresh Gaussian noise of 1 grey
  // level (a quiet sensor) on every frame, 500 frames.
  FreezeDetector d(2);
  const cv::Mat scene = texture(4);
  cv::RNG rng(5);
  for (int i = 0; i < 500; ++i) {
    cv::Mat noise(scene.size(), CV_16SC3), frame;
    rng.fill(noise, cv::RNG::NORMAL, 0, 1.0);
    cv::Mat s16;
    scene.convertTo(s16, CV_16SC3);
    cv::Mat(s16 + noise).convertTo(frame, CV_8UC3);
    ASSERT_FALSE(d.update(frame)) << "frame " << i;
  }
}

TEST(FreezeDetector, OneChangedByteIsEnough) {
  // Even the faintest live signal, one byte of the last row, keeps the view live.
  FreezeDetector d(1);
  cv::Mat img = texture(6, CV_8UC1);
  d.update(img);
  for (int i = 0; i < 20; ++i) {
    img.at<uint8_t>(img.rows - 1, img.cols - 1) ^= 1;
    ASSERT_FALSE(d.update(img)) << i;
  }
  EXPECT_TRUE(d.update(img));
}

TEST(FreezeDetector, SizeOrTypeChangeIsAChangeNotAFreeze) {
  FreezeDetector d(1);
  d.update(cv::Mat::zeros(48, 64, CV_8UC1));
  EXPECT_FALSE(d.update(cv::Mat::zeros(48, 64, CV_8UC3)));
  EXPECT_FALSE(d.update(cv::Mat::zeros(24, 32, CV_8UC3)));
  EXPECT_FALSE(d.update(cv::Mat::zeros(24, 32, CV_16UC3)));
  EXPECT_TRUE(d.update(cv::Mat::zeros(24, 32, CV_16UC3)));
}

TEST(FreezeDetector, ComparesRowsOfNonContinuousViewsAndKeepsItsOwnCopy) {
  // A view into a larger buffer (a ROS message wrapped without copy has a step >= its row): only
  // the row bytes count, and the caller may overwrite its buffer after update().
  cv::Mat big = texture(7, CV_8UC1, cv::Size(80, 48));
  cv::Mat view = big.colRange(0, 64);
  FreezeDetector d(1);
  d.update(view);
  big.colRange(64, 80).setTo(0);  // outside the view: no change
  EXPECT_TRUE(d.update(view));
  big.at<uint8_t>(10, 5) ^= 0xff;  // inside: a change, seen although d saw this buffer before
  EXPECT_FALSE(d.update(view));
}

TEST(FreezeDetector, ZeroTurnsItOffAndResetForgets) {
  FreezeDetector off(0);
  const cv::Mat still = texture(8);
  for (int i = 0; i < 100; ++i) ASSERT_FALSE(off.update(still));
  FreezeDetector d(2);
  for (int i = 0; i < 5; ++i) d.update(still);
  ASSERT_TRUE(d.frozen());
  d.reset();
  EXPECT_FALSE(d.frozen());
  EXPECT_FALSE(d.update(still));
  EXPECT_EQ(d.unchangedRun(), 0);
  d.setFreezeFrames(0);
  EXPECT_FALSE(d.update(still));
  EXPECT_THROW(FreezeDetector(-1), std::invalid_argument);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
