// endo_stereo_eval: scores the robust matcher on pairs with ground truth, for tuning the presets
// and recording their figures; with --peers beside OpenCV StereoBM and StereoSGBM (the settings of
// sequence_evaluation.hpp) on the same pairs.
//
//   endo_stereo_eval [--data DIR] [--params FILE.yaml] [--set section.field=value]...
//                    [--scenes tsukuba,venus,teddy | --no-middlebury] [--sweep field=v1,v2,...]
//                    [--detail] [--gt-pair DIR --gt-range MIN:MAX]... [--peers [--json FILE]]
//
// DIR holds one folder per Middlebury scene (default ../shared/data/middlebury relative to the
// repository), scored in its nonocc mask. --gt-pair adds a pair in the layout of SCARED's
// rectified keyframes: left.png, right.png, disparity_left.tiff (float px, 0 = none),
// occlusion_left.png (scored where 255), searched over MIN..MAX.
// Each pair runs through Pipeline::process as the first frame of a stream (what endo_stereo_cli
// does with a single pair); every section of FILE applies. The search range of a Middlebury
// scene is 0 .. max disparity from its info.txt, unless --set matcher.max_disparity=... is given.
// --peers prints, per pair and method, bad2 and bad3 (shares of output pixels off by more than
// 2 / 3 px), the mean error over output pixels, density (output pixels / ground-truth pixels in
// the mask) and the time of one run; --json writes the same.

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <map>
#include <fstream>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "endo_stereo/core/evaluation.hpp"
#include "endo_stereo/core/matcher.hpp"
#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/core/sequence_evaluation.hpp"
#include "json_writer.hpp"
#include "tool_args.hpp"

namespace es = endo_stereo;
using endo_stereo::tools::splitList;

namespace {

// One pair through Pipeline::process, as endo_stereo_cli runs a single pair (already rectified
// input, the first frame of a stream): the figures are what a user of the CLI or the nodelet gets.
// @p ms_taken is the whole process() call.
bool runPipeline(const es::PipelineParams& params, const es::MiddleburyScene& s,
                 es::MatchResult& result, double& ms_taken, std::string& error) {
  es::Pipeline pipeline(params);
  es::PipelineOutput out;
  const es::StereoInput in{s.left, s.right, "mono8", "mono8", 0.0};
  const auto t0 = std::chrono::steady_clock::now();
  const bool ok = pipeline.process(in, out, &error);
  ms_taken = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                 .count();
  result = out.match;
  return ok;
}

// A rectified pair in the layout of SCARED's keyframes (see the header comment).
es::MiddleburyScene loadGtPair(const std::string& dir, int min_d, int max_d) {
  es::MiddleburyScene s;
  const size_t end = dir.find_last_not_of('/');
  const std::string trimmed = dir.substr(0, end == std::string::npos ? 0 : end + 1);
  s.name = trimmed.substr(trimmed.find_last_of('/') == std::string::npos
                              ? 0
                              : trimmed.find_last_of('/') + 1);
  s.left = cv::imread(dir + "/left.png", cv::IMREAD_GRAYSCALE);
  s.right = cv::imread(dir + "/right.png", cv::IMREAD_GRAYSCALE);
  const cv::Mat gt = cv::imread(dir + "/disparity_left.tiff", cv::IMREAD_UNCHANGED);
  const cv::Mat occ = cv::imread(dir + "/occlusion_left.png", cv::IMREAD_GRAYSCALE);
  if (s.left.empty() || s.right.empty() || gt.empty() || occ.empty()) {
    throw std::runtime_error("cannot read left.png, right.png, disparity_left.tiff and "
                             "occlusion_left.png in " + dir);
  }
  if (gt.type() != CV_32FC1 || gt.size() != s.left.size() || s.right.size() != s.left.size() ||
      occ.size() != s.left.size()) {
    throw std::runtime_error(dir + ": sizes differ or disparity_left.tiff is not float");
  }
  s.gt = gt.clone();
  s.gt.setTo(std::numeric_limits<float>::quiet_NaN(), gt <= 0.f);
  s.nonocc = occ == 255;
  s.disc = cv::Mat::zeros(s.left.size(), CV_8UC1);
  s.all = occ > 0;
  (void)min_d;  // the caller keeps the range's start; the scene records its end
  s.max_disp = max_d;
  return s;
}

// Share of output pixels in the mask with |d - gt| > t.
double shareAbove(const cv::Mat& d, const cv::Mat& gt, const cv::Mat& mask, double t) {
  int64_t out = 0, bad = 0;
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      const float v = d.at<float>(y, x), g = gt.at<float>(y, x);
      if (!mask.at<uint8_t>(y, x) || !std::isfinite(g) || !std::isfinite(v)) continue;
      ++out;
      bad += std::fabs(v - g) > t;
    }
  }
  return out ? double(bad) / out : 0.0;
}

