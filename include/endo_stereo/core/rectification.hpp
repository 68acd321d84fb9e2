/**
 * @file rectification.hpp
 * @brief Stereo rectification in three modes (docs/method.md section 1) and its quality figure.
 *
 * 1. Calibrated: undistort-rectify maps from two CameraInfo-model calibrations (K, D, R, P with
 *    binning and ROI), built once and cached until the calibration or the image size changes.
 *    When P is not given but the extrinsics are, the rectification is computed with
 *    cv::stereoRectify (alpha, output size and zero-disparity as options).
 * 2. Uncalibrated, as in the paper: SIFT features (Lowe 2004) with the ratio test, the
 *    fundamental matrix by RANSAC, its epipoles, then either
 *    - homography rectification (Hartley, "Theory and practice of projective rectification",
 *      IJCV 1999): the right image's epipole is sent to infinity along x; the left homography
 *      is the F-compatible one whose warp has no shear at the image centre (Hartley instead
 *      minimises disparity), shifted so that the inliers' median disparity equals their median
 *      raw horizontal disparity; both then get a common scale and shift that keeps the left
 *      image's area and centre. Used when both epipoles lie
 *      far outside the images (the usual stereo endoscope).
 *    - polar rectification (Pollefeys, Koch and Van Gool, "A simple and efficient rectification
 *      method for general motion", ICCV 1999): rows are corresponding epipolar half-lines sampled
 *      so that no pixel is compressed in either image, columns are distances from the epipole.
 *      Exact for any epipole position, including inside the image. See PolarRectification
 *      (below) for how a polar pixel and a polar disparity map back to the raw images.
 *    Matches are pooled over RectifyParams::estimation_frames frames; the estimate then stays
 *    fixed while the quality figure stays good and is re-estimated when it drifts. Estimation
 *    is refused (rectify() returns false, "could not be estimated: ...") with too few
 *    consistent matches (textureless pairs), when over 90% of them fit one homography (a planar
 *    scene or no parallax: F is ambiguous), or when the result does not align its own inliers.
 * 3. Pass-through: the input is already rectified (geometry from the calibration's P when given,
 *    else from focal_px / baseline_m).
 *
 * Quality (all modes): every quality_stride frames, SIFT matches between the two images, their
 * RANSAC inliers of a fundamental matrix (so no row alignment is assumed), and the median and
 * 90th percentile of their vertical offset after rectification. A warning is raised above
 * quality_warn_px (1 px by default): a wrong calibration shows here before it becomes a wrong
 * surface.
 *
 * Use:
 * @code
 *   endo_stereo::RectifyParams rp;                       // calibrated by default
 *   endo_stereo::StereoRectifier rectifier(rp);
 *   std::string err = rectifier.setCalibration(calib);  // "" = ok
 *   cv::Mat lg, rg, lc;
 *   if (!rectifier.rectify(left_gray, right_gray, left_bgr, lg, rg, lc, &err)) { ... }
 *   const endo_stereo::RectifiedGeometry& g = rectifier.geometry();
 *   if (rectifier.quality().warning) { ... }
 * @endcode
 *
 * Thread safety: not thread-safe (it caches maps and estimation state); one instance per thread.
 * The const accessors may be called concurrently with each other, not with rectify().
 */
#pragma once

#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {

enum class RectifyMode {
  kCalibrated,    ///< from the two calibrations (setCalibration() required)
  kUncalibrated,  ///< estimated from the images, as in the paper
  kPassThrough,   ///< input already rectified
};

enum class UncalibratedMethod {
  kAuto,        ///< homography when both epipoles are far outside the images, else polar
  kHomography,  ///< Hartley 1999
  kPolar,       ///< Pollefeys, Koch, Van Gool 1999
};

