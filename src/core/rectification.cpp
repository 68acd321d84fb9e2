// Temporary stub (headers published early); the implementation follows.
#include "endo_stereo/core/rectification.hpp"

#include <stdexcept>

namespace endo_stereo {

std::string toString(RectifyMode mode) {
  switch (mode) {
    case RectifyMode::kCalibrated: return "calibrated";
    case RectifyMode::kUncalibrated: return "uncalibrated";
    case RectifyMode::kPassThrough: return "pass_through";
  }
  return "calibrated";
}
bool parseRectifyMode(const std::string& t, RectifyMode* m) {
  if (t == "calibrated") *m = RectifyMode::kCalibrated;
  else if (t == "uncalibrated") *m = RectifyMode::kUncalibrated;
  else if (t == "pass_through" || t == "passthrough" || t == "none") *m = RectifyMode::kPassThrough;
  else return false;
  return true;
}
std::string toString(UncalibratedMethod m) {
  switch (m) {
    case UncalibratedMethod::kAuto: return "auto";
    case UncalibratedMethod::kHomography: return "homography";
    case UncalibratedMethod::kPolar: return "polar";
  }
  return "auto";
}
bool parseUncalibratedMethod(const std::string& t, UncalibratedMethod* m) {
  if (t == "auto") *m = UncalibratedMethod::kAuto;
  else if (t == "homography") *m = UncalibratedMethod::kHomography;
  else if (t == "polar") *m = UncalibratedMethod::kPolar;
  else return false;
  return true;
}
std::string RectifyParams::validate() const { return {}; }

cv::Point2d PolarRectification::toRaw(bool, double, double) const { return {}; }
bool PolarRectification::toRectified(bool, const cv::Point2d&, cv::Point2d*) const { return false; }

struct StereoRectifier::Impl {
  RectifyParams params;
  RectifiedGeometry geometry;
};

StereoRectifier::StereoRectifier(const RectifyParams& params) : impl_(new Impl) {
  impl_->params = params;
}
StereoRectifier::~StereoRectifier() = default;
void StereoRectifier::setParams(const RectifyParams& params) { impl_->params = params; }
const RectifyParams& StereoRectifier::params() const { return impl_->params; }
std::string StereoRectifier::setCalibration(const StereoCalibration& c) { return c.validate(); }
bool StereoRectifier::hasCalibration() const { return false; }
bool StereoRectifier::rectify(const cv::Mat&, const cv::Mat&, const cv::Mat&, cv::Mat&, cv::Mat&,
                              cv::Mat&, std::string* error) {
  if (error) *error = "StereoRectifier: not implemented yet";
  return false;
}
bool StereoRectifier::rectifyImage(bool, const cv::Mat&, cv::Mat&, int, std::string*) const {
  return false;
}
bool StereoRectifier::rawToRectified(bool, const cv::Point2d&, cv::Point2d*) const { return false; }
bool StereoRectifier::rectifiedToRaw(bool, const cv::Point2d&, cv::Point2d*) const { return false; }
const RectifiedGeometry& StereoRectifier::geometry() const { return impl_->geometry; }
RectificationQuality StereoRectifier::quality() const { return {}; }
uint64_t StereoRectifier::generation() const { return 0; }
std::string StereoRectifier::activeMethod() const { return ""; }
bool StereoRectifier::homographies(cv::Matx33d*, cv::Matx33d*) const { return false; }
const PolarRectification* StereoRectifier::polar() const { return nullptr; }
bool StereoRectifier::fundamentalMatrix(cv::Matx33d*) const { return false; }
void StereoRectifier::reset() {}

RectificationQuality measureRowAlignment(const cv::Mat&, const cv::Mat&, int, double, double) {
  return {};
}

}  // namespace endo_stereo
