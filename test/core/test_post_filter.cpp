// Isolated-outlier removal and small-hole filling (docs/method.md section 3) on hand-made maps.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <vector>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {
namespace {

const float kNaN = std::numeric_limits<float>::quiet_NaN();

cv::Mat filled(int rows, int cols, float v) { return cv::Mat(rows, cols, CV_32FC1, cv::Scalar(v)); }

PostFilterParams paperFilter() {
  PostFilterParams p;  // paper: 5 x 5 window, 4 px, mu 0.4, holes up to 2 px
  p.outlier_window_px = 5;
  p.outlier_disparity_tol_px = 4.0;
  p.outlier_min_share = 0.4;
  p.fill_max_hole_px = 2;
  return p;
}

TEST(IsolatedOutliers, RemovesALonePixelAndKeepsItsSupportedNeighbours) {
  cv::Mat d = filled(9, 9, kNaN);
  d.at<float>(4, 4) = 10.f;  // no matched neighbour at all
  cv::Mat code(9, 9, CV_8UC1, cv::Scalar(kCodeAcceptedBase));
  EXPECT_EQ(removeIsolatedOutliers(d, code, paperFilter()), 1);
  EXPECT_TRUE(std::isnan(d.at<float>(4, 4)));
  EXPECT_EQ(code.at<uint8_t>(4, 4), kCodeRejectOutlier);
}

TEST(IsolatedOutliers, RemovesAPixelDifferingFromAUniformField) {
  cv::Mat d = filled(9, 9, 10.f);
  d.at<float>(4, 4) = 30.f;
  cv::Mat code;
  // The centre goes, and so do the four image corners: the denominator is always window^2
  // (docs/method.md), and a corner sees only 3 x 3 - 1 = 8 neighbours, fewer than 0.4 * 25 = 10.
  EXPECT_EQ(removeIsolatedOutliers(d, code, paperFilter()), 5);
  EXPECT_TRUE(std::isnan(d.at<float>(4, 4)));
  EXPECT_TRUE(std::isnan(d.at<float>(0, 0)));
  EXPECT_EQ(d.at<float>(4, 3), 10.f);
  EXPECT_EQ(d.at<float>(0, 1), 10.f);  // 3 x 4 - 1 = 11 neighbours
}

TEST(IsolatedOutliers, ThresholdIsStrictShareOfTheFullWindow) {
  // mu = 0.4 of a 5 x 5 window: 10 agreeing neighbours keep a pixel (10/25 = 0.4 is not < 0.4),
  // 9 remove it. The neighbours are placed so that each of them has enough support itself.
  for (int n_agree : {9, 10}) {
    cv::Mat d = filled(5, 5, kNaN);
    d.at<float>(2, 2) = 20.f;
    int placed = 0;
    for (int y = 0; y < 5 && placed < n_agree; ++y) {
      for (int x = 0; x < 5 && placed < n_agree; ++x) {
        if (y == 2 && x == 2) continue;
        d.at<float>(y, x) = 20.f + 3.9f;  // differs by less than 4 px: agrees
        ++placed;
      }
    }
    cv::Mat code;
    PostFilterParams p = paperFilter();
    cv::Mat before = d.clone();
    removeIsolatedOutliers(d, code, p);
    if (n_agree == 10) {
      EXPECT_EQ(d.at<float>(2, 2), 20.f) << "10 agreeing neighbours must keep the pixel";
    } else {
      EXPECT_TRUE(std::isnan(d.at<float>(2, 2))) << "9 agreeing neighbours must remove it";
    }
  }
}

TEST(IsolatedOutliers, NeighbourExactlyAtToleranceDoesNotAgree) {
  cv::Mat d = filled(5, 5, 14.f);  // every neighbour differs by exactly 4 px
  d.at<float>(2, 2) = 10.f;
  cv::Mat code;
  removeIsolatedOutliers(d, code, paperFilter());
  EXPECT_TRUE(std::isnan(d.at<float>(2, 2)));
}

TEST(IsolatedOutliers, DecidesFromTheInputMapNotFromEarlierRemovals) {
  // A 2 x 5 strip of equal values: every pixel has 9 agreeing neighbours at most. All are removed,
  // and the result does not depend on visiting order (the first removal must not change the
  // count of the next pixel). A 4 x 5 block keeps its pixels with >= 10 neighbours.
  cv::Mat d = filled(12, 12, kNaN);
  d(cv::Rect(1, 1, 5, 2)).setTo(7.f);
  d(cv::Rect(3, 5, 5, 4)).setTo(3.f);
  cv::Mat code;
  removeIsolatedOutliers(d, code, paperFilter());
  EXPECT_EQ(cv::countNonZero(d(cv::Rect(1, 1, 5, 2)) == 7.f), 0);
  // In the 4 x 5 block the centre pixels have 4*5 - 1 = 19 (or fewer near its edge) neighbours;
  // corner pixels have 3*3 - 1 = 8 < 10 and go.
  EXPECT_EQ(d.at<float>(6, 5), 3.f);
  EXPECT_TRUE(std::isnan(d.at<float>(5, 3)));
}

// docs/method.md's rule written out plainly: a measured pixel goes when fewer than
// outlier_min_share * window^2 of its in-image neighbours (itself excluded) lie within the
// tolerance of it.
cv::Mat referenceRemoval(const cv::Mat& d, const PostFilterParams& p) {
  const int half = p.outlier_window_px / 2;
  const double need = p.outlier_min_share * p.outlier_window_px * p.outlier_window_px;
  cv::Mat out = d.clone();
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const float s = d.at<float>(y, x);
      if (std::isnan(s)) continue;
      int agree = 0;
      for (int yy = std::max(0, y - half); yy <= std::min(d.rows - 1, y + half); ++yy) {
        for (int xx = std::max(0, x - half); xx <= std::min(d.cols - 1, x + half); ++xx) {
          if (yy == y && xx == x) continue;
          const float n = d.at<float>(yy, xx);
          if (std::fabs(n - s) < static_cast<float>(p.outlier_disparity_tol_px)) ++agree;
        }
      }
      if (agree < need) out.at<float>(y, x) = kNaN;
    }
  }
  return out;
}

