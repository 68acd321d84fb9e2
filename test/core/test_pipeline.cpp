// The Pipeline's plumbing: stages in order, errors reported without throwing, temporal state
// reset on the events docs/method.md section 4 names, optional outputs, geometry from calibration.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>

#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/core/temporal_matching.hpp"
#include "endo_stereo/synthetic/surgical_scene.hpp"
#include "synthetic_scene.hpp"

namespace {

using namespace endo_stereo;

// Small scenes keep each test well under a second on two cores.
SyntheticScene smallScene() {
  SyntheticSceneParams p;
  p.width = 160;
  p.height = 120;
  p.seed = 3;
  p.base_disparity_px = 10.0;
  p.slope_x = 0.02;
  return makeSyntheticScene(p);
}

PipelineParams passThroughParams() {
  PipelineParams p;
  p.rectify.mode = RectifyMode::kPassThrough;
  p.rectify.quality_stride = 0;  // no SIFT residual: these tests are about the other stages
  p.matcher.min_disparity = 0;
  p.matcher.max_disparity = 31;
  p.output.point_cloud = false;
  return p;
}

StereoInput monoInput(const SyntheticScene& s, double stamp_s) {
  StereoInput in;
  in.left = s.left;
  in.right = s.right;
  in.left_encoding = "mono8";
  in.right_encoding = "mono8";
  in.stamp_s = stamp_s;
  return in;
}

// NaN-aware exact equality of two disparity maps.
bool sameDisparity(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int y = 0; y < a.rows; ++y) {
    for (int x = 0; x < a.cols; ++x) {
      const float u = a.at<float>(y, x), v = b.at<float>(y, x);
      if (std::isnan(u) != std::isnan(v) || (!std::isnan(u) && u != v)) return false;
    }
  }
  return true;
}

// Little texture and some noise: the first window often finds no confident match, a larger one
// does.
SyntheticScene lowTextureScene() {
  SyntheticSceneParams p;
  p.width = 160;
  p.height = 120;
  p.seed = 11;
  p.base_disparity_px = 12.0;
  p.slope_x = 0.02;
  p.texture_stdev = 10.0;
  p.noise_stdev = 3.0;
  return makeSyntheticScene(p);
}

bool sameMatch(const MatchResult& a, const MatchResult& b) {
  return sameDisparity(a.disparity, b.disparity) && cv::norm(a.code, b.code, cv::NORM_INF) == 0 &&
         cv::norm(a.confidence, b.confidence, cv::NORM_INF) == 0 &&
         a.stats.valid_pixels == b.stats.valid_pixels && a.stats.rejected == b.stats.rejected &&
         a.stats.accepted_per_window == b.stats.accepted_per_window;
}

class PipelineTest : public ::testing::Test {
 protected:
  void SetUp() override { cv::setNumThreads(2); }
};

TEST_F(PipelineTest, PassThroughGivesExactlyTheMatchersOutput) {
  const SyntheticScene s = smallScene();
  // Priors on (the shipped preset): the first frame of a stream has none and searches the full
  // range, so its output is exactly the matcher's.
  PipelineParams params = passThroughParams();
  Pipeline pipeline(params);
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(monoInput(s, 0.0), out, &error)) << error;

  RobustMatcher matcher(params.matcher, params.filter);
  MatchResult direct;
  matcher.compute(s.left, s.right, direct);
  EXPECT_TRUE(sameDisparity(out.match.disparity, direct.disparity));
  EXPECT_GT(out.match.stats.density(), 0.3);  // a textured scene: the matcher outputs plenty
  EXPECT_EQ(out.left_rect_gray.size(), s.left.size());
  EXPECT_GE(out.total_ms, out.match_ms);
  EXPECT_GT(out.match_ms, 0.0);
  EXPECT_FALSE(out.priors_used);  // first frame: nothing to narrow with
}

