// endo_stereo_cli: the robust matcher (the whole Pipeline: pre-processing, rectification, matching,
// temporal priors, fusion, coverage, point cloud) on image files or image sequences. Runs the same
// core as the nodelet (one code path: what is tuned offline is what runs live). `endo_stereo_cli --help` lists the flags.
//
// Exit status: 0 success; 1 an input could not be read or processed (unreadable file, size
// mismatch, rectification failure, unwritable output); 2 bad usage (unknown flag, bad value,
// bad parameters or disparity range).
#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <regex>
#include <string>
#include <vector>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/core/pipeline.hpp"
#include "json_writer.hpp"
#include "tool_params.hpp"

namespace {

using endo_stereo::tools::JsonWriter;

constexpr int kExitOk = 0;
constexpr int kExitInput = 1;
constexpr int kExitUsage = 2;

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
  --list-params               print every parameter key with its value and type, then exit

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

struct Options {
  std::string left, right;
  bool has_first = false;
  int first = 0;
  int count = -1;
  double fps = 25.0;
  std::string params_file;
  std::vector<std::string> overrides;
  bool has_min = false, has_max = false;
  int min_disparity = 0, max_disparity = 0;
  bool has_threads = false;
  int threads = 0;
  std::string calib;
  bool uncalibrated = false;
  bool has_focal = false, has_baseline = false;
  double focal = 0.0, baseline = 0.0;
  bool has_downsample = false;
  int downsample = 1;
  std::string out_rectified, out_disparity, out_color, out_cloud, out_fused, out_coverage, stats;
  bool ply_ascii = false;
  bool no_priors = false;
  bool quiet = false;
  bool list_params = false;
};

struct UsageError {
  std::string message;
};

bool parseInt(const std::string& text, int* out) {
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0' || errno == ERANGE || v < INT32_MIN || v > INT32_MAX)
    return false;
  *out = static_cast<int>(v);
  return true;
}

bool parseDouble(const std::string& text, double* out) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(v)) return false;
  *out = v;
  return true;
}

Options parseArgs(int argc, char** argv) {
  Options o;
  auto need = [&](int& i, const std::string& flag) -> std::string {
    if (i + 1 >= argc) throw UsageError{flag + " needs a value"};
    return argv[++i];
  };
  auto needInt = [&](int& i, const std::string& flag) {
    const std::string v = need(i, flag);
    int out = 0;
    if (!parseInt(v, &out)) throw UsageError{flag + ": expected an integer, got '" + v + "'"};
    return out;
  };
  auto needDouble = [&](int& i, const std::string& flag) {
    const std::string v = need(i, flag);
    double out = 0;
    if (!parseDouble(v, &out)) throw UsageError{flag + ": expected a number, got '" + v + "'"};
    return out;
  };
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      std::cout << kUsage;
      std::exit(kExitOk);
    } else if (a == "--left") {
      o.left = need(i, a);
    } else if (a == "--right") {
      o.right = need(i, a);
    } else if (a == "--first") {
      o.first = needInt(i, a);
      o.has_first = true;
      if (o.first < 0) throw UsageError{"--first must be >= 0"};
    } else if (a == "--count") {
      o.count = needInt(i, a);
      if (o.count < 1) throw UsageError{"--count must be >= 1"};
    } else if (a == "--fps") {
      o.fps = needDouble(i, a);
      if (o.fps <= 0) throw UsageError{"--fps must be > 0"};
    } else if (a == "--params") {
      o.params_file = need(i, a);
    } else if (a == "--set") {
      o.overrides.push_back(need(i, a));
    } else if (a == "--min-disparity") {
      o.min_disparity = needInt(i, a);
      o.has_min = true;
    } else if (a == "--max-disparity") {
      o.max_disparity = needInt(i, a);
      o.has_max = true;
    } else if (a == "--threads") {
      o.threads = needInt(i, a);
      o.has_threads = true;
      if (o.threads < 0) throw UsageError{"--threads must be >= 0"};
    } else if (a == "--calib") {
      o.calib = need(i, a);
    } else if (a == "--uncalibrated") {
      o.uncalibrated = true;
    } else if (a == "--focal") {
      o.focal = needDouble(i, a);
      o.has_focal = true;
      if (o.focal <= 0) throw UsageError{"--focal must be > 0 (px)"};
    } else if (a == "--baseline") {
      o.baseline = needDouble(i, a);
      o.has_baseline = true;
      if (o.baseline <= 0) throw UsageError{"--baseline must be > 0 (m)"};
    } else if (a == "--downsample") {
      o.downsample = needInt(i, a);
      o.has_downsample = true;
    } else if (a == "--out-rectified") {
      o.out_rectified = need(i, a);
    } else if (a == "--out-disparity") {
      o.out_disparity = need(i, a);
    } else if (a == "--out-color") {
      o.out_color = need(i, a);
    } else if (a == "--out-cloud") {
      o.out_cloud = need(i, a);
    } else if (a == "--ply-ascii") {
      o.ply_ascii = true;
    } else if (a == "--out-fused") {
      o.out_fused = need(i, a);
    } else if (a == "--out-coverage") {
      o.out_coverage = need(i, a);
    } else if (a == "--stats") {
      o.stats = need(i, a);
    } else if (a == "--no-priors") {
      o.no_priors = true;
    } else if (a == "--quiet") {
      o.quiet = true;
    } else if (a == "--list-params") {
      o.list_params = true;
    } else {
      throw UsageError{"unknown argument '" + a + "' (see --help)"};
    }
  }
  if (o.list_params) return o;
  if (o.left.empty() || o.right.empty()) throw UsageError{"--left and --right are required"};
  if (!o.calib.empty() && o.uncalibrated) {
    throw UsageError{"--calib and --uncalibrated exclude each other"};
  }
  return o;
}

