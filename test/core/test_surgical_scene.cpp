// Tests of the synthetic surgical stereo generator
// (include/endo_stereo/synthetic/surgical_scene.hpp): exact ground truth, determinism, calibration,
// masks, degradations.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "endo_stereo/synthetic/surgical_scene.hpp"

namespace endo_stereo {
namespace {

// Small frames keep each render in the tens of milliseconds on a 2-core machine.
SurgicalSceneParams smallParams() {
  SurgicalSceneParams p;
  p.width = 320;
  p.height = 180;
  p.noise_sigma = 0.0;
  return p;
}

bool identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  cv::Mat diff;
  cv::compare(a, b, diff, cv::CMP_NE);  // NaN != NaN, but the GT has no NaN
  return cv::countNonZero(diff.reshape(1)) == 0;
}

TEST(SurgicalScene, RejectsInvalidParams) {
  SurgicalSceneParams p;
  p.width = 10;
  EXPECT_NE(p.validate().find("width"), std::string::npos);
  EXPECT_THROW(SurgicalScene{p}, std::invalid_argument);
  p = SurgicalSceneParams();
  p.instruments = 3;
  EXPECT_NE(p.validate().find("instruments"), std::string::npos);
  p = SurgicalSceneParams();
  p.motion_blur_samples = 0;
  EXPECT_NE(p.validate().find("motion_blur_samples"), std::string::npos);
  EXPECT_EQ(SurgicalSceneParams().validate(), "");
}

TEST(SurgicalScene, GroundTruthWarpsRightOntoLeft) {
  cv::setNumThreads(2);
  const SurgicalScene scene(smallParams());
  SurgicalFrame frame;
  scene.render(37, frame);
  int64_t count = 0;
  const double err = groundTruthWarpError(frame, 0.0, 2, &count);
  // Most of the image is seen by both cameras away from highlights and depth steps.
  EXPECT_GT(count, frame.left.total() / 2);
  // With exact ground truth what remains is the bilinear interpolation of a texture that has
  // detail at the pixel scale: about 0.6 grey levels measured. A quarter-pixel error in the
  // ground truth adds about half a grey level, half a pixel about 1.5 levels, so the bound of 1.0
  // and the comparisons below fail for any systematic error of a quarter pixel or more.
  EXPECT_LT(err, 1.0);
  for (double offset : {-0.5, -0.25, 0.25, 0.5}) {
    EXPECT_LT(err, groundTruthWarpError(frame, offset, 2)) << "offset " << offset;
  }
  EXPECT_GT(groundTruthWarpError(frame, 0.5, 2), 2.5 * err);
  EXPECT_GT(groundTruthWarpError(frame, -0.5, 2), 2.5 * err);
}

TEST(SurgicalScene, DistortedGroundTruthMatchesRectifiedViews) {
  cv::setNumThreads(2);
  SurgicalSceneParams p = smallParams();
  p.distorted = true;
  const SurgicalScene scene(p);
  SurgicalFrame raw;
  scene.render(12, raw);
  // Rectify the raw views with OpenCV from the published calibration, then warp as above.
  const StereoCalibration& c = scene.calibration();
  SurgicalFrame rect = raw;
  cv::Mat valid_right;
  for (int k = 0; k < 2; ++k) {
    const CameraCalibration& cc = k == 0 ? c.left : c.right;
    cv::Mat m1, m2;
    cv::initUndistortRectifyMap(cv::Mat(cc.K), cc.D, cv::Mat(cc.R), cv::Mat(cc.P).colRange(0, 3),
                                cv::Size(cc.width, cc.height), CV_32FC1, m1, m2);
    cv::remap(k == 0 ? raw.left : raw.right, k == 0 ? rect.left : rect.right, m1, m2,
              cv::INTER_CUBIC);
    cv::Mat& spec = k == 0 ? rect.left_specular : rect.right_specular;
    cv::remap(k == 0 ? raw.left_specular : raw.right_specular, spec, m1, m2, cv::INTER_NEAREST);
    cv::dilate(spec, spec, cv::Mat());
    // Pixels whose rectified source lies outside the raw image count as highlights (unusable).
    cv::Mat inside;
    cv::remap(cv::Mat(raw.left.size(), CV_8UC1, cv::Scalar(255)), inside, m1, m2, cv::INTER_NEAREST,
              cv::BORDER_CONSTANT, cv::Scalar(0));
    cv::erode(inside, inside, cv::Mat(), cv::Point(-1, -1), 3);
    spec.setTo(255, inside == 0);
  }
  int64_t count = 0;
  const double err = groundTruthWarpError(rect, 0.0, 2, &count);
  EXPECT_GT(count, rect.left.total() / 2);
  // Two interpolations now (cubic rectification, bilinear warp): about 0.7-0.8 grey levels.
  EXPECT_LT(err, 1.2);
  for (double offset : {-0.5, -0.25, 0.25, 0.5}) {
    EXPECT_LT(err, groundTruthWarpError(rect, offset, 2)) << "offset " << offset;
  }
  // The rectified rows must be aligned too: a vertical shift of the right image by half a pixel
  // raises the error clearly.
  SurgicalFrame shifted = rect;
  const cv::Matx23d shift(1, 0, 0, 0, 1, 0.5);
  cv::warpAffine(rect.right, shifted.right, shift, rect.right.size(), cv::INTER_LINEAR);
  EXPECT_GT(groundTruthWarpError(shifted, 0.0, 2), 1.5 * err);
}

TEST(SurgicalScene, GroundTruthIsFocalTimesBaselineOverDepth) {
  const SurgicalScene scene(smallParams());
  SurgicalFrame frame;
  scene.render(3, frame);
  const RectifiedGeometry g = scene.geometry();
  ASSERT_TRUE(g.metric);
  for (int y = 0; y < frame.gt_disparity.rows; y += 7) {
    for (int x = 0; x < frame.gt_disparity.cols; x += 7) {
      const double z = frame.gt_depth_m.at<float>(y, x);
      // float storage: relative 1e-6
      EXPECT_NEAR(frame.gt_disparity.at<float>(y, x), g.f_px * g.baseline_m / z + g.doffs(), 1e-4);
    }
  }
  // Instruments hover in front of the tissue: nearer, so larger disparities.
  const cv::Scalar inst = cv::mean(frame.gt_disparity, frame.instrument_mask);
  const cv::Scalar tissue = cv::mean(frame.gt_disparity, frame.instrument_mask == 0);
  ASSERT_GT(cv::countNonZero(frame.instrument_mask), 100);
  EXPECT_GT(inst[0], tissue[0] + 5.0);
}

TEST(SurgicalScene, CalibrationDescribesRectifiedRig) {
  const SurgicalScene scene(smallParams());
  const StereoCalibration& c = scene.calibration();
  EXPECT_EQ(c.left.width, 320);
  EXPECT_EQ(c.left.height, 180);
  EXPECT_EQ(c.left.distortion_model, "plumb_bob");
  ASSERT_EQ(c.left.D.size(), 5u);
  EXPECT_DOUBLE_EQ(c.left.P(0, 3), 0.0);
  EXPECT_NEAR(c.right.P(0, 3), -c.right.P(0, 0) * scene.geometry().baseline_m, 1e-12);
  EXPECT_NEAR(scene.geometry().baseline_m, scene.params().baseline_m, 1e-12);
  EXPECT_NE(c.left.frame_id, c.right.frame_id);
  int dmin = 0, dmax = 0;
  scene.suggestedDisparityRange(&dmin, &dmax);
  EXPECT_EQ(dmin % 16, 0);
  EXPECT_EQ((dmax + 1) % 16, 0);
  SurgicalFrame frame;
  for (int i : {0, 20, 40, 60}) {
    scene.render(i, frame);
    double lo = 0, hi = 0;
    cv::minMaxLoc(frame.gt_disparity, &lo, &hi, nullptr, nullptr, frame.visibility == kVisibleBoth);
    EXPECT_GE(lo, dmin) << "frame " << i;
    EXPECT_LE(hi, dmax) << "frame " << i;
  }
}

TEST(SurgicalScene, SameSeedGivesIdenticalFramesForAnyThreadCount) {
  SurgicalSceneParams p = smallParams();
  p.noise_sigma = 2.0;
  SurgicalFrame a, b;
  cv::setNumThreads(1);
  SurgicalScene(p).render(5, a);
  cv::setNumThreads(2);
  SurgicalScene(p).render(5, b);
  EXPECT_TRUE(identical(a.left, b.left));
  EXPECT_TRUE(identical(a.right, b.right));
  EXPECT_TRUE(identical(a.gt_disparity, b.gt_disparity));
  EXPECT_TRUE(identical(a.visibility, b.visibility));
  p.seed = 2;
  SurgicalScene(p).render(5, b);
  EXPECT_FALSE(identical(a.left, b.left));
  EXPECT_FALSE(identical(a.gt_disparity, b.gt_disparity));
}

TEST(SurgicalScene, SceneMovesOverTime) {
  const SurgicalScene scene(smallParams());
  SurgicalFrame a, b;
  scene.render(0, a);
  scene.render(1, b);
  EXPECT_DOUBLE_EQ(b.stamp_s - a.stamp_s, 1.0 / 25.0);
  cv::Mat diff;
  cv::absdiff(a.gt_disparity, b.gt_disparity, diff);
  double max_change = 0;
  cv::minMaxLoc(diff, nullptr, &max_change);
  EXPECT_GT(max_change, 0.01);  // breathing, heartbeat and the instrument move the surface
  EXPECT_FALSE(identical(a.left, b.left));
}

TEST(SurgicalScene, OccludedPixelsSeeSomethingElseInTheRightView) {
  const SurgicalScene scene(smallParams());
  SurgicalFrame frame;
  scene.render(37, frame);
  const cv::Mat occluded = frame.visibility == kOccludedInRight;
  ASSERT_GT(cv::countNonZero(occluded), 50);
  // Where the left pixel's point is hidden, the right image at x - d shows the instrument: the
  // colours differ by far more than the ~0.6 levels of visible pixels.
  double sum = 0;
  int n = 0;
  for (int y = 0; y < occluded.rows; ++y) {
    for (int x = 0; x < occluded.cols; ++x) {
      if (!occluded.at<uint8_t>(y, x)) continue;
      const int xr = int(std::lround(x - frame.gt_disparity.at<float>(y, x)));
      if (xr < 0) continue;
      const cv::Vec3b l = frame.left.at<cv::Vec3b>(y, x), r = frame.right.at<cv::Vec3b>(y, xr);
      for (int c = 0; c < 3; ++c) sum += std::abs(int(l[c]) - int(r[c]));
      ++n;
    }
  }
  ASSERT_GT(n, 0);
  EXPECT_GT(sum / (3.0 * n), 10.0);
  // Pixels near the left border see points outside the right image.
  EXPECT_EQ(frame.visibility.at<uint8_t>(90, 0), kOutsideRightImage);
}

TEST(SurgicalScene, HighlightsDifferBetweenViews) {
  const SurgicalScene scene(smallParams());
  SurgicalFrame frame;
  scene.render(10, frame);
  const int left_n = cv::countNonZero(frame.left_specular);
  ASSERT_GT(left_n, 100);
  ASSERT_GT(cv::countNonZero(frame.right_specular), 100);
  // A highlight of the left view is, at the same surface point, often absent from the right view.
  int unmatched = 0;
  for (int y = 0; y < frame.left.rows; ++y) {
    for (int x = 0; x < frame.left.cols; ++x) {
      if (!frame.left_specular.at<uint8_t>(y, x) ||
          frame.visibility.at<uint8_t>(y, x) != kVisibleBoth)
        continue;
      const int xr = int(std::lround(x - frame.gt_disparity.at<float>(y, x)));
      unmatched += frame.right_specular.at<uint8_t>(y, xr) == 0;
    }
  }
  EXPECT_GT(unmatched, left_n / 10);
  // Matte tissue has highlights on the instrument only.
  SurgicalSceneParams p = smallParams();
  p.specular_strength = 0.0;
  SurgicalScene(p).render(10, frame);
  EXPECT_EQ(cv::countNonZero(frame.left_specular & (frame.instrument_mask == 0)), 0);
}

TEST(SurgicalScene, InterlacedOddRowsAreHalfAFrameLater) {
  SurgicalSceneParams p = smallParams();
  p.interlaced = true;
  SurgicalFrame inter, even, odd;
  SurgicalScene(p).render(4, inter);
  p.interlaced = false;
  SurgicalScene(p).render(4, even);  // t = 4 / 25
  p.fps = 50.0;
  SurgicalScene(p).render(9, odd);  // t = 9 / 50 = (4 + 0.5) / 25
  for (int y = 0; y < inter.left.rows; ++y) {
    const SurgicalFrame& ref = y % 2 == 0 ? even : odd;
    ASSERT_TRUE(identical(inter.left.row(y), ref.left.row(y))) << "row " << y;
    ASSERT_TRUE(identical(inter.gt_disparity.row(y), ref.gt_disparity.row(y))) << "row " << y;
  }
  EXPECT_FALSE(identical(even.left, odd.left));
}

TEST(SurgicalScene, MotionBlurSmearsTheMovingInstrument) {
  SurgicalSceneParams p = smallParams();
  SurgicalFrame sharp, blurred;
  SurgicalScene(p).render(30, sharp);
  p.motion_blur_samples = 5;
  p.exposure_s = 0.04;
  SurgicalScene(p).render(30, blurred);
  EXPECT_TRUE(identical(sharp.gt_disparity, blurred.gt_disparity));  // GT at mid-exposure
  cv::Mat diff;
  cv::absdiff(sharp.left, blurred.left, diff);
  cv::cvtColor(diff, diff, cv::COLOR_BGR2GRAY);
  // The instrument (and its edges) moves much faster than the breathing tissue.
  cv::Mat edge_band;
  cv::dilate(sharp.instrument_mask, edge_band, cv::Mat(), cv::Point(-1, -1), 3);
  const double on_instrument = cv::mean(diff, edge_band)[0];
  const double on_tissue = cv::mean(diff, edge_band == 0)[0];
  EXPECT_GT(on_instrument, 3.0 * on_tissue);
  EXPECT_GT(on_instrument, 1.0);
}

TEST(SurgicalScene, SensorNoiseHasTheRequestedSigma) {
  SurgicalSceneParams p = smallParams();
  SurgicalFrame clean, noisy;
  SurgicalScene(p).render(0, clean);
  p.noise_sigma = 4.0;
  SurgicalScene(p).render(0, noisy);
  cv::Mat a, b;
  clean.left.convertTo(a, CV_32F);
  noisy.left.convertTo(b, CV_32F);
  cv::Scalar mean, stddev;
  const cv::Mat diff = b - a;
  cv::meanStdDev(diff.reshape(1), mean, stddev);
  // Rounding to 8 bits and clipping at saturated highlights bend it a little: +-10%.
  EXPECT_NEAR(stddev[0], 4.0, 0.4);
  EXPECT_NEAR(mean[0], 0.0, 0.2);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
