#include "synthetic_rig.hpp"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace endo_stereo {

StereoCalibration SyntheticRig::calibration() const {
  StereoCalibration c;
  const RigCamera* cams[2] = {&left, &right};
  CameraCalibration* out[2] = {&c.left, &c.right};
  for (int i = 0; i < 2; ++i) {
    out[i]->width = cams[i]->size.width;
    out[i]->height = cams[i]->size.height;
    out[i]->K = cams[i]->K;
    out[i]->D = cams[i]->D;
    out[i]->distortion_model = cams[i]->D.empty() ? "" : "plumb_bob";
  }
  c.left.frame_id = "left_optical";
  c.right.frame_id = "right_optical";
  // x_r = R_r X + t_r and X = R_l^T (x_l - t_l)  =>  x_r = R_r R_l^T x_l + (t_r - R_r R_l^T t_l).
  c.R_right_left = right.R * left.R.t();
  c.T_right_left = right.t - c.R_right_left * left.t;
  c.has_extrinsics = true;
  return c;
}

cv::Matx33d rodrigues(const cv::Vec3d& r) {
  cv::Matx33d R;
  cv::Rodrigues(r, R);
  return R;
}

SyntheticRig makeParallelRig(const cv::Size& size, double f_px, double baseline_m) {
  SyntheticRig rig;
  const cv::Matx33d K(f_px, 0, (size.width - 1) / 2.0, 0, f_px, (size.height - 1) / 2.0, 0, 0, 1);
  rig.left.size = rig.right.size = size;
  rig.left.K = rig.right.K = K;
  rig.right.t = cv::Vec3d(-baseline_m, 0, 0);
  return rig;
}

bool projectPoint(const RigCamera& cam, const cv::Point3d& X, cv::Point2d* px) {
  const cv::Vec3d xc = cam.R * cv::Vec3d(X.x, X.y, X.z) + cam.t;
  if (!(xc[2] > 0)) return false;
  std::vector<cv::Point3d> obj{cv::Point3d(xc[0], xc[1], xc[2])};
  std::vector<cv::Point2d> img;
  cv::projectPoints(obj, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cam.K,
                    cam.D.empty() ? cv::Mat() : cv::Mat(cam.D), img);
  *px = img[0];
  return true;
}

double TexturedSurface::depth(double X, double Y) const {
  const double k = 2 * M_PI / wavelength_m;
  return z0_m + slope_x * X + slope_y * Y + bump_m * std::sin(k * X) * std::cos(k * Y);
}

float TexturedSurface::intensity(double X, double Y) const {
  const double u = X / texel_m + texture.cols / 2.0, v = Y / texel_m + texture.rows / 2.0;
  const int u0 = int(std::floor(u)), v0 = int(std::floor(v));
  if (u0 < 0 || v0 < 0 || u0 + 1 >= texture.cols || v0 + 1 >= texture.rows) return 128.f;
  const float a = float(u - u0), b = float(v - v0);
  const float* r0 = texture.ptr<float>(v0);
  const float* r1 = texture.ptr<float>(v0 + 1);
  return (1 - b) * ((1 - a) * r0[u0] + a * r0[u0 + 1]) + b * ((1 - a) * r1[u0] + a * r1[u0 + 1]);
}

bool TexturedSurface::intersect(const cv::Vec3d& o, const cv::Vec3d& d, cv::Point3d* X) const {
  if (!(d[2] > 1e-9)) return false;
  // Newton on g(lambda) = o_z + lambda d_z - depth(o_xy + lambda d_xy), from the mean plane.
  // The surface slope along the ray stays well below d_z for the parameters used in the tests,
  // so g is monotonic and Newton converges in a few steps.
  const double k = 2 * M_PI / wavelength_m;
  double lambda = (z0_m - o[2]) / d[2];
  for (int it = 0; it < 30; ++it) {
    const double x = o[0] + lambda * d[0], y = o[1] + lambda * d[1];
    const double sx = std::sin(k * x), cx = std::cos(k * x);
    const double sy = std::sin(k * y), cy = std::cos(k * y);
    const double g = o[2] + lambda * d[2] - (z0_m + slope_x * x + slope_y * y + bump_m * sx * cy);
    const double dzdx = slope_x + bump_m * k * cx * cy;
    const double dzdy = slope_y - bump_m * k * sx * sy;
    const double dg = d[2] - dzdx * d[0] - dzdy * d[1];
    if (!(std::abs(dg) > 1e-12)) return false;
    const double step = g / dg;
    lambda -= step;
    if (std::abs(step) < 1e-12) break;
  }
  if (!(lambda > 0)) return false;
  *X = cv::Point3d(o[0] + lambda * d[0], o[1] + lambda * d[1], o[2] + lambda * d[2]);
  return true;
}

TexturedSurface makeTexturedSurface(uint64_t seed, int texels) {
  TexturedSurface s;
  cv::RNG rng(seed);
  cv::Mat acc(texels, texels, CV_32FC1, cv::Scalar(0));
  // Several scales of blurred noise give blob-like structure at many sizes (for SIFT) and fine
  // detail (for matching).
  const double sigmas[3] = {1.2, 4.0, 12.0};
  const double weights[3] = {1.0, 1.5, 2.5};
  for (int i = 0; i < 3; ++i) {
    cv::Mat n(texels, texels, CV_32FC1);
    rng.fill(n, cv::RNG::NORMAL, 0.0, 1.0);
    cv::GaussianBlur(n, n, cv::Size(0, 0), sigmas[i]);
    cv::Scalar mean, sd;
    cv::meanStdDev(n, mean, sd);
    acc += n * (weights[i] / sd[0]);
  }
  cv::Scalar mean, sd;
  cv::meanStdDev(acc, mean, sd);
  acc = (acc - mean[0]) * (45.0 / sd[0]) + 128.0;
  cv::min(cv::max(acc, 5.0), 250.0, s.texture);
  return s;
}