// --- file names ------------------------------------------------------------------------------

bool isPattern(const std::string& s) { return s.find('%') != std::string::npos; }

// A sequence pattern holds exactly one integer conversion (%d, %04d, %6i) and no other '%'
// except '%%'; anything else would make snprintf read arguments that are not there.
bool validPattern(const std::string& s) {
  static const std::regex conversion("%[0-9]*[di]");
  int conversions = 0;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] != '%') continue;
    if (i + 1 < s.size() && s[i + 1] == '%') {
      ++i;
      continue;
    }
    std::smatch m;
    const std::string rest = s.substr(i);
    if (!std::regex_search(rest, m, conversion, std::regex_constants::match_continuous)) {
      return false;
    }
    ++conversions;
    i += m.length(0) - 1;
  }
  return conversions == 1;
}

std::string formatPattern(const std::string& pattern, int index) {
  std::vector<char> buf(pattern.size() + 32);
  std::snprintf(buf.data(), buf.size(), pattern.c_str(), index);
  return std::string(buf.data());
}

bool fileExists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode);
}

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

// Reads an image as stored (8/16 bit, 1/3/4 channels) and names its ROS encoding. 16-bit colour
// is scaled to 8 bit (the pipeline's colour encodings are 8-bit).
bool readImage(const std::string& path, cv::Mat& image, std::string& encoding, std::string* error) {
  if (!fileExists(path)) {
    *error = "cannot read image '" + path + "': no such file";
    return false;
  }
  image = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (image.empty()) {
    *error = "cannot read image '" + path + "': not an image format OpenCV reads";
    return false;
  }
  const int depth = image.depth(), channels = image.channels();
  if (depth == CV_16U && channels > 1) {
    image.convertTo(image, CV_8U, 1.0 / 257.0);
  } else if (depth != CV_8U && depth != CV_16U) {
    *error = "image '" + path + "': unsupported pixel depth (8- or 16-bit images only)";
    return false;
  }
  switch (image.type()) {
    case CV_8UC1:
      encoding = "mono8";
      break;
    case CV_16UC1:
      encoding = "mono16";
      break;
    case CV_8UC3:
      encoding = "bgr8";
      break;
    case CV_8UC4:
      encoding = "bgra8";
      break;
    default:
      *error = "image '" + path + "': unsupported channel count " + std::to_string(channels);
      return false;
  }
  return true;
}

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

