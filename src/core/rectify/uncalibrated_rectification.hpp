// Private to the rectify library: the building blocks of uncalibrated rectification, shared by
// rectification.cpp (the state machine) and uncalibrated_rectification.cpp (the algorithms).
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/rectification.hpp"

namespace endo_stereo {
namespace detail {

/// Corresponding points, raw px.
struct Matches {
  std::vector<cv::Point2d> left, right;
  size_t size() const { return left.size(); }
  void append(const Matches& o) {
    left.insert(left.end(), o.left.begin(), o.left.end());
    right.insert(right.end(), o.right.begin(), o.right.end());
  }
};

/// SIFT (Lowe 2004) keypoints on both images, brute-force L2 2-NN matching left -> right, Lowe's
/// ratio test and a uniqueness check on the right image.
void siftMatches(const cv::Mat& left, const cv::Mat& right, int max_features, double ratio,
                 Matches* out);

/// Fundamental matrix (x_r^T F x_l = 0) by USAC (RANSAC with local optimisation and the DEGENSAC
/// degeneracy test), then the inliers. @return false when fewer than 8 matches or no model.
bool robustFundamental(const Matches& m, double threshold_px, double confidence, cv::Matx33d* F,
                       Matches* inliers);

/// Share of the matches (0..1) that one homography explains within @p threshold_px (RANSAC):
/// close to 1 when the scene is a plane or the views do not move, and F is then ambiguous.
double homographyShare(const Matches& m, double threshold_px);

/// Null vectors of F: F e_left = 0, F^T e_right = 0 (homogeneous, unit norm).
void epipoles(const cv::Matx33d& F, cv::Vec3d* e_left, cv::Vec3d* e_right);

/// Distance of a homogeneous point from the image centre in image diagonals (inf at infinity).
double epipoleDistance(const cv::Vec3d& e, const cv::Size& size);

/// Hartley's projective rectification (see rectification.hpp); H map raw px -> rectified px
/// of an output image of @p size; @p inliers set the horizontal offset (median disparity kept).
/// @return false (with a reason) when an image would cross the line at infinity (epipole too
/// close: use polar) or the result is degenerate.
bool homographyRectification(const cv::Matx33d& F, const Matches& inliers, const cv::Size& size,
                             cv::Matx33d* H_left, cv::Matx33d* H_right, std::string* error);

/// Pollefeys' polar rectification (see PolarRectification). @p inliers orient the half-lines.
bool polarRectification(const cv::Matx33d& F, const Matches& inliers, const cv::Size& size,
                        PolarRectification* out, std::string* error);

/// remap() maps (CV_32FC1) of one image of a polar rectification; -1 outside the raw image.
void polarMaps(const PolarRectification& p, bool left, cv::Mat& map_x, cv::Mat& map_y);

/// |y_l - y_r| statistics (median, 90th percentile) of a set of offsets.
void offsetStatistics(std::vector<double> offsets, double* median, double* p90);

}  // namespace detail
}  // namespace endo_stereo
