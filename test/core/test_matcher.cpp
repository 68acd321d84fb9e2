// The robust matcher (docs/method.md section 2) on synthetic scenes with exact ground truth.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "endo_stereo/core/evaluation.hpp"
#include "endo_stereo/core/matcher.hpp"
#include "endo_stereo/core/reference_matcher.hpp"
#include "synthetic_scene.hpp"
// The depth-edge filter on its own, on hand-made maps with exact answers (a core-private header).
#include "../../src/core/match/depth_edge_filter.hpp"

namespace endo_stereo {
namespace {

PostFilterParams noFilter() {
  PostFilterParams p;
  p.remove_outliers = false;
  p.fill_holes = false;
  return p;
}

MatcherParams range(int lo, int hi) {
  MatcherParams p;
  p.min_disparity = lo;
  p.max_disparity = hi;
  return p;
}

class MatcherTest : public ::testing::Test {
 protected:
  void SetUp() override { cv::setNumThreads(1); }  // pinned; one test checks 2 threads itself
  void TearDown() override { cv::setNumThreads(-1); }
};

int countCode(const cv::Mat& code, const cv::Mat& mask, int c) {
  return cv::countNonZero((code == c) & mask);
}

cv::Mat acceptedMask(const cv::Mat& code) { return code >= static_cast<int>(kCodeAcceptedBase); }

TEST_F(MatcherTest, RecoversAConstantShiftOfRandomTexture) {
  SyntheticSceneParams sp;
  sp.base_disparity_px = 12;
  const SyntheticScene s = makeSyntheticScene(sp);
  RobustMatcher m(range(0, 31), noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r);
  const DisparityScore score = scoreDisparity(r.disparity, s.disparity, s.occluded == 0);
  // Rich texture, no noise: nearly every visible pixel away from the border must be matched, and
  // matched right (sub-pixel interpolation of the texture gives < 0.1 px error).
  EXPECT_GT(score.density, 0.9);
  EXPECT_EQ(score.n_bad1, 0);
  EXPECT_LT(score.mean_abs_error, 0.1);
  EXPECT_GT(r.stats.accepted_per_window[0], r.stats.total_pixels / 2);
}

TEST_F(MatcherTest, SubpixelErrorSmallOnASlantedPlane) {
  SyntheticSceneParams sp;
  sp.base_disparity_px = 15.3;
  sp.slope_x = 0.04;
  sp.slope_y = -0.02;
  sp.noise_stdev = 1.0;
  const SyntheticScene s = makeSyntheticScene(sp);
  RobustMatcher m(range(0, 31), noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r);
  const DisparityScore score = scoreDisparity(r.disparity, s.disparity, s.occluded == 0);
  // docs/method.md: a point cloud needs sub-pixel disparities; we require < 0.2 px on a smooth
  // slanted surface. The parabola's known bias (pixel locking) is about 0.1 px at worst.
  EXPECT_GT(score.density, 0.8);
  EXPECT_LT(score.mean_abs_error, 0.2);
  EXPECT_EQ(score.n_bad1, 0);
  // Without the parabola the error is that of rounding (about 0.25 px mean): the test can tell.
  MatcherParams p = range(0, 31);
  p.subpixel = false;
  m.setParams(p, noFilter());
  m.compute(s.left, s.right, r);
  EXPECT_GT(scoreDisparity(r.disparity, s.disparity, s.occluded == 0).mean_abs_error, 0.2);
}

TEST_F(MatcherTest, SubpixelErrorSmallOnACurvedSurface) {
  SyntheticSceneParams sp;
  sp.base_disparity_px = 20;
  sp.curvature = -0.0002;  // paraboloid: 20 px in the centre, about 12 px in the corners
  const SyntheticScene s = makeSyntheticScene(sp);
  RobustMatcher m(range(0, 31), noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r);
  const DisparityScore score = scoreDisparity(r.disparity, s.disparity, s.occluded == 0);
  EXPECT_GT(score.density, 0.8);
  EXPECT_LT(score.mean_abs_error, 0.2);
}

TEST_F(MatcherTest, RejectsTexturelessPatchByStructure) {
  SyntheticSceneParams sp;
  sp.textureless = cv::Rect(100, 60, 120, 120);
  const SyntheticScene s = makeSyntheticScene(sp);
  MatcherParams p = range(0, 31);
  p.gamma_min = 0.5;
  RobustMatcher m(p, noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r);
  // Deep inside the patch (farther than w_max / 2 from its edge) no window sees texture.
  const cv::Rect inner(100 + 16, 60 + 16, 120 - 32, 120 - 32);
  const cv::Mat all(inner.size(), CV_8UC1, cv::Scalar(255));
  EXPECT_EQ(cv::countNonZero(acceptedMask(r.code(inner))), 0);
  EXPECT_EQ(countCode(r.code(inner), all, kCodeRejectStructure), inner.area());
  // The textured rest is kept.
  const DisparityScore outside =
      scoreDisparity(r.disparity(cv::Rect(0, 0, 90, 240)), s.disparity(cv::Rect(0, 0, 90, 240)),
                     s.occluded(cv::Rect(0, 0, 90, 240)) == 0);
  EXPECT_GT(outside.density, 0.8);
}

TEST_F(MatcherTest, RejectsRepetitivePatternByPeakGap) {
  SyntheticSceneParams sp;
  sp.repetitive = cv::Rect(80, 40, 160, 160);
  sp.repetitive_period_px = 8;  // peaks every 8 px inside a 32-disparity search range
  const SyntheticScene s = makeSyntheticScene(sp);
  RobustMatcher m(range(0, 31), noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r);
  const cv::Rect inner(80 + 16, 40 + 16, 160 - 32, 160 - 32);
  const cv::Mat all(inner.size(), CV_8UC1, cv::Scalar(255));
  EXPECT_EQ(cv::countNonZero(acceptedMask(r.code(inner))), 0);
  EXPECT_EQ(countCode(r.code(inner), all, kCodeRejectPeakGap), inner.area());
  // The same region with ordinary texture is matched: the pattern is what fails.
  sp.repetitive = cv::Rect();
  const SyntheticScene plain = makeSyntheticScene(sp);
  m.compute(plain.left, plain.right, r);
  EXPECT_GT(cv::countNonZero(acceptedMask(r.code(inner))), inner.area() * 9 / 10);
}

TEST_F(MatcherTest, RejectsOccludedPixelsByLeftRightConsistency) {
  SyntheticSceneParams sp;
  sp.base_disparity_px = 6;
  sp.occluder = cv::Rect(140, 50, 80, 140);
  sp.occluder_disparity_px = 26;  // a 20 px wide strip left of it is hidden from the right view
  const SyntheticScene s = makeSyntheticScene(sp);
  MatcherParams p = range(0, 31);
  p.window_max_px = p.window_min_px;  // one window: no fattening from large windows here
  p.epsilon_px = 1.0;
  p.delta_min = 0.0;  // peak gap off: the left-right check alone must reject
  p.min_ncc = -1.0;
  p.edge_disparity_jump_px = 0.0;  // and so must our edge measure
  RobustMatcher m(p, noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r);
  // The hidden strip, away from the occluder's edge by more than the window half width.
  const cv::Rect strip(140 - 20 + 4, 60, 12, 120);
  const cv::Mat all(strip.size(), CV_8UC1, cv::Scalar(255));
  ASSERT_EQ(cv::countNonZero(s.occluded(strip)), strip.area());
  const int lr = countCode(r.code(strip), all, kCodeRejectLeftRight);
  const int accepted = cv::countNonZero(acceptedMask(r.code(strip)));
  // A hidden pixel has no true match; the few that find a consistent wrong one are random hits.
  EXPECT_GT(lr, strip.area() * 8 / 10);
  EXPECT_LT(accepted, strip.area() / 10);
  // With the check off (epsilon huge) most of them are accepted, wrongly.
  p.epsilon_px = 1000;
  m.setParams(p, noFilter());
  m.compute(s.left, s.right, r);
  EXPECT_GT(cv::countNonZero(acceptedMask(r.code(strip))), strip.area() / 2);
}

TEST_F(MatcherTest, GrowsWindowsWhereTextureIsPoor) {
  SyntheticSceneParams rich;
  rich.noise_stdev = 1.0;
  SyntheticSceneParams poor = rich;
  poor.texture_stdev = 2.5;  // faint, smooth texture under the same noise
  poor.texture_blur_px = 2.0;
  auto meanWindow = [](const MatchResult& r) {
    double sum = 0, n = 0;
    for (int k = 0; k < 16; ++k) {
      sum += k * static_cast<double>(r.stats.accepted_per_window[k]);
      n += static_cast<double>(r.stats.accepted_per_window[k]);
    }
    return n > 0 ? sum / n : -1.0;
  };
  MatcherParams p = range(0, 31);
  p.edge_disparity_jump_px = 0.0;  // the growth itself is under test, not what our edge step keeps
  p.window_min_px = 7;             // from the paper's first window (the figures below are for it)
  RobustMatcher m(p, noFilter());
  MatchResult r;
  m.compute(makeSyntheticScene(rich).left, makeSyntheticScene(rich).right, r);
  const double rich_mean = meanWindow(r);
  const SyntheticScene ps = makeSyntheticScene(poor);
  m.compute(ps.left, ps.right, r);
  const double poor_mean = meanWindow(r);
  // Rich texture: practically everything at w_min. Faint texture: a large share needs larger
  // windows (measured 0.40 window steps on average for this seed, 0.01 for the rich one).
  EXPECT_LT(rich_mean, 0.05);
  EXPECT_GT(poor_mean, 0.3);
  // And what the larger windows accept is right (measured: bad2 0.13%, bad1 2.3%: a faint
  // texture under noise costs sub-pixel accuracy, rarely a gross error).
  const DisparityScore poor_score = scoreDisparity(r.disparity, ps.disparity, ps.occluded == 0);
  EXPECT_LT(poor_score.bad2, 0.005);
  EXPECT_LT(poor_score.bad1, 0.05);
  EXPECT_GT(poor_score.density, 0.9);
}

TEST_F(MatcherTest, RespectsThePerPixelSearchRange) {
  SyntheticSceneParams sp;
  sp.base_disparity_px = 14;
  sp.slope_x = 0.03;
  const SyntheticScene s = makeSyntheticScene(sp);
  SearchRange rg;
  rg.lo.create(s.left.size(), CV_16SC1);
  rg.hi.create(s.left.size(), CV_16SC1);
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      const int g = static_cast<int>(std::lround(s.disparity.at<float>(y, x)));
      // Left half: +-4 around the truth. Right half: a range 8..12 px off the truth.
      const int c = x < s.left.cols / 2 ? g : g + 10;
      rg.lo.at<int16_t>(y, x) = static_cast<int16_t>(c - 4 + (x < s.left.cols / 2 ? 0 : 2));
      rg.hi.at<int16_t>(y, x) = static_cast<int16_t>(c + 4 - (x < s.left.cols / 2 ? 0 : 2));
    }
  }
  // A band of rows is not searched at all.
  rg.lo.rowRange(100, 110).setTo(5);
  rg.hi.rowRange(100, 110).setTo(4);
  RobustMatcher m(range(0, 47), PostFilterParams{});  // defaults, post-filters on
  MatchResult r;
  m.compute(s.left, s.right, r, &rg);
  int outside = 0, accepted_left = 0, accepted_right = 0;
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      const float d = r.disparity.at<float>(y, x);
      if (std::isnan(d)) continue;
      if (d < rg.lo.at<int16_t>(y, x) - 0.5f || d > rg.hi.at<int16_t>(y, x) + 0.5f) ++outside;
      (x < s.left.cols / 2 ? accepted_left : accepted_right)++;
    }
  }
  EXPECT_EQ(outside, 0);
  EXPECT_EQ(cv::countNonZero(r.code.rowRange(100, 110) != kCodeNotSearched), 0);
  EXPECT_EQ(cv::countNonZero(acceptedMask(r.code.rowRange(100, 110))), 0);
  EXPECT_GT(accepted_left, s.left.total() / 2 * 0.8);
  // A range that misses the truth holds only noise peaks; min_ncc and the post-filters must reject
  // nearly all of them (a narrowed range has no competitor for the peak gap, see min_ncc).
  EXPECT_LT(accepted_right, s.left.total() / 2 / 50);
  EXPECT_GT(r.stats.prior_pixels, 0);
  // Full search gives the same matches where the range holds the truth... within the parabola.
  const DisparityScore with_range =
      scoreDisparity(r.disparity.colRange(0, 160), s.disparity.colRange(0, 160));
  EXPECT_EQ(with_range.n_bad1, 0);
}

