// A downstream program: matches a generated pair (random texture, the right view shifted by a
// known disparity) with endo_stereo's matcher, scores it with its evaluation library, and exits
// 0 only when the result is right (most pixels matched, none more than 1 px off).
#include <cstdio>
#include <endo_stereo/core/evaluation.hpp>
#include <endo_stereo/core/matcher.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

int main() {
  const int width = 160, height = 120, shift = 9;
  cv::Mat wide(height, width + shift, CV_8UC1);
  cv::RNG rng(7);
  rng.fill(wide, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(wide, wide, cv::Size(3, 3), 0.8);
  // left(x) = wide(x), right(x) = wide(x + shift): right(x - shift) = left(x), disparity = shift.
  const cv::Mat left = wide.colRange(0, width).clone();
  const cv::Mat right = wide.colRange(shift, shift + width).clone();
  endo_stereo::MatcherParams mp;
  mp.min_disparity = 0;
  mp.max_disparity = 31;
  endo_stereo::RobustMatcher matcher(mp, endo_stereo::PostFilterParams{});
  endo_stereo::MatchResult result;
  matcher.compute(left, right, result);
  const cv::Mat truth(height, width, CV_32FC1, cv::Scalar(shift));
  // Only pixels whose match lies inside the right view.
  cv::Mat mask(height, width, CV_8UC1, cv::Scalar(0));
  mask.colRange(shift, width).setTo(255);
  const endo_stereo::DisparityScore score =
      endo_stereo::scoreDisparity(result.disparity, truth, mask);
  std::printf("downstream_match: density %.3f, pixels off by more than 1 px: %lld\n", score.density,
              static_cast<long long>(score.n_bad1));
  return score.density > 0.8 && score.n_bad1 == 0 ? 0 : 1;
}
