/**
 * @file temporal.hpp
 * @brief Temporal smoothness over video (docs/method.md section 4): search-range priors from the
 * previous frames, temporal fusion of recent valid disparities, and coverage over time (the
 * paper's Fig. 6: per pixel the longest run of frames without an update).
 *
 * Bernhardt et al. (2012) use the disparities of one frame pair as priors for the next, so a pixel
 * with a recent valid disparity searches only a narrow range around it. Ours on top of the paper:
 * - the narrowed range of a pixel spans the priors of a small neighbourhood (image motion of a few
 *   pixels), and near a depth edge in the priors the span of both sides (a moving instrument);
 * - a narrowed range is searched with every window size, as the full range is (the window grows
 *   for a pixel that fails, docs/method.md section 5.3);
 * - a frame without usable priors (the first one, after a reset or a cut) searches the full range,
 *   so its output is exactly a full search's;
 * - a pixel without a prior searches the full range in one frame of full_range_period_frames (row
 *   stripes take turns), so no pixel goes longer than that without a search;
 * - a failed narrowed search does not refresh a prior, so a pixel whose narrowed search keeps
 *   failing is back to the full range once its prior is max_prior_age_frames old; when the share
 *   of narrowed searches that succeed drops to a fraction of the previous frame's (a cut), all
 *   priors are dropped and the frame can be matched again;
 * - all temporal state is forgotten when time goes back (a looping bag), after a long gap, or when
 *   the image size, the disparity range or the calibration changes.
 * Priors must not weaken the acceptance criteria: the matcher applies the same criteria, only the
 * range changes, and where a narrowed range measurably let more errors through (cuts, moving
 * edges) the rules above widen it. docs/temporal_results.md has the measurements.
 *
 * Use (what Pipeline does per frame):
 * @code
 *   endo_stereo::TemporalTracker temporal(params.temporal);
 *   // per frame:
 *   endo_stereo::TemporalFrameInfo info{left.size(), stamp_s, calibration_generation,
 *                                       mp.min_disparity, mp.max_disparity, left};
 *   std::string reset_reason;
 *   const endo_stereo::SearchRange* range = temporal.beginFrame(info, &reset_reason);
 *   // TemporalMatcher::compute(): the pass with range (nullptr = the full range),
 *   // rejectPriors() (a cut: the frame again over the full range), the post-filter.
 *   temporal_matcher.compute(left, right, temporal, range, match);
 *   temporal.endFrame(match.disparity, want_fused, want_coverage);
 *   // temporal.prior().stats(), temporal.fusion().disparity() / age(),
 *   // temporal.coverage().longestRun(), temporal.coverage().stats(), coverage().colorImage()
 * @endcode
 *
 * Thread safety: none of these classes is thread-safe; one instance per processing thread.
 * ROS-free: OpenCV only.
 */
#pragma once

#include <cstdint>
#include <limits>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {

/// Parameters of the temporal stage. Defaults are the shipped preset.
struct TemporalParams {
  /// Use temporal search-range priors. Fusion and coverage are requested separately (they run
  /// whether or not priors are used, so "--no-priors" runs can be compared on coverage too).
  bool enabled = true;
  /// Half-width of the narrowed search around a prior, px (+-4 by default). In [1, 64].
  int prior_radius_px = 4;
  /// The narrowed range of a pixel spans the priors found within this many pixels of it
  /// (a (2k+1)^2 neighbourhood), so small image motion and newly uncovered neighbours of valid
  /// pixels are covered. In [0, 16]; 0 = the pixel's own prior only.
  int prior_neighbourhood_px = 2;
  /// Depth edges move (an instrument sweeping over tissue): a pixel within this many pixels of a
  /// prior discontinuity (priors in that neighbourhood spanning more than 2 * prior_radius_px)
  /// searches the span of both sides, [min - r, max + r] over the neighbourhood, so tissue that an
  /// instrument uncovers is searched at the tissue's disparity too. The zone is computed on 4 x 4
  /// blocks, so it reaches between this and this + 7 px. In [0, 64]; 0 = off (also when <=
  /// prior_neighbourhood_px).
  int prior_edge_zone_px = 16;
  /// A valid disparity measured at most this many frames ago is a prior (1 = previous frame only).
  /// A narrowed search that finds nothing keeps the prior without refreshing it, so this also
  /// bounds how many frames in a row a failing prior is tried before the pixel is back to the
  /// full range. In [1, 1000].
  int max_prior_age_frames = 10;
  /// A pixel without a usable prior (none valid within max_prior_age_frames in its neighbourhood)
  /// searches the full range in one frame of this many: each frame, one in every
  /// full_range_period_frames stripes of kFullRangeStripeRows rows takes its turn; elsewhere such
  /// pixels are not searched (matcher code "unsearched") and keep whatever prior they had (it
  /// ages). 1 = every frame (docs/method.md section 4 to the letter). Most pixels without a prior
  /// fail again (the textureless instrument, the band at the left border, wet highlights), and a
  /// failure at the full range runs every window size: on the surgical sequence 4 cuts 22% of the
  /// matcher's instructions per frame with priors, for -0.26 points of density and 97.9% instead of
  /// 98.2% of central pixels updated within 10 frames (docs/temporal_results.md). In [1, 1000].
  int full_range_period_frames = 4;
  /// Scene change: when the share of a frame's narrowed searches that find a valid disparity
  /// falls below this fraction of the previous frame's share, the priors are dropped at once (a
  /// cut, a jump of the endoscope): TemporalTracker::rejectPriors() then asks for the frame to be
  /// matched again over the full range (TemporalMatcher), or else the
  /// next frame searches it. Relative, because the share depends on the scene: 91-93% on the
  /// generated sequence, 37-70% on the in-vivo video (median 53%, no frame below 0.78 x the
  /// previous one over frames 1-150), and a cut between two generated scenes drops it to 27%
  /// (0.30 x). Judged only when at least 5% of the pixels were narrowed and the previous frame's
  /// share is known (not on the first narrowed frame after a reset or a scene change).
  /// In [0, 1]; 0 = off.
  double min_prior_hit_share = 0.5;
  /// Forget the temporal state when the stamp moves forward by more than this, s. > 0.
  double max_gap_s = 0.5;
  /// Fused output: keep a pixel's most recent valid disparity for at most this many frames
  /// (0 = this frame only). In [0, 65534].
  int fused_max_age_frames = 10;
  /// Coverage figures: a pixel counts as "updated within N frames" when its longest run of
  /// consecutive frames without a valid disparity is < N (every N consecutive frames hold an
  /// update; paper: 10 frames at 25 fps). In [1, 65534].
  int coverage_within_frames = 10;

  /// @return an empty string when valid, otherwise a message naming the bad field and its range.
  std::string validate() const;
};

/// Height of the row stripes that take turns at a full-range search (TemporalParams::
/// full_range_period_frames).
constexpr int kFullRangeStripeRows = 8;

/// What identifies a continuous stream for the temporal state.
struct TemporalFrameInfo {
  cv::Size size;                        ///< size of the (rectified) images matched
  double stamp_s = 0.0;                 ///< capture time, s; NaN = unknown (time checks skipped)
  uint64_t calibration_generation = 0;  ///< bump whenever the calibration changes
  int min_disparity = 0;                ///< matcher's full range, px, inclusive
  int max_disparity = 63;
};

/**
 * Decides whether the temporal state must be forgotten before a frame: time went back, a gap
 * longer than max_gap_s, or a change of image size, disparity range or calibration generation.
 */