// RobustMatcher against the brute-force statement of the method (reference_matcher.hpp): one
// pixel at a time, every window sum afresh. Both normalise the NCC in float with the same
// expressions from exact integer window sums, so they must agree exactly: the same code for every
// pixel, and the same disparity and confidence bits. (A double-precision reference would differ
// at near-ties between two peaks; an exact reference lets the test demand zero differences.)
void expectSameAsReference(const SyntheticScene& s, const MatcherParams& p, const SearchRange* rg,
                           int threads) {
  MatchResult ref;
  referenceMatch(s.left, s.right, p, rg, ref);
  MatcherParams mp = p;
  mp.num_threads = threads;
  RobustMatcher m(mp, noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r, rg);
  int code_diff = 0, disp_diff = 0, conf_diff = 0, accepted = 0;
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      code_diff += r.code.at<uint8_t>(y, x) != ref.code.at<uint8_t>(y, x);
      accepted += ref.code.at<uint8_t>(y, x) >= kCodeAcceptedBase;
      // Bit patterns: NaN (no disparity) must be NaN in both, values equal to the last bit.
      disp_diff += std::memcmp(&r.disparity.at<float>(y, x), &ref.disparity.at<float>(y, x),
                               sizeof(float)) != 0;
      conf_diff += std::memcmp(&r.confidence.at<float>(y, x), &ref.confidence.at<float>(y, x),
                               sizeof(float)) != 0;
    }
  }
  const int n = static_cast<int>(s.left.total());
  EXPECT_EQ(code_diff, 0) << "codes differ from the reference";
  EXPECT_EQ(disp_diff, 0) << "disparities differ from the reference";
  EXPECT_EQ(conf_diff, 0) << "confidences differ from the reference";
  EXPECT_EQ(r.stats.prior_pixels, ref.stats.prior_pixels);
  // Most pixels are accepted, and the peak-gap and left-right criteria, where a near-tie would
  // show, reject some (the scenes' noise gives every patch structure at gamma_min 3).
  EXPECT_GT(accepted, n / 3);
  for (const int c : {kCodeRejectPeakGap, kCodeRejectLeftRight}) {
    EXPECT_GT(cv::countNonZero(ref.code == c), 0) << "no pixel with code " << c;
  }
  std::printf(
      "reference comparison: %d code, %d disparity, %d confidence differences, %d accepted, "
      "%d peak-gap, %d left-right, %d no-peak, %d structure rejections\n",
      code_diff, disp_diff, conf_diff, accepted, cv::countNonZero(ref.code == kCodeRejectPeakGap),
      cv::countNonZero(ref.code == kCodeRejectLeftRight), cv::countNonZero(ref.code == kCodeNoPeak),
      cv::countNonZero(ref.code == kCodeRejectStructure));
}

