// libFuzzer harness: the ROS camera_info YAML loader (calibration_io.hpp parseCameraInfoYaml) on
// any text, then what a loaded calibration does downstream: written back and parsed again, paired
// into a stereo calibration, handed to a calibrated Pipeline and used on one small pair.
//
// Contract checked: the loader never throws, fails with a message, and what it accepts is valid
// (validate() is empty) and survives a write/parse round trip; setCalibration() never throws.
#include <stdexcept>

#include "endo_stereo/core/calibration_io.hpp"
#include "fuzz_common.hpp"

using namespace endo_stereo;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  cv::setNumThreads(1);
  const std::string text(reinterpret_cast<const char*>(data), size);
  CameraCalibration cam;
  std::string error;
  bool ok = false;
  ES_FUZZ_NO_THROW(ok = parseCameraInfoYaml(text, cam, &error), "parseCameraInfoYaml");
  if (!ok) {
    ES_FUZZ_CHECK(!error.empty(), "failed without a message");
    return 0;
  }
  ES_FUZZ_CHECK(cam.validate("camera").empty(), "accepted an invalid camera: " + cam.validate("camera"));

  // What we write we must read back.
  CameraCalibration again;
  std::string error2;
  const std::string written = cameraInfoYamlString(cam, "fuzz");
  ES_FUZZ_CHECK(parseCameraInfoYaml(written, again, &error2), "round trip failed: " + error2);

  // A stereo pair out of it: the right camera shifted by a baseline (given P: Tx = -fx B).
  StereoCalibration stereo;
  stereo.left = cam;
  stereo.right = cam;
  if (cam.hasProjection()) stereo.right.P(0, 3) = -cam.P(0, 0) * 0.005;
  if (!stereo.validate().empty()) return 0;

  PipelineParams params;
  params.matcher.max_disparity = 7;
  params.matcher.window_max_px = 11;
  params.rectify.quality_stride = 1000;  // the SIFT quality check is not under test here
  Pipeline pipeline(params);
  std::string cal_error;
  ES_FUZZ_NO_THROW(cal_error = pipeline.setCalibration(stereo), "setCalibration");
  if (!cal_error.empty()) return 0;

  // One pair at the calibrated size when that is small, else a small pair of the wrong size
  // (which must be refused with a message, not crash).
  cv::Size sz = cam.binnedSize();
  if (sz.area() <= 0 || sz.width > 64 || sz.height > 64) sz = cv::Size(24, 16);
  cv::Mat left(sz, CV_8UC1), right;
  cv::randu(left, 0, 256);
  left.copyTo(right);
  StereoInput in{left, right, "mono8", "mono8", 1.0};
  PipelineOutput out;
  std::string perr;
  bool processed = false;
  ES_FUZZ_NO_THROW(processed = pipeline.process(in, out, &perr), "process");
  if (processed) fuzz::checkOutput(params, out);
  else ES_FUZZ_CHECK(!perr.empty(), "process failed without a message");
  return 0;
}
