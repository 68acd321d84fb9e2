// Frozen-view detection: bit-identical images pair after pair. See freeze_detector.hpp.
#include "endo_stereo/core/freeze_detector.hpp"

#include <cstring>
#include <limits>
#include <stdexcept>

namespace endo_stereo {

FreezeDetector::FreezeDetector(int freeze_frames) : freeze_frames_(0) {
  setFreezeFrames(freeze_frames);
}

void FreezeDetector::setFreezeFrames(int freeze_frames) {
  if (freeze_frames < 0) {
    throw std::invalid_argument("freeze_frames must be >= 0, got " +
                                std::to_string(freeze_frames));
  }
  freeze_frames_ = freeze_frames;
  if (freeze_frames_ == 0) {
    reset();
  } else {
    frozen_ = run_ >= freeze_frames_;
  }
}

void FreezeDetector::reset() {
  previous_.release();
  has_previous_ = false;
  run_ = 0;
  frozen_ = false;
}

bool FreezeDetector::identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type() || a.dims != b.dims) return false;
  if (a.dims > 2) return false;  // images only; a volume is never called identical
  const size_t row_bytes = static_cast<size_t>(a.cols) * a.elemSize();
  for (int r = 0; r < a.rows; ++r) {
    if (std::memcmp(a.ptr(r), b.ptr(r), row_bytes) != 0) return false;
  }
  return true;
}

bool FreezeDetector::update(const cv::Mat& image) {
  if (freeze_frames_ == 0) return false;
  if (has_previous_ && identical(image, previous_)) {
    if (run_ < std::numeric_limits<int>::max()) ++run_;
  } else {
    run_ = 0;
    image.copyTo(previous_);  // reuses the buffer while the size and type stay
    has_previous_ = true;
  }
  frozen_ = run_ >= freeze_frames_;
  return frozen_;
}

}  // namespace endo_stereo
