// endo_stereo_evaluate end to end: on a generated sequence (image files and the same frames as a
// bag) its OpenCV BM and SGBM figures (jumps and motion-compensated flicker included) equal an
// independent computation, and so they do on the
// real in-vivo recording when ../shared/data is present.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#ifndef ES_EVALUATE_PATH
#error "ES_EVALUATE_PATH must name the endo_stereo_evaluate executable"
#endif
#ifndef ES_GENERATE_PATH
#error "ES_GENERATE_PATH must name the endo_stereo_generate executable"
#endif

namespace {

int runCommand(const std::string& cmd) {
  const int raw = std::system(cmd.c_str());
  return WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
}

bool exists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0;
}

YAML::Node methodNode(const YAML::Node& root, const std::string& key) {
  for (const auto& m : root["methods"]) {
    if (m["key"].as<std::string>() == key) return m;
  }
  return YAML::Node();
}

struct Figures {
  double density_mean = 0, density_median = 0;
  int64_t jumps = 0, compared = 0, flicker = 0;
  double covered = 0, never = 0;
};

// Motion-compensated flicker between two OpenCV outputs (1/16 px integers), in integers: per
// pixel compared, the sums of the compared changes and of the compared pixels over its 17x17
// square (cut at the border) from summed-area tables, and |change - sum / count| > 2 px tested
// as |change * count - sum| > 32 * count, exactly.
int64_t flickerCount(const cv::Mat& now, const cv::Mat& before, int min_d) {
  const int w = now.cols, h = now.rows, r = 8;
  std::vector<int64_t> sum((w + 1) * (h + 1), 0), cnt((w + 1) * (h + 1), 0);
  auto at = [w](int x, int y) { return size_t(y) * (w + 1) + x; };
  auto compared = [&](int x, int y) {
    return now.at<int16_t>(y, x) >= min_d * 16 && before.at<int16_t>(y, x) >= min_d * 16;
  };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool c = compared(x, y);
      const int64_t change = c ? now.at<int16_t>(y, x) - before.at<int16_t>(y, x) : 0;
      sum[at(x + 1, y + 1)] = change + sum[at(x, y + 1)] + sum[at(x + 1, y)] - sum[at(x, y)];
      cnt[at(x + 1, y + 1)] = c + cnt[at(x, y + 1)] + cnt[at(x + 1, y)] - cnt[at(x, y)];
    }
  }
  int64_t flicker = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!compared(x, y)) continue;
      const int x0 = std::max(0, x - r), x1 = std::min(w, x + r + 1);
      const int y0 = std::max(0, y - r), y1 = std::min(h, y + r + 1);
      const int64_t s = sum[at(x1, y1)] - sum[at(x0, y1)] - sum[at(x1, y0)] + sum[at(x0, y0)];
      const int64_t n = cnt[at(x1, y1)] - cnt[at(x0, y1)] - cnt[at(x1, y0)] + cnt[at(x0, y0)];
      const int64_t change = now.at<int16_t>(y, x) - before.at<int16_t>(y, x);
      flicker += std::abs(change * n - s) > 32 * n;
    }
  }
  return flicker;
}

