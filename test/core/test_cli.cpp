// endo_stereo_cli end to end: image files in, PFM / PNG / JSON / PLY out, and the error exits.
// Runs the built binary (ES_CLI_PATH) in a temporary folder.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <regex>
#include <sstream>
#include <string>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/synthetic/surgical_scene.hpp"
#include "synthetic_scene.hpp"

namespace {

using namespace endo_stereo;

struct RunResult {
  int status = -1;
  std::string err;  // stderr
};

class CliTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    char tmpl[] = "/tmp/es_test_cli_XXXXXX";
    const char* d = ::mkdtemp(tmpl);
    ASSERT_NE(d, nullptr);
    dir_ = d;
    SyntheticSceneParams p;
    p.width = 160;
    p.height = 120;
    p.seed = 9;
    p.base_disparity_px = 12.0;
    p.slope_x = 0.02;
    scene_ = makeSyntheticScene(p);
    ASSERT_TRUE(cv::imwrite(dir_ + "/left.png", scene_.left));
    ASSERT_TRUE(cv::imwrite(dir_ + "/right.png", scene_.right));
    // A 3-frame sequence of the same pair (frames 1..3, as many recorders number them).
    for (int i = 1; i <= 3; ++i) {
      char l[64], r[64];
      std::snprintf(l, sizeof(l), "/seq_l_%03d.png", i);
      std::snprintf(r, sizeof(r), "/seq_r_%03d.png", i);
      ASSERT_TRUE(cv::imwrite(dir_ + l, scene_.left));
      ASSERT_TRUE(cv::imwrite(dir_ + r, scene_.right));
    }
  }
  static void TearDownTestSuite() {
    if (!dir_.empty()) std::system(("rm -rf '" + dir_ + "'").c_str());
  }

  // Runs the CLI with @p args (already quoted where needed) inside the temporary folder.
  static RunResult run(const std::string& args) {
    const std::string err_file = dir_ + "/stderr.txt";
    const std::string cmd = "cd '" + dir_ + "' && '" + std::string(ES_CLI_PATH) + "' " + args +
                            " --threads 2 > /dev/null 2> '" + err_file + "'";
    const int raw = std::system(cmd.c_str());
    RunResult r;
    r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
    r.err = readText(err_file);
    return r;
  }
  static std::string readText(const std::string& path) {
    std::ifstream in(path);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  }
  static bool exists(const std::string& name) {
    struct stat st;
    return ::stat((dir_ + "/" + name).c_str(), &st) == 0;
  }
  // The first number after "key": in a JSON text.
  static double jsonNumber(const std::string& json, const std::string& key) {
    std::smatch m;
    const std::regex re("\"" + key + "\": (-?[0-9.eE+-]+)");
    if (!std::regex_search(json, m, re)) return std::nan("");
    return std::stod(m[1]);
  }
  static int countOf(const std::string& text, const std::string& what) {
    int n = 0;
    for (size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
    return n;
  }

  static std::string dir_;
  static SyntheticScene scene_;
};

std::string CliTest::dir_;
SyntheticScene CliTest::scene_;

TEST_F(CliTest, WritesPfmColourAndStatsThatAgreeWithEachOther) {
  const RunResult r =
      run("--left left.png --right right.png --min-disparity 0 --max-disparity 31 "
          "--out-disparity d.pfm --out-color d.png --stats s.json");
  ASSERT_EQ(r.status, 0) << r.err;
  std::string error;
  const cv::Mat d = readPfm(dir_ + "/d.pfm", &error);
  ASSERT_EQ(d.size(), scene_.left.size()) << error;
  // Accurate where output: sub-pixel matching of a smooth slanted plane (0.5 px is loose; the
  // matcher's own tests hold it to 0.2 px).
  int valid = 0, close = 0;
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const float v = d.at<float>(y, x);
      if (std::isnan(v) || scene_.occluded.at<uint8_t>(y, x)) continue;
      ++valid;
      if (std::abs(v - scene_.disparity.at<float>(y, x)) < 0.5f) ++close;
    }
  }
  ASSERT_GT(valid, 0.3 * d.total());
  EXPECT_GT(close, 0.98 * valid);

  const cv::Mat color = cv::imread(dir_ + "/d.png", cv::IMREAD_COLOR);
  ASSERT_EQ(color.size(), d.size());
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const bool black = color.at<cv::Vec3b>(y, x) == cv::Vec3b(0, 0, 0);
      ASSERT_EQ(black, std::isnan(d.at<float>(y, x))) << "invalid <=> black at " << x << "," << y;
    }
  }

  const std::string json = readText(dir_ + "/s.json");
  int finite = 0;
  for (int y = 0; y < d.rows; ++y)
    for (int x = 0; x < d.cols; ++x) finite += std::isfinite(d.at<float>(y, x)) ? 1 : 0;
  EXPECT_NEAR(jsonNumber(json, "density"), double(finite) / d.total(), 1e-5);
  EXPECT_EQ(jsonNumber(json, "valid_pixels"), finite);
  for (const char* k : {"not_searched", "structure", "peak_gap", "left_right", "outlier",
                        "ms_per_frame_median", "matcher.delta_min"}) {
    EXPECT_NE(json.find(std::string("\"") + k + "\""), std::string::npos) << k;
  }
  EXPECT_GT(jsonNumber(json, "ms_per_frame_median"), 0.0);
}

