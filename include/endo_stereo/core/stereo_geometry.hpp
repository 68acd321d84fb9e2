/**
 * @file stereo_geometry.hpp
 * @brief Calibration types (the ROS CameraInfo model without ROS) and the rectified geometry.
 *
 * ROS-free: the nodelet converts sensor_msgs/CameraInfo to CameraCalibration; the CLI loads the
 * same struct from camera_info YAML or OpenCV stereo YAML (calibration_io.hpp).
 */
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace endo_stereo {

/// One camera, in the sensor_msgs/CameraInfo model. Units: px for K and P, metres for P's Tx
/// (P(0,3) = -fx' * baseline for the right camera).
struct CameraCalibration {
  int width = 0;   ///< image width, px (full resolution, before binning)
  int height = 0;  ///< image height, px
  /// "plumb_bob" (4 or 5 coefficients k1 k2 p1 p2 [k3]), "rational_polynomial" (8), "equidistant"
  /// (4, fisheye k1..k4), or "" with D empty or all zero (no distortion). Up to 14 OpenCV
  /// coefficients are accepted under "plumb_bob"/"rational_polynomial" as OpenCV orders them.
  std::string distortion_model;
  std::vector<double> D;                 ///< distortion coefficients in the OpenCV order
  cv::Matx33d K = cv::Matx33d::zeros();  ///< intrinsics of the raw image
  cv::Matx33d R = cv::Matx33d::eye();    ///< rectification rotation
  cv::Matx34d P =
      cv::Matx34d::zeros();  ///< projection of the rectified image; all-zero = not given
  int binning_x = 1;         ///< 0 or 1 = none; images are (roi or full) size / binning
  int binning_y = 1;
  cv::Rect roi;          ///< in full-resolution px; empty = full image
  std::string frame_id;  ///< optical frame of this camera

  /// @return empty when usable, else a message naming the field (e.g. "left.K: fx must be > 0").
  /// Sizes: both 0 (unknown: taken from the first images) or both > 0.
  std::string validate(const std::string& name) const;
  bool hasProjection() const { return P(0, 0) != 0.0; }
  /// Size of the images this camera delivers: (roi or full size) / binning, px (0x0 if unknown).
  cv::Size binnedSize() const;
  /// K adjusted for ROI and binning (image_geometry semantics: cx' = (cx - roi.x) / binning_x).
  cv::Matx33d binnedK() const;
  /// P adjusted for ROI and binning, as binnedK() (Tx scales with fx).
  cv::Matx34d binnedP() const;
  /// Value equality of every field (used to cache rectification maps).
  bool operator==(const CameraCalibration& o) const;
  bool operator!=(const CameraCalibration& o) const { return !(*this == o); }
};

/// A stereo pair's calibration. When P is not given in either camera, R_right_left / T_right_left
/// (the pose of the left camera in the right camera's frame, OpenCV stereoCalibrate's R and T,
/// metres) let the rectifier compute its own rectification.
struct StereoCalibration {
  CameraCalibration left;
  CameraCalibration right;
  cv::Matx33d R_right_left = cv::Matx33d::eye();
  cv::Vec3d T_right_left = cv::Vec3d(0, 0, 0);
  bool has_extrinsics = false;
  /// @return empty when usable, else a message naming the field ("left.K: fx must be > 0",
  /// "T_right_left: baseline must be > 0", "right.width: ... differs from left").
  std::string validate() const;
  bool operator==(const StereoCalibration& o) const;
  bool operator!=(const StereoCalibration& o) const { return !(*this == o); }
};

/// Geometry of a rectified pair, as needed to turn disparity into depth. Z = f * B / (d - doffs),
/// with doffs = cx_left - cx_right (verged principal points, applied once).
///
/// Non-metric geometry (metric == false: uncalibrated without focal_px/baseline_m): f_px is the
/// supplied or an assumed focal length (the image width) and baseline_m is 1, so a cloud built
/// from it is in units of the baseline and only correct up to a projective ambiguity.
/// A polar-rectified pair (polar == true) has no such geometry: its rows are epipolar lines and its
/// columns distances from the epipole, so disparity there does not map to depth by this formula.
struct RectifiedGeometry {
  int width = 0;          ///< rectified image width, px
  int height = 0;         ///< rectified image height, px
  double f_px = 0.0;      ///< rectified focal length (horizontal, fx), px
  double cx_left = 0.0;   ///< principal point of the rectified left image, px
  double cx_right = 0.0;  ///< principal point of the rectified right image, px
  double cy = 0.0;
  double baseline_m = 0.0;  ///< > 0; meaningful only when metric
  bool metric = false;      ///< false: uncalibrated without focal/baseline: disparity only
  std::string frame_id;     ///< left rectified optical frame
  /// Vertical rectified focal length (fy), px; 0 = same as f_px. Differs from f_px only for
  /// non-square pixels (e.g. a single field of interlaced video rectified to its own size).
  double fy_px = 0.0;
  bool polar = false;  ///< polar rectification: no depth from disparity (see above)
  /// Rotation from the raw left optical frame to the left rectified optical frame (calibrated
  /// modes; identity otherwise): X_rect = R_rect_raw_left * X_raw.
  cv::Matx33d R_rect_raw_left = cv::Matx33d::eye();
  double doffs() const { return cx_left - cx_right; }
  double fyOrF() const { return fy_px > 0.0 ? fy_px : f_px; }
  /// Depth for disparity @p d (px): f_px * baseline_m / (d - doffs()); NaN when d <= doffs().
  double depthFromDisparity(double d) const;
};

}  // namespace endo_stereo
