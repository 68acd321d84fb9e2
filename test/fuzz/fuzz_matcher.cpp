// libFuzzer harness: endo_stereo::RobustMatcher::compute() on rectified pairs of any size, type
// and content, with any matcher / post-filter parameters and any per-pixel search range (including
// ranges outside the image, inverted, or of the wrong size or type), then the two post-filters on
// a disparity holding NaN and inf.
//
// Contract checked (matcher.hpp): the constructor and setParams() throw std::invalid_argument
// exactly when validate() fails; compute() throws only std::invalid_argument (bad type / size /
// range); a result is consistent (sizes, types, disparities inside the searched range).
#include <stdexcept>

#include "fuzz_common.hpp"

using namespace endo_stereo;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider fdp(data, size);
  cv::setNumThreads(1);

  PipelineParams params;
  params.matcher.max_disparity = 15;
  fuzz::fuzzParams(fdp, params, 6);
  const long range = static_cast<long>(params.matcher.max_disparity) - params.matcher.min_disparity;
  if (range > 4 * fuzz::kMaxSide || params.matcher.window_max_px > 2 * fuzz::kMaxSide) return 0;

  const bool valid = params.matcher.validate().empty() && params.filter.validate().empty();
  std::unique_ptr<RobustMatcher> matcher;
  try {
    matcher = std::make_unique<RobustMatcher>(params.matcher, params.filter);
  } catch (const std::invalid_argument&) {
    ES_FUZZ_CHECK(!valid, "constructor threw for valid params");
    return 0;
  }
  ES_FUZZ_CHECK(valid, "constructor accepted invalid params");

  const cv::Size image_size = fuzz::pickSize(fdp);
  const int type = fdp.ConsumeIntegralInRange<int>(0, 5) == 0 ? fuzz::pickCvType(fdp) : CV_8UC1;
  const cv::Mat left = fuzz::makeImage(fdp, image_size, type);
  const bool same = fdp.ConsumeIntegralInRange<int>(0, 7) != 0;
  const cv::Mat right = fuzz::makeRight(fdp, left, same ? image_size : fuzz::pickSize(fdp), type);

  SearchRange search;
  const bool use_range = fdp.ConsumeBool();
  if (use_range) {
    cv::Size rs = image_size;
    int rtype = CV_16SC1;
    if (fdp.ConsumeIntegralInRange<int>(0, 7) == 0) rs = fuzz::pickSize(fdp);
    if (fdp.ConsumeIntegralInRange<int>(0, 7) == 0) rtype = fuzz::pickCvType(fdp);
    if (rs.area() > 0) {
      search.lo.create(rs, rtype);
      search.hi.create(rs, rtype);
      cv::RNG rng(fdp.ConsumeIntegral<uint32_t>() | 1u);
      const int a = fdp.ConsumeIntegralInRange<int>(-100, 100);
      const int b = fdp.ConsumeIntegralInRange<int>(-100, 100);
      rng.fill(search.lo, cv::RNG::UNIFORM, cv::Scalar::all(std::min(a, b)),
               cv::Scalar::all(std::max(a, b) + 1));
      rng.fill(search.hi, cv::RNG::UNIFORM, cv::Scalar::all(std::min(a, b)),
               cv::Scalar::all(std::max(a, b) + 1));
    }
  }

  MatchResult result;
  bool computed = false;
  try {
    matcher->compute(left, right, result, use_range ? &search : nullptr);
    computed = true;
  } catch (const std::invalid_argument&) {
    // Documented for empty input, a type or size mismatch.
  }
  if (computed) {
    ES_FUZZ_CHECK(!left.empty() && left.type() == CV_8UC1 && left.size() == right.size() &&
                      right.type() == CV_8UC1,
                  "compute() accepted an empty, mistyped or mismatched pair");
    PipelineOutput out;
    out.match = result;
    out.left_rect_gray = left;
    PipelineParams checked = params;
    checked.output.point_cloud = false;
    fuzz::checkOutput(checked, out);
  }

  // Post-filters on their own, on a disparity with NaN and inf.
  if (image_size.area() > 0 && params.filter.validate().empty()) {
    cv::Mat disparity(image_size, CV_32FC1);
    cv::RNG rng(fdp.ConsumeIntegral<uint32_t>() | 1u);
    rng.fill(disparity, cv::RNG::UNIFORM, cv::Scalar(-5), cv::Scalar(40));
    const int specials = fdp.ConsumeIntegralInRange<int>(0, 20);
    for (int i = 0; i < specials; ++i) {
      const int idx = fdp.ConsumeIntegralInRange<int>(0, static_cast<int>(image_size.area()) - 1);
      disparity.at<float>(idx) = static_cast<float>(fuzz::interestingDouble(fdp));
    }
    cv::Mat code = fdp.ConsumeBool() ? cv::Mat(image_size, CV_8UC1, cv::Scalar(16)) : cv::Mat();
    try {
      removeIsolatedOutliers(disparity, code, params.filter);
      fillSmallHoles(disparity, code, params.filter);
    } catch (const std::invalid_argument&) {
    }
  }
  return 0;
}