// BM / SGBM with every setting spelled out (the settings of ../shared/data/README.md), counted
// with plain loops: nothing shared with the tool but OpenCV.
Figures independent(const std::vector<std::string>& lefts, const std::vector<std::string>& rights,
                    bool sgbm, int min_d, int max_d) {
  const int num_d = (max_d - min_d + 1 + 15) / 16 * 16;
  cv::Ptr<cv::StereoMatcher> matcher;
  if (sgbm) {
    matcher = cv::StereoSGBM::create(min_d, num_d, 5, 200, 800, 0, 0, 10, 0, 0,
                                     cv::StereoSGBM::MODE_SGBM);
  } else {
    auto bm = cv::StereoBM::create(num_d, 15);
    bm->setMinDisparity(min_d);
    bm->setUniquenessRatio(15);
    matcher = bm;
  }
  const size_t n = lefts.size();
  std::vector<cv::Mat> raw(n);
  std::vector<double> dens;
  Figures f;
  for (size_t i = 0; i < n; ++i) {
    cv::Mat l, r;
    cv::cvtColor(cv::imread(lefts[i], cv::IMREAD_COLOR), l, cv::COLOR_BGR2GRAY);
    cv::cvtColor(cv::imread(rights[i], cv::IMREAD_COLOR), r, cv::COLOR_BGR2GRAY);
    matcher->compute(l, r, raw[i]);
    dens.push_back(double(cv::countNonZero(raw[i] >= min_d * 16)) / raw[i].total());
    f.density_mean += dens.back() / n;
    if (i == 0) continue;
    for (int y = 0; y < raw[i].rows; ++y) {
      for (int x = 0; x < raw[i].cols; ++x) {
        const int16_t a = raw[i].at<int16_t>(y, x), b = raw[i - 1].at<int16_t>(y, x);
        if (a < min_d * 16 || b < min_d * 16) continue;
        ++f.compared;
        f.jumps += std::abs(a - b) > 32;  // more than 2 px in 1/16 px units
      }
    }
    f.flicker += flickerCount(raw[i], raw[i - 1], min_d);
  }
  std::sort(dens.begin(), dens.end());
  f.density_median = n % 2 ? dens[n / 2] : 0.5 * (dens[n / 2 - 1] + dens[n / 2]);
  const int w = raw[0].cols, h = raw[0].rows, window = std::min<int>(10, n);
  int64_t central = 0, covered = 0, never = 0;
  for (int y = (h - h / 2) / 2; y < (h - h / 2) / 2 + h / 2; ++y) {
    for (int x = (w - w / 2) / 2; x < (w - w / 2) / 2 + w / 2; ++x) {
      ++central;
      int run = 0, longest = 0;
      for (size_t i = 0; i < n; ++i) {
        run = raw[i].at<int16_t>(y, x) >= min_d * 16 ? 0 : run + 1;
        longest = std::max(longest, run);
      }
      covered += longest < window;
      never += longest == static_cast<int>(n);
    }
  }
  f.covered = double(covered) / central;
  f.never = double(never) / central;
  return f;
}

class EvaluateTool : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    char tmpl[] = "/tmp/es_test_evaluate_XXXXXX";
    const char* d = ::mkdtemp(tmpl);
    ASSERT_NE(d, nullptr);
    dir_ = d;
    // A generated surgical sequence, as image files and as a bag with camera_info.
    const std::string cmd = std::string(ES_GENERATE_PATH) + " --out " + dir_ + "/seq --bag " +
                            dir_ + "/seq.bag --frames 12 --width 256 --height 192 --seed 3 " +
                            "--no-gt > " + dir_ + "/generate.log 2>&1";
    ASSERT_EQ(runCommand(cmd), 0) << "the generator failed, see " << dir_ << "/generate.log";
    const YAML::Node seq = YAML::LoadFile(dir_ + "/seq/sequence.yaml");
    min_d_ = seq["min_disparity"].as<int>();
    max_d_ = seq["max_disparity"].as<int>();
    for (int i = 0; i < 12; ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "/%06d.png", i);
      lefts_.push_back(dir_ + "/seq/left" + name);
      rights_.push_back(dir_ + "/seq/right" + name);
    }
  }
  static void TearDownTestSuite() {
    if (!dir_.empty()) runCommand("rm -rf '" + dir_ + "'");
  }
  static int evaluate(const std::string& args) {
    return runCommand(std::string(ES_EVALUATE_PATH) + " " + args + " --threads 2 --quiet > " +
                      dir_ + "/stdout.txt 2> " + dir_ + "/stderr.txt");
  }
  static std::string range() {
    return " --min-disparity " + std::to_string(min_d_) + " --max-disparity " +
           std::to_string(max_d_);
  }
  static std::string dir_;
  static int min_d_, max_d_;
  static std::vector<std::string> lefts_, rights_;
};
std::string EvaluateTool::dir_;
int EvaluateTool::min_d_ = 0;
int EvaluateTool::max_d_ = 0;
std::vector<std::string> EvaluateTool::lefts_;
std::vector<std::string> EvaluateTool::rights_;

// JSON numbers are written with 6 significant digits: shares agree to 1e-5 of their value.
constexpr double kJsonTol = 1e-5;