TEST_F(MatcherTest, MatchesTheReferenceImplementationFullSearch) {
  SyntheticSceneParams sp;
  sp.width = 120;
  sp.height = 90;
  sp.base_disparity_px = 9;
  sp.slope_x = 0.03;
  sp.noise_stdev = 4.0;
  sp.texture_stdev = 12.0;  // faint enough that larger windows are needed in places
  sp.occluder = cv::Rect(50, 20, 30, 45);
  sp.occluder_disparity_px = 20;
  sp.textureless = cv::Rect(90, 55, 14, 14);
  const SyntheticScene s = makeSyntheticScene(sp);
  MatcherParams p = range(0, 24);
  p.window_min_px = 5;
  p.window_step_px = 4;
  p.window_max_px = 17;
  p.gamma_min = 3.0;
  p.delta_min = 0.15;
  p.min_ncc = 0.3;
  p.epsilon_px = 1.0;
  p.edge_disparity_jump_px = 0.0;
  expectSameAsReference(s, p, nullptr, 1);
  expectSameAsReference(s, p, nullptr, 2);
}

TEST_F(MatcherTest, MatchesTheReferenceImplementationWhereStructureRejects) {
  // Without noise a textureless square wider than the largest window has no structure at all:
  // the structure criterion gets the last word there.
  SyntheticSceneParams sp;
  sp.width = 100;
  sp.height = 80;
  sp.base_disparity_px = 8;
  sp.noise_stdev = 0.0;
  sp.texture_stdev = 12.0;
  sp.textureless = cv::Rect(40, 20, 34, 34);
  const SyntheticScene s = makeSyntheticScene(sp);
  MatcherParams p = range(0, 20);
  p.window_min_px = 5;
  p.window_step_px = 4;
  p.window_max_px = 17;
  p.gamma_min = 3.0;
  p.delta_min = 0.15;
  p.min_ncc = 0.3;
  p.epsilon_px = 1.0;
  p.edge_disparity_jump_px = 0.0;
  expectSameAsReference(s, p, nullptr, 2);
  MatchResult ref;
  referenceMatch(s.left, s.right, p, nullptr, ref);
  EXPECT_GT(cv::countNonZero(ref.code == kCodeRejectStructure), 0);
}