/// "calibrated" | "uncalibrated" | "pass_through" (also "passthrough", "none").
std::string toString(RectifyMode mode);
bool parseRectifyMode(const std::string& text, RectifyMode* mode);
/// "auto" | "homography" | "polar".
std::string toString(UncalibratedMethod method);
bool parseUncalibratedMethod(const std::string& text, UncalibratedMethod* method);

/// Parameters of rectification. Defaults: calibrated mode, the stereo_image_proc-like output.
struct RectifyParams {
  RectifyMode mode = RectifyMode::kCalibrated;

  // --- Calibrated from raw K/D/R/T (no P in the calibration): cv::stereoRectify options.
  /// Free scaling, -1 (OpenCV's default) or [0, 1]: 0 = only valid pixels, 1 = all source pixels.
  double alpha = 0.0;
  /// Principal points made equal (cx_left == cx_right, doffs = 0); false keeps verged points.
  bool zero_disparity = true;
  /// Output size, px; 0 = input size times output_scale_x / output_scale_y.
  int output_width_px = 0;
  int output_height_px = 0;
  /// Output size relative to the input, (0, 4]; e.g. output_scale_y = 2 for a field image
  /// (the UCL reference uses newImageSize = (w, 2h)). Ignored where output_*_px is set.
  double output_scale_x = 1.0;
  double output_scale_y = 1.0;
  /// Fixed-point maps (CV_16SC2, about twice as fast, 1/32 px steps) instead of CV_32FC1.
  bool fixed_point_maps = false;

  // --- Uncalibrated.
  UncalibratedMethod method = UncalibratedMethod::kAuto;
  /// Most SIFT features per image, >= 0 (0 = unlimited).
  int sift_features = 2000;
  /// Lowe's ratio test: best / second-best descriptor distance below this, (0, 1).
  double ratio_test = 0.75;
  /// RANSAC inlier threshold for the fundamental matrix, px, > 0.
  double ransac_threshold_px = 1.0;
  /// RANSAC confidence, (0, 1).
  double ransac_confidence = 0.999;
  /// Least RANSAC inliers (pooled over the estimation frames) to accept an estimate, >= 8.
  int min_inliers = 40;
  /// Frames whose matches are pooled before the estimate is frozen, >= 1.
  int estimation_frames = 5;
  /// Re-estimate when the measured median vertical offset exceeds this, px; 0 = never.
  double reestimate_threshold_px = 1.0;
  /// ... in this many consecutive quality measurements, >= 1.
  int reestimate_after = 2;
  /// kAuto uses polar when an epipole is closer to the image centre than this many image
  /// diagonals, > 0.
  double polar_auto_distance = 5.0;
  /// Focal length of the (rectified) left camera, px; 0 = unknown (disparity only).
  double focal_px = 0.0;
  /// Baseline, metres; 0 = unknown. Depth is metric only with both focal_px and baseline_m.
  double baseline_m = 0.0;

  // --- Quality figure, all modes.
  /// Measure every this many frames (frame 0 included); 0 = never.
  int quality_stride = 30;
  /// Warning threshold on the median vertical offset, px, > 0.
  double quality_warn_px = 1.0;
  /// Most patches of the quality figure, >= 0 (0 = one per 16 x 16 px;
  /// measureRowAlignmentPatches). Uncalibrated mode, while pooling, uses its SIFT matches.
  int quality_max_features = 300;
  /// Row correction (ours; calibrated and pass-through modes): shift the right view's rows by
  /// the vertical offset the quality figure measured, fitted as a plane over the image
  /// (RectificationQuality::row_offset), so that a calibration that leaves the views' rows a
  /// fraction of a pixel apart does not cost matches. Applied from the first measurement on and
  /// updated with each one (measured on the uncorrected pair, so quality reports the
  /// calibration). docs/method.md, section 1.
  bool row_correction = true;
  /// The least number of patch matches a fitted offset needs before it is applied, >= 3.
  int row_correction_min_matches = 30;
  /// Applied only when the fitted plane reaches this offset at a corner of the image, px, >= 0:
  /// below it the rows are as well aligned as the measure tells (its patches are good to about
  /// 0.05 px), and a bilinear shift would only blur the right view.
  double row_correction_min_px = 0.1;

