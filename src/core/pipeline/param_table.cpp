// The one table of pipeline parameters: key, type, range, meaning and origin of every field of
// the params structs, and how each is read and written as text. Loading, overriding, listing
// (`endo_stereo_cli --list-params`), writing YAML and the README's parameter table all go through
// it, so they cannot disagree; test_params_io checks the presets, the struct defaults, the ranges
// (against each struct's validate()) and the README against it. Adding a field to a params struct
// means adding one entry here. The method behind each parameter: docs/method.md.
#include "param_table.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <limits>
#include <utility>

namespace endo_stereo {
namespace detail {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}


// --- text <-> value, one overload per supported field type -------------------------------------

std::string toText(bool v) { return v ? "true" : "false"; }
std::string toText(int v) { return std::to_string(v); }
std::string toText(double v) {
  // Shortest text that reads back to the same double.
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof(buf), v);
  std::string s(buf, res.ptr);
  // Keep a decimal point so a YAML reader sees a float, not an int.
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}
[[maybe_unused]] std::string toText(const std::string& v) { return v; }

std::string fromText(const std::string& text, bool& out) {
  const std::string t = lower(trimText(text));
  if (t == "true" || t == "yes" || t == "on" || t == "1") {
    out = true;
    return {};
  }
  if (t == "false" || t == "no" || t == "off" || t == "0") {
    out = false;
    return {};
  }
  return "expected a boolean (true/false), got '" + text + "'";
}

std::string fromText(const std::string& text, int& out) {
  std::string t = trimText(text);
  if (!t.empty() && t[0] == '+') t.erase(0, 1);
  int v = 0;
  const auto res = std::from_chars(t.data(), t.data() + t.size(), v);
  if (t.empty() || res.ec != std::errc() || res.ptr != t.data() + t.size()) {
    return "expected an integer, got '" + text + "'";
  }
  out = v;
  return {};
}

std::string fromText(const std::string& text, double& out) {
  std::string t = trimText(text);
  if (!t.empty() && t[0] == '+') t.erase(0, 1);
  double v = 0.0;
  const auto res = std::from_chars(t.data(), t.data() + t.size(), v);
  if (t.empty() || res.ec != std::errc() || res.ptr != t.data() + t.size()) {
    return "expected a number, got '" + text + "'";
  }
  if (!std::isfinite(v)) return "expected a finite number, got '" + text + "'";
  out = v;
  return {};
}

[[maybe_unused]] std::string fromText(const std::string& text, std::string& out) {
  out = text;
  return {};
}

template <typename T>
constexpr ParamType typeOf() {
  if constexpr (std::is_same_v<T, bool>) return ParamType::kBool;
  if constexpr (std::is_same_v<T, int>) return ParamType::kInt;
  if constexpr (std::is_same_v<T, double>) return ParamType::kDouble;
  return ParamType::kString;
}

// --- ranges -------------------------------------------------------------------------------------

std::string number(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[32];
  const auto res = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, res.ptr);
}

ParamBounds interval(double lo, double hi, bool lo_open, bool hi_open) {
  ParamBounds b;
  b.lo = lo;
  b.hi = hi;
  b.lo_open = lo_open;
  b.hi_open = hi_open;
  b.exact = true;
  return b;
}
ParamBounds in(double lo, double hi) { return interval(lo, hi, false, false); }  // [lo, hi]
ParamBounds atLeast(double lo) { return interval(lo, kInf, false, false); }      // >= lo
ParamBounds above(double lo) { return interval(lo, kInf, true, false); }         // > lo
ParamBounds aboveUpTo(double lo, double hi) { return interval(lo, hi, true, false); }  // (lo, hi]
ParamBounds strictlyIn(double lo, double hi) { return interval(lo, hi, true, true); }  // (lo, hi)
// Not a plain interval (the range text says what is accepted): outer limits only.
ParamBounds rule(double lo = -kInf, double hi = kInf) {
  ParamBounds b = interval(lo, hi, false, false);
  b.exact = false;
  return b;
}
const ParamBounds kNoBounds = rule();

std::string rangeText(const ParamBounds& b) {
  if (std::isinf(b.hi)) return (b.lo_open ? "> " : ">= ") + number(b.lo);
  return std::string(b.lo_open ? "(" : "[") + number(b.lo) + ", " + number(b.hi) +
         (b.hi_open ? ")" : "]");
}