class TemporalResetDetector {
 public:
  explicit TemporalResetDetector(double max_gap_s = 0.5) : max_gap_s_(max_gap_s) {}
  void setMaxGap(double max_gap_s) { max_gap_s_ = max_gap_s; }
  /// Record @p info as the latest frame.
  /// @return "" when the stream is continuous with the previous frame (or on the first frame),
  ///         otherwise the reason (e.g. "time went back by 3.96 s").
  std::string check(const TemporalFrameInfo& info);
  /// Forget the previous frame (the next check() returns "").
  void reset() { has_previous_ = false; }

 private:
  double max_gap_s_;
  bool has_previous_ = false;
  TemporalFrameInfo previous_;
};

/// Counters of the latest frame of a TemporalPrior.
struct TemporalPriorStats {
  int64_t narrowed_pixels = 0;    ///< pixels given a range narrower than the full one
  int64_t full_range_pixels = 0;  ///< pixels searching the full range this frame (no usable
                                  ///< prior, or its stripe's turn)
  int64_t deferred_pixels = 0;    ///< not searched this frame: full range, not their stripe's turn
                                  ///< (full_range_period_frames); not in full_range_pixels
  int64_t edge_zone_pixels = 0;   ///< narrowed pixels given the span of a nearby depth edge
  bool scene_change = false;      ///< all priors dropped this frame: too few narrowed searches hit
  int64_t prior_hits = 0;         ///< narrowed pixels that got a valid disparity (after update())
  int64_t prior_misses = 0;       ///< narrowed pixels that got none (after update())
  double mean_narrowed_width_px = 0.0;  ///< mean hi - lo + 1 over narrowed pixels
};

/**
 * Search-range priors from the previous frames' valid disparities (docs/method.md section 4).
 *
 * Per pixel it keeps the most recent valid disparity and its age in frames. buildRange() gives
 * pixel p the range [floor(min_N(p) - r), ceil(max_N(p) + r)], where min_N / max_N are the
 * extreme priors within prior_neighbourhood_px of p (priors no older than max_prior_age_frames),
 * clamped to the full range. Near a prior depth edge (within prior_edge_zone_px) the span of both
 * sides is searched instead. Pixels with no such prior search the full range in one frame of
 * full_range_period_frames (their row stripe's turn) and are deferred in the others.
 */
class TemporalPrior {
 public:
  /// @throws std::invalid_argument when params fail validate().
  explicit TemporalPrior(const TemporalParams& params = TemporalParams());
  /// @throws std::invalid_argument when invalid (old ones kept). State is kept.
  void setParams(const TemporalParams& params);
  const TemporalParams& params() const { return params_; }

  /// Forget all priors.
  void reset();

  /**
   * Build the search range of the next frame.
   * A change of size or full range against the stored state resets it first.
   * @return true when at least one pixel got a narrowed range (pass &range to the matcher);
   *         false when every pixel searches the full range (range cleared; pass nullptr).
   */
  bool buildRange(cv::Size size, int min_disparity, int max_disparity, SearchRange& range);

  /**
   * Record the frame's final disparity (CV_32FC1, NaN invalid, the size given to buildRange()).
   * Call once after each buildRange(); also fills the hit/miss counters of stats(). When the hit
   * share of the narrowed searches falls below min_prior_hit_share x referenceHitShare(), all
   * priors are dropped (stats().scene_change).
   * @throws std::invalid_argument on a type or size mismatch.
   */
  void update(const cv::Mat& disparity);

  /// Share of the latest buildRange()'s narrowed pixels that @p disparity (CV_32FC1, NaN invalid)
  /// gives a valid value, in [0, 1] (1 when none was narrowed); @p judged gets their number.
  double hitShare(const cv::Mat& disparity, int64_t* judged = nullptr) const;
  /// Whether hitShare() says the scene changed (min_prior_hit_share x referenceHitShare(); >= 5%
  /// of pixels judged).
  bool sceneChanged(const cv::Mat& disparity) const;
  /// The scene-change test on counts: @p hits of @p judged narrowed searches, @p total pixels.
  bool isSceneChange(int64_t hits, int64_t judged, int64_t total) const;
  /// The hit share of the latest update() that was judged and not a scene change; -1 = none yet
  /// (after a reset or a scene change).
  double referenceHitShare() const { return reference_hit_share_; }
  /// Drop every prior now (a scene change); the next update() treats all pixels as searched over
  /// the full range. Sets stats().scene_change.
  void dropAll();

