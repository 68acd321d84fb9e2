// endo_stereo_speed: times the robust matcher against OpenCV StereoSGBM (MODE_SGBM, blockSize 5,
// the same 64-disparity range) in the same run, at 960x540 on a synthetic textured scene with a
// slanted background and an occluder; then with a per-pixel range of +-4 px around the known
// disparity. Prints medians, the ratio, and the peak resident memory of the process.
//
//   endo_stereo_speed [--frames N] [--threads N] [--width W --height H] [--params FILE.yaml]
#include <sys/resource.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/evaluation.hpp"
#include "endo_stereo/core/matcher.hpp"
#include "synthetic_scene.hpp"
#include "tool_args.hpp"

namespace es = endo_stereo;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

double peakRssMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss / 1024.0;  // Linux: kilobytes
}

double cpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// Wall time of f; its process CPU time is appended to *cpu (a check on a loaded machine: with
// one thread, CPU time is what the work costs whatever else runs).
template <typename F>
double timeMs(F&& f, std::vector<double>* cpu = nullptr) {
  const double c0 = cpuMs();
  const auto t0 = std::chrono::steady_clock::now();
  f();
  const double wall =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (cpu) cpu->push_back(cpuMs() - c0);
  return wall;
}

const char* kUsage =
    "usage: endo_stereo_speed [--frames N] [--threads N] [--width W --height H] "
    "[--window-max W] [--only-full | --only-prior] [--quick]\n";

struct Options {
  int frames = 15, threads = 0, width = 960, height = 540, window_max = 0;
  bool run_full = true, run_prior = true, quick = false;
};

Options parseArgs(int argc, char** argv) {
  Options o;
  endo_stereo::tools::ArgReader args(argc, argv);
  while (args.next()) {
    if (args.is("--help") || args.is("-h")) {
      std::fputs(kUsage, stdout);
      std::exit(0);
    } else if (args.is("--frames")) {
      o.frames = std::max(1, args.integer());
    } else if (args.is("--threads")) {
      o.threads = args.integer();
    } else if (args.is("--width")) {
      o.width = args.integer(1);
    } else if (args.is("--height")) {
      o.height = args.integer(1);
    } else if (args.is("--window-max")) {
      o.window_max = args.integer(0);
    } else if (args.is("--only-full")) {
      o.run_prior = false;
    } else if (args.is("--only-prior")) {
      o.run_full = false;
    } else if (args.is("--quick")) {  // for profilers: no warm-up, no SGBM, no thread check
      o.quick = true;
    } else {
      args.unknown();
    }
  }
  return o;
}