TEST(IsolatedOutliers, MatchesThePlainRuleOnRandomMaps) {
  // Smooth patches, jumps, isolated values, holes and values a quarter pixel apart (so that
  // neighbours exactly at the tolerance occur), several sizes (rows not a multiple of the
  // vector width), windows, tolerances and shares: the vectorised filter and its shortcut for
  // uniform windows must decide every pixel as the plain rule does.
  cv::RNG rng(7);
  int cases = 0;
  for (int window : {3, 5, 7}) {
    for (double tol : {0.5, 1.0, 4.0}) {
      for (double share : {0.2, 0.4, 0.9}) {
        const int rows = 20 + rng.uniform(0, 9), cols = 37 + rng.uniform(0, 40);
        cv::Mat d(rows, cols, CV_32FC1);
        for (int y = 0; y < rows; ++y) {
          for (int x = 0; x < cols; ++x) {
            const float base = (x < cols / 2 ? 20.f : 32.f) + 0.25f * static_cast<float>(y / 4);
            const int kind = rng.uniform(0, 100);
            float v = base + 0.25f * static_cast<float>(rng.uniform(0, 5));
            if (kind < 12) v = kNaN;
            if (kind >= 12 && kind < 17) v = 0.25f * static_cast<float>(rng.uniform(0, 240));
            d.at<float>(y, x) = v;
          }
        }
        PostFilterParams p = paperFilter();
        p.outlier_window_px = window;
        p.outlier_disparity_tol_px = tol;
        p.outlier_min_share = share;
        const cv::Mat expected = referenceRemoval(d, p);
        cv::Mat got = d.clone(), code;
        removeIsolatedOutliers(got, code, p);
        int diff = 0;
        for (int y = 0; y < rows; ++y) {
          for (int x = 0; x < cols; ++x) {
            const float a = got.at<float>(y, x), b = expected.at<float>(y, x);
            diff += !(a == b || (std::isnan(a) && std::isnan(b)));
          }
        }
        EXPECT_EQ(diff, 0) << "window " << window << " tol " << tol << " share " << share;
        ++cases;
      }
    }
  }
  EXPECT_EQ(cases, 27);
}