// The command line.
struct Options {
  Options() {
    // Every section applies (--params, --set); the input is rectified, so no rectification runs,
    // and nothing but the disparity is produced.
    pp.rectify.mode = es::RectifyMode::kPassThrough;
    pp.output.point_cloud = false;
  }
  std::string data = std::string(ES_SOURCE_DIR) + "/../shared/data/middlebury";
  std::vector<std::string> scenes = {"tsukuba", "venus", "teddy"};
  es::PipelineParams pp;
  bool detail = false;
  std::string dump_dir;
  bool fixed_max = false;  // --set matcher.max_disparity=... given
  std::string sweep_key;
  std::vector<std::string> sweep_values{""};
  bool peers = false, middlebury = true;
  std::string json_path;
  std::vector<std::pair<std::string, std::string>> gt_pairs;  // folder, "MIN:MAX"
};

// What the steps before the scoring return when the program goes on (otherwise: its exit status).
constexpr int kContinue = -1;

const char* const kUsage =
    "usage: endo_stereo_eval [--data DIR] [--params FILE] [--set k=v]... "
    "[--scenes a,b | --no-middlebury] [--sweep k=v1,v2] [--detail] [--dump DIR] "
    "[--gt-pair DIR --gt-range MIN:MAX]... [--peers [--json FILE]]\n"
    "Scores our pipeline (and with --peers OpenCV BM and SGBM) against ground truth: the "
    "Middlebury scenes under --data (default ../shared/data/middlebury) and each --gt-pair folder, "
    "searched over its --gt-range.\n";

// Reads the flags into @p o (--params and --set apply to its parameters as they come).
// @return kContinue or 2.
int readOptions(int argc, char** argv, Options& o) {
  endo_stereo::tools::ArgReader args(argc, argv);
  try {
    while (args.next()) {
      const std::string a = args.flag();
      auto next = [&] { return args.text(); };
      if (a == "--data") {
        o.data = next();
      } else if (a == "--params") {
        const std::string err = es::loadPipelineParams(next(), o.pp);
        if (!err.empty()) {
          std::cerr << err << "\n";
          return 2;
        }
      } else if (a == "--set") {
        const std::string kv = next();
        const size_t eq = kv.find('=');
        const std::string err =
            eq == std::string::npos
                ? "expected key=value: " + kv
                : es::setPipelineParam(o.pp, kv.substr(0, eq), kv.substr(eq + 1));
        if (!err.empty()) {
          std::cerr << err << "\n";
          return 2;
        }
        if (kv.rfind("matcher.max_disparity", 0) == 0) o.fixed_max = true;
      } else if (a == "--scenes") {
        o.scenes = splitList(next(), ',');
      } else if (a == "--sweep") {
        const std::string kv = next();
        const size_t eq = kv.find('=');
        if (eq == std::string::npos) {
          std::cerr << "--sweep key=v1,v2,...\n";
          return 2;
        }
        o.sweep_key = kv.substr(0, eq);
        o.sweep_values = splitList(kv.substr(eq + 1), ',');
      } else if (a == "--dump") {
        o.dump_dir = next();
      } else if (a == "--detail") {
        o.detail = true;
      } else if (a == "--peers") {
        o.peers = true;
      } else if (a == "--json") {
        o.json_path = next();
      } else if (a == "--no-middlebury") {
        o.middlebury = false;
      } else if (a == "--gt-pair") {
        o.gt_pairs.emplace_back(next(), "");
      } else if (a == "--gt-range") {
        if (o.gt_pairs.empty() || !o.gt_pairs.back().second.empty()) {
          std::cerr << "--gt-range MIN:MAX follows its --gt-pair DIR\n";
          return 2;
        }
        o.gt_pairs.back().second = next();
      } else if (a == "--help" || a == "-h") {
        std::cout << kUsage;
        return 0;
      } else {
        std::cerr << "unknown argument '" << a << "'\n" << kUsage;
        return 2;
      }
    }
  } catch (const endo_stereo::tools::UsageError& e) {
    std::cerr << e.what() << "\n";
    return endo_stereo::tools::kExitUsage;
  }
  return kContinue;
}

// A pair to score and the start of its search range.
struct Pair {
  es::MiddleburyScene scene;
  int min_disparity = 0;
};