// Identical output whatever the thread count (fixed row stripes, exact sums): 1 vs 2 threads,
// full search and per-pixel range.
bool sameOutputAtOneAndTwoThreads(const es::MatcherParams& mp, const es::SyntheticScene& scene,
                                  const es::SearchRange& range) {
  es::MatcherParams p1 = mp, p2 = mp;
  p1.num_threads = 1;
  p2.num_threads = 2;
  es::RobustMatcher m1(p1, es::PostFilterParams{}), m2(p2, es::PostFilterParams{});
  es::MatchResult r1, r2;
  m1.compute(scene.left, scene.right, r1);
  m2.compute(scene.left, scene.right, r2);
  m1.compute(scene.left, scene.right, r1, &range);
  es::MatchResult r1p = r1;
  m2.compute(scene.left, scene.right, r2, &range);
  auto same = [](const cv::Mat& a, const cv::Mat& b) {
    if (a.size() != b.size() || a.type() != b.type()) return false;
    for (int y = 0; y < a.rows; ++y) {
      if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
    }
    return true;
  };
  es::MatchResult f1, f2;
  m1.compute(scene.left, scene.right, f1);
  m2.compute(scene.left, scene.right, f2);
  return same(f1.disparity, f2.disparity) && same(f1.code, f2.code) &&
         same(f1.confidence, f2.confidence) && same(r1p.disparity, r2.disparity) &&
         same(r1p.code, r2.code);
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  try {
    o = parseArgs(argc, argv);
  } catch (const endo_stereo::tools::UsageError& e) {
    std::fprintf(stderr, "endo_stereo_speed: %s\n%s", e.what(), kUsage);
    return endo_stereo::tools::kExitUsage;
  }
  const int frames = o.frames, threads = o.threads, width = o.width, height = o.height;
  const int window_max = o.window_max;
  const bool run_full = o.run_full, run_prior = o.run_prior, quick = o.quick;
  if (threads > 0) cv::setNumThreads(threads);

  es::SyntheticSceneParams sp;
  sp.width = width;
  sp.height = height;
  sp.base_disparity_px = 30;
  sp.slope_x = 0.02;
  sp.slope_y = 0.01;
  sp.texture_stdev = 25;
  sp.texture_blur_px = 1.5;
  sp.noise_stdev = 2.0;
  sp.occluder = cv::Rect(width * 2 / 5, height / 4, width / 5, height / 2);
  sp.occluder_disparity_px = 55;
  sp.textureless = cv::Rect(width / 10, height / 10, width / 12, height / 8);
  const es::SyntheticScene scene = es::makeSyntheticScene(sp);

  es::MatcherParams mp;
  mp.min_disparity = 0;
  mp.max_disparity = 63;
  if (window_max > 0) mp.window_max_px = window_max;
  es::RobustMatcher matcher(mp, es::PostFilterParams{});
  auto sgbm = cv::StereoSGBM::create(0, 64, 5);
  sgbm->setMode(cv::StereoSGBM::MODE_SGBM);

  es::SearchRange range;
  range.lo.create(scene.left.size(), CV_16SC1);
  range.hi.create(scene.left.size(), CV_16SC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const int d = static_cast<int>(std::lround(scene.disparity.at<float>(y, x)));
      range.lo.at<int16_t>(y, x) = static_cast<int16_t>(d - 4);
      range.hi.at<int16_t>(y, x) = static_cast<int16_t>(d + 4);
    }
  }

  es::MatchResult res;
  cv::Mat sg_disp;
  // Warm-up: first-call allocations of both.
  if (!quick) {
    matcher.compute(scene.left, scene.right, res);
    sgbm->compute(scene.left, scene.right, sg_disp);
  }
  std::vector<double> t_ours, t_sgbm, t_prior, t_match, t_filter, c_ours, c_sgbm, c_prior;
  for (int i = 0; i < frames && run_full; ++i) {
    if (!quick) {
      t_sgbm.push_back(timeMs([&] { sgbm->compute(scene.left, scene.right, sg_disp); }, &c_sgbm));
    }
    t_ours.push_back(timeMs([&] { matcher.compute(scene.left, scene.right, res); }, &c_ours));
    t_match.push_back(res.stats.match_ms);
    t_filter.push_back(res.stats.filter_ms);
  }
  const es::DisparityScore full_score =
      res.disparity.empty() ? es::DisparityScore{}
                            : es::scoreDisparity(res.disparity, scene.disparity, scene.occluded == 0);
  for (int i = 0; i < frames && run_prior; ++i) {
    t_prior.push_back(
        timeMs([&] { matcher.compute(scene.left, scene.right, res, &range); }, &c_prior));
  }
  const es::DisparityScore prior_score =
      es::scoreDisparity(res.disparity, scene.disparity, scene.occluded == 0);

  std::printf("endo_stereo_speed: %dx%d, disparities 0..63, %d frames, OpenCV threads %d\n", width,
              height, frames, cv::getNumThreads());
  std::printf("  StereoSGBM MODE_SGBM block 5   median %8.1f ms\n", median(t_sgbm));
  std::printf(
      "  ours, full search              median %8.1f ms  (match %.1f + filters %.1f)  "
      "ratio ours/SGBM %.2f  density %.1f%% bad2 %.2f%%\n",
      median(t_ours), median(t_match), median(t_filter), median(t_ours) / median(t_sgbm),
      100 * full_score.density, 100 * full_score.bad2);
  std::printf("  ours, per-pixel range +-4 px   median %8.1f ms  density %.1f%% bad2 %.2f%%\n",
              median(t_prior), 100 * prior_score.density, 100 * prior_score.bad2);
  std::printf(
      "  CPU time medians (all threads): SGBM %.1f ms, ours full %.1f ms (ratio %.2f), "
      "ours +-4 px %.1f ms\n",
      median(c_sgbm), median(c_ours), median(c_ours) / median(c_sgbm), median(c_prior));
  std::printf("  peak RSS %.1f MB (one matcher, both modes)\n", peakRssMb());
  // Where the pixels end up (last frame of each mode): accepted per window size, rejections.
  auto outcome = [&](const char* label, const es::MatchStats& st) {
    std::printf("  %s: accepted per window", label);
    for (int k = 0; k < 16 && mp.window_min_px + k * mp.window_step_px <= mp.window_max_px; ++k) {
      std::printf(" w%d=%lld", mp.window_min_px + k * mp.window_step_px,
                  static_cast<long long>(st.accepted_per_window[k]));
    }
    std::printf("; rejected structure %lld gap %lld lr %lld edge %lld nopeak %lld\n",
                static_cast<long long>(st.rejected[es::kCodeRejectStructure]),
                static_cast<long long>(st.rejected[es::kCodeRejectPeakGap]),
                static_cast<long long>(st.rejected[es::kCodeRejectLeftRight]),
                static_cast<long long>(st.rejected[es::kCodeRejectEdge]),
                static_cast<long long>(st.rejected[es::kCodeNoPeak]));
  };
  if (run_full && !quick) {
    matcher.compute(scene.left, scene.right, res);
    outcome("full", res.stats);
  }
  if (run_prior && !quick) {
    matcher.compute(scene.left, scene.right, res, &range);
    outcome("+-4 px", res.stats);
  }
  if (!quick) {
    const bool ok = sameOutputAtOneAndTwoThreads(mp, scene, range);
    std::printf("  1 vs 2 threads: output %s\n", ok ? "identical (bitwise)" : "DIFFERS");
  }
  return 0;
}