// docs/method.md's hole rule written out plainly: an invalid pixel inside a horizontal or vertical
// run of at most max_hole invalid pixels with a valid pixel at both ends takes the lower median of
// its valid 8-neighbours in the input map.
cv::Mat referenceFill(const cv::Mat& d, int max_hole) {
  auto invalid = [&](int y, int x) { return std::isnan(d.at<float>(y, x)); };
  cv::Mat out = d.clone();
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      if (!invalid(y, x)) continue;
      int a = x, b = x;
      while (a > 0 && invalid(y, a - 1)) --a;
      while (b < d.cols - 1 && invalid(y, b + 1)) ++b;
      const bool h = a > 0 && b < d.cols - 1 && b - a + 1 <= max_hole;
      int t = y, u = y;
      while (t > 0 && invalid(t - 1, x)) --t;
      while (u < d.rows - 1 && invalid(u + 1, x)) ++u;
      const bool v = t > 0 && u < d.rows - 1 && u - t + 1 <= max_hole;
      if (!h && !v) continue;
      std::vector<float> n;
      for (int yy = std::max(0, y - 1); yy <= std::min(d.rows - 1, y + 1); ++yy) {
        for (int xx = std::max(0, x - 1); xx <= std::min(d.cols - 1, x + 1); ++xx) {
          if (!invalid(yy, xx)) n.push_back(d.at<float>(yy, xx));
        }
      }
      std::sort(n.begin(), n.end());
      out.at<float>(y, x) = n[(n.size() - 1) / 2];
    }
  }
  return out;
}

TEST(SmallHoles, MatchesThePlainRuleOnRandomMapsAcrossRowBlocks) {
  // Maps taller than several of the filter's row blocks (it works on blocks of rows in
  // parallel), with holes of 1-4 px in both directions, many of them straddling block edges,
  // and larger invalid areas; both hole limits; 1 and 2 threads.
  cv::RNG rng(11);
  for (int max_hole : {1, 2}) {
    for (int threads : {1, 2}) {
      cv::setNumThreads(threads);
      const int rows = 97 + rng.uniform(0, 40), cols = 50 + rng.uniform(0, 30);
      cv::Mat d(rows, cols, CV_32FC1);
      for (int y = 0; y < rows; ++y) {
        for (int x = 0; x < cols; ++x) d.at<float>(y, x) = 10.f + 0.5f * rng.uniform(0, 20);
      }
      for (int k = 0; k < 200; ++k) {  // short runs, vertical ones placed around row 32 * m
        const bool vertical = rng.uniform(0, 2) == 1;
        const int len = rng.uniform(1, 5);
        int y = rng.uniform(0, rows), x = rng.uniform(0, cols);
        if (vertical && rng.uniform(0, 2) == 1) {
          y = 32 * rng.uniform(1, rows / 32 + 1) - rng.uniform(0, 4);
        }
        for (int i = 0; i < len; ++i) {
          const int yy = vertical ? y + i : y, xx = vertical ? x : x + i;
          if (yy >= 0 && yy < rows && xx < cols) d.at<float>(yy, xx) = kNaN;
        }
      }
      for (int k = 0; k < 4; ++k) {  // larger invalid areas
        const int y = rng.uniform(0, rows - 8), x = rng.uniform(0, cols - 8);
        d(cv::Rect(x, y, 6, 7)).setTo(kNaN);
      }
      PostFilterParams p = paperFilter();
      p.fill_max_hole_px = max_hole;
      const cv::Mat expected = referenceFill(d, max_hole);
      cv::Mat got = d.clone(), code;
      const int64_t n = fillSmallHoles(got, code, p);
      int diff = 0, filled = 0;
      for (int y = 0; y < rows; ++y) {
        for (int x = 0; x < cols; ++x) {
          const float a = got.at<float>(y, x), b = expected.at<float>(y, x);
          diff += !(a == b || (std::isnan(a) && std::isnan(b)));
          filled += std::isnan(d.at<float>(y, x)) && !std::isnan(b);
        }
      }
      EXPECT_EQ(diff, 0) << "max_hole " << max_hole << " threads " << threads;
      EXPECT_EQ(n, filled);
      EXPECT_GT(filled, 50);  // the map does hold holes to fill
    }
  }
  cv::setNumThreads(-1);
}