  /// Counters of the latest buildRange() / update().
  const TemporalPriorStats& stats() const { return stats_; }
  /// Most recent valid disparity per pixel (CV_32FC1, NaN none), regardless of age.
  const cv::Mat& lastDisparity() const { return last_disparity_; }
  /// Frames since lastDisparity() was measured (CV_16UC1; 0 = the latest frame, 65535 = never).
  const cv::Mat& priorAge() const { return age_; }

 private:
  TemporalParams params_;
  cv::Size size_;
  int min_disparity_ = 0, max_disparity_ = -1;
  cv::Mat last_disparity_;  // CV_32FC1
  cv::Mat age_;             // CV_16UC1
  cv::Mat narrowed_;        // CV_8UC1 1 where the last built range was narrowed, 2 deferred
  int64_t frame_count_ = 0; // update() calls since the last reset (selects the stripes' turn)
  double reference_hit_share_ = -1.0;  // see referenceHitShare()
  cv::Mat lo_f_, hi_f_;     // scratch: priors spread over the neighbourhood
  cv::Mat lo_e_, hi_e_;     // scratch: priors spread over the edge zone
  std::vector<uint8_t> zero_row_;           // scratch: "not narrowed" row (update() without a range)
  TemporalPriorStats stats_;
};

/// Age value meaning "no value".
constexpr uint16_t kAgeNone = std::numeric_limits<uint16_t>::max();

/**
 * Temporal fusion (optional output): per pixel the most recent valid disparity not older than
 * fused_max_age_frames, with its age in frames, so a consumer can choose between "this frame
 * only" (age 0) and "recent and trusted".
 */
class TemporalFusion {
 public:
  /// @param max_age_frames in [0, 65534].
  explicit TemporalFusion(int max_age_frames = 10);
  void setMaxAge(int max_age_frames);
  void reset();
  /// Fold in a frame's disparity (CV_32FC1, NaN invalid). A size change resets first.
  void update(const cv::Mat& disparity);
  /// CV_32FC1, px; NaN where no valid disparity within the max age.
  const cv::Mat& disparity() const { return disparity_; }
  /// CV_16UC1, frames since the fused value was measured (0 = this frame), kAgeNone where NaN.
  const cv::Mat& age() const { return age_; }

 private:
  int max_age_frames_;
  cv::Mat disparity_, age_;
};

/// Figures of a CoverageTracker.
struct CoverageStats {
  int frames = 0;              ///< frames folded in
  int within_frames = 10;      ///< the N of "updated within N frames"
  double central_share = 0.0;  ///< central-region pixels updated at least once, longest run < N
  double overall_share = 0.0;  ///< all pixels updated at least once with longest run < N
  double central_never = 0.0;  ///< central-region pixels never updated, [0, 1]
  double overall_never = 0.0;  ///< all pixels never updated, [0, 1]
  cv::Rect central_region;     ///< the middle half of the image by area
};

/**
 * Coverage over time (the paper's Fig. 6): per pixel the longest run of consecutive frames
 * without a valid disparity so far (a run still open counts, and so do the frames before the first
 * update).
 */