TEST_F(PipelineTest, BadInputReturnsFalseWithAMessageAndThePipelineStaysUsable) {
  const SyntheticScene s = smallScene();
  Pipeline pipeline(passThroughParams());
  PipelineOutput out;
  std::string error;

  StereoInput empty = monoInput(s, 0.0);
  empty.right = cv::Mat();
  EXPECT_FALSE(pipeline.process(empty, out, &error));
  EXPECT_NE(error.find("empty right"), std::string::npos) << error;

  StereoInput mismatch = monoInput(s, 0.0);
  mismatch.right = s.right(cv::Rect(0, 0, 100, 120)).clone();
  EXPECT_FALSE(pipeline.process(mismatch, out, &error));
  EXPECT_NE(error.find("size mismatch"), std::string::npos) << error;

  StereoInput bayer = monoInput(s, 0.0);
  bayer.left_encoding = "bayer_rggb8";
  EXPECT_FALSE(pipeline.process(bayer, out, &error));
  EXPECT_NE(error.find("bayer_rggb8"), std::string::npos) << error;

  StereoInput wrong_type = monoInput(s, 0.0);
  wrong_type.right_encoding = "bgr8";  // but the matrix is one-channel
  EXPECT_FALSE(pipeline.process(wrong_type, out, &error));
  EXPECT_NE(error.find("right"), std::string::npos) << error;

  error.clear();
  EXPECT_TRUE(pipeline.process(monoInput(s, 0.0), out, &error)) << error;
  EXPECT_GT(out.match.stats.valid_pixels, 0);
}

TEST_F(PipelineTest, InvalidParamsAreRejectedNamingTheFieldAndTheOldOnesKept) {
  PipelineParams bad = passThroughParams();
  bad.matcher.window_min_px = 4;
  try {
    Pipeline p(bad);
    FAIL() << "constructed with an even window";
  } catch (const std::invalid_argument& ex) {
    EXPECT_NE(std::string(ex.what()).find("window_min_px"), std::string::npos) << ex.what();
  }
  Pipeline pipeline(passThroughParams());
  PipelineParams bad_temporal = passThroughParams();
  bad_temporal.temporal.prior_radius_px = 0;
  EXPECT_THROW(pipeline.setParams(bad_temporal), std::invalid_argument);
  EXPECT_EQ(pipeline.params().temporal.prior_radius_px,
            passThroughParams().temporal.prior_radius_px);
  PipelineParams bad_range = passThroughParams();
  bad_range.matcher.max_disparity = -5;
  EXPECT_NE(bad_range.validate().find("matcher."), std::string::npos) << bad_range.validate();
}

TEST_F(PipelineTest, CalibratedModeWithoutACalibrationFailsClearly) {
  PipelineParams params = passThroughParams();
  params.rectify.mode = RectifyMode::kCalibrated;
  Pipeline pipeline(params);
  PipelineOutput out;
  std::string error;
  EXPECT_FALSE(pipeline.process(monoInput(smallScene(), 0.0), out, &error));
  EXPECT_NE(error.find("calibrat"), std::string::npos) << error;
}