// The Middlebury scenes (unless --no-middlebury), then the --gt-pair pairs.
// @return kContinue or the exit status.
int loadPairs(const Options& o, std::vector<Pair>& pairs) {
  for (const auto& name : o.middlebury ? o.scenes : std::vector<std::string>{}) {
    try {
      pairs.push_back({es::loadMiddleburyScene(o.data + "/" + name), 0});
    } catch (const std::exception& e) {
      std::cerr << e.what() << "\n";
      return 1;
    }
  }
  for (const auto& [dir, range] : o.gt_pairs) {
    int lo = 0, hi = 0;
    const std::vector<std::string> ends = splitList(range, ':');
    if (ends.size() != 2 || !endo_stereo::tools::parseInt(ends[0], &lo) ||
        !endo_stereo::tools::parseInt(ends[1], &hi) || lo < 0 || hi < lo) {
      std::cerr << "--gt-pair " << dir << " needs --gt-range MIN:MAX (got '" << range << "')\n";
      return 2;
    }
    try {
      pairs.push_back({loadGtPair(dir, lo, hi), lo});
    } catch (const std::exception& e) {
      std::cerr << e.what() << "\n";
      return 1;
    }
  }
  if (pairs.empty()) {
    std::cerr << "no pair to score\n";
    return 2;
  }
  return kContinue;
}

// @p base with the search range of @p pair: from its start to the scene's end, unless --set gave
// matcher.max_disparity (@p fixed_max). @return the parameters' error, empty when valid.
std::string pairParams(const es::PipelineParams& base, bool fixed_max, const Pair& pair,
                       es::PipelineParams& ps) {
  ps = base;
  ps.matcher.min_disparity = pair.min_disparity;
  if (!fixed_max) ps.matcher.max_disparity = pair.scene.max_disp;
  return ps.validate();
}

