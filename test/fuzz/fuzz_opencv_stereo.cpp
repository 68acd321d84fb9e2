// libFuzzer harness: the OpenCV stereo calibration loader (calibration_io.hpp loadOpenCvStereoYaml,
// cv::FileStorage YAML or XML: M1 D1 M2 D2 R T [R1 R2 P1 P2] and the image size), then a
// calibrated Pipeline with what it loaded, on one small pair.
//
// The loader takes a path, so each input is written to a private temporary file first.
// Contract checked: the loader never throws, fails with a message, and what it accepts is valid;
// setCalibration() and process() never throw.
#include <unistd.h>

#include <fstream>
#include <stdexcept>

#include "endo_stereo/core/calibration_io.hpp"
#include "fuzz_common.hpp"

using namespace endo_stereo;

namespace {

const std::string& tempPath(bool xml) {
  static const std::string yaml_path =
      "/tmp/es_fuzz_stereo_" + std::to_string(::getpid()) + ".yaml";
  static const std::string xml_path = "/tmp/es_fuzz_stereo_" + std::to_string(::getpid()) + ".xml";
  return xml ? xml_path : yaml_path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  cv::setNumThreads(1);
  if (size == 0) return 0;
  // The first byte picks the file name extension (FileStorage uses it when the content does not
  // announce its format) and the translation scale.
  const bool xml = data[0] & 1;
  const double scale = (data[0] & 2) ? 0.001 : 1.0;
  const std::string& path = tempPath(xml);
  {
    std::ofstream os(path, std::ios::binary | std::ios::trunc);
    os.write(reinterpret_cast<const char*>(data + 1), static_cast<std::streamsize>(size - 1));
  }
  StereoCalibration calib;
  std::string error;
  bool ok = false;
  ES_FUZZ_NO_THROW(ok = loadOpenCvStereoYaml(path, calib, &error, scale), "loadOpenCvStereoYaml");
  if (!ok) {
    ES_FUZZ_CHECK(!error.empty(), "failed without a message");
    return 0;
  }
  ES_FUZZ_CHECK(calib.validate().empty(), "accepted an invalid calibration: " + calib.validate());

  PipelineParams params;
  params.matcher.max_disparity = 7;
  params.matcher.window_max_px = 11;
  params.rectify.quality_stride = 1000;
  Pipeline pipeline(params);
  std::string cal_error;
  ES_FUZZ_NO_THROW(cal_error = pipeline.setCalibration(calib), "setCalibration");
  if (!cal_error.empty()) return 0;
  cv::Size sz(calib.left.width, calib.left.height);
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