TEST_F(PipelineTest, PriorsNarrowTheNextFrameAndResetWhenTimeGoesBackOrJumps) {
  const SyntheticScene s = smallScene();
  Pipeline pipeline(passThroughParams());
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(monoInput(s, 10.0), out, &error)) << error;
  EXPECT_FALSE(out.priors_used);  // no prior yet: the full range
  const cv::Mat full = out.match.disparity.clone();
  ASSERT_TRUE(pipeline.process(monoInput(s, 10.04), out, &error)) << error;
  EXPECT_TRUE(out.priors_used);  // the previous frame's disparities
  EXPECT_FALSE(out.priors_reset);
  EXPECT_GT(out.prior_stats.narrowed_pixels, 0);
  EXPECT_GT(out.prior_stats.prior_hits, 0);

  // After a reset the old priors are gone: the frame searches the full range again, and its
  // output is the first frame's exactly.
  ASSERT_TRUE(pipeline.process(monoInput(s, 9.0), out, &error)) << error;  // a looping bag
  EXPECT_TRUE(out.priors_reset);
  EXPECT_FALSE(out.reset_reason.empty());
  EXPECT_FALSE(out.priors_used);
  EXPECT_TRUE(sameDisparity(out.match.disparity, full));

  ASSERT_TRUE(pipeline.process(monoInput(s, 9.04), out, &error)) << error;
  EXPECT_TRUE(out.priors_used);
  ASSERT_TRUE(pipeline.process(monoInput(s, 60.0), out, &error)) << error;  // a long gap
  EXPECT_TRUE(out.priors_reset);
  EXPECT_FALSE(out.priors_used);
  EXPECT_TRUE(sameDisparity(out.match.disparity, full));

  ASSERT_TRUE(pipeline.process(monoInput(s, 60.04), out, &error)) << error;
  EXPECT_TRUE(out.priors_used);
  pipeline.reset();  // asked for by the caller (the nodelet on a reconfigure, for instance)
  ASSERT_TRUE(pipeline.process(monoInput(s, 60.08), out, &error)) << error;
  EXPECT_FALSE(out.priors_used);
  EXPECT_TRUE(sameDisparity(out.match.disparity, full));
}

// A scene change (a cut, a jump of the endoscope): the previous frame's priors point at the wrong
// disparities, the narrowed search finds almost nothing, and the pipeline matches the frame again
// over the full range instead of outputting what the wrong ranges let through.
TEST_F(PipelineTest, PriorsFromAnotherSceneAreRejectedAndTheFrameIsMatchedInFull) {
  const SyntheticScene a = smallScene();
  SyntheticSceneParams pb;
  pb.width = 160;
  pb.height = 120;
  pb.seed = 77;
  pb.base_disparity_px = 24.0;  // far outside +-4 px of scene a's 10 px
  const SyntheticScene b = makeSyntheticScene(pb);
  PipelineParams params = passThroughParams();
  Pipeline pipeline(params);
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(monoInput(a, 0.0), out, &error)) << error;
  ASSERT_TRUE(pipeline.process(monoInput(a, 0.04), out, &error)) << error;
  ASSERT_TRUE(pipeline.process(monoInput(a, 0.08), out, &error)) << error;
  ASSERT_TRUE(out.priors_used);
  ASSERT_TRUE(pipeline.process(monoInput(b, 0.12), out, &error)) << error;
  EXPECT_TRUE(out.priors_rejected);
  EXPECT_FALSE(out.priors_used);
  RobustMatcher matcher(params.matcher, params.filter);
  MatchResult full;
  matcher.compute(b.left, b.right, full);
  EXPECT_TRUE(sameDisparity(out.match.disparity, full.disparity));
}

TEST_F(PipelineTest, ChangingTheDisparityRangeResetsPriorsAndDisablingThemSearchesFully) {
  const SyntheticScene s = smallScene();
  PipelineParams params = passThroughParams();
  Pipeline pipeline(params);
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(monoInput(s, 0.0), out, &error)) << error;
  params.matcher.max_disparity = 39;
  pipeline.setParams(params);
  ASSERT_TRUE(pipeline.process(monoInput(s, 0.04), out, &error)) << error;
  EXPECT_TRUE(out.priors_reset) << "range changed, old priors no longer fit";
  EXPECT_FALSE(out.priors_used);

  params.temporal.enabled = false;
  pipeline.setParams(params);
  const cv::Mat first = out.match.disparity.clone();
  ASSERT_TRUE(pipeline.process(monoInput(s, 0.08), out, &error)) << error;
  EXPECT_FALSE(out.priors_used);
  EXPECT_EQ(out.prior_stats.narrowed_pixels, 0);
  EXPECT_TRUE(sameDisparity(first, out.match.disparity));  // the same pair, the same full search
}

