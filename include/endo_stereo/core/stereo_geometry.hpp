/**
 * @file stereo_geometry.hpp
 * @brief Calibration types (the ROS CameraInfo model without ROS) and the rectified geometry.
 *
 * ROS-free: the nodelet converts sensor_msgs/CameraInfo to CameraCalibration; the CLI loads the
 * same struct from camera_info YAML or OpenCV stereo YAML (calibration_io.hpp).
 */
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace endo_stereo {

/// One camera, in the sensor_msgs/CameraInfo model. Units: px for K and P, metres for P's Tx
/// (P(0,3) = -fx' * baseline for the right camera).
struct CameraCalibration {
  int width = 0;                   ///< image width, px (full resolution, before binning)
  int height = 0;                  ///< image height, px
  std::string distortion_model;    ///< "plumb_bob", "rational_polynomial" or "" (no distortion)
  std::vector<double> D;           ///< distortion coefficients (5 or 8 for the models above)
  cv::Matx33d K = cv::Matx33d::zeros();  ///< intrinsics of the raw image
  cv::Matx33d R = cv::Matx33d::eye();    ///< rectification rotation
  cv::Matx34d P = cv::Matx34d::zeros();  ///< projection of the rectified image; all-zero = not given
  int binning_x = 1;               ///< 0 or 1 = none
  int binning_y = 1;
  cv::Rect roi;                    ///< empty = full image
  std::string frame_id;            ///< optical frame of this camera

  /// @return empty when usable, else a message naming the field (e.g. "left.K: fx must be > 0").
  std::string validate(const std::string& name) const;
  bool hasProjection() const { return P(0, 0) != 0.0; }
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
  std::string validate() const;
};

/// Geometry of a rectified pair, as needed to turn disparity into depth. Z = f * B / (d - doffs),
/// with doffs = cx_left - cx_right (verged principal points, applied once).
struct RectifiedGeometry {
  int width = 0;
  int height = 0;
  double f_px = 0.0;        ///< rectified focal length, px
  double cx_left = 0.0;     ///< principal point of the rectified left image, px
  double cx_right = 0.0;    ///< principal point of the rectified right image, px
  double cy = 0.0;
  double baseline_m = 0.0;  ///< > 0; meaningful only when metric
  bool metric = false;      ///< false: uncalibrated without focal/baseline: disparity only
  std::string frame_id;     ///< left rectified optical frame
  double doffs() const { return cx_left - cx_right; }
};

}  // namespace endo_stereo