TEST_F(CliTest, ParamsFileThenOverridesThenFlagsApplyInOrder) {
  std::ofstream(dir_ + "/preset.yaml") << "matcher:\n  delta_min: 0.3\n  window_max_px: 15\n";
  const RunResult r =
      run("--left left.png --right right.png --params preset.yaml "
          "--set matcher.delta_min=0.25 --max-disparity 40 --stats p.json");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string json = readText(dir_ + "/p.json");
  EXPECT_NE(json.find("\"matcher.delta_min\": \"0.25\""), std::string::npos);
  EXPECT_NE(json.find("\"matcher.window_max_px\": \"15\""), std::string::npos);
  EXPECT_NE(json.find("\"matcher.max_disparity\": \"40\""), std::string::npos);
}

TEST_F(CliTest, SequenceModeWritesEachFrameAndUsesPriorsUnlessTold) {
  RunResult r =
      run("--left seq_l_%03d.png --right seq_r_%03d.png --max-disparity 31 "
          "--out-disparity sd_%03d.pfm --out-fused sf_%03d.pfm "
          "--out-coverage cov.png --stats seq.json");
  ASSERT_EQ(r.status, 0) << r.err;
  for (const char* f : {"sd_001.pfm", "sd_002.pfm", "sd_003.pfm", "sf_003.pfm", "cov.png"}) {
    EXPECT_TRUE(exists(f)) << f;
  }
  EXPECT_FALSE(exists("sd_000.pfm"));
  EXPECT_FALSE(exists("sd_004.pfm"));
  std::string json = readText(dir_ + "/seq.json");
  EXPECT_EQ(jsonNumber(json, "frames_processed"), 3);
  // The frames after the first (which has no prior and searches the full range).
  EXPECT_EQ(countOf(json, "\"priors_used\": true"), 2);
  EXPECT_GT(jsonNumber(json, "prior_hits"), 0);
  EXPECT_NE(json.find("\"central_share_updated_within\""), std::string::npos);

  r =
      run("--left seq_l_%03d.png --right seq_r_%03d.png --max-disparity 31 --first 2 --count 2 "
          "--no-priors --stats seq2.json");
  ASSERT_EQ(r.status, 0) << r.err;
  json = readText(dir_ + "/seq2.json");
  EXPECT_EQ(jsonNumber(json, "frames_processed"), 2);
  EXPECT_EQ(countOf(json, "\"priors_used\": true"), 0);
  EXPECT_EQ(jsonNumber(json, "index"), 2);
}

// A single pair with the defaults (priors on) is the first frame of a stream: it searches the full
// range, so its disparity is the full search's (priors off) to the bit.
TEST_F(CliTest, ASinglePairWithTheDefaultsIsAFullSearch) {
  RunResult r = run("--left left.png --right right.png --max-disparity 31 --out-disparity d1.pfm");
  ASSERT_EQ(r.status, 0) << r.err;
  r = run("--left left.png --right right.png --max-disparity 31 --set temporal.enabled=false "
          "--out-disparity d0.pfm");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string with_priors = readText(dir_ + "/d1.pfm");
  ASSERT_GT(with_priors.size(), 1000u);
  EXPECT_TRUE(with_priors == readText(dir_ + "/d0.pfm"));
}

