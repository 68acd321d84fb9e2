// Bad-input regression tests at the core level (RELIABILITY.md): every entry of the
// bad-input inventory that exists without ROS is fed to endo_stereo::Pipeline (or the loader /
// buffer wrapper it reaches), and each must give a clear error naming the problem, or a defined
// behaviour, and leave the pipeline able to process the next good pair. The crashes found by the
// libFuzzer harnesses (test/fuzz, scripts/fuzz.sh) are kept here as tests too ("Fuzz" suites).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/core/preprocess.hpp"

namespace endo_stereo {
namespace {

constexpr int kWidth = 64;
constexpr int kHeight = 48;
constexpr int kShiftPx = 6;  // true disparity of the good pair
constexpr double kFocalPx = 80.0;
constexpr double kBaselineM = 0.005;
const double kNaN = std::numeric_limits<double>::quiet_NaN();

/// A blurred random texture: every window has structure, so the matcher accepts most pixels.
cv::Mat texture(cv::Size size, uint64_t seed) {
  cv::Mat t(size, CV_8UC1);
  cv::RNG rng(seed);
  rng.fill(t, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(t, t, cv::Size(3, 3), 0.8);
  return t;
}

/// A fronto-parallel pair with disparity kShiftPx everywhere: right(x) = left(x + d).
StereoInput goodPair(double stamp_s, cv::Size size = cv::Size(kWidth, kHeight)) {
  const cv::Mat wide = texture(cv::Size(size.width + kShiftPx, size.height), 7);
  StereoInput in;
  in.left = wide(cv::Rect(0, 0, size.width, size.height)).clone();
  in.right = wide(cv::Rect(kShiftPx, 0, size.width, size.height)).clone();
  in.left_encoding = in.right_encoding = "mono8";
  in.stamp_s = stamp_s;
  return in;
}

PipelineParams passThroughParams() {
  PipelineParams p;
  p.rectify.mode = RectifyMode::kPassThrough;
  p.rectify.focal_px = kFocalPx;
  p.rectify.baseline_m = kBaselineM;
  p.rectify.quality_stride = 1000;  // the SIFT quality check is not under test here
  p.matcher.min_disparity = 0;
  p.matcher.max_disparity = 15;
  p.matcher.num_threads = 1;
  return p;
}

/// A calibration of an ideal rectified rig (no distortion, R = I) for images of @p size.
StereoCalibration idealCalibration(cv::Size size = cv::Size(kWidth, kHeight),
                                   double baseline_m = kBaselineM) {
  StereoCalibration s;
  for (CameraCalibration* c : {&s.left, &s.right}) {
    c->width = size.width;
    c->height = size.height;
    c->distortion_model = "plumb_bob";
    c->D.assign(5, 0.0);
    c->K = cv::Matx33d(kFocalPx, 0, size.width / 2.0, 0, kFocalPx, size.height / 2.0, 0, 0, 1);
    c->P = cv::Matx34d(kFocalPx, 0, size.width / 2.0, 0, 0, kFocalPx, size.height / 2.0, 0, 0, 0, 1,
                       0);
  }
  s.left.frame_id = "left_optical";
  s.right.frame_id = "right_optical";
  s.right.P(0, 3) = -kFocalPx * baseline_m;
  return s;
}

PipelineParams calibratedParams() {
  PipelineParams p = passThroughParams();
  p.rectify.mode = RectifyMode::kCalibrated;
  p.rectify.focal_px = 0.0;
  p.rectify.baseline_m = 0.0;
  return p;
}

/// The good pair is processed: most pixels valid, at the true disparity. Tolerances: the pair is
/// an exact integer shift of a textured image, so valid disparities sit within 0.5 px of it
/// (sub-pixel refinement); 30% density is far below what the default preset gets on such a
/// texture (borders of half a window and the search range are not matchable) yet far above 0.
void expectGoodPairProcessed(Pipeline& pipeline, double stamp_s, const std::string& after) {
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(goodPair(stamp_s), out, &error))
      << "good pair refused after " << after << ": " << error;
  EXPECT_GT(out.match.stats.density(), 0.3) << "after " << after;
  std::vector<float> valid;
  for (int y = 0; y < out.match.disparity.rows; ++y) {
    for (int x = 0; x < out.match.disparity.cols; ++x) {
      const float d = out.match.disparity.at<float>(y, x);
      if (std::isfinite(d)) valid.push_back(d);
    }
  }
  ASSERT_FALSE(valid.empty()) << "after " << after;
  std::nth_element(valid.begin(), valid.begin() + valid.size() / 2, valid.end());
  EXPECT_NEAR(valid[valid.size() / 2], kShiftPx, 0.5) << "after " << after;
}

/// Feeds @p bad, expects a refusal whose message contains @p expected, then a good pair.
void expectRefusedThenRecovers(Pipeline& pipeline, const StereoInput& bad,
                               const std::string& expected, const std::string& what) {
  PipelineOutput out;
  std::string error;
  bool ok = true;
  EXPECT_NO_THROW(ok = pipeline.process(bad, out, &error)) << what;
  EXPECT_FALSE(ok) << what << " was accepted";
  EXPECT_NE(error.find(expected), std::string::npos)
      << what << ": message '" << error << "' does not mention '" << expected << "'";
  expectGoodPairProcessed(pipeline, bad.stamp_s + 0.04, what);
}

/// Writes an OpenCV stereo calibration file (YAML) of a 64x48 rectified rig with no D1/D2; the
/// T block's header lines (rows, cols) are @p t_shape.
void writeOpenCvStereoFile(const std::string& path,
                           const std::string& t_shape = "   rows: 3\n   cols: 1\n") {
  std::ofstream os(path);
  os << "%YAML:1.0\n---\nimage_width: 64\nimage_height: 48\n";
  for (const char* m : {"M1", "M2"}) {
    os << m << ": !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
       << "   data: [ 80., 0., 32., 0., 80., 24., 0., 0., 1. ]\n";
  }
  os << "R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
     << "   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\n";
  os << "T: !!opencv-matrix\n" << t_shape << "   dt: d\n   data: [ -0.005, 0., 0. ]\n";
}

// --- Images -------------------------------------------------------------------------------------

TEST(BadImage, EmptyLeftOrRightIsRefusedByName) {
  Pipeline pipeline(passThroughParams());
  StereoInput in = goodPair(1.0);
  in.left = cv::Mat();
  expectRefusedThenRecovers(pipeline, in, "empty left", "an empty left image");
  in = goodPair(2.0);
  in.right = cv::Mat();
  expectRefusedThenRecovers(pipeline, in, "empty right", "an empty right image");
}

TEST(BadImage, OnePixelImageIsHandled) {
  // Defined behaviour: either a clear refusal or an output with no valid pixel (no window fits).
  Pipeline pipeline(passThroughParams());
  StereoInput in = goodPair(1.0);
  in.left = cv::Mat(1, 1, CV_8UC1, cv::Scalar(100));
  in.right = cv::Mat(1, 1, CV_8UC1, cv::Scalar(100));
  PipelineOutput out;
  std::string error;
  bool ok = false;
  ASSERT_NO_THROW(ok = pipeline.process(in, out, &error));
  if (ok) {
    EXPECT_EQ(out.match.disparity.size(), cv::Size(1, 1));
    EXPECT_EQ(out.match.stats.valid_pixels, 0);
  } else {
    EXPECT_FALSE(error.empty());
  }
  expectGoodPairProcessed(pipeline, 1.04, "a 1x1 pair");
}

TEST(BadImage, ThinImagesAreHandled) {
  // 1xN and Nx1: narrower than any matching window.
  Pipeline pipeline(passThroughParams());
  for (const cv::Size s : {cv::Size(1, 40), cv::Size(40, 1), cv::Size(3, 3)}) {
    StereoInput in = goodPair(1.0);
    in.left = texture(s, 1);
    in.right = texture(s, 2);
    PipelineOutput out;
    std::string error;
    bool ok = false;
    ASSERT_NO_THROW(ok = pipeline.process(in, out, &error)) << s;
    if (ok) {
      EXPECT_EQ(out.match.disparity.size(), s);
      EXPECT_EQ(out.match.stats.valid_pixels, 0) << s;
    } else {
      EXPECT_FALSE(error.empty());
    }
  }
  expectGoodPairProcessed(pipeline, 5.0, "thin images");
}

TEST(BadImage, OddSizesAreProcessedAtTheDocumentedSize) {
  // Odd widths and heights with every down-sampling and interlace mode: the output has
  // preprocessedSize() (the image is cropped to a multiple of the factor, never read past).
  for (const int downsample : {1, 2, 4}) {
    for (const InterlaceMode mode :
         {InterlaceMode::kNone, InterlaceMode::kDownsample, InterlaceMode::kField}) {
      PipelineParams p = passThroughParams();
      p.preprocess.downsample = downsample;
      p.preprocess.interlace = mode;
      Pipeline pipeline(p);
      const cv::Size odd(kWidth * 2 + 3, kHeight * 2 + 1);
      StereoInput in = goodPair(1.0, odd);
      PipelineOutput out;
      std::string error;
      ASSERT_TRUE(pipeline.process(in, out, &error))
          << "downsample " << downsample << ", " << toString(mode) << ": " << error;
      EXPECT_EQ(out.match.disparity.size(), preprocessedSize(odd, p.preprocess))
          << "downsample " << downsample << ", " << toString(mode);
    }
  }
}

TEST(BadImage, DifferentLeftAndRightSizesAreRefused) {
  Pipeline pipeline(passThroughParams());
  StereoInput in = goodPair(1.0);
  in.right = in.right(cv::Rect(0, 0, kWidth - 2, kHeight)).clone();
  expectRefusedThenRecovers(pipeline, in, "size mismatch", "left/right of different sizes");
}

TEST(BadImage, EveryUnsupportedEncodingIsRefusedByName) {
  Pipeline pipeline(passThroughParams());
  double stamp = 1.0;
  for (const char* enc :
       {"bayer_rggb8", "bayer_bggr16", "bgr16", "rgb16", "rgba16", "mono32", "32FC1", "16SC1",
        "8SC1", "64FC1", "nv21", "jpeg", "MONO8", "mono8 ", "no such encoding"}) {
    StereoInput in = goodPair(stamp);
    in.left_encoding = in.right_encoding = enc;
    expectRefusedThenRecovers(pipeline, in, "unsupported encoding",
                              std::string("encoding '") + enc + "'");
    stamp += 0.1;
  }
  // A type that no encoding name maps to, with the encoding left for the pipeline to infer.
  StereoInput in = goodPair(stamp + 1.0);
  in.left.convertTo(in.left, CV_32F);
  in.right.convertTo(in.right, CV_32F);
  in.left_encoding = in.right_encoding = "";
  PipelineOutput out;
  std::string error;
  EXPECT_FALSE(pipeline.process(in, out, &error));
  EXPECT_FALSE(error.empty());
  expectGoodPairProcessed(pipeline, stamp + 2.0, "a CV_32F image without an encoding");
}

TEST(BadImage, EncodingThatDisagreesWithTheBufferIsRefused) {
  // "bgr8" on a one-channel buffer, "mono16" on 8-bit data, left and right encodings differing.
  Pipeline pipeline(passThroughParams());
  StereoInput in = goodPair(1.0);
  in.left_encoding = in.right_encoding = "bgr8";
  expectRefusedThenRecovers(pipeline, in, "bgr8", "bgr8 on a CV_8UC1 buffer");
  in = goodPair(2.0);
  in.left_encoding = in.right_encoding = "mono16";
  expectRefusedThenRecovers(pipeline, in, "mono16", "mono16 on a CV_8UC1 buffer");
  in = goodPair(3.0);
  in.right_encoding = "rgb8";
  expectRefusedThenRecovers(pipeline, in, "right image", "right encoding rgb8 on mono8 data");
}

TEST(BadImage, DifferentButSupportedEncodingsAreMatchedOnLuma) {
  // Defined behaviour: a mono8 left and a bgr8 right are both converted to gray and matched.
  Pipeline pipeline(passThroughParams());
  StereoInput in = goodPair(1.0);
  cv::cvtColor(in.right, in.right, cv::COLOR_GRAY2BGR);
  in.right_encoding = "bgr8";
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(in, out, &error)) << error;
  EXPECT_GT(out.match.stats.density(), 0.3);
}

// --- Raw buffers (what sensor_msgs/Image carries) ------------------------------------------------

TEST(BadBuffer, StepShorterThanARowIsRefused) {
  std::vector<uint8_t> data(kWidth * kHeight * 3, 0);
  cv::Mat out;
  std::string error;
  EXPECT_FALSE(wrapRawImage(data.data(), data.size(), kWidth, kHeight, kWidth * 3 - 1, "bgr8",
                            false, out, &error));
  EXPECT_NE(error.find("step"), std::string::npos) << error;
}

TEST(BadBuffer, TruncatedDataIsRefused) {
  std::vector<uint8_t> data(kWidth * kHeight - 1, 0);  // one byte short of a mono8 image
  cv::Mat out;
  std::string error;
  EXPECT_FALSE(
      wrapRawImage(data.data(), data.size(), kWidth, kHeight, kWidth, "mono8", false, out, &error));
  EXPECT_NE(error.find("bytes"), std::string::npos) << error;
  EXPECT_FALSE(wrapRawImage(nullptr, 0, kWidth, kHeight, kWidth, "mono8", false, out, &error));
  EXPECT_FALSE(
      wrapRawImage(data.data(), data.size(), 0, kHeight, kWidth, "mono8", false, out, &error));
}

TEST(BadBuffer, PaddedStepIsAcceptedAndUnpadded) {
  // Defined behaviour: a step larger than a row (row padding) is legal and stripped.
  const int step = kWidth + 5;
  std::vector<uint8_t> data(step * kHeight, 0);
  for (int y = 0; y < kHeight; ++y) data[y * step] = static_cast<uint8_t>(y);
  cv::Mat out;
  std::string error;
  ASSERT_TRUE(
      wrapRawImage(data.data(), data.size(), kWidth, kHeight, step, "mono8", false, out, &error))
      << error;
  EXPECT_EQ(out.size(), cv::Size(kWidth, kHeight));
  EXPECT_EQ(out.at<uint8_t>(kHeight - 1, 0), kHeight - 1);
}

// Found by fuzz_raw_image: a mono16 buffer whose step is not a multiple of 2 bytes made OpenCV
// throw cv::Exception out of wrapRawImage (documented to return false), which would escape a ROS
// image callback.
TEST(FuzzRawImage, StepNotAMultipleOfThePixelDepthIsRefused) {
  std::vector<uint8_t> data(4 * 7, 0);
  cv::Mat out;
  std::string error;
  bool ok = true;
  ASSERT_NO_THROW(
      ok = wrapRawImage(data.data(), data.size(), 3, 4, 7, "mono16", false, out, &error));
  EXPECT_FALSE(ok);
  EXPECT_NE(error.find("step"), std::string::npos) << error;
}

// Found by fuzz_raw_image: step * height wrapped around size_t, so a huge step passed the buffer
// size check and the image was read far outside the buffer.
TEST(FuzzRawImage, StepTimesHeightOverflowIsRefused) {
  std::vector<uint8_t> data(64, 0);
  const size_t huge_step = (std::numeric_limits<size_t>::max() / 2) + 1;  // * 2 wraps to 0
  cv::Mat out;
  std::string error;
  bool ok = true;
  ASSERT_NO_THROW(
      ok = wrapRawImage(data.data(), data.size(), 4, 2, huge_step, "mono8", false, out, &error));
  EXPECT_FALSE(ok);
}

// --- Calibration
// ----------------------------------------------------------------------------------

TEST(BadCalibration, NaNOrZeroEntriesAreRefusedByField) {
  Pipeline pipeline(calibratedParams());
  struct Case {
    const char* what;
    const char* field;  // what the message must name
    void (*spoil)(StereoCalibration&);
  };
  const Case cases[] = {
      {"NaN fx", "K", [](StereoCalibration& s) { s.left.K(0, 0) = kNaN; }},
      {"zero fx", "fx", [](StereoCalibration& s) { s.right.K(0, 0) = 0.0; }},
      {"zero fy", "fy", [](StereoCalibration& s) { s.left.K(1, 1) = 0.0; }},
      {"NaN cx", "K", [](StereoCalibration& s) { s.left.K(0, 2) = kNaN; }},
      {"all-zero K", "K", [](StereoCalibration& s) { s.left.K = cv::Matx33d::zeros(); }},
      {"NaN distortion", "D", [](StereoCalibration& s) { s.right.D[1] = kNaN; }},
      {"NaN in P", "P", [](StereoCalibration& s) { s.right.P(1, 2) = kNaN; }},
      {"NaN in R", "R", [](StereoCalibration& s) { s.left.R(0, 1) = kNaN; }},
  };
  ASSERT_EQ(pipeline.setCalibration(idealCalibration()), "");
  double stamp = 1.0;
  for (const Case& c : cases) {
    StereoCalibration bad = idealCalibration();
    c.spoil(bad);
    std::string error;
    ASSERT_NO_THROW(error = pipeline.setCalibration(bad)) << c.what;
    EXPECT_FALSE(error.empty()) << c.what << " was accepted";
    EXPECT_NE(error.find(c.field), std::string::npos)
        << c.what << ": message '" << error << "' does not name " << c.field;
    // Defined behaviour: a refused calibration leaves the previous one in use.
    expectGoodPairProcessed(pipeline, stamp, c.what);
    stamp += 0.04;
  }
}

TEST(BadCalibration, ZeroOrNegativeBaselineIsRefused) {
  Pipeline pipeline(calibratedParams());
  for (const double b : {0.0, -kBaselineM}) {
    std::string error;
    ASSERT_NO_THROW(error =
                        pipeline.setCalibration(idealCalibration(cv::Size(kWidth, kHeight), b)));
    EXPECT_NE(error.find("baseline"), std::string::npos)
        << "baseline " << b << ": '" << error << "'";
  }
  // A NaN baseline is a NaN in the right projection matrix, and is named as such.
  std::string error;
  ASSERT_NO_THROW(error =
                      pipeline.setCalibration(idealCalibration(cv::Size(kWidth, kHeight), kNaN)));
  EXPECT_NE(error.find("right.P"), std::string::npos) << error;
  // Without any accepted calibration a calibrated pipeline refuses pairs with a message ...
  PipelineOutput out;
  EXPECT_FALSE(pipeline.process(goodPair(1.0), out, &error));
  EXPECT_FALSE(error.empty());
  // ... and works as soon as a good one arrives.
  ASSERT_EQ(pipeline.setCalibration(idealCalibration()), "");
  expectGoodPairProcessed(pipeline, 1.04, "bad baselines");
}

TEST(BadCalibration, ZeroOrNegativeBaselineInPassThroughParamsIsRefused) {
  PipelineParams p = passThroughParams();
  p.rectify.baseline_m = -0.005;
  EXPECT_THROW(Pipeline{p}, std::invalid_argument);
  p.rectify.baseline_m = kNaN;
  EXPECT_THROW(Pipeline{p}, std::invalid_argument);
}

TEST(BadCalibration, CalibrationForAnotherImageSizeIsRefused) {
  Pipeline pipeline(calibratedParams());
  ASSERT_EQ(pipeline.setCalibration(idealCalibration(cv::Size(2 * kWidth, 2 * kHeight))), "");
  PipelineOutput out;
  std::string error;
  bool ok = true;
  ASSERT_NO_THROW(ok = pipeline.process(goodPair(1.0), out, &error));
  EXPECT_FALSE(ok) << "a 64x48 pair was rectified with a 128x96 calibration";
  EXPECT_NE(error.find("128x96"), std::string::npos) << error;
  ASSERT_EQ(pipeline.setCalibration(idealCalibration()), "");
  expectGoodPairProcessed(pipeline, 1.04, "a calibration of another size");
}

TEST(BadCalibration, LeftAndRightOfDifferentSizesAreRefused) {
  Pipeline pipeline(calibratedParams());
  StereoCalibration s = idealCalibration();
  s.right.width = kWidth + 2;
  EXPECT_NE(pipeline.setCalibration(s).find("width"), std::string::npos);
}

// Found by fuzz_opencv_stereo: an OpenCV stereo file without D1/D2 (rectified cameras, as
// stereo_calib.cpp writes for zero distortion) divided by zero in OpenCV's iterator arithmetic
// (an empty cv::Mat's begin/end): SIGFPE instead of a calibration without distortion.
TEST(FuzzOpenCvStereo, FileWithoutDistortionLoads) {
  const std::string path = "/tmp/test_bad_input_" + std::to_string(::getpid()) + ".yaml";
  writeOpenCvStereoFile(path);
  StereoCalibration calib;
  std::string error;
  const bool ok = loadOpenCvStereoYaml(path, calib, &error);
  ::unlink(path.c_str());
  ASSERT_TRUE(ok) << error;
  EXPECT_TRUE(calib.left.D.empty());
  EXPECT_TRUE(calib.right.D.empty());
}

// Found by fuzz_opencv_stereo: an empty key inside a matrix block makes OpenCV 4.6's YAML parser
// throw std::length_error (not cv::Exception), which escaped the loader (documented to return
// false with a message) and would terminate the command-line tools.
TEST(FuzzOpenCvStereo, EmptyKeyIsAnErrorNotAnException) {
  const std::string path = "/tmp/test_bad_input_key_" + std::to_string(::getpid()) + ".yaml";
  {
    std::ofstream os(path);
    os << "%YAML:1.0\n---\nM1: !!opencv-matrix\n   rows: 3\n   : [ 1. ]\n";
  }
  StereoCalibration calib;
  std::string error;
  bool ok = true;
  EXPECT_NO_THROW(ok = loadOpenCvStereoYaml(path, calib, &error));
  ::unlink(path.c_str());
  EXPECT_FALSE(ok);
  EXPECT_NE(error.find(path), std::string::npos) << "message does not name the file: " << error;
}

// Found by fuzz_opencv_stereo: a corrupted matrix header ("rows: 2147483647" in T) made
// cv::read() allocate rows x cols (16 GB) before it compared them with the three values given:
// out of memory under the fuzzer, a multi-gigabyte allocation or std::bad_alloc in a tool. The
// loader now checks the declared shape against the data first and names the field.
TEST(FuzzOpenCvStereo, ImpossibleMatrixShapeIsRefusedBeforeAllocating) {
  const std::string path = "/tmp/test_bad_input_shape_" + std::to_string(::getpid()) + ".yaml";
  auto write = [&](const std::string& t_shape) { writeOpenCvStereoFile(path, t_shape); };
  StereoCalibration calib;
  std::string error;
  write("   rows: 2147483647\n   cols: 1\n");
  EXPECT_FALSE(loadOpenCvStereoYaml(path, calib, &error));
  EXPECT_NE(error.find("T: rows = 2147483647"), std::string::npos) << error;
  write("   rows: 8\n   cols: 8\n");  // within the side limit, but 64 elements for 3 values
  EXPECT_FALSE(loadOpenCvStereoYaml(path, calib, &error));
  EXPECT_NE(error.find("T: declares 64 elements but holds 3 values"), std::string::npos) << error;
  write("   rows: 3\n   cols: 1\n");  // the same file with a sane header loads
  const bool ok = loadOpenCvStereoYaml(path, calib, &error);
  ::unlink(path.c_str());
  EXPECT_TRUE(ok) << error;
}

// Found by fuzz_opencv_stereo: a NUL byte inside an XML attribute made OpenCV 4.6's XML parser
// dereference a null pointer (SIGSEGV in cv::FileStorage::open, no exception to catch). The loader
// refuses a file with a NUL byte before the parser sees it.
TEST(FuzzOpenCvStereo, NulByteIsRefusedBeforeTheParser) {
  const std::string path = "/tmp/test_bad_input_nul_" + std::to_string(::getpid()) + ".xml";
  {
    std::ofstream os(path, std::ios::binary);
    const std::string text = std::string("<?xml version=\"1.0\"?>\n<opencv_storage>\n") +
                             "<T type_id=" + std::string(1, '\0') +
                             "\"opencv-matrix\"><rows>3</rows><cols>1</cols><dt>d</dt>"
                             "<data>-0.005 0. 0.</data></T>\n</opencv_storage>\n";
    os.write(text.data(), static_cast<std::streamsize>(text.size()));
  }
  StereoCalibration calib;
  std::string error;
  const bool ok = loadOpenCvStereoYaml(path, calib, &error);
  ::unlink(path.c_str());
  EXPECT_FALSE(ok);
  EXPECT_NE(error.find("NUL byte at offset 50"), std::string::npos) << error;
}

// --- Time
// -------------------------------------------------------------------------------------------

TEST(BadTime, TimeGoingBackResetsTheTemporalState) {
  Pipeline pipeline(passThroughParams());
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(goodPair(10.0), out, &error)) << error;
  ASSERT_TRUE(pipeline.process(goodPair(10.04), out, &error)) << error;
  ASSERT_TRUE(pipeline.process(goodPair(2.0), out, &error)) << error;  // a looping bag
  EXPECT_TRUE(out.priors_reset);
  EXPECT_NE(out.reset_reason.find("back"), std::string::npos) << out.reset_reason;
  // No priors of the future: the frame searches the full range.
  EXPECT_FALSE(out.priors_used)
      << "priors of the future were used after time went back";
  expectGoodPairProcessed(pipeline, 2.04, "time going back");
}