TEST_F(PipelineTest, FusedAndCoverageOutputsOnlyWhenRequested) {
  const SyntheticScene s = smallScene();
  PipelineParams params = passThroughParams();
  Pipeline plain(params);
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(plain.process(monoInput(s, 0.0), out, &error)) << error;
  EXPECT_TRUE(out.fused_disparity.empty());
  EXPECT_TRUE(out.coverage.empty());

  params.output.fused = true;
  params.output.coverage = true;
  Pipeline full(params);
  ASSERT_TRUE(full.process(monoInput(s, 0.0), out, &error)) << error;
  ASSERT_TRUE(full.process(monoInput(s, 0.04), out, &error)) << error;
  ASSERT_EQ(out.fused_disparity.size(), s.left.size());
  ASSERT_EQ(out.fused_age.type(), CV_16UC1);
  ASSERT_EQ(out.coverage.type(), CV_16UC1);
  // Every pixel valid in this frame is fused with age 0 and this frame's value.
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      const float d = out.match.disparity.at<float>(y, x);
      if (std::isnan(d)) continue;
      ASSERT_EQ(out.fused_age.at<uint16_t>(y, x), 0);
      ASSERT_EQ(out.fused_disparity.at<float>(y, x), d);
    }
  }
  EXPECT_EQ(full.temporal().coverage().frames(), 2);
}

TEST_F(PipelineTest, DownsamplingHalvesTheMatchedImages) {
  const SyntheticScene s = smallScene();
  PipelineParams params = passThroughParams();
  params.preprocess.downsample = 2;
  params.matcher.max_disparity = 15;
  Pipeline pipeline(params);
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(monoInput(s, 0.0), out, &error)) << error;
  EXPECT_EQ(out.match.disparity.size(), cv::Size(80, 60));
}

// Calibrated mode on the synthetic endoscope: the geometry comes from the calibration, the cloud is
// metric and its depth follows Z = f B / (d - doffs) of the pipeline's own disparities, and a new
// calibration resets the temporal state.
TEST_F(PipelineTest, CalibratedCloudIsMetricAndANewCalibrationResetsPriors) {
  SurgicalSceneParams sp;
  sp.width = 192;
  sp.height = 144;
  sp.seed = 5;
  sp.instruments = 0;
  const SurgicalScene scene(sp);
  SurgicalFrame frame;
  scene.render(0, frame);
  int d_min = 0, d_max = 0;
  scene.suggestedDisparityRange(&d_min, &d_max);

  PipelineParams params = passThroughParams();
  params.rectify.mode = RectifyMode::kCalibrated;
  params.matcher.min_disparity = d_min;
  params.matcher.max_disparity = d_max;
  params.output.point_cloud = true;
  Pipeline pipeline(params);
  ASSERT_EQ(pipeline.setCalibration(scene.calibration()), "");
  StereoInput in{frame.left, frame.right, "bgr8", "bgr8", 0.0};
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(in, out, &error)) << error;

  const RectifiedGeometry truth = scene.geometry();
  EXPECT_NEAR(out.geometry.f_px, truth.f_px, 1e-6 * truth.f_px);
  EXPECT_NEAR(out.geometry.baseline_m, truth.baseline_m, 1e-9);
  EXPECT_TRUE(out.geometry.metric);
  ASSERT_TRUE(out.cloud.metric);
  ASSERT_EQ(out.cloud.xyz.size(), frame.left.size());
  int checked = 0, close_to_truth = 0;
  for (int y = 0; y < out.cloud.xyz.rows; ++y) {
    for (int x = 0; x < out.cloud.xyz.cols; ++x) {
      const float d = out.match.disparity.at<float>(y, x);
      const cv::Vec3f p = out.cloud.xyz.at<cv::Vec3f>(y, x);
      if (std::isnan(d)) {
        EXPECT_TRUE(std::isnan(p[2]));
        continue;
      }
      const double z = out.geometry.f_px * out.geometry.baseline_m / (d - out.geometry.doffs());
      ASSERT_NEAR(p[2], z, 1e-4 * z);  // float32 xyz against the same formula in double
      ++checked;
      // 0.5 px of disparity error at these disparities is a few percent of depth.
      if (std::abs(p[2] - frame.gt_depth_m.at<float>(y, x)) <
          0.05 * frame.gt_depth_m.at<float>(y, x))
        ++close_to_truth;
    }
  }
  ASSERT_GT(checked, 1000);
  EXPECT_GT(close_to_truth, 0.95 * checked);

  in.stamp_s = 0.04;
  ASSERT_TRUE(pipeline.process(in, out, &error)) << error;
  EXPECT_TRUE(out.priors_used);
  ASSERT_EQ(pipeline.setCalibration(scene.calibration()), "");  // the same values: no change
  in.stamp_s = 0.08;
  ASSERT_TRUE(pipeline.process(in, out, &error)) << error;
  EXPECT_FALSE(out.priors_reset);

  StereoCalibration changed = scene.calibration();
  changed.right.P(0, 3) *= 1.01;  // a slightly different baseline
  ASSERT_EQ(pipeline.setCalibration(changed), "");
  in.stamp_s = 0.12;
  ASSERT_TRUE(pipeline.process(in, out, &error)) << error;
  EXPECT_TRUE(out.priors_reset);
  EXPECT_FALSE(out.priors_used);  // the old priors are gone: the full range

  StereoCalibration broken = scene.calibration();
  broken.left.K(0, 0) = 0.0;
  const std::string err = pipeline.setCalibration(broken);
  EXPECT_NE(err.find("left"), std::string::npos) << err;
}

