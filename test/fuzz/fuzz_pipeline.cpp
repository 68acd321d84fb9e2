// libFuzzer harness: endo_stereo::Pipeline::process() on pairs of any size, OpenCV type, encoding
// and content, any parameters, any calibration, and stamps that go back, repeat or are NaN, over a
// few frames (so the temporal state and parameter swaps between frames are exercised).
//
// Contract checked (pipeline.hpp): process() never throws, returns false with a non-empty message
// for bad input, and its successful outputs are consistent (fuzz::checkOutput). The constructor and
// setParams() throw std::invalid_argument exactly when validate() is not empty.
#include <stdexcept>

#include "fuzz_common.hpp"

using namespace endo_stereo;

namespace {

// Only parameter sets that keep one execution short: the fuzzer looks for wrong handling, not for
// the (documented, linear) cost of a huge search range or SIFT budget on a 48x48 image.
bool affordable(const PipelineParams& p) {
  const long range = static_cast<long>(p.matcher.max_disparity) - p.matcher.min_disparity;
  return range <= 4 * fuzz::kMaxSide && p.matcher.window_max_px <= 2 * fuzz::kMaxSide &&
         p.rectify.sift_features <= 4000 && p.rectify.quality_max_features <= 4000 &&
         p.rectify.output_width_px <= 4 * fuzz::kMaxSide &&
         p.rectify.output_height_px <= 4 * fuzz::kMaxSide && p.rectify.output_scale_x <= 4.0 &&
         p.rectify.output_scale_y <= 4.0 && p.rectify.estimation_frames <= 10;
}

void checkConstruction(const PipelineParams& p, bool threw) {
  const std::string v = p.validate();
  ES_FUZZ_CHECK(threw == !v.empty(), threw ? "threw for valid params" : "accepted: " + v);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider fdp(data, size);
  cv::setNumThreads(1);

  PipelineParams params;
  params.matcher.max_disparity = 15;  // small default range: one execution stays fast
  params.rectify.mode = fdp.PickValueInArray(
      {RectifyMode::kPassThrough, RectifyMode::kCalibrated, RectifyMode::kUncalibrated});
  params.rectify.focal_px = 100.0;
  params.rectify.baseline_m = 0.005;
  fuzz::fuzzParams(fdp, params, 6);
  if (!affordable(params)) return 0;

  std::unique_ptr<Pipeline> pipeline;
  try {
    pipeline = std::make_unique<Pipeline>(params);
    checkConstruction(params, false);
  } catch (const std::invalid_argument&) {
    checkConstruction(params, true);
    return 0;
  }

  cv::Size image_size = fuzz::pickSize(fdp);
  if (fdp.ConsumeBool()) {
    const std::string err = pipeline->setCalibration(fuzz::makeCalibration(fdp, image_size));
    (void)err;  // refusing a broken calibration is fine; it must not crash
  }

  double stamp = fdp.ConsumeFloatingPointInRange<double>(0.0, 1e6);
  PipelineOutput out;
  const int frames = fdp.ConsumeIntegralInRange<int>(1, 4);
  for (int f = 0; f < frames && fdp.remaining_bytes() > 0; ++f) {
    if (f > 0 && fdp.ConsumeIntegralInRange<int>(0, 3) == 0) {
      // A reconfigure between two frames (the nodelet's path).
      PipelineParams next = pipeline->params();
      fuzz::fuzzParams(fdp, next, 3);
      if (affordable(next)) {
        bool threw = false;
        try {
          pipeline->setParams(next);
        } catch (const std::invalid_argument&) {
          threw = true;
        }
        checkConstruction(next, threw);
      }
    }
    if (f > 0 && fdp.ConsumeIntegralInRange<int>(0, 3) == 0) image_size = fuzz::pickSize(fdp);

    StereoInput in;
    const int left_type = fuzz::pickCvType(fdp);
    const bool same = fdp.ConsumeIntegralInRange<int>(0, 7) != 0;
    const int right_type = same ? left_type : fuzz::pickCvType(fdp);
    const cv::Size right_size = same ? image_size : fuzz::pickSize(fdp);
    in.left = fuzz::makeImage(fdp, image_size, left_type);
    in.right = fuzz::makeRight(fdp, in.left, right_size, right_type);
    in.left_encoding = fuzz::pickEncoding(fdp);
    in.right_encoding = same ? in.left_encoding : fuzz::pickEncoding(fdp);
    switch (fdp.ConsumeIntegralInRange<int>(0, 4)) {
      case 0: stamp += 0.04; break;                   // 25 fps
      case 1: break;                                  // duplicated stamp
      case 2: stamp -= 5.0; break;                    // time jumped back (a looping bag)
      case 3: stamp = fuzz::interestingDouble(fdp); break;  // NaN, inf, huge, negative
      default: stamp += 10.0; break;                  // a gap
    }
    in.stamp_s = stamp;

    std::string error;
    bool ok = false;
    ES_FUZZ_NO_THROW(ok = pipeline->process(in, out, &error), "process()");
    if (ok) {
      fuzz::checkOutput(pipeline->params(), out);
    } else {
      ES_FUZZ_CHECK(!error.empty(), "process() failed without a message");
    }
  }
  return 0;
}
