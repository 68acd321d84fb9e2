/**
 * @file conversions.hpp
 * @brief Free functions between ROS messages and the ROS-free core types, each with its inverse
 * (round trips are tested in test/ros/test_conversions.cpp).
 *
 * Conventions (those stereo_image_proc users expect):
 * - stereo_msgs/DisparityImage: 32FC1, f and T from the rectified geometry, Z = f T / d. The core
 *   keeps NaN for invalid pixels and a disparity measured between the rectified images
 *   (d_core = x_left - x_right); the message holds d_msg = d_core - doffs (doffs = cx_left -
 *   cx_right, zero for the usual rectification) so that Z = f T / d_msg holds without doffs, and
 *   writes invalid pixels as min_disparity - 1 (below the published min_disparity).
 * - sensor_msgs/PointCloud2: organized H x W, fields x y z rgb (float32, rgb packed as in PCL),
 *   NaN xyz for invalid pixels, is_dense = false, metres, frame = header.frame_id.
 *
 * Thread safety: all functions are reentrant.
 */
#pragma once

#include <string>

#include <opencv2/core.hpp>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Header.h>
#include <stereo_msgs/DisparityImage.h>

#include "endo_stereo/core/point_cloud.hpp"
#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {
namespace ros_conv {

// ---------------------------------------------------------------------------------------------
// Calibration
// ---------------------------------------------------------------------------------------------

/// CameraInfo -> CameraCalibration (copies every field; K, R, P row-major as in the message).
/// Does not validate: call CameraCalibration::validate() or checkCameraInfo().
CameraCalibration fromCameraInfo(const sensor_msgs::CameraInfo& info);

/// CameraCalibration -> CameraInfo (inverse of fromCameraInfo; header.frame_id = frame_id).
sensor_msgs::CameraInfo toCameraInfo(const CameraCalibration& calib);

/**
 * The camera_info of the left rectified view as a depth or colour image of @p width x @p height
 * pixels publishes it (an RGB-D camera's depth/camera_info, REP 104): K = P's left 3x3 =
 * [f_px 0 cx_left; 0 fyOrF() cy; 0 0 1], P(0,3) = P(1,3) = 0, R identity, plumb_bob with five
 * zero coefficients, no binning, no ROI; header as given (the pair's stamp, the left rectified
 * optical frame). image_geometry's PinholeCameraModel back-projects a depth image with it into
 * the points of disparityToCloud().
 */
sensor_msgs::CameraInfo rectifiedCameraInfo(const RectifiedGeometry& geometry, int width,
                                            int height, const std_msgs::Header& header);

/**
 * Checks a CameraInfo for what the ROS layer can tell on its own: all numbers finite, a non-zero
 * size, fx, fy > 0 in K, a known distortion model with a matching number of coefficients (an empty
 * model with no coefficients means no distortion), and, when @p image_width / @p image_height are
 * > 0, that the image has the size the CameraInfo describes (after binning and ROI).
 * @param name used in the message ("left/camera_info").
 * @return "" when usable, otherwise a message naming the field.
 */
std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& name,
                            int image_width = 0, int image_height = 0);

/**
 * The stereo calibration of two CameraInfo messages (the ROS stereo model: the right camera's P
 * holds Tx = -fx' * baseline). Extrinsics are not filled (has_extrinsics = false): rectification
 * uses R and P of both cameras.
 */
StereoCalibration stereoFromCameraInfo(const sensor_msgs::CameraInfo& left,
                                       const sensor_msgs::CameraInfo& right);

// ---------------------------------------------------------------------------------------------
// Images
// ---------------------------------------------------------------------------------------------

/**
 * Copies an Image message into a cv::Mat of the encoding's type (preprocess.hpp:
 * encodingToCvType(); mono16 big-endian data is swapped to host order). Checks the encoding,
 * that step and data size are consistent, and that the size is not zero.
 * @param copy  false: @p mat is a read-only view of msg.data (no copy) unless a byte swap is
 *              needed; the message must outlive the use of @p mat.
 * @return false with a message in @p error naming the mismatch.
 */
bool imageToMat(const sensor_msgs::Image& msg, cv::Mat& mat, std::string* error,
                bool copy = true);

/// cv::Mat -> Image with the given encoding (copies). The inverse of imageToMat.
/// @throws std::invalid_argument when the Mat type does not fit the encoding.
sensor_msgs::Image matToImage(const cv::Mat& mat, const std::string& encoding,
                              const std_msgs::Header& header);

// ---------------------------------------------------------------------------------------------
// Disparity
// ---------------------------------------------------------------------------------------------

/// Range and resolution of the published disparity, in the core's units (before doffs).
struct DisparityRange {
  int min_disparity = 0;   ///< smallest disparity searched, px
  int max_disparity = 63;  ///< largest disparity searched, px (inclusive)
  double delta_d = 1.0;    ///< smallest disparity increment the matcher can resolve, px
};

/**
 * Core disparity -> DisparityImage.
 * @param disparity CV_32FC1, px, NaN (or any non-finite value) = invalid.
 * @param geometry  rectified geometry (f, baseline, cx, frame); when not metric, f and T are
 *                  written as given (possibly 0), so consumers can tell Z is unavailable.
 * @param range     searched range; min/max_disparity are published minus doffs.
 * @param header    stamp of the input pair, frame = left rectified optical frame.
 * valid_window is the bounding box of the valid pixels (empty, all zeros, when none), always
 * inside the image.
 */
stereo_msgs::DisparityImage toDisparityImage(const cv::Mat& disparity,
                                             const RectifiedGeometry& geometry,
                                             const DisparityRange& range,
                                             const std_msgs::Header& header);

/**
 * DisparityImage -> core disparity (inverse of toDisparityImage): CV_32FC1 with NaN where the
 * message holds a value below min_disparity or a non-finite value, and @p doffs added back.
 * @return an empty Mat with a message in @p error when the message is malformed.
 */
cv::Mat fromDisparityImage(const stereo_msgs::DisparityImage& msg, double doffs,
                           std::string* error = nullptr);

/// The bounding box of the finite pixels of a CV_32FC1 image; empty Rect when none.
cv::Rect validBoundingBox(const cv::Mat& disparity);

// ---------------------------------------------------------------------------------------------
// Point cloud
// ---------------------------------------------------------------------------------------------

/// Organized cloud -> PointCloud2 (x y z rgb float32, 16-byte points, NaN invalid, is_dense false).
sensor_msgs::PointCloud2 toPointCloud2(const OrganizedCloud& cloud, const std_msgs::Header& header);

/// PointCloud2 with float32 x y z and rgb (or rgba) fields -> organized cloud (inverse of the
/// above). @return false with a message in @p error when fields are missing or the layout is wrong.
bool fromPointCloud2(const sensor_msgs::PointCloud2& msg, OrganizedCloud& cloud,
                     std::string* error = nullptr);

}  // namespace ros_conv
}  // namespace endo_stereo
