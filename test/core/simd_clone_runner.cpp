// One build of the matcher per SIMD clone (see simd_clone_runner.hpp). This file is compiled with
// the matcher's sources into each clone's library; `endo_stereo` below is renamed per clone.
#include "simd_clone_runner.hpp"

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {

CloneTestOutput runMatcherForCloneTest(const cv::Mat& left, const cv::Mat& right, const cv::Mat& lo,
                                       const cv::Mat& hi, int threads) {
  MatcherParams mp;  // the default preset: depth-edge filter and its second chance on
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

}  // namespace endo_stereo
