// The metrics of a recording without ground truth (density, jumps between frames, motion-
// compensated flicker, coverage of the central pixels) on sequences whose answers are known by
// construction, and OpenCV's BM / SGBM
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

// --- motion-compensated flicker ----------------------------------------------------------------

// A tilted plane, 10 + x / 4 + y / 8 px: not constant, and every value and every difference of
// two values exact in float and double, so the flicker tests below can ask for exact counts.
cv::Mat plane(cv::Size size, float offset) {
  cv::Mat d(size, CV_32FC1);
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) d.at<float>(y, x) = 10.f + x / 4.f + y / 8.f + offset;
  }
  return d;
}

TEST(SequenceMetrics, ACoherentShiftIsAJumpEverywhereAndNoFlicker) {
  // 5 frames of 90x70, the whole map 3 px further each frame: every compared pixel jumps, and
  // every pixel's change equals its square's mean change. Holes make the squares uneven: the
  // left 30 columns have a value only on every 4th row and column (a sparse map: 1 in 16 pixels
  // of a square counts), a 20x20 block never has one, and the image border cuts the squares
  // (a corner pixel's square holds 9x9). Dividing by the square's area instead of by the pixels
  // compared in it would give 3 - 3/16 at the sparse pixels and 3 - 3 * 81 / 289 at the
  // corners, both flicker; only the compared pixels' mean gives exactly 0.
  const cv::Size size(90, 70);
  // Pixels with a value in every frame: the sparse part's columns 0, 4, .., 28 on rows
  // 0, 4, .., 68, and the dense 60 columns less the block.
  const int64_t valid = 8 * 18 + 60 * 70 - 20 * 20;
  SequenceMetrics m;
  for (int k = 0; k < 5; ++k) {
    cv::Mat d = plane(size, 3.f * k);
    for (int y = 0; y < size.height; ++y) {
      for (int x = 0; x < 30; ++x) {
        if (y % 4 != 0 || x % 4 != 0) d.at<float>(y, x) = kNaN;
      }
    }
    d(cv::Rect(50, 30, 20, 20)).setTo(kNaN);
    ASSERT_EQ(cv::countNonZero(d == d), valid);  // NaN != NaN
    m.addFrame(d);
  }
  const SequenceSummary s = m.summary();
  EXPECT_EQ(s.compared_pixels, 4 * valid);
  EXPECT_EQ(s.jump_pixels, 4 * valid);
  EXPECT_EQ(s.jump_share, 1.0);
  EXPECT_EQ(s.flicker_pixels, 0);
  EXPECT_EQ(s.flicker_share, 0.0);
  ASSERT_EQ(m.flickerCounts().size(), 4u);
  for (int64_t f : m.flickerCounts()) EXPECT_EQ(f, 0);
  EXPECT_EQ(cv::countNonZero(m.lastFlickerMap() == 1), valid);
  EXPECT_EQ(cv::countNonZero(m.lastFlickerMap() == 2), 0);
}

TEST(SequenceMetrics, IsolatedJumpsFlickerAndCoherentMotionAroundThemDoesNot) {
  // 6 frames of 100x80 on the plane. Frame 2 raises 30 single pixels by 5 px (a grid: columns 0,
  // 20, .., 80 and 99, rows 0, 20, .., 60 and 79, corners included) and frame 3 drops them back:
  // 30 flickers in each of the two pairs. Frame 4 shifts the whole map by 3 px and 20 other
  // pixels (columns 10, 30, .., 90, rows 10, 30, 50, 70) by 3 + 5 px: every pixel jumps, only
  // those 20 flicker. Frame 5 is frame 4 again.
  // Exact counts, no tolerance: any two planted pixels are at least 19 px apart, so a square
  // holds at most one. A planted pixel's residual is 5 - 5 / k, its neighbours' 5 / k in
  // magnitude, with k >= 81 the compared pixels of the square (a corner's 9x9); 4.9 and 0.06 px
  // are far from the 2 px threshold for any rounding.
  const cv::Size size(100, 80);
  const int64_t n = size.area();
  const std::vector<int> xs1 = {0, 20, 40, 60, 80, 99}, ys1 = {0, 20, 40, 60, 79};
  const std::vector<int> xs2 = {10, 30, 50, 70, 90}, ys2 = {10, 30, 50, 70};
  std::vector<cv::Mat> frames = {plane(size, 0.f), plane(size, 0.f), plane(size, 0.f),
                                 plane(size, 0.f), plane(size, 3.f), plane(size, 3.f)};
  for (int y : ys1) {
    for (int x : xs1) frames[2].at<float>(y, x) += 5.f;
  }
  for (int k : {4, 5}) {
    for (int y : ys2) {
      for (int x : xs2) frames[k].at<float>(y, x) += 5.f;
    }
  }
  const int64_t planted1 = 6 * 5, planted2 = 5 * 4;
  SequenceMetrics m;
  for (int k = 0; k < 6; ++k) {
    m.addFrame(frames[k]);
    if (k == 2) {  // frame 2 against 1: the planted pixels flicker, their neighbours do not
      const cv::Mat f = m.lastFlickerMap();
      EXPECT_EQ(cv::countNonZero(f == 2), planted1);
      EXPECT_EQ(f.at<uint8_t>(20, 20), 2);
      EXPECT_EQ(f.at<uint8_t>(79, 99), 2);
      EXPECT_EQ(f.at<uint8_t>(20, 21), 1);
      EXPECT_EQ(f.at<uint8_t>(1, 1), 1);
    }
  }
  const SequenceSummary s = m.summary();
  ASSERT_EQ(m.flickerCounts().size(), 5u);
  EXPECT_EQ(m.flickerCounts()[0], 0);
  EXPECT_EQ(m.flickerCounts()[1], planted1);
  EXPECT_EQ(m.flickerCounts()[2], planted1);
  EXPECT_EQ(m.flickerCounts()[3], planted2);
  EXPECT_EQ(m.flickerCounts()[4], 0);
  EXPECT_EQ(s.compared_pixels, 5 * n);
  EXPECT_EQ(s.flicker_pixels, 2 * planted1 + planted2);
  EXPECT_DOUBLE_EQ(s.flicker_share, double(2 * planted1 + planted2) / (5 * n));
  EXPECT_EQ(s.jump_pixels, 2 * planted1 + n);  // the raw jumps count the whole shift
}