TEST(BadTime, DuplicatedStampIsProcessedAsTheNextFrame) {
  // Defined behaviour at the core: a repeated stamp is a zero-length step, not a reset (the
  // nodelet decides whether to drop duplicates before they reach the pipeline).
  Pipeline pipeline(passThroughParams());
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(goodPair(5.0), out, &error)) << error;
  ASSERT_TRUE(pipeline.process(goodPair(5.0), out, &error)) << error;
  EXPECT_FALSE(out.priors_reset) << out.reset_reason;
  EXPECT_EQ(out.frame_index, 1);
  expectGoodPairProcessed(pipeline, 5.0, "a duplicated stamp");
}

TEST(BadTime, NonFiniteStampsDoNotBreakTheStream) {
  Pipeline pipeline(passThroughParams());
  double stamp = 1.0;
  for (const double s : {kNaN, std::numeric_limits<double>::infinity(), -1e300, 0.0}) {
    PipelineOutput out;
    std::string error;
    bool ok = false;
    ASSERT_NO_THROW(ok = pipeline.process(goodPair(s), out, &error));
    if (!ok) EXPECT_FALSE(error.empty());
    expectGoodPairProcessed(pipeline, stamp, "stamp " + std::to_string(s));
    stamp += 0.04;
  }
}

// --- Search range and parameters
// -----------------------------------------------------------------------