cv::Mat renderSurface(const RigCamera& cam, const TexturedSurface& surf, double flat_value) {
  const int ss = 2;
  std::vector<cv::Point2d> px;
  px.reserve(size_t(cam.size.area()) * ss * ss);
  for (int v = 0; v < cam.size.height; ++v)
    for (int u = 0; u < cam.size.width; ++u)
      for (int sy = 0; sy < ss; ++sy)
        for (int sx = 0; sx < ss; ++sx)
          px.emplace_back(u + (sx + 0.5) / ss - 0.5, v + (sy + 0.5) / ss - 0.5);
  std::vector<cv::Point2d> norm(px.size());
  if (cam.D.empty()) {
    const cv::Matx33d Ki = cam.K.inv();
    for (size_t i = 0; i < px.size(); ++i) {
      const cv::Vec3d q = Ki * cv::Vec3d(px[i].x, px[i].y, 1);
      norm[i] = cv::Point2d(q[0] / q[2], q[1] / q[2]);
    }
  } else {
    // Undistort a pixel-spaced grid exactly (iterated to convergence) and interpolate the
    // sub-pixel samples bilinearly: the distortion is smooth, so the interpolation error over
    // half a pixel is ~1e-6 px, and the cost drops by the supersampling factor.
    const int gw = cam.size.width + 2, gh = cam.size.height + 2;
    std::vector<cv::Point2d> grid, grid_n;
    grid.reserve(size_t(gw) * gh);
    for (int v = 0; v < gh; ++v)
      for (int u = 0; u < gw; ++u) grid.emplace_back(u - 1.0, v - 1.0);
    cv::undistortPoints(
        grid, grid_n, cam.K, cv::Mat(cam.D), cv::noArray(), cv::noArray(),
        cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 50, 1e-14));
    for (size_t i = 0; i < px.size(); ++i) {
      const double gx = px[i].x + 1.0, gy = px[i].y + 1.0;
      const int x0 = std::min(std::max(int(std::floor(gx)), 0), gw - 2);
      const int y0 = std::min(std::max(int(std::floor(gy)), 0), gh - 2);
      const double a = gx - x0, b = gy - y0;
      const cv::Point2d& p00 = grid_n[size_t(y0) * gw + x0];
      const cv::Point2d& p01 = grid_n[size_t(y0) * gw + x0 + 1];
      const cv::Point2d& p10 = grid_n[size_t(y0 + 1) * gw + x0];
      const cv::Point2d& p11 = grid_n[size_t(y0 + 1) * gw + x0 + 1];
      norm[i] = (1 - b) * ((1 - a) * p00 + a * p01) + b * ((1 - a) * p10 + a * p11);
    }
  }
  const cv::Matx33d Rt = cam.R.t();
  const cv::Vec3d origin = -(Rt * cam.t);
  cv::Mat out(cam.size, CV_8UC1);
  size_t i = 0;
  for (int v = 0; v < cam.size.height; ++v) {
    uchar* row = out.ptr<uchar>(v);
    for (int u = 0; u < cam.size.width; ++u) {
      double acc = 0;
      for (int k = 0; k < ss * ss; ++k, ++i) {
        const cv::Vec3d dir = Rt * cv::Vec3d(norm[i].x, norm[i].y, 1.0);
        cv::Point3d X;
        if (flat_value >= 0) {
          acc += flat_value;
        } else if (surf.intersect(origin, dir, &X)) {
          acc += surf.intensity(X.x, X.y);
        }
      }
      row[u] = cv::saturate_cast<uchar>(acc / (ss * ss));
    }
  }
  return out;
}

cv::Mat renderDots(const RigCamera& cam, const std::vector<cv::Point3d>& points, double sigma,
                   double peak) {
  cv::Mat img(cam.size, CV_32FC1, cv::Scalar(0));
  const int r = int(std::ceil(4 * sigma));
  for (const auto& X : points) {
    cv::Point2d p;
    if (!projectPoint(cam, X, &p)) continue;
    for (int v = int(p.y) - r; v <= int(p.y) + r; ++v) {
      if (v < 0 || v >= img.rows) continue;
      float* row = img.ptr<float>(v);
      for (int u = int(p.x) - r; u <= int(p.x) + r; ++u) {
        if (u < 0 || u >= img.cols) continue;
        const double d2 = (u - p.x) * (u - p.x) + (v - p.y) * (v - p.y);
        row[u] += float(peak * std::exp(-d2 / (2 * sigma * sigma)));
      }
    }
  }
  cv::Mat out;
  img.convertTo(out, CV_8UC1);
  return out;
}

bool dotCentroid(const cv::Mat& image, const cv::Point2d& guess, int radius, cv::Point2d* c) {
  double sw = 0, sx = 0, sy = 0;
  const int gx = int(std::lround(guess.x)), gy = int(std::lround(guess.y));
  for (int v = gy - radius; v <= gy + radius; ++v) {
    if (v < 0 || v >= image.rows) continue;
    for (int u = gx - radius; u <= gx + radius; ++u) {
      if (u < 0 || u >= image.cols) continue;
      const double w = image.type() == CV_8UC1 ? image.at<uchar>(v, u) : image.at<float>(v, u);
      sw += w;
      sx += w * u;
      sy += w * v;
    }
  }
  if (!(sw > 0)) return false;
  *c = cv::Point2d(sx / sw, sy / sw);
  return true;
}

}  // namespace endo_stereo