TEST_F(CliTest, UnreadableInputsExitWithOneAndNameTheFile) {
  RunResult r = run("--left missing.png --right right.png");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("missing.png"), std::string::npos) << r.err;

  std::ofstream(dir_ + "/garbage.png") << "not an image";
  r = run("--left left.png --right garbage.png");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("garbage.png"), std::string::npos) << r.err;

  cv::imwrite(dir_ + "/small.png", scene_.right(cv::Rect(0, 0, 100, 80)));
  r = run("--left left.png --right small.png");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("size mismatch"), std::string::npos) << r.err;

  r = run("--left left.png --right right.png --out-disparity /nonexistent_dir/d.pfm");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("/nonexistent_dir/d.pfm"), std::string::npos) << r.err;

  r = run("--left none_%03d.png --right none_r_%03d.png");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("none_000.png"), std::string::npos) << r.err;
}

TEST_F(CliTest, BadUsageRangesAndParamsExitWithTwoAndSayWhy) {
  struct Case {
    std::string args, expect;
  };
  const Case cases[] = {
      {"--left left.png --right right.png --min-disparity 20 --max-disparity 10", "range"},
      {"--left left.png --right right.png --max-disparity ten", "--max-disparity"},
      // A bad number is refused, not read as 0 or as its leading digits.
      {"--left left.png --right right.png --threads abc",
       "--threads: expected an integer >= 0, got 'abc'"},
      {"--left seq_l_%03d.png --right seq_r_%03d.png --count 1x",
       "--count: expected an integer >= 1, got '1x'"},
      {"--left left.png --right right.png --max-disparity 1e99",
       "--max-disparity: expected an integer, got '1e99'"},
      {"--left left.png --right right.png --fps 0", "--fps: expected a number > 0, got '0'"},
      {"--left left.png --right right.png --set matcher.delta_mn=0.2", "matcher.delta_mn"},
      {"--left left.png --right right.png --set matcher.window_min_px=4", "window_min_px"},
      {"--left left.png --right right.png --set matcher.delta_min=abc", "matcher.delta_min"},
      {"--left left.png --right right.png --set delta_min", "malformed"},
      {"--left left.png --right right.png --params nowhere.yaml", "nowhere.yaml"},
      {"--left left.png --right right.png --downsample 3", "downsample"},
      {"--left left.png --right right.png --frobnicate", "--frobnicate"},
      {"--left left.png", "--right"},
      {"--left seq_l_%03d.png --right seq_r_%03d.png --out-disparity one.pfm", "pattern"},
      {"--left left.png --right right.png --calib a.yaml --uncalibrated", "--uncalibrated"},
      {"--left left.png --right right.png --set rectify.mode=calibrated", "--calib"},
  };
  for (const Case& c : cases) {
    const RunResult r = run(c.args);
    EXPECT_EQ(r.status, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.expect), std::string::npos) << c.args << "\n" << r.err;
  }
  std::ofstream(dir_ + "/unknown.yaml") << "matcher:\n  gama_min: 1\n";
  const RunResult r = run("--left left.png --right right.png --params unknown.yaml");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("matcher.gama_min"), std::string::npos) << r.err;
}

