/**
 * @file image_io.hpp
 * @brief Disparity file I/O and pictures: PFM (Middlebury convention), colour maps.
 * ROS-free.
 */
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace endo_stereo {

/// Write a CV_32FC1 disparity as a little-endian float32 PFM (bottom-to-top rows, the PFM
/// convention). NaN (invalid) is written as +inf, the Middlebury convention.
/// @return false with a message in @p error when the file cannot be written or the type is wrong.
bool writePfm(const std::string& path, const cv::Mat& disparity, std::string* error = nullptr);

/// Read a one-channel PFM into CV_32FC1 (top-to-bottom rows). Non-finite values become NaN.
/// @return an empty matrix with a message in @p error on failure.
cv::Mat readPfm(const std::string& path, std::string* error = nullptr);

/// Colourise a disparity for people: values in [d_min, d_max] through a perceptual colour map,
/// invalid (NaN) pixels black. When d_min >= d_max the finite range of the image is used.
/// @return CV_8UC3 BGR.
cv::Mat colorizeDisparity(const cv::Mat& disparity, double d_min = 0.0, double d_max = 0.0);

}  // namespace endo_stereo