class CoverageTracker {
 public:
  /// @param within_frames the N of "updated within N frames", in [1, 65534].
  explicit CoverageTracker(int within_frames = 10);
  void setWithinFrames(int within_frames);
  void reset();
  /// Fold in a frame's disparity (CV_32FC1, NaN invalid). A size change resets first.
  void update(const cv::Mat& disparity);
  /// CV_16UC1, longest run of frames without an update per pixel (saturates at 65535).
  const cv::Mat& longestRun() const { return longest_; }
  /// CV_16UC1, frames since the last update per pixel (the open run).
  const cv::Mat& currentRun() const { return current_; }
  int frames() const { return frames_; }
  /// The figures (central region = centred rectangle with sides / sqrt(2), half the area).
  CoverageStats stats() const;
  /**
   * Colour picture of longestRun() (BGR): 0 frames dark blue through green/yellow up to red at
   * 2N frames and above; pixels never updated are black; the central region is outlined in white.
   * Empty before the first update().
   */
  cv::Mat colorImage() const;
  /// The middle half of an image of @p size by area (centred, sides scaled by 1/sqrt(2)).
  static cv::Rect centralRegion(cv::Size size);

 private:
  int within_frames_;
  int frames_ = 0;
  cv::Mat current_, longest_;
  cv::Mat ever_;  // CV_8UC1, 1 once updated
};

/**
 * The temporal stage as the pipeline runs it: reset detection, priors, fusion and coverage
 * behind two calls per frame (beginFrame() before matching, endFrame() after).
 */
class TemporalTracker {
 public:
  /// @throws std::invalid_argument when params fail validate().
  explicit TemporalTracker(const TemporalParams& params = TemporalParams());
  /// @throws std::invalid_argument when invalid (old ones kept). State is kept.
  void setParams(const TemporalParams& params);
  const TemporalParams& params() const { return params_; }

  /// Forget priors, fusion and coverage.
  void reset();

  /**
   * Before matching a frame. Resets all state when the stream is not continuous (reason in
   * @p reset_reason, "" otherwise). A scene change detected by the previous endFrame() (priors
   * dropped, fused disparities forgotten; coverage kept) is reported here too.
   * @return the per-pixel range to pass to RobustMatcher::compute(), or nullptr for the full
   *         range (priors disabled, first frame, just reset, or no valid prior anywhere).
   *         The pointer stays valid until the next beginFrame().
   */
  const SearchRange* beginFrame(const TemporalFrameInfo& info, std::string* reset_reason = nullptr);

  /**
   * Optional, between matching and endFrame(): did the priors describe another scene (a cut, a
   * jump of the endoscope)? When the share of the narrowed searches that found a disparity fell
   * below min_prior_hit_share x the previous frame's share, the priors and fused disparities are
   * dropped at once and true is returned: match the frame again over the full range (range =
   * nullptr) and pass that result to endFrame().
   * Without this call the same test runs inside endFrame() and only the next frame searches the
   * full range (this frame's output keeps what the wrong priors let through).
   */
  bool rejectPriors(const cv::Mat& disparity);

  /**
   * After matching, with the frame's final disparity (CV_32FC1, NaN invalid).
   * @param fuse           update the fused disparity / age
   * @param track_coverage update the coverage tracker
   */
  void endFrame(const cv::Mat& disparity, bool fuse, bool track_coverage);

  const TemporalPrior& prior() const { return prior_; }
  const TemporalFusion& fusion() const { return fusion_; }
  const CoverageTracker& coverage() const { return coverage_; }
  /// Whether the range returned by the latest beginFrame() was non-null.
  bool priorsUsed() const { return priors_used_; }
  /// The narrowed range of the latest beginFrame() (meaningful while priorsUsed()), kept until
  /// the next beginFrame().
  const SearchRange& range() const { return range_; }

 private:
  TemporalParams params_;
  TemporalResetDetector detector_;
  TemporalPrior prior_;
  TemporalFusion fusion_;
  CoverageTracker coverage_;
  SearchRange range_;
  bool priors_used_ = false;
  bool frame_open_ = false;
  std::string pending_reason_;  // a scene change seen in endFrame(), reported by beginFrame()
};

}  // namespace endo_stereo
