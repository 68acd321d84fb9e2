// StereoRectifier: calibrated, uncalibrated and pass-through rectification of the raw pair, and
// the scheduling of the quality measure (rectification_quality.cpp). Names and parameter
// validation: rectify_params.cpp.

#include "endo_stereo/core/rectification.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <future>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>

#include "uncalibrated_rectification.hpp"

#ifdef __linux__
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

namespace endo_stereo {

namespace {

// The background measurement is bookkeeping: it should take only CPU time the frames leave
// idle. Linux: niceness 19 for the calling thread (a thread may always lower its own priority).
void lowerThisThreadsPriority() {
#ifdef __linux__
  (void)setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 19);
#endif
}

bool fail(std::string* error, const std::string& msg) {
  if (error) *error = msg;
  return false;
}

std::string sizeStr(const cv::Size& s) {
  return std::to_string(s.width) + "x" + std::to_string(s.height);
}

bool isFisheye(const CameraCalibration& c) {
  return c.distortion_model == "equidistant" || c.distortion_model == "fisheye";
}

cv::Mat distortionMat(const CameraCalibration& c) {
  if (c.D.empty()) return cv::Mat();
  return cv::Mat(c.D, true).reshape(1, 1);
}

enum class UncalState { kCollecting, kFrozen };

}  // namespace

struct StereoRectifier::Impl {
  RectifyParams params;

  // Calibration and the maps built from it (calibrated mode).
  bool has_calib = false;
  StereoCalibration calib;
  bool maps_valid = false;
  cv::Size maps_in_size;  // input size the maps were built for
  cv::Size out_size;
  cv::Mat map_l1, map_l2, map_r1, map_r2;
  // The per-frame remap tables: map_* converted once to OpenCV's fixed-point form (CV_16SC2
  // integer part + CV_16UC1 1/32-px interpolation index). cv::remap with INTER_LINEAR converts
  // float maps to exactly this form block by block on every call (same rounding), so remapping
  // with these gives identical images at a fraction of the cost. map_* (float) stay for
  // rectifyImage(), whose caller may ask for another interpolation.
  cv::Mat fast_l1, fast_l2, fast_r1, fast_r2;
  cv::Matx33d K_l, K_r, R_l, R_r;  // effective (binned) raw intrinsics, rectification rotations
  cv::Matx34d P_l, P_r;            // effective rectified projections
  cv::Mat D_l, D_r;
  bool fisheye = false;

  // Uncalibrated estimate.
  UncalState state = UncalState::kCollecting;
  bool have_uncal = false;
  std::string uncal_method;  // "homography" | "polar"
  cv::Matx33d F = cv::Matx33d::zeros(), H_l = cv::Matx33d::eye(), H_r = cv::Matx33d::eye();
  PolarRectification polar;
  detail::Matches pool;
  int pooled_frames = 0;
  int bad_measurements = 0;
  cv::Size uncal_size;
  std::string last_estimation_error;

  RectifiedGeometry geometry;
  RectificationQuality quality;
  // Row correction (RectifyParams::row_correction): the offset plane in use, for the
  // rectification of generation row_generation; the maps that apply it, cached.
  bool have_row_model = false;
  cv::Vec3d row_model{0, 0, 0};
  uint64_t row_generation = 0;
  cv::Mat row_map_x, row_map_y, row_shifted;
  cv::Vec3d row_map_model{0, 0, 0};
  uint64_t generation = 0;
  int64_t frame_index = 0;
  std::string active;

  void dropUncalibrated() {
    state = UncalState::kCollecting;
    have_uncal = false;
    pool = detail::Matches();
    pooled_frames = 0;
    bad_measurements = 0;
    uncal_method.clear();
  }

  cv::Size outputSize(const cv::Size& in) const {
    const int w = params.output_width_px > 0 ? params.output_width_px
                                             : int(std::lround(in.width * params.output_scale_x));
    const int h = params.output_height_px > 0 ? params.output_height_px
                                              : int(std::lround(in.height * params.output_scale_y));
    return cv::Size(std::max(w, 1), std::max(h, 1));
  }

