// The metrics of a recording without ground truth (density, jumps between frames, coverage of the
// central pixels) on sequences whose answers are known by construction, and OpenCV's BM / SGBM
// as the comparisons run them, against an independent computation.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "endo_stereo/core/sequence_evaluation.hpp"
#include "surgical_scene.hpp"

namespace endo_stereo {
namespace {

const float kNaN = std::numeric_limits<float>::quiet_NaN();

TEST(CentralHalf, IsTheMiddleHalfInEachDirection) {
  EXPECT_EQ(centralHalf(cv::Size(360, 288)), cv::Rect(90, 72, 180, 144));
  EXPECT_EQ(centralHalf(cv::Size(7, 5)), cv::Rect(2, 1, 3, 2));
}

TEST(SequenceMetrics, ConstantDisparityHasNoJumpsAndFullCoverage) {
  SequenceMetrics m;
  const cv::Mat d(48, 64, CV_32FC1, cv::Scalar(17.25f));
  for (int i = 0; i < 25; ++i) m.addFrame(d);
  const SequenceSummary s = m.summary();
  EXPECT_EQ(s.frames, 25);
  EXPECT_EQ(s.density_median, 1.0);
  EXPECT_EQ(s.density_mean, 1.0);
  EXPECT_EQ(s.jump_pixels, 0);
  EXPECT_EQ(s.compared_pixels, 24 * 48 * 64);
  EXPECT_EQ(s.jump_share, 0.0);
  EXPECT_EQ(s.coverage_every_window, 1.0);
  EXPECT_EQ(s.coverage_never, 0.0);
  EXPECT_EQ(s.window_frames, 10);
}

TEST(SequenceMetrics, PlantedJumpsGiveExactlyTheirShare) {
  // 8 frames of 40x30 at 20 px. Frame 3 moves a 10x7 block by +5 px (a jump into frame 3 and one
  // back out of it in frame 4), frame 6 moves 13 single pixels by -2.5 px (one jump each, frame 7
  // keeps them), and 2.0 px changes elsewhere in frame 5 are not jumps (the threshold is > 2).
  // Frame 2 has no value in a 5x5 block: those pixels are compared in no pair that includes it.
  const cv::Size size(40, 30);
  std::vector<cv::Mat> frames(8);
  for (auto& f : frames) f = cv::Mat(size, CV_32FC1, cv::Scalar(20.f));
  frames[3](cv::Rect(5, 5, 10, 7)).setTo(25.f);
  for (int k = 0; k < 13; ++k) {
    frames[6].at<float>(20, 2 + 2 * k) = 17.5f;
    frames[7].at<float>(20, 2 + 2 * k) = 17.5f;
  }
  frames[5](cv::Rect(20, 0, 20, 4)).setTo(22.f);  // +2.0 into 5, -2.0 back out in 6: no jumps
  frames[2](cv::Rect(30, 25, 5, 5)).setTo(kNaN);

  SequenceMetrics m;
  for (const auto& f : frames) m.addFrame(f);
  const SequenceSummary s = m.summary();
  const int64_t n = size.area();
  const int64_t compared = 7 * n - 2 * 25;  // pairs (1,2) and (2,3) lose the 25 holes
  const int64_t jumps = 2 * 70 + 13;
  EXPECT_EQ(s.compared_pixels, compared);
  EXPECT_EQ(s.jump_pixels, jumps);
  EXPECT_DOUBLE_EQ(s.jump_share, double(jumps) / compared);
  ASSERT_EQ(m.jumpCounts().size(), 7u);
  EXPECT_EQ(m.jumpCounts()[2], 70);  // frame 3 against frame 2
  EXPECT_EQ(m.jumpCounts()[3], 70);
  EXPECT_EQ(m.jumpCounts()[4], 0);
  EXPECT_EQ(m.jumpCounts()[5], 13);
  EXPECT_EQ(m.jumpCounts()[6], 0);
  EXPECT_EQ(m.comparedCounts()[1], n - 25);
  // The latest frame's map: frame 7 against 6, all compared and stable.
  EXPECT_EQ(cv::countNonZero(m.lastJumpMap() == 1), n);
  // Densities: frame 2 lacks 25 pixels.
  EXPECT_DOUBLE_EQ(m.densities()[2], double(n - 25) / n);
  EXPECT_DOUBLE_EQ(s.density_median, 1.0);
  EXPECT_DOUBLE_EQ(s.density_mean, (7.0 + double(n - 25) / n) / 8.0);
}

TEST(SequenceMetrics, JumpMapMarksJumpedStableAndUncompared) {
  SequenceMetrics m;
  m.addFrame((cv::Mat_<float>(1, 4) << 1.f, 1.f, kNaN, 1.f));
  EXPECT_EQ(cv::countNonZero(m.lastJumpMap()), 0);  // the first frame compares nothing
  m.addFrame((cv::Mat_<float>(1, 4) << 1.5f, 9.f, 1.f, kNaN));
  const cv::Mat j = m.lastJumpMap();
  EXPECT_EQ(j.at<uint8_t>(0, 0), 1);
  EXPECT_EQ(j.at<uint8_t>(0, 1), 2);
  EXPECT_EQ(j.at<uint8_t>(0, 2), 0);
  EXPECT_EQ(j.at<uint8_t>(0, 3), 0);
}

TEST(SequenceMetrics, CoverageCountsPixelsWithAValueInEveryWindow) {
  // 30 frames of 8x8; the central region is the 4x4 block at (2, 2), 16 pixels. Four of them
  // have a value every 10th frame (0, 10, 20: gaps of 9, then 9 at the end) and are covered;
  // four every 11th (0, 11, 22: gaps of 10) are not; four never have one; four only in frames
  // 9..20 (a gap of 9 at the start, 9 at the end) are covered. Pixels outside the centre have
  // no value ever and must not count.
  const int frames = 30;
  SequenceMetrics m;
  for (int i = 0; i < frames; ++i) {
    cv::Mat d(8, 8, CV_32FC1, cv::Scalar(kNaN));
    for (int x = 2; x < 6; ++x) {
      if (i % 10 == 0) d.at<float>(2, x) = 30.f;
      if (i % 11 == 0) d.at<float>(3, x) = 30.f;
      if (i >= 9 && i <= 20) d.at<float>(5, x) = 30.f;
    }
    m.addFrame(d);
  }
  const SequenceSummary s = m.summary();
  EXPECT_EQ(s.central, cv::Rect(2, 2, 4, 4));
  EXPECT_DOUBLE_EQ(s.coverage_every_window, 8.0 / 16.0);
  EXPECT_DOUBLE_EQ(s.coverage_never, 4.0 / 16.0);
  const cv::Mat gap = m.longestGap();
  EXPECT_EQ(gap.at<uint16_t>(2, 2), 9);
  EXPECT_EQ(gap.at<uint16_t>(3, 2), 10);
  EXPECT_EQ(gap.at<uint16_t>(4, 2), frames);
  EXPECT_EQ(gap.at<uint16_t>(5, 2), 9);
}

TEST(SequenceMetrics, ASequenceShorterThanTheWindowNeedsOneValue) {
  SequenceMetrics m;
  for (int i = 0; i < 4; ++i) {
    cv::Mat d(4, 4, CV_32FC1, cv::Scalar(kNaN));
    if (i == 3) d.at<float>(1, 1) = 5.f;  // one of the 4 central pixels, in the last frame only
    m.addFrame(d);
  }
  const SequenceSummary s = m.summary();
  EXPECT_EQ(s.window_frames, 4);
  EXPECT_DOUBLE_EQ(s.coverage_every_window, 0.25);
  EXPECT_DOUBLE_EQ(s.coverage_never, 0.75);
}

TEST(SequenceMetrics, RejectsBadFrames) {
  SequenceMetrics m;
  EXPECT_THROW(m.addFrame(cv::Mat(4, 4, CV_8UC1)), std::invalid_argument);
  m.addFrame(cv::Mat(4, 4, CV_32FC1, cv::Scalar(1.f)));
  EXPECT_THROW(m.addFrame(cv::Mat(4, 5, CV_32FC1, cv::Scalar(1.f))), std::invalid_argument);
  SequenceMetricsParams p;
  p.window_frames = 0;
  EXPECT_THROW(SequenceMetrics{p}, std::invalid_argument);
}

// --- OpenCV's matchers as the comparisons run them, against an independent computation --------

struct Independent {
  double density_mean = 0;
  int64_t jumps = 0, compared = 0, covered = 0, never = 0, central = 0;
};

// Written without SequenceMetrics: OpenCV called with every setting spelled out, counts by loops.
Independent independentFigures(const std::vector<cv::Mat>& lefts,
                               const std::vector<cv::Mat>& rights, bool sgbm, int min_d,
                               int num_d) {
  cv::Ptr<cv::StereoMatcher> matcher;
  if (sgbm) {
    matcher = cv::StereoSGBM::create(min_d, num_d, 5, 200, 800, 0, 0, 10, 0, 0,
                                     cv::StereoSGBM::MODE_SGBM);
  } else {
    auto bm = cv::StereoBM::create(num_d, 15);
    bm->setMinDisparity(min_d);
    bm->setUniquenessRatio(15);
    matcher = bm;
  }
  Independent r;
  cv::Mat prev;
  const int n = static_cast<int>(lefts.size());
  std::vector<cv::Mat> valid(n);
  for (int i = 0; i < n; ++i) {
    cv::Mat raw;
    matcher->compute(lefts[i], rights[i], raw);
    cv::Mat d;
    raw.convertTo(d, CV_32F, 1.0 / 16);
    valid[i] = raw >= min_d * 16;  // OpenCV writes (min - 1) * 16 where it has no disparity
    r.density_mean += double(cv::countNonZero(valid[i])) / raw.total() / n;
    if (i > 0) {
      for (int y = 0; y < d.rows; ++y) {
        for (int x = 0; x < d.cols; ++x) {
          if (!valid[i].at<uint8_t>(y, x) || !valid[i - 1].at<uint8_t>(y, x)) continue;
          ++r.compared;
          if (std::abs(d.at<float>(y, x) - prev.at<float>(y, x)) > 2.0f) ++r.jumps;
        }
      }
    }
    prev = d;
  }
  const int w = lefts[0].cols, h = lefts[0].rows;
  const int window = std::min(10, n);
  for (int y = (h - h / 2) / 2; y < (h - h / 2) / 2 + h / 2; ++y) {
    for (int x = (w - w / 2) / 2; x < (w - w / 2) / 2 + w / 2; ++x) {
      ++r.central;
      int run = 0, longest = 0;
      for (int i = 0; i < n; ++i) {
        run = valid[i].at<uint8_t>(y, x) ? 0 : run + 1;
        longest = std::max(longest, run);
      }
      r.covered += longest < window;
      r.never += longest == n;
    }
  }
  return r;
}

TEST(ReferenceMatchers, FiguresMatchAnIndependentComputation) {
  SurgicalSceneParams p;
  p.width = 256;
  p.height = 192;
  p.seed = 3;
  SurgicalScene scene(p);
  int min_d = 0, max_d = 0;
  scene.suggestedDisparityRange(&min_d, &max_d);
  const int num_d = referenceNumDisparities(min_d, max_d);
  ASSERT_EQ(num_d % 16, 0);
  ASSERT_GE(min_d + num_d - 1, max_d);
  std::vector<cv::Mat> lefts, rights;
  SurgicalFrame f;
  for (int i = 0; i < 12; ++i) {
    scene.render(i, f);
    cv::Mat l, r;
    cv::cvtColor(f.left, l, cv::COLOR_BGR2GRAY);
    cv::cvtColor(f.right, r, cv::COLOR_BGR2GRAY);
    lefts.push_back(l);
    rights.push_back(r);
  }
  for (bool sgbm : {false, true}) {
    SCOPED_TRACE(sgbm ? "SGBM" : "BM");
    cv::Ptr<cv::StereoMatcher> matcher;
    if (sgbm) {
      matcher = makeReferenceSgbm(min_d, num_d);
    } else {
      matcher = makeReferenceBm(min_d, num_d);
    }
    SequenceMetrics m;
    for (size_t i = 0; i < lefts.size(); ++i) {
      cv::Mat raw;
      matcher->compute(lefts[i], rights[i], raw);
      m.addFrame(referenceDisparityToFloat(raw, min_d));
    }
    const SequenceSummary s = m.summary();
    const Independent ind = independentFigures(lefts, rights, sgbm, min_d, num_d);
    ASSERT_GT(ind.compared, 0);
    // Same counts; the shares are ratios of the same integers (the mean density sums the frames
    // in the same order, so only rounding in the last bits can differ).
    EXPECT_EQ(s.jump_pixels, ind.jumps);
    EXPECT_EQ(s.compared_pixels, ind.compared);
    EXPECT_NEAR(s.density_mean, ind.density_mean, 1e-12);
    EXPECT_EQ(s.central.area(), ind.central);
    EXPECT_DOUBLE_EQ(s.coverage_every_window, double(ind.covered) / ind.central);
    EXPECT_DOUBLE_EQ(s.coverage_never, double(ind.never) / ind.central);
    // A sanity floor so that an empty output cannot pass: both matchers find most of a textured
    // generated scene.
    EXPECT_GT(s.density_mean, 0.3);
  }
}

TEST(ReferenceMatchers, FixedPointConversionMarksMissingValues) {
  const cv::Mat raw = (cv::Mat_<int16_t>(1, 4) << 47 * 16, 48 * 16, 48 * 16 + 8, 111 * 16);
  const cv::Mat d = referenceDisparityToFloat(raw, 48);
  EXPECT_TRUE(std::isnan(d.at<float>(0, 0)));
  EXPECT_EQ(d.at<float>(0, 1), 48.f);
  EXPECT_EQ(d.at<float>(0, 2), 48.5f);
  EXPECT_EQ(d.at<float>(0, 3), 111.f);
  EXPECT_EQ(referenceNumDisparities(48, 111), 64);
  EXPECT_EQ(referenceNumDisparities(0, 127), 128);
  EXPECT_EQ(referenceNumDisparities(0, 59), 64);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