// What a table row says about one parameter besides its key.
struct Doc {
  ParamOrigin origin;
  ParamBounds bounds;
  const char* meaning;
  const char* range = nullptr;  // when the bounds alone do not say it
};

ParamEntry describe(const char* section, const char* name, ParamType type, const Doc& doc) {
  ParamEntry e;
  e.section = section;
  e.field = name;
  e.type = type;
  e.origin = doc.origin;
  e.bounds = doc.bounds;
  e.meaning = doc.meaning;
  if (doc.range) {
    e.range = doc.range;
  } else if (doc.bounds.exact) {
    e.range = rangeText(doc.bounds);
  }
  return e;
}

// A plain field: bool, int, double or std::string.
template <typename Component, typename T>
ParamEntry field(const char* section, const char* name, Component PipelineParams::*component,
                 T Component::*member, const Doc& doc) {
  ParamEntry e = describe(section, name, typeOf<T>(), doc);
  e.get = [component, member](const PipelineParams& p) { return toText(p.*component.*member); };
  e.set = [component, member](PipelineParams& p, const std::string& text) {
    T value{};
    std::string err = fromText(text, value);
    if (err.empty()) p.*component.*member = value;
    return err;
  };
  return e;
}

// An enumeration, written as one of its names.
template <typename Component, typename E>
ParamEntry enumField(const char* section, const char* name, Component PipelineParams::*component,
                     E Component::*member, std::vector<std::pair<std::string, E>> names,
                     ParamOrigin origin, const char* meaning) {
  ParamEntry e = describe(section, name, ParamType::kString, Doc{origin, kNoBounds, meaning});
  for (const auto& n : names) e.choices.push_back(n.first);
  for (const auto& c : e.choices) e.range += (e.range.empty() ? "" : ", ") + c;
  e.get = [component, member, names](const PipelineParams& p) {
    for (const auto& n : names)
      if (n.second == p.*component.*member) return n.first;
    return std::string("?");
  };
  e.set = [component, member, names](PipelineParams& p, const std::string& text) {
    const std::string t = lower(trimText(text));
    for (const auto& n : names) {
      if (n.first == t) {
        p.*component.*member = n.second;
        return std::string();
      }
    }
    std::string msg = "expected one of";
    for (const auto& n : names) msg += " '" + n.first + "'";
    return msg + ", got '" + text + "'";
  };
  return e;
}

constexpr ParamOrigin kPaper = ParamOrigin::kPaper;
constexpr ParamOrigin kOurs = ParamOrigin::kOurs;
constexpr ParamOrigin kSetting = ParamOrigin::kSetting;
using PP = PipelineParams;