  /// Build the calibrated maps for input images of @p in (validated calibration).
  bool buildCalibratedMaps(const cv::Size& in, std::string* error) {
    const CameraCalibration& L = calib.left;
    const CameraCalibration& R = calib.right;
    K_l = L.binnedK();
    K_r = R.binnedK();
    D_l = distortionMat(L);
    D_r = distortionMat(R);
    fisheye = isFisheye(L);
    if (isFisheye(L) != isFisheye(R)) {
      return fail(error, "right.distortion_model: equidistant in one camera only");
    }
    try {
      if (L.hasProjection()) {
        R_l = L.R;
        R_r = R.R;
        P_l = L.binnedP();
        P_r = R.binnedP();
        out_size = in;
      } else {
        out_size = outputSize(in);
        cv::Mat r1, r2, p1, p2, q;
        const cv::Mat Rm(calib.R_right_left), Tm(calib.T_right_left);
        if (fisheye) {
          cv::fisheye::stereoRectify(cv::Mat(K_l), D_l, cv::Mat(K_r), D_r, in, Rm, Tm, r1, r2, p1,
                                     p2, q, params.zero_disparity ? cv::CALIB_ZERO_DISPARITY : 0,
                                     out_size, std::max(0.0, params.alpha), 1.0);
        } else {
          cv::stereoRectify(cv::Mat(K_l), D_l, cv::Mat(K_r), D_r, in, Rm, Tm, r1, r2, p1, p2, q,
                            params.zero_disparity ? cv::CALIB_ZERO_DISPARITY : 0, params.alpha,
                            out_size);
        }
        r1.convertTo(r1, CV_64F);
        r2.convertTo(r2, CV_64F);
        p1.convertTo(p1, CV_64F);
        p2.convertTo(p2, CV_64F);
        R_l = cv::Matx33d(r1);
        R_r = cv::Matx33d(r2);
        P_l = cv::Matx34d(p1);
        P_r = cv::Matx34d(p2);
        if (std::abs(P_r(1, 3)) > std::abs(P_r(0, 3))) {
          return fail(error,
                      "T_right_left: vertical stereo (baseline mostly along y) is not supported");
        }
      }
      const int map_type = params.fixed_point_maps ? CV_16SC2 : CV_32FC1;
      if (fisheye) {
        cv::fisheye::initUndistortRectifyMap(cv::Mat(K_l), D_l, cv::Mat(R_l), cv::Mat(P_l),
                                             out_size, map_type, map_l1, map_l2);
        cv::fisheye::initUndistortRectifyMap(cv::Mat(K_r), D_r, cv::Mat(R_r), cv::Mat(P_r),
                                             out_size, map_type, map_r1, map_r2);
      } else {
        cv::initUndistortRectifyMap(cv::Mat(K_l), D_l, cv::Mat(R_l), cv::Mat(P_l), out_size,
                                    map_type, map_l1, map_l2);
        cv::initUndistortRectifyMap(cv::Mat(K_r), D_r, cv::Mat(R_r), cv::Mat(P_r), out_size,
                                    map_type, map_r1, map_r2);
      }
      convertFastMaps();
    } catch (const std::exception& ex) {
      return fail(error, std::string("rectification maps could not be built: ") + ex.what());
    }
    const double baseline = -P_r(0, 3) / P_r(0, 0);
    if (!(baseline > 0)) {
      std::ostringstream m;
      m << "T_right_left: rectified baseline must be > 0, got " << baseline
        << " m (left and right swapped?)";
      return fail(error, m.str());
    }
    RectifiedGeometry g;
    g.width = out_size.width;
    g.height = out_size.height;
    g.f_px = P_l(0, 0);
    g.fy_px = P_l(1, 1);
    g.cx_left = P_l(0, 2);
    g.cx_right = P_r(0, 2);
    g.cy = P_l(1, 2);
    g.baseline_m = baseline;
    g.metric = true;
    g.frame_id = L.frame_id;
    g.R_rect_raw_left = R_l;
    geometry = g;
    maps_in_size = in;
    maps_valid = true;
    active = "calibrated";
    ++generation;
    return true;
  }

  /// Geometry of pass-through input.
  void passThroughGeometry(const cv::Size& in) {
    RectifiedGeometry g;
    g.width = in.width;
    g.height = in.height;
    if (has_calib && calib.left.hasProjection()) {
      const cv::Matx34d pl = calib.left.binnedP(), pr = calib.right.binnedP();
      g.f_px = pl(0, 0);
      g.fy_px = pl(1, 1);
      g.cx_left = pl(0, 2);
      g.cx_right = pr(0, 2);
      g.cy = pl(1, 2);
      g.baseline_m = -pr(0, 3) / pr(0, 0);
      g.metric = true;
      g.frame_id = calib.left.frame_id;
    } else {
      g.f_px = params.focal_px > 0 ? params.focal_px : double(in.width);
      g.cx_left = g.cx_right = (in.width - 1) / 2.0;
      g.cy = (in.height - 1) / 2.0;
      g.baseline_m = params.baseline_m > 0 ? params.baseline_m : 1.0;
      g.metric = params.focal_px > 0 && params.baseline_m > 0;
    }
    const bool changed = g.width != geometry.width || g.height != geometry.height ||
                         g.f_px != geometry.f_px || g.baseline_m != geometry.baseline_m ||
                         g.cx_left != geometry.cx_left || g.cx_right != geometry.cx_right ||
                         active != "pass_through";
    geometry = g;
    active = "pass_through";
    if (changed) ++generation;
  }

