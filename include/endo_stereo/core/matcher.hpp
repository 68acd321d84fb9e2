/**
 * @file matcher.hpp
 * @brief Robust dense stereo matcher of Bernhardt, Abi-Nahed and Abugharbieh (2012).
 *
 * ZNCC over the search range with an adaptive square window (w_min, w_min+dw, ... <= w_max) and
 * three confidence criteria: structure (stdev of the Laplacian, gamma), discrimination (gap between
 * the two highest NCC peaks, delta) and left-right consistency (epsilon). Sub-pixel refinement by a
 * parabola through the best peak (ours). Post-processing (isolated-outlier removal, 1-2 px hole
 * filling) is configured by PostFilterParams (post_filter.hpp) and run by the matcher after
 * matching. The method, step by step, with the function implementing each: docs/method.md.
 *
 * Ours, in the default preset (the paper preset, config/paper.yaml, switches them off): a test
 * against fattening at depth edges (a pixel whose accepting window straddles a disparity jump is
 * flagged, edge_*; it is kept only when every small window holding it confirms its disparity
 * against the neighbours' disparities, edge_verify_*, else rejected), a least NCC for the best
 * peak (min_ncc, stronger for narrowed per-pixel ranges), epsilon 1.5 px. Measurements:
 * docs/matcher_design.md / BENCHMARKS.md.
 *
 * A pixel searches the disparities of its range for which both windows lie inside the images (the
 * range is cut at the borders); pixels whose window leaves the image are not searched.
 *
 * Use:
 * @code
 *   endo_stereo::MatcherParams mp;            // defaults = the trustworthy preset
 *   mp.min_disparity = 0; mp.max_disparity = 63;
 *   endo_stereo::RobustMatcher matcher(mp, endo_stereo::PostFilterParams{});
 *   endo_stereo::MatchResult result;
 *   matcher.compute(left_gray, right_gray, result);          // full search
 *   matcher.compute(left_gray, right_gray, result, &range);  // per-pixel search range
 * @endcode
 *
 * ROS-free: depends on OpenCV only.
 */
#pragma once

#include <array>
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>

#include "endo_stereo/core/post_filter.hpp"

