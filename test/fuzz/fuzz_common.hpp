/**
 * @file fuzz_common.hpp
 * @brief Shared decoding for the libFuzzer harnesses of endo_stereo (built by scripts/fuzz.sh).
 *
 * The harnesses turn the fuzzer's bytes into core inputs with FuzzedDataProvider: parameters are
 * decoded through params_io's key list (so every field of every params struct is reachable and a
 * new field is fuzzed without touching this file), images get any size, OpenCV type, encoding name
 * and content, calibrations get any value including zero, negative, NaN and huge ones.
 *
 * A harness reports a contract violation with ES_FUZZ_CHECK, which prints what was violated and
 * aborts, so libFuzzer records the input as a crash. Only the documented failure modes (a false
 * return with a message, std::invalid_argument where the API documents it) are accepted.
 */
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <limits>
#include <string>
#include <vector>

#include <fuzzer/FuzzedDataProvider.h>
#include <opencv2/core.hpp>

#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"

#define ES_FUZZ_CHECK(cond, msg)                                                       \
  do {                                                                                 \
    if (!(cond)) {                                                                     \
      std::fprintf(stderr, "ES_FUZZ_CHECK failed at %s:%d: %s: %s\n", __FILE__,       \
                   __LINE__, #cond, std::string(msg).c_str());                         \
      std::abort();                                                                    \
    }                                                                                  \
  } while (0)

/// Run @p stmt; any exception is a contract violation reported with its message.
#define ES_FUZZ_NO_THROW(stmt, label)                                                    \
  do {                                                                                  \
    try {                                                                               \
      stmt;                                                                             \
    } catch (const std::exception& ex__) {                                              \
      ES_FUZZ_CHECK(false, std::string(label) + " threw: " + ex__.what());              \
    } catch (...) {                                                                     \
      ES_FUZZ_CHECK(false, std::string(label) + " threw a non-std exception");          \
    }                                                                                   \
  } while (0)

namespace endo_stereo {
namespace fuzz {

/// Largest image side a harness builds: keeps one execution in the millisecond range on purpose,
/// the bugs of interest (sizes, borders, ranges, NaN) show on small images.
constexpr int kMaxSide = 48;

/// A double from a palette of the values that break arithmetic, or any double.
inline double interestingDouble(FuzzedDataProvider& fdp) {
  static const double kPalette[] = {0.0,
                                    -0.0,
                                    1.0,
                                    -1.0,
                                    0.5,
                                    2.0,
                                    1e-12,
                                    -1e-12,
                                    1e12,
                                    -1e12,
                                    std::numeric_limits<double>::quiet_NaN(),
                                    std::numeric_limits<double>::infinity(),
                                    -std::numeric_limits<double>::infinity(),
                                    std::numeric_limits<double>::max(),
                                    std::numeric_limits<double>::denorm_min(),
                                    2147483648.0};
  if (fdp.ConsumeBool()) return fdp.PickValueInArray(kPalette);
  return fdp.ConsumeFloatingPoint<double>();
}

/// An int near the usual parameter values, or at the extremes.
inline int interestingInt(FuzzedDataProvider& fdp) {
  switch (fdp.ConsumeIntegralInRange<int>(0, 3)) {
    case 0: return fdp.ConsumeIntegralInRange<int>(-3, 8);
    case 1: return fdp.ConsumeIntegralInRange<int>(-70, 70);
    case 2: {
      static const int kPalette[] = {std::numeric_limits<int>::min(),
                                     std::numeric_limits<int>::max(), -1000000, 1000000, 65535,
                                     65536, 32767, -32768, 1 << 20};
      return fdp.PickValueInArray(kPalette);
    }
    default: return fdp.ConsumeIntegral<int>();
  }
}

/// Text for one parameter of type @p info.type (sometimes garbage, to reach the parse errors).
inline std::string valueText(FuzzedDataProvider& fdp, const ParamInfo& info) {
  if (fdp.ConsumeIntegralInRange<int>(0, 15) == 0) return fdp.ConsumeRandomLengthString(12);
  switch (info.type) {
    case ParamType::kBool: return fdp.ConsumeBool() ? "true" : "false";
    case ParamType::kInt: return std::to_string(interestingInt(fdp));
    case ParamType::kDouble: {
      const double v = interestingDouble(fdp);
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.17g", v);
      return buf;
    }
    case ParamType::kString:
    default:
      if (!info.choices.empty()) {
        return info.choices[fdp.ConsumeIntegralInRange<size_t>(0, info.choices.size() - 1)];
      }
      return fdp.ConsumeRandomLengthString(12);
  }
}

/// Largest matcher.num_threads a harness lets through to RobustMatcher::compute().
constexpr int kMaxFuzzThreads = 4;

/// matcher.num_threads goes to the process-wide cv::setNumThreads() for the duration of
/// compute(). With Debian's OpenCV 4.6 on oneTBB, setting it back after a value above 65536
/// segfaults inside libtbbmalloc (in any build: reproduced without sanitizers, see
/// test/fuzz/regressions/matcher/num_threads_over_65536), and every large value builds a TBB
/// arena with that many slots (1.2 GB peak RSS under ASan). MatcherParams::validate() has no upper
/// bound for it yet (reported to the matcher's owner), so the harnesses map a value above
/// kMaxFuzzThreads to 1..kMaxFuzzThreads (the output does not depend on it); negative values are
/// left alone for the validate() checks. Once validate() bounds it, a unit test covers the bound.
inline void boundThreadCount(PipelineParams& params) {
  int& n = params.matcher.num_threads;
  if (n > kMaxFuzzThreads) n = 1 + n % kMaxFuzzThreads;
}

/// Apply up to @p max_edits parameter edits decoded from the input (through params_io, so a bad
/// value is rejected by setPipelineParam and only well-typed values reach the structs).
inline void fuzzParams(FuzzedDataProvider& fdp, PipelineParams& params, int max_edits) {
  const std::vector<ParamInfo> infos = listPipelineParams(params);
  if (infos.empty()) return;
  const int edits = fdp.ConsumeIntegralInRange<int>(0, max_edits);
  for (int i = 0; i < edits && fdp.remaining_bytes() > 0; ++i) {
    const ParamInfo& info = infos[fdp.ConsumeIntegralInRange<size_t>(0, infos.size() - 1)];
    setPipelineParam(params, info.key, valueText(fdp, info));  // an error keeps the old value
  }
  boundThreadCount(params);
}

/// OpenCV types an image may arrive in (the supported ones and a few that are not).
inline int pickCvType(FuzzedDataProvider& fdp) {
  static const int kTypes[] = {CV_8UC1, CV_8UC1,  CV_8UC3,  CV_8UC3, CV_8UC4, CV_16UC1,
                               CV_8UC2, CV_16UC3, CV_32FC1, CV_16SC1, CV_8SC1, CV_64FC3};
  return fdp.PickValueInArray(kTypes);
}

/// Encoding names: the supported ones, near misses, and whatever the input spells.
inline std::string pickEncoding(FuzzedDataProvider& fdp) {
  static const char* kEncodings[] = {"",       "mono8",  "mono16",      "bgr8",       "rgb8",
                                     "bgra8",  "rgba8",  "yuv422",      "bayer_rggb8", "32FC1",
                                     "16UC1",  "8UC3",   "MONO8",       "bgr16",      "uyvy",
                                     "yuv422_yuy2", "rgb16", "mono8 "};
  if (fdp.ConsumeIntegralInRange<int>(0, 20) == 0) return fdp.ConsumeRandomLengthString(10);
  return fdp.PickValueInArray(kEncodings);
}

/// An image of @p size and @p type whose content is textured (so the matcher gets past its
/// criteria) or taken from the input, with NaN/inf sprinkled into float images.
inline cv::Mat makeImage(FuzzedDataProvider& fdp, cv::Size size, int type) {
  if (size.width <= 0 || size.height <= 0) return cv::Mat();
  cv::Mat img(size, type);
  const int content = fdp.ConsumeIntegralInRange<int>(0, 3);
  cv::RNG rng(fdp.ConsumeIntegral<uint32_t>() | 1u);
  if (content == 0) {
    img.setTo(cv::Scalar::all(fdp.ConsumeIntegralInRange<int>(0, 255)));  // textureless
  } else if (content == 1 || fdp.remaining_bytes() == 0) {
    rng.fill(img, cv::RNG::UNIFORM, cv::Scalar::all(0), cv::Scalar::all(256));
  } else {
    // Bytes from the input, repeated to fill the image.
    const std::vector<uint8_t> bytes = fdp.ConsumeBytes<uint8_t>(
        fdp.ConsumeIntegralInRange<size_t>(1, 256));
    const size_t n = img.total() * img.elemSize();
    uint8_t* dst = img.ptr<uint8_t>();
    for (size_t i = 0; i < n; ++i) dst[i] = bytes.empty() ? 0 : bytes[i % bytes.size()];
  }
  if (img.depth() == CV_32F && fdp.ConsumeBool()) {
    img.ptr<float>()[0] = std::numeric_limits<float>::quiet_NaN();
  } else if (img.depth() == CV_64F && fdp.ConsumeBool()) {
    img.ptr<double>()[0] = std::numeric_limits<double>::infinity();
  }
  return img;
}

/// A right image: the left one shifted by a disparity (a matchable pair) or an independent one.
inline cv::Mat makeRight(FuzzedDataProvider& fdp, const cv::Mat& left, cv::Size size, int type) {
  if (!left.empty() && left.size() == size && left.type() == type && fdp.ConsumeBool()) {
    const int shift = fdp.ConsumeIntegralInRange<int>(-8, 24);
    cv::Mat right(left.size(), left.type(), cv::Scalar::all(0));
    for (int y = 0; y < left.rows; ++y) {
      for (int x = 0; x < left.cols; ++x) {
        const int xs = x + shift;  // x_right = x_left - d
        if (xs >= 0 && xs < left.cols) {
          std::memcpy(right.ptr(y, x), left.ptr(y, xs), left.elemSize());
        }
      }
    }
    return right;
  }
  return makeImage(fdp, size, type);
}

/// Image size: mostly small and sane, sometimes empty, 1xN, odd.
inline cv::Size pickSize(FuzzedDataProvider& fdp) {
  return cv::Size(fdp.ConsumeIntegralInRange<int>(0, kMaxSide),
                  fdp.ConsumeIntegralInRange<int>(0, kMaxSide));
}

/// One camera of a calibration for an image of about @p size, with any value broken.
inline CameraCalibration makeCamera(FuzzedDataProvider& fdp, cv::Size size, double tx) {
  CameraCalibration c;
  const bool sane = fdp.ConsumeBool();
  c.width = sane ? size.width : interestingInt(fdp);
  c.height = sane ? size.height : interestingInt(fdp);
  const double f = sane ? fdp.ConsumeFloatingPointInRange<double>(5.0, 200.0) : interestingDouble(fdp);
  const double cx = sane ? size.width / 2.0 : interestingDouble(fdp);
  const double cy = sane ? size.height / 2.0 : interestingDouble(fdp);
  c.K = cv::Matx33d(f, 0, cx, 0, f, cy, 0, 0, 1);
  c.distortion_model = fdp.ConsumeBool() ? "plumb_bob" : fdp.ConsumeBool() ? "equidistant" : "";
  const int nd = fdp.ConsumeIntegralInRange<int>(0, 8);
  for (int i = 0; i < nd; ++i) c.D.push_back(sane ? fdp.ConsumeFloatingPointInRange<double>(-0.2, 0.2)
                                                  : interestingDouble(fdp));
  if (fdp.ConsumeBool()) c.P = cv::Matx34d(f, 0, cx, tx, 0, f, cy, 0, 0, 0, 1, 0);
  if (!sane && fdp.ConsumeBool()) c.R(fdp.ConsumeIntegralInRange<int>(0, 2),
                                      fdp.ConsumeIntegralInRange<int>(0, 2)) = interestingDouble(fdp);
  if (!sane && fdp.ConsumeBool()) {
    c.binning_x = interestingInt(fdp);
    c.binning_y = interestingInt(fdp);
  }
  if (!sane && fdp.ConsumeBool()) {
    c.roi = cv::Rect(interestingInt(fdp), interestingInt(fdp), interestingInt(fdp),
                     interestingInt(fdp));
  }
  c.frame_id = fdp.ConsumeBool() ? "left_optical" : fdp.ConsumeRandomLengthString(8);
  return c;
}

/// A stereo calibration with any value broken (zero, negative or NaN baseline included).
inline StereoCalibration makeCalibration(FuzzedDataProvider& fdp, cv::Size size) {
  StereoCalibration s;
  const double f = 100.0;
  const double baseline = fdp.ConsumeBool() ? 0.005 : interestingDouble(fdp);
  s.left = makeCamera(fdp, size, 0.0);
  s.right = makeCamera(fdp, size, -f * baseline);
  if (fdp.ConsumeBool()) {
    s.has_extrinsics = true;
    s.T_right_left = cv::Vec3d(-baseline, fdp.ConsumeBool() ? 0.0 : interestingDouble(fdp), 0.0);
  }
  return s;
}

/**
 * Checks of a successful process() result that hold for any input: sizes and types agree,
 * disparities lie in the searched range (1 px of sub-pixel and median slack), confidences in
 * [0, 1], the cloud is organized like the disparity.
 */
inline void checkOutput(const PipelineParams& params, const PipelineOutput& out) {
  const cv::Mat& d = out.match.disparity;
  ES_FUZZ_CHECK(d.type() == CV_32FC1, "disparity type");
  ES_FUZZ_CHECK(d.size() == out.left_rect_gray.size(), "disparity size != rectified size");
  ES_FUZZ_CHECK(out.match.code.size() == d.size() && out.match.code.type() == CV_8UC1, "code map");
  ES_FUZZ_CHECK(out.match.confidence.empty() || out.match.confidence.size() == d.size(),
                "confidence size");
  const double lo = params.matcher.min_disparity - 1.0, hi = params.matcher.max_disparity + 1.0;
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const float v = d.at<float>(y, x);
      if (std::isnan(v)) continue;
      ES_FUZZ_CHECK(std::isfinite(v) && v >= lo && v <= hi,
                    "disparity " + std::to_string(v) + " outside the searched range");
      if (!out.match.confidence.empty()) {
        const float c = out.match.confidence.at<float>(y, x);
        ES_FUZZ_CHECK(c >= 0.f && c <= 1.f, "confidence outside [0,1]");
      }
    }
  }
  if (params.output.point_cloud) {
    ES_FUZZ_CHECK(out.cloud.xyz.size() == d.size(), "cloud not organized like the disparity");
  }
}

}  // namespace fuzz
}  // namespace endo_stereo
