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

}  // namespace

int main(int argc, char** argv) {
  endo_stereo::SurgicalSceneParams sp;
  endo_stereo::PipelineParams pp;
  int frames = 100, warmup = 5, threads = 1, picture_frame = -1;
  bool breakdown = false;
  bool levels = false;
  bool stages = false;
  bool run_sgbm = true, run_without = true, pipeline_stages = false, pipeline_cloud = true;
  bool async_quality = false;
  std::string out_dir;
  std::vector<std::string> overrides;
  std::string params_file;
  endo_stereo::tools::ArgReader args(argc, argv);
  try {
    while (args.next()) {
      if (args.is("-h") || args.is("--help")) {
        std::cout << kUsage;
        return 0;
      } else if (args.is("--frames")) {
        frames = args.integer();
      } else if (args.is("--warmup")) {
        warmup = args.integer();
      } else if (args.is("--width")) {
        sp.width = args.integer();
      } else if (args.is("--height")) {
        sp.height = args.integer();
      } else if (args.is("--seed")) {
        sp.seed = uint64_t(args.integer64());
      } else if (args.is("--instrument-speed")) {
        sp.instrument_speed = args.number();
      } else if (args.is("--noise")) {
        sp.noise_sigma = args.number();
      } else if (args.is("--params")) {
        params_file = args.text();
      } else if (args.is("--set")) {
        overrides.push_back(args.text());
      } else if (args.is("--levels")) {
        levels = true;
      } else if (args.is("--stages")) {
        stages = true;
      } else if (args.is("--breakdown")) {
        breakdown = true;
      } else if (args.is("--threads")) {
        threads = args.integer();
      } else if (args.is("--no-baseline")) {
        run_without = false;
      } else if (args.is("--no-sgbm")) {
        run_sgbm = false;
      } else if (args.is("--out")) {
        out_dir = args.text();
      } else if (args.is("--pipeline")) {
        pipeline_stages = true;
      } else if (args.is("--async-quality")) {
        async_quality = true;
      } else if (args.is("--pipeline-no-cloud")) {
        pipeline_stages = true;
        pipeline_cloud = false;
      } else if (args.is("--picture-frame")) {
        picture_frame = args.integer();
      } else {
        args.unknown();
      }
    }
  } catch (const endo_stereo::tools::UsageError& e) {
    std::cerr << e.what() << "\n";
    return endo_stereo::tools::kExitUsage;
  }
  if (frames < 2 || warmup < 0 || warmup >= frames) {
    std::cerr << "--frames must be >= 2 and 0 <= --warmup < --frames\n";
    return 2;
  }
  if (picture_frame < 0 || picture_frame >= frames) picture_frame = frames - 1;
  if (!out_dir.empty()) {
    // Made before the long run, so that a bad path fails now and not silently at the end.
    std::error_code ec;
    std::filesystem::create_directories(out_dir, ec);
    if (ec || !std::filesystem::is_directory(out_dir)) {
      std::cerr << "--out " << out_dir << ": cannot create the folder"
                << (ec ? ": " + ec.message() : std::string()) << "\n";
      return 2;
    }
  }
  const std::string scene_error = sp.validate();
  if (!scene_error.empty()) {
    std::cerr << scene_error << "\n";
    return 2;
  }
  endo_stereo::SurgicalScene scene(sp);
  int dmin = 0, dmax = 0;
  scene.suggestedDisparityRange(&dmin, &dmax);
  pp.matcher.min_disparity = dmin;
  pp.matcher.max_disparity = dmax;
  if (!params_file.empty()) {
    const std::string e = endo_stereo::loadPipelineParams(params_file, pp);
    if (!e.empty()) {
      std::cerr << e << "\n";
      return 2;
    }
    // The scene decides the range unless overridden below.
    pp.matcher.min_disparity = dmin;
    pp.matcher.max_disparity = dmax;
  }
  for (const std::string& o : overrides) {
    const std::string e = endo_stereo::applyParamOverride(pp, o);
    if (!e.empty()) {
      std::cerr << e << "\n";
      return 2;
    }
  }
  pp.matcher.num_threads = threads;
  cv::setNumThreads(threads);
  if (pipeline_stages) return runPipelineStages(scene, pp, frames, warmup, pipeline_cloud,
                                                 async_quality);
  // Ours as users run it: Pipeline::process on the gray pair (already rectified, mono8), with the
  // preset's priors and with priors off; fused output and coverage on.
  endo_stereo::PipelineParams with = pp, without = pp;
  for (endo_stereo::PipelineParams* q : {&with, &without}) {
    q->rectify.mode = endo_stereo::RectifyMode::kPassThrough;
    q->output.point_cloud = false;
    q->output.fused = true;
    q->output.coverage = true;
  }
  with.temporal.enabled = true;
  without.temporal.enabled = false;
  endo_stereo::Pipeline pipeline_with(with), pipeline_without(without);
  pipeline_with.setColorOutput(false);
  pipeline_without.setColorOutput(false);
  endo_stereo::PipelineOutput out_with, out_without;
  std::string error;
  const int num_disp = ((pp.matcher.max_disparity - pp.matcher.min_disparity + 1 + 15) / 16) * 16;
  cv::Ptr<cv::StereoSGBM> sgbm = cv::StereoSGBM::create(pp.matcher.min_disparity, num_disp, 5,
                                                        8 * 25, 32 * 25, 1, 0, 10, 100, 1,
                                                        cv::StereoSGBM::MODE_SGBM);

  Timing t_with, t_without, t_sgbm;
  // --stages: priors and temporal update, prepare, search, edge, filters, the rest, total.
  Timing stage_ms[7];
  Score s_with, s_without, s_sgbm, s_fused, s_with_narrowed, s_with_full;
  int64_t narrowed = 0, hits = 0, fallbacks = 0, deferred = 0, searched = 0;
  double width_sum = 0;
  int width_frames = 0;
  endo_stereo::SurgicalFrame frame;
  cv::Mat picture_left, picture_disp, picture_fused;
  std::vector<double> frame_ms_with;
  int64_t breakdown_with[4] = {0, 0, 0, 0}, breakdown_without[4] = {0, 0, 0, 0};
  for (int i = 0; i < frames; ++i) {
    scene.render(i, frame);
    cv::Mat l, r;
    cv::cvtColor(frame.left, l, cv::COLOR_BGR2GRAY);
    cv::cvtColor(frame.right, r, cv::COLOR_BGR2GRAY);
    const cv::Mat nonocc = frame.visibility == endo_stereo::kVisibleBoth;
    const endo_stereo::StereoInput in{l, r, "mono8", "mono8", frame.stamp_s};
    // 1. with priors: the whole Pipeline::process call
    auto t0 = std::chrono::steady_clock::now();
    if (!pipeline_with.process(in, out_with, &error)) {
      std::cerr << "frame " << i << ": " << error << "\n";
      return 1;
    }
    const double ms_with = msSince(t0);
    const endo_stereo::MatchResult& res_with = out_with.match;
    if (i >= warmup) {
      const endo_stereo::MatchStats& st = res_with.stats;
      stage_ms[0].ms.push_back(out_with.temporal_ms);
      stage_ms[1].ms.push_back(st.prepare_ms);
      stage_ms[2].ms.push_back(st.match_ms - st.prepare_ms - st.edge_ms);
      stage_ms[3].ms.push_back(st.edge_ms);
      stage_ms[4].ms.push_back(st.filter_ms);
      stage_ms[5].ms.push_back(ms_with - out_with.temporal_ms - st.match_ms - st.filter_ms);
      stage_ms[6].ms.push_back(ms_with);
    }
    // The range this frame searched (the tracker keeps it until the next frame).
    const endo_stereo::SearchRange* range =
        out_with.priors_used ? &pipeline_with.temporal().range() : nullptr;
    // 2. without priors
    double ms_without = 0;
    if (run_without) {
      t0 = std::chrono::steady_clock::now();
      if (!pipeline_without.process(in, out_without, &error)) {
        std::cerr << "frame " << i << ": " << error << "\n";
        return 1;
      }
      ms_without = msSince(t0);
    } else {
      out_without.match.disparity =
          cv::Mat(l.size(), CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
    }
    const endo_stereo::MatchResult& res_without = out_without.match;
    // 3. SGBM
    double ms_sgbm = 0;
    cv::Mat d_sgbm;
    if (run_sgbm) {
      t0 = std::chrono::steady_clock::now();
      d_sgbm = sgbmDisparity(sgbm, l, r, pp.matcher.max_disparity);
      ms_sgbm = msSince(t0);
    }
    frame_ms_with.push_back(ms_with);
    if (i >= warmup) {
      t_with.ms.push_back(ms_with);
      t_without.ms.push_back(ms_without);
      if (run_sgbm) t_sgbm.ms.push_back(ms_sgbm);
    }
    s_with.add(res_with.disparity, frame.gt_disparity, nonocc);
    if (range) {
      // Split the with-priors score by what each pixel searched.
      const cv::Mat full = (range->lo <= pp.matcher.min_disparity) & (range->hi >= pp.matcher.max_disparity);
      const cv::Mat deferred_mask = range->lo > range->hi;  // not searched this frame
      s_with_narrowed.add(res_with.disparity, frame.gt_disparity, nonocc & ~full & ~deferred_mask);
      s_with_full.add(res_with.disparity, frame.gt_disparity, nonocc & full);
    }
    s_without.add(res_without.disparity, frame.gt_disparity, nonocc);
    s_fused.add(out_with.fused_disparity, frame.gt_disparity, nonocc);
    if (run_sgbm) s_sgbm.add(d_sgbm, frame.gt_disparity, nonocc);
    const endo_stereo::TemporalPriorStats& ps = out_with.prior_stats;
    if (range) {
      narrowed += ps.narrowed_pixels;
      hits += ps.prior_hits;
      fallbacks += ps.fallback_pixels;
      deferred += ps.deferred_pixels;
      searched += int64_t(l.total());
      width_sum += ps.mean_narrowed_width_px;
      ++width_frames;
    }
    if (breakdown && i >= warmup) {
      // Where do the bad pixels lie? near an instrument edge (10 px), in a highlight, elsewhere.
      cv::Mat edge;
      cv::Mat dil, ero;
      cv::dilate(frame.instrument_mask, dil, cv::Mat(), cv::Point(-1, -1), 10);
      cv::erode(frame.instrument_mask, ero, cv::Mat(), cv::Point(-1, -1), 10);
      edge = dil & ~ero;
      cv::Mat spec;
      cv::dilate(frame.left_specular, spec, cv::Mat(), cv::Point(-1, -1), 3);
      for (int k = 0; k < 2; ++k) {
        const cv::Mat& d = k == 0 ? res_with.disparity : res_without.disparity;
        cv::Mat err;
        cv::absdiff(d, frame.gt_disparity, err);
        const cv::Mat bad = (err > 2.0f) & nonocc;  // NaN compares false
        const int n_bad = cv::countNonZero(bad);
        const int n_edge = cv::countNonZero(bad & edge);
        const int n_spec = cv::countNonZero(bad & spec & ~edge);
        const int n_inst = cv::countNonZero(bad & frame.instrument_mask & ~edge & ~spec);
        int64_t* acc = k == 0 ? breakdown_with : breakdown_without;
        acc[0] += n_edge;
        acc[1] += n_spec;
        acc[2] += n_inst;
        acc[3] += n_bad - n_edge - n_spec - n_inst;
        std::fprintf(stderr, "  %s: bad %d: instrument edge %d, highlight %d, instrument %d, other %d\n",
                     k == 0 ? "with   " : "without", n_bad, n_edge, n_spec, n_inst, n_bad - n_edge - n_spec - n_inst);
      }
    }
    if (i == picture_frame) {
      picture_left = frame.left.clone();
      picture_disp = endo_stereo::colorizeDisparity(res_with.disparity, dmin, dmax);
      picture_fused = endo_stereo::colorizeDisparity(out_with.fused_disparity, dmin, dmax);
    }
    Score this_frame, this_frame_without;
    this_frame.add(res_with.disparity, frame.gt_disparity, nonocc);
    this_frame_without.add(res_without.disparity, frame.gt_disparity, nonocc);
    std::fprintf(stderr,
                 "frame %3d: with priors %7.1f ms bad2 %.2f%% density %.1f%% | without %7.1f ms bad2 %.2f%% "
                 "density %.1f%% | sgbm %7.1f ms\n",
                 i, ms_with, 100.0 * this_frame.bad2(), 100.0 * this_frame.density(), ms_without,
                 100.0 * this_frame_without.bad2(), 100.0 * this_frame_without.density(), ms_sgbm);
    if (levels) {
      const endo_stereo::MatchStats& st = res_with.stats;
      std::string acc, rej;
      for (size_t k = 0; k < st.accepted_per_window.size(); ++k) {
        if (st.accepted_per_window[k]) acc += " w" + std::to_string(k) + "=" + std::to_string(st.accepted_per_window[k]);
      }
      static const char* kNames[] = {"unsearched", "structure", "gap", "lr", "edge", "outlier", "nopeak", "filled"};
      for (size_t k = 0; k < st.rejected.size() && k < 8; ++k) {
        rej += std::string(" ") + kNames[k] + "=" + std::to_string(st.rejected[k]);
      }
      std::fprintf(stderr, "  levels: narrowed %lld | accepted%s |%s | match %.1f ms filter %.1f ms\n",
                   static_cast<long long>(st.prior_pixels), acc.c_str(), rej.c_str(), st.match_ms,
                   st.filter_ms);
    }
  }
  const endo_stereo::CoverageStats cov_with = pipeline_with.temporal().coverage().stats();
  const endo_stereo::CoverageStats cov_without = pipeline_without.temporal().coverage().stats();

  char buf[8192];
  std::snprintf(buf, sizeof(buf),
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
                "  \"prior_narrowed_share\": %.4f, \"prior_hit_share\": %.4f, \"prior_fallback_share\": %.5f,\n"
                "  \"prior_deferred_share\": %.4f,\n"
                "  \"mean_narrowed_width_px\": %.2f,\n"
                "  \"coverage_with_priors\": {\"central_within_10\": %.4f, \"overall_within_10\": %.4f, \"central_never\": %.4f},\n"
                "  \"coverage_without_priors\": {\"central_within_10\": %.4f, \"overall_within_10\": %.4f, \"central_never\": %.4f}\n"
                "}\n",
                frames, warmup, sp.width, sp.height, (unsigned long long)sp.seed, pp.matcher.min_disparity,
                pp.matcher.max_disparity, threads, t_with.mean(), t_with.median(), t_without.mean(),
                t_without.median(), t_sgbm.mean(), t_sgbm.median(),
                t_sgbm.mean() > 0 ? t_with.mean() / t_sgbm.mean() : 0.0, s_with.bad2(), s_with.density(),
                s_without.bad2(), s_without.density(), s_with_narrowed.bad2(), s_with_full.bad2(), (long long)s_with.bad, (long long)s_with.output,
                (long long)s_without.bad, (long long)s_without.output, s_fused.bad2(), s_fused.density(), s_sgbm.bad2(),
                s_sgbm.density(), searched ? double(narrowed) / searched : 0.0,
                narrowed ? double(hits) / narrowed : 0.0, searched ? double(fallbacks) / searched : 0.0,
                searched ? double(deferred) / searched : 0.0,
                width_frames ? width_sum / width_frames : 0.0, cov_with.central_share, cov_with.overall_share,
                cov_with.central_never, cov_without.central_share, cov_without.overall_share,
                cov_without.central_never);
  std::cout << buf;
  if (stages) {
    static const char* const names[7] = {
        "priors, fusion, coverage (temporal stage)", "matcher: preparation (buffers, views, integrals)",
        "matcher: search (all passes, all window sizes)", "matcher: edge measure",
        "matcher: post-filters", "the rest (pre-processing, conversions, counts)",
        "total with priors (Pipeline::process)"};
    std::printf("stages of a frame with priors, median of frames %d..%d (ms; the medians do not add "
                "up exactly):\n", warmup, frames - 1);
    for (int k = 0; k < 7; ++k) std::printf("  %-50s %7.2f\n", names[k], stage_ms[k].median());
  }
  if (breakdown) {
    std::printf("bad pixels after warm-up (instrument edge, highlight, instrument, other): with priors "
                "%lld %lld %lld %lld, without %lld %lld %lld %lld\n",
                (long long)breakdown_with[0], (long long)breakdown_with[1], (long long)breakdown_with[2],
                (long long)breakdown_with[3], (long long)breakdown_without[0], (long long)breakdown_without[1],
                (long long)breakdown_without[2], (long long)breakdown_without[3]);
  }
  if (!out_dir.empty()) {
    std::ofstream json(out_dir + "/results.json");
    json << buf;
    bool ok = static_cast<bool>(json);
    ok &= cv::imwrite(out_dir + "/coverage.png",
                      labelled(pipeline_with.temporal().coverage().colorImage(),
                               "longest run without update (0 .. 20+ frames)"));
    ok &= cv::imwrite(out_dir + "/coverage_without_priors.png",
                      labelled(pipeline_without.temporal().coverage().colorImage(),
                               "no priors: longest run without update"));
    cv::Mat row;
    cv::hconcat(std::vector<cv::Mat>{labelled(picture_left, "input (left)"),
                                     labelled(picture_disp, "this frame"),
                                     labelled(picture_fused, "fused (<= 10 frames old)")},
                row);
    ok &= cv::imwrite(out_dir + "/fused.png", row);
    if (!ok) {
      std::cerr << "--out " << out_dir << ": could not write results.json and the pictures\n";
      return 1;
    }
    std::cout << "written: " << out_dir
              << "/results.json, coverage.png, coverage_without_priors.png, fused.png\n";
  }
  return 0;
}