TEST_F(MatcherTest, MatchesTheReferenceImplementationWithPerPixelRanges) {
  SyntheticSceneParams sp;
  sp.width = 120;
  sp.height = 90;
  sp.base_disparity_px = 9;
  sp.slope_x = 0.03;
  sp.noise_stdev = 4.0;
  sp.texture_stdev = 12.0;
  sp.occluder = cv::Rect(50, 20, 30, 45);
  sp.occluder_disparity_px = 20;
  const SyntheticScene s = makeSyntheticScene(sp);
  SearchRange rg;
  rg.lo.create(s.left.size(), CV_16SC1);
  rg.hi.create(s.left.size(), CV_16SC1);
  cv::RNG rng(3);
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      // Around the truth with a random offset (some miss it), a random radius, some empty, one
      // in five the full range (so rows mix narrowed and full-range pixels).
      const int g = static_cast<int>(std::lround(s.disparity.at<float>(y, x))) + rng.uniform(-3, 4);
      const int rad = rng.uniform(1, 7);
      const bool full = rng.uniform(0, 5) == 0;
      rg.lo.at<int16_t>(y, x) = static_cast<int16_t>(full ? 0 : g - rad);
      rg.hi.at<int16_t>(y, x) = static_cast<int16_t>(full                      ? 24
                                                     : rng.uniform(0, 20) == 0 ? g - rad - 1
                                                                               : g + rad);
    }
  }
  MatcherParams p = range(0, 24);
  p.window_min_px = 5;
  p.window_step_px = 4;
  p.window_max_px = 17;
  p.gamma_min = 3.0;
  p.delta_min = 0.15;
  p.min_ncc = 0.3;
  p.epsilon_px = 1.0;
  p.edge_disparity_jump_px = 0.0;
  // Windows 5, 9, 13, 17: narrowed and full-range pixels both grow their window when they fail.
  expectSameAsReference(s, p, &rg, 1);
  expectSameAsReference(s, p, &rg, 2);
  RobustMatcher m(p, noFilter());
  MatchResult r;
  m.compute(s.left, s.right, r, &rg);
  // Pixels accepted with a window above 9 px, narrowed and full-range ones apart: the comparison
  // above covers the growth of both kinds only when the scene needs it for both.
  int above_narrowed = 0, above_full = 0;
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      if (r.code.at<uint8_t>(y, x) <= kCodeAcceptedBase + 1) continue;
      const bool full = rg.lo.at<int16_t>(y, x) <= 0 && rg.hi.at<int16_t>(y, x) >= 24;
      (full ? above_full : above_narrowed) += 1;
    }
  }
  EXPECT_GT(above_full, 0) << "the scene should need windows above 9 px somewhere";
  EXPECT_GT(above_narrowed, 0) << "the scene should need windows above 9 px somewhere";
}