// The rectify stage remaps with fixed-point tables converted once from the float maps; OpenCV's
// INTER_LINEAR remap converts float maps to the same form on every call, so the images must be
// bit-identical to a remap with the float maps (rectifyImage() still uses those).
TEST_F(PipelineTest, CalibratedRectificationIsBitIdenticalToTheFloatMapRemap) {
  SurgicalSceneParams sp;
  sp.width = 200;  // not a multiple of any SIMD width
  sp.height = 150;
  sp.seed = 9;
  const SurgicalScene scene(sp);
  SurgicalFrame frame;
  scene.render(0, frame);
  PipelineParams params = passThroughParams();
  params.rectify.mode = RectifyMode::kCalibrated;
  params.output.point_cloud = true;
  Pipeline pipeline(params);
  // The scene's own calibration is already rectified (identity maps): give the cameras some
  // radial distortion so that the maps interpolate between pixels.
  StereoCalibration calib = scene.calibration();
  calib.left.D = {-0.08, 0.01, 0.0, 0.0, 0.0};
  calib.right.D = {0.05, -0.01, 0.0, 0.0, 0.0};
  ASSERT_EQ(pipeline.setCalibration(calib), "");
  StereoInput in{frame.left, frame.right, "bgr8", "bgr8", 0.0};
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(in, out, &error)) << error;

  cv::Mat left_gray, right_gray, ref;
  cv::cvtColor(frame.left, left_gray, cv::COLOR_BGR2GRAY);
  cv::cvtColor(frame.right, right_gray, cv::COLOR_BGR2GRAY);
  ASSERT_TRUE(pipeline.rectifier().rectifyImage(true, left_gray, ref, cv::INTER_LINEAR, &error));
  EXPECT_EQ(cv::norm(out.left_rect_gray, ref, cv::NORM_INF), 0.0);
  ASSERT_TRUE(pipeline.rectifier().rectifyImage(false, right_gray, ref, cv::INTER_LINEAR, &error));
  EXPECT_EQ(cv::norm(out.right_rect_gray, ref, cv::NORM_INF), 0.0);
  ASSERT_TRUE(pipeline.rectifier().rectifyImage(true, frame.left, ref, cv::INTER_LINEAR, &error));
  EXPECT_EQ(cv::norm(out.left_rect_color, ref, cv::NORM_INF), 0.0);
  // The maps are not the identity: the test would notice a remap that did nothing.
  EXPECT_GT(cv::norm(out.left_rect_gray, left_gray, cv::NORM_L1), 0.0);
}

