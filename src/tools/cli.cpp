// endo_stereo_cli: the robust matcher (the whole Pipeline: pre-processing, rectification, matching,
// temporal priors, fusion, coverage, point cloud) on image files or image sequences. Runs the same
// core as the nodelet (one code path: what is tuned offline is what runs live). `endo_stereo_cli --help` lists the flags.
//
// Exit status: 0 success; 1 an input could not be read or processed (unreadable file, size
// mismatch, rectification failure, unwritable output); 2 bad usage (unknown flag, bad value,
// bad parameters or disparity range).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <memory>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "frame_sources.hpp"
#include "json_writer.hpp"
#include "tool_args.hpp"
#include "tool_params.hpp"

namespace {

using endo_stereo::tools::formatPattern;
using endo_stereo::tools::InputError;
using endo_stereo::tools::isPattern;
using endo_stereo::tools::JsonWriter;
using endo_stereo::tools::kExitInput;
using endo_stereo::tools::validPattern;

constexpr int kExitOk = 0;

const char* kUsage = R"(endo_stereo_cli - robust dense stereo (Bernhardt et al. 2012) on image files

Usage:
  endo_stereo_cli --left L --right R [options]

Input:
  --left PATH, --right PATH   a stereo pair (any format OpenCV reads: PNG, JPEG, TIFF, PPM, ...;
                              8- or 16-bit, gray or colour), or printf patterns such as
                              left_%04d.png for a sequence
  --first N                   first index of a sequence (default: 0, or 1 when frame 0 is missing)
  --count N                   number of frames (default: until the first missing left image)
  --fps F                     frame rate of a sequence, sets the stamps i/F (default 25)

Parameters (applied in this order; keys are listed by --list-params):
  --params FILE.yaml          a preset (config/default.yaml, config/paper.yaml, ...)
  --set KEY=VALUE             override one parameter, e.g. --set matcher.delta_min=0.2 (repeatable)
  --min-disparity N           smallest disparity searched, px (matcher.min_disparity)
  --max-disparity N           largest disparity searched, px, inclusive (matcher.max_disparity)
  --threads N                 worker threads (0 = OpenCV's default); results do not depend on it
  --list-params               print every parameter: key = value (type; range; paper, ours or
                              setting) and what it does, then exit; with --markdown the table of
                              defaults that README.md shows

Rectification (default: the input is already rectified):
  --calib SPEC                calibrated: 'left.yaml,right.yaml' (ROS camera_info YAML pair) or one
                              OpenCV stereo calibration YAML/XML (M1 D1 M2 D2 R T [R1 R2 P1 P2])
  --uncalibrated              estimate the rectification from the images (SIFT, F by RANSAC)
  --focal PX, --baseline M    focal length (px) and baseline (m) for metric depth when the input
                              is uncalibrated or already rectified
  --downsample N              downsample the input by N (1, 2, 4) before matching
  --out-rectified PREFIX      write the rectified pair as PREFIX_left.png / PREFIX_right.png
                              (sequences: PREFIX_left_000012.png, ... by frame index)

Outputs (in sequence mode the per-frame outputs need a printf pattern, e.g. disp_%04d.pfm):
  --out-disparity D.pfm       float32 PFM disparity, invalid = +inf (Middlebury convention)
  --out-color D.png           colourised disparity (turbo map over the search range), invalid black
  --out-cloud C.ply           organized cloud's valid points with colour (binary PLY; metres when
                              the geometry is metric, else baseline units)
  --ply-ascii                 write the PLY as ASCII
  --out-fused F.pfm|F.png     temporally fused disparity (PFM, or colourised for other extensions)
  --out-coverage C.png        coverage map over the sequence (longest run of frames without an
                              update per pixel), written at the end
  --stats S.json              density, rejections per criterion, milliseconds per frame (sequence
                              mode: per-frame time, density, prior hits; summary and coverage)
  --no-priors                 sequence mode without temporal priors (to compare)
  --quiet                     no per-frame progress lines
  --help                      this text

Exit status: 0 success, 1 unreadable or unprocessable input (or unwritable output), 2 bad usage
or parameters.
)";

using endo_stereo::tools::ArgReader;
using endo_stereo::tools::UsageError;

