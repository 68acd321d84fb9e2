/**
 * @file frame_sources.hpp
 * @brief Where the tools' frames come from: image files (a pair, or printf patterns for a
 * sequence), one pair repeated or seen through a moving crop window (frame_sources.cpp, no ROS),
 * or a ROS bag with the usual stereo topics (frame_source_bag.cpp, links rosbag).
 */
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <string>

#include "endo_stereo/core/pipeline.hpp"
#include "endo_stereo/core/stereo_geometry.hpp"

namespace endo_stereo {
namespace tools {

/// What to read. Image files: left/right (a pair, or printf patterns with one integer
/// conversion); bag: bag_path with the topics under ns.
struct FrameSourceSettings {
  std::string left, right;  ///< files or printf patterns
  bool has_first = false;   ///< first given (else 0, or 1 when frame 0 is missing)
  int first = 0;
  int count = -1;       ///< frames of a sequence or bag; -1 = all
  double fps = 25.0;    ///< stamps of image files: index / fps
  cv::Size crop;        ///< centre crop of every image (empty = none)
  int repeat = 0;       ///< a single pair: this many frames of it
  int pan = 0;          ///< a single pair with crop: this many frames of a moving crop
  int pan_radius = 24;  ///< px, radius of the crop window's circle
  int pan_period = 75;  ///< frames per turn
  std::string bag_path;
  std::string ns = "/endoscope";
};

/// One pair to process.
struct Frame {
  StereoInput input;
  std::string name;  ///< file or stamp, for messages
  int index = 0;     ///< image files: the sequence index (a single pair: first)
  std::string left_path, right_path;  ///< image files: the files read (empty for a bag)
};

/// Frames in order. next() returns false at the end, or on an error with a message in @p error.
class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual bool next(Frame& f, std::string* error) = 0;
  /// Frames this source will give.
  virtual int size() const = 0;
  virtual std::string describe() const = 0;
  /// Why size() is 0 (a sequence's first file is missing); "" when there are frames.
  virtual std::string emptyReason() const { return ""; }
  /// A calibration the pipeline must rectify with (a bag's camera_info); false otherwise.
  virtual bool calibration(StereoCalibration*) const { return false; }
};

/// True when @p path names a regular file.
bool fileExists(const std::string& path);
/// @p pattern with @p index in its integer conversion (validPattern(pattern) must hold).
std::string formatPattern(const std::string& pattern, int index);
/// True when @p s holds a '%' (a sequence pattern).
bool isPattern(const std::string& s);
/// A pattern with exactly one integer conversion (%d, %04d, %i) and no other '%' but '%%'.
bool validPattern(const std::string& s);

/// Reads an image as stored (8/16 bit, 1/3/4 channels) and names its ROS encoding; 16-bit colour
/// is scaled to 8 bit. On failure @p error names the file and why.
bool readImage(const std::string& path, cv::Mat& image, std::string& encoding, std::string* error);

/// The image-file source for @p settings (bag_path ignored); @p settings must outlive it.
std::unique_ptr<FrameSource> makeFileFrameSource(const FrameSourceSettings& settings);

/// The source for @p settings (a bag when bag_path is set), from frame_source_bag.cpp.
/// @throws std::exception when a bag cannot be opened.
std::unique_ptr<FrameSource> makeFrameSource(const FrameSourceSettings& settings);

}  // namespace tools
}  // namespace endo_stereo