  /// @return "" when valid, else a message naming the field and its accepted range.
  std::string validate() const;
};

/// The latest measured rectification residual.
struct RectificationQuality {
  bool valid = false;           ///< a measurement exists (false: not yet, or too few matches)
  double median_offset_px = 0;  ///< median |y_left - y_right| of inlier matches, rectified px
  double p90_offset_px = 0;     ///< 90th percentile of the same
  int num_matches = 0;          ///< inlier matches the figures are computed from
  int64_t frame_index = -1;     ///< rectify() call (0-based) it was measured on
  /// Patch measure: most textured patches found no match within +-8 px rows and the disparity
  /// range (rows misaligned by more, views that differ, or a range that misses the scene); valid
  /// is then false and warning true.
  bool misaligned = false;
  bool warning = false;  ///< median_offset_px > RectifyParams::quality_warn_px, or misaligned
  /// Patch measure: the signed vertical offset of the right view (its matching row minus the
  /// left row, px) as a plane over the right image, offset = c0 + c1 x + c2 y, fitted to the
  /// matches by least squares with outliers dropped; row_offset_matches = the matches it rests on
  /// (0: none fitted).
  cv::Vec3d row_offset{0, 0, 0};
  int row_offset_matches = 0;
  /// Uncalibrated: the rectification was estimated (false: "could not be estimated"). True in
  /// the other modes.
  bool estimated = false;
  std::string method;   ///< "calibrated", "homography", "polar", "pass_through"
  std::string message;  ///< human-readable state or reason (empty when all is well)
};

/**
 * A polar rectification of one pair (Pollefeys et al. 1999), exposed for mapping results back.
 *
 * Rectified row i is the epipolar half-line at angle theta[i] around the left epipole and at
 * angle phi[i] around the right epipole (angles in radians, image axes x right, y down, and the
 * two half-lines correspond). Rectified column c is at distance
 *   r = r_ref + sign * (c - c_ref)
 * from the epipole along that half-line (per image: r_ref, sign, c_ref below). So a left pixel
 * (c, i) is the raw point e + r (cos theta[i], sin theta[i]); a polar disparity d at (c, i) means
 * the right match is column c - d of row i, i.e. the raw point e' + r' (cos phi[i], sin phi[i])
 * with r' = r_ref_right + sign_right * (c - d - c_ref). Triangulating such a pair needs the
 * cameras, which uncalibrated mode does not have: the pipeline gets the rectified pair, a
 * quality figure and (with focal_px/baseline_m) no metric depth; RectifiedGeometry::polar is set.
 * For epipoles far outside the images, sign is chosen so that columns increase with raw x and
 * rows with raw y, and r_ref/c_ref put the image centres on the middle column, so disparities
 * approximate the raw horizontal disparities.
 */
struct PolarRectification {
  cv::Point2d epipole_left;  ///< raw px (finite; clamped to 1e9 px from the image centre)
  cv::Point2d epipole_right;
  std::vector<double> theta;               ///< per row, left half-line angle, rad, monotonic
  std::vector<double> phi;                 ///< per row, right half-line angle, rad, monotonic
  double r_ref_left = 0, r_ref_right = 0;  ///< distance at column c_ref, px
  double sign_left = 1, sign_right = 1;    ///< +1: column grows with r
  double c_ref = 0;                        ///< reference column (same for both images)
  int width = 0;                           ///< rectified width, px
  /// Raw point of rectified pixel (col, row) in the left (left = true) or right image.
  cv::Point2d toRaw(bool left, double col, double row) const;
  /// Rectified (col, row) of a raw point; false when it lies outside the rectified region.
  bool toRectified(bool left, const cv::Point2d& raw, cv::Point2d* rect) const;
};

/**
 * The rectifier (see the file comment for the methods and their references).
 * Not thread-safe; one instance per processing thread.
 */