  /// Geometry of a homography-rectified pair: assumed disparity zero at infinity, focal scaled
  /// by the left homography's local x scale at the image centre.
  void homographyGeometry(const cv::Size& in) {
    RectifiedGeometry g;
    g.width = in.width;
    g.height = in.height;
    const cv::Point2d c((in.width - 1) / 2.0, (in.height - 1) / 2.0);
    auto apply = [&](const cv::Point2d& p) {
      const cv::Vec3d q = H_l * cv::Vec3d(p.x, p.y, 1);
      return cv::Point2d(q[0] / q[2], q[1] / q[2]);
    };
    const cv::Point2d c_rect = apply(c);
    const double sx = cv::norm(apply(c + cv::Point2d(1, 0)) - c_rect);
    const double sy = cv::norm(apply(c + cv::Point2d(0, 1)) - c_rect);
    const double f = params.focal_px > 0 ? params.focal_px : double(in.width);
    g.f_px = f * sx;
    g.fy_px = f * sy;
    g.cx_left = g.cx_right = c_rect.x;
    g.cy = c_rect.y;
    g.baseline_m = params.baseline_m > 0 ? params.baseline_m : 1.0;
    g.metric = params.focal_px > 0 && params.baseline_m > 0;
    geometry = g;
  }

  /// Estimate an uncalibrated rectification from the pooled matches; installs it on success.
  bool estimateUncalibrated(const cv::Size& size, std::string* why) {
    detail::Matches inl;
    cv::Matx33d F_new;
    const size_t n = pool.size();
    if (!detail::robustFundamental(pool, params.ransac_threshold_px, params.ransac_confidence,
                                   &F_new, &inl) ||
        int(inl.size()) < params.min_inliers) {
      std::ostringstream m;
      m << "only " << (n < 8 ? 0 : inl.size()) << " consistent feature matches (of " << n
        << ") over " << pooled_frames << " frame(s), need >= " << params.min_inliers;
      *why = m.str();
      return false;
    }
    {
      // Matches that one homography explains (a plane, or no parallax) leave F undetermined
      // (any epipole fits), and a rectification from it would be garbage off that plane. Scenes
      // with relief stay well below: 0.3-0.6 on the synthetic surfaces of the tests, pooled
      // frames of different scenes lower still.
      constexpr double kMaxHomographyShare = 0.9;
      const double share = detail::homographyShare(inl, params.ransac_threshold_px);
      if (share > kMaxHomographyShare) {
        std::ostringstream m;
        m << int(std::lround(100 * share)) << "% of the " << inl.size()
          << " matches fit one homography (a nearly planar scene or no parallax), so the "
             "epipolar geometry is ambiguous; more frames of a moving scene are needed";
        *why = m.str();
        return false;
      }
    }
    cv::Vec3d el, er;
    detail::epipoles(F_new, &el, &er);
    std::string method;
    switch (params.method) {
      case UncalibratedMethod::kHomography:
        method = "homography";
        break;
      case UncalibratedMethod::kPolar:
        method = "polar";
        break;
      case UncalibratedMethod::kAuto:
        method = std::min(detail::epipoleDistance(el, size), detail::epipoleDistance(er, size)) >
                         params.polar_auto_distance
                     ? "homography"
                     : "polar";
        break;
    }
    cv::Matx33d hl, hr;
    PolarRectification pol;
    std::string err;
    if (method == "homography") {
      if (!detail::homographyRectification(F_new, inl, size, &hl, &hr, &err)) {
        *why = "homography rectification failed: " + err;
        return false;
      }
    } else if (!detail::polarRectification(F_new, inl, size, &pol, &err)) {
      *why = "polar rectification failed: " + err;
      return false;
    }
    // Sanity: the inliers must come out row-aligned (guards against a degenerate F).
    std::vector<double> dy;
    dy.reserve(inl.size());
    for (size_t i = 0; i < inl.size(); ++i) {
      cv::Point2d a, b;
      if (method == "homography") {
        const cv::Vec3d qa = hl * cv::Vec3d(inl.left[i].x, inl.left[i].y, 1);
        const cv::Vec3d qb = hr * cv::Vec3d(inl.right[i].x, inl.right[i].y, 1);
        a = cv::Point2d(qa[0] / qa[2], qa[1] / qa[2]);
        b = cv::Point2d(qb[0] / qb[2], qb[1] / qb[2]);
      } else if (!pol.toRectified(true, inl.left[i], &a) ||
                 !pol.toRectified(false, inl.right[i], &b)) {
        continue;
      }
      dy.push_back(std::abs(a.y - b.y));
    }
    double med = 0, p90 = 0;
    detail::offsetStatistics(dy, &med, &p90);
    if (dy.size() < size_t(params.min_inliers) || med > 2.0 * params.ransac_threshold_px) {
      std::ostringstream m;
      m << "degenerate estimate: " << dy.size() << " inliers with median vertical offset " << med
        << " px after rectification";
      *why = m.str();
      return false;
    }
    // Install.
    F = F_new;
    uncal_method = method;
    uncal_size = size;
    if (method == "homography") {
      H_l = hl;
      H_r = hr;
      const int map_type = params.fixed_point_maps ? CV_16SC2 : CV_32FC1;
      cv::Mat eye = cv::Mat::eye(3, 3, CV_64F);
      // initUndistortRectifyMap with K = I, no distortion, R = H, P = I builds the inverse warp
      // of a homography as a remap table (the same remap path as calibrated mode).
      cv::initUndistortRectifyMap(eye, cv::Mat(), cv::Mat(H_l), eye, size, map_type, map_l1,
                                  map_l2);
      cv::initUndistortRectifyMap(eye, cv::Mat(), cv::Mat(H_r), eye, size, map_type, map_r1,
                                  map_r2);
      convertFastMaps();
      out_size = size;
      homographyGeometry(size);
    } else {
      polar = pol;
      detail::polarMaps(polar, true, map_l1, map_l2);
      detail::polarMaps(polar, false, map_r1, map_r2);
      convertFastMaps();
      out_size = cv::Size(polar.width, int(polar.theta.size()));
      RectifiedGeometry g;
      g.width = out_size.width;
      g.height = out_size.height;
      g.polar = true;
      g.metric = false;
      geometry = g;
    }
    have_uncal = true;
    active = method;
    ++generation;
    quality.estimated = true;
    return true;
  }

