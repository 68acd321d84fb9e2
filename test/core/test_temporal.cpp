// Tests of the temporal stage (temporal.hpp): priors, resets, fusion, coverage; on hand-made
// sequences with known answers and on the synthetic surgical sequence.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "endo_stereo/core/matcher.hpp"
#include "endo_stereo/core/temporal.hpp"
#include "endo_stereo/synthetic/surgical_scene.hpp"

namespace endo_stereo {
namespace {

const float kNaN = std::numeric_limits<float>::quiet_NaN();

cv::Mat constantDisparity(cv::Size size, float d) { return cv::Mat(size, CV_32FC1, cv::Scalar(d)); }

// Priors alone: no edge zones, scene-change test or deferral, so every expected range is easy to
// state.
TemporalParams plainParams() {
  TemporalParams p;
  p.prior_edge_zone_px = 0;
  p.min_prior_hit_share = 0.0;
  p.full_range_period_frames = 1;
  return p;
}

TEST(TemporalParams, ValidateNamesTheField) {
  EXPECT_EQ(TemporalParams().validate(), "");
  TemporalParams p;
  p.prior_radius_px = 0;
  EXPECT_NE(p.validate().find("prior_radius_px"), std::string::npos);
  p = TemporalParams();
  p.max_gap_s = -1;
  EXPECT_NE(p.validate().find("max_gap_s"), std::string::npos);
  p = TemporalParams();
  p.max_prior_age_frames = 0;
  EXPECT_NE(p.validate().find("max_prior_age_frames"), std::string::npos);
  p = TemporalParams();
  p.full_range_period_frames = 0;
  EXPECT_NE(p.validate().find("full_range_period_frames"), std::string::npos);
  EXPECT_THROW(TemporalPrior{p}, std::invalid_argument);
  EXPECT_THROW(TemporalTracker{p}, std::invalid_argument);
}

TEST(TemporalResetDetector, ReportsEveryDiscontinuity) {
  TemporalResetDetector det(0.5);
  TemporalFrameInfo info{cv::Size(64, 48), 10.0, 1, 0, 63};
  EXPECT_EQ(det.check(info), "");  // first frame
  info.stamp_s = 10.04;
  EXPECT_EQ(det.check(info), "");
  info.stamp_s = 10.04;  // a repeated stamp is not a jump
  EXPECT_EQ(det.check(info), "");
  info.stamp_s = 6.0;  // a looping bag
  EXPECT_NE(det.check(info).find("time went back"), std::string::npos);
  info.stamp_s = 7.0;  // 1 s gap > 0.5
  EXPECT_NE(det.check(info).find("gap"), std::string::npos);
  info.stamp_s = 7.04;
  info.size = cv::Size(32, 24);
  EXPECT_NE(det.check(info).find("size"), std::string::npos);
  info.stamp_s = 7.08;
  info.calibration_generation = 2;
  EXPECT_NE(det.check(info).find("calibration"), std::string::npos);
  info.stamp_s = 7.12;
  info.max_disparity = 95;
  EXPECT_NE(det.check(info).find("disparity range"), std::string::npos);
  info.stamp_s = std::numeric_limits<double>::quiet_NaN();  // unknown time: no time checks
  EXPECT_EQ(det.check(info), "");
}

TEST(TemporalPrior, FirstFrameSearchesTheFullRange) {
  TemporalPrior prior;
  SearchRange range;
  EXPECT_FALSE(prior.buildRange(cv::Size(40, 30), 0, 63, range));
  EXPECT_TRUE(range.empty());
  EXPECT_EQ(prior.stats().full_range_pixels, 40 * 30);
  EXPECT_EQ(prior.stats().narrowed_pixels, 0);
}

TEST(TemporalPrior, NarrowsAroundPreviousDisparity) {
  TemporalParams p = plainParams();
  p.prior_radius_px = 4;
  p.prior_neighbourhood_px = 2;
  TemporalPrior prior(p);
  const cv::Size size(40, 30);
  SearchRange range;
  prior.buildRange(size, 0, 63, range);
  cv::Mat d = constantDisparity(size, 30.3f);
  d(cv::Rect(10, 10, 10, 10)).setTo(kNaN);  // a hole
  d.at<float>(25, 35) = 50.0f;              // a different surface
  prior.update(d);
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  ASSERT_EQ(range.lo.type(), CV_16SC1);
  // floor(30.3 - 4) = 26, ceil(30.3 + 4) = 35.
  EXPECT_EQ(range.lo.at<int16_t>(0, 0), 26);
  EXPECT_EQ(range.hi.at<int16_t>(0, 0), 35);
  // Inside the hole beyond the neighbourhood: the full range.
  EXPECT_EQ(range.lo.at<int16_t>(15, 15), 0);
  EXPECT_EQ(range.hi.at<int16_t>(15, 15), 63);
  // In the hole but within 2 px of valid pixels: their priors.
  EXPECT_EQ(range.lo.at<int16_t>(11, 11), 26);
  EXPECT_EQ(range.hi.at<int16_t>(11, 11), 35);
  // Next to the odd pixel the range spans both surfaces: [26, 54].
  EXPECT_EQ(range.lo.at<int16_t>(24, 34), 26);
  EXPECT_EQ(range.hi.at<int16_t>(24, 34), 54);
  // The hole's interior: 6 x 6 pixels further than 2 px from any valid pixel.
  EXPECT_EQ(prior.stats().full_range_pixels, 36);
  EXPECT_EQ(prior.stats().narrowed_pixels, 40 * 30 - 36);
  EXPECT_GT(prior.stats().mean_narrowed_width_px, 9.9);
  EXPECT_LT(prior.stats().mean_narrowed_width_px, 10.5);
  // Clamped to the full range at its ends.
  prior.update(constantDisparity(size, 62.0f));
  prior.buildRange(size, 0, 63, range);
  EXPECT_EQ(range.hi.at<int16_t>(5, 5), 63);
  EXPECT_EQ(range.lo.at<int16_t>(5, 5), 58);
}

// A failed narrowed search does not refresh the prior, so its age alone bounds how long it is
// tried: after max_prior_age_frames failed narrowed searches in a row the pixel searches the full
// range again.
TEST(TemporalPrior, FallsBackToFullRangeWhenPriorKeepsFailing) {
  TemporalParams p = plainParams();
  p.max_prior_age_frames = 5;
  p.prior_neighbourhood_px = 0;
  TemporalPrior prior(p);
  const cv::Size size(20, 20);
  SearchRange range;
  prior.buildRange(size, 0, 63, range);
  prior.update(constantDisparity(size, 20.0f));
  // The scene jumps: the block's true disparity leaves the narrowed range, so its searches fail.
  const cv::Rect block(5, 5, 6, 6);
  cv::Mat failed = constantDisparity(size, 20.0f);
  failed(block).setTo(kNaN);
  for (int k = 0; k < p.max_prior_age_frames; ++k) {
    ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
    EXPECT_EQ(range.lo.at<int16_t>(7, 7), 16) << "failure " << k << " not yet enough";
    EXPECT_EQ(range.hi.at<int16_t>(7, 7), 24) << "failure " << k;
    EXPECT_EQ(prior.stats().full_range_pixels, 0) << "failure " << k;
    prior.update(failed);
    EXPECT_EQ(prior.stats().prior_misses, block.area());
    EXPECT_EQ(prior.stats().prior_hits, 400 - block.area());
    EXPECT_EQ(prior.priorAge().at<uint16_t>(7, 7), k + 1) << "a failure does not refresh it";
  }
  // max_prior_age_frames failures in a row: the block searches the full range again.
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  EXPECT_EQ(range.lo.at<int16_t>(7, 7), 0);
  EXPECT_EQ(range.hi.at<int16_t>(7, 7), 63);
  EXPECT_EQ(prior.stats().full_range_pixels, block.area());
  EXPECT_EQ(prior.stats().narrowed_pixels, 400 - block.area());
  EXPECT_EQ(range.lo.at<int16_t>(0, 0), 16);  // the rest keeps its prior
  // The full search finds the new disparity: narrowed around it from then on.
  cv::Mat found = constantDisparity(size, 20.0f);
  found(block).setTo(45.0f);
  prior.update(found);
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  EXPECT_EQ(range.lo.at<int16_t>(7, 7), 41);
  EXPECT_EQ(range.hi.at<int16_t>(7, 7), 49);
  EXPECT_EQ(prior.stats().full_range_pixels, 0);
}

TEST(TemporalPrior, ForgetsPriorsOlderThanMaxAge) {
  TemporalParams p = plainParams();
  p.max_prior_age_frames = 2;
  TemporalPrior prior(p);
  const cv::Size size(16, 16);
  SearchRange range;
  prior.buildRange(size, 0, 63, range);
  prior.update(constantDisparity(size, 30.0f));        // age 0
  EXPECT_TRUE(prior.buildRange(size, 0, 63, range));   // measured 1 frame ago
  prior.update(constantDisparity(size, kNaN));         // age 1
  EXPECT_TRUE(prior.buildRange(size, 0, 63, range));   // 2 frames ago: still a prior
  prior.update(constantDisparity(size, kNaN));         // age 2
  EXPECT_FALSE(prior.buildRange(size, 0, 63, range));  // 3 frames ago: gone
  EXPECT_EQ(prior.stats().full_range_pixels, 256);
}

TEST(TemporalPrior, ANarrowedSearchThatFailsKeepsItsPrior) {
  TemporalParams p = plainParams();
  p.prior_neighbourhood_px = 0;
  p.max_prior_age_frames = 2;
  TemporalPrior prior(p);
  const cv::Size size(16, 32);
  SearchRange range;
  prior.buildRange(size, 0, 63, range);
  prior.update(constantDisparity(size, 30.0f));
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  // A narrowed search that fails keeps its prior, one frame older (used while younger than
  // max_prior_age_frames).
  cv::Mat d = constantDisparity(size, 30.0f);
  d.at<float>(3, 5) = kNaN;
  prior.update(d);
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  EXPECT_EQ(prior.lastDisparity().at<float>(3, 5), 30.0f);
  EXPECT_EQ(prior.priorAge().at<uint16_t>(3, 5), 1);
  EXPECT_EQ(range.lo.at<int16_t>(3, 5), 26);
  // The second failure in a row makes it 2 frames old, too old: the full range...
  prior.update(d);
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  EXPECT_EQ(range.lo.at<int16_t>(3, 5), 0);
  EXPECT_EQ(range.hi.at<int16_t>(3, 5), 63);
  EXPECT_EQ(range.lo.at<int16_t>(3, 6), 26);
  // ...and a full-range search that finds nothing drops the prior: a wrong prior cannot outlive it.
  prior.update(d);
  EXPECT_TRUE(std::isnan(prior.lastDisparity().at<float>(3, 5)));
}

TEST(TemporalPrior, DeferredFullRangeSearchesTakeTurns) {
  TemporalParams p = plainParams();
  p.prior_neighbourhood_px = 0;
  p.max_prior_age_frames = 1;
  p.full_range_period_frames = 4;
  TemporalPrior prior(p);
  // 18 columns: the vector loop takes 16 of them, the scalar tail the last two.
  const cv::Size size(18, 4 * kFullRangeStripeRows);
  SearchRange range;
  prior.buildRange(size, 0, 63, range);
  // Columns 0-7 matched at 30, columns 8-17 never: those have no prior.
  cv::Mat d = constantDisparity(size, 30.0f);
  d.colRange(8, 18).setTo(kNaN);
  prior.update(d);
  std::vector<int> searched(4, 0);
  for (int f = 1; f <= 4; ++f) {
    ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
    EXPECT_EQ(prior.stats().narrowed_pixels, 8 * size.height);
    EXPECT_EQ(prior.stats().full_range_pixels, 10 * kFullRangeStripeRows);
    EXPECT_EQ(prior.stats().deferred_pixels, 3 * 10 * kFullRangeStripeRows);
    for (int s = 0; s < 4; ++s) {
      const int y = s * kFullRangeStripeRows + 5;
      EXPECT_EQ(range.lo.at<int16_t>(y, 3), 26);  // a prior: narrowed whatever the stripe
      EXPECT_EQ(range.hi.at<int16_t>(y, 3), 34);
      bool full[2];
      for (int k = 0; k < 2; ++k) {
        const int x = k == 0 ? 12 : 17;  // vector loop, scalar tail
        const int lo = range.lo.at<int16_t>(y, x), hi = range.hi.at<int16_t>(y, x);
        full[k] = lo == 0 && hi == 63;
        if (!full[k]) EXPECT_GT(lo, hi) << "stripe " << s << " x " << x << ": not deferred";
      }
      EXPECT_EQ(full[0], full[1]) << "stripe " << s;
      searched[s] += full[0];
    }
    prior.update(d);
  }
  for (int s = 0; s < 4; ++s) EXPECT_EQ(searched[s], 1) << "stripe " << s;  // once in 4 frames

  // A deferred pixel was not searched: its prior ages but is kept. Pixel (y, 3) fails its
  // narrowed search once, which leaves its prior 1 frame old, too old for max_prior_age_frames =
  // 1: it searches the full range in its stripe's turn and is deferred in the other frames.
  const int y = 1 * kFullRangeStripeRows + 5;
  cv::Mat miss = d.clone();
  miss.at<float>(y, 3) = kNaN;
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  prior.update(miss);
  EXPECT_EQ(prior.stats().prior_misses, 1);
  for (int f = 0; f < 4; ++f) {
    ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
    const bool deferred = range.lo.at<int16_t>(y, 3) > range.hi.at<int16_t>(y, 3);
    if (!deferred) {
      EXPECT_EQ(range.lo.at<int16_t>(y, 3), 0);  // its turn: the full range (fallback)
      break;
    }
    const uint16_t age = prior.priorAge().at<uint16_t>(y, 3);
    prior.update(miss);
    EXPECT_EQ(prior.lastDisparity().at<float>(y, 3), 30.0f) << "frame " << f;
    EXPECT_EQ(prior.priorAge().at<uint16_t>(y, 3), age + 1) << "frame " << f;
    EXPECT_EQ(prior.stats().prior_misses, 0);  // nothing narrowed failed
  }
}

TEST(TemporalPrior, EdgeZoneSpansBothSidesOfADepthEdge) {
  TemporalParams p = plainParams();
  p.prior_neighbourhood_px = 2;
  p.prior_edge_zone_px = 6;
  TemporalPrior prior(p);
  const cv::Size size(40, 20);
  SearchRange range;
  prior.buildRange(size, 0, 63, range);
  cv::Mat d = constantDisparity(size, 20.0f);
  d.colRange(20, 40).setTo(40.0f);  // an instrument edge at x = 20
  prior.update(d);
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  // Within 6 px of the edge: both sides, [20 - 4, 40 + 4].
  EXPECT_EQ(range.lo.at<int16_t>(10, 15), 16);
  EXPECT_EQ(range.hi.at<int16_t>(10, 15), 44);
  EXPECT_EQ(range.lo.at<int16_t>(10, 24), 16);
  EXPECT_EQ(range.hi.at<int16_t>(10, 24), 44);
  // Further away: the own side only.
  EXPECT_EQ(range.lo.at<int16_t>(10, 5), 16);
  EXPECT_EQ(range.hi.at<int16_t>(10, 5), 24);
  EXPECT_EQ(range.lo.at<int16_t>(10, 35), 36);
  EXPECT_EQ(range.hi.at<int16_t>(10, 35), 44);
  // The zone works on 4 x 4 blocks: 6 px becomes 2 blocks, columns 12 .. 27 (6 to 8 px).
  EXPECT_EQ(prior.stats().edge_zone_pixels, 16 * 20);
  EXPECT_EQ(range.hi.at<int16_t>(10, 11), 24);
  EXPECT_EQ(range.hi.at<int16_t>(10, 12), 44);
  EXPECT_EQ(range.lo.at<int16_t>(10, 27), 16);
  EXPECT_EQ(range.lo.at<int16_t>(10, 28), 36);
  // A slanted surface is no edge: 0.2 px per column spans at most 4 px over the zone.
  for (int x = 0; x < 40; ++x) d.col(x).setTo(20.0f + 0.2f * x);
  prior.update(d);
  ASSERT_TRUE(prior.buildRange(size, 0, 63, range));
  EXPECT_EQ(prior.stats().edge_zone_pixels, 0);
}

TEST(TemporalPrior, ResetsOnSizeOrRangeChange) {
  TemporalPrior prior;
  SearchRange range;
  prior.buildRange(cv::Size(16, 16), 0, 63, range);
  prior.update(constantDisparity(cv::Size(16, 16), 30.0f));
  EXPECT_FALSE(prior.buildRange(cv::Size(16, 16), 0, 95, range));  // new full range
  prior.update(constantDisparity(cv::Size(16, 16), 30.0f));
  EXPECT_FALSE(prior.buildRange(cv::Size(20, 16), 0, 95, range));  // new size
  EXPECT_THROW(prior.update(constantDisparity(cv::Size(16, 16), 30.0f)), std::invalid_argument);
}

TEST(TemporalTracker, ResetsWhenTimeGoesBackOrAfterLongGap) {
  TemporalParams p = plainParams();
  p.max_gap_s = 0.5;
  TemporalTracker tracker(p);
  const cv::Size size(16, 16);
  const cv::Mat d = constantDisparity(size, 30.0f);
  std::string reason;
  TemporalFrameInfo info{size, 100.0, 0, 0, 63};
  EXPECT_EQ(tracker.beginFrame(info, &reason), nullptr);
  tracker.endFrame(d, true, true);
  info.stamp_s = 100.04;
  const SearchRange* range = tracker.beginFrame(info, &reason);
  EXPECT_EQ(reason, "");
  ASSERT_NE(range, nullptr);
  EXPECT_TRUE(tracker.priorsUsed());
  EXPECT_EQ(range->lo.at<int16_t>(8, 8), 26);
  tracker.endFrame(d, true, true);
  EXPECT_EQ(tracker.coverage().frames(), 2);
  // The bag loops: time goes back, everything is forgotten.
  info.stamp_s = 90.0;
  EXPECT_EQ(tracker.beginFrame(info, &reason), nullptr);
  EXPECT_NE(reason.find("time went back"), std::string::npos);
  EXPECT_TRUE(tracker.fusion().disparity().empty());
  EXPECT_EQ(tracker.coverage().frames(), 0);
  tracker.endFrame(d, true, true);
  info.stamp_s = 90.04;
  EXPECT_NE(tracker.beginFrame(info, &reason), nullptr);
  tracker.endFrame(d, true, true);
  // A long gap.
  info.stamp_s = 91.0;
  EXPECT_EQ(tracker.beginFrame(info, &reason), nullptr);
  EXPECT_NE(reason.find("gap"), std::string::npos);
  tracker.endFrame(d, true, true);
  // A new calibration.
  info.stamp_s = 91.04;
  info.calibration_generation = 7;
  EXPECT_EQ(tracker.beginFrame(info, &reason), nullptr);
  EXPECT_NE(reason.find("calibration"), std::string::npos);
}

TEST(TemporalTracker, DropsPriorsWhenTheHitShareFallsToAFractionOfThePreviousFrames) {
  TemporalParams p = plainParams();
  p.min_prior_hit_share = 0.5;
  TemporalTracker tracker(p);
  const cv::Size size(20, 20);
  std::string reason;
  TemporalFrameInfo info{size, 0.0, 0, 0, 63};
  tracker.beginFrame(info, &reason);
  tracker.endFrame(constantDisparity(size, 30.0f), true, true);
  // Each frame: the rows whose narrowed search fails (all 400 pixels are narrowed: every pixel
  // has a usable prior within 2 px), and whether that is a scene change.
  struct Step {
    int fail_begin, fail_end;
    bool scene_change;
  };
  const Step steps[] = {
      {0, 12, false},   // 40% hit, but the first narrowed frame has no previous share to judge by
      {0, 0, false},    // 100%
      {12, 20, false},  // 60% >= 0.5 x 100%
      {0, 13, false},   // 35% >= 0.5 x 60% (an absolute 50% would have dropped the priors here)
      {0, 17, true},    // 15% < 0.5 x 35%: the priors describe another scene
  };
  double t = 0.0;
  for (const Step& step : steps) {
    cv::Mat d = constantDisparity(size, 30.0f);
    d.rowRange(step.fail_begin, step.fail_end).setTo(kNaN);
    info.stamp_s = (t += 0.04);
    ASSERT_NE(tracker.beginFrame(info, &reason), nullptr);
    EXPECT_EQ(reason, "");
    EXPECT_EQ(tracker.prior().stats().narrowed_pixels, size.area());
    tracker.endFrame(d, true, true);
    EXPECT_EQ(tracker.prior().stats().scene_change, step.scene_change)
        << "rows " << step.fail_begin << "-" << step.fail_end;
  }
  // All priors dropped, and the fused disparities of the old scene with them.
  EXPECT_TRUE(std::isnan(tracker.fusion().disparity().at<float>(5, 5)));  // old values gone
  EXPECT_LT(tracker.prior().referenceHitShare(), 0.0);
  info.stamp_s = (t += 0.04);
  EXPECT_EQ(tracker.beginFrame(info, &reason), nullptr);  // the full range everywhere
  EXPECT_NE(reason.find("scene change"), std::string::npos);
  EXPECT_EQ(tracker.coverage().frames(), 6);  // coverage is a statistic of the whole sequence
  tracker.endFrame(constantDisparity(size, 30.0f), true, true);
  info.stamp_s = (t += 0.04);
  EXPECT_NE(tracker.beginFrame(info, &reason), nullptr);
  EXPECT_EQ(reason, "");
}

TEST(TemporalTracker, RejectPriorsAsksForAFullRangeMatchOfTheSameFrame) {
  TemporalParams p = plainParams();
  p.min_prior_hit_share = 0.5;
  TemporalTracker tracker(p);
  const cv::Size size(20, 20);
  std::string reason;
  TemporalFrameInfo info{size, 0.0, 0, 0, 63};
  EXPECT_EQ(tracker.beginFrame(info, &reason), nullptr);
  EXPECT_FALSE(tracker.rejectPriors(constantDisparity(size, kNaN)));  // nothing was narrowed
  tracker.endFrame(constantDisparity(size, 30.0f), true, true);
  info.stamp_s = 0.04;
  ASSERT_NE(tracker.beginFrame(info, &reason), nullptr);
  cv::Mat d = constantDisparity(size, 30.0f);
  d.rowRange(0, 12).setTo(kNaN);
  // The first narrowed frame: no previous share to compare with.
  EXPECT_FALSE(tracker.rejectPriors(d));
  tracker.endFrame(constantDisparity(size, 30.0f), true, true);  // every narrowed search hits
  info.stamp_s = 0.08;
  ASSERT_NE(tracker.beginFrame(info, &reason), nullptr);
  d = constantDisparity(size, 30.0f);
  d.rowRange(0, 8).setTo(kNaN);  // 60% hit, >= 0.5 x 100%: keep the priors
  EXPECT_FALSE(tracker.rejectPriors(d));
  d.rowRange(0, 12).setTo(kNaN);  // 40% hit: match again
  EXPECT_TRUE(tracker.rejectPriors(d));
  EXPECT_FALSE(tracker.priorsUsed());
  EXPECT_TRUE(tracker.fusion().disparity().empty());
  // The full-range result of the same frame seeds the new priors.
  tracker.endFrame(constantDisparity(size, 50.0f), true, true);
  EXPECT_TRUE(tracker.prior().stats().scene_change);
  info.stamp_s = 0.12;
  const SearchRange* range = tracker.beginFrame(info, &reason);
  ASSERT_NE(range, nullptr);
  EXPECT_EQ(range->lo.at<int16_t>(2, 2), 46);
  EXPECT_NE(reason.find("matched again"), std::string::npos);
}

TEST(TemporalTracker, DisabledPriorsNeverNarrowButFusionAndCoverageRun) {
  TemporalParams p;
  p.enabled = false;
  TemporalTracker tracker(p);
  const cv::Size size(16, 16);
  for (int k = 0; k < 3; ++k) {
    TemporalFrameInfo info{size, 0.04 * k, 0, 0, 63};
    EXPECT_EQ(tracker.beginFrame(info), nullptr);
    EXPECT_FALSE(tracker.priorsUsed());
    tracker.endFrame(constantDisparity(size, 30.0f), true, true);
  }
  EXPECT_EQ(tracker.coverage().frames(), 3);
  EXPECT_EQ(tracker.fusion().disparity().at<float>(3, 3), 30.0f);
  // Enabling them later starts from a clean prior.
  p.enabled = true;
  tracker.setParams(p);
  TemporalFrameInfo info{size, 0.12, 0, 0, 63};
  EXPECT_EQ(tracker.beginFrame(info), nullptr);
  tracker.endFrame(constantDisparity(size, 30.0f), false, false);
  info.stamp_s = 0.16;
  EXPECT_NE(tracker.beginFrame(info), nullptr);
}

// Hand-made 1 x 4 sequence, max age 2. Pixel columns:
//   0: valid every frame; 1: valid at frame 0 only; 2: never valid; 3: valid at frames 0 and 3.
TEST(TemporalFusion, KeepsMostRecentValidUntilMaxAge) {
  TemporalFusion fusion(2);
  const float seq[5][4] = {{10, 20, kNaN, 40},
                           {11, kNaN, kNaN, kNaN},
                           {12, kNaN, kNaN, kNaN},
                           {13, kNaN, kNaN, 43},
                           {14, kNaN, kNaN, kNaN}};
  const float want_d[5][4] = {{10, 20, kNaN, 40},
                              {11, 20, kNaN, 40},
                              {12, 20, kNaN, 40},
                              {13, kNaN, kNaN, 43},
                              {14, kNaN, kNaN, 43}};
  const uint16_t want_age[5][4] = {{0, 0, kAgeNone, 0},
                                   {0, 1, kAgeNone, 1},
                                   {0, 2, kAgeNone, 2},
                                   {0, kAgeNone, kAgeNone, 0},
                                   {0, kAgeNone, kAgeNone, 1}};
  for (int f = 0; f < 5; ++f) {
    const cv::Mat frame(1, 4, CV_32FC1, const_cast<float*>(seq[f]));
    fusion.update(frame);
    for (int x = 0; x < 4; ++x) {
      const float got = fusion.disparity().at<float>(0, x);
      if (std::isnan(want_d[f][x])) {
        EXPECT_TRUE(std::isnan(got)) << "frame " << f << " px " << x;
      } else {
        EXPECT_EQ(got, want_d[f][x]) << "frame " << f << " px " << x;
      }
      EXPECT_EQ(fusion.age().at<uint16_t>(0, x), want_age[f][x]) << "frame " << f << " px " << x;
    }
  }
  // max age 0 = this frame only.
  TemporalFusion now(0);
  now.update(cv::Mat(1, 4, CV_32FC1, const_cast<float*>(seq[0])));
  now.update(cv::Mat(1, 4, CV_32FC1, const_cast<float*>(seq[1])));
  EXPECT_EQ(now.disparity().at<float>(0, 0), 11.0f);
  EXPECT_TRUE(std::isnan(now.disparity().at<float>(0, 1)));
}

// Hand-made sequence of 12 frames on a 1 x 4 image, N = 3. Updates (1) per pixel:
//   0: every frame                      -> longest run 0
//   1: every third frame (0, 3, 6, 9)   -> runs of 2, and 2 at the end -> 2 (< 3: within)
//   2: frames 0 and 11                  -> run of 10 -> 10
//   3: never                            -> 12 (and never updated)
TEST(CoverageTracker, LongestRunOnHandMadeSequence) {
  CoverageTracker cov(3);
  for (int f = 0; f < 12; ++f) {
    cv::Mat d(1, 4, CV_32FC1, cv::Scalar(kNaN));
    d.at<float>(0, 0) = 1.0f;
    if (f % 3 == 0) d.at<float>(0, 1) = 1.0f;
    if (f == 0 || f == 11) d.at<float>(0, 2) = 1.0f;
    cov.update(d);
  }
  EXPECT_EQ(cov.frames(), 12);
  EXPECT_EQ(cov.longestRun().at<uint16_t>(0, 0), 0);
  EXPECT_EQ(cov.longestRun().at<uint16_t>(0, 1), 2);
  EXPECT_EQ(cov.longestRun().at<uint16_t>(0, 2), 10);
  EXPECT_EQ(cov.longestRun().at<uint16_t>(0, 3), 12);
  EXPECT_EQ(cov.currentRun().at<uint16_t>(0, 1), 2);
  const CoverageStats s = cov.stats();
  EXPECT_DOUBLE_EQ(s.overall_share, 0.5);
  EXPECT_DOUBLE_EQ(s.overall_never, 0.25);
  const cv::Mat img = cov.colorImage();
  ASSERT_EQ(img.type(), CV_8UC3);
  EXPECT_EQ(img.size(), cv::Size(4, 1));
}

// A sequence shorter than N: a pixel never updated has a longest run below N, yet it was not
// updated within N frames and must not count as covered.
TEST(CoverageTracker, NeverUpdatedPixelsDoNotCountInShortSequences) {
  CoverageTracker cov(10);
  for (int f = 0; f < 3; ++f) {
    cv::Mat d(1, 4, CV_32FC1, cv::Scalar(kNaN));
    d.at<float>(0, 0) = 1.0f;
    d.at<float>(0, 1) = 1.0f;
    cov.update(d);
  }
  const CoverageStats s = cov.stats();
  EXPECT_DOUBLE_EQ(s.overall_share, 0.5);
  EXPECT_DOUBLE_EQ(s.overall_never, 0.5);
}

TEST(CoverageTracker, CentralRegionIsTheMiddleHalfByArea) {
  const cv::Rect r = CoverageTracker::centralRegion(cv::Size(960, 540));
  EXPECT_NEAR(double(r.area()) / (960.0 * 540.0), 0.5, 0.005);
  EXPECT_NEAR(r.x + 0.5 * r.width, 480.0, 1.0);
  EXPECT_NEAR(r.y + 0.5 * r.height, 270.0, 1.0);
  // A 40 x 20 image whose border (outside the central region) is never updated.
  CoverageTracker cov(10);
  const cv::Size size(40, 20);
  const cv::Rect c = CoverageTracker::centralRegion(size);
  for (int f = 0; f < 15; ++f) {
    cv::Mat d(size, CV_32FC1, cv::Scalar(kNaN));
    d(c).setTo(5.0f);
    cov.update(d);
  }
  const CoverageStats s = cov.stats();
  EXPECT_EQ(s.central_region, c);
  EXPECT_DOUBLE_EQ(s.central_share, 1.0);
  EXPECT_DOUBLE_EQ(s.central_never, 0.0);
  EXPECT_NEAR(s.overall_share, double(c.area()) / size.area(), 1e-12);
  // The colour picture: never-updated pixels black, central ones coloured, outline white.
  const cv::Mat img = cov.colorImage();
  EXPECT_EQ(img.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(img.at<cv::Vec3b>(c.y, c.x), cv::Vec3b(255, 255, 255));
  EXPECT_NE(img.at<cv::Vec3b>(10, 20), cv::Vec3b(0, 0, 0));
}

// On the synthetic surgical sequence, with the ground truth standing in for a perfect matcher:
// the previous frame's disparities narrow the search, and the next frame's true disparity lies
// inside the narrowed range wherever the scene moved less than the radius.
TEST(TemporalPrior, RangesShrinkAndHoldTheNextFrameOnAMovingSequence) {
  cv::setNumThreads(2);
  SurgicalSceneParams sp;
  sp.width = 320;
  sp.height = 180;
  sp.noise_sigma = 0.0;
  const SurgicalScene scene(sp);
  int dmin = 0, dmax = 0;
  scene.suggestedDisparityRange(&dmin, &dmax);
  TemporalParams tp;
  // A pixel without a usable prior searches the full range at once (deferral:
  // DeferredFullRangeSearchesTakeTurns).
  tp.full_range_period_frames = 1;
  TemporalPrior prior(tp);
  SearchRange range;
  SurgicalFrame frame;
  auto measured = [&](const SurgicalFrame& f) {
    cv::Mat d = f.gt_disparity.clone();
    d.setTo(kNaN, f.visibility != kVisibleBoth);  // a matcher cannot see occluded points
    return d;
  };
  auto inside = [&](const SurgicalFrame& f, int64_t* narrowed, int64_t* held) {
    *narrowed = *held = 0;
    for (int y = 0; y < f.gt_disparity.rows; ++y) {
      for (int x = 0; x < f.gt_disparity.cols; ++x) {
        const int lo = range.lo.at<int16_t>(y, x), hi = range.hi.at<int16_t>(y, x);
        if (lo == dmin && hi == dmax) continue;
        ++*narrowed;
        const float d = f.gt_disparity.at<float>(y, x);
        *held += d >= lo && d <= hi;
      }
    }
  };
  for (int i = 0; i < 4; ++i) {
    scene.render(i, frame);
    const bool narrowed = prior.buildRange(frame.gt_disparity.size(), dmin, dmax, range);
    EXPECT_EQ(narrowed, i > 0);
    if (i > 0) {
      const int64_t total = int64_t(frame.gt_disparity.total());
      // Everything but the few columns at the left border (outside the right view) is narrowed.
      EXPECT_GT(prior.stats().narrowed_pixels, 0.85 * total);
      // 2 * 4 + 1 = 9 disparities around smooth priors; within 16 px of the instrument's edges
      // (a few percent of the pixels) the span of both sides, ~30: 11.2 on average measured,
      // instead of the full range (32 here).
      EXPECT_LT(prior.stats().mean_narrowed_width_px, 12.0);
      EXPECT_LT(prior.stats().mean_narrowed_width_px, 0.4 * (dmax - dmin + 1));
      int64_t n = 0, held = 0;
      inside(frame, &n, &held);
      // Misses only where the instrument's edge moved by more than the neighbourhood.
      EXPECT_GT(double(held) / double(n), 0.98) << "frame " << i;
    }
    prior.update(measured(frame));
  }
  // A sudden jump (a cut in the video: frame 60 after frame 3, with continuous stamps): where the
  // truth left the narrowed range a real matcher finds no valid peak; simulate that outcome. A
  // failed narrowed search keeps the prior without refreshing it, so a failing prior is tried
  // until it is max_prior_age_frames old, then the pixel searches the full range (unless a
  // neighbour's fresh prior narrows it).
  scene.render(60, frame);
  const int max_age = tp.max_prior_age_frames;
  // Pixels holding a prior too old to be used.
  auto expired = [&]() {
    const cv::Mat usable_age = prior.priorAge() < max_age;
    const cv::Mat has_prior = prior.lastDisparity() == prior.lastDisparity();  // not NaN
    return int64_t(cv::countNonZero(has_prior & ~usable_age));
  };
  int64_t n = 0, held = 0, full_before = 0;
  for (int k = 0; k <= max_age; ++k) {
    ASSERT_TRUE(prior.buildRange(frame.gt_disparity.size(), dmin, dmax, range));
    inside(frame, &n, &held);
    if (k == 0) ASSERT_GT(n - held, 500) << "the jump must put many pixels outside their prior";
    if (k < max_age) {
      // Every prior that failed since the jump is still tried: only the few pixels that were
      // failing already before the jump have an expired prior (0 to 6 measured, 50 allowed).
      EXPECT_LT(expired(), 50) << "frame " << k;
      full_before = prior.stats().full_range_pixels;
    } else {
      // max_prior_age_frames failures in a row: those priors are no longer used (810 pixels
      // measured, 500 required) and the full-range pixels grow by those no neighbour's fresh
      // prior covers (+384 measured, +300 required; the sequence and the rules are deterministic,
      // the margins only guard against small changes of the generated scene).
      EXPECT_GT(expired(), 500);
      EXPECT_GT(prior.stats().full_range_pixels, full_before + 300);
    }
    cv::Mat d = measured(frame);
    for (int y = 0; y < d.rows; ++y)
      for (int x = 0; x < d.cols; ++x) {
        const float v = d.at<float>(y, x);
        if (!(v >= range.lo.at<int16_t>(y, x) && v <= range.hi.at<int16_t>(y, x)))
          d.at<float>(y, x) = kNaN;
      }
    prior.update(d);
  }
  // The full searches found the new disparities: the priors hold the truth again.
  ASSERT_TRUE(prior.buildRange(frame.gt_disparity.size(), dmin, dmax, range));
  inside(frame, &n, &held);
  EXPECT_GT(double(held) / double(n), 0.98);
}

// The real matcher on a generated sequence with a cut: the tissue jumps 15 mm nearer (all priors
// wrong). The cut is detected from the failed narrowed searches, the frame is matched again over
// the full range, and output stays trustworthy throughout.
TEST(TemporalTracker, RecoversFromASceneCutWithTheRealMatcher) {
  cv::setNumThreads(2);
  SurgicalSceneParams sp;
  sp.width = 320;
  sp.height = 180;
  const SurgicalScene before(sp);
  sp.seed = 99;
  sp.tissue_distance_m = 0.065;
  const SurgicalScene after(sp);
  int dmin = 0, dmax = 0;
  before.suggestedDisparityRange(&dmin, &dmax);
  MatcherParams mp;
  mp.min_disparity = dmin;
  mp.max_disparity = dmax;
  RobustMatcher with_priors(mp, PostFilterParams()), without(mp, PostFilterParams());
  TemporalTracker tracker;  // the shipped defaults
  SurgicalFrame frame;
  MatchResult res, ref;
  for (int i = 0; i < 8; ++i) {
    (i < 4 ? before : after).render(i, frame);
    cv::Mat l, r;
    cv::cvtColor(frame.left, l, cv::COLOR_BGR2GRAY);
    cv::cvtColor(frame.right, r, cv::COLOR_BGR2GRAY);
    std::string reason;
    const SearchRange* range = tracker.beginFrame({l.size(), i / 25.0, 0, dmin, dmax}, &reason);
    with_priors.compute(l, r, res, range);
    const bool rejected = range && tracker.rejectPriors(res.disparity);
    EXPECT_EQ(rejected, i == 4) << "frame " << i;
    if (rejected) with_priors.compute(l, r, res, nullptr);
    tracker.endFrame(res.disparity, false, false);
    without.compute(l, r, ref, nullptr);
    EXPECT_EQ(tracker.prior().stats().scene_change, i == 4) << "frame " << i;
    if (i == 5) EXPECT_NE(reason.find("scene change"), std::string::npos);
    if (i > 0) EXPECT_NE(range, nullptr) << "frame " << i;
    // Priors cost no density (measured within 1%; 3% allowed for noise).
    EXPECT_GT(res.stats.density(), ref.stats.density() - 0.03) << "frame " << i;
    // Errors: bad2 among output pixels seen by both cameras stays at most 1% on every frame, the
    // cut frame included (1.9% there without the second match: what the wrong priors let through).
    cv::Mat err;
    cv::absdiff(res.disparity, frame.gt_disparity, err);
    const cv::Mat scored = (res.disparity == res.disparity) & (frame.visibility == kVisibleBoth);
    const double bad = cv::countNonZero((err > 2.0f) & scored);
    EXPECT_LE(bad / std::max(1, cv::countNonZero(scored)), 0.01) << "frame " << i;
  }
}

// The paper's claim is that every central pixel is updated within 10 frames. What the schedule
// can promise is a search (a search may find nothing): a pixel with a usable prior searches its
// narrowed range every frame, a pixel without one the full range when its stripe's turn comes, so
// no pixel waits more than full_range_period_frames (4 <= 10 in the shipped preset), whatever the
// outcomes. Here on a sequence with a region that is never matched, pixels that flicker and pixels
// that keep their value, all at the shipped temporal parameters.
TEST(TemporalPrior, NoPixelGoesLongerThanTheFullRangePeriodWithoutASearch) {
  TemporalParams p;  // the shipped preset
  ASSERT_LE(p.full_range_period_frames, 10);
  TemporalPrior prior(p);
  const cv::Size size(67, 5 * kFullRangeStripeRows + 3);
  cv::RNG rng(12345);
  SearchRange range;
  std::vector<int> last(size_t(size.area()), -1);  // frame of each pixel's latest search
  int longest = 0, longest_in_dead_block = 0;
  const int frames = 60;
  for (int f = 0; f < frames; ++f) {
    const bool narrowed = prior.buildRange(size, 0, 63, range);
    cv::Mat d = constantDisparity(size, kNaN);
    for (int y = 0; y < size.height; ++y) {
      for (int x = 0; x < size.width; ++x) {
        const bool searched =
            !narrowed || range.lo.at<int16_t>(y, x) <= range.hi.at<int16_t>(y, x);
        if (!searched) continue;
        int& l = last[size_t(y * size.width + x)];
        const int gap = f - l;  // frames since the latest search (f + 1 before the first)
        longest = std::max(longest, gap);
        if (x >= 44) longest_in_dead_block = std::max(longest_in_dead_block, gap);
        l = f;
        // Outcomes by column: 40..66 never matched (an instrument, a highlight); below it
        // x % 3 == 0 flickers (valid with probability 0.3), the rest is valid 9 times in 10.
        const bool valid = x < 40 && rng.uniform(0.0, 1.0) < (x % 3 == 0 ? 0.3 : 0.9);
        if (valid) d.at<float>(y, x) = 20.0f + float(x % 5);
      }
    }
    prior.update(d);
  }
  for (int i = 0; i < size.area(); ++i) longest = std::max(longest, frames - last[size_t(i)]);
  EXPECT_LE(longest, p.full_range_period_frames);
  // More than prior_neighbourhood_px from any prior, the pixels wait exactly one period between
  // full-range searches.
  EXPECT_EQ(longest_in_dead_block, p.full_range_period_frames);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