// --- matcher: the paper's robust NCC matcher (docs/method.md section 2) and our additions -------
void addMatcher(std::vector<ParamEntry>& t) {
  using M = MatcherParams;
  auto add = [&](const char* name, auto M::*member, const Doc& doc) {
    t.push_back(field("matcher", name, &PP::matcher, member, doc));
  };
  add("min_disparity", &M::min_disparity,
      {kSetting, rule(-16383, 16383), "smallest disparity searched, px (x_left - x_right)",
       "[-16383, 16383], <= max_disparity, at most 4096 disparities"});
  add("max_disparity", &M::max_disparity,
      {kSetting, rule(-16383, 16383), "largest disparity searched, px, inclusive",
       ">= min_disparity"});
  add("window_min_px", &M::window_min_px,
      {kPaper, rule(3, 31), "first (smallest) NCC window width w_min, px (paper: 7)",
       "odd, [3, 31], <= window_max_px"});
  add("window_step_px", &M::window_step_px,
      {kPaper, rule(2), "window growth step, px: windows w_min, w_min + step, ... (paper: 4)",
       "even, >= 2"});
  add("window_max_px", &M::window_max_px,
      {kPaper, rule(3, 32), "largest window width w_max, px",
       "[window_min_px, 32], at most 16 sizes"});
  add("gamma_min", &M::gamma_min,
      {kPaper, atLeast(0), "structure criterion: least stdev of the 3x3 Laplacian in the window "
                           "(grey levels 0..255; paper: 0.5)"});
  add("delta_min", &M::delta_min,
      {kPaper, in(0, 2), "discrimination criterion: least NCC gap between the best and the second "
                         "peak; the main knob between density and error"});
  add("epsilon_px", &M::epsilon_px,
      {kPaper, above(0), "left-right consistency tolerance on the integer peaks, px (paper: 5)"});
  add("min_ncc", &M::min_ncc,
      {kOurs, in(-1, 1), "least NCC of an accepted peak (-1 = off)"});
  add("min_ncc_narrowed", &M::min_ncc_narrowed,
      {kOurs, in(-1, 1), "the same for a pixel searched in a range narrowed by its priors"});
  add("subpixel", &M::subpixel,
      {kOurs, kNoBounds, "parabola sub-pixel refinement of accepted disparities"});
  add("num_threads", &M::num_threads,
      {kSetting, in(0, M::kMaxNumThreads),
       "worker threads (0 = OpenCV's default); the output does not depend on it"});
  add("edge_disparity_jump_px", &M::edge_disparity_jump_px,
      {kOurs, atLeast(0), "depth-edge filter: reject a pixel whose window holds accepted "
                          "disparities more than this below its own, px (0 = filter off)"});
  add("edge_disparity_jump_above_px", &M::edge_disparity_jump_above_px,
      {kOurs, atLeast(0), "the same above the pixel's own, px (0 = edge_disparity_jump_px)"});
  add("edge_margin_px", &M::edge_margin_px,
      {kOurs, in(0, 16), "how far beyond its window a pixel's edge test looks, px"});
  add("edge_verify_radius_px", &M::edge_verify_radius_px,
      {kOurs, in(0, 6), "second chance: a flagged pixel is kept when every (2r+1)^2 window holding "
                        "it prefers its disparity to the other side's (0 = off)"});
  add("edge_verify_min_ncc", &M::edge_verify_min_ncc,
      {kOurs, in(-1, 1), "second chance: least ZNCC of the pixel's own disparity in each window"});
  add("edge_support_share", &M::edge_support_share,
      {kOurs, in(0, 1), "the edge test ignores disparities that fewer than this share of their "
                        "neighbours agree with (0 = all count)"});
  add("edge_support_radius_px", &M::edge_support_radius_px,
      {kOurs, in(1, 8), "radius of that neighbourhood, px"});
  add("edge_slope_tolerant", &M::edge_slope_tolerant,
      {kOurs, kNoBounds, "the edge test compares each neighbour with its mirror image, so a steep "
                         "smooth surface is no depth edge"});
}

// --- filter: the paper's post-processing (docs/method.md section 3) -------------------------------
void addFilter(std::vector<ParamEntry>& t) {
  using F = PostFilterParams;
  auto add = [&](const char* name, auto F::*member, const Doc& doc) {
    t.push_back(field("filter", name, &PP::filter, member, doc));
  };
  add("remove_outliers", &F::remove_outliers,
      {kPaper, kNoBounds, "remove isolated outliers"});
  add("outlier_window_px", &F::outlier_window_px,
      {kPaper, rule(3, 31), "outlier test neighbourhood width (paper: Delta w = 5), px",
       "odd, [3, 31]"});
  add("outlier_disparity_tol_px", &F::outlier_disparity_tol_px,
      {kPaper, above(0), "neighbours agree within this (paper: Delta d = 4), px"});
  add("outlier_min_share", &F::outlier_min_share,
      {kPaper, in(0, 1), "a pixel is removed when fewer than this share of its neighbourhood "
                         "agrees (paper: mu = 0.4)"});
  add("fill_holes", &F::fill_holes, {kPaper, kNoBounds, "fill small holes"});
  add("fill_max_hole_px", &F::fill_max_hole_px,
      {kPaper, in(1, 2), "widest hole filled, px, with the median of the valid neighbours"});
}

// --- preprocess (docs/method.md section 1) ------------------------------------------------------
void addPreprocess(std::vector<ParamEntry>& t) {
  using P = PreprocessParams;
  t.push_back(field("preprocess", "downsample", &PP::preprocess, &P::downsample,
                    {kSetting, rule(1, 4), "downsample the input by this factor (intrinsics "
                                           "scale with it)", "1, 2 or 4"}));
  t.push_back(enumField("preprocess", "interlace", &PP::preprocess, &P::interlace,
                        {{"none", InterlaceMode::kNone},
                         {"downsample", InterlaceMode::kDownsample},
                         {"field", InterlaceMode::kField}},
                        kPaper, "interlaced input: downsample 2x2 (the paper: 1080i to 960x540) "
                                "or keep one field"));
  t.push_back(field("preprocess", "field_parity", &PP::preprocess, &P::field_parity,
                    {kSetting, in(0, 1), "field kept in field mode: 0 = even rows, 1 = odd rows"}));
  t.push_back(field("preprocess", "mono16_bits", &PP::preprocess, &P::mono16_bits,
                    {kSetting, in(8, 16), "significant bits of mono16 input"}));
}

