#include "endo_stereo/core/point_cloud.hpp"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>

namespace endo_stereo {

int OrganizedCloud::countValid() const {
  int n = 0;
  for (int v = 0; v < xyz.rows; ++v) {
    const cv::Vec3f* p = xyz.ptr<cv::Vec3f>(v);
    for (int u = 0; u < xyz.cols; ++u) n += std::isfinite(p[u][2]) ? 1 : 0;
  }
  return n;
}

void disparityToCloud(const cv::Mat& disparity, const cv::Mat& left_rect_bgr,
                      const RectifiedGeometry& g, OrganizedCloud& out) {
  if (disparity.type() != CV_32FC1) {
    throw std::invalid_argument("disparityToCloud: disparity must be CV_32FC1");
  }
  if (!left_rect_bgr.empty()) {
    if (left_rect_bgr.size() != disparity.size()) {
      throw std::invalid_argument("disparityToCloud: colour image size differs from disparity");
    }
    if (left_rect_bgr.type() != CV_8UC3 && left_rect_bgr.type() != CV_8UC1) {
      throw std::invalid_argument("disparityToCloud: colour image must be CV_8UC3 or CV_8UC1");
    }
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  out.xyz.create(disparity.size(), CV_32FC3);
  out.metric = g.metric;
  if (left_rect_bgr.empty()) {
    out.bgr.release();
  } else if (left_rect_bgr.type() == CV_8UC1) {
    cv::cvtColor(left_rect_bgr, out.bgr, cv::COLOR_GRAY2BGR);
  } else {
    left_rect_bgr.copyTo(out.bgr);
  }
  const double f = g.f_px, fy = g.fyOrF();
  if (g.polar || !(f > 0.0) || !(fy > 0.0) || !(g.baseline_m > 0.0)) {
    out.xyz.setTo(cv::Scalar(nan, nan, nan));
    return;
  }
  // Double precision for the division: at 1 px disparity and f*B ~ 1e3 float would still be fine,
  // but the cost is negligible next to matching.
  const double fb = f * g.baseline_m, doffs = g.doffs();
  for (int v = 0; v < disparity.rows; ++v) {
    const float* d = disparity.ptr<float>(v);
    cv::Vec3f* p = out.xyz.ptr<cv::Vec3f>(v);
    const double y_n = (v - g.cy) / fy;
    for (int u = 0; u < disparity.cols; ++u) {
      const double denom = double(d[u]) - doffs;
      if (!std::isfinite(d[u]) || !(denom > 0.0)) {
        p[u] = cv::Vec3f(nan, nan, nan);
        continue;
      }
      const double z = fb / denom;
      p[u] = cv::Vec3f(float((u - g.cx_left) / f * z), float(y_n * z), float(z));
    }
  }
}

void disparityToDepth(const cv::Mat& disparity, const RectifiedGeometry& g, cv::Mat& depth) {
  if (disparity.type() != CV_32FC1) {
    throw std::invalid_argument("disparityToDepth: disparity must be CV_32FC1");
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  depth.create(disparity.size(), CV_32FC1);
  if (g.polar || !(g.f_px > 0.0) || !(g.fyOrF() > 0.0) || !(g.baseline_m > 0.0)) {
    depth.setTo(cv::Scalar(nan));
    return;
  }
  // The same arithmetic as disparityToCloud's z, so both outputs agree to the bit.
  const double fb = g.f_px * g.baseline_m, doffs = g.doffs();
  for (int v = 0; v < disparity.rows; ++v) {
    const float* d = disparity.ptr<float>(v);
    float* z = depth.ptr<float>(v);
    for (int u = 0; u < disparity.cols; ++u) {
      const double denom = double(d[u]) - doffs;
      z[u] = std::isfinite(d[u]) && denom > 0.0 ? float(fb / denom) : nan;
    }
  }
}

bool writePly(const std::string& path, const OrganizedCloud& cloud, bool binary,
              std::string* error) {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (cloud.xyz.empty() || cloud.xyz.type() != CV_32FC3) {
    return fail("writePly: cloud.xyz is empty or not CV_32FC3");
  }
  const bool colour = !cloud.bgr.empty();
  if (colour && (cloud.bgr.size() != cloud.xyz.size() || cloud.bgr.type() != CV_8UC3)) {
    return fail("writePly: cloud.bgr must be CV_8UC3 of the xyz size");
  }
  const int n = cloud.countValid();
  std::ofstream os(path, std::ios::binary);
  if (!os) return fail("writePly: cannot open '" + path + "' for writing");
  os << "ply\nformat " << (binary ? "binary_little_endian" : "ascii") << " 1.0\n"
     << "comment endo_stereo organized cloud, left rectified optical frame, "
     << (cloud.metric ? "metres" : "units of the baseline (not metric)") << "\n"
     << "element vertex " << n << "\n"
     << "property float x\nproperty float y\nproperty float z\n";
  if (colour) os << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  os << "end_header\n";
  std::vector<char> rec;
  for (int v = 0; v < cloud.xyz.rows; ++v) {
    const cv::Vec3f* p = cloud.xyz.ptr<cv::Vec3f>(v);
    const cv::Vec3b* c = colour ? cloud.bgr.ptr<cv::Vec3b>(v) : nullptr;
    for (int u = 0; u < cloud.xyz.cols; ++u) {
      if (!std::isfinite(p[u][2])) continue;
      if (binary) {
        // PLY binary_little_endian; x86 and ARM hosts are little-endian.
        char buf[15];
        std::memcpy(buf, &p[u][0], 4);
        std::memcpy(buf + 4, &p[u][1], 4);
        std::memcpy(buf + 8, &p[u][2], 4);
        int len = 12;
        if (colour) {
          buf[12] = char(c[u][2]);
          buf[13] = char(c[u][1]);
          buf[14] = char(c[u][0]);
          len = 15;
        }
        os.write(buf, len);
      } else {
        char line[128];
        int len;
        if (colour) {
          len = std::snprintf(line, sizeof(line), "%.7g %.7g %.7g %d %d %d\n", p[u][0], p[u][1],
                              p[u][2], c[u][2], c[u][1], c[u][0]);
        } else {
          len = std::snprintf(line, sizeof(line), "%.7g %.7g %.7g\n", p[u][0], p[u][1], p[u][2]);
        }
        os.write(line, len);
      }
    }
  }
  if (!os) return fail("writePly: write to '" + path + "' failed");
  return true;
}

}  // namespace endo_stereo
