// Message <-> core conversions. See conversions.hpp for the conventions.
#include "endo_stereo/ros/conversions.hpp"

#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <sensor_msgs/image_encodings.h>

#include "endo_stereo/core/preprocess.hpp"

namespace endo_stereo {
namespace ros_conv {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// The ROS stereo model fixes this byte layout (stereo_image_proc's points2 uses the same):
// x y z rgb as float32, 16 bytes per point, rgb packed as PCL does (0x00RRGGBB in a float).
constexpr uint32_t kPointStep = 16;

template <typename T, size_t N>
bool allFinite(const boost::array<T, N>& a) {
  for (const T& v : a) {
    if (!std::isfinite(v)) return false;
  }
  return true;
}

bool allFinite(const std::vector<double>& v) {
  for (double x : v) {
    if (!std::isfinite(x)) return false;
  }
  return true;
}

void setError(std::string* error, const std::string& message) {
  if (error) *error = message;
}

}  // namespace

CameraCalibration fromCameraInfo(const sensor_msgs::CameraInfo& info) {
  CameraCalibration c;
  c.width = static_cast<int>(info.width);
  c.height = static_cast<int>(info.height);
  c.distortion_model = info.distortion_model;
  c.D = info.D;
  for (int i = 0; i < 9; ++i) c.K.val[i] = info.K[i];
  for (int i = 0; i < 9; ++i) c.R.val[i] = info.R[i];
  for (int i = 0; i < 12; ++i) c.P.val[i] = info.P[i];
  c.binning_x = static_cast<int>(info.binning_x);
  c.binning_y = static_cast<int>(info.binning_y);
  // CameraInfo says an all-zero ROI means the full image; the core uses an empty Rect for that.
  if (info.roi.width > 0 && info.roi.height > 0) {
    c.roi = cv::Rect(static_cast<int>(info.roi.x_offset), static_cast<int>(info.roi.y_offset),
                     static_cast<int>(info.roi.width), static_cast<int>(info.roi.height));
  }
  c.frame_id = info.header.frame_id;
  return c;
}

sensor_msgs::CameraInfo toCameraInfo(const CameraCalibration& c) {
  sensor_msgs::CameraInfo info;
  info.header.frame_id = c.frame_id;
  info.width = static_cast<uint32_t>(std::max(0, c.width));
  info.height = static_cast<uint32_t>(std::max(0, c.height));
  info.distortion_model = c.distortion_model;
  info.D = c.D;
  for (int i = 0; i < 9; ++i) info.K[i] = c.K.val[i];
  for (int i = 0; i < 9; ++i) info.R[i] = c.R.val[i];
  for (int i = 0; i < 12; ++i) info.P[i] = c.P.val[i];
  info.binning_x = static_cast<uint32_t>(std::max(0, c.binning_x));
  info.binning_y = static_cast<uint32_t>(std::max(0, c.binning_y));
  if (!c.roi.empty()) {
    info.roi.x_offset = static_cast<uint32_t>(c.roi.x);
    info.roi.y_offset = static_cast<uint32_t>(c.roi.y);
    info.roi.width = static_cast<uint32_t>(c.roi.width);
    info.roi.height = static_cast<uint32_t>(c.roi.height);
  }
  return info;
}

sensor_msgs::CameraInfo rectifiedCameraInfo(const RectifiedGeometry& g, int width, int height,
                                            const std_msgs::Header& header) {
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = static_cast<uint32_t>(std::max(0, width));
  info.height = static_cast<uint32_t>(std::max(0, height));
  info.distortion_model = "plumb_bob";
  info.D.assign(5, 0.0);
  info.K = {g.f_px, 0.0, g.cx_left, 0.0, g.fyOrF(), g.cy, 0.0, 0.0, 1.0};
  info.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  info.P = {g.f_px, 0.0, g.cx_left, 0.0, 0.0, g.fyOrF(), g.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return info;
}

std::string checkCameraInfo(const sensor_msgs::CameraInfo& info, const std::string& name,
                            int image_width, int image_height) {
  if (!allFinite(info.K) || !allFinite(info.R) || !allFinite(info.P) || !allFinite(info.D)) {
    return name + ": contains NaN or infinity";
  }
  if (info.width == 0 || info.height == 0) {
    // A zero size is what an uncalibrated driver publishes (and a default-constructed message):
    // the image size cannot be checked against it, so refuse it rather than guess.
    std::ostringstream m;
    m << name << ": width/height must be > 0, got " << info.width << "x" << info.height
      << " (is the camera calibrated?)";
    return m.str();
  }
  const CameraCalibration c = fromCameraInfo(info);
  std::string e = c.validate(name);
  if (!e.empty()) return e;
  if (image_width > 0 && image_height > 0) {
    const cv::Size expected = c.binnedSize();
    if (expected.width != image_width || expected.height != image_height) {
      std::ostringstream m;
      m << name << ": describes " << expected.width << "x" << expected.height
        << " images (size / binning, roi), but the image is " << image_width << "x"
        << image_height;
      return m.str();
    }
  }
  return {};
}

StereoCalibration stereoFromCameraInfo(const sensor_msgs::CameraInfo& left,
                                       const sensor_msgs::CameraInfo& right) {
  StereoCalibration s;
  s.left = fromCameraInfo(left);
  s.right = fromCameraInfo(right);
  s.has_extrinsics = false;
  return s;
}

bool imageToMat(const sensor_msgs::Image& msg, cv::Mat& mat, std::string* error, bool copy) {
  if (msg.width == 0 || msg.height == 0) {
    setError(error, "empty image (" + std::to_string(msg.width) + "x" +
                        std::to_string(msg.height) + ", encoding '" + msg.encoding + "')");
    return false;
  }
  if (!isSupportedEncoding(msg.encoding)) {
    setError(error, "unsupported encoding '" + msg.encoding +
                        "' (accepted: mono8, mono16, bgr8, rgb8, bgra8, rgba8, yuv422)");
    return false;
  }
  return wrapRawImage(msg.data.data(), msg.data.size(), static_cast<int>(msg.width),
                      static_cast<int>(msg.height), msg.step, msg.encoding,
                      msg.is_bigendian != 0, mat, error, copy);
}

sensor_msgs::Image matToImage(const cv::Mat& mat, const std::string& encoding,
                              const std_msgs::Header& header) {
  namespace enc = sensor_msgs::image_encodings;
  int expected = -1;
  if (encoding == enc::TYPE_32FC1) {
    expected = CV_32FC1;
  } else if (encoding == enc::TYPE_16UC1) {
    expected = CV_16UC1;
  } else {
    expected = encodingToCvType(encoding);
  }
  if (expected < 0 || mat.type() != expected) {
    throw std::invalid_argument("matToImage: a Mat of type " + std::to_string(mat.type()) +
                                " does not fit encoding '" + encoding + "'");
  }
  sensor_msgs::Image msg;
  msg.header = header;
  msg.height = static_cast<uint32_t>(mat.rows);
  msg.width = static_cast<uint32_t>(mat.cols);
  msg.encoding = encoding;
  msg.is_bigendian = 0;  // host order (little-endian on the platforms ROS 1 runs on)
  const size_t row_bytes = mat.cols * mat.elemSize();
  msg.step = static_cast<uint32_t>(row_bytes);
  msg.data.resize(row_bytes * mat.rows);
  for (int r = 0; r < mat.rows; ++r) {
    std::memcpy(msg.data.data() + r * row_bytes, mat.ptr(r), row_bytes);
  }
  return msg;
}

cv::Rect validBoundingBox(const cv::Mat& disparity) {
  CV_Assert(disparity.type() == CV_32FC1);
  int x0 = disparity.cols, y0 = disparity.rows, x1 = -1, y1 = -1;
  for (int r = 0; r < disparity.rows; ++r) {
    const float* p = disparity.ptr<float>(r);
    // From both ends inwards: a row with valid pixels near its ends costs a few reads, not a pass.
    int first = 0;
    while (first < disparity.cols && !std::isfinite(p[first])) ++first;
    if (first == disparity.cols) continue;
    int last = disparity.cols - 1;
    while (!std::isfinite(p[last])) --last;
    x0 = std::min(x0, first);
    x1 = std::max(x1, last);
    y0 = std::min(y0, r);
    y1 = r;
  }
  if (x1 < 0) return {};
  return cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1);
}

stereo_msgs::DisparityImage toDisparityImage(const cv::Mat& disparity,
                                             const RectifiedGeometry& geometry,
                                             const DisparityRange& range,
                                             const std_msgs::Header& header) {
  CV_Assert(disparity.type() == CV_32FC1);
  stereo_msgs::DisparityImage msg;
  msg.header = header;
  const double doffs = geometry.doffs();
  msg.f = static_cast<float>(geometry.f_px);
  msg.T = static_cast<float>(geometry.baseline_m);
  msg.min_disparity = static_cast<float>(range.min_disparity - doffs);
  msg.max_disparity = static_cast<float>(range.max_disparity - doffs);
  msg.delta_d = static_cast<float>(range.delta_d);
  const float invalid = msg.min_disparity - 1.0f;

  sensor_msgs::Image& img = msg.image;
  img.header = header;
  img.height = static_cast<uint32_t>(disparity.rows);
  img.width = static_cast<uint32_t>(disparity.cols);
  img.encoding = sensor_msgs::image_encodings::TYPE_32FC1;
  img.is_bigendian = 0;
  img.step = static_cast<uint32_t>(disparity.cols * sizeof(float));
  img.data.resize(static_cast<size_t>(img.step) * img.height);
  const float shift = static_cast<float>(doffs);
  for (int r = 0; r < disparity.rows; ++r) {
    const float* src = disparity.ptr<float>(r);
    float* dst = reinterpret_cast<float*>(img.data.data() + static_cast<size_t>(r) * img.step);
    for (int c = 0; c < disparity.cols; ++c) {
      // isfinite as one ordered compare (false for NaN and inf), so that the loop vectorises.
      const bool finite = std::fabs(src[c]) <= std::numeric_limits<float>::max();
      dst[c] = finite ? src[c] - shift : invalid;
    }
  }
  // The box is computed from what was written, so it always lies inside the image and is empty
  // (all zero) when nothing is valid; stereo_image_proc derives it from the SGBM parameters
  // instead and can wrap around.
  const cv::Rect box = validBoundingBox(disparity);
  msg.valid_window.x_offset = static_cast<uint32_t>(box.x);
  msg.valid_window.y_offset = static_cast<uint32_t>(box.y);
  msg.valid_window.width = static_cast<uint32_t>(box.width);
  msg.valid_window.height = static_cast<uint32_t>(box.height);
  msg.valid_window.do_rectify = false;
  return msg;
}

cv::Mat fromDisparityImage(const stereo_msgs::DisparityImage& msg, double doffs,
                           std::string* error) {
  const sensor_msgs::Image& img = msg.image;
  if (img.encoding != sensor_msgs::image_encodings::TYPE_32FC1) {
    setError(error, "disparity image encoding is '" + img.encoding + "', expected 32FC1");
    return {};
  }
  const size_t row_bytes = static_cast<size_t>(img.width) * sizeof(float);
  if (img.step < row_bytes || img.data.size() < static_cast<size_t>(img.step) * img.height) {
    setError(error, "disparity image step/data size inconsistent with its width/height");
    return {};
  }
  cv::Mat out(static_cast<int>(img.height), static_cast<int>(img.width), CV_32FC1);
  for (int r = 0; r < out.rows; ++r) {
    const uint8_t* row = img.data.data() + static_cast<size_t>(r) * img.step;
    float* dst = out.ptr<float>(r);
    for (int c = 0; c < out.cols; ++c) {
      float v;
      std::memcpy(&v, row + c * sizeof(float), sizeof(float));
      dst[c] = (std::isfinite(v) && v >= msg.min_disparity) ? static_cast<float>(v + doffs) : kNaN;
    }
  }
  return out;
}

sensor_msgs::PointCloud2 toPointCloud2(const OrganizedCloud& cloud,
                                       const std_msgs::Header& header) {
  CV_Assert(cloud.xyz.type() == CV_32FC3);
  CV_Assert(cloud.bgr.empty() ||
            (cloud.bgr.type() == CV_8UC3 && cloud.bgr.size() == cloud.xyz.size()));
  sensor_msgs::PointCloud2 msg;
  msg.header = header;
  msg.height = static_cast<uint32_t>(cloud.xyz.rows);
  msg.width = static_cast<uint32_t>(cloud.xyz.cols);
  msg.fields.resize(4);
  const char* names[4] = {"x", "y", "z", "rgb"};
  for (int i = 0; i < 4; ++i) {
    msg.fields[i].name = names[i];
    msg.fields[i].offset = static_cast<uint32_t>(4 * i);
    msg.fields[i].datatype = sensor_msgs::PointField::FLOAT32;
    msg.fields[i].count = 1;
  }
  msg.is_bigendian = false;
  msg.point_step = kPointStep;
  msg.row_step = kPointStep * msg.width;
  msg.is_dense = false;  // invalid pixels stay in place as NaN (organized cloud)
  msg.data.resize(static_cast<size_t>(msg.row_step) * msg.height);
  for (int r = 0; r < cloud.xyz.rows; ++r) {
    const cv::Vec3f* p = cloud.xyz.ptr<cv::Vec3f>(r);
    const cv::Vec3b* col = cloud.bgr.empty() ? nullptr : cloud.bgr.ptr<cv::Vec3b>(r);
    uint8_t* dst = msg.data.data() + static_cast<size_t>(r) * msg.row_step;
    // Branch-free, one 16-byte record per point (the valid / invalid pattern of a disparity map
    // is irregular, so a branch per point mispredicts often).
    constexpr float kMax = std::numeric_limits<float>::max();
    for (int c = 0; c < cloud.xyz.cols; ++c, dst += kPointStep) {
      const float x = p[c][0], y = p[c][1], z = p[c][2];
      const bool finite = (std::fabs(x) <= kMax) & (std::fabs(y) <= kMax) & (std::fabs(z) <= kMax);
      uint32_t rgb = 0;
      if (col) {
        rgb = (static_cast<uint32_t>(col[c][2]) << 16) | (static_cast<uint32_t>(col[c][1]) << 8) |
              static_cast<uint32_t>(col[c][0]);
      }
      float record[4] = {finite ? x : kNaN, finite ? y : kNaN, finite ? z : kNaN, 0.0f};
      std::memcpy(&record[3], &rgb, sizeof(rgb));
      std::memcpy(dst, record, sizeof(record));
    }
  }
  return msg;
}

bool fromPointCloud2(const sensor_msgs::PointCloud2& msg, OrganizedCloud& cloud,
                     std::string* error) {
  int off[4] = {-1, -1, -1, -1};
  const char* names[4] = {"x", "y", "z", "rgb"};
  for (const auto& f : msg.fields) {
    for (int i = 0; i < 4; ++i) {
      const bool name_ok = f.name == names[i] || (i == 3 && f.name == "rgba");
      if (name_ok && f.datatype == sensor_msgs::PointField::FLOAT32 && off[i] < 0) {
        off[i] = static_cast<int>(f.offset);
      } else if (name_ok && i == 3 && f.datatype == sensor_msgs::PointField::UINT32 &&
                 off[i] < 0) {
        off[i] = static_cast<int>(f.offset);
      }
    }
  }
  for (int i = 0; i < 3; ++i) {
    if (off[i] < 0) {
      setError(error, std::string("PointCloud2 has no float32 field '") + names[i] + "'");
      return false;
    }
  }
  if (msg.is_bigendian) {
    setError(error, "big-endian PointCloud2 is not supported");
    return false;
  }
  if (msg.point_step < 12 || msg.row_step < msg.point_step * msg.width ||
      msg.data.size() < static_cast<size_t>(msg.row_step) * msg.height) {
    setError(error, "PointCloud2 point_step/row_step/data size inconsistent with width/height");
    return false;
  }
  for (int i = 0; i < 4; ++i) {
    if (off[i] >= 0 && static_cast<uint32_t>(off[i]) + 4 > msg.point_step) {
      setError(error, std::string("PointCloud2 field '") + names[i] + "' lies outside point_step");
      return false;
    }
  }
  cloud.xyz.create(static_cast<int>(msg.height), static_cast<int>(msg.width), CV_32FC3);
  if (off[3] >= 0) {
    cloud.bgr.create(cloud.xyz.size(), CV_8UC3);
  } else {
    cloud.bgr.release();
  }
  for (int r = 0; r < cloud.xyz.rows; ++r) {
    const uint8_t* row = msg.data.data() + static_cast<size_t>(r) * msg.row_step;
    cv::Vec3f* p = cloud.xyz.ptr<cv::Vec3f>(r);
    for (int c = 0; c < cloud.xyz.cols; ++c) {
      const uint8_t* pt = row + static_cast<size_t>(c) * msg.point_step;
      for (int i = 0; i < 3; ++i) std::memcpy(&p[c][i], pt + off[i], sizeof(float));
      if (off[3] >= 0) {
        uint32_t rgb;
        std::memcpy(&rgb, pt + off[3], sizeof(rgb));
        cloud.bgr.at<cv::Vec3b>(r, c) =
            cv::Vec3b(rgb & 0xff, (rgb >> 8) & 0xff, (rgb >> 16) & 0xff);
      }
    }
  }
  return true;
}

}  // namespace ros_conv
}  // namespace endo_stereo
