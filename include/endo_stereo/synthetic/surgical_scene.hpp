/**
 * @file surgical_scene.hpp
 * @brief Synthetic surgical stereo video with exact ground truth (the temporal benchmark's and the
 * generator's input).
 *
 * A calibrated stereo endoscope looks at a smooth, deforming tissue surface (breathing, heartbeat,
 * a slow peristaltic wave) with a procedural tissue texture (vessels, mottling, colour variation,
 * fat patches); a metallic instrument (a capsule) moves in front of it and occludes it. The light
 * sits at the endoscope tip, so diffuse shading is the same in both views while Blinn-Phong
 * specular highlights (wet tissue, metal) differ between the views. Optional motion blur,
 * interlacing (two fields half a frame apart) and sensor noise.
 *
 * Ground truth is exact by construction: every pixel of both views is ray-cast against the same
 * analytic scene (Newton on the height field to 1e-10 m, the capsule in closed form), and the
 * ground-truth disparity of rectified left pixel (u, v) is f' * B / Z' of the point its ray hits,
 * with Z' the depth along the rectified left optical axis. Texture lives on the tissue (material
 * coordinates), so both views see the same albedo at a 3D point. Masks say where a left pixel is
 * not seen by the right camera (occluded or outside its image) and where highlights are.
 *
 * By default the rig is already rectified (no distortion, parallel axes): raw == rectified. With
 * distorted = true the raw images go through plumb_bob lenses and slightly rotated cameras; the
 * calibration then holds the rectification computed by cv::stereoRectify, and ground truth stays
 * in that rectified left frame.
 *
 * Deterministic: the same params (seed included) give bit-identical frames for any thread count.
 *
 * Use:
 * @code
 *   endo_stereo::SurgicalSceneParams p;  // 960x540, instrument, highlights, noise
 *   p.seed = 7;
 *   endo_stereo::SurgicalScene scene(p);
 *   endo_stereo::SurgicalFrame frame;
 *   for (int i = 0; i < 100; ++i) scene.render(i, frame);  // frame.left/right/gt_disparity ...
 *   scene.calibration();                                   // camera_info model of both cameras
 * @endcode
 *
 * ROS-free: OpenCV only. Thread safety: render() is const and may run concurrently on one scene.
 */
#pragma once

#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <string>

#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {

/// Parameters of the synthetic surgical scene. Lengths in metres, times in seconds, intensities
/// on the 0..255 scale.
struct SurgicalSceneParams {
  int width = 960;    ///< image width, px, >= 32
  int height = 540;   ///< image height, px, >= 32
  uint64_t seed = 1;  ///< everything random derives from it
  double fps = 25.0;  ///< frame rate, > 0; frame i is at time i / fps
  // Rig.
  double hfov_deg = 70.0;      ///< horizontal field of view, (10, 150)
  double baseline_m = 0.0045;  ///< distance between the optical centres, > 0
  bool distorted = false;      ///< plumb_bob lenses and rotated cameras (raw != rectified)
  // Tissue.
  double tissue_distance_m = 0.08;        ///< mean depth of the tissue, > 0
  double tissue_relief_m = 0.008;         ///< amplitude of the smooth relief (bumps, folds), >= 0
  double breathing_amplitude_m = 0.002;   ///< depth swing of breathing, >= 0
  double breathing_period_s = 4.0;        ///< > 0
  double heartbeat_amplitude_m = 0.0006;  ///< local pulsation, >= 0
  double heartbeat_period_s = 0.85;       ///< > 0
  double tissue_stretch_m = 0.0008;       ///< lateral tissue motion with breathing, >= 0
  double camera_motion_m = 0.002;         ///< slow drift of the endoscope, >= 0
  double camera_motion_period_s = 7.0;    ///< > 0
  double vessel_density = 1.0;            ///< vessels per unit, [0, 10]
  double texture_contrast = 1.0;          ///< multiplies the mottling amplitude, [0, 5]
  double specular_strength = 1.0;         ///< tissue highlight strength, [0, 10] (0 = matte)
  // Instrument.
  int instruments = 1;                  ///< number of instruments, 0..2
  double instrument_radius_m = 0.0025;  ///< shaft radius, > 0
  double instrument_speed = 1.0;        ///< multiplies the instrument's motion speed, [0, 20]
  double instrument_texture = 0.3;  ///< brushed-metal texture amplitude, [0, 1] (0 = textureless)
  // Degradations.
  double noise_sigma = 1.5;     ///< Gaussian sensor noise, grey levels, >= 0
  int motion_blur_samples = 1;  ///< sub-frame renders averaged (1 = no blur), 1..16
  double exposure_s = 0.02;     ///< exposure time spanned by the blur samples, >= 0
  bool interlaced = false;      ///< odd rows are a second field, captured 0.5 / fps later