TEST_F(EvaluateTool, OpenCvFiguresOnAGeneratedSequenceMatchAnIndependentComputation) {
  ASSERT_EQ(evaluate("--left " + dir_ + "/seq/left/%06d.png --right " + dir_ +
                     "/seq/right/%06d.png --out " + dir_ + "/files" + range()),
            0);
  const YAML::Node root = YAML::LoadFile(dir_ + "/files/evaluation.json");
  EXPECT_EQ(root["frames"].as<int>(), 12);
  for (const char* key : {"bm", "sgbm"}) {
    SCOPED_TRACE(key);
    const YAML::Node m = methodNode(root, key);
    ASSERT_TRUE(m) << "no " << key << " in the JSON";
    const Figures f = independent(lefts_, rights_, std::string(key) == "sgbm", min_d_, max_d_);
    ASSERT_GT(f.compared, 0);
    EXPECT_EQ(m["jump_pixels"].as<int64_t>(), f.jumps);
    EXPECT_EQ(m["compared_pixels"].as<int64_t>(), f.compared);
    EXPECT_EQ(m["flicker_pixels"].as<int64_t>(), f.flicker);
    EXPECT_NEAR(m["flicker_share"].as<double>(), double(f.flicker) / f.compared, kJsonTol);
    EXPECT_NEAR(m["density_mean"].as<double>(), f.density_mean, kJsonTol);
    EXPECT_NEAR(m["density_median"].as<double>(), f.density_median, kJsonTol);
    EXPECT_NEAR(m["coverage_every_window"].as<double>(), f.covered, kJsonTol);
    EXPECT_NEAR(m["coverage_never"].as<double>(), f.never, kJsonTol);
    EXPECT_GT(m["ms_median"].as<double>(), 0.0);
  }
  // Ours, with and without priors, and their fused outputs are all there, and the figure too.
  for (const char* key : {"ours", "ours-fused", "ours-no-priors", "ours-no-priors-fused"}) {
    SCOPED_TRACE(key);
    const YAML::Node m = methodNode(root, key);
    ASSERT_TRUE(m);
    EXPECT_EQ(m["density"].size(), 12u);
    EXPECT_EQ(m["flicker"].size(), 11u);
    EXPECT_TRUE(m["flicker_share"]);
    // A floor so that an empty output fails: the matcher finds most of a generated scene.
    EXPECT_GT(m["density_mean"].as<double>(), 0.3);
  }
  // Ours' time per stage: every stage, none negative (the rest is the call's wall time less the
  // others, each measured inside the call), the total the call's median time.
  for (const char* key : {"ours", "ours-no-priors"}) {
    SCOPED_TRACE(key);
    const YAML::Node m = methodNode(root, key);
    const YAML::Node stages = m["stage_ms_median"];
    ASSERT_TRUE(stages.IsMap());
    for (const char* stage : {"rectify_preprocess", "priors", "prepare", "search", "edge",
                              "filters", "rest", "total"}) {
      ASSERT_TRUE(stages[stage]) << stage;
      EXPECT_GE(stages[stage].as<double>(), 0.0) << stage;
    }
    EXPECT_GT(stages["search"].as<double>(), 0.0);
    EXPECT_DOUBLE_EQ(stages["total"].as<double>(), m["ms_median"].as<double>());
  }
  for (const char* key : {"sgbm", "ours-fused"}) {  // ours' measured streams only
    const YAML::Node m = methodNode(root, key);
    EXPECT_FALSE(m["stage_ms_median"]) << key;
  }
  const cv::Mat figure = cv::imread(dir_ + "/files/comparison.png");
  ASSERT_FALSE(figure.empty());
  EXPECT_EQ(figure.cols, 7 * 256);  // the left image and six streams, at full width (< 480)
  // Rows: disparity, jumps, flicker, coverage, each under a 22 px caption.
  EXPECT_EQ(figure.rows, 4 * (192 + 22));
  for (const char* f : {"left.png", "disparity_sgbm.png", "jumps_ours.png",
                        "flicker_ours-fused.png", "coverage_bm.png"}) {
    EXPECT_TRUE(exists(dir_ + "/files/" + f)) << f;
  }
}

TEST_F(EvaluateTool, ABagGivesTheSameFramesAsTheImageFiles) {
  ASSERT_EQ(
      evaluate("--bag " + dir_ + "/seq.bag --methods ours,bm --out " + dir_ + "/bag" + range()), 0)
      << dir_ << "/stderr.txt";
  const YAML::Node root = YAML::LoadFile(dir_ + "/bag/evaluation.json");
  EXPECT_EQ(root["frames"].as<int>(), 12);
  EXPECT_NE(root["input"].as<std::string>().find("rectified with its camera_info"),
            std::string::npos);
  const Figures f = independent(lefts_, rights_, false, min_d_, max_d_);
  // The bag's frames pass through the pipeline's rectification with the generator's camera_info
  // (no distortion, R = I: identity maps, up to float rounding in the maps, which bilinear
  // interpolation can turn into a grey level here and there). A 1-point margin on density
  // allows that and still fails a pairing or ordering error (those change density by far more
  // or change the frame count).
  EXPECT_NEAR(methodNode(root, "bm")["density_mean"].as<double>(), f.density_mean, 0.01);
}

