// endo_stereo_evaluate: how the robust matcher compares with OpenCV's StereoBM and StereoSGBM on a
// recording without ground truth. Runs the Pipeline (temporal priors on, and off) and both OpenCV
// matchers on the same rectified frames, and reports per method density, temporal stability
// (disparity jumps between consecutive frames, raw and motion-compensated), coverage of the
// central pixels and time per frame (ours also per stage of the pipeline); pictures of one
// frame. The metrics are sequence_evaluation.hpp's. `--help` lists flags.
//
// Exit status: 0 success; 1 an input could not be read or processed, or an output not written;
// 2 bad usage.
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/core/sequence_evaluation.hpp"
#include "frame_sources.hpp"
#include "json_writer.hpp"
#include "tool_args.hpp"
#include "tool_params.hpp"
#include "machine_info.hpp"

namespace {

using endo_stereo::tools::cpuModel;
using endo_stereo::tools::loadAverage;

using endo_stereo::tools::Frame;
using endo_stereo::tools::FrameSource;
using endo_stereo::tools::InputError;
using endo_stereo::tools::isPattern;
using endo_stereo::tools::JsonWriter;
using endo_stereo::tools::kExitInput;
using endo_stereo::tools::splitList;
using endo_stereo::tools::UsageError;
using endo_stereo::tools::validPattern;
using Clock = std::chrono::steady_clock;

constexpr int kExitOk = 0;

const char* kUsage =
    R"(endo_stereo_evaluate - ours beside OpenCV BM and SGBM on a recording without ground truth

Usage:
  endo_stereo_evaluate --left L --right R --min-disparity N --max-disparity N [options]
  endo_stereo_evaluate --bag FILE.bag --min-disparity N --max-disparity N [options]

Input (the same frames go to every method):
  --left PATH, --right PATH   a stereo pair, or printf patterns (left/%04d.png) for a sequence
  --first N, --count N        first index (default 0, or 1 when frame 0 is missing) and number of
                              frames of a sequence (default: until the first missing left image)
  --bag FILE.bag              a bag with NS/left/image_raw and NS/right/image_raw (pairs matched by
                              stamp); when NS/left/camera_info and NS/right/camera_info hold a
                              projection, the pipeline rectifies with them
  --namespace NS              topic namespace of --bag (default /endoscope)
  --fps F                     stamps of image files, i / F (default 25)
  --crop WxH                  cut the centre W x H out of every input image (use on rectified
                              input: the crop keeps the rows aligned)
  --repeat N                  a single pair: N frames of the same pair (a static scene)
  --pan N                     a single pair with --crop: N frames in which the crop window moves on
                              a circle (radius --pan-radius px, default 24, one turn every
                              --pan-period frames, default 75): a slow pan over a real image, every
                              frame an exact crop (integer offsets, no resampling)

Our pipeline (as endo_stereo_cli): --params FILE.yaml, --set KEY=VALUE, --calib SPEC,
  --threads N. The input is taken as rectified unless --calib or a bag's camera_info says more.
  --min-disparity N, --max-disparity N   the search range of every method, px (required).
                              OpenCV's matchers search a multiple of 16 disparities from the
                              minimum, at least up to the maximum.

Evaluation:
  --methods LIST              of ours, ours-no-priors, bm, sgbm (default: all four)
  --jump-px T                 a change larger than T px between frames is a jump, and a change
                              more than T px off its neighbourhood's mean change a flicker
                              (default 2)
  --flicker-window N          side of the flicker's neighbourhood square, px (odd, >= 3;
                              default 17)
  --window N                  coverage window, frames (default 10)
  --skip-timing N             frames left out of the time medians (default 2: start-up, priors)
  --picture-frame K           the frame (0-based position in the run) the pictures show
                              (default: the middle one)
  --label TEXT                a name for the recording in the table and the JSON

Output:
  --out DIR                   DIR/evaluation.json and the pictures: comparison.png (left image;
                              per method the disparity on one colour scale, the jump map, the
                              flicker map, the coverage map), left.png, disparity_*.png,
                              jumps_*.png, flicker_*.png, coverage_*.png
  --json FILE                 the JSON elsewhere (default DIR/evaluation.json)
  --quiet                     no progress lines
  --help

