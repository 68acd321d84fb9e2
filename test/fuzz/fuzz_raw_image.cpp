// libFuzzer harness: raw sensor_msgs/Image-style buffers (preprocess.hpp wrapRawImage) with any
// width, height, step, encoding, endianness and a buffer that may be truncated, then the
// conversion and pre-processing of what was accepted, with any pre-processing parameters.
//
// Contract checked: wrapRawImage accepts a buffer only when it holds height rows of step bytes with
// step >= width * bytes per pixel, and returns an image of exactly width x height; conversion and
// pre-processing never throw and report failures with a message; their outputs are CV_8UC1 /
// CV_8UC3 of the documented size.
#include <stdexcept>

#include "fuzz_common.hpp"

using namespace endo_stereo;

namespace {

// Conversion and pre-processing of an accepted image, with their output contracts.
void convertAll(const cv::Mat& raw, const std::string& encoding, const PreprocessParams& pp,
                cv::Mat& gray, cv::Mat& bgr) {
  std::string error;
  // convertImage() shifts by mono16_bits - 8 and its callers pass validated params
  // (PreprocessParams: 8..16); an out-of-range value found here (shift exponent 2147418282, UB)
  // is reported to the owner as a missing check, and the harness keeps to the documented range.
  const int bits = pp.mono16_bits >= 8 && pp.mono16_bits <= 16 ? pp.mono16_bits : 16;
  if (convertImage(raw, encoding, bits, gray, &bgr, &error)) {
    ES_FUZZ_CHECK(gray.type() == CV_8UC1 && gray.size() == raw.size(), "gray output");
    ES_FUZZ_CHECK(bgr.type() == CV_8UC3 && bgr.size() == raw.size(), "colour output");
  } else {
    ES_FUZZ_CHECK(!error.empty(), "convertImage failed without a message");
  }
  if (pp.validate().empty()) {
    if (preprocessImage(raw, encoding, pp, gray, &bgr, &error)) {
      ES_FUZZ_CHECK(gray.type() == CV_8UC1 && bgr.type() == CV_8UC3 && gray.size() == bgr.size(),
                    "pre-processed outputs disagree");
      ES_FUZZ_CHECK(gray.size() == preprocessedSize(raw.size(), pp),
                    "pre-processed size differs from preprocessedSize()");
    } else {
      ES_FUZZ_CHECK(!error.empty(), "preprocessImage failed without a message");
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider fdp(data, size);
  cv::setNumThreads(1);
  const int width = fdp.ConsumeIntegralInRange<int>(-2, 40);
  const int height = fdp.ConsumeIntegralInRange<int>(-2, 40);
  const std::string encoding = fuzz::pickEncoding(fdp);
  const bool big_endian = fdp.ConsumeBool();
  size_t step = 0;
  switch (fdp.ConsumeIntegralInRange<int>(0, 3)) {
    case 0: step = static_cast<size_t>(std::max(width, 0)) * 1; break;
    case 1: step = static_cast<size_t>(std::max(width, 0)) * 3; break;
    case 2: step = fdp.ConsumeIntegralInRange<size_t>(0, 200); break;
    default: step = fdp.ConsumeIntegral<size_t>(); break;  // absurd strides, overflow bait
  }
  PipelineParams params;
  fuzz::fuzzParams(fdp, params, 4);
  const std::vector<uint8_t> buffer = fdp.ConsumeRemainingBytes<uint8_t>();

  cv::Mat raw;
  std::string error;
  bool ok = false;
  ES_FUZZ_NO_THROW(ok = wrapRawImage(buffer.data(), buffer.size(), width, height, step, encoding,
                                     big_endian, raw, &error),
                   "wrapRawImage");
  if (!ok) {
    ES_FUZZ_CHECK(!error.empty(), "wrapRawImage failed without a message");
    return 0;
  }
  ES_FUZZ_CHECK(width > 0 && height > 0, "accepted a non-positive size");
  ES_FUZZ_CHECK(raw.cols == width && raw.rows == height, "wrapped image has the wrong size");
  const size_t row_bytes = static_cast<size_t>(width) * raw.elemSize();
  ES_FUZZ_CHECK(step >= row_bytes, "accepted a step shorter than a row");
  size_t needed = 0;  // step * (height - 1) + row_bytes, without wrapping around
  const bool wraps = __builtin_mul_overflow(step, static_cast<size_t>(height - 1), &needed) ||
                     __builtin_add_overflow(needed, row_bytes, &needed);
  ES_FUZZ_CHECK(!wraps && buffer.size() >= needed, "accepted a truncated buffer");

  cv::Mat gray, bgr;
  ES_FUZZ_NO_THROW(convertAll(raw, encoding, params.preprocess, gray, bgr), "conversion");
  return 0;
}