// The shared flags (tool_args.hpp) the CLI takes, with their ranges' defaults, and its own.
struct Options : endo_stereo::tools::SharedOptions {
  Options()
      : SharedOptions(endo_stereo::tools::kFlagLeftRight | endo_stereo::tools::kFlagFirst |
                      endo_stereo::tools::kFlagCount | endo_stereo::tools::kFlagFps |
                      endo_stereo::tools::kFlagParams | endo_stereo::tools::kFlagDisparityRange |
                      endo_stereo::tools::kFlagThreads | endo_stereo::tools::kFlagQuiet) {}
  bool uncalibrated = false;
  bool has_focal = false, has_baseline = false;
  double focal = 0.0, baseline = 0.0;
  bool has_downsample = false;
  int downsample = 1;
  std::string out_rectified, out_disparity, out_color, out_cloud, out_fused, out_coverage, stats;
  bool ply_ascii = false;
  bool no_priors = false;
  bool list_params = false;
  bool markdown = false;
};

// --uncalibrated, --focal, --baseline, --downsample: true when the flag is one of them.
bool readRectifyOption(ArgReader& args, Options& o) {
  if (args.is("--uncalibrated")) {
    o.uncalibrated = true;
  } else if (args.is("--focal")) {
    o.focal = args.positive();
    o.has_focal = true;
  } else if (args.is("--baseline")) {
    o.baseline = args.positive();
    o.has_baseline = true;
  } else if (args.is("--downsample")) {
    o.downsample = args.integer();
    o.has_downsample = true;
  } else {
    return false;
  }
  return true;
}

// The files written: --out-*, --ply-ascii, --stats.
bool readOutputOption(ArgReader& args, Options& o) {
  if (args.is("--out-rectified")) {
    o.out_rectified = args.text();
  } else if (args.is("--out-disparity")) {
    o.out_disparity = args.text();
  } else if (args.is("--out-color")) {
    o.out_color = args.text();
  } else if (args.is("--out-cloud")) {
    o.out_cloud = args.text();
  } else if (args.is("--ply-ascii")) {
    o.ply_ascii = true;
  } else if (args.is("--out-fused")) {
    o.out_fused = args.text();
  } else if (args.is("--out-coverage")) {
    o.out_coverage = args.text();
  } else if (args.is("--stats")) {
    o.stats = args.text();
  } else {
    return false;
  }
  return true;
}

// --no-priors, --list-params, --markdown.
bool readRunOption(ArgReader& args, Options& o) {
  if (args.is("--no-priors")) {
    o.no_priors = true;
  } else if (args.is("--list-params")) {
    o.list_params = true;
  } else if (args.is("--markdown")) {
    o.markdown = true;
  } else {
    return false;
  }
  return true;
}

Options parseArgs(int argc, char** argv) {
  Options o;
  endo_stereo::tools::readArguments(argc, argv, kUsage, o, [&o](ArgReader& args) {
    return readRectifyOption(args, o) || readOutputOption(args, o) || readRunOption(args, o);
  });
  if (o.markdown && !o.list_params) throw UsageError("--markdown goes with --list-params");
  if (o.list_params) return o;
  if (o.left.empty() || o.right.empty()) throw UsageError("--left and --right are required");
  if (!o.calib.empty() && o.uncalibrated) {
    throw UsageError("--calib and --uncalibrated exclude each other");
  }
  return o;
}

// --- file names ------------------------------------------------------------------------------

std::string withSuffix(const std::string& prefix, const std::string& side, bool sequence,
                       int index) {
  if (!sequence) return prefix + "_" + side + ".png";
  char num[16];
  std::snprintf(num, sizeof(num), "%06d", index);
  return prefix + "_" + side + "_" + num + ".png";
}

std::string lowerExtension(const std::string& path) {
  const size_t dot = path.find_last_of('.');
  const size_t slash = path.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string ext = path.substr(dot + 1);
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return ext;
}

// --- images ----------------------------------------------------------------------------------

bool writeImage(const std::string& path, const cv::Mat& image, std::string* error) {
  bool ok = false;
  try {
    ok = cv::imwrite(path, image);
  } catch (const cv::Exception& ex) {
    *error = "cannot write '" + path + "': " + ex.what();
    return false;
  }
  if (!ok) *error = "cannot write '" + path + "' (missing folder or unknown image extension)";
  return ok;
}

// --- statistics ------------------------------------------------------------------------------