TEST_F(CliTest, HelpAndParameterListAreAvailable) {
  RunResult r = run("--help");
  EXPECT_EQ(r.status, 0);
  const std::string help_cmd = "'" + std::string(ES_CLI_PATH) + "' --help";
  FILE* pipe = ::popen(help_cmd.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string help;
  char buf[512];
  while (size_t n = std::fread(buf, 1, sizeof(buf), pipe)) help.append(buf, n);
  ::pclose(pipe);
  for (const char* flag :
       {"--left",          "--right",         "--params",    "--set",          "--min-disparity",
        "--max-disparity", "--out-disparity", "--out-color", "--stats",        "--calib",
        "--uncalibrated",  "--focal",         "--baseline",  "--downsample",   "--out-rectified",
        "--out-cloud",     "--no-priors",     "--out-fused", "--out-coverage", "--threads",
        "--first",         "--count"}) {
    EXPECT_NE(help.find(flag), std::string::npos) << flag;
  }
  r = run("--list-params");
  EXPECT_EQ(r.status, 0);
}

// Calibrated end to end: raw distorted images of the synthetic endoscope and its camera_info
// YAML pair in; rectified pair, metric cloud (binary and ASCII PLY) out.
TEST_F(CliTest, CalibratedPairGivesRectifiedImagesAndAMetricCloud) {
  SurgicalSceneParams sp;
  sp.width = 192;
  sp.height = 144;
  sp.seed = 4;
  sp.distorted = true;
  const SurgicalScene scene(sp);
  SurgicalFrame f;
  scene.render(0, f);
  ASSERT_TRUE(cv::imwrite(dir_ + "/raw_l.png", f.left));
  ASSERT_TRUE(cv::imwrite(dir_ + "/raw_r.png", f.right));
  std::string error;
  ASSERT_TRUE(saveCameraInfoYaml(dir_ + "/cam_l.yaml", scene.calibration().left, "left", &error))
      << error;
  ASSERT_TRUE(saveCameraInfoYaml(dir_ + "/cam_r.yaml", scene.calibration().right, "right", &error))
      << error;
  int d_min = 0, d_max = 0;
  scene.suggestedDisparityRange(&d_min, &d_max);
  const std::string range =
      " --min-disparity " + std::to_string(d_min) + " --max-disparity " + std::to_string(d_max);
  RunResult r = run("--left raw_l.png --right raw_r.png --calib cam_l.yaml,cam_r.yaml" + range +
                    " --out-rectified rect --out-cloud c.ply --out-disparity cd.pfm");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(exists("rect_left.png"));
  EXPECT_TRUE(exists("rect_right.png"));
  const std::string ply = readText(dir_ + "/c.ply");
  EXPECT_EQ(ply.rfind("ply\nformat binary_little_endian", 0), 0u);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(ply, m, std::regex("element vertex ([0-9]+)")));
  const int vertices = std::stoi(m[1]);
  EXPECT_GT(vertices, 1000);
  const cv::Mat d = readPfm(dir_ + "/cd.pfm");
  int finite = 0;
  for (int y = 0; y < d.rows; ++y)
    for (int x = 0; x < d.cols; ++x) finite += std::isfinite(d.at<float>(y, x)) ? 1 : 0;
  EXPECT_EQ(vertices, finite);  // one point per output disparity

  r = run("--left raw_l.png --right raw_r.png --calib cam_l.yaml,cam_r.yaml" + range +
          " --out-cloud ca.ply --ply-ascii");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string ascii = readText(dir_ + "/ca.ply");
  EXPECT_EQ(ascii.rfind("ply\nformat ascii", 0), 0u);
  // The depth of the first point is near the scene's working distance (8 cm +- relief).
  const size_t body = ascii.find("end_header\n");
  ASSERT_NE(body, std::string::npos);
  std::istringstream points(ascii.substr(body + 11));
  double x = 0, y = 0, z = 0;
  points >> x >> y >> z;
  EXPECT_GT(z, 0.05);
  EXPECT_LT(z, 0.12);

  r = run("--left raw_l.png --right raw_r.png --calib missing_l.yaml,cam_r.yaml");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("missing_l.yaml"), std::string::npos) << r.err;
}

// Uncalibrated, as in the paper: the rectification is estimated from the images and its quality
// reported; a pair without texture is refused instead of producing garbage.
TEST_F(CliTest, UncalibratedModeEstimatesTheRectificationOrRefusesClearly) {
  SurgicalSceneParams sp;
  sp.width = 320;
  sp.height = 240;
  sp.seed = 6;
  sp.instruments = 0;
  const SurgicalScene scene(sp);
  SurgicalFrame f;
  scene.render(0, f);
  ASSERT_TRUE(cv::imwrite(dir_ + "/un_l.png", f.left));
  ASSERT_TRUE(cv::imwrite(dir_ + "/un_r.png", f.right));
  int d_min = 0, d_max = 0;
  scene.suggestedDisparityRange(&d_min, &d_max);
  RunResult r =
      run("--left un_l.png --right un_r.png --uncalibrated --focal 300 --baseline 0.0045"
          " --min-disparity " +
          std::to_string(d_min - 16) + " --max-disparity " + std::to_string(d_max + 16) +
          " --stats un.json");
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string json = readText(dir_ + "/un.json");
  EXPECT_NE(json.find("\"measured\": true"), std::string::npos) << json;
  EXPECT_LT(jsonNumber(json, "median_offset_px"),
            1.0);  // the rectification warning threshold (1 px)
  EXPECT_GT(jsonNumber(json, "density"), 0.2);

  cv::imwrite(dir_ + "/flat_l.png", cv::Mat(120, 160, CV_8UC1, cv::Scalar(128)));
  cv::imwrite(dir_ + "/flat_r.png", cv::Mat(120, 160, CV_8UC1, cv::Scalar(128)));
  r = run("--left flat_l.png --right flat_r.png --uncalibrated");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("could not be estimated"), std::string::npos) << r.err;
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
