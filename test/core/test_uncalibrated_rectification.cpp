// Uncalibrated rectification (homography and polar) on synthetic rigs with exact geometry.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <opencv2/core/utility.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/point_cloud.hpp"
#include "endo_stereo/core/rectification.hpp"
#include "synthetic_rig.hpp"

namespace endo_stereo {
namespace {

const cv::Size kSize(480, 360);
constexpr double kF = 420.0;

/// Right camera with its centre at @p c (left frame, m) and orientation r (Rodrigues, rad).
SyntheticRig rigWith(const cv::Vec3d& c, const cv::Vec3d& r) {
  SyntheticRig rig = makeParallelRig(kSize, kF, 0.005);
  rig.right.R = rodrigues(r);
  rig.right.t = -(rig.right.R * c);
  return rig;
}

SyntheticRig namedRig(const std::string& name) {
  if (name == "parallel") return rigWith({0.005, 0, 0}, {0, 0, 0});
  // Toed in by 3 degrees (epipole about 19 focal lengths away).
  if (name == "verged") return rigWith({0.005, 0.0001, 0}, {0.004, -0.052, 0.0});
  // Rolled by 3 degrees, pitched by 0.6 degrees: epipolar lines tilted in the raw right image.
  if (name == "rotated") return rigWith({0.005, 0, 0.0002}, {0.01, 0.0, 0.052});
  // Mostly forward motion: the epipoles lie inside the images, where only polar works.
  return rigWith({0.0012, 0.0006, 0.010}, {0.0, 0.0, 0.0});
}

struct Frame {
  cv::Mat left, right;
  TexturedSurface surface;
};

/// Rendered frames per rig, cached across tests (rendering dominates the run time).
const std::vector<Frame>& frames(const std::string& rig_name, int n) {
  static std::map<std::string, std::vector<Frame>> cache;
  std::vector<Frame>& f = cache[rig_name];
  const SyntheticRig rig = namedRig(rig_name);
  while (int(f.size()) < n) {
    Frame fr;
    fr.surface = makeTexturedSurface(100 + f.size());
    fr.surface.z0_m = 0.075 + 0.01 * double(f.size());
    fr.left = renderSurface(rig.left, fr.surface);
    fr.right = renderSurface(rig.right, fr.surface);
    f.push_back(fr);
  }
  return f;
}

struct Residual {
  double median = 0, p90 = 0, depth_error = 0;
  double d_min = 1e9, d_max = -1e9;  // rectified disparity range of the points, px
  int n = 0;
};

/// Ground truth: surface points seen by a grid of left pixels, projected into the right view,
/// mapped through the rectifier; the vertical offsets of the pairs (and, for the metric check,
/// the median relative depth error of f B / d).
Residual groundTruthResidual(const StereoRectifier& r, const SyntheticRig& rig,
                             const TexturedSurface& surf) {
  std::vector<double> dy, dz;
  double d_min = 1e9, d_max = -1e9;
  const cv::Matx33d Ki = rig.left.K.inv();
  for (int v = 10; v < kSize.height - 10; v += 12) {
    for (int u = 10; u < kSize.width - 10; u += 12) {
      const cv::Vec3d ray = Ki * cv::Vec3d(u, v, 1);
      cv::Point3d X;
      cv::Point2d pr, a, b;
      if (!surf.intersect(cv::Vec3d(0, 0, 0), ray, &X)) continue;
      if (!projectPoint(rig.right, X, &pr)) continue;
      if (pr.x < 0 || pr.y < 0 || pr.x > kSize.width - 1 || pr.y > kSize.height - 1) continue;
      if (!r.rawToRectified(true, cv::Point2d(u, v), &a) || !r.rawToRectified(false, pr, &b))
        continue;
      dy.push_back(std::abs(a.y - b.y));
      d_min = std::min(d_min, a.x - b.x);
      d_max = std::max(d_max, a.x - b.x);
      const RectifiedGeometry& g = r.geometry();
      if (!g.polar) dz.push_back(std::abs(g.depthFromDisparity(a.x - b.x) - X.z) / X.z);
    }
  }
  Residual res;
  res.n = int(dy.size());
  res.d_min = d_min;
  res.d_max = d_max;
  if (dy.empty()) return res;
  std::sort(dy.begin(), dy.end());
  res.median = dy[dy.size() / 2];
  res.p90 = dy[size_t(0.9 * double(dy.size() - 1))];
  if (!dz.empty()) {
    std::sort(dz.begin(), dz.end());
    res.depth_error = dz[dz.size() / 2];
  }
  return res;
}

struct UncalCase {
  const char* rig;
  UncalibratedMethod method;
  const char* expected;  // method the rectifier should end up using
};

class UncalibratedRigTest : public ::testing::TestWithParam<UncalCase> {
 protected:
  void SetUp() override { cv::setNumThreads(1); }  // SIFT/USAC results pinned
  void TearDown() override { cv::setNumThreads(-1); }
};

TEST_P(UncalibratedRigTest, AlignsRowsWithoutCalibration) {
  const UncalCase uc = GetParam();
  const SyntheticRig rig = namedRig(uc.rig);
  const std::vector<Frame>& fr = frames(uc.rig, 2);
  RectifyParams rp;
  rp.mode = RectifyMode::kUncalibrated;
  rp.method = uc.method;
  rp.estimation_frames = 2;
  rp.quality_stride = 1;
  StereoRectifier rect(rp);
  cv::Mat lg, rg, lc;
  std::string err;
  for (int i = 0; i < 2; ++i) {
    ASSERT_TRUE(rect.rectify(fr[i].left, fr[i].right, cv::Mat(), lg, rg, lc, &err)) << err;
  }
  EXPECT_EQ(rect.activeMethod(), uc.expected);
  const RectificationQuality q = rect.quality();
  const Residual gt = groundTruthResidual(rect, rig, fr[1].surface);
  std::printf(
      "[ measure  ] %s/%s -> %s: ground truth |dy| median %.3f p90 %.3f px (%d points); "
      "feature residual median %.3f p90 %.3f px (%d); rectified %dx%d, disparities %.1f..%.1f px\n",
      uc.rig, toString(uc.method).c_str(), rect.activeMethod().c_str(), gt.median, gt.p90, gt.n,
      q.median_offset_px, q.p90_offset_px, q.num_matches, lg.cols, lg.rows, gt.d_min, gt.d_max);
  ASSERT_GT(gt.n, 300);
  // Requirement: median vertical offset after uncalibrated rectification under 0.5 px.
  EXPECT_LT(gt.median, 0.5);
  EXPECT_TRUE(q.valid);
  EXPECT_TRUE(q.estimated);
  EXPECT_LT(q.median_offset_px, 0.5);
  EXPECT_FALSE(q.warning);
  // The rectified images themselves (the remap tables, not only the point mapping) are
  // row-aligned: SIFT matches measured directly on them.
  const RectificationQuality qi = measureRowAlignment(lg, rg, 1000, 0.75, 1.0);
  std::printf("[ measure  ]   on the rectified images: median %.3f p90 %.3f px (%d matches)\n",
              qi.median_offset_px, qi.p90_offset_px, qi.num_matches);
  EXPECT_TRUE(qi.valid);
  EXPECT_LT(qi.median_offset_px, 0.5);
  // The rectified left view keeps most of the image (not a sliver or an empty frame).
  EXPECT_GT(cv::countNonZero(lg), int(0.5 * kSize.area()));
  if (rect.activeMethod() == "polar") {
    const PolarRectification* p = rect.polar();
    ASSERT_NE(p, nullptr);
    EXPECT_TRUE(rect.geometry().polar);
    EXPECT_FALSE(rect.geometry().metric);
    if (std::string(uc.rig) != "forward") {
      // Epipoles outside the images: upright and not mirrored (columns follow raw x, rows raw y).
      cv::Point2d a, b, c;
      ASSERT_TRUE(p->toRectified(true, cv::Point2d(100, 180), &a));
      ASSERT_TRUE(p->toRectified(true, cv::Point2d(380, 180), &b));
      ASSERT_TRUE(p->toRectified(true, cv::Point2d(240, 300), &c));
      EXPECT_GT(b.x - a.x, 200);
      EXPECT_GT(c.y - a.y, 80);
    }
    // Round trip raw -> polar -> raw.
    cv::Point2d pr, back;
    ASSERT_TRUE(p->toRectified(true, cv::Point2d(200.5, 150.25), &pr));
    back = p->toRaw(true, pr.x, pr.y);
    EXPECT_NEAR(back.x, 200.5, 1e-3);
    EXPECT_NEAR(back.y, 150.25, 1e-3);
  } else {
    cv::Matx33d hl, hr;
    EXPECT_TRUE(rect.homographies(&hl, &hr));
    // No shear between the views: the surface spans about 21-28 px of true disparity (depth
    // 66-94 mm); a sheared left warp (e.g. an unrotated left view against a rolled right one)
    // would add up to sin(3 deg) * 360 = 19 px across the rows.
    EXPECT_LT(gt.d_max - gt.d_min, 10.0);
    EXPECT_GT(gt.d_min, 0.0);              // raw disparities keep their sign
    EXPECT_FALSE(rect.geometry().metric);  // no focal / baseline given: disparity only
  }
}

INSTANTIATE_TEST_SUITE_P(
    Rigs, UncalibratedRigTest,
    ::testing::Values(UncalCase{"parallel", UncalibratedMethod::kAuto, "homography"},
                      UncalCase{"verged", UncalibratedMethod::kAuto, "homography"},
                      UncalCase{"rotated", UncalibratedMethod::kAuto, "homography"},
                      UncalCase{"parallel", UncalibratedMethod::kPolar, "polar"},
                      UncalCase{"verged", UncalibratedMethod::kPolar, "polar"},
                      UncalCase{"rotated", UncalibratedMethod::kPolar, "polar"},
                      UncalCase{"forward", UncalibratedMethod::kAuto, "polar"}),
    [](const ::testing::TestParamInfo<UncalCase>& info) {
      return std::string(info.param.rig) + "_" + toString(info.param.method);
    });

class UncalibratedTest : public ::testing::Test {
 protected:
  void SetUp() override { cv::setNumThreads(1); }
  void TearDown() override { cv::setNumThreads(-1); }

