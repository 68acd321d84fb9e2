// The Pipeline's plumbing: stages in order, errors reported without throwing, temporal state
// reset on the events METHOD.md section 4 names, optional outputs, geometry from calibration.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <stdexcept>
#include <string>

#include "endo_stereo/core/pipeline.hpp"
#include "surgical_scene.hpp"
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

class PipelineTest : public ::testing::Test {
 protected:
  void SetUp() override { cv::setNumThreads(2); }
};

TEST_F(PipelineTest, PassThroughGivesExactlyTheMatchersOutput) {
  const SyntheticScene s = smallScene();
  const PipelineParams params = passThroughParams();
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
  EXPECT_FALSE(out.priors_used);
  ASSERT_TRUE(pipeline.process(monoInput(s, 10.04), out, &error)) << error;
  EXPECT_TRUE(out.priors_used);
  EXPECT_FALSE(out.priors_reset);
  EXPECT_GT(out.prior_stats.narrowed_pixels, 0);
  EXPECT_GT(out.prior_stats.prior_hits, 0);

  ASSERT_TRUE(pipeline.process(monoInput(s, 9.0), out, &error)) << error;  // a looping bag
  EXPECT_TRUE(out.priors_reset);
  EXPECT_FALSE(out.reset_reason.empty());
  EXPECT_FALSE(out.priors_used);

  ASSERT_TRUE(pipeline.process(monoInput(s, 9.04), out, &error)) << error;
  EXPECT_TRUE(out.priors_used);
  ASSERT_TRUE(pipeline.process(monoInput(s, 60.0), out, &error)) << error;  // a long gap
  EXPECT_TRUE(out.priors_reset);
  EXPECT_FALSE(out.priors_used);

  ASSERT_TRUE(pipeline.process(monoInput(s, 60.04), out, &error)) << error;
  EXPECT_TRUE(out.priors_used);
  pipeline.reset();  // asked for by the caller (the nodelet on a reconfigure, for instance)
  ASSERT_TRUE(pipeline.process(monoInput(s, 60.08), out, &error)) << error;
  EXPECT_FALSE(out.priors_used);
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
  const PipelineParams params = passThroughParams();
  Pipeline pipeline(params);
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(monoInput(a, 0.0), out, &error)) << error;
  ASSERT_TRUE(pipeline.process(monoInput(a, 0.04), out, &error)) << error;
  ASSERT_TRUE(out.priors_used);
  ASSERT_TRUE(pipeline.process(monoInput(b, 0.08), out, &error)) << error;
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
  EXPECT_FALSE(out.priors_used);

  StereoCalibration broken = scene.calibration();
  broken.left.K(0, 0) = 0.0;
  const std::string err = pipeline.setCalibration(broken);
  EXPECT_NE(err.find("left"), std::string::npos) << err;
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
