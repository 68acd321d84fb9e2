/**
 * @file evaluation.hpp
 * @brief Scoring a disparity map against ground truth, and loading Middlebury-layout scenes.
 *
 * The protocol follows the Middlebury evaluation and OpenCV's test_stereomatching.cpp: error
 * rates are counted among the pixels a matcher output (so a sparse but trustworthy matcher is not
 * penalised for pixels it declined), and density is reported beside them.
 *
 * Use:
 * @code
 *   endo_stereo::MiddleburyScene scene = endo_stereo::loadMiddleburyScene("data/middlebury/venus");
 *   endo_stereo::DisparityScore s = endo_stereo::scoreDisparity(disp, scene.gt, scene.nonocc);
 *   printf("bad2 %.2f%% density %.1f%%\n", 100 * s.bad2, 100 * s.density);
 * @endcode
 *
 * ROS-free: OpenCV only. Free functions, thread-safe.
 */
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>

namespace endo_stereo {

/// Scores of one disparity map within one mask.
struct DisparityScore {
  double bad1 = 0.0;            ///< share of output pixels with |d - gt| > 1 px, [0, 1]
  double bad2 = 0.0;            ///< share of output pixels with |d - gt| > 2 px, [0, 1]
  double mean_abs_error = 0.0;  ///< mean |d - gt| over output pixels, px
  double density = 0.0;         ///< n_out / n_gt, [0, 1]
  int64_t n_out = 0;   ///< pixels in the mask with known ground truth and a finite disparity
  int64_t n_gt = 0;    ///< pixels in the mask with known ground truth
  int64_t n_bad1 = 0;  ///< output pixels with error > 1 px
  int64_t n_bad2 = 0;  ///< output pixels with error > 2 px
};

/**
 * Score @p disparity against @p gt within @p mask.
 * @param disparity CV_32FC1, px; non-finite (NaN, +-inf) = no output.
 * @param gt        CV_32FC1 ground truth, px; non-finite = unknown (not counted anywhere).
 * @param mask      CV_8UC1, non-zero = evaluated; empty = every pixel.
 * @throws std::invalid_argument on type or size mismatch.
 */
DisparityScore scoreDisparity(const cv::Mat& disparity, const cv::Mat& gt,
                              const cv::Mat& mask = cv::Mat());

/// A scene in the Middlebury 2001/2003 layout: imL.png, imR.png, groundtruth.png (disparity times
/// the scale on line 1 of info.txt, 0 = unknown), nonocc.png, disc.png, all.png (white = in the
/// mask), info.txt (line 1 scale, line 2 the largest disparity in px).
struct MiddleburyScene {
  std::string name;  ///< folder name
  cv::Mat left;      ///< CV_8UC1 gray
  cv::Mat right;     ///< CV_8UC1 gray
  cv::Mat gt;        ///< CV_32FC1 px, NaN = unknown
  cv::Mat nonocc;    ///< CV_8UC1 255 = non-occluded, else 0
  cv::Mat disc;      ///< CV_8UC1 255 = near a depth discontinuity (and non-occluded), else 0
  cv::Mat all;       ///< CV_8UC1 255 = ground truth defined, else 0
  int scale = 1;     ///< ground-truth PNG value per px of disparity
  int max_disp = 0;  ///< largest disparity of the scene, px (info.txt line 2)
};

/// Load a Middlebury-layout scene from @p dir. @throws std::runtime_error naming the missing or
/// unreadable file, or a size mismatch.
MiddleburyScene loadMiddleburyScene(const std::string& dir);

}  // namespace endo_stereo