  /// @return an empty string when valid, otherwise a message naming the bad field and its range.
  std::string validate() const;
};

/// Codes of SurgicalFrame::visibility.
enum SceneVisibility : uint8_t {
  kVisibleBoth = 0,        ///< the right camera sees the point of this left pixel
  kOccludedInRight = 1,    ///< the point is hidden from the right camera (by an instrument)
  kOutsideRightImage = 2,  ///< the point projects outside the right image
};

/// One rendered stereo frame with its ground truth.
struct SurgicalFrame {
  int index = 0;
  double stamp_s = 0.0;     ///< index / fps (the time of the first field)
  cv::Mat left;             ///< CV_8UC3 BGR raw left image
  cv::Mat right;            ///< CV_8UC3 BGR raw right image
  cv::Mat gt_disparity;     ///< CV_32FC1, px, rectified left view, finite everywhere
  cv::Mat gt_depth_m;       ///< CV_32FC1, depth along the rectified left optical axis, m
  cv::Mat visibility;       ///< CV_8UC1 SceneVisibility per rectified left pixel
  cv::Mat instrument_mask;  ///< CV_8UC1, 255 where the rectified left pixel sees an instrument
  cv::Mat left_specular;    ///< CV_8UC1, 255 where a highlight adds > 2 grey levels (raw left)
  cv::Mat right_specular;   ///< CV_8UC1, same for the raw right image
};

/// The scene. Construction builds the texture atlas (a fraction of a second at 960x540).
class SurgicalScene {
 public:
  /// @throws std::invalid_argument when params fail validate().
  explicit SurgicalScene(const SurgicalSceneParams& params);
  ~SurgicalScene();
  SurgicalScene(const SurgicalScene&) = delete;
  SurgicalScene& operator=(const SurgicalScene&) = delete;

  const SurgicalSceneParams& params() const { return params_; }

  /// Render frame @p index (>= 0) into @p out (buffers reused). Deterministic.
  void render(int index, SurgicalFrame& out) const;

  /// The camera_info model of both cameras (K, D, R, P; frames "endoscope_left_optical" and
  /// "endoscope_right_optical") plus the extrinsics R_right_left / T_right_left.
  const StereoCalibration& calibration() const { return calibration_; }
  /// The rectified geometry (f, principal points, baseline; metric).
  RectifiedGeometry geometry() const;

  /// A disparity search range that holds every ground-truth disparity of the scene (estimated
  /// from the scene's depth bounds), rounded outward to multiples of 16 (SGBM's granularity).
  void suggestedDisparityRange(int* min_disparity, int* max_disparity) const;

 private:
  struct Impl;
  SurgicalSceneParams params_;
  StereoCalibration calibration_;
  std::unique_ptr<Impl> impl_;
};

/// Mean absolute difference (grey, 0..255) between the left image and the right image warped by
/// the ground-truth disparity (bilinear), over rectified left pixels seen by both cameras, free
/// of highlights in both views and at least @p margin_px away from any ground-truth disparity
/// step > 1 px; @p disparity_offset_px is added to the ground truth (to show the error rises when
/// the disparity is wrong). Needs an undistorted scene. Also returns the pixel count in @p count.
double groundTruthWarpError(const SurgicalFrame& frame, double disparity_offset_px = 0.0,
                            int margin_px = 2, int64_t* count = nullptr);

}  // namespace endo_stereo
