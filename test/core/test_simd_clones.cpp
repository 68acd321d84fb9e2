// The matcher's kernels are built for x86-64-v4 (AVX-512), AVX2 and the baseline, and the library
// picks one at load time (simd.hpp). The core builds with -ffp-contract=off so that all of them
// round alike (v4 has FMA). This test builds the whole matcher once per clone (each in its own
// namespace, CMakeLists.txt), runs each on the same inputs, and requires the same disparity,
// code and confidence bits from every clone and from the dispatched library.
#include <gtest/gtest.h>

#include <cstring>
#include <opencv2/core/utility.hpp>

#include "endo_stereo/core/matcher.hpp"
#include "simd_clone_runner.hpp"
#include "synthetic_scene.hpp"

ES_DECLARE_CLONE_RUNNER(endo_stereo_clone_baseline)
ES_DECLARE_CLONE_RUNNER(endo_stereo_clone_avx2)
ES_DECLARE_CLONE_RUNNER(endo_stereo_clone_v4)

namespace endo_stereo {
namespace {

bool cpuHasAvx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2");
}

bool cpuHasX86_64V4() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
         __builtin_cpu_supports("avx512cd") && __builtin_cpu_supports("avx512dq") &&
         __builtin_cpu_supports("avx512vl");
}

/// Number of pixels whose bits differ in any of the three outputs.
int differingPixels(const CloneTestOutput& a, const CloneTestOutput& b) {
  int n = 0;
  for (int y = 0; y < a.code.rows; ++y) {
    for (int x = 0; x < a.code.cols; ++x) {
      const bool same =
          a.code.at<uint8_t>(y, x) == b.code.at<uint8_t>(y, x) &&
          std::memcmp(&a.disparity.at<float>(y, x), &b.disparity.at<float>(y, x), 4) == 0 &&
          std::memcmp(&a.confidence.at<float>(y, x), &b.confidence.at<float>(y, x), 4) == 0;
      n += !same;
    }
  }
  return n;
}

CloneTestOutput dispatched(const cv::Mat& left, const cv::Mat& right, const cv::Mat& lo,
                           const cv::Mat& hi, int threads) {
  MatcherParams mp;
  mp.min_disparity = 0;
  mp.max_disparity = 47;
  mp.num_threads = threads;
  RobustMatcher matcher(mp, PostFilterParams{});
  MatchResult r;
  SearchRange range;
  range.lo = lo;
  range.hi = hi;
  matcher.compute(left, right, r, lo.empty() ? nullptr : &range);
  return CloneTestOutput{r.disparity, r.code, r.confidence};
}

// The baseline clone's output on a scene, checked to be non-trivial (most pixels matched, some
// rejected), so that agreeing with it means something.
CloneTestOutput baselineOutput(const SyntheticScene& s, const cv::Mat& lo, const cv::Mat& hi) {
  const CloneTestOutput base =
      endo_stereo_clone_baseline::runMatcherForCloneTest(s.left, s.right, lo, hi, 2);
  const int valid = cv::countNonZero(base.code >= static_cast<int>(kCodeAcceptedBase));
  EXPECT_GT(valid, static_cast<int>(s.left.total() / 2));
  EXPECT_LT(valid, static_cast<int>(s.left.total()));
  return base;
}

SyntheticScene scene() {
  SyntheticSceneParams sp;
  sp.width = 200;
  sp.height = 150;
  sp.base_disparity_px = 14;
  sp.slope_x = 0.04;
  sp.curvature = 0.0004;
  sp.noise_stdev = 3.0;
  sp.texture_stdev = 20.0;
  sp.occluder = cv::Rect(70, 40, 50, 60);  // depth edges: the depth-edge filter acts
  sp.occluder_disparity_px = 30;
  sp.textureless = cv::Rect(150, 100, 30, 30);  // larger windows
  return makeSyntheticScene(sp);
}

// +-4 around the truth with an offset (some miss it), one in four the full range.
void perPixelRanges(const SyntheticScene& s, cv::Mat* lo, cv::Mat* hi) {
  lo->create(s.left.size(), CV_16SC1);
  hi->create(s.left.size(), CV_16SC1);
  cv::RNG rng(5);
  for (int y = 0; y < s.left.rows; ++y) {
    for (int x = 0; x < s.left.cols; ++x) {
      const int g = static_cast<int>(std::lround(s.disparity.at<float>(y, x))) + rng.uniform(-2, 3);
      const bool full = rng.uniform(0, 4) == 0;
      lo->at<int16_t>(y, x) = static_cast<int16_t>(full ? 0 : g - 4);
      hi->at<int16_t>(y, x) = static_cast<int16_t>(full ? 47 : g + 4);
    }
  }
}

// One test per clone and search kind, so that a clone this CPU cannot run is a skip that names
// the missing instruction set (the test runner accepts a skip only when it says what is absent).
class SimdClones : public ::testing::TestWithParam<bool> {  // true: per-pixel ranges
 protected:
  void SetUp() override {
    s_ = scene();
    if (GetParam()) perPixelRanges(s_, &lo_, &hi_);
  }
  SyntheticScene s_;
  cv::Mat lo_, hi_;
};

TEST_P(SimdClones, DispatchedLibraryMatchesTheBaselineClone) {
  const CloneTestOutput base = baselineOutput(s_, lo_, hi_);
  EXPECT_EQ(differingPixels(base, dispatched(s_.left, s_.right, lo_, hi_, 2)), 0);
}

TEST_P(SimdClones, Avx2CloneMatchesTheBaselineClone) {
  if (!cpuHasAvx2()) GTEST_SKIP() << "absent: AVX2 on this CPU, the AVX2 clone cannot run";
  const CloneTestOutput base = baselineOutput(s_, lo_, hi_);
  EXPECT_EQ(differingPixels(
                base, endo_stereo_clone_avx2::runMatcherForCloneTest(s_.left, s_.right, lo_, hi_, 1)),
            0);
}

TEST_P(SimdClones, Avx512CloneMatchesTheBaselineClone) {
  if (!cpuHasX86_64V4()) {
    GTEST_SKIP() << "absent: AVX-512 (x86-64-v4) on this CPU, the AVX-512 clone cannot run";
  }
  const CloneTestOutput base = baselineOutput(s_, lo_, hi_);
  EXPECT_EQ(differingPixels(
                base, endo_stereo_clone_v4::runMatcherForCloneTest(s_.left, s_.right, lo_, hi_, 1)),
            0);
}

INSTANTIATE_TEST_SUITE_P(Search, SimdClones, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& i) {
                           return std::string(i.param ? "PerPixelRanges" : "FullRange");
                         });

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