  bool mapToRect(bool left, const cv::Point2d& raw, cv::Point2d* rect) const {
    if (active == "pass_through") {
      *rect = raw;
      return true;
    }
    if (active == "homography") {
      const cv::Vec3d q = (left ? H_l : H_r) * cv::Vec3d(raw.x, raw.y, 1);
      if (!(std::abs(q[2]) > 0)) return false;
      *rect = cv::Point2d(q[0] / q[2], q[1] / q[2]);
      return true;
    }
    if (active == "polar") return polar.toRectified(left, raw, rect);
    if (active == "calibrated") {
      std::vector<cv::Point2d> in{raw}, out;
      const cv::Mat K(left ? K_l : K_r), R(left ? R_l : R_r), P(left ? P_l : P_r);
      const cv::Mat& D = left ? D_l : D_r;
      if (fisheye) {
        cv::fisheye::undistortPoints(in, out, K, D, R, P);
      } else {
        // Iterate to convergence: the default 5 iterations leave ~1e-3 px under strong distortion.
        cv::undistortPoints(
            in, out, K, D, R, P,
            cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 50, 1e-14));
      }
      *rect = out[0];
      return true;
    }
    return false;
  }

  bool mapToRaw(bool left, const cv::Point2d& rect, cv::Point2d* raw) const {
    if (active == "pass_through") {
      *raw = rect;
      return true;
    }
    if (active == "homography") {
      const cv::Vec3d q = (left ? H_l : H_r).inv() * cv::Vec3d(rect.x, rect.y, 1);
      if (!(std::abs(q[2]) > 0)) return false;
      *raw = cv::Point2d(q[0] / q[2], q[1] / q[2]);
      return true;
    }
    if (active == "polar") {
      *raw = polar.toRaw(left, rect.x, rect.y);
      return std::isfinite(raw->x);
    }
    if (active == "calibrated") {
      const cv::Matx34d& P = left ? P_l : P_r;
      const cv::Matx33d& R = left ? R_l : R_r;
      // Rectified pixel -> ray in the rectified frame -> raw camera frame -> distorted pixel.
      const double y = (rect.y - P(1, 2)) / P(1, 1);
      const double x = (rect.x - P(0, 2) - P(0, 1) * y) / P(0, 0);
      const cv::Vec3d ray = R.t() * cv::Vec3d(x, y, 1.0);
      if (!(ray[2] > 0)) return false;
      std::vector<cv::Point3d> obj{cv::Point3d(ray[0] / ray[2], ray[1] / ray[2], 1.0)};
      std::vector<cv::Point2d> img;
      const cv::Mat K(left ? K_l : K_r);
      const cv::Mat& D = left ? D_l : D_r;
      if (fisheye) {
        cv::fisheye::projectPoints(obj, img, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D);
      } else {
        cv::projectPoints(obj, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D, img);
      }
      *raw = img[0];
      return true;
    }
    return false;
  }

  // Call after every change of map_*: fills fast_* (a plain reference when map_* are
  // fixed-point already).
  void convertFastMaps() {
    auto convert = [](const cv::Mat& m1, const cv::Mat& m2, cv::Mat& f1, cv::Mat& f2) {
      if (m1.type() == CV_16SC2) {
        f1 = m1;
        f2 = m2;
      } else {
        cv::convertMaps(m1, m2, f1, f2, CV_16SC2, false);
      }
    };
    convert(map_l1, map_l2, fast_l1, fast_l2);
    convert(map_r1, map_r2, fast_r1, fast_r2);
  }

  void remapPair(const cv::Mat& lg, const cv::Mat& rg, const cv::Mat& lc, cv::Mat& olg,
                 cv::Mat& org, cv::Mat& olc) const {
    cv::remap(lg, olg, fast_l1, fast_l2, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    cv::remap(rg, org, fast_r1, fast_r2, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    if (lc.empty()) {
      olc.release();
    } else {
      cv::remap(lc, olc, fast_l1, fast_l2, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    }
  }

  // setAsyncQuality(): one measurement at a time on a background thread.
  bool async_quality = false;
  // setQualityDisparityRange(); min > max: not set.
  int quality_dmin = 0, quality_dmax = -1;
  std::future<RectificationQuality> pending_quality;
  int64_t pending_frame = 0;
  uint64_t pending_generation = 0;

  // Calibrated / pass-through: measure the rectified pair now, or start a background measurement.
  void measureQuality(const cv::Mat& left_rect, const cv::Mat& right_rect) {
    // The disparity range of the search: the caller's (the pipeline passes the matcher's), else
    // +- a quarter of the width.
    const bool range_set = quality_dmin <= quality_dmax;
    const int dmin = range_set ? quality_dmin : -left_rect.cols / 4;
    const int dmax = range_set ? quality_dmax : left_rect.cols / 4;
    if (!async_quality) {
      recordQuality(measureRowAlignmentPatches(left_rect, right_rect, dmin, dmax,
                                               params.quality_max_features));
      judgeDrift();
      return;
    }
    if (pending_quality.valid()) return;  // the previous one still runs: skip this one
    pending_frame = frame_index;
    pending_generation = generation;
    pending_quality = std::async(std::launch::async, [l = left_rect.clone(), r = right_rect.clone(),
                                                      dmin, dmax, n = params.quality_max_features] {
      lowerThisThreadsPriority();
      return measureRowAlignmentPatches(l, r, dmin, dmax, n);
    });
  }

  // Records a finished background measurement (wait: block until it is done; discard: drop it,
  // as after a change of calibration it describes the old one).
  void collectQuality(bool wait, bool discard = false) {
    if (!pending_quality.valid()) return;
    if (!wait && pending_quality.wait_for(std::chrono::seconds(0)) != std::future_status::ready) {
      return;
    }
    const RectificationQuality q = pending_quality.get();
    // A measurement of an earlier rectification (re-estimated since) says nothing about this one.
    if (discard || pending_generation != generation) return;
    const int64_t now = frame_index;
    frame_index = pending_frame;  // the frame that was measured
    recordQuality(q);
    frame_index = now;
    judgeDrift();
  }

  void recordQuality(RectificationQuality q) {
    q.frame_index = frame_index;
    q.method = active;
    q.estimated = params.mode != RectifyMode::kUncalibrated || have_uncal;
    q.warning = (q.valid && q.median_offset_px > params.quality_warn_px) || q.misaligned;
    if (q.warning && q.message.empty()) {
      std::ostringstream m;
      m << "rectification residual: median vertical offset " << q.median_offset_px << " px exceeds "
        << params.quality_warn_px << " px (check the calibration)";
      q.message = m.str();
    }
    quality = q;
    if (q.valid && q.row_offset_matches >= params.row_correction_min_matches &&
        (active == "calibrated" || active == "pass_through")) {
      have_row_model = true;
      row_model = q.row_offset;
      row_generation = generation;
    }
  }

  // Calibrated / pass-through, after the quality measure (which sees the uncorrected pair): the
  // right view's rows shifted by the latest fitted offset plane of this rectification.
  void correctRows(cv::Mat& right_rect) {
    if (!rowCorrectionApplies(right_rect.size())) return;
    shiftRows(right_rect, row_model, row_shifted, row_map_x, row_map_y, row_map_model);
    row_shifted.copyTo(right_rect);
  }
  // Whether the right view of this rectification (of @p size) gets its rows shifted: the
  // correction is on, fitted for this rectification, and reaches row_correction_min_px at an
  // image corner.
  bool rowCorrectionApplies(const cv::Size& size) const {
    if (!params.row_correction || !have_row_model || row_generation != generation) return false;
    const cv::Vec3d& m = row_model;
    const double w = size.width - 1, h = size.height - 1;
    const double corner = std::max({std::abs(m[0]), std::abs(m[0] + m[1] * w),
                                    std::abs(m[0] + m[2] * h), std::abs(m[0] + m[1] * w + m[2] * h)});
    return corner >= params.row_correction_min_px;
  }

  bool measureNow() const {
    return params.quality_stride > 0 && frame_index % params.quality_stride == 0;
  }

  bool rectifyUncalibrated(const cv::Mat& lg, const cv::Mat& rg, const cv::Mat& lc, cv::Mat& olg,
                           cv::Mat& org, cv::Mat& olc, std::string* error) {
    const cv::Size size = lg.size();
    if (have_uncal && size != uncal_size) dropUncalibrated();
    const bool collecting = state == UncalState::kCollecting;
    detail::Matches m;
    if (collecting) detail::siftMatches(lg, rg, params.sift_features, params.ratio_test, &m);
    if (collecting) {
      // Cap the pool (oldest first) so that estimation cost stays bounded.
      const size_t kMaxPool = 20000;
      pool.append(m);
      if (pool.size() > kMaxPool) {
        const long drop = long(pool.size() - kMaxPool);
        pool.left.erase(pool.left.begin(), pool.left.begin() + drop);
        pool.right.erase(pool.right.begin(), pool.right.begin() + drop);
      }
      ++pooled_frames;
      const bool complete = pooled_frames >= params.estimation_frames;
      if (!have_uncal || complete) {
        std::string why;
        if (estimateUncalibrated(size, &why)) {
          if (complete) {
            state = UncalState::kFrozen;
            pool = detail::Matches();
          }
        } else {
          last_estimation_error = why;
          if (!have_uncal) {
            RectificationQuality q;
            q.message = "rectification could not be estimated: " + why;
            recordQuality(q);
            quality.estimated = false;
            return fail(error, q.message);
          }
        }
      }
    }
    remapPair(lg, rg, lc, olg, org, olc);
    if (measureNow() && !collecting) {
      // Frozen estimate: the patch measure on the rectified pair (in the background for a live
      // caller), judged for drift when it is recorded (judgeDrift).
      measureQuality(olg, org);
    } else if (measureNow()) {
      // While pooling, this frame's SIFT matches are at hand: their residual after rectification.
      RectificationQuality q;
      detail::Matches inl;
      cv::Matx33d F_frame;
      if (detail::robustFundamental(m, params.ransac_threshold_px, 0.999, &F_frame, &inl)) {
        std::vector<double> dy;
        for (size_t i = 0; i < inl.size(); ++i) {
          cv::Point2d a, b;
          if (mapToRect(true, inl.left[i], &a) && mapToRect(false, inl.right[i], &b)) {
            dy.push_back(std::abs(a.y - b.y));
          }
        }
        if (dy.size() >= 8) {
          detail::offsetStatistics(dy, &q.median_offset_px, &q.p90_offset_px);
          q.num_matches = int(dy.size());
          q.valid = true;
        }
      }
      if (!q.valid) q.message = "too few feature matches to measure the rectification";
      recordQuality(q);
      judgeDrift();
    }
    return true;
  }

  // Uncalibrated, frozen estimate: count measurements above reestimate_threshold_px (or with rows
  // misaligned beyond the patch search) and start pooling afresh after reestimate_after of them
  // in a row. The current rectification stays in use until a new one is found.
  void judgeDrift() {
    if (params.mode != RectifyMode::kUncalibrated || state != UncalState::kFrozen ||
        !(params.reestimate_threshold_px > 0)) {
      return;
    }
    const RectificationQuality& q = quality;
    if (!q.valid && !q.misaligned) return;
    const bool bad = q.misaligned || q.median_offset_px > params.reestimate_threshold_px;
    bad_measurements = bad ? bad_measurements + 1 : 0;
    if (bad_measurements >= params.reestimate_after) {
      state = UncalState::kCollecting;
      pool = detail::Matches();
      pooled_frames = 0;
      bad_measurements = 0;
      quality.message = "rectification drifted: re-estimating";
    }
  }
};

StereoRectifier::StereoRectifier(const RectifyParams& params) : impl_(new Impl) {
  const std::string e = params.validate();
  if (!e.empty()) throw std::invalid_argument(e);
  impl_->params = params;
}

StereoRectifier::~StereoRectifier() = default;

void StereoRectifier::setParams(const RectifyParams& params) {
  const std::string e = params.validate();
  if (!e.empty()) throw std::invalid_argument(e);
  RectifyParams a = impl_->params, b = params;
  // Quality settings do not change the rectification.
  a.quality_stride = b.quality_stride = 0;
  a.quality_warn_px = b.quality_warn_px = 1;
  a.quality_max_features = b.quality_max_features = 0;
  const bool same =
      a.mode == b.mode && a.alpha == b.alpha && a.zero_disparity == b.zero_disparity &&
      a.output_width_px == b.output_width_px && a.output_height_px == b.output_height_px &&
      a.output_scale_x == b.output_scale_x && a.output_scale_y == b.output_scale_y &&
      a.fixed_point_maps == b.fixed_point_maps && a.method == b.method &&
      a.sift_features == b.sift_features && a.ratio_test == b.ratio_test &&
      a.ransac_threshold_px == b.ransac_threshold_px &&
      a.ransac_confidence == b.ransac_confidence && a.min_inliers == b.min_inliers &&
      a.estimation_frames == b.estimation_frames &&
      a.polar_auto_distance == b.polar_auto_distance && a.focal_px == b.focal_px &&
      a.baseline_m == b.baseline_m;
  impl_->params = params;
  if (!same) {
    impl_->maps_valid = false;
    impl_->dropUncalibrated();
    impl_->active.clear();
  }
}

const RectifyParams& StereoRectifier::params() const { return impl_->params; }

std::string StereoRectifier::setCalibration(const StereoCalibration& calibration) {
  const std::string e = calibration.validate();
  if (!e.empty()) return e;
  Impl& s = *impl_;
  if (s.has_calib && s.calib == calibration) return {};
  s.collectQuality(true, true);  // a measurement of the old calibration is not reported
  const StereoCalibration old = s.calib;
  const bool had = s.has_calib;
  s.calib = calibration;
  s.has_calib = true;
  s.maps_valid = false;
  if (s.params.mode == RectifyMode::kCalibrated) {
    const cv::Size in = calibration.left.binnedSize();
    if (in.area() > 0) {
      std::string err;
      if (!s.buildCalibratedMaps(in, &err)) {
        s.calib = old;
        s.has_calib = had;
        s.maps_valid = false;
        return err;
      }
    } else {
      ++s.generation;
    }
  } else {
    ++s.generation;
  }
  return {};
}

bool StereoRectifier::hasCalibration() const { return impl_->has_calib; }

bool StereoRectifier::rectify(const cv::Mat& left_gray, const cv::Mat& right_gray,
                              const cv::Mat& left_bgr, cv::Mat& left_rect_gray,
                              cv::Mat& right_rect_gray, cv::Mat& left_rect_bgr,
                              std::string* error) {
  Impl& s = *impl_;
  if (left_gray.empty() || right_gray.empty()) return fail(error, "rectify: empty input image");
  if (left_gray.type() != CV_8UC1 || right_gray.type() != CV_8UC1) {
    return fail(error, "rectify: gray images must be CV_8UC1");
  }
  if (left_gray.size() != right_gray.size()) {
    return fail(error, "rectify: left image is " + sizeStr(left_gray.size()) + ", right is " +
                           sizeStr(right_gray.size()));
  }
  if (!left_bgr.empty() && (left_bgr.type() != CV_8UC3 || left_bgr.size() != left_gray.size())) {
    return fail(error, "rectify: left colour image must be CV_8UC3 of the gray image's size");
  }
  const cv::Size in = left_gray.size();
  bool ok = true;
  s.collectQuality(false);
  try {
    switch (s.params.mode) {
      case RectifyMode::kPassThrough: {
        s.passThroughGeometry(in);
        left_gray.copyTo(left_rect_gray);
        right_gray.copyTo(right_rect_gray);
        if (left_bgr.empty()) {
          left_rect_bgr.release();
        } else {
          left_bgr.copyTo(left_rect_bgr);
        }
        if (s.measureNow()) s.measureQuality(left_rect_gray, right_rect_gray);
        s.correctRows(right_rect_gray);
        break;
      }
      case RectifyMode::kCalibrated: {
        if (!s.has_calib) {
          ok = fail(error, "rectify: calibrated mode needs a calibration (none set)");
          break;
        }
        const cv::Size expected = s.calib.left.binnedSize();
        if (expected.area() > 0 && expected != in) {
          ok = fail(error, "rectify: images are " + sizeStr(in) + " but the calibration expects " +
                               sizeStr(expected) + " (width/binning_x, height/binning_y)");
          break;
        }
        if (!s.maps_valid || s.maps_in_size != in) {
          if (!s.buildCalibratedMaps(in, error)) {
            ok = false;
            break;
          }
        }
        s.remapPair(left_gray, right_gray, left_bgr, left_rect_gray, right_rect_gray,
                    left_rect_bgr);
        if (s.measureNow()) s.measureQuality(left_rect_gray, right_rect_gray);
        s.correctRows(right_rect_gray);
        break;
      }
      case RectifyMode::kUncalibrated:
        ok = s.rectifyUncalibrated(left_gray, right_gray, left_bgr, left_rect_gray, right_rect_gray,
                                   left_rect_bgr, error);
        break;
    }
  } catch (const std::exception& ex) {
    ok = fail(error, std::string("rectify: ") + ex.what());
  }
  ++s.frame_index;
  return ok;
}

bool StereoRectifier::rectifyImage(bool left, const cv::Mat& raw, cv::Mat& rectified,
                                   int interpolation, std::string* error) const {
  const Impl& s = *impl_;
  // The right camera's images get the rows shifted as the matched right view does (calibrated
  // and pass-through modes), with the caller's interpolation.
  auto correct = [&](cv::Mat& img) {
    if (left || !s.rowCorrectionApplies(img.size())) return;
    cv::Mat src = img.clone(), map_x, map_y;
    cv::Vec3d map_model;
    shiftRows(src, s.row_model, img, map_x, map_y, map_model, interpolation);
  };
  if (s.active == "pass_through") {
    raw.copyTo(rectified);
    correct(rectified);
    return true;
  }
  const bool have = (s.active == "calibrated" && s.maps_valid) ||
                    ((s.active == "homography" || s.active == "polar") && s.have_uncal);
  if (!have) return fail(error, "rectifyImage: no rectification available yet");
  const cv::Size expected = s.active == "calibrated" ? s.maps_in_size : s.uncal_size;
  if (raw.size() != expected) {
    return fail(
        error, "rectifyImage: image is " + sizeStr(raw.size()) + ", expected " + sizeStr(expected));
  }
  cv::remap(raw, rectified, left ? s.map_l1 : s.map_r1, left ? s.map_l2 : s.map_r2, interpolation,
            cv::BORDER_CONSTANT);
  if (s.active == "calibrated") correct(rectified);
  return true;
}

bool StereoRectifier::rawToRectified(bool left, const cv::Point2d& raw, cv::Point2d* rect) const {
  return impl_->mapToRect(left, raw, rect);
}

bool StereoRectifier::rectifiedToRaw(bool left, const cv::Point2d& rect, cv::Point2d* raw) const {
  return impl_->mapToRaw(left, rect, raw);
}

const RectifiedGeometry& StereoRectifier::geometry() const { return impl_->geometry; }
RectificationQuality StereoRectifier::quality() const { return impl_->quality; }
uint64_t StereoRectifier::generation() const { return impl_->generation; }
std::string StereoRectifier::activeMethod() const { return impl_->active; }

bool StereoRectifier::homographies(cv::Matx33d* left, cv::Matx33d* right) const {
  if (impl_->active != "homography") return false;
  *left = impl_->H_l;
  *right = impl_->H_r;
  return true;
}

const PolarRectification* StereoRectifier::polar() const {
  return impl_->active == "polar" ? &impl_->polar : nullptr;
}

bool StereoRectifier::fundamentalMatrix(cv::Matx33d* F) const {
  if (!impl_->have_uncal) return false;
  *F = impl_->F;
  return true;
}

void StereoRectifier::setQualityDisparityRange(int min_disparity, int max_disparity) {
  impl_->quality_dmin = min_disparity;
  impl_->quality_dmax = max_disparity;
}

void StereoRectifier::setAsyncQuality(bool async) {
  impl_->collectQuality(true);
  impl_->async_quality = async;
}

void StereoRectifier::reset() {
  impl_->collectQuality(true, true);
  impl_->dropUncalibrated();
  if (impl_->active == "homography" || impl_->active == "polar") impl_->active.clear();
  impl_->frame_index = 0;
  impl_->quality = RectificationQuality();
}

}  // namespace endo_stereo