std::string statsJson(const std::vector<FrameRecord>& frames, const endo_stereo::PipelineParams& p,
                      bool sequence, int failed_frames, const endo_stereo::Pipeline& pipeline,
                      bool coverage) {
  JsonWriter j;
  j.beginObject();
  j.key("tool").value("endo_stereo_cli");
  j.key("mode").value(sequence ? "sequence" : "single");
  j.key("frames_processed").value(static_cast<int>(frames.size()));
  j.key("frames_failed").value(failed_frames);

  // Summary first, so a person reading the file sees the figures at the top.
  std::vector<double> total_ms, match_ms;
  double density_sum = 0;
  endo_stereo::MatchStats sums;
  int64_t hits = 0, misses = 0, narrowed = 0;
  for (const FrameRecord& f : frames) {
    total_ms.push_back(f.total_ms);
    match_ms.push_back(f.match_ms);
    density_sum += f.match.density();
    for (int c = 0; c < endo_stereo::kNumRejectCodes; ++c) sums.rejected[c] += f.match.rejected[c];
    sums.valid_pixels += f.match.valid_pixels;
    sums.total_pixels += f.match.total_pixels;
    hits += f.prior.prior_hits;
    misses += f.prior.prior_misses;
    narrowed += f.prior.narrowed_pixels;
  }
  j.key("summary").beginObject();
  j.key("density").value(frames.empty() ? 0.0 : density_sum / frames.size());
  j.key("ms_per_frame_median").value(median(total_ms));
  j.key("match_ms_median").value(median(match_ms));
  j.key("rejected");
  writeRejections(j, sums);
  j.key("valid_pixels").value(sums.valid_pixels);
  j.key("total_pixels").value(sums.total_pixels);
  if (sequence) {
    // Steady state: the first frame searches the full range whatever the priors.
    std::vector<double> steady(total_ms.begin() + std::min<size_t>(1, total_ms.size()),
                               total_ms.end());
    j.key("ms_per_frame_median_after_first").value(median(steady));
    j.key("prior_narrowed_pixels").value(narrowed);
    j.key("prior_hits").value(hits);
    j.key("prior_misses").value(misses);
    j.key("prior_hit_rate").value(hits + misses ? double(hits) / double(hits + misses) : 0.0);
  }
  if (coverage && pipeline.temporal().coverage().frames() > 0) {
    const endo_stereo::CoverageStats c = pipeline.temporal().coverage().stats();
    j.key("coverage").beginObject();
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
  j.endObject();

  j.key("frames").beginArray();
  for (const FrameRecord& f : frames) {
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
    j.key("ms").beginObject();
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
    j.key("priors_used").value(f.priors_used);
    j.key("priors_rejected").value(f.priors_rejected);
    j.key("priors_reset").value(f.priors_reset);
    if (f.priors_reset) j.key("reset_reason").value(f.reset_reason);
    j.key("prior").beginObject();
    j.key("narrowed_pixels").value(f.prior.narrowed_pixels);
    j.key("full_range_pixels").value(f.prior.full_range_pixels);
    j.key("fallback_pixels").value(f.prior.fallback_pixels);
    j.key("refresh_pixels").value(f.prior.refresh_pixels);
    j.key("deferred_pixels").value(f.prior.deferred_pixels);
    j.key("edge_zone_pixels").value(f.prior.edge_zone_pixels);
    j.key("highlight_pixels").value(f.prior.highlight_pixels);
    j.key("hits").value(f.prior.prior_hits);
    j.key("misses").value(f.prior.prior_misses);
    j.key("mean_narrowed_width_px").value(f.prior.mean_narrowed_width_px);
    j.endObject();
    j.key("rectification").beginObject();
    j.key("method").value(f.quality.method);
    j.key("measured").value(f.quality.valid);
    if (f.quality.valid) {
      j.key("median_offset_px").value(f.quality.median_offset_px);
      j.key("p90_offset_px").value(f.quality.p90_offset_px);
      j.key("num_matches").value(f.quality.num_matches);
      j.key("measured_on_frame").value(f.quality.frame_index);
      if (f.quality.row_offset_matches > 0) {
        // the fitted offset plane c0 + c1 x + c2 y (px) and its matches (rectify.row_correction)
        j.key("row_offset_px").beginArray();
        for (int i = 0; i < 3; ++i) j.value(f.quality.row_offset[i]);
        j.endArray();
        j.key("row_offset_matches").value(f.quality.row_offset_matches);
      }
      j.key("warning").value(f.quality.warning);
    }
    if (f.quality.misaligned) j.key("misaligned").value(true);
    if (!f.quality.message.empty()) j.key("message").value(f.quality.message);
    j.endObject();
    j.endObject();
  }
  j.endArray();

  j.key("params").beginObject();
  for (const endo_stereo::ParamInfo& info : endo_stereo::listPipelineParams(p)) {
    j.key(info.key).value(info.value);
  }
  j.endObject();
  j.endObject();
  return j.str();
}

// --- main ------------------------------------------------------------------------------------

int run(int argc, char** argv) {
  Options o;
  try {
    o = parseArgs(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << "endo_stereo_cli: " << e.message << "\n";
    return kExitUsage;
  }

  // Parameters: defaults (input already rectified), then the file, the overrides, the flags.
  endo_stereo::PipelineParams params;
  params.rectify.mode = endo_stereo::RectifyMode::kPassThrough;
  params.output.point_cloud = false;
  std::string err =
      endo_stereo::tools::applyPresetAndOverrides(o.params_file, o.overrides, params);
  if (!err.empty()) {
    std::cerr << "endo_stereo_cli: " << err << "\n";
    return kExitUsage;
  }
  if (o.has_min) params.matcher.min_disparity = o.min_disparity;
  if (o.has_max) params.matcher.max_disparity = o.max_disparity;
  if (params.matcher.min_disparity > params.matcher.max_disparity) {
    std::cerr << "endo_stereo_cli: bad disparity range: min " << params.matcher.min_disparity
              << " > max " << params.matcher.max_disparity << "\n";
    return kExitUsage;
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
  if (o.list_params) {
    for (const endo_stereo::ParamInfo& info : endo_stereo::listPipelineParams(params)) {
      std::cout << info.key << " = " << info.value << "  ("
                << endo_stereo::paramTypeName(info.type);
      if (!info.choices.empty()) {
        std::cout << ":";
        for (const auto& c : info.choices) std::cout << " " << c;
      }
      std::cout << ")\n";
    }
    return kExitOk;
  }
  err = params.validate();
  if (!err.empty()) {
    std::cerr << "endo_stereo_cli: bad parameters: " << err << "\n";
    return kExitUsage;
  }
  if (params.rectify.mode == endo_stereo::RectifyMode::kCalibrated && o.calib.empty()) {
    std::cerr << "endo_stereo_cli: rectify.mode is 'calibrated' but no --calib was given\n";
    return kExitUsage;
  }
  if (o.has_threads && o.threads > 0) cv::setNumThreads(o.threads);

  // Frames.
  const bool sequence = isPattern(o.left) || isPattern(o.right);
  if (sequence) {
    if (!isPattern(o.left) || !isPattern(o.right) || !validPattern(o.left) ||
        !validPattern(o.right)) {
      std::cerr << "endo_stereo_cli: a sequence needs --left and --right patterns with one "
                   "integer conversion each, e.g. left_%04d.png\n";
      return kExitUsage;
    }
    for (const std::string* out : {&o.out_disparity, &o.out_color, &o.out_cloud, &o.out_fused}) {
      if (!out->empty() && !(isPattern(*out) && validPattern(*out))) {
        std::cerr << "endo_stereo_cli: in sequence mode '" << *out
                  << "' must be a printf pattern with one integer conversion, e.g. disp_%04d.pfm\n";
        return kExitUsage;
      }
    }
  } else {
    if (o.has_first || o.count > 0) {
      std::cerr << "endo_stereo_cli: --first/--count need --left/--right patterns\n";
      return kExitUsage;
    }
    for (const std::string* out : {&o.out_disparity, &o.out_color, &o.out_cloud, &o.out_fused}) {
      if (!out->empty() && isPattern(*out) && !validPattern(*out)) {
        std::cerr << "endo_stereo_cli: bad output name '" << *out << "'\n";
        return kExitUsage;
      }
    }
  }
  int first = o.first;
  if (sequence && !o.has_first && !fileExists(formatPattern(o.left, 0)) &&
      fileExists(formatPattern(o.left, 1))) {
    first = 1;
  }

  std::unique_ptr<endo_stereo::Pipeline> pipeline;
  try {
    pipeline = std::make_unique<endo_stereo::Pipeline>(params);
  } catch (const std::exception& ex) {
    std::cerr << "endo_stereo_cli: bad parameters: " << ex.what() << "\n";
    return kExitUsage;
  }
  if (!o.calib.empty()) {
    endo_stereo::StereoCalibration calibration;
    if (!endo_stereo::loadStereoCalibration(o.calib, calibration, &err)) {
      std::cerr << "endo_stereo_cli: --calib: " << err << "\n";
      return kExitInput;
    }
    err = pipeline->setCalibration(calibration);
    if (!err.empty()) {
      std::cerr << "endo_stereo_cli: --calib: " << err << "\n";
      return kExitInput;
    }
  }

  std::vector<FrameRecord> records;
  endo_stereo::PipelineOutput out;
  int failed = 0;
  bool warned_cloud = false;
  const int count = sequence ? o.count : 1;  // -1: a sequence runs until its first missing frame
  for (int n = 0; count < 0 || n < count; ++n) {
    const int index = first + n;
    const std::string left_path = sequence ? formatPattern(o.left, index) : o.left;
    const std::string right_path = sequence ? formatPattern(o.right, index) : o.right;
    if (sequence && count < 0 && !fileExists(left_path)) {
      if (n == 0) {
        std::cerr << "endo_stereo_cli: no frame found: '" << left_path << "' does not exist\n";
        return kExitInput;
      }
      break;  // the end of the sequence
    }
    endo_stereo::StereoInput input;
    if (!readImage(left_path, input.left, input.left_encoding, &err) ||
        !readImage(right_path, input.right, input.right_encoding, &err)) {
      std::cerr << "endo_stereo_cli: " << err << "\n";
      return kExitInput;
    }
    if (input.left.size() != input.right.size()) {
      std::cerr << "endo_stereo_cli: size mismatch: '" << left_path << "' is " << input.left.cols
                << "x" << input.left.rows << ", '" << right_path << "' is " << input.right.cols
                << "x" << input.right.rows << "\n";
      return kExitInput;
    }
    input.stamp_s = sequence ? index / o.fps : 0.0;
    if (!pipeline->process(input, out, &err)) {
      std::cerr << "endo_stereo_cli: frame " << index << " (" << left_path << "): " << err << "\n";
      ++failed;
      if (!sequence) return kExitInput;
      continue;
    }
    FrameRecord r;
    r.index = index;
    r.stamp_s = input.stamp_s;
    r.left = left_path;
    r.right = right_path;
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
    records.push_back(r);
    if (out.rect_quality.valid && out.rect_quality.warning &&
        out.rect_quality.frame_index == out.frame_index) {
      std::cerr << "endo_stereo_cli: warning: frame " << index
                << ": rectification leaves a median vertical offset of "
                << out.rect_quality.median_offset_px << " px (90th percentile "
                << out.rect_quality.p90_offset_px << " px): check the calibration\n";
    } else if (out.rect_quality.misaligned && out.rect_quality.frame_index == out.frame_index) {
      std::cerr << "endo_stereo_cli: warning: frame " << index << ": "
                << out.rect_quality.message << ": check the calibration\n";
    }

    // Outputs of this frame.
    auto name = [&](const std::string& path) {
      return sequence ? formatPattern(path, index) : path;
    };
    if (!o.out_disparity.empty() &&
        !endo_stereo::writePfm(name(o.out_disparity), out.match.disparity, &err)) {
      std::cerr << "endo_stereo_cli: " << err << "\n";
      return kExitInput;
    }
    const double d_lo = params.matcher.min_disparity, d_hi = params.matcher.max_disparity;
    if (!o.out_color.empty() &&
        !writeImage(name(o.out_color),
                    endo_stereo::colorizeDisparity(out.match.disparity, d_lo, d_hi), &err)) {
      std::cerr << "endo_stereo_cli: " << err << "\n";
      return kExitInput;
    }
    if (!o.out_fused.empty()) {
      const std::string path = name(o.out_fused);
      const bool ok =
          lowerExtension(path) == "pfm"
              ? endo_stereo::writePfm(path, out.fused_disparity, &err)
              : writeImage(path, endo_stereo::colorizeDisparity(out.fused_disparity, d_lo, d_hi),
                           &err);
      if (!ok) {
        std::cerr << "endo_stereo_cli: " << err << "\n";
        return kExitInput;
      }
    }
    if (!o.out_rectified.empty()) {
      if (!writeImage(withSuffix(o.out_rectified, "left", sequence, index), out.left_rect_gray,
                      &err) ||
          !writeImage(withSuffix(o.out_rectified, "right", sequence, index), out.right_rect_gray,
                      &err)) {
        std::cerr << "endo_stereo_cli: " << err << "\n";
        return kExitInput;
      }
    }
    if (!o.out_cloud.empty()) {
      if (!warned_cloud && (out.geometry.polar || !out.cloud.metric)) {
        std::cerr << "endo_stereo_cli: note: "
                  << (out.geometry.polar
                          ? "polar rectification has no depth from disparity: the cloud is empty"
                          : "no metric geometry (give --calib, or --focal and --baseline): the "
                            "cloud is in units of the baseline")
                  << "\n";
        warned_cloud = true;
      }
      if (!endo_stereo::writePly(name(o.out_cloud), out.cloud, !o.ply_ascii, &err)) {
        std::cerr << "endo_stereo_cli: " << err << "\n";
        return kExitInput;
      }
    }
    if (!o.quiet) {
      std::fprintf(stderr, "frame %d: %dx%d density %.1f%% %.1f ms%s%s\n", index, r.size.width,
                   r.size.height, 100.0 * r.match.density(), r.total_ms,
                   r.priors_used       ? " (priors)"
                   : r.priors_rejected ? " (priors rejected: scene change, full range)"
                                       : "",
                   r.priors_reset ? (" reset: " + r.reset_reason).c_str() : "");
    }
  }

  if (!o.out_coverage.empty()) {
    const cv::Mat picture = pipeline->temporal().coverage().colorImage();
    if (picture.empty()) {
      std::cerr << "endo_stereo_cli: no coverage to write (no frame was processed)\n";
      return kExitInput;
    }
    if (!writeImage(o.out_coverage, picture, &err)) {
      std::cerr << "endo_stereo_cli: " << err << "\n";
      return kExitInput;
    }
  }
  if (!o.stats.empty()) {
    std::ofstream f(o.stats);
    f << statsJson(records, params, sequence, failed, *pipeline, params.output.coverage);
    if (!f) {
      std::cerr << "endo_stereo_cli: cannot write '" << o.stats << "'\n";
      return kExitInput;
    }
  }
  if (!o.quiet && !records.empty()) {
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
  return failed ? kExitInput : kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& ex) {
    std::cerr << "endo_stereo_cli: unexpected error: " << ex.what() << "\n";
    return kExitInput;
  }
}