class StereoRectifier {
 public:
  /// @throws std::invalid_argument when params fail validate().
  explicit StereoRectifier(const RectifyParams& params = RectifyParams());
  ~StereoRectifier();
  StereoRectifier(const StereoRectifier&) = delete;
  StereoRectifier& operator=(const StereoRectifier&) = delete;

  /// Replace the parameters. A change to anything but the quality settings drops the cached
  /// maps / uncalibrated estimate (the generation then advances on the next rectify()).
  /// @throws std::invalid_argument when invalid (old ones kept).
  void setParams(const RectifyParams& params);
  const RectifyParams& params() const;

  /**
   * Set or replace the calibration (calibrated mode; in pass-through mode its P gives the
   * geometry). Validates it; maps are rebuilt lazily only when the values differ from the cached
   * ones. @return "" or a message naming the bad field; on error the old calibration is kept.
   */
  std::string setCalibration(const StereoCalibration& calibration);
  bool hasCalibration() const;

  /**
   * Rectify one pair (any mode).
   * @param left_gray, right_gray CV_8UC1, same size (the pre-processed images; in calibrated
   *        mode their size must match CameraCalibration::binnedSize()).
   * @param left_bgr  CV_8UC3 of the same size, or empty (then left_rect_bgr is left empty).
   * @param left_rect_gray, right_rect_gray, left_rect_bgr outputs (reallocated on size change).
   * @return false with a message in @p error: no calibration, size mismatch, or (uncalibrated)
   *         "rectification could not be estimated: ..." for pairs without enough texture.
   *         Never throws for bad input.
   */
  bool rectify(const cv::Mat& left_gray, const cv::Mat& right_gray, const cv::Mat& left_bgr,
               cv::Mat& left_rect_gray, cv::Mat& right_rect_gray, cv::Mat& left_rect_bgr,
               std::string* error);

  /// Apply the current rectification to one more image of the left (left = true) or right camera
  /// (a mask with INTER_NEAREST, the right colour image, ...), as rectify() treats that camera's
  /// view: a right image also gets the row correction (RectifyParams::row_correction) when
  /// rectify() applies it. Valid after a successful rectify().
  /// @return false when no rectification is available or the size does not match.
  bool rectifyImage(bool left, const cv::Mat& raw, cv::Mat& rectified,
                    int interpolation /* cv::InterpolationFlags */, std::string* error) const;

  /// Map a raw (pre-processed) image point to the rectified image and back. Valid after a
  /// successful rectify() (or, calibrated, after setCalibration() with known sizes).
  bool rawToRectified(bool left, const cv::Point2d& raw, cv::Point2d* rectified) const;
  bool rectifiedToRaw(bool left, const cv::Point2d& rectified, cv::Point2d* raw) const;

  /// Geometry of the rectified pair (valid after a successful rectify(); calibrated mode also
  /// after setCalibration() when image sizes are known).
  const RectifiedGeometry& geometry() const;
  /// Latest quality measurement (see RectificationQuality).
  RectificationQuality quality() const;
  /// Advances whenever the rectification changes (new calibration, new or re-estimated
  /// uncalibrated rectification, size change): temporal state keyed to the old one must reset.
  uint64_t generation() const;
  /// Name of the method in use: "calibrated", "homography", "polar", "pass_through", or "" when
  /// none is established yet.
  std::string activeMethod() const;

  /// Uncalibrated: the current homographies (raw -> rectified) when the method is homography.
  bool homographies(cv::Matx33d* left, cv::Matx33d* right) const;
  /// Uncalibrated: the current polar rectification when the method is polar (else nullptr).
  const PolarRectification* polar() const;
  /// Uncalibrated: the estimated fundamental matrix (x_right^T F x_left = 0, raw px).
  bool fundamentalMatrix(cv::Matx33d* F) const;

  /// Forget the uncalibrated estimate and the frame counter (calibration and maps kept).
  void reset();

