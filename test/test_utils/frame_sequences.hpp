/**
 * @file frame_sequences.hpp
 * @brief Consecutive stereo frames for the tests that need a moving scene: the generated surgical
 * scene (always available) and the real in-vivo recording (when ../shared/data is present).
 */
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace endo_stereo {
namespace test {

/// Left and right images of consecutive frames, index for index.
struct FramePairs {
  std::vector<cv::Mat> left, right;
};

/// @p n consecutive frames of the generated surgical scene at 320x240 (seed 3, undistorted,
/// disparities within 16..79), with its sensor noise.
FramePairs generatedSurgicalFrames(int n);

/// The real rectified in-vivo folder (@p shared_data_dir/real/hamlyn_invivo1), links resolved.
std::string invivoDir(const std::string& shared_data_dir);

/// Up to the first @p n pairs of the in-vivo recording (360x288, search 0..127); empty when the
/// data is absent.
FramePairs invivoFrames(const std::string& shared_data_dir, int n);

}  // namespace test
}  // namespace endo_stereo