namespace endo_stereo {

/// Parameters of the matching stage. Defaults are the shipped "default" (trustworthy) preset.
struct MatcherParams {
  /// Smallest disparity searched, px (disparity = x_left - x_right). Any integer.
  int min_disparity = 0;
  /// Largest disparity searched, px, inclusive; must be >= min_disparity.
  int max_disparity = 63;
  /// Smallest window width, px; odd, >= 3. Default 9 (paper: 7): on real in-vivo video a 7 px
  /// window on smooth tissue gives a noisy peak that the depth-edge filter then rejects
  /// (docs/method.md, section 5, has the figures; Middlebury is measured with it too).
  int window_min_px = 9;
  /// Window growth step, px; even, >= 2 (keeps widths odd). Default 6 (paper: 4): windows 9, 15,
  /// 21, 27 reach as far as 9, 13, ..., 29 with four sizes instead of six (docs/method.md,
  /// section 5).
  int window_step_px = 6;
  /// Largest window width allowed, px, in [window_min_px, 32] (up to 32 x 32 the window sums are
  /// exact in float). Widths tried: min, min+step, ... <= max (at most 16 of them).
  int window_max_px = 30;
  /// Structure threshold: stdev of the 3x3 Laplacian over the window, intensities 0..255. >= 0.
  /// Default 2.0 (paper: 0.5), chosen on surgical video (docs/decisions/structure-threshold.md).
  double gamma_min = 2.0;
  /// Least NCC gap between the best and the second-highest peak, [0, 2].
  double delta_min = 0.1;
  /// Left-right consistency tolerance |d_LR + d_RL| < epsilon, px, > 0. Compared on the integer
  /// peaks: 1 means "the same disparity", 1.5 "within one disparity" (paper: 5).
  double epsilon_px = 1.5;
  /// Least NCC of the best peak, [-1, 1] (ours; -1 = off). A weak best peak means the window
  /// found no real match, which matters most with a narrowed per-pixel range: there the true peak
  /// may lie outside the range, and a noise peak inside it has no competitor. Counted as a
  /// discrimination failure (kCodeRejectPeakGap).
  double min_ncc = 0.5;
  /// Least NCC of the best peak for a pixel whose per-pixel search range is narrower than
  /// [min_disparity, max_disparity] (ours; the larger of this and min_ncc applies). A narrowed
  /// range has lost the competitors outside it; when it misses the true disparity its profile
  /// holds only noise peaks. [-1, 1].
  double min_ncc_narrowed = 0.7;
  /// Refine accepted disparities with a parabola through the NCC peak.
  bool subpixel = true;
  /// Worker threads, 0..kMaxNumThreads; 0 = OpenCV's default. When > 0, cv::setNumThreads() is
  /// set to it for the duration of compute() and restored after (a process-wide OpenCV setting).
  /// The output does not depend on this value.
  int num_threads = 0;
  static constexpr int kMaxNumThreads = 256;
  // Ours, against window fattening at depth edges: see matcher.cpp and BENCHMARKS.md.
  /// Reject a pixel whose accepting window (widened by edge_margin_px) holds accepted disparities
  /// more than this below its own: its window straddles a depth edge and it may carry the nearer
  /// surface's disparity (foreground fattening). px, >= 0; 0 switches the whole test off.
  double edge_disparity_jump_px = 3.0;
  /// The same test for accepted disparities above the pixel's own (it may carry the farther
  /// surface's disparity into the nearer one's edge). px, >= 0; 0 = edge_disparity_jump_px.
  double edge_disparity_jump_above_px = 6.0;
  /// How far beyond its accepting window a pixel's edge test looks, px, in [0, 16]. 6 with the
  /// 9 px first window (docs/decisions/edge-thresholds-on-real-video.md).
  int edge_margin_px = 6;
  /// Second chance for pixels the edge test flags (ours; 0 = off: every flagged pixel is
  /// rejected). Competitors are the disparities measured on the other side of the jump (those of
  /// the neighbours that triggered the test, rounded, +-1 px). A flagged pixel is kept when EVERY
  /// square window of width 2 r + 1 that contains it ((2 r + 1)^2 windows, all inside the images)
  /// gives its own disparity (the better of the integers around it) a ZNCC of at least
  /// edge_verify_min_ncc and a higher ZNCC than each competitor. Some of those windows lie wholly
  /// on the pixel's own side of the depth edge: there a fattened pixel (the farther surface
  /// carrying the nearer one's disparity) loses to its true disparity, while a true foreground
  /// pixel next to the edge keeps winning. Radius r in px, [0, 6].
  int edge_verify_radius_px = 4;
  /// Least ZNCC of the pixel's own disparity in each verifying window, [-1, 1].
  double edge_verify_min_ncc = 0.5;
  /// Which disparities the edge test looks at (ours; 0 = all accepted ones): only those with the
  /// support of a surface, i.e. at least this share of the (2 edge_support_radius_px + 1)^2
  /// pixels around them accepted within edge_disparity_jump_px of them (the pixel itself not
  /// counted, the share of the full square also at the border, as the outlier filter counts).
  /// One isolated wrong disparity is no depth edge and does not reject the good pixels around
  /// it (it meets the outlier filter later). Share in [0, 1].
  double edge_support_share = 0.4;
  /// Radius of the support square, px, in [1, 8].
  int edge_support_radius_px = 2;
  /// Slope-tolerant edge test (ours): a flagged pixel is judged again with the surface's slope
  /// taken out (each neighbour q against its mirror image 2 p - q: the second difference
  /// d(q) + d(2p - q) - 2 d(p), zero on any plane, must exceed the thresholds), so that an
  /// oblique smooth surface is no depth edge; pixels it clears are kept without a second chance.
  bool edge_slope_tolerant = true;