The tables go to stdout: the figures per method, then ours' time per stage. Density: share of
pixels with a value in a frame. Jumps: among pixels with a value in two consecutive frames, the
share whose disparity changed by more than T px. Motion-compensated flicker: among the same
pixels, the share whose change differs by more than T px from the mean change of the pixels with
a value in both frames within the --flicker-window square centred on it (itself included): motion
shared by the neighbourhood cancels. Coverage: share of the central pixels (middle half in each
direction) with a value in every window of N consecutive frames; never: without a value in any
frame. Ours also gets a line for its fused output (the latest value measured within the
pipeline's temporal.fused_max_age_frames); its own line counts only the values measured on each
frame. Stages of ours (the median of each over the timed frames; the JSON's stage_ms_median):
pre-processing and rectification, the temporal stage (priors, fusion, coverage), the matcher's
preparation, search, depth-edge filter and post-filters, the rest (the call's wall time less all
of these), the total (the call's wall time).
)";

using endo_stereo::tools::ArgReader;

// --min-disparity and --max-disparity are >= -100000 (a smaller one is a usage error at once).
endo_stereo::tools::SharedRanges sharedRanges() {
  endo_stereo::tools::SharedRanges r;
  r.disparity_min = -100000;
  return r;
}

// The shared flags (tool_args.hpp) this tool takes, and its own.
struct Options : endo_stereo::tools::SharedOptions {
  Options()
      : SharedOptions(endo_stereo::tools::kFlagLeftRight | endo_stereo::tools::kFlagFirst |
                          endo_stereo::tools::kFlagCount | endo_stereo::tools::kFlagFps |
                          endo_stereo::tools::kFlagBag | endo_stereo::tools::kFlagParams |
                          endo_stereo::tools::kFlagDisparityRange |
                          endo_stereo::tools::kFlagThreads | endo_stereo::tools::kFlagOutDir |
                          endo_stereo::tools::kFlagQuiet,
                      sharedRanges()) {}
  cv::Size crop;
  int repeat = 0, pan = 0, pan_radius = 24, pan_period = 75;
  std::vector<std::string> methods = {"ours", "ours-no-priors", "bm", "sgbm"};
  double jump_px = 2.0;
  int flicker_window = 17;
  int window = 10, skip_timing = 2, picture_frame = -1;
  std::string label, json;
};

// WxH, each side >= 16.
cv::Size parseCrop(const std::string& v) {
  int w = 0, h = 0;
  const auto parts = splitList(v, 'x');
  if (parts.size() != 2 || !endo_stereo::tools::parseInt(parts[0], &w) ||
      !endo_stereo::tools::parseInt(parts[1], &h) || w < 16 || h < 16) {
    throw UsageError("--crop: expected WxH (each >= 16), got '" + v + "'");
  }
  return cv::Size(w, h);
}

std::vector<std::string> parseMethods(const std::string& v) {
  const std::vector<std::string> methods = splitList(v, ',');
  for (const std::string& m : methods) {
    if (m != "ours" && m != "ours-no-priors" && m != "bm" && m != "sgbm") {
      throw UsageError("--methods: unknown method '" + m + "' (ours, ours-no-priors, bm, sgbm)");
    }
  }
  if (methods.empty()) throw UsageError("--methods: empty list");
  return methods;
}

// How a single pair becomes frames: --crop, --repeat, --pan, --pan-radius, --pan-period.
bool readFramingOption(ArgReader& args, Options& o) {
  if (args.is("--crop")) {
    o.crop = parseCrop(args.text());
  } else if (args.is("--repeat")) {
    o.repeat = args.integer(1);
  } else if (args.is("--pan")) {
    o.pan = args.integer(1);
  } else if (args.is("--pan-radius")) {
    o.pan_radius = args.integer(0);
  } else if (args.is("--pan-period")) {
    o.pan_period = args.integer(2);
  } else {
    return false;
  }
  return true;
}

// --methods, --jump-px, --flicker-window, --window, --skip-timing, --picture-frame, --label,
// --json.
bool readEvaluationOption(ArgReader& args, Options& o) {
  if (args.is("--methods")) {
    o.methods = parseMethods(args.text());
  } else if (args.is("--jump-px")) {
    o.jump_px = args.positive();
  } else if (args.is("--flicker-window")) {
    o.flicker_window = args.integer(3);
    if (o.flicker_window % 2 == 0) {
      throw UsageError("--flicker-window: expected an odd number, got " +
                       std::to_string(o.flicker_window));
    }
  } else if (args.is("--window")) {
    o.window = args.integer(1);
  } else if (args.is("--skip-timing")) {
    o.skip_timing = args.integer(0);
  } else if (args.is("--picture-frame")) {
    o.picture_frame = args.integer(0);
  } else if (args.is("--label")) {
    o.label = args.text();
  } else if (args.is("--json")) {
    o.json = args.text();
  } else {
    return false;
  }
  return true;
}

// The flags that go together: one input, the search range, the framing of a single pair.
void checkOptions(const Options& o) {
  const bool files = !o.left.empty() || !o.right.empty();
  if (files == !o.bag.empty()) throw UsageError("give either --left and --right, or --bag");
  if (files && (o.left.empty() || o.right.empty())) {
    throw UsageError("--left and --right go together");
  }
  if (!o.has_min || !o.has_max)
    throw UsageError("--min-disparity and --max-disparity are required");
  if (o.min_disparity < 0 || o.min_disparity > o.max_disparity) {
    throw UsageError("bad disparity range " + std::to_string(o.min_disparity) + ".." +
                     std::to_string(o.max_disparity));
  }
  if (o.repeat > 0 && o.pan > 0) throw UsageError("--repeat and --pan exclude each other");
  if (o.pan > 0 && o.crop.area() == 0) throw UsageError("--pan needs --crop WxH");
  if (!o.bag.empty() && (o.repeat > 0 || o.pan > 0)) {
    throw UsageError("--repeat and --pan take a single pair of image files");
  }
  if (!o.bag.empty() && !o.calib.empty()) {
    throw UsageError("--calib is for image files (a bag brings its camera_info)");
  }
}

Options parseArgs(int argc, char** argv) {
  Options o;
  endo_stereo::tools::readArguments(argc, argv, kUsage, o, [&o](ArgReader& args) {
    return readFramingOption(args, o) || readEvaluationOption(args, o);
  });
  if (!o.ns.empty() && o.ns.back() == '/') o.ns.pop_back();
  checkOptions(o);
  return o;
}

// --- methods ---------------------------------------------------------------------------------

double processCpuMs() {
  timespec ts{};
  ::clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// The stages of a Pipeline::process call, as endo_stereo_temporal_bench --stages splits them:
/// pre-processing and rectification; the temporal stage (priors, fusion, coverage); the matcher's
/// preparation, search (all passes, all window sizes), depth-edge measure and post-filters; the
/// rest (the call's wall time less all of these: conversions, counts, range handling); the call's
/// wall time.
enum Stage {
  kStageRectify,
  kStagePriors,
  kStagePrepare,
  kStageSearch,
  kStageEdge,
  kStageFilters,
  kStageRest,
  kStageTotal,
  kNumStages
};
struct StageName {
  const char* key;    // in the JSON
  const char* label;  // in the table
};
constexpr StageName kStageNames[kNumStages] = {
    {"rectify_preprocess", "pre-processing and rectification"},
    {"priors", "priors, fusion, coverage (temporal stage)"},
    {"prepare", "matcher: preparation (views, integrals, ranges)"},
    {"search", "matcher: search (all passes, all window sizes)"},
    {"edge", "matcher: depth-edge filter"},
    {"filters", "matcher: post-filters"},
    {"rest", "the rest (conversions, counts, range handling)"},
    {"total", "total (Pipeline::process wall time)"}};

/// Splits one frame's @p wall_ms (the whole process() call) into the stages.
std::array<double, kNumStages> stageTimes(const endo_stereo::PipelineOutput& out, double wall_ms) {
  const endo_stereo::MatchStats& st = out.match.stats;
  std::array<double, kNumStages> t{};
  t[kStageRectify] = out.preprocess_ms + out.rectify_ms;
  t[kStagePriors] = out.temporal_ms;
  t[kStagePrepare] = st.prepare_ms;
  t[kStageSearch] = st.match_ms - st.prepare_ms - st.edge_ms;
  t[kStageEdge] = st.edge_ms;
  t[kStageFilters] = st.filter_ms;
  t[kStageRest] = wall_ms - t[kStageRectify] - out.temporal_ms - st.match_ms - st.filter_ms;
  t[kStageTotal] = wall_ms;
  return t;
}

/// One disparity stream under evaluation (a method, or our fused output).
struct Stream {
  std::string key, name;
  bool timed = true;  // fused streams come from the same call as their method
  endo_stereo::SequenceMetrics metrics;
  std::vector<double> ms, cpu_ms;
  std::array<std::vector<double>, kNumStages> stage_ms;  // ours' measured streams only
  cv::Mat picture_disparity, picture_jumps, picture_flicker;
  explicit Stream(const endo_stereo::SequenceMetricsParams& p) : metrics(p) {}
};

// --- pictures --------------------------------------------------------------------------------

cv::Mat toBgr(const cv::Mat& m) {
  cv::Mat out;
  if (m.type() == CV_8UC3) return m.clone();
  if (m.type() == CV_8UC1) {
    cv::cvtColor(m, out, cv::COLOR_GRAY2BGR);
    return out;
  }
  CV_Error(cv::Error::StsBadArg, "toBgr: 8-bit gray or BGR expected");
}

/// A cell of the comparison figure: the picture scaled to @p width with a caption above it.
cv::Mat cell(const cv::Mat& picture, int width, const std::string& caption) {
  const double s = double(width) / picture.cols;
  cv::Mat scaled;
  cv::resize(picture, scaled, cv::Size(width, std::max(1, int(std::lround(picture.rows * s)))), 0,
             0, cv::INTER_AREA);
  cv::Mat out(scaled.rows + 22, width, CV_8UC3, cv::Scalar::all(255));
  scaled.copyTo(out(cv::Rect(0, 22, width, scaled.rows)));
  cv::putText(out, caption, cv::Point(4, 16), cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar::all(0), 1,
              cv::LINE_AA);
  return out;
}

cv::Mat blankLike(const cv::Mat& c) { return cv::Mat(c.size(), CV_8UC3, cv::Scalar::all(255)); }

void putLines(cv::Mat& m, const std::vector<std::string>& lines, int y0) {
  int y = y0;
  for (const std::string& l : lines) {
    cv::putText(m, l, cv::Point(6, y), cv::FONT_HERSHEY_SIMPLEX, 0.42, cv::Scalar::all(0), 1,
                cv::LINE_AA);
    y += 18;
  }
}

bool writeImage(const std::string& path, const cv::Mat& image, std::string* error) {
  bool ok = false;
  try {
    ok = cv::imwrite(path, image);
  } catch (const cv::Exception& ex) {
    *error = "cannot write '" + path + "': " + ex.what();
    return false;
  }
  if (!ok) *error = "cannot write '" + path + "'";
  return ok;
}

/// What the JSON says about the run besides the streams.
struct RunInfo {
  std::string label, input, load_start;
  int frames = 0, failed = 0, num_disp = 0, window = 0, picture = 0;
  cv::Size size;
  double sgbm_ms = 0.0;
};

/// Median of the times after the first @p skip frames (all of them when there are no more).
double timingMedian(const std::vector<double>& v, int skip) {
  const size_t k = v.size() > size_t(skip) ? size_t(skip) : 0;
  return median(std::vector<double>(v.begin() + k, v.end()));
}

/// The evaluation's JSON (summary figures, per-frame series, machine, parameters).
std::string evaluationJson(const Options& o, const RunInfo& r,
                           const std::vector<std::unique_ptr<Stream>>& streams,
                           const endo_stereo::PipelineParams* params) {
  JsonWriter j;
  j.beginObject();
  j.key("tool").value("endo_stereo_evaluate");
  j.key("label").value(r.label);
  j.key("input").value(r.input);
  j.key("frames").value(r.frames);
  j.key("frames_failed").value(r.failed);
  j.key("width").value(r.size.width).key("height").value(r.size.height);
  j.key("min_disparity").value(o.min_disparity).key("max_disparity").value(o.max_disparity);
  j.key("opencv_num_disparities").value(r.num_disp);
  j.key("jump_px").value(o.jump_px).key("window_frames").value(r.window);
  j.key("flicker_window_px").value(o.flicker_window);
  j.key("skip_timing_frames").value(o.skip_timing);
  j.key("picture_frame").value(r.picture);
  j.key("machine").beginObject();
  j.key("cpu").value(cpuModel());
  j.key("logical_cpus").value(static_cast<int>(::sysconf(_SC_NPROCESSORS_ONLN)));
  j.key("opencv").value(CV_VERSION).key("opencv_threads").value(cv::getNumThreads());
  j.key("load_average_start").value(r.load_start).key("load_average_end").value(loadAverage());
  j.endObject();
  j.key("opencv_settings").beginObject();
  j.key("bm").value("StereoBM blockSize 15, uniquenessRatio 15, other settings OpenCV defaults");
  j.key("sgbm").value(
      "StereoSGBM MODE_SGBM blockSize 5, P1 200, P2 800, uniquenessRatio 10, other settings "
      "OpenCV defaults");
  j.endObject();
  j.key("methods").beginArray();
  for (const auto& s : streams) {
    const endo_stereo::SequenceSummary sum = s->metrics.summary();
    j.beginObject();
    j.key("key").value(s->key).key("name").value(s->name);
    j.key("density_median").value(sum.density_median);
    j.key("density_mean").value(sum.density_mean);
    j.key("jump_share").value(sum.jump_share);
    j.key("jump_pixels").value(sum.jump_pixels).key("compared_pixels").value(sum.compared_pixels);
    j.key("flicker_share").value(sum.flicker_share);
    j.key("flicker_pixels").value(sum.flicker_pixels);
    j.key("coverage_every_window").value(sum.coverage_every_window);
    j.key("coverage_never").value(sum.coverage_never);
    if (s->timed) {
      const double ms = timingMedian(s->ms, o.skip_timing);
      j.key("ms_median").value(ms);
      j.key("cpu_ms_median").value(timingMedian(s->cpu_ms, o.skip_timing));
      if (std::isfinite(r.sgbm_ms)) j.key("time_over_sgbm").value(ms / r.sgbm_ms);
      if (!s->stage_ms[kStageTotal].empty()) {
        j.key("stage_ms_median").beginObject();
        for (int k = 0; k < kNumStages; ++k) {
          j.key(kStageNames[k].key).value(timingMedian(s->stage_ms[size_t(k)], o.skip_timing));
        }
        j.endObject();
      }
      j.key("ms").beginArray();
      for (double v : s->ms) j.value(v);
      j.endArray();
    }
    j.key("density").beginArray();
    for (double v : s->metrics.densities()) j.value(v);
    j.endArray();
    j.key("jumps").beginArray();
    for (int64_t v : s->metrics.jumpCounts()) j.value(v);
    j.endArray();
    j.key("flicker").beginArray();
    for (int64_t v : s->metrics.flickerCounts()) j.value(v);
    j.endArray();
    j.key("compared").beginArray();
    for (int64_t v : s->metrics.comparedCounts()) j.value(v);
    j.endArray();
    j.endObject();
  }
  j.endArray();
  if (params) {
    j.key("params").beginObject();
    for (const endo_stereo::ParamInfo& info : endo_stereo::listPipelineParams(*params)) {
      j.key(info.key).value(info.value);
    }
    j.endObject();
  }
  j.endObject();
  return j.str();
}

/// Writes left.png, disparity_*.png, jumps_*.png, flicker_*.png, coverage_*.png and comparison.png
/// to o.out_dir.
bool writePictures(const Options& o, const std::vector<std::unique_ptr<Stream>>& streams,
                   const cv::Mat& picture_left, int picture, int n, int window, cv::Size frame_size,
                   std::string* error) {
  const std::string d = o.out_dir + "/";
  const double lo = o.min_disparity, hi = o.max_disparity;
  if (!writeImage(d + "left.png", picture_left, error)) {
    return false;
  }
  const int cw = std::min(frame_size.width, 480);
  std::vector<cv::Mat> row_disp, row_jump, row_flicker, row_cov;
  row_disp.push_back(cell(picture_left, cw, cv::format("left, frame %d of %d", picture + 1, n)));
  cv::Mat gray_bg;
  cv::cvtColor(picture_left, gray_bg, cv::COLOR_BGR2GRAY);
  for (const auto& s : streams) {
    if (s->picture_disparity.empty()) continue;
    std::string file = s->key;
    const cv::Mat disp = endo_stereo::colorizeDisparity(s->picture_disparity, lo, hi);
    const cv::Mat jumps = endo_stereo::jumpMapImage(s->picture_jumps, gray_bg);
    const cv::Mat flicker = endo_stereo::jumpMapImage(s->picture_flicker, gray_bg);
    const endo_stereo::SequenceSummary sum = s->metrics.summary();
    const cv::Mat cov =
        endo_stereo::coverageMapImage(s->metrics.longestGap(), sum.frames, o.window);
    if (!writeImage(d + "disparity_" + file + ".png", disp, error) ||
        !writeImage(d + "jumps_" + file + ".png", jumps, error) ||
        !writeImage(d + "flicker_" + file + ".png", flicker, error) ||
        !writeImage(d + "coverage_" + file + ".png", cov, error)) {
      return false;
    }
    const double dens = s->metrics.densities()[picture];
    row_disp.push_back(cell(disp, cw, cv::format("%s: %.0f%% dense", s->name.c_str(), 100 * dens)));
    row_jump.push_back(cell(jumps, cw, cv::format("jumps > %g px vs previous frame", o.jump_px)));
    row_flicker.push_back(cell(flicker, cw,
                               cv::format("flicker > %g px (%dx%d motion removed)", o.jump_px,
                                          o.flicker_window, o.flicker_window)));
    row_cov.push_back(
        cell(cov, cw,
             cv::format("coverage: %.0f%% every %d, %.0f%% never", 100 * sum.coverage_every_window,
                        sum.window_frames, 100 * sum.coverage_never)));
  }
  // The first column's lower cells: the colour scale and the legends.
  cv::Mat scale_cell = blankLike(row_disp[0]);
  {
    cv::Mat ramp(1, cw - 20, CV_32FC1);
    for (int x = 0; x < ramp.cols; ++x) ramp.at<float>(0, x) = lo + (hi - lo) * x / (ramp.cols - 1);
    cv::Mat bar = endo_stereo::colorizeDisparity(ramp, lo, hi);
    cv::resize(bar, bar, cv::Size(ramp.cols, 20), 0, 0, cv::INTER_NEAREST);
    bar.copyTo(scale_cell(cv::Rect(10, 30, bar.cols, bar.rows)));
    putLines(scale_cell,
             {cv::format("disparity %d px", o.min_disparity) +
                  std::string(std::max(1, (cw - 20) / 8 - 16), ' ') +
                  cv::format("%d px", o.max_disparity),
              "black: no value", "jump maps: red = jumped, green = stable,",
              "  dark = no value in this or the previous frame",
              cv::format("coverage: green = a value in every %d frames,", window),
              "  yellow..red = longer gaps, dark red = never;",
              "  white box = central region (half each way)"},
             70);
  }
  std::vector<cv::Mat> rows;
  auto hrow = [&](std::vector<cv::Mat> cells) {
    cv::Mat r;
    cv::hconcat(cells, r);
    rows.push_back(r);
  };
  hrow(row_disp);
  if (!row_jump.empty()) {
    row_jump.insert(row_jump.begin(), scale_cell);
    hrow(row_jump);
    cv::Mat flicker_legend = blankLike(row_disp[0]);
    putLines(
        flicker_legend,
        {"flicker maps: as the jump maps, for the", "  change minus the mean change of the pixels",
         cv::format("  compared in its %dx%d square", o.flicker_window, o.flicker_window)},
        40);
    row_flicker.insert(row_flicker.begin(), flicker_legend);
    hrow(row_flicker);
    row_cov.insert(row_cov.begin(), blankLike(row_disp[0]));
    hrow(row_cov);
  }
  cv::Mat figure;
  cv::vconcat(rows, figure);
  if (!writeImage(d + "comparison.png", figure, error)) {
    return false;
  }
  return true;
}

// --- steps of a run --------------------------------------------------------------------------

// Image files: a sequence needs valid patterns and takes neither --repeat nor --pan; a single pair
// takes neither --first nor --count.
void checkImageFiles(const Options& o) {
  if (o.left.empty()) return;
  const bool seq = isPattern(o.left) || isPattern(o.right);
  if (seq && (!validPattern(o.left) || !validPattern(o.right))) {
    throw UsageError(
        "a sequence needs --left and --right patterns with one integer conversion each, e.g. "
        "left/%04d.png");
  }
  if (seq && (o.repeat > 0 || o.pan > 0)) {
    throw UsageError("--repeat and --pan take a single pair, not a pattern");
  }
  if (!seq && (o.has_first || o.count > 0)) {
    throw UsageError("--first/--count need --left/--right patterns");
  }
}

// Our pipeline's parameters: as endo_stereo_cli (built-in defaults, input already rectified, then
// the preset and the overrides), with the search range of every method and the fused output.
endo_stereo::PipelineParams makeParams(const Options& o) {
  endo_stereo::PipelineParams params;
  params.rectify.mode = endo_stereo::RectifyMode::kPassThrough;
  const std::string err =
      endo_stereo::tools::applyPresetAndOverrides(o.params_file, o.overrides, params);
  if (!err.empty()) throw UsageError(err);
  params.matcher.min_disparity = o.min_disparity;
  params.matcher.max_disparity = o.max_disparity;
  if (o.has_threads) params.matcher.num_threads = o.threads;
  params.output.point_cloud = false;
  params.output.fused = true;
  params.output.coverage = false;  // coverage is measured here, the same way for every method
  if (!o.calib.empty()) params.rectify.mode = endo_stereo::RectifyMode::kCalibrated;
  const std::string bad = params.validate();
  if (!bad.empty()) throw UsageError("bad parameters: " + bad);
  return params;
}

endo_stereo::tools::FrameSourceSettings sourceSettings(const Options& o) {
  endo_stereo::tools::FrameSourceSettings fs = endo_stereo::tools::frameSourceSettings(o);
  fs.crop = o.crop;
  fs.repeat = o.repeat;
  fs.pan = o.pan;
  fs.pan_radius = o.pan_radius;
  fs.pan_period = o.pan_period;
  return fs;
}

// The frames of @p settings (which must outlive the source): image files or a bag, at least one.
std::unique_ptr<FrameSource> openSource(const endo_stereo::tools::FrameSourceSettings& settings) {
  std::unique_ptr<FrameSource> source;
  try {
    source = endo_stereo::tools::makeFrameSource(settings);
  } catch (const std::exception& ex) {
    throw InputError{std::string("cannot read the bag: ") + ex.what()};
  }
  if (source->size() == 0) throw InputError{"no frame found (" + source->describe() + ")"};
  return source;
}

// The calibration our pipeline rectifies with: --calib's, else a bag's camera_info (then
// rectify.mode becomes calibrated). False when there is none.
bool findCalibration(const Options& o, const FrameSource& source,
                     endo_stereo::StereoCalibration* calibration,
                     endo_stereo::PipelineParams* params) {
  if (!o.calib.empty()) {
    std::string err;
    if (!endo_stereo::loadStereoCalibration(o.calib, *calibration, &err)) {
      throw InputError{"--calib: " + err};
    }
    return true;
  }
  if (!source.calibration(calibration)) return false;
  params->rectify.mode = endo_stereo::RectifyMode::kCalibrated;
  return true;
}

/// Our pipeline in one setting (priors or none), its last output and its two streams.
struct Ours {
  std::unique_ptr<endo_stereo::Pipeline> pipeline;
  endo_stereo::PipelineOutput out;
  Stream* measured = nullptr;
  Stream* fused = nullptr;
};

/// The methods --methods names and their streams, in the order of the table.
struct Methods {
  std::vector<std::unique_ptr<Stream>> streams;
  std::vector<Ours> ours;
  bool any_ours = false;
  int num_disp = 0;  ///< OpenCV's number of disparities
  cv::Ptr<cv::StereoBM> bm;
  cv::Ptr<cv::StereoSGBM> sgbm;
  Stream* bm_stream = nullptr;
  Stream* sgbm_stream = nullptr;
};

bool hasMethod(const Options& o, const std::string& m) {
  return std::find(o.methods.begin(), o.methods.end(), m) != o.methods.end();
}

Stream* addStream(Methods& m, const Options& o, const std::string& key, const std::string& name,
                  bool timed) {
  endo_stereo::SequenceMetricsParams mp;
  mp.jump_px = o.jump_px;
  mp.flicker_window_px = o.flicker_window;
  mp.window_frames = o.window;
  m.streams.push_back(std::make_unique<Stream>(mp));
  m.streams.back()->key = key;
  m.streams.back()->name = name;
  m.streams.back()->timed = timed;
  return m.streams.back().get();
}

// Our pipeline with priors ("ours") and without ("ours-no-priors"), as --methods names them, each
// with a measured and a fused stream; @p calibration (null: none) set on each.
void addOurs(Methods& m, const Options& o, const endo_stereo::PipelineParams& params,
             const endo_stereo::StereoCalibration* calibration) {
  for (const std::string key : {"ours", "ours-no-priors"}) {
    if (!hasMethod(o, key)) continue;
    endo_stereo::PipelineParams p = params;
    const bool priors = key == std::string("ours");
    p.temporal.enabled = priors && params.temporal.enabled;
    Ours x;
    try {
      x.pipeline = std::make_unique<endo_stereo::Pipeline>(p);
    } catch (const std::exception& ex) {
      throw UsageError(std::string("bad parameters: ") + ex.what());
    }
    if (calibration) {
      const std::string err = x.pipeline->setCalibration(*calibration);
      if (!err.empty()) throw InputError{"calibration: " + err};
    }
    const std::string base = priors ? "ours, priors" : "ours, no priors";
    x.measured = addStream(m, o, key, base, true);
    x.fused = addStream(m, o, key + "-fused", base + ", fused output", false);
    m.ours.push_back(std::move(x));
  }
}

// OpenCV's StereoBM and StereoSGBM, as --methods names them, over the same range.
void addOpenCv(Methods& m, const Options& o) {
  m.num_disp = endo_stereo::referenceNumDisparities(o.min_disparity, o.max_disparity);
  if (hasMethod(o, "bm")) {
    m.bm = endo_stereo::makeReferenceBm(o.min_disparity, m.num_disp);
    m.bm_stream = addStream(m, o, "bm", "OpenCV BM", true);
  }
  if (hasMethod(o, "sgbm")) {
    m.sgbm = endo_stereo::makeReferenceSgbm(o.min_disparity, m.num_disp);
    m.sgbm_stream = addStream(m, o, "sgbm", "OpenCV SGBM", true);
  }
}

Methods makeMethods(const Options& o, const endo_stereo::PipelineParams& params,
                    const endo_stereo::StereoCalibration* calibration) {
  Methods m;
  m.any_ours = hasMethod(o, "ours") || hasMethod(o, "ours-no-priors");
  if (calibration && !m.any_ours) {
    throw UsageError(
        "rectification runs in our pipeline: with a calibration, --methods needs ours or "
        "ours-no-priors");
  }
  addOurs(m, o, params, calibration);
  addOpenCv(m, o);
  return m;
}

// Keeps the picture frame's disparity, jump map and flicker map of @p s.
void keepPicture(Stream& s, const cv::Mat& disparity) {
  s.picture_disparity = disparity;
  s.picture_jumps = s.metrics.lastJumpMap().clone();
  s.picture_flicker = s.metrics.lastFlickerMap().clone();
}

// Every setting of our pipeline on @p frame, timed (wall, CPU, stages), into its streams;
// @p left_gray and @p right_gray become the first one's rectified gray pair. False when a pipeline
// fails on the frame (said on stderr, @p err set).
bool runOurs(Methods& m, const Frame& frame, bool picture, cv::Mat* left_gray, cv::Mat* right_gray,
             std::string* err) {
  for (Ours& x : m.ours) {
    const double cpu = processCpuMs();
    const auto t0 = Clock::now();
    const bool processed = x.pipeline->process(frame.input, x.out, err);
    const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    if (!processed) {
      std::cerr << "endo_stereo_evaluate: frame " << frame.name << ": " << *err << "\n";
      return false;
    }
    x.measured->ms.push_back(ms);
    x.measured->cpu_ms.push_back(processCpuMs() - cpu);
    const std::array<double, kNumStages> stages = stageTimes(x.out, ms);
    for (int k = 0; k < kNumStages; ++k) x.measured->stage_ms[size_t(k)].push_back(stages[k]);
    x.measured->metrics.addFrame(x.out.match.disparity);
    x.fused->metrics.addFrame(x.out.fused_disparity);
    if (left_gray->empty()) {
      *left_gray = x.out.left_rect_gray;
      *right_gray = x.out.right_rect_gray;
    }
    if (picture) {
      keepPicture(*x.measured, x.out.match.disparity.clone());
      keepPicture(*x.fused, x.out.fused_disparity.clone());
    }
  }
  return true;
}

// An input image in 8-bit gray, as the pipeline converts it.
cv::Mat grayOf(const cv::Mat& m, const std::string& encoding) {
  cv::Mat g;
  if (encoding == "mono8") return m;
  if (encoding == "mono16") {
    m.convertTo(g, CV_8U, 1.0 / 257.0);
  } else if (encoding == "bgra8") {
    cv::cvtColor(m, g, cv::COLOR_BGRA2GRAY);
  } else {
    cv::cvtColor(m, g, cv::COLOR_BGR2GRAY);
  }
  return g;
}

// OpenCV's matchers on the rectified gray pair, timed (wall, CPU), into their streams.
void runOpenCv(Methods& m, const Options& o, const cv::Mat& left_gray, const cv::Mat& right_gray,
               bool picture) {
  for (auto& [matcher, stream] :
       {std::make_pair(cv::Ptr<cv::StereoMatcher>(m.bm), m.bm_stream),
        std::make_pair(cv::Ptr<cv::StereoMatcher>(m.sgbm), m.sgbm_stream)}) {
    if (!matcher) continue;
    cv::Mat fixed;
    const double cpu = processCpuMs();
    const auto t0 = Clock::now();
    matcher->compute(left_gray, right_gray, fixed);
    const cv::Mat d = endo_stereo::referenceDisparityToFloat(fixed, o.min_disparity);
    stream->ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    stream->cpu_ms.push_back(processCpuMs() - cpu);
    stream->metrics.addFrame(d);
    if (picture) keepPicture(*stream, d);
  }
}

// A frame's progress line: per timed stream its density and time.
void printProgress(const Methods& m, int n, int total, const std::string& name) {
  std::fprintf(stderr, "frame %d/%d (%s):", n + 1, total, name.c_str());
  for (const auto& s : m.streams) {
    if (s->timed) {
      std::fprintf(stderr, " %s %.1f%% %.0f ms;", s->key.c_str(),
                   100.0 * s->metrics.densities().back(), s->ms.back());
    }
  }
  std::fprintf(stderr, "\n");
}

// Every method on every frame of @p source. Sets @p info's frames, failed, size, picture and
// load_start; returns the picture frame's left image (ours' rectified colour image when there is
// one). @p err: a frame's error, the source's error at the end.
cv::Mat runFrames(const Options& o, FrameSource& source, Methods& m, RunInfo* info,
                  std::string* err) {
  const int total = source.size();
  info->picture = o.picture_frame >= 0 ? std::min(o.picture_frame, std::max(0, total - 1))
                                       : std::max(0, total - 1) / 2;
  info->load_start = loadAverage();
  cv::Mat picture_left;
  Frame frame;
  while (source.next(frame, err)) {
    const bool picture = info->frames == info->picture;
    cv::Mat left_gray, right_gray;
    if (!runOurs(m, frame, picture, &left_gray, &right_gray, err)) {
      ++info->failed;
      continue;
    }
    if (left_gray.empty()) {  // no pipeline ran: the input is rectified, convert as it would
      left_gray = grayOf(frame.input.left, frame.input.left_encoding);
      right_gray = grayOf(frame.input.right, frame.input.right_encoding);
    }
    info->size = left_gray.size();
    runOpenCv(m, o, left_gray, right_gray, picture);
    if (picture) {
      picture_left = (m.ours.empty() || m.ours[0].out.left_rect_color.empty())
                         ? toBgr(left_gray)
                         : m.ours[0].out.left_rect_color.clone();
    }
    if (!o.quiet) printProgress(m, info->frames, total, frame.name);
    ++info->frames;
  }
  return picture_left;
}

// The figures per method, one row each.
void printMethodTable(const Options& o, const Methods& m, const RunInfo& r) {
  std::printf("%s: %d frames %dx%d, disparities %d..%d (OpenCV: %d..%d)\n\n", r.label.c_str(),
              r.frames, r.size.width, r.size.height, o.min_disparity, o.max_disparity,
              o.min_disparity, o.min_disparity + r.num_disp - 1);
  std::printf(
      "| method | density median %% | density mean %% | jumps > %g px %% | motion-compensated "
      "flicker > %g px %% | central covered every %d frames %% | central never %% | ms/frame "
      "median | time / SGBM | CPU ms median |\n"
      "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
      o.jump_px, o.jump_px, r.window);
  for (const auto& s : m.streams) {
    const endo_stereo::SequenceSummary sum = s->metrics.summary();
    char timing[128] = "| - | - | - |";
    if (s->timed) {
      const double ms = timingMedian(s->ms, o.skip_timing);
      std::snprintf(timing, sizeof(timing), "| %.1f | %s | %.1f |", ms,
                    std::isfinite(r.sgbm_ms) ? cv::format("%.2f", ms / r.sgbm_ms).c_str() : "-",
                    timingMedian(s->cpu_ms, o.skip_timing));
    }
    std::printf("| %s | %.1f | %.1f | %.2f | %.2f | %.1f | %.1f %s\n", s->name.c_str(),
                100 * sum.density_median, 100 * sum.density_mean, 100 * sum.jump_share,
                100 * sum.flicker_share, 100 * sum.coverage_every_window, 100 * sum.coverage_never,
                timing);
  }
  std::printf(
      "\nTimes: wall time per frame, median over frames %d..%d; ours is the whole "
      "Pipeline::process "
      "call (threads: %d), OpenCV's the compute() call on the same rectified gray pair.%s\n",
      std::min(o.skip_timing, r.frames - 1) + 1, r.frames, cv::getNumThreads(),
      r.failed ? cv::format(" %d frame(s) failed.", r.failed).c_str() : "");
}

// Ours' time per stage, a column per setting.
void printStageTable(const Options& o, const Methods& m) {
  std::printf("\n| stage, ms (median, threads: %d) |", cv::getNumThreads());
  for (const Ours& x : m.ours) std::printf(" %s |", x.measured->name.c_str());
  std::printf("\n|---|");
  for (size_t i = 0; i < m.ours.size(); ++i) std::printf("---:|");
  std::printf("\n");
  for (int k = 0; k < kNumStages; ++k) {
    std::printf("| %s |", kStageNames[k].label);
    for (const Ours& x : m.ours) {
      std::printf(" %.2f |", timingMedian(x.measured->stage_ms[size_t(k)], o.skip_timing));
    }
    std::printf("\n");
  }
  std::printf(
      "\nStages: the median of each over the same frames as the times above; the medians need "
      "not add up to the total exactly.\n");
}

// The JSON (--json, else DIR/evaluation.json) and the pictures in DIR.
void writeOutputs(const Options& o, const RunInfo& info, const Methods& m,
                  const endo_stereo::PipelineParams& params, const cv::Mat& picture_left) {
  std::string json_path = o.json;
  if (json_path.empty() && !o.out_dir.empty()) json_path = o.out_dir + "/evaluation.json";
  if (!o.out_dir.empty()) ::mkdir(o.out_dir.c_str(), 0755);
  if (!json_path.empty()) {
    const std::string text = evaluationJson(o, info, m.streams, m.any_ours ? &params : nullptr);
    std::ofstream f(json_path);
    f << text;
    if (!f) throw InputError{"cannot write '" + json_path + "'"};
  }
  std::string err;
  if (!o.out_dir.empty() && !picture_left.empty() &&
      !writePictures(o, m.streams, picture_left, info.picture, info.frames, info.window, info.size,
                     &err)) {
    throw InputError{err};
  }
}

// Checks, parameters, frames, methods; every frame through every method; the tables, the JSON,
// the pictures.
int evaluate(const Options& o) {
  checkImageFiles(o);
  endo_stereo::PipelineParams params = makeParams(o);
  if (o.has_threads && o.threads > 0) cv::setNumThreads(o.threads);
  const endo_stereo::tools::FrameSourceSettings settings = sourceSettings(o);
  const std::unique_ptr<FrameSource> source = openSource(settings);
  endo_stereo::StereoCalibration calibration;
  const bool calibrated = findCalibration(o, *source, &calibration, &params);
  Methods methods = makeMethods(o, params, calibrated ? &calibration : nullptr);

  RunInfo info;
  std::string err;
  const cv::Mat picture_left = runFrames(o, *source, methods, &info, &err);
  if (!err.empty()) throw InputError{err};
  if (info.frames == 0) throw InputError{"no frame could be processed"};
  info.sgbm_ms =
      methods.sgbm_stream ? timingMedian(methods.sgbm_stream->ms, o.skip_timing) : std::nan("");
  info.label = o.label.empty() ? source->describe() : o.label;
  info.input = source->describe();
  info.num_disp = methods.num_disp;
  info.window = std::min(o.window, info.frames);

  printMethodTable(o, methods, info);
  if (!methods.ours.empty()) printStageTable(o, methods);
  std::fflush(stdout);
  writeOutputs(o, info, methods, params, picture_left);
  return info.failed ? kExitInput : kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  return endo_stereo::tools::runTool("endo_stereo_evaluate",
                                     [&] { return evaluate(parseArgs(argc, argv)); });
}
