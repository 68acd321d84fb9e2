/**
 * @file preprocess.hpp
 * @brief Pre-processing of raw frames (docs/method.md section 1): encoding conversion to gray (luma
 * BT.601, or the Y channel of YUV) and BGR colour, interlace handling and downsampling, with the
 * calibration scaled consistently (the sensor_msgs/CameraInfo binning and ROI semantics).
 *
 * Order of operations on one image: (1) interlace handling: keep one field (rows of one parity),
 * or nothing (the paper's "downsample by 2" is folded into step 3); (2) encoding conversion;
 * (3) downsampling by an integer factor with area averaging, after cropping the image to a
 * multiple of the factor so that output pixel (u, v) covers exactly the input block
 * [u*s, (u+1)*s) x [v*s, (v+1)*s).
 *
 * Calibration: scaleCalibration() multiplies binning_x/binning_y and shifts roi.y for the odd
 * field, so K and P stay in full-resolution pixels as CameraInfo requires; the rectifier uses
 * CameraCalibration::binnedK()/binnedP() (cx' = (cx - roi.x) / binning_x, as image_geometry).
 * That convention maps output pixel u to full-resolution x = u * s, a quarter pixel (for s = 2)
 * from the exact centre of the averaged block; the shift is the same in both cameras, so rows
 * stay aligned and disparities are unchanged.
 *
 * Use:
 * @code
 *   endo_stereo::PreprocessParams pp;  pp.interlace = endo_stereo::InterlaceMode::kDownsample;
 *   cv::Mat gray, bgr;  std::string err;
 *   if (!endo_stereo::preprocessImage(raw, "bgr8", pp, gray, bgr, &err)) { ... }
 *   endo_stereo::StereoCalibration scaled = endo_stereo::scaleCalibration(calib, pp);
 * @endcode
 * All functions are reentrant (no shared state).
 */
#pragma once

#include <cstddef>
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>

#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {

/// What to do with interlaced video (both fields of a frame in alternate rows).
enum class InterlaceMode {
  kNone,        ///< progressive input, or already de-interlaced
  kDownsample,  ///< the paper's choice: average 2x2 blocks (1920x1080i -> 960x540), before
                ///< the general downsample factor (so the total factor is 2 * downsample)
  kField,       ///< keep one field (rows of parity field_parity): 1920x1080i -> 1920x540,
                ///< non-square pixels (fy = fx / 2), then the general downsample factor
};

/// "none", "downsample", "field"; parseInterlaceMode() returns false for anything else.
std::string toString(InterlaceMode mode);
bool parseInterlaceMode(const std::string& text, InterlaceMode* mode);

/// Parameters of pre-processing.
struct PreprocessParams {
  /// Integer downsampling factor applied to both axes, one of 1, 2, 4.
  int downsample = 1;
  /// Interlace handling (see InterlaceMode).
  InterlaceMode interlace = InterlaceMode::kNone;
  /// Field kept by InterlaceMode::kField: 0 = even rows (top field), 1 = odd rows.
  int field_parity = 0;
  /// Significant bits of mono16 input, 8..16: gray = value >> (mono16_bits - 8), saturated.
  int mono16_bits = 16;

  /// @return "" when valid, else a message naming the field and its accepted range.
  std::string validate() const;
  /// Area-averaging factor along x and y: downsample, times 2 for InterlaceMode::kDownsample
  /// (field selection in kField mode halves the rows on top of this).
  int factorX() const;
  int factorY() const;
};

/// Encodings accepted by convertImage(): mono8, mono16, bgr8, rgb8, bgra8, rgba8, yuv422 (UYVY,
/// as ROS names it; "uyvy" is accepted too) and yuv422_yuy2 / "yuyv" (YUYV byte order).
/// @return true when @p encoding is one of them.
bool isSupportedEncoding(const std::string& encoding);

/// The OpenCV type an encoding is stored in (CV_8UC1, CV_16UC1, CV_8UC3, CV_8UC4, CV_8UC2);
/// -1 for an unsupported encoding.
int encodingToCvType(const std::string& encoding);

/**
 * Wrap (and copy) a raw buffer as delivered by sensor_msgs/Image into a cv::Mat of the
 * encoding's type, checking width, height, step and buffer size against the encoding.
 * mono16 with big_endian = true is byte-swapped into the host order.
 * @param copy  true: @p out owns a copy. false: @p out is a read-only view of @p data (no copy;
 *              the caller keeps the buffer alive and unchanged while @p out is used, and must
 *              not write through it), except where a byte swap is needed (then a copy).
 * @return false with a message naming the encoding and the mismatching value.
 */
bool wrapRawImage(const uint8_t* data, size_t data_size, int width, int height, size_t step,
                  const std::string& encoding, bool big_endian, cv::Mat& out, std::string* error,
                  bool copy = true);

/**
 * Convert one raw image to gray and colour.
 * @param raw      image stored in the encoding's type (encodingToCvType()).
 * @param encoding ROS encoding name (see isSupportedEncoding()).
 * @param gray     out: CV_8UC1, luma BT.601 (0.299 R + 0.587 G + 0.114 B) or the Y of YUV input.
 * @param bgr      out: CV_8UC3 BGR (gray replicated for mono input). Pass nullptr to skip.
 * @return false with "unsupported encoding 'X'" or a message naming the type/size mismatch.
 */
bool convertImage(const cv::Mat& raw, const std::string& encoding, int mono16_bits, cv::Mat& gray,
                  cv::Mat* bgr, std::string* error);

/**
 * The whole pre-processing of one raw image: interlace handling, conversion, downsampling.
 * @param gray out: CV_8UC1 of size (W / factorX(), H' / factorY()) with H' the rows kept.
 * @param bgr  out: CV_8UC3 of the same size (nullptr to skip the colour path).
 * @return false with a message (unsupported encoding, size/type mismatch, image too small).
 */
bool preprocessImage(const cv::Mat& raw, const std::string& encoding,
                     const PreprocessParams& params, cv::Mat& gray, cv::Mat* bgr,
                     std::string* error);

/// Size of the image preprocessImage() produces from a raw image of @p raw_size.
cv::Size preprocessedSize(const cv::Size& raw_size, const PreprocessParams& params);

/**
 * The calibration of the pre-processed images, in CameraInfo semantics: K, D, R, P unchanged
 * (full resolution), binning_x *= factorX(), binning_y *= factorY(), roi.y shifted by the kept
 * field's parity (times the incoming binning_y), roi sized to the area the output covers.
 * Width and height stay the full-resolution ones. Identity when params are the defaults.
 */
CameraCalibration scaleCalibration(const CameraCalibration& calibration,
                                   const PreprocessParams& params);
StereoCalibration scaleCalibration(const StereoCalibration& calibration,
                                   const PreprocessParams& params);

}  // namespace endo_stereo