// Ranges like the temporal priors': +-4 px around a smooth estimate (the truth plus an offset
// that drifts slowly across the image, so chunks of 8 columns hold slightly different ranges),
// a few pixels with the full range, a few with none. The rows are dense (narrowed engine) at the
// first window; the image width is no multiple of 8 and the range reaches below zero, so the
// chunks at both ends of a row and negative disparities are covered. Every first-window width
// with its own code path (the unrolled 7 and 9, the general loop) against the reference.
TEST_F(MatcherTest, MatchesTheReferenceImplementationWithPriorLikeRanges) {
  SyntheticSceneParams sp;
  sp.width = 203;
  sp.height = 72;
  sp.base_disparity_px = 9;
  sp.slope_x = 0.04;
  sp.noise_stdev = 4.0;
  sp.texture_stdev = 12.0;
  sp.occluder = cv::Rect(80, 15, 40, 40);
  sp.occluder_disparity_px = 20;
  const SyntheticScene s = makeSyntheticScene(sp);
  const int dmin = -4, dmax = 27;
  SearchRange rg;
  rg.lo.create(s.left.size(), CV_16SC1);
  rg.hi.create(s.left.size(), CV_16SC1);
  cv::RNG rng(7);
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      const double drift = 2.0 * std::sin(x / 23.0) + 1.5 * std::cos(y / 17.0);
      const int g = static_cast<int>(std::lround(s.disparity.at<float>(y, x) + drift));
      const int u = rng.uniform(0, 40);
      const bool full = u == 0, none = u == 1;
      rg.lo.at<int16_t>(y, x) = static_cast<int16_t>(full ? dmin : none ? g : g - 4);
      rg.hi.at<int16_t>(y, x) = static_cast<int16_t>(full ? dmax : none ? g - 1 : g + 4);
    }
  }
  MatcherParams p = range(dmin, dmax);
  p.window_step_px = 6;
  p.window_max_px = 21;
  p.gamma_min = 3.0;
  p.delta_min = 0.15;
  p.min_ncc = 0.3;
  p.epsilon_px = 1.0;
  p.edge_disparity_jump_px = 0.0;
  for (const int w : {9, 7, 5}) {
    p.window_min_px = w;
    expectSameAsReference(s, p, &rg, 1);
    expectSameAsReference(s, p, &rg, 2);
  }
}

TEST_F(MatcherTest, SameOutputForOneAndTwoThreads) {
  SyntheticSceneParams sp;
  sp.width = 256;
  sp.height = 200;
  sp.base_disparity_px = 10;
  sp.slope_x = 0.02;
  sp.noise_stdev = 3.0;
  sp.occluder = cv::Rect(90, 40, 60, 100);
  sp.occluder_disparity_px = 24;
  sp.textureless = cv::Rect(180, 120, 40, 40);
  const SyntheticScene s = makeSyntheticScene(sp);
  MatchResult r1, r2;
  for (int threads : {1, 2}) {
    MatcherParams p = range(0, 31);
    p.num_threads = threads;
    RobustMatcher m(p, PostFilterParams{});
    m.compute(s.left, s.right, threads == 1 ? r1 : r2);
  }
  auto sameBits = [](const cv::Mat& a, const cv::Mat& b) {
    if (a.size() != b.size() || a.type() != b.type()) return false;
    for (int y = 0; y < a.rows; ++y) {
      if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
    }
    return true;
  };
  EXPECT_TRUE(sameBits(r1.disparity, r2.disparity));
  EXPECT_TRUE(sameBits(r1.code, r2.code));
  EXPECT_TRUE(sameBits(r1.confidence, r2.confidence));
  EXPECT_GT(r1.stats.valid_pixels, r1.stats.total_pixels / 2);
}

TEST_F(MatcherTest, ValidateNamesTheBadField) {
  struct Case {
    const char* field;
    void (*set)(MatcherParams&);
  };
  const Case cases[] = {
      {"max_disparity", [](MatcherParams& p) { p.max_disparity = p.min_disparity - 1; }},
      {"window_min_px", [](MatcherParams& p) { p.window_min_px = 6; }},
      {"window_min_px", [](MatcherParams& p) { p.window_min_px = 1; }},
      {"window_step_px", [](MatcherParams& p) { p.window_step_px = 3; }},
      {"window_max_px", [](MatcherParams& p) { p.window_max_px = 5; }},
      {"window_max_px", [](MatcherParams& p) { p.window_max_px = 40; }},
      {"gamma_min", [](MatcherParams& p) { p.gamma_min = -1; }},
      {"delta_min", [](MatcherParams& p) { p.delta_min = 2.5; }},
      {"epsilon_px", [](MatcherParams& p) { p.epsilon_px = 0; }},
      {"min_ncc", [](MatcherParams& p) { p.min_ncc = 1.5; }},
      {"min_ncc_narrowed", [](MatcherParams& p) { p.min_ncc_narrowed = -2; }},
      {"num_threads", [](MatcherParams& p) { p.num_threads = -2; }},
      {"edge_disparity_jump_px", [](MatcherParams& p) { p.edge_disparity_jump_px = -1; }},
      {"edge_disparity_jump_above_px",
       [](MatcherParams& p) { p.edge_disparity_jump_above_px = -1; }},
      {"edge_margin_px", [](MatcherParams& p) { p.edge_margin_px = 17; }},
  };
  EXPECT_EQ(MatcherParams{}.validate(), "");
  for (const Case& c : cases) {
    MatcherParams p;
    c.set(p);
    const std::string msg = p.validate();
    EXPECT_NE(msg.find(c.field), std::string::npos) << c.field << ": '" << msg << "'";
    try {
      RobustMatcher m(p, PostFilterParams{});
      ADD_FAILURE() << "constructor accepted bad " << c.field;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(c.field), std::string::npos) << e.what();
    }
  }
  RobustMatcher m(MatcherParams{}, PostFilterParams{});
  MatcherParams bad;
  bad.delta_min = -1;
  EXPECT_THROW(m.setParams(bad, PostFilterParams{}), std::invalid_argument);
  EXPECT_EQ(m.matcherParams().delta_min, MatcherParams{}.delta_min);  // old ones kept
}