const char* kRejectNames[endo_stereo::kNumRejectCodes] = {
    "not_searched", "structure", "peak_gap", "left_right", "edge", "outlier", "no_peak", "filled"};

struct FrameRecord {
  int index = 0;
  double stamp_s = 0;
  std::string left, right;
  cv::Size size;
  endo_stereo::MatchStats match;
  endo_stereo::TemporalPriorStats prior;
  endo_stereo::RectificationQuality quality;
  bool priors_used = false, priors_rejected = false, priors_reset = false;
  std::string reset_reason;
  double preprocess_ms = 0, rectify_ms = 0, match_ms = 0, temporal_ms = 0, cloud_ms = 0,
         total_ms = 0;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

void writeRejections(JsonWriter& j, const endo_stereo::MatchStats& s) {
  j.beginObject();
  for (int c = 0; c < endo_stereo::kNumRejectCodes; ++c)
    j.key(kRejectNames[c]).value(s.rejected[c]);
  j.endObject();
}

// The sums over the frames that the summary reports.
struct FrameTotals {
  std::vector<double> total_ms, match_ms;
  double density_sum = 0;
  endo_stereo::MatchStats sums;
  int64_t hits = 0, misses = 0, narrowed = 0;
};

FrameTotals sumFrames(const std::vector<FrameRecord>& frames) {
  FrameTotals t;
  for (const FrameRecord& f : frames) {
    t.total_ms.push_back(f.total_ms);
    t.match_ms.push_back(f.match_ms);
    t.density_sum += f.match.density();
    for (int c = 0; c < endo_stereo::kNumRejectCodes; ++c) {
      t.sums.rejected[c] += f.match.rejected[c];
    }
    t.sums.valid_pixels += f.match.valid_pixels;
    t.sums.total_pixels += f.match.total_pixels;
    t.hits += f.prior.prior_hits;
    t.misses += f.prior.prior_misses;
    t.narrowed += f.prior.narrowed_pixels;
  }
  return t;
}

// The coverage map's figures over the sequence.
void writeCoverage(JsonWriter& j, const endo_stereo::CoverageStats& c) {
  j.beginObject();
  j.key("frames").value(c.frames);
  j.key("within_frames").value(c.within_frames);
  j.key("central_share_updated_within").value(c.central_share);
  j.key("overall_share_updated_within").value(c.overall_share);
  j.key("central_never_updated").value(c.central_never);
  j.key("overall_never_updated").value(c.overall_never);
  j.key("central_region").beginArray();
  j.value(c.central_region.x).value(c.central_region.y);
  j.value(c.central_region.width).value(c.central_region.height);
  j.endArray();
  j.endObject();
}

// Density, times and rejections over all frames; in sequence mode also the priors' figures and,
// when the pipeline kept it, the coverage.
void writeSummary(JsonWriter& j, const std::vector<FrameRecord>& frames, bool sequence,
                  const endo_stereo::Pipeline& pipeline, bool coverage) {
  const FrameTotals t = sumFrames(frames);
  j.beginObject();
  j.key("density").value(frames.empty() ? 0.0 : t.density_sum / frames.size());
  j.key("ms_per_frame_median").value(median(t.total_ms));
  j.key("match_ms_median").value(median(t.match_ms));
  j.key("rejected");
  writeRejections(j, t.sums);
  j.key("valid_pixels").value(t.sums.valid_pixels);
  j.key("total_pixels").value(t.sums.total_pixels);
  if (sequence) {
    // Steady state: the first frame searches the full range whatever the priors.
    std::vector<double> steady(t.total_ms.begin() + std::min<size_t>(1, t.total_ms.size()),
                               t.total_ms.end());
    j.key("ms_per_frame_median_after_first").value(median(steady));
    j.key("prior_narrowed_pixels").value(t.narrowed);
    j.key("prior_hits").value(t.hits);
    j.key("prior_misses").value(t.misses);
    j.key("prior_hit_rate")
        .value(t.hits + t.misses ? double(t.hits) / double(t.hits + t.misses) : 0.0);
  }
  if (coverage && pipeline.temporal().coverage().frames() > 0) {
    j.key("coverage");
    writeCoverage(j, pipeline.temporal().coverage().stats());
  }
  j.endObject();
}

// A frame's milliseconds per stage.
void writeFrameTimes(JsonWriter& j, const FrameRecord& f) {
  j.beginObject();
  j.key("total").value(f.total_ms);
  j.key("preprocess").value(f.preprocess_ms);
  j.key("rectify").value(f.rectify_ms);
  j.key("match").value(f.match_ms);
  j.key("match_only").value(f.match.match_ms);
  j.key("match_prepare").value(f.match.prepare_ms);  // part of match_only
  j.key("match_edge").value(f.match.edge_ms);        // part of match_only
  j.key("filter").value(f.match.filter_ms);
  j.key("temporal").value(f.temporal_ms);
  j.key("cloud").value(f.cloud_ms);
  j.endObject();
}

// What a frame's temporal priors did.
void writePriorStats(JsonWriter& j, const endo_stereo::TemporalPriorStats& prior) {
  j.beginObject();
  j.key("narrowed_pixels").value(prior.narrowed_pixels);
  j.key("full_range_pixels").value(prior.full_range_pixels);
  j.key("deferred_pixels").value(prior.deferred_pixels);
  j.key("edge_zone_pixels").value(prior.edge_zone_pixels);
  j.key("hits").value(prior.prior_hits);
  j.key("misses").value(prior.prior_misses);
  j.key("mean_narrowed_width_px").value(prior.mean_narrowed_width_px);
  j.endObject();
}

// How well a frame's rows line up after rectification, when it was measured.
void writeRectificationQuality(JsonWriter& j, const endo_stereo::RectificationQuality& q) {
  j.beginObject();
  j.key("method").value(q.method);
  j.key("measured").value(q.valid);
  if (q.valid) {
    j.key("median_offset_px").value(q.median_offset_px);
    j.key("p90_offset_px").value(q.p90_offset_px);
    j.key("num_matches").value(q.num_matches);
    j.key("measured_on_frame").value(q.frame_index);
    if (q.row_offset_matches > 0) {
      // the fitted offset plane c0 + c1 x + c2 y (px) and its matches (rectify.row_correction)
      j.key("row_offset_px").beginArray();
      for (int i = 0; i < 3; ++i) j.value(q.row_offset[i]);
      j.endArray();
      j.key("row_offset_matches").value(q.row_offset_matches);
    }
    j.key("warning").value(q.warning);
  }
  if (q.misaligned) j.key("misaligned").value(true);
  if (!q.message.empty()) j.key("message").value(q.message);
  j.endObject();
}

// One frame: files, size, density, rejections, accepted matches per window size, times, priors,
// rectification quality.
void writeFrame(JsonWriter& j, const FrameRecord& f, const endo_stereo::PipelineParams& p) {
  j.beginObject();
  j.key("index").value(f.index);
  j.key("stamp_s").value(f.stamp_s);
  j.key("left").value(f.left);
  j.key("right").value(f.right);
  j.key("width").value(f.size.width);
  j.key("height").value(f.size.height);
  j.key("density").value(f.match.density());
  j.key("valid_pixels").value(f.match.valid_pixels);
  j.key("total_pixels").value(f.match.total_pixels);
  j.key("rejected");
  writeRejections(j, f.match);
  j.key("accepted_per_window").beginObject();
  for (int k = 0; k < 16; ++k) {
    const int w = p.matcher.window_min_px + k * p.matcher.window_step_px;
    if (w > p.matcher.window_max_px) break;
    j.key(std::to_string(w)).value(f.match.accepted_per_window[k]);
  }
  j.endObject();
  j.key("ms");
  writeFrameTimes(j, f);
  j.key("priors_used").value(f.priors_used);
  j.key("priors_rejected").value(f.priors_rejected);
  j.key("priors_reset").value(f.priors_reset);
  if (f.priors_reset) j.key("reset_reason").value(f.reset_reason);
  j.key("prior");
  writePriorStats(j, f.prior);
  j.key("rectification");
  writeRectificationQuality(j, f.quality);
  j.endObject();
}

// The statistics file: the run, its summary first (the figures at the top for a person reading
// it), every frame, the parameters.
std::string statsJson(const std::vector<FrameRecord>& frames, const endo_stereo::PipelineParams& p,
                      bool sequence, int failed_frames, const endo_stereo::Pipeline& pipeline,
                      bool coverage) {
  JsonWriter j;
  j.beginObject();
  j.key("tool").value("endo_stereo_cli");
  j.key("mode").value(sequence ? "sequence" : "single");
  j.key("frames_processed").value(static_cast<int>(frames.size()));
  j.key("frames_failed").value(failed_frames);
  j.key("summary");
  writeSummary(j, frames, sequence, pipeline, coverage);
  j.key("frames").beginArray();
  for (const FrameRecord& f : frames) writeFrame(j, f, p);
  j.endArray();
  j.key("params").beginObject();
  for (const endo_stereo::ParamInfo& info : endo_stereo::listPipelineParams(p)) {
    j.key(info.key).value(info.value);
  }
  j.endObject();
  j.endObject();
  return j.str();
}

// --- steps of a run ---------------------------------------------------------------------------

// Defaults (input already rectified), then the preset, the overrides, the flags.
endo_stereo::PipelineParams makeParams(const Options& o) {
  endo_stereo::PipelineParams params;
  params.rectify.mode = endo_stereo::RectifyMode::kPassThrough;
  params.output.point_cloud = false;
  const std::string err =
      endo_stereo::tools::applyPresetAndOverrides(o.params_file, o.overrides, params);
  if (!err.empty()) throw UsageError(err);
  if (o.has_min) params.matcher.min_disparity = o.min_disparity;
  if (o.has_max) params.matcher.max_disparity = o.max_disparity;
  if (params.matcher.min_disparity > params.matcher.max_disparity) {
    throw UsageError("bad disparity range: min " + std::to_string(params.matcher.min_disparity) +
                     " > max " + std::to_string(params.matcher.max_disparity));
  }
  if (o.has_threads) params.matcher.num_threads = o.threads;
  if (o.has_downsample) params.preprocess.downsample = o.downsample;
  if (!o.calib.empty()) params.rectify.mode = endo_stereo::RectifyMode::kCalibrated;
  if (o.uncalibrated) params.rectify.mode = endo_stereo::RectifyMode::kUncalibrated;
  if (o.has_focal) params.rectify.focal_px = o.focal;
  if (o.has_baseline) params.rectify.baseline_m = o.baseline;
  if (o.no_priors) params.temporal.enabled = false;
  if (!o.out_fused.empty()) params.output.fused = true;
  if (!o.out_coverage.empty()) params.output.coverage = true;
  if (!o.out_cloud.empty()) params.output.point_cloud = true;
  return params;
}

// One line per parameter: key = value (type; range; origin) and what it does.
void printParams(const endo_stereo::PipelineParams& params) {
  for (const endo_stereo::ParamInfo& info : endo_stereo::listPipelineParams(params)) {
    std::cout << info.key << " = " << info.value << "  (" << endo_stereo::paramTypeName(info.type);
    if (!info.range.empty()) std::cout << "; " << info.range;
    std::cout << "; " << endo_stereo::paramOriginName(info.origin) << ")  " << info.meaning
              << "\n";
  }
}

// Sequence mode needs patterns for the inputs and the per-frame outputs; a single pair takes
// neither --first/--count nor a malformed pattern.
void checkFileNames(const Options& o, bool sequence) {
  const std::string* outputs[] = {&o.out_disparity, &o.out_color, &o.out_cloud, &o.out_fused};
  if (sequence) {
    if (!isPattern(o.left) || !isPattern(o.right) || !validPattern(o.left) ||
        !validPattern(o.right)) {
      throw UsageError(
          "a sequence needs --left and --right patterns with one integer conversion each, e.g. "
          "left_%04d.png");
    }
    for (const std::string* out : outputs) {
      if (!out->empty() && !(isPattern(*out) && validPattern(*out))) {
        throw UsageError("in sequence mode '" + *out +
                         "' must be a printf pattern with one integer conversion, e.g. "
                         "disp_%04d.pfm");
      }
    }
    return;
  }
  if (o.has_first || o.count > 0) {
    throw UsageError("--first/--count need --left/--right patterns");
  }
  for (const std::string* out : outputs) {
    if (!out->empty() && isPattern(*out) && !validPattern(*out)) {
      throw UsageError("bad output name '" + *out + "'");
    }
  }
}

std::unique_ptr<endo_stereo::Pipeline> makePipeline(const endo_stereo::PipelineParams& params,
                                                    const std::string& calib) {
  std::unique_ptr<endo_stereo::Pipeline> pipeline;
  try {
    pipeline = std::make_unique<endo_stereo::Pipeline>(params);
  } catch (const std::exception& ex) {
    throw UsageError(std::string("bad parameters: ") + ex.what());
  }
  if (!calib.empty()) {
    endo_stereo::StereoCalibration calibration;
    std::string err;
    if (!endo_stereo::loadStereoCalibration(calib, calibration, &err)) {
      throw InputError{"--calib: " + err};
    }
    err = pipeline->setCalibration(calibration);
    if (!err.empty()) throw InputError{"--calib: " + err};
  }
  return pipeline;
}

FrameRecord makeRecord(const endo_stereo::tools::Frame& frame,
                       const endo_stereo::PipelineOutput& out) {
  FrameRecord r;
  r.index = frame.index;
  r.stamp_s = frame.input.stamp_s;
  r.left = frame.left_path;
  r.right = frame.right_path;
  r.size = out.match.disparity.size();
  r.match = out.match.stats;
  r.prior = out.prior_stats;
  r.quality = out.rect_quality;
  r.priors_used = out.priors_used;
  r.priors_rejected = out.priors_rejected;
  r.priors_reset = out.priors_reset;
  r.reset_reason = out.reset_reason;
  r.preprocess_ms = out.preprocess_ms;
  r.rectify_ms = out.rectify_ms;
  r.match_ms = out.match_ms;
  r.temporal_ms = out.temporal_ms;
  r.cloud_ms = out.cloud_ms;
  r.total_ms = out.total_ms;
  return r;
}

void warnAboutRectification(const endo_stereo::PipelineOutput& out, int index) {
  const endo_stereo::RectificationQuality& q = out.rect_quality;
  if (q.valid && q.warning && q.frame_index == out.frame_index) {
    std::cerr << "endo_stereo_cli: warning: frame " << index
              << ": rectification leaves a median vertical offset of " << q.median_offset_px
              << " px (90th percentile " << q.p90_offset_px << " px): check the calibration\n";
  } else if (q.misaligned && q.frame_index == out.frame_index) {
    std::cerr << "endo_stereo_cli: warning: frame " << index << ": " << q.message
              << ": check the calibration\n";
  }
}

void check(bool ok, const std::string& err) {
  if (!ok) throw InputError{err};
}

// The per-frame outputs the flags ask for; a sequence's names are its patterns at @p index.
void writeFrameOutputs(const Options& o, const endo_stereo::PipelineParams& params,
                       const endo_stereo::PipelineOutput& out, bool sequence, int index,
                       bool* warned_cloud) {
  auto name = [&](const std::string& path) {
    return sequence ? formatPattern(path, index) : path;
  };
  std::string err;
  if (!o.out_disparity.empty()) {
    check(endo_stereo::writePfm(name(o.out_disparity), out.match.disparity, &err), err);
  }
  const double d_lo = params.matcher.min_disparity, d_hi = params.matcher.max_disparity;
  if (!o.out_color.empty()) {
    check(writeImage(name(o.out_color),
                     endo_stereo::colorizeDisparity(out.match.disparity, d_lo, d_hi), &err),
          err);
  }
  if (!o.out_fused.empty()) {
    const std::string path = name(o.out_fused);
    check(lowerExtension(path) == "pfm"
              ? endo_stereo::writePfm(path, out.fused_disparity, &err)
              : writeImage(path, endo_stereo::colorizeDisparity(out.fused_disparity, d_lo, d_hi),
                           &err),
          err);
  }
  if (!o.out_rectified.empty()) {
    check(writeImage(withSuffix(o.out_rectified, "left", sequence, index), out.left_rect_gray,
                     &err) &&
              writeImage(withSuffix(o.out_rectified, "right", sequence, index),
                         out.right_rect_gray, &err),
          err);
  }
  if (o.out_cloud.empty()) return;
  if (!*warned_cloud && (out.geometry.polar || !out.cloud.metric)) {
    std::cerr << "endo_stereo_cli: note: "
              << (out.geometry.polar
                      ? "polar rectification has no depth from disparity: the cloud is empty"
                      : "no metric geometry (give --calib, or --focal and --baseline): the "
                        "cloud is in units of the baseline")
              << "\n";
    *warned_cloud = true;
  }
  check(endo_stereo::writePly(name(o.out_cloud), out.cloud, !o.ply_ascii, &err), err);
}

void printProgress(const FrameRecord& r) {
  std::fprintf(stderr, "frame %d: %dx%d density %.1f%% %.1f ms%s%s\n", r.index, r.size.width,
               r.size.height, 100.0 * r.match.density(), r.total_ms,
               r.priors_used       ? " (priors)"
               : r.priors_rejected ? " (priors rejected: scene change, full range)"
                                   : "",
               r.priors_reset ? (" reset: " + r.reset_reason).c_str() : "");
}

void printSummary(const std::vector<FrameRecord>& records, int failed) {
  std::vector<double> ms;
  double density = 0;
  for (const FrameRecord& r : records) {
    ms.push_back(r.total_ms);
    density += r.match.density();
  }
  std::fprintf(stderr, "%zu frame(s): median %.1f ms/frame, mean density %.1f%%%s\n",
               records.size(), median(ms), 100.0 * density / records.size(),
               failed ? (", " + std::to_string(failed) + " failed").c_str() : "");
}

// The outputs written once at the end: the coverage picture and the statistics.
void writeRunOutputs(const Options& o, const endo_stereo::PipelineParams& params,
                     const endo_stereo::Pipeline& pipeline,
                     const std::vector<FrameRecord>& records, bool sequence, int failed) {
  if (!o.out_coverage.empty()) {
    const cv::Mat picture = pipeline.temporal().coverage().colorImage();
    if (picture.empty()) throw InputError{"no coverage to write (no frame was processed)"};
    std::string err;
    check(writeImage(o.out_coverage, picture, &err), err);
  }
  if (!o.stats.empty()) {
    std::ofstream f(o.stats);
    f << statsJson(records, params, sequence, failed, pipeline, params.output.coverage);
    if (!f) throw InputError{"cannot write '" + o.stats + "'"};
  }
}

// --- main ------------------------------------------------------------------------------------

// Options, parameters, file names, the pipeline; then every frame through it and its outputs.
int process(const Options& o) {
  const endo_stereo::PipelineParams params = makeParams(o);
  if (o.list_params) {
    if (o.markdown) {
      std::cout << endo_stereo::paramTableMarkdown();
    } else {
      printParams(params);
    }
    return kExitOk;
  }
  const std::string err = params.validate();
  if (!err.empty()) throw UsageError("bad parameters: " + err);
  if (params.rectify.mode == endo_stereo::RectifyMode::kCalibrated && o.calib.empty()) {
    throw UsageError("rectify.mode is 'calibrated' but no --calib was given");
  }
  if (o.has_threads && o.threads > 0) cv::setNumThreads(o.threads);
  const bool sequence = isPattern(o.left) || isPattern(o.right);
  checkFileNames(o, sequence);
  const std::unique_ptr<endo_stereo::Pipeline> pipeline = makePipeline(params, o.calib);

  const endo_stereo::tools::FrameSourceSettings settings =
      endo_stereo::tools::frameSourceSettings(o);
  const std::unique_ptr<endo_stereo::tools::FrameSource> source =
      endo_stereo::tools::makeFileFrameSource(settings);
  if (source->size() == 0) throw InputError{"no frame found: " + source->emptyReason()};

  std::vector<FrameRecord> records;
  endo_stereo::tools::Frame frame;
  endo_stereo::PipelineOutput out;
  int failed = 0;
  bool warned_cloud = false;
  std::string frame_err;
  while (source->next(frame, &frame_err)) {
    if (!pipeline->process(frame.input, out, &frame_err)) {
      std::cerr << "endo_stereo_cli: frame " << frame.index << " (" << frame.left_path
                << "): " << frame_err << "\n";
      ++failed;
      if (!sequence) return kExitInput;
      frame_err.clear();
      continue;
    }
    records.push_back(makeRecord(frame, out));
    warnAboutRectification(out, frame.index);
    writeFrameOutputs(o, params, out, sequence, frame.index, &warned_cloud);
    if (!o.quiet) printProgress(records.back());
  }
  if (!frame_err.empty()) throw InputError{frame_err};
  writeRunOutputs(o, params, *pipeline, records, sequence, failed);
  if (!o.quiet && !records.empty()) printSummary(records, failed);
  return failed ? kExitInput : kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  return endo_stereo::tools::runTool("endo_stereo_cli",
                                     [&] { return process(parseArgs(argc, argv)); });
}
