#include "endo_stereo/core/stereo_geometry.hpp"

#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>

namespace endo_stereo {

namespace {

template <int R, int C>
bool allFinite(const cv::Matx<double, R, C>& m) {
  for (int i = 0; i < R * C; ++i) {
    if (!std::isfinite(m.val[i])) return false;
  }
  return true;
}

template <int R, int C>
bool equalValues(const cv::Matx<double, R, C>& a, const cv::Matx<double, R, C>& b) {
  for (int i = 0; i < R * C; ++i) {
    // Bitwise-equal semantics except that NaN never validates anyway; plain == is enough.
    if (a.val[i] != b.val[i]) return false;
  }
  return true;
}

int effectiveBinning(int b) { return b <= 0 ? 1 : b; }

/// Larger images are refused (a corrupt file must not make the rectifier allocate gigabytes).
constexpr int kMaxImageSidePx = 32768;

}  // namespace

std::string CameraCalibration::validate(const std::string& name) const {
  std::ostringstream msg;
  if (width < 0 || height < 0 || (width == 0) != (height == 0)) {
    msg << name << ".width/height: must both be > 0 (or both 0 = taken from the images), got "
        << width << "x" << height;
    return msg.str();
  }
  if (width > kMaxImageSidePx || height > kMaxImageSidePx) {
    msg << name << ".width/height: must be <= " << kMaxImageSidePx << ", got " << width << "x"
        << height;
    return msg.str();
  }
  if (binning_x < 0 || binning_y < 0 || binning_x > 64 || binning_y > 64) {
    msg << name << ".binning_x/binning_y: must be in [0, 64], got " << binning_x << ", "
        << binning_y;
    return msg.str();
  }
  if (!allFinite(K)) return name + ".K: contains NaN or infinity";
  if (!(K(0, 0) > 0.0)) {
    msg << name << ".K: fx must be > 0, got " << K(0, 0);
    return msg.str();
  }
  if (!(K(1, 1) > 0.0)) {
    msg << name << ".K: fy must be > 0, got " << K(1, 1);
    return msg.str();
  }
  if (K(2, 0) != 0.0 || K(2, 1) != 0.0 || std::abs(K(2, 2) - 1.0) > 1e-9) {
    return name + ".K: last row must be [0 0 1]";
  }
  for (double d : D) {
    if (!std::isfinite(d)) return name + ".D: contains NaN or infinity";
  }
  bool any_distortion = false;
  for (double d : D) any_distortion = any_distortion || d != 0.0;
  const size_t n = D.size();
  if (distortion_model == "plumb_bob" || distortion_model == "rational_polynomial") {
    if (n != 0 && n != 4 && n != 5 && n != 8 && n != 12 && n != 14) {
      msg << name << ".D: " << distortion_model << " needs 4, 5, 8, 12 or 14 coefficients, got "
          << n;
      return msg.str();
    }
  } else if (distortion_model == "equidistant" || distortion_model == "fisheye") {
    if (n != 4) {
      msg << name << ".D: equidistant needs 4 coefficients, got " << n;
      return msg.str();
    }
  } else if (distortion_model.empty() || distortion_model == "none") {
    if (any_distortion) {
      return name + ".distortion_model: empty but D has non-zero coefficients";
    }
  } else {
    return name + ".distortion_model: unsupported '" + distortion_model +
           "' (accepted: plumb_bob, rational_polynomial, equidistant, none)";
  }
  if (!allFinite(R)) return name + ".R: contains NaN or infinity";
  {
    const cv::Matx33d should_be_eye = R * R.t();
    double err = cv::norm(should_be_eye - cv::Matx33d::eye(), cv::NORM_INF);
    if (err > 1e-3 || cv::determinant(R) <= 0.0) {
      msg << name << ".R: not a rotation (|R R^T - I| = " << err << ", det = " << cv::determinant(R)
          << ")";
      return msg.str();
    }
  }
  if (!allFinite(P)) return name + ".P: contains NaN or infinity";
  if (hasProjection()) {
    if (!(P(0, 0) > 0.0) || !(P(1, 1) > 0.0)) {
      msg << name << ".P: fx and fy must be > 0, got " << P(0, 0) << ", " << P(1, 1);
      return msg.str();
    }
  } else {
    for (int i = 0; i < 12; ++i) {
      if (P.val[i] != 0.0) return name + ".P: fx is 0 but other entries are not (not given?)";
    }
  }
  if (roi.x < 0 || roi.y < 0 || roi.width < 0 || roi.height < 0 || roi.x > kMaxImageSidePx ||
      roi.y > kMaxImageSidePx || roi.width > kMaxImageSidePx || roi.height > kMaxImageSidePx) {
    return name + ".roi: offsets and sizes must be in [0, " + std::to_string(kMaxImageSidePx) + "]";
  }
  // One row/column of slack: an odd field's ROI (preprocess.hpp) may end one row past the image.
  if (width > 0 && (int64_t(roi.x) + roi.width > int64_t(width) + 1 ||
                    int64_t(roi.y) + roi.height > int64_t(height) + 1)) {
    msg << name << ".roi: " << roi << " exceeds the image " << width << "x" << height;
    return msg.str();
  }
  return {};
}

cv::Size CameraCalibration::binnedSize() const {
  const int bx = effectiveBinning(binning_x), by = effectiveBinning(binning_y);
  const bool has_roi = roi.width > 0 && roi.height > 0;
  const int w = has_roi ? roi.width : width;
  const int h = has_roi ? roi.height : height;
  return cv::Size(w / bx, h / by);
}

cv::Matx33d CameraCalibration::binnedK() const {
  const double bx = effectiveBinning(binning_x), by = effectiveBinning(binning_y);
  cv::Matx33d k = K;
  k(0, 0) /= bx;
  k(0, 1) /= bx;
  k(0, 2) = (k(0, 2) - roi.x) / bx;
  k(1, 1) /= by;
  k(1, 2) = (k(1, 2) - roi.y) / by;
  return k;
}

cv::Matx34d CameraCalibration::binnedP() const {
  const double bx = effectiveBinning(binning_x), by = effectiveBinning(binning_y);
  cv::Matx34d p = P;
  // Row 0 of P is fx*[1 0 cx/fx Tx/fx]-like: shifting by roi.x and dividing by bx must act on the
  // homogeneous row, hence the third-row subtraction (which is [0 0 1 0] for a CameraInfo P).
  for (int c = 0; c < 4; ++c) {
    p(0, c) = (P(0, c) - roi.x * P(2, c)) / bx;
    p(1, c) = (P(1, c) - roi.y * P(2, c)) / by;
  }
  return p;
}

bool CameraCalibration::operator==(const CameraCalibration& o) const {
  return width == o.width && height == o.height && distortion_model == o.distortion_model &&
         D == o.D && equalValues(K, o.K) && equalValues(R, o.R) && equalValues(P, o.P) &&
         effectiveBinning(binning_x) == effectiveBinning(o.binning_x) &&
         effectiveBinning(binning_y) == effectiveBinning(o.binning_y) && roi == o.roi &&
         frame_id == o.frame_id;
}

std::string StereoCalibration::validate() const {
  std::string e = left.validate("left");
  if (!e.empty()) return e;
  e = right.validate("right");
  if (!e.empty()) return e;
  std::ostringstream msg;
  if (left.width != right.width || left.height != right.height) {
    msg << "right.width/height: " << right.width << "x" << right.height << " differs from left "
        << left.width << "x" << left.height;
    return msg.str();
  }
  if (left.binnedSize() != right.binnedSize()) {
    msg << "right.binning/roi: binned size " << right.binnedSize() << " differs from left "
        << left.binnedSize();
    return msg.str();
  }
  if (left.hasProjection() != right.hasProjection()) {
    return std::string(left.hasProjection() ? "right" : "left") + ".P: given for one camera only";
  }
  if (left.hasProjection()) {
    const cv::Matx34d pl = left.P, pr = right.P;
    const double tx = -pr(0, 3) / pr(0, 0);
    if (!(std::abs(tx) > 0.0)) return "right.P: baseline (-P[0,3]/P[0,0]) must be > 0, got 0";
    if (tx < 0.0) {
      msg << "right.P: baseline (-P[0,3]/P[0,0]) must be > 0, got " << tx
          << " m (left and right swapped?)";
      return msg.str();
    }
    if (std::abs(pr(1, 3)) > 1e-9 * std::abs(pr(0, 3)) + 1e-12) {
      return "right.P: P[1,3] must be 0 (vertical stereo is not supported)";
    }
    if (std::abs(pl(0, 0) - pr(0, 0)) > 1e-6 * pl(0, 0) ||
        std::abs(pl(1, 1) - pr(1, 1)) > 1e-6 * pl(1, 1)) {
      return "right.P: focal lengths differ from left.P (not a rectified pair)";
    }
    if (std::abs(pl(1, 2) - pr(1, 2)) > 1e-3) {
      msg << "right.P: cy " << pr(1, 2) << " differs from left.P cy " << pl(1, 2)
          << " (rows would not align)";
      return msg.str();
    }
  } else if (!has_extrinsics) {
    return "T_right_left: no projection matrices (P) and no extrinsics (R, T) given";
  }
  if (has_extrinsics) {
    if (!allFinite(R_right_left)) return "R_right_left: contains NaN or infinity";
    const double err = cv::norm(R_right_left * R_right_left.t() - cv::Matx33d::eye(), cv::NORM_INF);
    if (err > 1e-3 || cv::determinant(R_right_left) <= 0.0) {
      msg << "R_right_left: not a rotation (|R R^T - I| = " << err << ")";
      return msg.str();
    }
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(T_right_left[i])) return "T_right_left: contains NaN or infinity";
    }
    if (!(cv::norm(T_right_left) > 0.0)) return "T_right_left: baseline must be > 0, got 0";
  }
  return {};
}

bool StereoCalibration::operator==(const StereoCalibration& o) const {
  return left == o.left && right == o.right && has_extrinsics == o.has_extrinsics &&
         equalValues(R_right_left, o.R_right_left) && T_right_left == o.T_right_left;
}

double RectifiedGeometry::depthFromDisparity(double d) const {
  const double denom = d - doffs();
  if (!(denom > 0.0) || !(f_px > 0.0) || polar) return std::numeric_limits<double>::quiet_NaN();
  return f_px * baseline_m / denom;
}

}  // namespace endo_stereo