// --peers: one method ("ours", "OpenCV BM" or "OpenCV SGBM", @p num_d disparities) on a pair: its
// disparity and the time of one run. @return false when ours failed (reported).
bool runPeer(const std::string& method, const es::PipelineParams& ps, const Pair& pair, int num_d,
             cv::Mat& d, double& ms_taken) {
  const es::MiddleburyScene& s = pair.scene;
  const int lo = pair.min_disparity;
  const auto t0 = std::chrono::steady_clock::now();
  if (method == "ours") {
    es::MatchResult r;
    std::string error;
    if (!runPipeline(ps, s, r, ms_taken, error)) {
      std::cerr << s.name << ": " << error << "\n";
      return false;
    }
    d = r.disparity;
    return true;
  }
  cv::Ptr<cv::StereoMatcher> m;
  if (method == "OpenCV BM") {
    m = es::makeReferenceBm(lo, num_d);
  } else {
    m = es::makeReferenceSgbm(lo, num_d);
  }
  cv::Mat raw;
  m->compute(s.left, s.right, raw);
  d = es::referenceDisparityToFloat(raw, lo);
  ms_taken =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

// --peers, one pair: ours, OpenCV BM and SGBM, a table row and a JSON object each.
// @return 0, or 1 when ours failed.
int scorePeers(const Pair& pair, const es::PipelineParams& ps, endo_stereo::tools::JsonWriter& j) {
  const es::MiddleburyScene& s = pair.scene;
  const int lo = pair.min_disparity;
  const es::MatcherParams& ms = ps.matcher;
  const int num_d = es::referenceNumDisparities(lo, ms.max_disparity);
  j.beginObject();
  j.key("pair").value(s.name).key("width").value(s.left.cols).key("height").value(s.left.rows);
  j.key("min_disparity").value(lo).key("max_disparity").value(ms.max_disparity);
  j.key("methods").beginArray();
  for (const char* method : {"ours", "OpenCV BM", "OpenCV SGBM"}) {
    cv::Mat d;
    double ms_taken = 0.0;
    if (!runPeer(method, ps, pair, num_d, d, ms_taken)) return 1;
    const es::DisparityScore sc = es::scoreDisparity(d, s.gt, s.nonocc);
    const double bad3 = shareAbove(d, s.gt, s.nonocc, 3.0);
    std::printf("| %s %dx%d, %d..%d | %s | %.2f | %.2f | %.2f | %.1f | %.1f |\n", s.name.c_str(),
                s.left.cols, s.left.rows, lo, ms.max_disparity, method, 100 * sc.bad2, 100 * bad3,
                sc.mean_abs_error, 100 * sc.density, ms_taken);
    j.beginObject();
    j.key("method").value(method);
    j.key("bad2").value(sc.bad2).key("bad3").value(bad3);
    j.key("mean_abs_error_px").value(sc.mean_abs_error).key("density").value(sc.density);
    j.key("n_out").value(sc.n_out).key("n_gt").value(sc.n_gt).key("ms").value(ms_taken);
    j.endObject();
  }
  j.endArray();
  j.endObject();
  return 0;
}

// --peers: ours and OpenCV's matchers on the same gray pairs, same range (OpenCV's rounded up to a
// multiple of 16 disparities); the table, and --json. @return the exit status.
int runPeers(const Options& o, const std::vector<Pair>& pairs) {
  endo_stereo::tools::JsonWriter j;
  j.beginObject();
  j.key("tool").value("endo_stereo_eval --peers");
  j.key("pairs").beginArray();
  std::printf(
      "| pair | method | bad2 %% | bad3 %% | mean error px | density %% | ms |\n"
      "|---|---|---:|---:|---:|---:|---:|\n");
  for (const Pair& pair : pairs) {
    es::PipelineParams ps;
    const std::string err = pairParams(o.pp, o.fixed_max, pair, ps);
    if (!err.empty()) {
      std::cerr << err << "\n";
      return 2;
    }
    const int rc = scorePeers(pair, ps, j);
    if (rc != 0) return rc;
  }
  j.endArray();
  j.endObject();
  if (!o.json_path.empty()) {
    std::ofstream f(o.json_path);
    f << j.str();
    if (!f) {
      std::cerr << "cannot write " << o.json_path << "\n";
      return 1;
    }
  }
  return 0;
}

// --dump: the error map of a disparity. Grey = right (|e| <= 1), yellow = 1 < |e| <= 2, red =
// |e| > 2, blue = output outside the nonocc mask; rejected: magenta = edge, dark blue = peak gap,
// teal = left-right, orange = no peak, white = outlier, green = structure, black = not searched.
cv::Mat errorMap(const es::MiddleburyScene& s, const es::MatchResult& r) {
  cv::Mat vis(s.gt.size(), CV_8UC3, cv::Scalar(0, 0, 0));
  for (int y = 0; y < s.gt.rows; ++y) {
    for (int x = 0; x < s.gt.cols; ++x) {
      const float d = r.disparity.at<float>(y, x), g = s.gt.at<float>(y, x);
      cv::Vec3b c(0, 0, 0);
      if (!std::isnan(d)) {
        if (!s.nonocc.at<uint8_t>(y, x) || std::isnan(g))
          c = cv::Vec3b(255, 0, 0);
        else if (std::fabs(d - g) > 2)
          c = cv::Vec3b(0, 0, 255);
        else if (std::fabs(d - g) > 1)
          c = cv::Vec3b(0, 255, 255);
        else
          c = cv::Vec3b(160, 160, 160);
      } else {
        const int code = r.code.at<uint8_t>(y, x);
        if (code == es::kCodeRejectEdge)
          c = cv::Vec3b(255, 0, 255);
        else if (code == es::kCodeRejectPeakGap)
          c = cv::Vec3b(120, 40, 0);
        else if (code == es::kCodeRejectLeftRight)
          c = cv::Vec3b(120, 120, 0);
        else if (code == es::kCodeNoPeak)
          c = cv::Vec3b(0, 100, 200);
        else if (code == es::kCodeRejectOutlier)
          c = cv::Vec3b(255, 255, 255);
        else if (code == es::kCodeRejectStructure)
          c = cv::Vec3b(0, 90, 0);
      }
      vis.at<cv::Vec3b>(y, x) = c;
    }
  }
  return vis;
}

// --detail: per accepting window, its count and bad2 within nonocc.
void printWindowScores(const es::MiddleburyScene& s, const es::MatchResult& r,
                       const es::MatcherParams& ms) {
  for (int k = 0; k < 16; ++k) {
    int64_t n = 0, bad = 0;
    for (int y = 0; y < s.gt.rows; ++y) {
      for (int x = 0; x < s.gt.cols; ++x) {
        if (!s.nonocc.at<uint8_t>(y, x) || std::isnan(s.gt.at<float>(y, x))) continue;
        if (r.code.at<uint8_t>(y, x) != es::kCodeAcceptedBase + k) continue;
        const float d = r.disparity.at<float>(y, x);
        if (std::isnan(d)) continue;
        ++n;
        if (std::fabs(d - s.gt.at<float>(y, x)) > 2) ++bad;
      }
    }
    if (n)
      std::printf("    window %2d: %7lld px, bad2 %.2f%%\n",
                  ms.window_min_px + k * ms.window_step_px, static_cast<long long>(n),
                  100.0 * bad / n);
  }
}

// --detail: the codes within nonocc (and of those, near discontinuities), then over the image.
void printCodes(const es::MiddleburyScene& s, const es::MatchResult& r) {
  int64_t in_nonocc[32] = {0}, in_disc[32] = {0};
  for (int y = 0; y < s.gt.rows; ++y) {
    for (int x = 0; x < s.gt.cols; ++x) {
      if (!s.nonocc.at<uint8_t>(y, x) || std::isnan(s.gt.at<float>(y, x))) continue;
      const int c = std::min<int>(31, r.code.at<uint8_t>(y, x));
      ++in_nonocc[c];
      if (s.disc.at<uint8_t>(y, x)) ++in_disc[c];
    }
  }
  std::printf("    nonocc codes (of which near disc):");
  for (int c = 0; c < es::kNumRejectCodes; ++c) {
    std::printf(" %d:%lld(%lld)", c, static_cast<long long>(in_nonocc[c]),
                static_cast<long long>(in_disc[c]));
  }
  std::printf("\n");
  std::printf("    codes:");
  for (int c = 0; c < es::kNumRejectCodes; ++c) {
    std::printf(" %d:%lld", c, static_cast<long long>(r.stats.rejected[c]));
  }
  std::printf("\n");
}

// Without --peers, one --sweep value @p sv (the only run without --sweep): a row per pair with
// its --dump and --detail, then the summary. @return the exit status.
int sweepValue(const Options& o, const std::string& sv, const std::vector<Pair>& pairs) {
  es::PipelineParams swept = o.pp;
  if (!o.sweep_key.empty()) {
    const std::string err = es::setPipelineParam(swept, o.sweep_key, sv);
    if (!err.empty()) {
      std::cerr << err << "\n";
      return 2;
    }
  }
  const char* sweep_label = o.sweep_key.empty() ? "-" : sv.c_str();
  double worst_b2 = 0, sum_b2 = 0, min_dens = 1;
  for (const Pair& pair : pairs) {
    const es::MiddleburyScene& s = pair.scene;
    es::PipelineParams ps;
    const std::string err = pairParams(swept, o.fixed_max, pair, ps);
    if (!err.empty()) {
      std::cerr << err << "\n";
      return 2;
    }
    es::MatchResult r;
    double ms_taken = 0.0;
    std::string error;
    if (!runPipeline(ps, s, r, ms_taken, error)) {
      std::cerr << s.name << ": " << error << "\n";
      return 1;
    }
    const es::DisparityScore sc = es::scoreDisparity(r.disparity, s.gt, s.nonocc);
    const es::DisparityScore dc = es::scoreDisparity(r.disparity, s.gt, s.disc);
    std::printf("%-10s %-8s %7.2f %7.2f %8.1f %7.3f %8.2f %8.1f %8lld\n", sweep_label,
                s.name.c_str(), 100 * sc.bad1, 100 * sc.bad2, 100 * sc.density, sc.mean_abs_error,
                100 * dc.bad2, ms_taken, static_cast<long long>(r.stats.valid_pixels));
    worst_b2 = std::max(worst_b2, sc.bad2);
    sum_b2 += sc.bad2;
    min_dens = std::min(min_dens, sc.density);
    if (!o.dump_dir.empty()) {
      cv::imwrite(o.dump_dir + "/" + s.name + "_" + (sv.empty() ? "run" : sv) + ".png",
                  errorMap(s, r));
    }
    if (o.detail) {
      printWindowScores(s, r, ps.matcher);
      printCodes(s, r);
    }
  }
  std::printf("%-10s %-8s worst bad2 %.2f%%  mean bad2 %.2f%%  min density %.1f%%\n", sweep_label,
              "ALL", 100 * worst_b2, 100 * sum_b2 / pairs.size(), 100 * min_dens);
  return 0;
}

// Without --peers: the table of every --sweep value on every pair. @return the exit status.
int runSweep(const Options& o, const std::vector<Pair>& pairs) {
  std::printf("%-10s %-8s %7s %7s %8s %7s %8s %8s %8s\n", "sweep", "scene", "bad1%", "bad2%",
              "density%", "mae", "disc_b2%", "ms", "valid");
  for (const std::string& sv : o.sweep_values) {
    const int rc = sweepValue(o, sv, pairs);
    if (rc != 0) return rc;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  int rc = readOptions(argc, argv, o);
  if (rc != kContinue) return rc;
  std::vector<Pair> pairs;
  rc = loadPairs(o, pairs);
  if (rc != kContinue) return rc;
  return o.peers ? runPeers(o, pairs) : runSweep(o, pairs);
}
