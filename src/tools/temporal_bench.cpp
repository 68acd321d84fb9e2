// endo_stereo_temporal_bench: the temporal-prior targets (density, bad2, coverage, time against
// SGBM) on a generated surgical sequence.
// For every frame of a synthetic 960x540 sequence (instrument, highlights, noise) it runs, on the
// same rectified gray frames in the same process:
//   1. Pipeline::process with the preset's temporal priors (priors, fusion, coverage), as the CLI
//      and the nodelet run it (the gray pair as mono8, already rectified),
//   2. the same Pipeline without priors (full range every frame; its own coverage),
//   3. OpenCV StereoSGBM (MODE_SGBM, blockSize 5, the same disparity range),
// and reports steady-state time per frame, bad2 among output pixels (against the exact ground
// truth, pixels seen by both cameras), density, and the share of central-region pixels updated
// within 10 frames. Writes a coverage picture and a fused disparity frame beside its input.
// `endo_stereo_temporal_bench --help` lists the flags.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/core/matcher.hpp"
#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/core/temporal.hpp"
#include "surgical_scene.hpp"
#include "tool_args.hpp"

namespace {

const char* kUsage = R"(endo_stereo_temporal_bench - temporal priors, fusion and coverage on a synthetic surgical sequence

Usage:
  endo_stereo_temporal_bench [options]

Options:
  --frames N          frames (default 100)
  --warmup N          first frames left out of the steady-state timing (default 5)
  --width W --height H  image size (default 960 x 540)
  --seed S            scene seed (default 1)
  --noise SIGMA       sensor noise, grey levels (default 1.5)
  --instrument-speed X  instrument speed factor (default 1)
  --params FILE.yaml  pipeline preset (matcher, filter, temporal sections are used)
  --set KEY=VALUE     override one parameter (repeatable), e.g. --set temporal.prior_radius_px=3
  --breakdown         per frame, where the bad pixels lie (instrument edge, highlight, ...)
  --levels            per frame, our matcher's outcome with priors: pixels searched with a narrowed
                      range, accepted per window size, rejected per criterion, match / filter ms
  --stages            after the run: the median time of each stage of a frame with priors (range
                      building, the matcher's preparation, search, edge measure and post-filters,
                      the prior/fusion/coverage update), steady state
  --threads N         worker threads of our matcher (0 = OpenCV's default; default 1).
                      SGBM's MODE_SGBM runs on one thread whatever this says.
  --no-sgbm           skip the SGBM baseline
  --no-baseline       skip our matcher without priors
  --out DIR           write coverage.png, fused.png (input | this frame | fused) and
                      results.json there (default: no files)
  --picture-frame N   frame shown in fused.png (default: the last)
  --pipeline          instead of the comparison: run the whole per-frame Pipeline (bgr8 input,
                      calibrated rectification with the scene's calibration, priors, the outputs
                      of the preset plus the point cloud) and print the median / minimum time of
                      each stage after the warm-up, and a checksum of the disparities and clouds
                      of all frames (equal checksums: identical outputs)
  --pipeline-no-cloud  the same without the point cloud and the rectified colour image (the
                      nodelet's work while only the disparity has listeners)
  --async-quality     with --pipeline: measure the rectification quality in the background, as
                      the nodelet does
  -h, --help          this text
)";

struct Score {
  int64_t output = 0, bad = 0, gt_pixels = 0;
  void add(const cv::Mat& disp, const cv::Mat& gt, const cv::Mat& nonocc) {
    for (int y = 0; y < disp.rows; ++y) {
      const float* d = disp.ptr<float>(y);
      const float* g = gt.ptr<float>(y);
      const uint8_t* m = nonocc.ptr<uint8_t>(y);
      for (int x = 0; x < disp.cols; ++x) {
        if (!m[x]) continue;
        ++gt_pixels;
        if (!std::isfinite(d[x])) continue;
        ++output;
        bad += std::abs(d[x] - g[x]) > 2.0f;
      }
    }
  }
  double bad2() const { return output ? double(bad) / double(output) : 0.0; }
  double density() const { return gt_pixels ? double(output) / double(gt_pixels) : 0.0; }
};

struct Timing {
  std::vector<double> ms;
  double mean() const {
    double s = 0;
    for (double v : ms) s += v;
    return ms.empty() ? 0.0 : s / ms.size();
  }
  double median() const {
    if (ms.empty()) return 0.0;
    std::vector<double> v = ms;
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  }
  double min() const { return ms.empty() ? 0.0 : *std::min_element(ms.begin(), ms.end()); }
  double max() const { return ms.empty() ? 0.0 : *std::max_element(ms.begin(), ms.end()); }
};

double msSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

cv::Mat sgbmDisparity(cv::Ptr<cv::StereoSGBM>& sgbm, const cv::Mat& l, const cv::Mat& r, int dmax) {
  cv::Mat raw, out;
  sgbm->compute(l, r, raw);
  raw.convertTo(out, CV_32F, 1.0 / 16.0);
  // Invalid pixels come back as (minDisparity - 1) * 16.
  out.setTo(std::numeric_limits<float>::quiet_NaN(), raw < sgbm->getMinDisparity() * 16);
  out.setTo(std::numeric_limits<float>::quiet_NaN(), out > dmax);
  return out;
}

// FNV-1a over a matrix's rows (type and size included): a checksum of outputs across builds.
void hashMat(const cv::Mat& m, uint64_t* h) {
  auto add = [h](const void* p, size_t n) {
    const uint8_t* b = static_cast<const uint8_t*>(p);
    for (size_t i = 0; i < n; ++i) *h = (*h ^ b[i]) * 1099511628211ull;
  };
  const int head[3] = {m.type(), m.rows, m.cols};
  add(head, sizeof(head));
  for (int y = 0; y < m.rows; ++y) add(m.ptr(y), m.cols * m.elemSize());
}

// --pipeline: the per-frame stages of Pipeline::process as the nodelet runs them.
int runPipelineStages(endo_stereo::SurgicalScene& scene, endo_stereo::PipelineParams pp, int frames,
                      int warmup, bool with_cloud, bool async_quality) {
  pp.rectify.mode = endo_stereo::RectifyMode::kCalibrated;
  pp.output.point_cloud = with_cloud;
  endo_stereo::Pipeline pipeline(pp);
  // Without a cloud: what the nodelet does while only the disparity has listeners.
  pipeline.setColorOutput(with_cloud);
  pipeline.setAsyncRectificationQuality(async_quality);
  const std::string e = pipeline.setCalibration(scene.calibration());
  if (!e.empty()) {
    std::cerr << "calibration refused: " << e << "\n";
    return 1;
  }
  Timing pre, rect, temporal, match, cloud, total;
  uint64_t h_disp = 1469598103934665603ull, h_cloud = h_disp;
  endo_stereo::SurgicalFrame frame;
  endo_stereo::PipelineOutput out;
  for (int i = 0; i < frames; ++i) {
    scene.render(i, frame);
    endo_stereo::StereoInput in{frame.left, frame.right, "bgr8", "bgr8", frame.stamp_s};
    std::string error;
    if (!pipeline.process(in, out, &error)) {
      std::cerr << "frame " << i << ": " << error << "\n";
      return 1;
    }
    hashMat(out.match.disparity, &h_disp);
    hashMat(out.cloud.xyz, &h_cloud);
    hashMat(out.cloud.bgr, &h_cloud);
    if (i < warmup) {
      // The start-up frames, one by one: what a node's first pairs cost.
      std::printf("  start-up frame %d: total %7.2f ms (preprocess %.2f, rectify %.2f, temporal "
                  "%.2f, match %.2f [preparation %.2f, edge %.2f, filters %.2f], cloud %.2f)\n",
                  i, out.total_ms, out.preprocess_ms, out.rectify_ms, out.temporal_ms,
                  out.match_ms, out.match.stats.prepare_ms, out.match.stats.edge_ms,
                  out.match.stats.filter_ms, out.cloud_ms);
      continue;
    }
    pre.ms.push_back(out.preprocess_ms);
    rect.ms.push_back(out.rectify_ms);
    temporal.ms.push_back(out.temporal_ms);
    match.ms.push_back(out.match_ms);
    cloud.ms.push_back(out.cloud_ms);
    total.ms.push_back(out.total_ms);
  }
  auto line = [](const char* name, const Timing& t) {
    std::printf("  %-13s median %8.2f ms  min %8.2f ms  max %8.2f ms\n", name, t.median(), t.min(),
                t.max());
  };
  std::printf("pipeline stages, frames %d..%d:\n", warmup, frames - 1);
  line("preprocess", pre);
  line("rectify", rect);
  line("temporal", temporal);
  line("match", match);
  line("cloud", cloud);
  line("total", total);
  line("outside match", [&] {
    Timing t;
    for (size_t k = 0; k < total.ms.size(); ++k) t.ms.push_back(total.ms[k] - match.ms[k]);
    return t;
  }());
  std::printf("checksum disparity %016llx cloud %016llx\n", (unsigned long long)h_disp,
              (unsigned long long)h_cloud);
  return 0;
}

cv::Mat labelled(const cv::Mat& img, const std::string& text) {
  cv::Mat out = img.clone();
  cv::putText(out, text, cv::Point(12, 32), cv::FONT_HERSHEY_SIMPLEX, 0.9, cv::Scalar(0, 0, 0), 4, cv::LINE_AA);
  cv::putText(out, text, cv::Point(12, 32), cv::FONT_HERSHEY_SIMPLEX, 0.9, cv::Scalar(255, 255, 255), 2, cv::LINE_AA);
  return out;
}

// The command line.
struct Options {
  endo_stereo::SurgicalSceneParams scene;
  int frames = 100, warmup = 5, threads = 1, picture_frame = -1;
  bool breakdown = false;
  bool levels = false;
  bool stages = false;
  bool run_sgbm = true, run_without = true, pipeline_stages = false, pipeline_cloud = true;
  bool async_quality = false;
  std::string out_dir;
  std::vector<std::string> overrides;
  std::string params_file;
};

// What the steps before the run return when the program goes on (otherwise: its exit status).
constexpr int kContinue = -1;

// Reads the flags into @p o. @return kContinue, 0 after --help, kExitUsage on bad usage.
int readOptions(int argc, char** argv, Options& o) {
  endo_stereo::tools::ArgReader args(argc, argv);
  try {
    while (args.next()) {
      if (args.is("-h") || args.is("--help")) {
        std::cout << kUsage;
        return 0;
      } else if (args.is("--frames")) {
        o.frames = args.integer();
      } else if (args.is("--warmup")) {
        o.warmup = args.integer();
      } else if (args.is("--width")) {
        o.scene.width = args.integer();
      } else if (args.is("--height")) {
        o.scene.height = args.integer();
      } else if (args.is("--seed")) {
        o.scene.seed = uint64_t(args.integer64());
      } else if (args.is("--instrument-speed")) {
        o.scene.instrument_speed = args.number();
      } else if (args.is("--noise")) {
        o.scene.noise_sigma = args.number();
      } else if (args.is("--params")) {
        o.params_file = args.text();
      } else if (args.is("--set")) {
        o.overrides.push_back(args.text());
      } else if (args.is("--levels")) {
        o.levels = true;
      } else if (args.is("--stages")) {
        o.stages = true;
      } else if (args.is("--breakdown")) {
        o.breakdown = true;
      } else if (args.is("--threads")) {
        o.threads = args.integer();
      } else if (args.is("--no-baseline")) {
        o.run_without = false;
      } else if (args.is("--no-sgbm")) {
        o.run_sgbm = false;
      } else if (args.is("--out")) {
        o.out_dir = args.text();
      } else if (args.is("--pipeline")) {
        o.pipeline_stages = true;
      } else if (args.is("--async-quality")) {
        o.async_quality = true;
      } else if (args.is("--pipeline-no-cloud")) {
        o.pipeline_stages = true;
        o.pipeline_cloud = false;
      } else if (args.is("--picture-frame")) {
        o.picture_frame = args.integer();
      } else {
        args.unknown();
      }
    }
  } catch (const endo_stereo::tools::UsageError& e) {
    std::cerr << e.what() << "\n";
    return endo_stereo::tools::kExitUsage;
  }
  return kContinue;
}

// The checks that need all the flags; makes the --out folder. @return kContinue or 2.
int checkOptions(Options& o) {
  if (o.frames < 2 || o.warmup < 0 || o.warmup >= o.frames) {
    std::cerr << "--frames must be >= 2 and 0 <= --warmup < --frames\n";
    return 2;
  }
  if (o.picture_frame < 0 || o.picture_frame >= o.frames) o.picture_frame = o.frames - 1;
  if (!o.out_dir.empty()) {
    // Made before the long run, so that a bad path fails now and not silently at the end.
    std::error_code ec;
    std::filesystem::create_directories(o.out_dir, ec);
    if (ec || !std::filesystem::is_directory(o.out_dir)) {
      std::cerr << "--out " << o.out_dir << ": cannot create the folder"
                << (ec ? ": " + ec.message() : std::string()) << "\n";
      return 2;
    }
  }
  const std::string scene_error = o.scene.validate();
  if (!scene_error.empty()) {
    std::cerr << scene_error << "\n";
    return 2;
  }
  return kContinue;
}

// The pipeline's parameters: the preset (--params, --set), the scene's disparity range
// [@p dmin, @p dmax] unless a --set gives another, --threads. @return kContinue or 2.
int pipelineParams(const Options& o, int dmin, int dmax, endo_stereo::PipelineParams& pp) {
  pp.matcher.min_disparity = dmin;
  pp.matcher.max_disparity = dmax;
  if (!o.params_file.empty()) {
    const std::string e = endo_stereo::loadPipelineParams(o.params_file, pp);
    if (!e.empty()) {
      std::cerr << e << "\n";
      return 2;
    }
    // The scene decides the range unless overridden below.
    pp.matcher.min_disparity = dmin;
    pp.matcher.max_disparity = dmax;
  }
  for (const std::string& ov : o.overrides) {
    const std::string e = endo_stereo::applyParamOverride(pp, ov);
    if (!e.empty()) {
      std::cerr << e << "\n";
      return 2;
    }
  }
  pp.matcher.num_threads = o.threads;
  return kContinue;
}

// Ours as users run it: Pipeline::process on the gray pair (already rectified, mono8), with the
// preset's priors (@p priors) or with priors off; fused output and coverage on.
endo_stereo::PipelineParams comparedParams(endo_stereo::PipelineParams p, bool priors) {
  p.rectify.mode = endo_stereo::RectifyMode::kPassThrough;
  p.output.point_cloud = false;
  p.output.fused = true;
  p.output.coverage = true;
  p.temporal.enabled = priors;
  return p;
}

// What the comparison adds up over the frames.
struct Totals {
  Timing t_with, t_without, t_sgbm;
  // --stages: priors and temporal update, prepare, search, edge, filters, the rest, total.
  Timing stage_ms[7];
  Score s_with, s_without, s_sgbm, s_fused, s_with_narrowed, s_with_full;
  int64_t narrowed = 0, hits = 0, deferred = 0, searched = 0;
  double width_sum = 0;
  int width_frames = 0;
  int64_t breakdown_with[4] = {0, 0, 0, 0}, breakdown_without[4] = {0, 0, 0, 0};
};

// --breakdown, one frame: where the bad pixels of the disparities with and without priors lie
// (near an instrument edge (10 px), in a highlight, elsewhere on the instrument, elsewhere);
// printed and added to @p t.
void countBadPixels(const endo_stereo::SurgicalFrame& frame, const cv::Mat& nonocc,
                    const cv::Mat& d_with, const cv::Mat& d_without, Totals& t) {
  cv::Mat edge;
  cv::Mat dil, ero;
  cv::dilate(frame.instrument_mask, dil, cv::Mat(), cv::Point(-1, -1), 10);
  cv::erode(frame.instrument_mask, ero, cv::Mat(), cv::Point(-1, -1), 10);
  edge = dil & ~ero;
  cv::Mat spec;
  cv::dilate(frame.left_specular, spec, cv::Mat(), cv::Point(-1, -1), 3);
  for (int k = 0; k < 2; ++k) {
    const cv::Mat& d = k == 0 ? d_with : d_without;
    cv::Mat err;
    cv::absdiff(d, frame.gt_disparity, err);
    const cv::Mat bad = (err > 2.0f) & nonocc;  // NaN compares false
    const int n_bad = cv::countNonZero(bad);
    const int n_edge = cv::countNonZero(bad & edge);
    const int n_spec = cv::countNonZero(bad & spec & ~edge);
    const int n_inst = cv::countNonZero(bad & frame.instrument_mask & ~edge & ~spec);
    int64_t* acc = k == 0 ? t.breakdown_with : t.breakdown_without;
    acc[0] += n_edge;
    acc[1] += n_spec;
    acc[2] += n_inst;
    acc[3] += n_bad - n_edge - n_spec - n_inst;
    std::fprintf(stderr,
                 "  %s: bad %d: instrument edge %d, highlight %d, instrument %d, other %d\n",
                 k == 0 ? "with   " : "without", n_bad, n_edge, n_spec, n_inst,
                 n_bad - n_edge - n_spec - n_inst);
  }
}

// The per-frame line on stderr: time, bad2 and density with and without priors, SGBM's time.
void printFrame(int i, const endo_stereo::SurgicalFrame& frame, const cv::Mat& nonocc,
                const cv::Mat& d_with, const cv::Mat& d_without, double ms_with, double ms_without,
                double ms_sgbm) {
  Score this_frame, this_frame_without;
  this_frame.add(d_with, frame.gt_disparity, nonocc);
  this_frame_without.add(d_without, frame.gt_disparity, nonocc);
  std::fprintf(
      stderr,
      "frame %3d: with priors %7.1f ms bad2 %.2f%% density %.1f%% | without %7.1f ms bad2 %.2f%% "
      "density %.1f%% | sgbm %7.1f ms\n",
      i, ms_with, 100.0 * this_frame.bad2(), 100.0 * this_frame.density(), ms_without,
      100.0 * this_frame_without.bad2(), 100.0 * this_frame_without.density(), ms_sgbm);
}

// --levels, one frame: our matcher's outcome with priors.
void printLevels(const endo_stereo::MatchStats& st) {
  std::string acc, rej;
  for (size_t k = 0; k < st.accepted_per_window.size(); ++k) {
    if (st.accepted_per_window[k])
      acc += " w" + std::to_string(k) + "=" + std::to_string(st.accepted_per_window[k]);
  }
  static const char* kNames[] = {"unsearched", "structure", "gap",    "lr",
                                 "edge",       "outlier",   "nopeak", "filled"};
  for (size_t k = 0; k < st.rejected.size() && k < 8; ++k) {
    rej += std::string(" ") + kNames[k] + "=" + std::to_string(st.rejected[k]);
  }
  std::fprintf(stderr, "  levels: narrowed %lld | accepted%s |%s | match %.1f ms filter %.1f ms\n",
               static_cast<long long>(st.prior_pixels), acc.c_str(), rej.c_str(), st.match_ms,
               st.filter_ms);
}

// The results as JSON (printed, and written to --out's results.json).
std::string resultsJson(const Options& o, const endo_stereo::PipelineParams& pp, const Totals& t,
                        const endo_stereo::CoverageStats& cov_with,
                        const endo_stereo::CoverageStats& cov_without) {
  char buf[8192];
  std::snprintf(
      buf, sizeof(buf),
      "{\n"
      "  \"frames\": %d, \"warmup\": %d, \"width\": %d, \"height\": %d, \"seed\": %llu,\n"
      "  \"disparity_range\": [%d, %d], \"threads\": %d,\n"
      "  \"ms_per_frame_with_priors\": {\"mean\": %.2f, \"median\": %.2f},\n"
      "  \"ms_per_frame_without_priors\": {\"mean\": %.2f, \"median\": %.2f},\n"
      "  \"ms_per_frame_sgbm\": {\"mean\": %.2f, \"median\": %.2f},\n"
      "  \"ratio_with_priors_to_sgbm\": %.4f,\n"
      "  \"bad2_with_priors\": %.5f, \"density_with_priors\": %.4f,\n"
      "  \"bad2_without_priors\": %.5f, \"density_without_priors\": %.4f,\n"
      "  \"bad2_with_priors_narrowed_pixels\": %.5f, \"bad2_with_priors_full_range_pixels\": %.5f,\n"
      "  \"bad_pixels_with_priors\": %lld, \"output_pixels_with_priors\": %lld,\n"
      "  \"bad_pixels_without_priors\": %lld, \"output_pixels_without_priors\": %lld,\n"
      "  \"bad2_fused\": %.5f, \"density_fused\": %.4f,\n"
      "  \"bad2_sgbm\": %.5f, \"density_sgbm\": %.4f,\n"
      "  \"prior_narrowed_share\": %.4f, \"prior_hit_share\": %.4f,\n"
      "  \"prior_deferred_share\": %.4f,\n"
      "  \"mean_narrowed_width_px\": %.2f,\n"
      "  \"coverage_with_priors\": {\"central_within_10\": %.4f, \"overall_within_10\": %.4f, \"central_never\": %.4f},\n"
      "  \"coverage_without_priors\": {\"central_within_10\": %.4f, \"overall_within_10\": %.4f, \"central_never\": %.4f}\n"
      "}\n",
      o.frames, o.warmup, o.scene.width, o.scene.height, (unsigned long long)o.scene.seed,
      pp.matcher.min_disparity, pp.matcher.max_disparity, o.threads, t.t_with.mean(),
      t.t_with.median(), t.t_without.mean(), t.t_without.median(), t.t_sgbm.mean(),
      t.t_sgbm.median(), t.t_sgbm.mean() > 0 ? t.t_with.mean() / t.t_sgbm.mean() : 0.0,
      t.s_with.bad2(), t.s_with.density(), t.s_without.bad2(), t.s_without.density(),
      t.s_with_narrowed.bad2(), t.s_with_full.bad2(), (long long)t.s_with.bad,
      (long long)t.s_with.output, (long long)t.s_without.bad, (long long)t.s_without.output,
      t.s_fused.bad2(), t.s_fused.density(), t.s_sgbm.bad2(), t.s_sgbm.density(),
      t.searched ? double(t.narrowed) / t.searched : 0.0,
      t.narrowed ? double(t.hits) / t.narrowed : 0.0,
      t.searched ? double(t.deferred) / t.searched : 0.0,
      t.width_frames ? t.width_sum / t.width_frames : 0.0, cov_with.central_share,
      cov_with.overall_share, cov_with.central_never, cov_without.central_share,
      cov_without.overall_share, cov_without.central_never);
  return buf;
}

// --stages: the median time of each stage of a frame with priors after the warm-up.
void printStages(const Totals& t, int warmup, int frames) {
  static const char* const names[7] = {"priors, fusion, coverage (temporal stage)",
                                       "matcher: preparation (buffers, views, integrals)",
                                       "matcher: search (all passes, all window sizes)",
                                       "matcher: edge measure",
                                       "matcher: post-filters",
                                       "the rest (pre-processing, conversions, counts)",
                                       "total with priors (Pipeline::process)"};
  std::printf(
      "stages of a frame with priors, median of frames %d..%d (ms; the medians do not add "
      "up exactly):\n",
      warmup, frames - 1);
  for (int k = 0; k < 7; ++k) std::printf("  %-50s %7.2f\n", names[k], t.stage_ms[k].median());
}

// --breakdown: the bad pixels of all frames after the warm-up, by where they lie.
void printBreakdown(const Totals& t) {
  std::printf(
      "bad pixels after warm-up (instrument edge, highlight, instrument, other): with priors "
      "%lld %lld %lld %lld, without %lld %lld %lld %lld\n",
      (long long)t.breakdown_with[0], (long long)t.breakdown_with[1],
      (long long)t.breakdown_with[2], (long long)t.breakdown_with[3],
      (long long)t.breakdown_without[0], (long long)t.breakdown_without[1],
      (long long)t.breakdown_without[2], (long long)t.breakdown_without[3]);
}

// The comparison on the gray frames: Pipeline::process with the preset's priors and without them,
// and OpenCV's StereoSGBM, frame by frame; then its report.
class Comparison {
 public:
  Comparison(const Options& o, const endo_stereo::PipelineParams& pp, int dmin, int dmax)
      : o_(o),
        pp_(pp),
        dmin_(dmin),
        dmax_(dmax),
        with_(comparedParams(pp, true)),
        without_(comparedParams(pp, false)) {
    with_.setColorOutput(false);
    without_.setColorOutput(false);
    const int num_disp = ((pp.matcher.max_disparity - pp.matcher.min_disparity + 1 + 15) / 16) * 16;
    sgbm_ = cv::StereoSGBM::create(pp.matcher.min_disparity, num_disp, 5, 8 * 25, 32 * 25, 1, 0, 10,
                                   100, 1, cv::StereoSGBM::MODE_SGBM);
  }

  // Every frame of @p scene. @return false after a frame the pipeline refused (reported).
  bool run(endo_stereo::SurgicalScene& scene) {
    endo_stereo::SurgicalFrame frame;
    for (int i = 0; i < o_.frames; ++i) {
      scene.render(i, frame);
      if (!compareFrame(i, frame)) return false;
    }
    return true;
  }

  // Prints the results (JSON, --stages, --breakdown) and writes --out's files. @return the exit
  // status.
  int report() {
    const endo_stereo::CoverageStats cov_with = with_.temporal().coverage().stats();
    const endo_stereo::CoverageStats cov_without = without_.temporal().coverage().stats();
    const std::string json = resultsJson(o_, pp_, t_, cov_with, cov_without);
    std::cout << json;
    if (o_.stages) printStages(t_, o_.warmup, o_.frames);
    if (o_.breakdown) printBreakdown(t_);
    return o_.out_dir.empty() ? 0 : writeFiles(json);
  }

 private:
  // One frame through the three methods, scored and added up.
  bool compareFrame(int i, const endo_stereo::SurgicalFrame& frame) {
    cv::Mat l, r;
    cv::cvtColor(frame.left, l, cv::COLOR_BGR2GRAY);
    cv::cvtColor(frame.right, r, cv::COLOR_BGR2GRAY);
    const cv::Mat nonocc = frame.visibility == endo_stereo::kVisibleBoth;
    const endo_stereo::StereoInput in{l, r, "mono8", "mono8", frame.stamp_s};
    // 1. with priors: the whole Pipeline::process call
    double ms_with = 0;
    if (!timedProcess(with_, in, out_with_, i, &ms_with)) return false;
    const endo_stereo::MatchResult& res_with = out_with_.match;
    if (i >= o_.warmup) recordStages(ms_with);
    // The range this frame searched (the tracker keeps it until the next frame).
    const endo_stereo::SearchRange* range =
        out_with_.priors_used ? &with_.temporal().range() : nullptr;
    // 2. without priors
    double ms_without = 0;
    if (o_.run_without) {
      if (!timedProcess(without_, in, out_without_, i, &ms_without)) return false;
    } else {
      out_without_.match.disparity =
          cv::Mat(l.size(), CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
    }
    const endo_stereo::MatchResult& res_without = out_without_.match;
    // 3. SGBM
    double ms_sgbm = 0;
    cv::Mat d_sgbm;
    if (o_.run_sgbm) {
      const auto t0 = std::chrono::steady_clock::now();
      d_sgbm = sgbmDisparity(sgbm_, l, r, pp_.matcher.max_disparity);
      ms_sgbm = msSince(t0);
    }
    if (i >= o_.warmup) {
      t_.t_with.ms.push_back(ms_with);
      t_.t_without.ms.push_back(ms_without);
      if (o_.run_sgbm) t_.t_sgbm.ms.push_back(ms_sgbm);
    }
    addScores(frame, nonocc, range, d_sgbm);
    if (range) addPriorStats(l.total());
    if (o_.breakdown && i >= o_.warmup) {
      countBadPixels(frame, nonocc, res_with.disparity, res_without.disparity, t_);
    }
    if (i == o_.picture_frame) keepPicture(frame);
    printFrame(i, frame, nonocc, res_with.disparity, res_without.disparity, ms_with, ms_without,
               ms_sgbm);
    if (o_.levels) printLevels(res_with.stats);
    return true;
  }

  // Pipeline::process, timed. @return false after a refused frame (reported).
  bool timedProcess(endo_stereo::Pipeline& pipeline, const endo_stereo::StereoInput& in,
                    endo_stereo::PipelineOutput& out, int i, double* ms) {
    const auto t0 = std::chrono::steady_clock::now();
    if (!pipeline.process(in, out, &error_)) {
      std::cerr << "frame " << i << ": " << error_ << "\n";
      return false;
    }
    *ms = msSince(t0);
    return true;
  }

  // --stages: the stages of this frame with priors.
  void recordStages(double ms_with) {
    const endo_stereo::MatchStats& st = out_with_.match.stats;
    t_.stage_ms[0].ms.push_back(out_with_.temporal_ms);
    t_.stage_ms[1].ms.push_back(st.prepare_ms);
    t_.stage_ms[2].ms.push_back(st.match_ms - st.prepare_ms - st.edge_ms);
    t_.stage_ms[3].ms.push_back(st.edge_ms);
    t_.stage_ms[4].ms.push_back(st.filter_ms);
    t_.stage_ms[5].ms.push_back(ms_with - out_with_.temporal_ms - st.match_ms - st.filter_ms);
    t_.stage_ms[6].ms.push_back(ms_with);
  }

  // Every method's output of this frame against the ground truth; @p range: what the frame with
  // priors searched (null: priors unused).
  void addScores(const endo_stereo::SurgicalFrame& frame, const cv::Mat& nonocc,
                 const endo_stereo::SearchRange* range, const cv::Mat& d_sgbm) {
    const cv::Mat& d_with = out_with_.match.disparity;
    t_.s_with.add(d_with, frame.gt_disparity, nonocc);
    if (range) {
      // Split the with-priors score by what each pixel searched.
      const cv::Mat full =
          (range->lo <= pp_.matcher.min_disparity) & (range->hi >= pp_.matcher.max_disparity);
      const cv::Mat deferred_mask = range->lo > range->hi;  // not searched this frame
      t_.s_with_narrowed.add(d_with, frame.gt_disparity, nonocc & ~full & ~deferred_mask);
      t_.s_with_full.add(d_with, frame.gt_disparity, nonocc & full);
    }
    t_.s_without.add(out_without_.match.disparity, frame.gt_disparity, nonocc);
    t_.s_fused.add(out_with_.fused_disparity, frame.gt_disparity, nonocc);
    if (o_.run_sgbm) t_.s_sgbm.add(d_sgbm, frame.gt_disparity, nonocc);
  }

  // The priors' figures of a frame that used them, over its @p pixels.
  void addPriorStats(size_t pixels) {
    const endo_stereo::TemporalPriorStats& ps = out_with_.prior_stats;
    t_.narrowed += ps.narrowed_pixels;
    t_.hits += ps.prior_hits;
    t_.deferred += ps.deferred_pixels;
    t_.searched += int64_t(pixels);
    t_.width_sum += ps.mean_narrowed_width_px;
    ++t_.width_frames;
  }

  // The frame shown in fused.png.
  void keepPicture(const endo_stereo::SurgicalFrame& frame) {
    picture_left_ = frame.left.clone();
    picture_disp_ = endo_stereo::colorizeDisparity(out_with_.match.disparity, dmin_, dmax_);
    picture_fused_ = endo_stereo::colorizeDisparity(out_with_.fused_disparity, dmin_, dmax_);
  }

  // --out: results.json, the coverage pictures and fused.png. @return the exit status.
  int writeFiles(const std::string& json_text) {
    const std::string& out_dir = o_.out_dir;
    std::ofstream json(out_dir + "/results.json");
    json << json_text;
    bool ok = static_cast<bool>(json);
    ok &= cv::imwrite(out_dir + "/coverage.png",
                      labelled(with_.temporal().coverage().colorImage(),
                               "longest run without update (0 .. 20+ frames)"));
    // The run without priors (unless --no-baseline) has a coverage map of its own.
    if (o_.run_without) {
      ok &= cv::imwrite(out_dir + "/coverage_without_priors.png",
                        labelled(without_.temporal().coverage().colorImage(),
                                 "no priors: longest run without update"));
    }
    cv::Mat row;
    cv::hconcat(std::vector<cv::Mat>{labelled(picture_left_, "input (left)"),
                                     labelled(picture_disp_, "this frame"),
                                     labelled(picture_fused_, "fused (<= 10 frames old)")},
                row);
    ok &= cv::imwrite(out_dir + "/fused.png", row);
    if (!ok) {
      std::cerr << "--out " << out_dir << ": could not write results.json and the pictures\n";
      return 1;
    }
    std::cout << "written: " << out_dir << "/results.json, coverage.png, "
              << (o_.run_without ? "coverage_without_priors.png, " : "") << "fused.png\n";
    return 0;
  }

  const Options& o_;
  const endo_stereo::PipelineParams pp_;
  const int dmin_, dmax_;
  endo_stereo::Pipeline with_, without_;
  cv::Ptr<cv::StereoSGBM> sgbm_;
  endo_stereo::PipelineOutput out_with_, out_without_;
  std::string error_;
  Totals t_;
  cv::Mat picture_left_, picture_disp_, picture_fused_;
};

}  // namespace

int main(int argc, char** argv) {
  Options o;
  int rc = readOptions(argc, argv, o);
  if (rc == kContinue) rc = checkOptions(o);
  if (rc != kContinue) return rc;
  endo_stereo::SurgicalScene scene(o.scene);
  int dmin = 0, dmax = 0;
  scene.suggestedDisparityRange(&dmin, &dmax);
  endo_stereo::PipelineParams pp;
  rc = pipelineParams(o, dmin, dmax, pp);
  if (rc != kContinue) return rc;
  cv::setNumThreads(o.threads);
  if (o.pipeline_stages) {
    return runPipelineStages(scene, pp, o.frames, o.warmup, o.pipeline_cloud, o.async_quality);
  }
  Comparison comparison(o, pp, dmin, dmax);
  if (!comparison.run(scene)) return 1;
  return comparison.report();
}