TEST_F(EvaluateTool, AStaticPairHasNoJumpsForOpenCv) {
  ASSERT_EQ(evaluate("--left " + lefts_[0] + " --right " + rights_[0] +
                     " --repeat 4 --methods bm,sgbm --json " + dir_ + "/static.json" + range()),
            0);
  const YAML::Node root = YAML::LoadFile(dir_ + "/static.json");
  EXPECT_EQ(root["frames"].as<int>(), 4);
  for (const char* key : {"bm", "sgbm"}) {
    const YAML::Node m = methodNode(root, key);
    EXPECT_EQ(m["jump_pixels"].as<int64_t>(), 0) << key;  // deterministic on the same pair
    EXPECT_EQ(m["flicker_pixels"].as<int64_t>(), 0) << key;
    EXPECT_GT(m["compared_pixels"].as<int64_t>(), 0) << key;
  }
}

TEST_F(EvaluateTool, BadUsageExitsWithTwo) {
  EXPECT_EQ(evaluate("--left " + lefts_[0] + " --right " + rights_[0]), 2);  // no range
  EXPECT_EQ(
      evaluate("--left " + lefts_[0] + " --right " + rights_[0] + range() + " --methods ours,elas"),
      2);
  EXPECT_EQ(evaluate("--left " + lefts_[0] + " --right " + rights_[0] + range() + " --pan 5"),
            2);  // --pan needs --crop
  EXPECT_EQ(evaluate("--left " + dir_ + "/missing.png --right " + rights_[0] + range()), 1);
  // A bad number is refused, not read as 0 or as its leading digits.
  const std::string pair = "--left " + lefts_[0] + " --right " + rights_[0];
  EXPECT_EQ(evaluate(pair + range() + " --threads abc"), 2);
  EXPECT_EQ(evaluate(pair + range() + " --jump-px 2px"), 2);
  EXPECT_EQ(evaluate(pair + range() + " --flicker-window 16"), 2);  // odd only
  EXPECT_EQ(evaluate(pair + range() + " --flicker-window 1"), 2);
  EXPECT_EQ(evaluate("--left " + dir_ + "/seq/left/%06d.png --right " + dir_ +
                     "/seq/right/%06d.png --count 1x" + range()),
            2);
  EXPECT_EQ(evaluate(pair + " --min-disparity 0 --max-disparity 1e99"), 2);
}

// The same check on the real in-vivo recording (frames 1-60, search 0..127) when ../shared/data
// is present: real tissue has holes and jumps that a generated scene may not have.
TEST_F(EvaluateTool, OpenCvFiguresOnTheInVivoRecordingMatchAnIndependentComputation) {
  const std::string d = std::string(ES_SHARED_DATA) + "/real/hamlyn_invivo1";
  if (!exists(d + "/left/0001.png")) {
    GTEST_SKIP() << "absent: " << d << " (../shared/data beside the repository)";
  }
  ASSERT_EQ(evaluate("--left " + d + "/left/%04d.png --right " + d +
                     "/right/%04d.png --first 1 --count 60 --methods bm,sgbm --json " + dir_ +
                     "/invivo.json --min-disparity 0 --max-disparity 127"),
            0);
  const YAML::Node root = YAML::LoadFile(dir_ + "/invivo.json");
  std::vector<std::string> lefts, rights;
  for (int i = 1; i <= 60; ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "/%04d.png", i);
    lefts.push_back(d + "/left" + name);
    rights.push_back(d + "/right" + name);
  }
  for (const char* key : {"bm", "sgbm"}) {
    SCOPED_TRACE(key);
    const YAML::Node m = methodNode(root, key);
    ASSERT_TRUE(m);
    const Figures f = independent(lefts, rights, std::string(key) == "sgbm", 0, 127);
    EXPECT_EQ(m["jump_pixels"].as<int64_t>(), f.jumps);
    EXPECT_EQ(m["compared_pixels"].as<int64_t>(), f.compared);
    EXPECT_EQ(m["flicker_pixels"].as<int64_t>(), f.flicker);
    EXPECT_NEAR(m["density_mean"].as<double>(), f.density_mean, kJsonTol);
    EXPECT_NEAR(m["coverage_every_window"].as<double>(), f.covered, kJsonTol);
    EXPECT_NEAR(m["coverage_never"].as<double>(), f.never, kJsonTol);
  }
}

}  // namespace

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