TEST(SmallHoles, FillsOneAndTwoPixelHolesWithTheNeighbourMedian) {
  cv::Mat d = filled(7, 9, 10.f);
  d.at<float>(1, 2) = 30.f;  // a neighbour with another value
  d.at<float>(2, 2) = kNaN;  // a 1 px hole
  d.at<float>(5, 3) = kNaN;  // a 2 px horizontal hole
  d.at<float>(5, 4) = kNaN;
  cv::Mat code(7, 9, CV_8UC1, cv::Scalar(kCodeAcceptedBase));
  EXPECT_EQ(fillSmallHoles(d, code, paperFilter()), 3);
  EXPECT_EQ(d.at<float>(2, 2), 10.f);  // median of seven 10s and one 30
  EXPECT_EQ(d.at<float>(5, 3), 10.f);
  EXPECT_EQ(d.at<float>(5, 4), 10.f);
  EXPECT_EQ(code.at<uint8_t>(5, 4), kCodeFilled);
}

TEST(SmallHoles, LeavesThreePixelHolesAndHolesAtTheBorder) {
  cv::Mat d = filled(9, 9, 10.f);
  d(cv::Rect(2, 2, 3, 3)).setTo(kNaN);  // 3 x 3: 3 px wide both ways
  d.at<float>(7, 0) = kNaN;             // touches the left border: not bounded horizontally...
  d.at<float>(6, 0) = 10.f;             // ...but bounded vertically (1 px tall): filled
  d.at<float>(0, 8) = kNaN;             // corner: bounded neither way
  cv::Mat code;
  EXPECT_EQ(fillSmallHoles(d, code, paperFilter()), 1);
  EXPECT_EQ(cv::countNonZero(d(cv::Rect(2, 2, 3, 3)) == d(cv::Rect(2, 2, 3, 3))), 0);
  EXPECT_EQ(d.at<float>(7, 0), 10.f);
  EXPECT_TRUE(std::isnan(d.at<float>(0, 8)));
}

TEST(SmallHoles, EvenCountTakesTheLowerMiddleValue) {
  // Hole at a depth edge: neighbours 4 x 10 and 4 x 20 -> the lower middle, 10, never 15.
  cv::Mat d = filled(3, 3, 10.f);
  d.at<float>(0, 2) = d.at<float>(1, 2) = d.at<float>(2, 2) = 20.f;
  d.at<float>(0, 1) = 20.f;
  d.at<float>(1, 1) = kNaN;
  cv::Mat code;
  EXPECT_EQ(fillSmallHoles(d, code, paperFilter()), 1);
  EXPECT_EQ(d.at<float>(1, 1), 10.f);
}

TEST(SmallHoles, OnePixelLimitLeavesTwoPixelHoles) {
  cv::Mat d = filled(5, 6, 10.f);
  d.at<float>(2, 2) = d.at<float>(2, 3) = kNaN;
  d.at<float>(1, 2) = d.at<float>(1, 3) = kNaN;  // 2 x 2 hole
  PostFilterParams p = paperFilter();
  p.fill_max_hole_px = 1;
  cv::Mat code;
  EXPECT_EQ(fillSmallHoles(d, code, p), 0);
  p.fill_max_hole_px = 2;
  EXPECT_EQ(fillSmallHoles(d, code, p), 4);
}

TEST(PostFilterParams, ValidateNamesTheBadField) {
  PostFilterParams p;
  EXPECT_EQ(p.validate(), "");
  p.outlier_window_px = 4;
  EXPECT_NE(p.validate().find("outlier_window_px"), std::string::npos);
  p = PostFilterParams{};
  p.outlier_disparity_tol_px = 0.0;
  EXPECT_NE(p.validate().find("outlier_disparity_tol_px"), std::string::npos);
  p = PostFilterParams{};
  p.outlier_min_share = 1.5;
  EXPECT_NE(p.validate().find("outlier_min_share"), std::string::npos);
  p = PostFilterParams{};
  p.fill_max_hole_px = 3;
  EXPECT_NE(p.validate().find("fill_max_hole_px"), std::string::npos);
}

TEST(PostFilter, RejectsWrongTypes) {
  cv::Mat d(4, 4, CV_64FC1, cv::Scalar(1));
  cv::Mat code;
  EXPECT_THROW(removeIsolatedOutliers(d, code, PostFilterParams{}), std::invalid_argument);
  EXPECT_THROW(fillSmallHoles(d, code, PostFilterParams{}), std::invalid_argument);
  cv::Mat f(4, 4, CV_32FC1, cv::Scalar(1));
  cv::Mat bad_code(3, 3, CV_8UC1);
  EXPECT_THROW(fillSmallHoles(f, bad_code, PostFilterParams{}), std::invalid_argument);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