// --- rectify (docs/method.md section 1) -----------------------------------------------------------
void addRectify(std::vector<ParamEntry>& t) {
  using R = RectifyParams;
  auto add = [&](const char* name, auto R::*member, const Doc& doc) {
    t.push_back(field("rectify", name, &PP::rectify, member, doc));
  };
  t.push_back(enumField("rectify", "mode", &PP::rectify, &R::mode,
                        {{"calibrated", RectifyMode::kCalibrated},
                         {"uncalibrated", RectifyMode::kUncalibrated},
                         {"pass_through", RectifyMode::kPassThrough}},
                        kSetting, "how the input is rectified: from a calibration, from the "
                                  "images (the paper's way), or taken as rectified"));
  add("alpha", &R::alpha,
      {kSetting, rule(-1, 1), "calibrated: cv::stereoRectify free scaling (0 = valid pixels "
                              "only, 1 = all source pixels)", "-1 or [0, 1]"});
  add("zero_disparity", &R::zero_disparity,
      {kSetting, kNoBounds, "calibrated: equal principal points (doffs = 0)"});
  add("output_width_px", &R::output_width_px,
      {kSetting, in(0, 32768), "rectified width, px (0 = input width x output_scale_x)"});
  add("output_height_px", &R::output_height_px,
      {kSetting, in(0, 32768), "rectified height, px (0 = input height x output_scale_y)"});
  add("output_scale_x", &R::output_scale_x,
      {kSetting, aboveUpTo(0, 4), "rectified width over input width"});
  add("output_scale_y", &R::output_scale_y,
      {kSetting, aboveUpTo(0, 4), "rectified height over input height (2 for one field of "
                                  "interlaced video)"});
  add("fixed_point_maps", &R::fixed_point_maps,
      {kSetting, kNoBounds, "CV_16SC2 remap tables: about twice as fast, 1/32 px steps"});
  t.push_back(enumField("rectify", "method", &PP::rectify, &R::method,
                        {{"auto", UncalibratedMethod::kAuto},
                         {"homography", UncalibratedMethod::kHomography},
                         {"polar", UncalibratedMethod::kPolar}},
                        kPaper, "uncalibrated: rectifying homographies or polar rectification "
                                "(auto: polar when an epipole is near)"));
  add("sift_features", &R::sift_features,
      {kPaper, atLeast(0), "uncalibrated: most SIFT features per image (0 = unlimited)"});
  add("ratio_test", &R::ratio_test,
      {kPaper, strictlyIn(0, 1), "uncalibrated: Lowe's ratio test on descriptor distances"});
  add("ransac_threshold_px", &R::ransac_threshold_px,
      {kPaper, above(0), "uncalibrated: RANSAC inlier threshold for F, px"});
  add("ransac_confidence", &R::ransac_confidence,
      {kPaper, strictlyIn(0, 1), "uncalibrated: RANSAC confidence"});
  add("min_inliers", &R::min_inliers,
      {kPaper, atLeast(8), "uncalibrated: least inliers to accept an estimate"});
  add("estimation_frames", &R::estimation_frames,
      {kOurs, atLeast(1), "uncalibrated: frames whose matches are pooled, then the estimate is "
                          "kept"});
  add("reestimate_threshold_px", &R::reestimate_threshold_px,
      {kOurs, atLeast(0), "uncalibrated: re-estimate when the measured row offset exceeds "
                          "this, px (0 = never)"});
  add("reestimate_after", &R::reestimate_after,
      {kOurs, atLeast(1), "uncalibrated: ... in this many measurements in a row"});
  add("polar_auto_distance", &R::polar_auto_distance,
      {kOurs, above(0), "uncalibrated, auto: polar when an epipole is closer than this many "
                        "image diagonals"});
  add("focal_px", &R::focal_px,
      {kSetting, atLeast(0), "uncalibrated / pass-through: focal length, px (0 = unknown: "
                             "disparity only)"});
  add("baseline_m", &R::baseline_m,
      {kSetting, atLeast(0), "uncalibrated / pass-through: baseline, m (metric depth needs "
                             "focal_px and baseline_m)"});
  add("quality_stride", &R::quality_stride,
      {kOurs, atLeast(0), "measure the rows' vertical offset every this many frames (0 = never)"});
  add("quality_warn_px", &R::quality_warn_px,
      {kOurs, above(0), "warn when the median vertical offset exceeds this, px"});
  add("quality_max_features", &R::quality_max_features,
      {kOurs, atLeast(0), "most patches of that measure (0 = one per 16x16 px)"});
  add("row_correction", &R::row_correction,
      {kOurs, kNoBounds, "calibrated / pass-through: shift the right view's rows by the measured "
                         "offset (a plane over the image)"});
  add("row_correction_min_matches", &R::row_correction_min_matches,
      {kOurs, atLeast(3), "... fitted to at least this many patch matches"});
  add("row_correction_min_px", &R::row_correction_min_px,
      {kOurs, atLeast(0), "... and applied only when it reaches this at a corner, px"});
}