  /**
   * Measure the quality (measureRowAlignmentPatches, about 13 ms at 960x540) on a background
   * thread at the lowest priority instead of inside rectify() (default false: inside). The
   * rectified images do not wait for it, only quality() does: it then reports the measurement
   * of an earlier frame (frame_index says which) once it is done, and a stride's measurement is
   * skipped while the previous one still runs. A live caller (the nodelet) uses this so that one
   * frame in quality_stride does not take longer. Uncalibrated mode measures the same way once
   * its estimate is frozen (a drift is then judged when the measurement is recorded, so a
   * re-estimation starts a few frames later); while it pools SIFT matches for an estimate, it
   * measures inline with those matches.
   */
  void setAsyncQuality(bool async);

  /// The disparity range the patch quality measurement searches
  /// (the pipeline passes the matcher's). Until set (or with min > max): +-width / 4.
  void setQualityDisparityRange(int min_disparity, int max_disparity);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/**
 * Measure the vertical offset between two row-aligned images: SIFT matches with the ratio test,
 * RANSAC inliers of a fundamental matrix (threshold ransac_threshold_px), then the median and
 * 90th percentile of |y_left - y_right|. Used by the rectifier and by tests. Fills
 * valid/median/p90/num_matches; valid is false below 8 inliers.
 */
RectificationQuality measureRowAlignment(const cv::Mat& left_gray, const cv::Mat& right_gray,
                                         int max_features, double ratio_test,
                                         double ransac_threshold_px);

/**
 * Measure the vertical offset between two row-aligned CV_8UC1 images without features: on a grid
 * of about max_patches cells (0: one per 16 x 16 px), the left 11 x 11 patch with the most
 * texture in both directions is searched in the right image over the disparities
 * [min_disparity, max_disparity] and vertical offsets of +-8 px (ZNCC); a match counts when its
 * ZNCC is at least 0.8, 0.05 above the best match 3 or more disparities away, and not cut by the
 * disparity range. Its vertical offset is refined to sub-pixel by a parabola; offsets beyond 8
 * px find no match: when most textured patches find none, misaligned is set (and valid is
 * false). Fills valid/median/p90/num_matches (valid needs 8 matches) and the fitted row offset
 * (fitRowOffset; row_offset, row_offset_matches). Uses no cv::parallel_for_
 * (safe on a background thread: OpenCV runs parallel_for_ serially while another thread is
 * inside one). The rectifier measures with this in every mode, except while uncalibrated mode
 * pools SIFT matches for an estimate (it then uses those matches).
 */
RectificationQuality measureRowAlignmentPatches(const cv::Mat& left_gray, const cv::Mat& right_gray,
                                                int min_disparity, int max_disparity,
                                                int max_patches);

/**
 * Fits offset = c0 + c1 x + c2 y to matches (x, y, signed vertical offset) by least squares,
 * then again without the matches further than max(0.5 px, 3 x the median absolute residual) from
 * the first fit. @p model gets (c0, c1, c2); returns the number of matches of the final fit (0
 * with fewer than 3 or a degenerate layout, model then zero).
 */
int fitRowOffset(const std::vector<cv::Vec3d>& matches, cv::Vec3d* model);

/**
 * Shifts the rows of @p right by the offset plane (c0 + c1 x + c2 y, px; the right row that
 * matches left row y is y + offset): out(x, y) = right(x, y + offset(x, y)), with
 * @p interpolation (cv::InterpolationFlags; bilinear unless told), the border row repeated.
 * @p map_x / @p map_y cache the maps (rebuilt when @p map_model or the size differs). out may
 * not alias right.
 */
void shiftRows(const cv::Mat& right, const cv::Vec3d& model, cv::Mat& out, cv::Mat& map_x,
               cv::Mat& map_y, cv::Vec3d& map_model, int interpolation = 1 /* INTER_LINEAR */);

}  // namespace endo_stereo