  /// @return an empty string when valid, otherwise a message naming the bad field and its range.
  std::string validate() const;
};

/// Per-pixel outcome, stored in MatchResult::code (CV_8UC1).
enum PixelCode : uint8_t {
  kCodeNotSearched = 0,      ///< outside the matchable area (border, empty search range)
  kCodeRejectStructure = 1,  ///< last window tried failed the structure criterion (gamma)
  kCodeRejectPeakGap = 2,    ///< last window tried failed the discrimination criterion (delta)
  kCodeRejectLeftRight = 3,  ///< last window tried failed the left-right consistency (epsilon)
  kCodeRejectEdge = 4,       ///< rejected by our depth-edge (anti-fattening) measure
  kCodeRejectOutlier = 5,    ///< accepted, then removed as an isolated outlier
  kCodeNoPeak = 6,           ///< no local maximum inside the search range
  kCodeFilled = 7,           ///< a 1-2 px hole filled by the median of its neighbours
  kCodeAcceptedBase = 16,    ///< accepted at window index k: code = kCodeAcceptedBase + k,
                             ///< window width = window_min_px + k * window_step_px
};

/// Number of distinct rejection codes counted in MatchStats (codes 0..kCodeFilled).
constexpr int kNumRejectCodes = 8;

/// Counters of one compute() call.
struct MatchStats {
  /// Pixels per rejection / fill code (index = PixelCode value, 0..kCodeFilled).
  std::array<int64_t, kNumRejectCodes> rejected{};
  /// Pixels accepted per window index (0 = window_min_px). Up to 16 window sizes.
  std::array<int64_t, 16> accepted_per_window{};
  int64_t valid_pixels = 0;  ///< pixels with a finite disparity in the output (incl. filled)
  int64_t total_pixels = 0;  ///< width * height
  int64_t prior_pixels = 0;  ///< pixels searched with a narrowed (per-pixel) range
  double density() const {
    return total_pixels ? double(valid_pixels) / double(total_pixels) : 0.0;
  }
  double match_ms = 0.0;    ///< wall time of matching, ms (includes the two below)
  double prepare_ms = 0.0;  ///< of which: the views' float copies, integrals, Laplacians, ranges
  double edge_ms = 0.0;     ///< of which: the measure against fattening at depth edges
  double filter_ms = 0.0;   ///< wall time of post-processing, ms
};

/// Output of RobustMatcher::compute(). Buffers are reused between calls.
struct MatchResult {
  cv::Mat disparity;   ///< CV_32FC1, px, left view; NaN = invalid
  cv::Mat code;        ///< CV_8UC1, PixelCode per pixel
  cv::Mat confidence;  ///< CV_32FC1 in [0, 1]; 0 where invalid (the peak gap delta, clamped)
  MatchStats stats;
};

/// Per-pixel search range: disparities lo(y,x) .. hi(y,x) inclusive, both CV_16SC1 of the image
/// size. A pixel with lo > hi is not searched. Empty matrices = the params' full range.
struct SearchRange {
  cv::Mat lo;
  cv::Mat hi;
  bool empty() const { return lo.empty(); }
};

/**
 * The robust matcher. Not thread-safe: one instance per thread (it keeps scratch buffers between
 * frames and uses a worker pool internally). Output is identical for any num_threads.
 */
class RobustMatcher {
 public:
  /// @throws std::invalid_argument when params fail validate().
  RobustMatcher(const MatcherParams& matcher_params, const PostFilterParams& filter_params);
  ~RobustMatcher();
  RobustMatcher(const RobustMatcher&) = delete;
  RobustMatcher& operator=(const RobustMatcher&) = delete;

  /// Replace the parameters. @throws std::invalid_argument when invalid (old ones kept).
  void setParams(const MatcherParams& matcher_params, const PostFilterParams& filter_params);
  const MatcherParams& matcherParams() const { return matcher_params_; }
  const PostFilterParams& filterParams() const { return filter_params_; }

  /**
   * Match a rectified pair.
   * @param left  rectified left image, CV_8UC1 (gray 0..255), at least 1x1.
   * @param right rectified right image, same size and type.
   * @param out   disparity, codes, confidence and stats (reallocated only on size change).
   * @param range optional per-pixel search range (clamped to [min_disparity, max_disparity]).
   * @throws std::invalid_argument on empty input, type or size mismatch (message names it).
   */
  void compute(const cv::Mat& left, const cv::Mat& right, MatchResult& out,
               const SearchRange* range = nullptr);

 private:
  struct Impl;
  MatcherParams matcher_params_;
  PostFilterParams filter_params_;
  Impl* impl_;
};

}  // namespace endo_stereo