TEST_F(PipelineTest, ColourIsSkippedOnlyWhenNeitherTheCloudNorTheColourImageIsWanted) {
  const SyntheticScene scene = smallScene();
  StereoInput in = monoInput(scene, 0.0);
  cv::Mat left_bgr, right_bgr;
  cv::cvtColor(scene.left, left_bgr, cv::COLOR_GRAY2BGR);
  cv::cvtColor(scene.right, right_bgr, cv::COLOR_GRAY2BGR);
  in.left = left_bgr;
  in.right = right_bgr;
  in.left_encoding = in.right_encoding = "bgr8";
  PipelineParams params = passThroughParams();
  params.rectify.focal_px = 500.0;  // a metric pass-through geometry, so that the cloud is built
  params.rectify.baseline_m = 0.005;
  Pipeline with_color(params), without_color(params);
  without_color.setColorOutput(false);
  PipelineOutput a, b;
  std::string error;
  ASSERT_TRUE(with_color.process(in, a, &error)) << error;
  ASSERT_TRUE(without_color.process(in, b, &error)) << error;
  EXPECT_FALSE(a.left_rect_color.empty());
  EXPECT_TRUE(b.left_rect_color.empty());
  EXPECT_TRUE(sameDisparity(a.match.disparity, b.match.disparity));

  // With a cloud the colour is computed anyway (the cloud is coloured).
  params.output.point_cloud = true;
  without_color.setParams(params);
  in.stamp_s = 0.04;
  ASSERT_TRUE(without_color.process(in, b, &error)) << error;
  ASSERT_FALSE(b.cloud.bgr.empty());
  EXPECT_EQ(cv::norm(b.cloud.bgr, left_bgr, cv::NORM_INF), 0.0);
}

