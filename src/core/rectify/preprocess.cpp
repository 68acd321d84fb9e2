#include "endo_stereo/core/preprocess.hpp"

#include <algorithm>
#include <cstring>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "enum_names.hpp"

namespace endo_stereo {

namespace {

bool fail(std::string* error, const std::string& msg) {
  if (error) *error = msg;
  return false;
}

std::string typeName(int type) { return cv::typeToString(type); }

}  // namespace

namespace {

const detail::EnumName<InterlaceMode> kInterlaceModes[] = {
    {InterlaceMode::kNone, "none"},
    {InterlaceMode::kDownsample, "downsample"},
    {InterlaceMode::kField, "field"},
    {InterlaceMode::kNone, "progressive"},
};

}  // namespace

std::string toString(InterlaceMode mode) { return detail::nameOf(kInterlaceModes, mode, "none"); }

bool parseInterlaceMode(const std::string& text, InterlaceMode* mode) {
  return detail::valueOf(kInterlaceModes, text, mode);
}

std::string PreprocessParams::validate() const {
  if (downsample != 1 && downsample != 2 && downsample != 4) {
    return "preprocess.downsample: must be 1, 2 or 4, got " + std::to_string(downsample);
  }
  if (field_parity != 0 && field_parity != 1) {
    return "preprocess.field_parity: must be 0 (even rows) or 1 (odd rows), got " +
           std::to_string(field_parity);
  }
  if (mono16_bits < 8 || mono16_bits > 16) {
    return "preprocess.mono16_bits: must be in [8, 16], got " + std::to_string(mono16_bits);
  }
  return {};
}

int PreprocessParams::factorX() const {
  return downsample * (interlace == InterlaceMode::kDownsample ? 2 : 1);
}

int PreprocessParams::factorY() const {
  return downsample * (interlace == InterlaceMode::kDownsample ? 2 : 1);
}

int encodingToCvType(const std::string& e) {
  if (e == "mono8" || e == "8UC1") return CV_8UC1;
  if (e == "mono16" || e == "16UC1") return CV_16UC1;
  if (e == "bgr8" || e == "rgb8" || e == "8UC3") return CV_8UC3;
  if (e == "bgra8" || e == "rgba8") return CV_8UC4;
  if (e == "yuv422" || e == "uyvy" || e == "yuv422_yuy2" || e == "yuyv") return CV_8UC2;
  return -1;
}

bool isSupportedEncoding(const std::string& encoding) { return encodingToCvType(encoding) >= 0; }

namespace {
const char* kSupported = "mono8, mono16, bgr8, rgb8, bgra8, rgba8, yuv422 (UYVY), yuv422_yuy2";
}

bool wrapRawImage(const uint8_t* data, size_t data_size, int width, int height, size_t step,
                  const std::string& encoding, bool big_endian, cv::Mat& out, std::string* error,
                  bool copy) {
  const int type = encodingToCvType(encoding);
  if (type < 0) {
    return fail(error, "unsupported encoding '" + encoding + "' (supported: " + kSupported + ")");
  }
  std::ostringstream msg;
  if (width <= 0 || height <= 0) {
    msg << "image (" << encoding << "): size " << width << "x" << height << " is empty";
    return fail(error, msg.str());
  }
  const size_t row_bytes = size_t(width) * CV_ELEM_SIZE(type);
  if (step < row_bytes) {
    msg << "image (" << encoding << "): step " << step << " is smaller than width " << width
        << " x " << CV_ELEM_SIZE(type) << " bytes per pixel = " << row_bytes;
    return fail(error, msg.str());
  }
  if (step % CV_ELEM_SIZE1(type) != 0) {  // cv::Mat would throw on such a step
    msg << "image (" << encoding << "): step " << step << " is not a multiple of "
        << CV_ELEM_SIZE1(type) << " bytes";
    return fail(error, msg.str());
  }
  // Compared by division: step * height can wrap around for a corrupt step.
  if (data == nullptr || data_size / size_t(height) < step) {
    msg << "image (" << encoding << "): data holds " << data_size << " bytes, step " << step
        << " x height " << height << " needs " << step * size_t(height);
    return fail(error, msg.str());
  }
  const cv::Mat view(height, width, type, const_cast<uint8_t*>(data), step);
  const bool swap = big_endian && CV_ELEM_SIZE1(type) == 2;
  if (!copy && !swap) {
    out = view;
    return true;
  }
  view.copyTo(out);
  if (swap) {
    for (int y = 0; y < out.rows; ++y) {
      uint16_t* p = out.ptr<uint16_t>(y);
      for (int x = 0; x < out.cols * out.channels(); ++x)
        p[x] = uint16_t((p[x] >> 8) | (p[x] << 8));
    }
  }
  return true;
}

bool convertImage(const cv::Mat& raw, const std::string& e, int mono16_bits, cv::Mat& gray,
                  cv::Mat* bgr, std::string* error) {
  const int type = encodingToCvType(e);
  if (type < 0) {
    return fail(error, "unsupported encoding '" + e + "' (supported: " + kSupported + ")");
  }
  if (raw.empty()) return fail(error, "image (" + e + "): empty");
  if (raw.type() != type) {
    return fail(error, "image (" + e + "): stored as " + typeName(raw.type()) +
                           ", the encoding needs " + typeName(type));
  }
  if (e == "mono8" || e == "8UC1") {
    raw.copyTo(gray);
    if (bgr) cv::cvtColor(raw, *bgr, cv::COLOR_GRAY2BGR);
  } else if (e == "mono16" || e == "16UC1") {
    if (mono16_bits < 8 || mono16_bits > 16) {
      return fail(error, "preprocess.mono16_bits: must be in [8, 16], got " +
                             std::to_string(mono16_bits));
    }
    // Keep the top 8 significant bits of an N-bit value (a 12-bit camera would otherwise be dark).
    raw.convertTo(gray, CV_8U, 1.0 / double(1 << (mono16_bits - 8)));
    if (bgr) cv::cvtColor(gray, *bgr, cv::COLOR_GRAY2BGR);
  } else if (e == "bgr8" || e == "8UC3") {
    cv::cvtColor(raw, gray, cv::COLOR_BGR2GRAY);  // BT.601 luma weights
    if (bgr) raw.copyTo(*bgr);
  } else if (e == "rgb8") {
    cv::cvtColor(raw, gray, cv::COLOR_RGB2GRAY);
    if (bgr) cv::cvtColor(raw, *bgr, cv::COLOR_RGB2BGR);
  } else if (e == "bgra8") {
    cv::cvtColor(raw, gray, cv::COLOR_BGRA2GRAY);
    if (bgr) cv::cvtColor(raw, *bgr, cv::COLOR_BGRA2BGR);
  } else if (e == "rgba8") {
    cv::cvtColor(raw, gray, cv::COLOR_RGBA2GRAY);
    if (bgr) cv::cvtColor(raw, *bgr, cv::COLOR_RGBA2BGR);
  } else if (e == "yuv422" || e == "uyvy") {
    // UYVY: U0 Y0 V0 Y1 -> Y is channel 1 of each 2-channel pixel.
    cv::extractChannel(raw, gray, 1);
    if (bgr) {
      if (raw.cols % 2 != 0) return fail(error, "image (" + e + "): width must be even");
      cv::cvtColor(raw, *bgr, cv::COLOR_YUV2BGR_UYVY);
    }
  } else {  // yuv422_yuy2 / yuyv: Y0 U0 Y1 V0
    cv::extractChannel(raw, gray, 0);
    if (bgr) {
      if (raw.cols % 2 != 0) return fail(error, "image (" + e + "): width must be even");
      cv::cvtColor(raw, *bgr, cv::COLOR_YUV2BGR_YUY2);
    }
  }
  return true;
}

cv::Size preprocessedSize(const cv::Size& raw_size, const PreprocessParams& p) {
  int h = raw_size.height;
  if (p.interlace == InterlaceMode::kField) h = (h - p.field_parity + 1) / 2;
  return cv::Size(raw_size.width / p.factorX(), h / p.factorY());
}

bool preprocessImage(const cv::Mat& raw, const std::string& encoding, const PreprocessParams& p,
                     cv::Mat& gray, cv::Mat* bgr, std::string* error) {
  const std::string perr = p.validate();
  if (!perr.empty()) return fail(error, perr);
  if (raw.empty()) return fail(error, "image (" + encoding + "): empty");
  cv::Mat src = raw;
  if (p.interlace == InterlaceMode::kField) {
    // One field: rows parity, parity + 2, ... (a strided view, no copy until conversion).
    const int rows = (raw.rows - p.field_parity + 1) / 2;
    if (rows <= 0) return fail(error, "image (" + encoding + "): too few rows for field mode");
    src = cv::Mat(rows, raw.cols, raw.type(), const_cast<uchar*>(raw.ptr(p.field_parity)),
                  raw.step[0] * 2);
  }
  const cv::Size out_size = preprocessedSize(raw.size(), p);
  if (out_size.width <= 0 || out_size.height <= 0) {
    std::ostringstream msg;
    msg << "image (" << encoding << "): " << raw.cols << "x" << raw.rows
        << " is too small for a downsample factor of " << p.factorX();
    return fail(error, msg.str());
  }
  const int fx = p.factorX(), fy = p.factorY();
  if (fx == 1 && fy == 1) return convertImage(src, encoding, p.mono16_bits, gray, bgr, error);
  // Crop to whole blocks so that output pixel u averages exactly input [u*s, (u+1)*s).
  const cv::Mat cropped = src(cv::Rect(0, 0, out_size.width * fx, out_size.height * fy));
  cv::Mat g, c;
  if (!convertImage(cropped, encoding, p.mono16_bits, g, bgr ? &c : nullptr, error)) return false;
  cv::resize(g, gray, out_size, 0, 0, cv::INTER_AREA);
  if (bgr) cv::resize(c, *bgr, out_size, 0, 0, cv::INTER_AREA);
  return true;
}

CameraCalibration scaleCalibration(const CameraCalibration& c, const PreprocessParams& p) {
  CameraCalibration out = c;
  const int fx = p.factorX(), fy = p.factorY();
  const bool field = p.interlace == InterlaceMode::kField;
  if (fx == 1 && fy == 1 && !field) return out;
  const int bx = c.binning_x <= 0 ? 1 : c.binning_x;
  const int by = c.binning_y <= 0 ? 1 : c.binning_y;
  const int field_factor = field ? 2 : 1;
  out.binning_x = bx * fx;
  out.binning_y = by * fy * field_factor;
  const cv::Size in_size = c.binnedSize();
  if (in_size.width > 0 && in_size.height > 0) {
    // The area of the full-resolution image the output covers: offsets add the field's parity
    // row (in incoming binned rows), sizes are whole output pixels.
    const cv::Size out_size = preprocessedSize(in_size, p);
    cv::Rect roi;
    roi.x = c.roi.x;
    roi.y = c.roi.y + (field ? p.field_parity * by : 0);
    roi.width = out_size.width * out.binning_x;
    roi.height = out_size.height * out.binning_y;
    const bool full = roi.x == 0 && roi.y == 0 && roi.width == c.width && roi.height == c.height;
    out.roi = full ? cv::Rect() : roi;
  }
  return out;
}

StereoCalibration scaleCalibration(const StereoCalibration& c, const PreprocessParams& p) {
  StereoCalibration out = c;
  out.left = scaleCalibration(c.left, p);
  out.right = scaleCalibration(c.right, p);
  return out;
}

}  // namespace endo_stereo