TEST(SequenceMetrics, APixelWithAValueInOnlyOneFrameIsNotCompared) {
  // 2 frames of 80x60, the second the plane shifted by 3 px. Pixel P (x 20, y 20) has a value
  // in the second frame only, and a wild one (1000 px); Q (40, 30) in the first only; R (5, 45)
  // in neither. S (70, 55), at least 25 px from each of them, below and right of P, is raised
  // by 5 px more: the one flicker. P's value must count neither for P nor in its neighbours'
  // mean change (1000 / 289 = 3.5 px would make every neighbour flicker), nor spoil the sums
  // that pass over it on their way to S.
  const cv::Size size(80, 60);
  const int64_t n = size.area();
  cv::Mat a = plane(size, 0.f), b = plane(size, 3.f);
  a.at<float>(20, 20) = kNaN;
  b.at<float>(20, 20) = 1000.f;
  b.at<float>(30, 40) = kNaN;
  a.at<float>(45, 5) = kNaN;
  b.at<float>(45, 5) = kNaN;
  b.at<float>(55, 70) += 5.f;
  SequenceMetrics m;
  m.addFrame(a);
  m.addFrame(b);
  const SequenceSummary s = m.summary();
  EXPECT_EQ(s.compared_pixels, n - 3);
  EXPECT_EQ(s.jump_pixels, n - 3);
  EXPECT_EQ(s.flicker_pixels, 1);
  EXPECT_DOUBLE_EQ(s.flicker_share, 1.0 / (n - 3));
  const cv::Mat f = m.lastFlickerMap();
  EXPECT_EQ(f.at<uint8_t>(20, 20), 0);
  EXPECT_EQ(f.at<uint8_t>(30, 40), 0);
  EXPECT_EQ(f.at<uint8_t>(45, 5), 0);
  EXPECT_EQ(f.at<uint8_t>(55, 70), 2);
  EXPECT_EQ(f.at<uint8_t>(20, 21), 1);
}

TEST(SequenceMetrics, TheFlickerSquareIsCutAtTheImageBorder) {
  // A corner pixel's square holds its 9x9 pixels inside the image, an interior pixel's 17x17.
  // Both change alone by c = 2 + 1/64 px (a jump each): the residual is c * 80 / 81 = 1.991 px
  // at the corner (no flicker) and c * 288 / 289 = 2.009 px inside (a flicker). A square
  // completed by reflection (OpenCV's default border) would hold 289 at the corner too, the
  // corner once among them: a flicker there as well.
  const cv::Size size(40, 30);
  cv::Mat b = plane(size, 0.f);
  b.at<float>(0, 0) += 2.015625f;
  b.at<float>(15, 20) += 2.015625f;
  SequenceMetrics m;
  m.addFrame(plane(size, 0.f));
  m.addFrame(b);
  const SequenceSummary s = m.summary();
  EXPECT_EQ(s.jump_pixels, 2);
  EXPECT_EQ(s.flicker_pixels, 1);
  EXPECT_EQ(m.lastFlickerMap().at<uint8_t>(0, 0), 1);
  EXPECT_EQ(m.lastFlickerMap().at<uint8_t>(15, 20), 2);
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
  for (int w : {16, 1, -3}) {
    SequenceMetricsParams q;
    q.flicker_window_px = w;
    EXPECT_THROW(SequenceMetrics{q}, std::invalid_argument) << w;
  }
  SequenceMetricsParams q;
  q.flicker_window_px = 3;
  EXPECT_NO_THROW(SequenceMetrics{q});
}

// --- OpenCV's matchers as the comparisons run them, against an independent computation --------

struct Independent {
  double density_mean = 0;
  int64_t jumps = 0, compared = 0, flicker = 0, covered = 0, never = 0, central = 0;
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
      // Flicker by direct sums over each 17x17 square, cut at the border (no box filter). The
      // values are multiples of 1/16 px below 2^10: every sum is exact in double in any order, so
      // the counts must agree exactly.
      for (int y = 0; y < d.rows; ++y) {
        for (int x = 0; x < d.cols; ++x) {
          if (!valid[i].at<uint8_t>(y, x) || !valid[i - 1].at<uint8_t>(y, x)) continue;
          double sum = 0.0;
          int count = 0;
          for (int v = std::max(0, y - 8); v <= std::min(d.rows - 1, y + 8); ++v) {
            for (int u = std::max(0, x - 8); u <= std::min(d.cols - 1, x + 8); ++u) {
              if (!valid[i].at<uint8_t>(v, u) || !valid[i - 1].at<uint8_t>(v, u)) continue;
              sum += double(d.at<float>(v, u)) - double(prev.at<float>(v, u));
              ++count;
            }
          }
          const double change = double(d.at<float>(y, x)) - double(prev.at<float>(y, x));
          if (std::abs(change - sum / count) > 2.0) ++r.flicker;
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
    EXPECT_EQ(s.flicker_pixels, ind.flicker);
    EXPECT_GT(ind.flicker, 0);  // not a comparison of zeros: both matchers flicker somewhere
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