  // The drift tests: uncalibrated, measured every frame, re-estimated after two measurements
  // above 1 px in a row.
  static RectifyParams driftParams() {
    RectifyParams rp;
    rp.mode = RectifyMode::kUncalibrated;
    rp.estimation_frames = 2;
    rp.quality_stride = 1;
    rp.reestimate_threshold_px = 1.0;
    rp.reestimate_after = 2;
    return rp;
  }
  // Pools the parallel rig's two frames: the estimate is then frozen.
  static void freezeOnParallelRig(StereoRectifier& rect) {
    const std::vector<Frame>& a = frames("parallel", 2);
    cv::Mat lg, rg, lc;
    std::string err;
    for (int i = 0; i < 2; ++i)
      ASSERT_TRUE(rect.rectify(a[i].left, a[i].right, cv::Mat(), lg, rg, lc, &err)) << err;
  }
};

TEST_F(UncalibratedTest, HomographyRefusesAnEpipoleInsideTheImage) {
  const std::vector<Frame>& fr = frames("forward", 1);
  RectifyParams rp;
  rp.mode = RectifyMode::kUncalibrated;
  rp.method = UncalibratedMethod::kHomography;
  rp.estimation_frames = 1;
  StereoRectifier rect(rp);
  cv::Mat lg, rg, lc;
  std::string err;
  EXPECT_FALSE(rect.rectify(fr[0].left, fr[0].right, cv::Mat(), lg, rg, lc, &err));
  EXPECT_NE(err.find("could not be estimated"), std::string::npos) << err;
  EXPECT_NE(err.find("polar"), std::string::npos) << err;
}

TEST_F(UncalibratedTest, TexturelessPairReportsFailureInsteadOfGarbage) {
  const SyntheticRig rig = namedRig("parallel");
  TexturedSurface flat = makeTexturedSurface(5, 64);
  cv::Mat l = renderSurface(rig.left, flat, 128.0), r = renderSurface(rig.right, flat, 128.0);
  // Sensor noise only: SIFT finds nothing that matches consistently.
  cv::Mat noise(l.size(), CV_8UC1);
  cv::RNG rng(9);
  rng.fill(noise, cv::RNG::NORMAL, 0, 1.5);
  l += noise;
  rng.fill(noise, cv::RNG::NORMAL, 0, 1.5);
  r += noise;
  RectifyParams rp;
  rp.mode = RectifyMode::kUncalibrated;
  StereoRectifier rect(rp);
  cv::Mat lg, rg, lc;
  std::string err;
  for (int i = 0; i < 3; ++i) {
    EXPECT_FALSE(rect.rectify(l, r, cv::Mat(), lg, rg, lc, &err));
    EXPECT_NE(err.find("could not be estimated"), std::string::npos) << err;
  }
  std::printf("[ measure  ] textureless: %s\n", err.c_str());
  EXPECT_FALSE(rect.quality().estimated);
  EXPECT_EQ(rect.activeMethod(), "");
  EXPECT_TRUE(lg.empty());
}

TEST_F(UncalibratedTest, PlanarSceneIsRefusedAsAmbiguous) {
  // A textured plane: every match fits one homography, so F (and any rectification from it) is
  // undetermined; the rectifier must say so rather than pick an arbitrary epipole.
  const SyntheticRig rig = namedRig("verged");
  TexturedSurface plane = makeTexturedSurface(21);
  plane.bump_m = 0;
  const cv::Mat l = renderSurface(rig.left, plane), r = renderSurface(rig.right, plane);
  RectifyParams rp;
  rp.mode = RectifyMode::kUncalibrated;
  rp.estimation_frames = 1;
  StereoRectifier rect(rp);
  cv::Mat lg, rg, lc;
  std::string err;
  EXPECT_FALSE(rect.rectify(l, r, cv::Mat(), lg, rg, lc, &err));
  std::printf("[ measure  ] planar scene: %s\n", err.c_str());
  EXPECT_NE(err.find("could not be estimated"), std::string::npos) << err;
  EXPECT_NE(err.find("homography"), std::string::npos) << err;
}

TEST_F(UncalibratedTest, ReestimatesWhenTheRigDrifts) {
  StereoRectifier rect(driftParams());
  ASSERT_NO_FATAL_FAILURE(freezeOnParallelRig(rect));
  const std::vector<Frame>& b = frames("rotated", 2);
  cv::Mat lg, rg, lc;
  std::string err;
  const uint64_t gen_a = rect.generation();
  EXPECT_LT(rect.quality().median_offset_px, 0.5);
  // The rig changes (the right camera rolls by 3 degrees): the fixed estimate is now wrong.
  ASSERT_TRUE(rect.rectify(b[0].left, b[0].right, cv::Mat(), lg, rg, lc, &err)) << err;
  EXPECT_TRUE(rect.quality().warning);
  EXPECT_EQ(rect.generation(), gen_a);  // one bad measurement is not enough
  ASSERT_TRUE(rect.rectify(b[1].left, b[1].right, cv::Mat(), lg, rg, lc, &err)) << err;
  // Second bad measurement: re-estimation starts; two frames are pooled, then it is replaced.
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(rect.rectify(b[i % 2].left, b[i % 2].right, cv::Mat(), lg, rg, lc, &err)) << err;
  }
  EXPECT_GT(rect.generation(), gen_a);
  const Residual gt = groundTruthResidual(rect, namedRig("rotated"), b[1].surface);
  std::printf(
      "[ measure  ] after drift: ground truth |dy| median %.3f px, measured median %.3f px\n",
      gt.median, rect.quality().median_offset_px);
  EXPECT_LT(gt.median, 0.5);
  EXPECT_FALSE(rect.quality().warning);
}

// The nodelet measures in the background: a drift measured there counts when it is recorded.
TEST_F(UncalibratedTest, BackgroundMeasurementsAlsoTriggerReestimation) {
  StereoRectifier rect(driftParams());
  ASSERT_NO_FATAL_FAILURE(freezeOnParallelRig(rect));
  const std::vector<Frame>& b = frames("rotated", 2);
  cv::Mat lg, rg, lc;
  std::string err;
  const uint64_t gen_a = rect.generation();
  rect.setAsyncQuality(true);
  ASSERT_TRUE(rect.rectify(b[0].left, b[0].right, cv::Mat(), lg, rg, lc, &err)) << err;
  rect.setAsyncQuality(false);  // waits for the background measurement and records it
  EXPECT_EQ(rect.quality().frame_index, 2);
  EXPECT_TRUE(rect.quality().warning) << rect.quality().message;
  EXPECT_EQ(rect.generation(), gen_a);  // one bad measurement is not enough
  ASSERT_TRUE(rect.rectify(b[1].left, b[1].right, cv::Mat(), lg, rg, lc, &err)) << err;
  // The second bad measurement in a row (the first was the background one): pooling starts.
  EXPECT_EQ(rect.quality().message, "rectification drifted: re-estimating");
  for (int i = 0; i < 2; ++i) {
    ASSERT_TRUE(rect.rectify(b[i].left, b[i].right, cv::Mat(), lg, rg, lc, &err)) << err;
  }
  EXPECT_GT(rect.generation(), gen_a);
  EXPECT_LT(groundTruthResidual(rect, namedRig("rotated"), b[1].surface).median, 0.5);
}

TEST_F(UncalibratedTest, FocalAndBaselineMakeDepthMetric) {
  const std::vector<Frame>& fr = frames("parallel", 2);
  RectifyParams rp;
  rp.mode = RectifyMode::kUncalibrated;
  rp.estimation_frames = 2;
  rp.focal_px = kF;
  rp.baseline_m = 0.005;
  StereoRectifier rect(rp);
  cv::Mat lg, rg, lc;
  std::string err;
  for (int i = 0; i < 2; ++i)
    ASSERT_TRUE(rect.rectify(fr[i].left, fr[i].right, cv::Mat(), lg, rg, lc, &err)) << err;
  EXPECT_TRUE(rect.geometry().metric);
  const Residual gt = groundTruthResidual(rect, namedRig("parallel"), fr[1].surface);
  std::printf(
      "[ measure  ] uncalibrated parallel rig with focal/baseline: median depth error %.2f%%\n",
      100 * gt.depth_error);
  // A parallel rig has zero disparity at infinity, the assumption metric uncalibrated depth makes;
  // the residual comes from the projective freedom left in the homographies (2% is generous).
  EXPECT_LT(gt.depth_error, 0.02);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