// --- temporal: the paper's priors (docs/method.md section 4) and our rules on top ------------------
void addTemporal(std::vector<ParamEntry>& t) {
  using T = TemporalParams;
  auto add = [&](const char* name, auto T::*member, const Doc& doc) {
    t.push_back(field("temporal", name, &PP::temporal, member, doc));
  };
  add("enabled", &T::enabled,
      {kPaper, kNoBounds, "search ranges narrowed around the previous frames' disparities"});
  add("prior_radius_px", &T::prior_radius_px,
      {kPaper, in(1, 64), "half-width of a narrowed range around a prior, px"});
  add("prior_neighbourhood_px", &T::prior_neighbourhood_px,
      {kOurs, in(0, 16), "a pixel's range spans the priors within this many px (image motion)"});
  add("prior_edge_zone_px", &T::prior_edge_zone_px,
      {kOurs, in(0, 64), "near a depth edge in the priors (this many px) the range spans both "
                         "sides (0 = off)"});
  add("max_prior_age_frames", &T::max_prior_age_frames,
      {kPaper, in(1, 1000), "a disparity measured up to this many frames ago is a prior; a "
                            "failed narrowed search does not refresh it (paper: 1)"});
  add("full_range_period_frames", &T::full_range_period_frames,
      {kOurs, in(1, 1000), "pixels without a prior search the full range one frame in this many "
                           "(row stripes take turns; paper: 1)"});
  add("min_prior_hit_share", &T::min_prior_hit_share,
      {kOurs, in(0, 1), "scene change: drop all priors when the share of narrowed searches that "
                        "hit falls below this x the previous frame's (0 = off)"});
  add("max_gap_s", &T::max_gap_s,
      {kOurs, above(0), "forget the temporal state after a longer gap in the stamps (or when "
                        "time goes back), s"});
  add("fused_max_age_frames", &T::fused_max_age_frames,
      {kOurs, in(0, 65534), "fused output: values up to this many frames old"});
  add("coverage_within_frames", &T::coverage_within_frames,
      {kSetting, in(1, 65534), "coverage figures: a pixel counts as covered when updated at least "
                               "once in every this many frames"});
}

// --- output ---------------------------------------------------------------------------------------
void addOutput(std::vector<ParamEntry>& t) {
  using O = OutputParams;
  t.push_back(field("output", "point_cloud", &PP::output, &O::point_cloud,
                    {kSetting, kNoBounds, "organized XYZRGB point cloud"}));
  t.push_back(field("output", "fused", &PP::output, &O::fused,
                    {kSetting, kNoBounds, "temporally fused disparity and its age"}));
  t.push_back(field("output", "coverage", &PP::output, &O::coverage,
                    {kSetting, kNoBounds, "per-pixel longest run of frames without an update"}));
}

}  // namespace

std::string trimText(const std::string& s) {
  size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return s.substr(b, e - b);
}

const std::vector<ParamEntry>& paramTable() {
  static const std::vector<ParamEntry> entries = [] {
    std::vector<ParamEntry> t;
    addMatcher(t);
    addFilter(t);
    addPreprocess(t);
    addRectify(t);
    addTemporal(t);
    addOutput(t);
    return t;
  }();
  return entries;
}

const ParamEntry* findParamEntry(const std::string& key) {
  for (const ParamEntry& e : paramTable()) {
    if (key == e.section + "." + e.field) return &e;
  }
  return nullptr;
}

}  // namespace detail
}  // namespace endo_stereo