TEST(BadParams, SearchRangeLargerThanTheImageIsHandled) {
  // Defined behaviour: disparities beyond the image width are simply never matched; pixels whose
  // whole range leaves the image stay invalid; the true disparity is still found.
  PipelineParams p = passThroughParams();
  p.matcher.min_disparity = -200;
  p.matcher.max_disparity = 300;
  Pipeline pipeline(p);
  PipelineOutput out;
  std::string error;
  ASSERT_TRUE(pipeline.process(goodPair(1.0), out, &error)) << error;
  int valid = 0;
  for (int y = 0; y < out.match.disparity.rows; ++y) {
    for (int x = 0; x < out.match.disparity.cols; ++x) {
      const float d = out.match.disparity.at<float>(y, x);
      if (!std::isfinite(d)) continue;
      ++valid;
      EXPECT_LT(x - d, kWidth) << "match outside the right image at " << x << "," << y;
      EXPECT_GE(x - d, -1.0) << "match outside the right image at " << x << "," << y;
    }
  }
  EXPECT_GT(valid, 0);
}

TEST(BadParams, InvalidParamsAreRefusedByNameAndTheOldOnesKept) {
  struct Case {
    const char* key;
    const char* value;
  };
  const Case cases[] = {
      {"matcher.window_min_px", "4"},
      {"matcher.window_min_px", "-1"},
      {"matcher.window_step_px", "3"},
      {"matcher.window_max_px", "1"},
      {"matcher.max_disparity", "-5"},
      {"matcher.delta_min", "3"},
      {"matcher.epsilon_px", "0"},
      {"matcher.gamma_min", "-1"},
      {"filter.outlier_window_px", "2"},
      {"filter.outlier_min_share", "1.5"},
      {"filter.fill_max_hole_px", "9"},
      {"preprocess.downsample", "3"},
      {"temporal.prior_radius_px", "0"},
      {"temporal.max_gap_s", "-1"},
      // Found by fuzzing: oneTBB crashed when the thread count went back down from > 65536.
      {"matcher.num_threads", "100000"},
      {"matcher.num_threads", "-1"},
      // Found by fuzzing: min - max overflowed int and the range passed validation.
      {"matcher.min_disparity", "-2147483648"},
  };
  Pipeline pipeline(passThroughParams());
  double stamp = 1.0;
  for (const Case& c : cases) {
    PipelineParams bad = passThroughParams();
    ASSERT_EQ(setPipelineParam(bad, c.key, c.value), "") << c.key;
    const std::string message = bad.validate();
    const std::string field = std::string(c.key).substr(std::string(c.key).find('.') + 1);
    EXPECT_NE(message.find(field), std::string::npos)
        << c.key << "=" << c.value << ": '" << message << "'";
    EXPECT_THROW(Pipeline{bad}, std::invalid_argument) << c.key << "=" << c.value;
    EXPECT_THROW(pipeline.setParams(bad), std::invalid_argument) << c.key << "=" << c.value;
    std::string kept;
    ASSERT_TRUE(getPipelineParam(pipeline.params(), c.key, &kept));
    std::string original;
    ASSERT_TRUE(getPipelineParam(passThroughParams(), c.key, &original));
    EXPECT_EQ(kept, original) << c.key << " changed by a refused setParams()";
    expectGoodPairProcessed(pipeline, stamp, std::string(c.key) + "=" + c.value);
    stamp += 0.04;
  }
}

