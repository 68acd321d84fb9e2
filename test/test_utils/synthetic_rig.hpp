/**
 * @file synthetic_rig.hpp
 * @brief Synthetic raw (unrectified, distorted) stereo rigs with exact geometry, for the
 * rectification tests: a calibrated pinhole + plumb_bob model per camera, a textured height-field
 * surface rendered by ray casting, and Gaussian dots at known 3D points.
 *
 * World frame = the left camera's optical frame (x right, y down, z forward, metres).
 *
 * Use:
 * @code
 *   endo_stereo::SyntheticRig rig = endo_stereo::makeParallelRig(cv::Size(480, 360), 420.0, 0.005);
 *   endo_stereo::TexturedSurface surf = endo_stereo::makeTexturedSurface(7);
 *   cv::Mat left = endo_stereo::renderSurface(rig.left, surf);
 *   cv::Mat right = endo_stereo::renderSurface(rig.right, surf);
 *   endo_stereo::StereoCalibration calib = rig.calibration();
 * @endcode
 * Deterministic. Reentrant.
 */
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {

/// One raw camera: x_cam = R * X_world + t, then pinhole K with plumb_bob distortion D.
struct RigCamera {
  cv::Size size;
  cv::Matx33d K = cv::Matx33d::eye();
  std::vector<double> D;  ///< k1 k2 p1 p2 k3 (empty = none)
  cv::Matx33d R = cv::Matx33d::eye();
  cv::Vec3d t = cv::Vec3d(0, 0, 0);
};

/// Two cameras; the left one sits at the world origin with R = I.
struct SyntheticRig {
  RigCamera left, right;
  /// The rig as a raw calibration (K, D, extrinsics, no P).
  StereoCalibration calibration() const;
};

/// Rotation from a Rodrigues vector (radians).
cv::Matx33d rodrigues(const cv::Vec3d& r);

/// Parallel rig: both cameras K = [f 0 cx; 0 f cy], right camera baseline_m along +x.
SyntheticRig makeParallelRig(const cv::Size& size, double f_px, double baseline_m);

/// Project a world point. @return false when behind the camera.
bool projectPoint(const RigCamera& cam, const cv::Point3d& X, cv::Point2d* px);

/// Height field z = z0_m + slope_x X + slope_y Y + bump_m sin(2 pi X / wavelength_m) *
/// cos(2 pi Y / wavelength_m), carrying a multi-scale random texture (texel_m per texel).
struct TexturedSurface {
  double z0_m = 0.08;
  double slope_x = 0.1;
  double slope_y = -0.05;
  double bump_m = 0.006;
  double wavelength_m = 0.04;
  double texel_m = 2e-4;
  cv::Mat texture;  ///< CV_32FC1, intensities 0..255, centred on X = Y = 0
  double depth(double X, double Y) const;
  float intensity(double X, double Y) const;
  /// The surface point seen along a ray from @p origin in direction @p dir (fixed-point march).
  bool intersect(const cv::Vec3d& origin, const cv::Vec3d& dir, cv::Point3d* X) const;
};

/// A surface with a deterministic random texture of texels x texels.
TexturedSurface makeTexturedSurface(uint64_t seed, int texels = 1024);

/// Render the surface into the raw (distorted) image of @p cam: CV_8UC1, 2x2 supersampled.
/// @p flat_value >= 0 renders a textureless surface of that intensity instead.
cv::Mat renderSurface(const RigCamera& cam, const TexturedSurface& surface, double flat_value = -1);

/// Black image with a Gaussian dot (sigma_px, peak) at the projection of each point.
cv::Mat renderDots(const RigCamera& cam, const std::vector<cv::Point3d>& points, double sigma_px,
                   double peak);

/// Intensity-weighted centroid of the pixels within @p radius of @p guess. @return false when
/// the window holds no intensity.
bool dotCentroid(const cv::Mat& image, const cv::Point2d& guess, int radius, cv::Point2d* centroid);

}  // namespace endo_stereo