TEST_F(MatcherTest, RejectsBadInputsNamingThem) {
  RobustMatcher m(MatcherParams{}, PostFilterParams{});
  MatchResult r;
  const cv::Mat ok(40, 50, CV_8UC1, cv::Scalar(0));
  auto message = [&](const cv::Mat& l, const cv::Mat& rr, const SearchRange* rg) -> std::string {
    try {
      m.compute(l, rr, r, rg);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_NE(message(cv::Mat(), ok, nullptr).find("left"), std::string::npos);
  EXPECT_NE(message(ok, cv::Mat(), nullptr).find("right"), std::string::npos);
  EXPECT_NE(message(cv::Mat(40, 50, CV_8UC3), ok, nullptr).find("left"), std::string::npos);
  EXPECT_NE(message(ok, cv::Mat(40, 50, CV_16UC1), nullptr).find("right"), std::string::npos);
  EXPECT_NE(message(ok, cv::Mat(41, 50, CV_8UC1), nullptr).find("size"), std::string::npos);
  SearchRange rg;
  rg.lo = cv::Mat(40, 50, CV_32SC1);
  rg.hi = cv::Mat(40, 50, CV_16SC1);
  EXPECT_NE(message(ok, ok, &rg).find("range"), std::string::npos);
  rg.lo = cv::Mat(40, 49, CV_16SC1);
  EXPECT_NE(message(ok, ok, &rg).find("range"), std::string::npos);
  // A tiny image is valid input: nothing is matched, nothing crashes.
  const cv::Mat tiny(1, 1, CV_8UC1, cv::Scalar(7));
  EXPECT_EQ(message(tiny, tiny, nullptr), "");
  EXPECT_EQ(r.stats.valid_pixels, 0);
  EXPECT_EQ(r.code.at<uint8_t>(0, 0), kCodeNotSearched);
}

// ---------------------------------------------------------------------------------------------
// Second chance of the edge test (MatcherParams::edge_verify_*), edge engineer's section.
// Scene: a textured foreground block (disparity 22) over a textured background (6) whose strip
// just right of the block is textureless. There the background has nothing of its own to match,
// so windows reaching the block's texture carry its disparity over the strip: fattened pixels
// with exact ground truth. Foreground pixels next to the block's edge are the true pixels the
// map-only test also flags (their windows hold the background's lower disparity).
// ---------------------------------------------------------------------------------------------
struct EdgeScene {
  SyntheticSceneParams sp;
  SyntheticScene s;
  EdgeScene() {
    sp.base_disparity_px = 6;
    sp.noise_stdev = 1.0;
    sp.occluder = cv::Rect(120, 60, 80, 120);
    sp.occluder_disparity_px = 22;
    sp.textureless = cv::Rect(200, 40, 6, 160);
    s = makeSyntheticScene(sp);
  }
};

struct EdgeCounts {
  int correct = 0;         // accepted, visible, |d - gt| <= 1
  int wrong = 0;           // accepted, visible, |d - gt| > 1
  int wrong_in_strip = 0;  // of those, in the textureless strip (fattened)
  int fg_band_kept = 0;    // accepted foreground pixels 3..6 px inside the block's lower edge
  MatchResult r;
};

EdgeCounts runEdgeScene(const EdgeScene& e, int verify_radius, double jump_px, int threads = 1) {
  MatcherParams p = range(0, 31);
  p.edge_verify_radius_px = verify_radius;
  p.edge_disparity_jump_px = jump_px;
  p.num_threads = threads;
  RobustMatcher m(p, noFilter());
  EdgeCounts c;
  m.compute(e.s.left, e.s.right, c.r);
  for (int y = 0; y < c.r.disparity.rows; ++y) {
    for (int x = 0; x < c.r.disparity.cols; ++x) {
      const float d = c.r.disparity.at<float>(y, x);
      if (e.s.occluded.at<uint8_t>(y, x) || std::isnan(d)) continue;
      if (std::fabs(d - e.s.disparity.at<float>(y, x)) <= 1.f) {
        ++c.correct;
        if (x >= 130 && x < 190 && y >= 173 && y <= 176) ++c.fg_band_kept;
      } else {
        ++c.wrong;
        if (e.sp.textureless.contains(cv::Point(x, y))) ++c.wrong_in_strip;
      }
    }
  }
  return c;
}

TEST_F(MatcherTest, EdgeVerifyKeepsTrueForegroundNextToAnEdge) {
  const EdgeScene e;
  const EdgeCounts flagged_only = runEdgeScene(e, 0, 2.0);
  const EdgeCounts verified = runEdgeScene(e, 4, 2.0);
  // The map-only test rejects the foreground band 3..6 px inside the block's lower edge almost
  // entirely (measured 0 of 240 kept); the second chance keeps a good part of it (measured 72):
  // windows wholly inside the block confirm its disparity against the background's. Bounds leave
  // room for small changes of the texture generator, not for losing the effect.
  EXPECT_LT(flagged_only.fg_band_kept, 30);
  EXPECT_GT(verified.fg_band_kept, 50);
  // Overall it gives back many correct pixels (measured +1979) ...
  EXPECT_GT(verified.correct, flagged_only.correct + 500);
  // ... and no wrong one.
  EXPECT_LE(verified.wrong, flagged_only.wrong);
}

TEST_F(MatcherTest, EdgeVerifyStillRejectsFattenedPixels) {
  const EdgeScene e;
  const EdgeCounts off = runEdgeScene(e, 0, 0.0);  // no edge test at all
  const EdgeCounts verified = runEdgeScene(e, 4, 2.0);
  // Without the edge test the block's disparity is carried over the textureless strip (measured
  // 198 wrong pixels there): the scene does fatten, so the next line can fail.
  EXPECT_GT(off.wrong_in_strip, 100);
  // With the test and its second chance none of them survives: every window lying wholly on the
  // background beside the strip prefers the background's disparity.
  EXPECT_EQ(verified.wrong_in_strip, 0);
  EXPECT_LT(verified.wrong, 10);  // measured 2, away from the strip
}

TEST_F(MatcherTest, EdgeVerifySameOutputForOneAndTwoThreads) {
  const EdgeScene e;
  const EdgeCounts a = runEdgeScene(e, 4, 2.0, 1);
  const EdgeCounts b = runEdgeScene(e, 4, 2.0, 2);
  // Thousands of flagged pixels: several chunks of the parallel verification.
  ASSERT_GT(cv::countNonZero(a.r.code == static_cast<int>(kCodeRejectEdge)), 1000);
  EXPECT_EQ(cv::countNonZero(a.r.code != b.r.code), 0);
  cv::Mat da = a.r.disparity.clone(), db = b.r.disparity.clone();
  da.setTo(-1, da != da);  // NaN -> -1 so that equal maps compare equal
  db.setTo(-1, db != db);
  EXPECT_EQ(cv::countNonZero(da != db), 0);
}

TEST_F(MatcherTest, EdgeVerifyValidateNamesTheBadField) {
  struct Case {
    const char* field;
    void (*set)(MatcherParams&);
  };
  const std::vector<Case> cases = {
      {"edge_verify_radius_px", [](MatcherParams& p) { p.edge_verify_radius_px = -1; }},
      {"edge_verify_radius_px", [](MatcherParams& p) { p.edge_verify_radius_px = 7; }},
      {"edge_verify_min_ncc", [](MatcherParams& p) { p.edge_verify_min_ncc = 1.5; }},
      {"edge_verify_min_ncc",
       [](MatcherParams& p) { p.edge_verify_min_ncc = std::numeric_limits<double>::quiet_NaN(); }},
  };
  for (const Case& c : cases) {
    MatcherParams p;
    c.set(p);
    EXPECT_NE(p.validate().find(c.field), std::string::npos) << c.field << ": " << p.validate();
    EXPECT_THROW(RobustMatcher(p, PostFilterParams{}), std::invalid_argument) << c.field;
  }
  MatcherParams ok;
  ok.edge_verify_radius_px = 6;
  ok.edge_verify_min_ncc = -1.0;
  EXPECT_EQ(ok.validate(), "");
}

// ---------------------------------------------------------------------------------------------
// Support of the edge test's disparities (MatcherParams::edge_support_*), on hand-made maps: every
// pixel accepted with the first window (7 px; margin 5: the test looks 3 + 5 = 8 px around), the
// second chance off (the images are then not read).
// ---------------------------------------------------------------------------------------------
struct EdgeMap {
  MatchResult r;
  cv::Mat window_idx;
  explicit EdgeMap(const cv::Mat& disparity) {
    r.disparity = disparity.clone();
    r.confidence = cv::Mat(disparity.size(), CV_32F, cv::Scalar(1));
    r.code = cv::Mat(disparity.size(), CV_8U, cv::Scalar(kCodeAcceptedBase));
    window_idx = cv::Mat(disparity.size(), CV_8U, cv::Scalar(0));
  }
  // Runs the filter; returns the number of pixels it rejected.
  int filter(double support_share, bool slope_tolerant = true) {
    MatcherParams p;
    p.edge_slope_tolerant = slope_tolerant;
    p.window_min_px = 7;
    p.edge_verify_radius_px = 0;
    p.edge_disparity_jump_px = 2.0;
    p.edge_disparity_jump_above_px = 4.0;
    p.edge_margin_px = 5;
    p.edge_support_share = support_share;
    p.edge_support_radius_px = 2;
    const cv::Mat no_image;
    cv::Mat lo_src, hi_src, lo, hi, reject;
    rejectEdgeStraddlers(p, no_image, no_image, 1, window_idx, r, lo_src, hi_src, lo, hi, reject);
    return cv::countNonZero(r.code == static_cast<int>(kCodeRejectEdge));
  }
};

TEST_F(MatcherTest, EdgeSupportAnIsolatedWrongDisparityRejectsOnlyItself) {
  // A flat surface at disparity 10 with one wrong pixel at 3 (a speck of a highlight, say).
  cv::Mat d(40, 60, CV_32F, cv::Scalar(10));
  d.at<float>(20, 30) = 3.f;
  EdgeMap without(d), with(d);
  // Without support every pixel within 8 px of the speck sees a disparity 7 px below its own:
  // the 17 x 17 square is rejected, the speck itself too (the surface lies 7 > 4 px above it).
  EXPECT_EQ(without.filter(0.0), 17 * 17);
  // With it the speck (no neighbour of its 5 x 5 square within 2 px) is no depth edge: only the
  // speck is rejected, judged against the surface around it.
  EXPECT_EQ(with.filter(0.4), 1);
  EXPECT_EQ(with.r.code.at<uint8_t>(20, 30), kCodeRejectEdge);
  EXPECT_TRUE(std::isnan(with.r.disparity.at<float>(20, 30)));
  EXPECT_FLOAT_EQ(with.r.disparity.at<float>(20, 31), 10.f);
}

TEST_F(MatcherTest, EdgeSupportKeepsTheTestAtAnInstrumentEdge) {
  // An instrument (disparity 20, columns 30..59) over tissue (10, columns 0..29): a true depth
  // edge, both sides supported surfaces.
  cv::Mat d(40, 60, CV_32F, cv::Scalar(10));
  d(cv::Rect(30, 0, 30, 40)).setTo(20);
  EdgeMap without(d), with(d);
  // The 8 columns on each side of the edge are rejected (instrument: 10 px below within reach;
  // tissue: 10 px above), with or without support: 16 columns of 40 rows.
  EXPECT_EQ(without.filter(0.0), 16 * 40);
  EXPECT_EQ(with.filter(0.4), 16 * 40);
  EXPECT_EQ(cv::countNonZero(with.r.code(cv::Rect(22, 0, 16, 40)) ==
                             static_cast<int>(kCodeRejectEdge)),
            16 * 40);
}

// The slope-tolerant form of the map test (MatcherParams::edge_slope_tolerant), on the same
// hand-made maps: a smooth surface seen at a steep angle, with and without a step on it.
int rejectedIn(const EdgeMap& m, int x0, int x1, int y0, int y1) {
  return cv::countNonZero(m.r.code(cv::Range(y0, y1 + 1), cv::Range(x0, x1 + 1)) ==
                          static_cast<int>(kCodeRejectEdge));
}

TEST_F(MatcherTest, EdgeSlopeASteepSmoothPlaneIsNoDepthEdge) {
  // d = 10 + 0.4 x: within the test's reach (8 px) a neighbour lies up to 3.2 px below, so the
  // plain test (more than 2 px below) flags every pixel with a neighbour 6+ columns to its left.
  cv::Mat d(40, 60, CV_32F);
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) d.at<float>(y, x) = 10.f + 0.4f * x;
  }
  EdgeMap plain(d), slope(d);
  plain.filter(0.4, false);
  slope.filter(0.4, true);
  // Pixels 10+ px from the border: there every neighbour's mirror image lies inside the map
  // and has a surface's support (the corners' do not, and where a mirror image is missing the
  // one-sided plain test applies): columns 10..49 of rows 10..29.
  EXPECT_EQ(rejectedIn(plain, 10, 49, 10, 29), 40 * 20);
  // Taking the slope out, each pair's second difference is zero up to float rounding (~1e-5):
  // nothing is an edge.
  EXPECT_EQ(rejectedIn(slope, 10, 49, 10, 29), 0);
}