TEST(BadParams, MalformedValuesAreRefusedByTheLoader) {
  PipelineParams p;
  for (const char* kv :
       {"matcher.delta_min=nan", "matcher.delta_min=inf", "matcher.window_min_px=7.5",
        "matcher.window_min_px=99999999999", "matcher.subpixel=maybe", "rectify.mode=sideways",
        "nosuch.key=1", "matcher.window_min_px", "=3"}) {
    EXPECT_NE(applyParamOverride(p, kv), "") << kv;
  }
  EXPECT_NE(loadPipelineParamsFromString("matcher: [1, 2]", p), "");
  EXPECT_NE(loadPipelineParamsFromString("matcher: {window_min_px: {a: 1}}", p), "");
  EXPECT_NE(loadPipelineParamsFromString("{{{", p), "");
  // Found by fuzzing: a map as a key made yaml-cpp throw out of the loader.
  EXPECT_NE(loadPipelineParamsFromString(std::string("{{}}0\x03"), p), "");
  EXPECT_NE(loadPipelineParamsFromString("{a: 1}: {b: 2}", p), "");
  EXPECT_EQ(pipelineParamsToYaml(p), pipelineParamsToYaml(PipelineParams()))
      << "a refused load or override changed the params";
}

TEST(BadParams, Mono16BitsOutsideItsRangeIsRefusedNotShifted) {
  // Found by fuzzing: an out-of-range bit count was an undefined shift in convertImage().
  const cv::Mat raw(4, 4, CV_16UC1, cv::Scalar(1000));
  cv::Mat gray;
  std::string error;
  for (const int bits : {7, 17, 40, -3}) {
    EXPECT_FALSE(convertImage(raw, "mono16", bits, gray, nullptr, &error)) << bits;
    EXPECT_NE(error.find("mono16_bits"), std::string::npos) << error;
  }
  EXPECT_TRUE(convertImage(raw, "mono16", 12, gray, nullptr, &error)) << error;
  EXPECT_EQ(gray.at<uint8_t>(0, 0), 1000 / 16);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  cv::setNumThreads(1);  // deterministic and light on a shared 2-core machine
  return RUN_ALL_TESTS();
}