// The nodelet measures the rectification quality in the background: the same figure as inline,
// reported later, with the frame it was measured on; the images do not change.
TEST_F(PipelineTest, BackgroundQualityMeasurementGivesTheInlineFigureLater) {
  SurgicalSceneParams sp;
  sp.width = 320;
  sp.height = 240;
  sp.seed = 4;
  const SurgicalScene scene(sp);
  SurgicalFrame frame;
  scene.render(0, frame);
  cv::Mat left_gray, right_gray;
  cv::cvtColor(frame.left, left_gray, cv::COLOR_BGR2GRAY);
  cv::cvtColor(frame.right, right_gray, cv::COLOR_BGR2GRAY);
  RectifyParams rp;
  rp.mode = RectifyMode::kCalibrated;
  rp.quality_stride = 2;
  rp.row_correction = false;  // first the measurement alone; the correction it feeds: below
  StereoRectifier inline_rect(rp), background(rp);
  ASSERT_EQ(inline_rect.setCalibration(scene.calibration()), "");
  ASSERT_EQ(background.setCalibration(scene.calibration()), "");
  background.setAsyncQuality(true);
  cv::Mat l1, r1, c1, l2, r2, c2;
  std::string error;
  ASSERT_TRUE(inline_rect.rectify(left_gray, right_gray, cv::Mat(), l1, r1, c1, &error)) << error;
  ASSERT_TRUE(background.rectify(left_gray, right_gray, cv::Mat(), l2, r2, c2, &error)) << error;
  EXPECT_EQ(cv::norm(l1, l2, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(r1, r2, cv::NORM_INF), 0.0);
  const RectificationQuality expected = inline_rect.quality();
  ASSERT_TRUE(expected.valid) << expected.message;
  background.setAsyncQuality(false);  // waits for the measurement in flight and records it
  const RectificationQuality q = background.quality();
  ASSERT_TRUE(q.valid) << q.message;
  EXPECT_EQ(q.frame_index, 0);
  EXPECT_EQ(q.num_matches, expected.num_matches);
  EXPECT_EQ(q.median_offset_px, expected.median_offset_px);
  EXPECT_EQ(q.p90_offset_px, expected.p90_offset_px);

  // With the row correction (applied whatever its size here), the background rectifier applies
  // the plane its measurement fitted once it is recorded: the next frame is the inline one's.
  rp.row_correction = true;
  rp.row_correction_min_px = 0.0;
  StereoRectifier inline_corr(rp), background_corr(rp);
  ASSERT_EQ(inline_corr.setCalibration(scene.calibration()), "");
  ASSERT_EQ(background_corr.setCalibration(scene.calibration()), "");
  background_corr.setAsyncQuality(true);
  for (int frame = 0; frame < 2; ++frame) {
    ASSERT_TRUE(inline_corr.rectify(left_gray, right_gray, cv::Mat(), l1, r1, c1, &error)) << error;
    ASSERT_TRUE(background_corr.rectify(left_gray, right_gray, cv::Mat(), l2, r2, c2, &error))
        << error;
    if (frame == 0) background_corr.setAsyncQuality(false);  // its measurement recorded
  }
  ASSERT_GT(inline_corr.quality().row_offset_matches, 0);
  EXPECT_EQ(background_corr.quality().row_offset, inline_corr.quality().row_offset);
  EXPECT_EQ(cv::norm(r1, r2, cv::NORM_INF), 0.0);
}

// Without a scene change the temporal matcher is one RobustMatcher::compute() with the same range,
// to the bit: the passes match, and the depth-edge measure and the post-filter then run as the
// matcher runs them. Narrowed ranges grow their window like full ones (pixels accepted with a
// window wider than the first in the frames with priors).
TEST_F(PipelineTest, TemporalMatcherWithoutASecondPassEqualsOneMatcherCall) {
  const SyntheticScene s = lowTextureScene();
  PipelineParams p = passThroughParams();
  RobustMatcher direct(p.matcher, p.filter);
  TemporalMatcher matcher(p.matcher, p.filter);
  TemporalTracker tracker(p.temporal);
  MatchResult a, b;
  int64_t wide = 0;
  for (int f = 0; f < 3; ++f) {
    TemporalFrameInfo info{s.left.size(), 0.04 * f, 0, p.matcher.min_disparity,
                           p.matcher.max_disparity};
    const SearchRange* range = tracker.beginFrame(info);
    EXPECT_EQ(range != nullptr, f > 0);
    direct.compute(s.left, s.right, a, range);
    TemporalMatchReport report;
    matcher.compute(s.left, s.right, tracker, range, b, &report);
    tracker.endFrame(b.disparity, false, false);
    EXPECT_TRUE(sameMatch(a, b)) << "frame " << f;
    if (f > 0) {
      for (size_t k = 1; k < b.stats.accepted_per_window.size(); ++k) {
        wide += b.stats.accepted_per_window[k];
      }
    }
  }
  EXPECT_GT(wide, 0);
}

// Priors narrow the search; they must not let errors through that the full search rejects. A
// generated moving sequence with exact ground truth (breathing, heartbeat, camera drift, an
// instrument moving 5x its default speed, highlights, sensor noise) through two pipelines, priors
// on (the shipped preset) and off: bad2 among output pixels seen by both cameras, pooled over the
// frames.
TEST_F(PipelineTest, PriorsAddNoErrorOnAGeneratedMovingSequence) {
  SurgicalSceneParams sp;
  sp.width = 320;
  sp.height = 180;
  sp.seed = 2;
  sp.instrument_speed = 5.0;
  const SurgicalScene scene(sp);
  int dmin = 0, dmax = 0;
  scene.suggestedDisparityRange(&dmin, &dmax);
  PipelineParams with = passThroughParams(), without = passThroughParams();
  for (PipelineParams* p : {&with, &without}) {
    p->matcher.min_disparity = dmin;
    p->matcher.max_disparity = dmax;
  }
  without.temporal.enabled = false;
  Pipeline pipeline_with(with), pipeline_without(without);
  PipelineOutput out_with, out_without;
  std::string error;
  int64_t output[2] = {0, 0}, bad[2] = {0, 0}, scored_gt = 0, narrowed_frames = 0;
  SurgicalFrame frame;
  for (int i = 0; i < 40; ++i) {
    scene.render(i, frame);
    cv::Mat l, r;
    cv::cvtColor(frame.left, l, cv::COLOR_BGR2GRAY);
    cv::cvtColor(frame.right, r, cv::COLOR_BGR2GRAY);
    const StereoInput in{l, r, "mono8", "mono8", frame.stamp_s};
    ASSERT_TRUE(pipeline_with.process(in, out_with, &error)) << error;
    ASSERT_TRUE(pipeline_without.process(in, out_without, &error)) << error;
    narrowed_frames += out_with.priors_used;
    const cv::Mat nonocc = frame.visibility == kVisibleBoth;
    scored_gt += cv::countNonZero(nonocc);
    for (int k = 0; k < 2; ++k) {
      const cv::Mat& d = (k == 0 ? out_with : out_without).match.disparity;
      for (int y = 0; y < d.rows; ++y) {
        for (int x = 0; x < d.cols; ++x) {
          const float v = d.at<float>(y, x);
          if (std::isnan(v) || !nonocc.at<uint8_t>(y, x)) continue;
          ++output[k];
          bad[k] += std::fabs(v - frame.gt_disparity.at<float>(y, x)) > 2.0f;
        }
      }
    }
  }
  EXPECT_EQ(narrowed_frames, 39);  // every frame after the first searched narrowed ranges
  const double bad2_with = double(bad[0]) / double(output[0]);
  const double bad2_without = double(bad[1]) / double(output[1]);
  const double density_with = double(output[0]) / double(scored_gt);
  const double density_without = double(output[1]) / double(scored_gt);
  RecordProperty("bad2_with_priors", std::to_string(bad2_with));
  RecordProperty("bad2_without_priors", std::to_string(bad2_without));
  RecordProperty("density_with_priors", std::to_string(density_with));
  RecordProperty("density_without_priors", std::to_string(density_without));
  // Measured: bad2 0.017% with priors, 0.019% without; density 86.9% and 87.9%. bad2 may be no
  // higher than without priors within 0.02 point (docs/method.md section 5.3: priors never add
  // error); with the narrowed guards off (min_ncc_narrowed -1, no edge zone, no neighbourhood,
  // +-1 px ranges) it is 0.56% (endo_stereo_temporal_bench --width 320 --height 180 --seed 2
  // --instrument-speed 5 --frames 40). Density: 1.5 points allowed for the measured 1.0 point
  // that priors cost on this fast instrument (narrowed misses near its moving edges, and pixels
  // without a prior searching the full range one frame in four, temporal.full_range_period_frames).
  EXPECT_LE(bad2_with, bad2_without + 0.0002) << bad2_with << " vs " << bad2_without;
  EXPECT_GE(density_with, density_without - 0.015) << density_with << " vs " << density_without;
}

// The output does not depend on the number of threads, with every pass on.
TEST_F(PipelineTest, TemporalPassesGiveTheSameOutputForOneAndTwoThreads) {
  const SyntheticScene a = lowTextureScene();
  const SyntheticScene b = smallScene();
  PipelineParams p = passThroughParams();
  cv::Mat first[4];
  for (const int threads : {1, 2}) {
    p.matcher.num_threads = threads;
    Pipeline pipeline(p);
    PipelineOutput out;
    std::string error;
    for (int f = 0; f < 4; ++f) {
      // A cut after two frames: a rejection and a full search again.
      ASSERT_TRUE(pipeline.process(monoInput(f < 2 ? a : b, 0.04 * f), out, &error)) << error;
      if (threads == 1) {
        first[f] = out.match.disparity.clone();
      } else {
        EXPECT_TRUE(sameDisparity(first[f], out.match.disparity)) << "frame " << f;
      }
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