TEST_F(MatcherTest, EdgeSlopeStillFindsAStepOnASteepPlane) {
  // The same plane with a raised block (an instrument, +10 px) from column 30 on.
  cv::Mat d(40, 60, CV_32F);
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) d.at<float>(y, x) = 10.f + 0.4f * x + (x >= 30 ? 10.f : 0.f);
  }
  EdgeMap slope(d);
  slope.filter(0.4, true);
  // Both sides of the step within reach (columns 22..37) are flagged: a pair across the step
  // has a second difference of +-10 px, beyond both thresholds (4 above, 2 below) ...
  EXPECT_EQ(rejectedIn(slope, 22, 37, 10, 29), 16 * 20);
  // ... and the plane beyond reach of it is left alone, on both sides (rows and columns 10+ px
  // from the border, as above).
  EXPECT_EQ(rejectedIn(slope, 10, 21, 10, 29), 0);
  EXPECT_EQ(rejectedIn(slope, 38, 49, 10, 29), 0);
}

TEST_F(MatcherTest, EdgeTestJudgesEveryPixelOfAMapWithoutStats) {
  // The instrument edge again, every pixel accepted with the first window, on a result whose
  // stats are empty (as a map merged from two passes is): the filter counts the pixels per
  // window size itself, and must judge all of them.
  cv::Mat d(40, 60, CV_32F, cv::Scalar(10));
  d(cv::Rect(30, 0, 30, 40)).setTo(20);
  EdgeMap merged(d);
  ASSERT_EQ(merged.r.stats.total_pixels, 0);
  // The pixels within 8 px of the edge (window 7: half 3, plus the 5 px margin): 16 columns.
  EXPECT_EQ(merged.filter(0.4, true), 16 * 40);
}

TEST_F(MatcherTest, EdgeSupportValidateNamesTheBadField) {
  MatcherParams p;
  p.edge_support_share = 1.5;
  EXPECT_NE(p.validate().find("edge_support_share"), std::string::npos);
  p = MatcherParams{};
  p.edge_support_share = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(p.validate().find("edge_support_share"), std::string::npos);
  p = MatcherParams{};
  p.edge_support_radius_px = 0;
  EXPECT_NE(p.validate().find("edge_support_radius_px"), std::string::npos);
  p.edge_support_radius_px = 9;
  EXPECT_NE(p.validate().find("edge_support_radius_px"), std::string::npos);
  p.edge_support_radius_px = 8;
  p.edge_support_share = 1.0;
  EXPECT_EQ(p.validate(), "");
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
