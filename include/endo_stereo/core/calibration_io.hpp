/**
 * @file calibration_io.hpp
 * @brief Loading and saving stereo calibrations (ROS-free, yaml-cpp and OpenCV FileStorage).
 *
 * Formats:
 * - ROS camera_info YAML (the camera_calibration_parsers format, one file per camera):
 *   image_width, image_height, camera_name, camera_matrix{rows,cols,data}, distortion_model,
 *   distortion_coefficients, rectification_matrix, projection_matrix (binning_x/y and roi are
 *   read when present).
 * - OpenCV stereo calibration (cv::FileStorage YAML or XML, as samples/cpp/stereo_calib.cpp
 *   writes it): M1 D1 M2 D2 R T, optionally R1 R2 P1 P2 (Q is ignored, it follows from P1/P2).
 *   R, T map left-camera points into the right camera (x_r = R x_l + T). Image size from
 *   image_width/image_height, width/height or image_size/imageSize when present, else 0 (taken
 *   from the first images). T is in the file's unit; translation_scale converts it to metres.
 * - Dataset formats used by the tests: scikit-surgery's OpenCV-matrix XML blocks
 *   (ucl_rectify_golden, which OpenCV 4.6 FileStorage rejects; the <rows>, <cols>, <data> blocks
 *   are parsed as text) and plain-text matrices (hamlyn_heart_phantom: 3x3 K, a distortion row,
 *   a 4x4 left-to-right transform in mm).
 *
 * Every loader validates the result (StereoCalibration::validate()) and reports errors that name
 * the file and the field. All functions are reentrant.
 */
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {

/// Load one camera from a ROS camera_info YAML file. @return false with a message naming the
/// file and field (missing key, wrong matrix size, non-numeric data).
bool loadCameraInfoYaml(const std::string& path, CameraCalibration& out, std::string* error);

/// Parse camera_info YAML text (same as loadCameraInfoYaml(), for in-memory content).
bool parseCameraInfoYaml(const std::string& text, CameraCalibration& out, std::string* error);

/// Write one camera as ROS camera_info YAML (readable by camera_calibration_parsers).
/// plumb_bob with 4 coefficients is padded to 5. @return false with a message on I/O failure.
bool saveCameraInfoYaml(const std::string& path, const CameraCalibration& calibration,
                        const std::string& camera_name, std::string* error);

/// The camera_info YAML text saveCameraInfoYaml() writes.
std::string cameraInfoYamlString(const CameraCalibration& calibration,
                                 const std::string& camera_name);

/// Load a stereo pair from two camera_info YAML files. The baseline is taken from the right
/// camera's P (Tx = -fx * B). Validated; @return false with a message naming the field.
bool loadStereoCameraInfoYaml(const std::string& left_path, const std::string& right_path,
                              StereoCalibration& out, std::string* error);

/// Load an OpenCV stereo calibration (see the file comment). Sets has_extrinsics; sets P/R of
/// both cameras when R1 R2 P1 P2 are present (P2's Tx converted with translation_scale).
bool loadOpenCvStereoYaml(const std::string& path, StereoCalibration& out, std::string* error,
                          double translation_scale = 1.0);

/// Either format, by content: one path = OpenCV stereo file; two paths (comma-separated in
/// @p spec, "left.yaml,right.yaml") = a camera_info YAML pair. For the CLI's --calib.
bool loadStereoCalibration(const std::string& spec, StereoCalibration& out, std::string* error);

/// Parse one OpenCV-matrix XML block file (<rows>, <cols>, <data>) as CV_64F, without
/// cv::FileStorage. @return false with a message naming the file and the missing block.
bool loadOpenCvXmlMatrix(const std::string& path, cv::Mat& out, std::string* error);

/**
 * scikit-surgery XML calibration directory (ucl_rectify_golden): calib.left.intrinsic.xml,
 * calib.left.distortion.xml, calib.right.intrinsic.xml, calib.right.distortion.xml,
 * calib.r2l.rotation.xml, calib.r2l.translation.xml (R and T as cv::stereoRectify takes them,
 * T in mm, converted to metres). No P: the rectifier computes its own rectification.
 */
bool loadSksurgeryXmlCalibration(const std::string& dir, int width, int height,
                                 StereoCalibration& out, std::string* error);

/**
 * Plain-text calibration directory (hamlyn_heart_phantom): calib.left.intrinsic.txt,
 * calib.right.intrinsic.txt (3x3), calib.{left,right}.distortion.txt (a row of coefficients),
 * calib.l2r.4x4 (left-to-right rigid transform, x_r = R x_l + t, t in mm, converted to metres).
 */
bool loadTextStereoCalibration(const std::string& dir, int width, int height,
                               StereoCalibration& out, std::string* error);

}  // namespace endo_stereo
