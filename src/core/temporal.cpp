// Temporal priors, fusion and coverage (METHOD.md section 4). See temporal.hpp.
#include "endo_stereo/core/temporal.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

namespace endo_stereo {

namespace {

std::string rangeMessage(const char* field, const std::string& range, double value) {
  std::ostringstream os;
  os << "temporal." << field << " must be in " << range << " (got " << value << ")";
  return os.str();
}

// Sentinel of "no prior" in the min/max filtered images: far outside any disparity, but finite so
// that arithmetic on it stays well defined.
constexpr float kNoPriorLo = 1e9f;
constexpr float kNoPriorHi = -1e9f;

// Block size of the coarse min / max grid behind the edge zone, px.
constexpr int kEdgeBlock = 4;

inline uint16_t saturatingIncrement(uint16_t v) { return v == kAgeNone ? v : uint16_t(v + 1); }

void checkDisparity(const cv::Mat& disparity, const char* who) {
  if (disparity.empty() || disparity.type() != CV_32FC1) {
    throw std::invalid_argument(std::string(who) + ": disparity must be a non-empty CV_32FC1");
  }
}

}  // namespace

std::string TemporalParams::validate() const {
  if (prior_radius_px < 1 || prior_radius_px > 64)
    return rangeMessage("prior_radius_px", "[1, 64]", prior_radius_px);
  if (prior_neighbourhood_px < 0 || prior_neighbourhood_px > 16)
    return rangeMessage("prior_neighbourhood_px", "[0, 16]", prior_neighbourhood_px);
  if (prior_edge_zone_px < 0 || prior_edge_zone_px > 64)
    return rangeMessage("prior_edge_zone_px", "[0, 64]", prior_edge_zone_px);
  if (highlight_gray < 0 || highlight_gray > 255)
    return rangeMessage("highlight_gray", "[0, 255]", highlight_gray);
  if (highlight_margin_px < 0 || highlight_margin_px > 64)
    return rangeMessage("highlight_margin_px", "[0, 64]", highlight_margin_px);
  if (max_prior_age_frames < 1 || max_prior_age_frames > 1000)
    return rangeMessage("max_prior_age_frames", "[1, 1000]", max_prior_age_frames);
  if (max_prior_failures < 1 || max_prior_failures > 1000)
    return rangeMessage("max_prior_failures", "[1, 1000]", max_prior_failures);
  if (refresh_period_frames < 0 || refresh_period_frames > 1000)
    return rangeMessage("refresh_period_frames", "[0, 1000]", refresh_period_frames);
  if (!(min_prior_hit_share >= 0.0 && min_prior_hit_share <= 1.0))
    return rangeMessage("min_prior_hit_share", "[0, 1]", min_prior_hit_share);
  if (!(max_gap_s > 0.0) || !std::isfinite(max_gap_s))
    return rangeMessage("max_gap_s", "(0, inf)", max_gap_s);
  if (fused_max_age_frames < 0 || fused_max_age_frames > 65534)
    return rangeMessage("fused_max_age_frames", "[0, 65534]", fused_max_age_frames);
  if (coverage_within_frames < 1 || coverage_within_frames > 65534)
    return rangeMessage("coverage_within_frames", "[1, 65534]", coverage_within_frames);
  return {};
}

// ------------------------------------------------------------------------------------------------
std::string TemporalResetDetector::check(const TemporalFrameInfo& info) {
  std::ostringstream reason;
  if (has_previous_) {
    const TemporalFrameInfo& p = previous_;
    if (info.size != p.size) {
      reason << "image size changed from " << p.size.width << "x" << p.size.height << " to "
             << info.size.width << "x" << info.size.height;
    } else if (info.min_disparity != p.min_disparity || info.max_disparity != p.max_disparity) {
      reason << "disparity range changed from [" << p.min_disparity << ", " << p.max_disparity
             << "] to [" << info.min_disparity << ", " << info.max_disparity << "]";
    } else if (info.calibration_generation != p.calibration_generation) {
      reason << "calibration changed";
    } else if (std::isfinite(info.stamp_s) && std::isfinite(p.stamp_s)) {
      const double dt = info.stamp_s - p.stamp_s;
      if (dt < 0.0) {
        reason << "time went back by " << -dt << " s";
      } else if (dt > max_gap_s_) {
        reason << "gap of " << dt << " s > max_gap_s " << max_gap_s_;
      }
    }
  }
  previous_ = info;
  previous_.left_gray.release();  // only the stream's identity is kept, not the image
  has_previous_ = true;
  return reason.str();
}

// ------------------------------------------------------------------------------------------------
TemporalPrior::TemporalPrior(const TemporalParams& params) { setParams(params); }

void TemporalPrior::setParams(const TemporalParams& params) {
  const std::string error = params.validate();
  if (!error.empty()) throw std::invalid_argument(error);
  params_ = params;
}

void TemporalPrior::reset() {
  size_ = cv::Size();
  min_disparity_ = 0;
  max_disparity_ = -1;
  last_disparity_.release();
  age_.release();
  failures_.release();
  narrowed_.release();
  frame_count_ = 0;
  stats_ = TemporalPriorStats();
}

bool TemporalPrior::buildRange(cv::Size size, int min_disparity, int max_disparity,
                               SearchRange& range, const cv::Mat& left_gray) {
  stats_ = TemporalPriorStats();
  if (size != size_ || min_disparity != min_disparity_ || max_disparity != max_disparity_ ||
      last_disparity_.empty()) {
    reset();
    size_ = size;
    min_disparity_ = min_disparity;
    max_disparity_ = max_disparity;
    last_disparity_.create(size, CV_32FC1);
    last_disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.create(size, CV_16UC1);
    age_.setTo(kAgeNone);
    failures_ = cv::Mat::zeros(size, CV_8UC1);
  }
  narrowed_.create(size, CV_8UC1);
  narrowed_.setTo(0);
  lo_f_.create(size, CV_32FC1);
  hi_f_.create(size, CV_32FC1);

  const int max_failures = params_.max_prior_failures;
  const int max_age = params_.max_prior_age_frames;
  int64_t usable = 0;
  for (int y = 0; y < size.height; ++y) {
    const float* d = last_disparity_.ptr<float>(y);
    const uint16_t* age = age_.ptr<uint16_t>(y);
    const uint8_t* fail = failures_.ptr<uint8_t>(y);
    float* lo = lo_f_.ptr<float>(y);
    float* hi = hi_f_.ptr<float>(y);
    for (int x = 0; x < size.width; ++x) {
      const bool fresh = std::isfinite(d[x]) && age[x] < max_age;
      if (fresh && fail[x] < max_failures) {
        lo[x] = d[x];
        hi[x] = d[x];
        ++usable;
      } else {
        lo[x] = kNoPriorLo;
        hi[x] = kNoPriorHi;
        // A pixel with a fresh prior that was dropped for failing: it falls back.
        if (fresh) ++stats_.fallback_pixels;
      }
    }
  }
  if (usable == 0) {
    range.lo.release();
    range.hi.release();
    stats_.full_range_pixels = int64_t(size.area());
    return false;
  }

  // Min / max filters spread each prior over a neighbourhood; the default border values of
  // erode / dilate (+inf / -inf) leave image borders neutral.
  const int e = params_.prior_edge_zone_px;
  const bool edge_zone = e > params_.prior_neighbourhood_px;
  if (edge_zone) {
    // The edge zone is wide (33 x 33 by default): min / max over kEdgeBlock^2 blocks first, then
    // over the blocks within ceil(e / kEdgeBlock) blocks. A pixel's zone then covers at least e px
    // around it (up to e + 2 * kEdgeBlock - 1), at a fraction of a full-resolution filter's cost.
    const cv::Size blocks((size.width + kEdgeBlock - 1) / kEdgeBlock,
                          (size.height + kEdgeBlock - 1) / kEdgeBlock);
    lo_e_.create(blocks, CV_32FC1);
    hi_e_.create(blocks, CV_32FC1);
    lo_e_.setTo(kNoPriorLo);
    hi_e_.setTo(kNoPriorHi);
    for (int y = 0; y < size.height; ++y) {
      const float* lo = lo_f_.ptr<float>(y);
      const float* hi = hi_f_.ptr<float>(y);
      float* blo = lo_e_.ptr<float>(y / kEdgeBlock);
      float* bhi = hi_e_.ptr<float>(y / kEdgeBlock);
      for (int x = 0; x < size.width; ++x) {
        blo[x / kEdgeBlock] = std::min(blo[x / kEdgeBlock], lo[x]);
        bhi[x / kEdgeBlock] = std::max(bhi[x / kEdgeBlock], hi[x]);
      }
    }
    const int eb = (e + kEdgeBlock - 1) / kEdgeBlock;
    const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * eb + 1, 2 * eb + 1));
    cv::erode(lo_e_, lo_e_, kernel);
    cv::dilate(hi_e_, hi_e_, kernel);
  }
  const int k = params_.prior_neighbourhood_px;
  if (k > 0) {
    const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * k + 1, 2 * k + 1));
    cv::erode(lo_f_, lo_f_, kernel);
    cv::dilate(hi_f_, hi_f_, kernel);
  }
  const float edge_jump = 2.0f * float(params_.prior_radius_px);
  const bool highlights = params_.highlight_gray > 0 && !left_gray.empty();
  if (highlights) {
    if (left_gray.type() != CV_8UC1 || left_gray.size() != size) {
      throw std::invalid_argument("TemporalPrior::buildRange: left_gray must be CV_8UC1 of the range size");
    }
    cv::compare(left_gray, params_.highlight_gray, bright_, cv::CMP_GE);
    const int m = params_.highlight_margin_px;
    if (m > 0) {
      cv::dilate(bright_, bright_,
                 cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * m + 1, 2 * m + 1)));
    }
  }

  range.lo.create(size, CV_16SC1);
  range.hi.create(size, CV_16SC1);
  const float r = float(params_.prior_radius_px);
  const int period = params_.refresh_period_frames;
  const int refresh_phase = period > 0 ? int(frame_count_ % period) : -1;
  int64_t width_sum = 0;
  for (int y = 0; y < size.height; ++y) {
    const bool refresh = period > 0 && (y / kRefreshStripeRows) % period == refresh_phase;
    const float* lo_f = lo_f_.ptr<float>(y);
    const float* hi_f = hi_f_.ptr<float>(y);
    const float* lo_e = edge_zone ? lo_e_.ptr<float>(y / kEdgeBlock) : nullptr;
    const float* hi_e = edge_zone ? hi_e_.ptr<float>(y / kEdgeBlock) : nullptr;
    const uint8_t* bright = highlights ? bright_.ptr<uint8_t>(y) : nullptr;
    int16_t* lo = range.lo.ptr<int16_t>(y);
    int16_t* hi = range.hi.ptr<int16_t>(y);
    uint8_t* narrowed = narrowed_.ptr<uint8_t>(y);
    for (int x = 0; x < size.width; ++x) {
      int a = min_disparity, b = max_disparity;
      if (refresh) {
        ++stats_.refresh_pixels;
      } else if (bright && bright[x]) {
        ++stats_.highlight_pixels;
      } else if (lo_f[x] < 0.5f * kNoPriorLo) {
        float lo_d = lo_f[x], hi_d = hi_f[x];
        // Near a depth edge in the priors, the span of both sides (the edge may have moved).
        if (edge_zone && hi_e[x / kEdgeBlock] - lo_e[x / kEdgeBlock] > edge_jump) {
          lo_d = lo_e[x / kEdgeBlock];
          hi_d = hi_e[x / kEdgeBlock];
          ++stats_.edge_zone_pixels;
        }
        a = std::max(min_disparity, int(std::floor(lo_d - r)));
        b = std::min(max_disparity, int(std::ceil(hi_d + r)));
        // A prior (sub-pixel) just outside the full range can leave nothing: search it all.
        if (a > b) {
          a = min_disparity;
          b = max_disparity;
        }
      }
      lo[x] = int16_t(a);
      hi[x] = int16_t(b);
      if (a > min_disparity || b < max_disparity) {
        narrowed[x] = 1;
        ++stats_.narrowed_pixels;
        width_sum += b - a + 1;
      } else {
        ++stats_.full_range_pixels;
      }
    }
  }
  if (stats_.narrowed_pixels > 0) {
    stats_.mean_narrowed_width_px = double(width_sum) / double(stats_.narrowed_pixels);
  }
  return stats_.narrowed_pixels > 0;
}

void TemporalPrior::update(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalPrior::update");
  if (last_disparity_.empty()) {
    // update() without a buildRange(): start the state at this size, full range unknown.
    size_ = disparity.size();
    last_disparity_.create(size_, CV_32FC1);
    last_disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.create(size_, CV_16UC1);
    age_.setTo(kAgeNone);
    failures_ = cv::Mat::zeros(size_, CV_8UC1);
  }
  if (disparity.size() != size_) {
    throw std::invalid_argument("TemporalPrior::update: disparity size differs from the range's");
  }
  const bool have_narrowed = !narrowed_.empty() && narrowed_.size() == size_;
  int64_t hits = 0, misses = 0;
  for (int y = 0; y < size_.height; ++y) {
    const float* in = disparity.ptr<float>(y);
    float* d = last_disparity_.ptr<float>(y);
    uint16_t* age = age_.ptr<uint16_t>(y);
    uint8_t* fail = failures_.ptr<uint8_t>(y);
    const uint8_t* narrowed = have_narrowed ? narrowed_.ptr<uint8_t>(y) : nullptr;
    for (int x = 0; x < size_.width; ++x) {
      const bool valid = std::isfinite(in[x]);
      const bool was_narrowed = narrowed && narrowed[x];
      if (valid) {
        d[x] = in[x];
        age[x] = 0;
        fail[x] = 0;
        hits += was_narrowed;
      } else {
        if (was_narrowed) {
          age[x] = saturatingIncrement(age[x]);
          ++misses;
          if (fail[x] < 255) ++fail[x];
        } else {
          // The whole range was searched and nothing passed the criteria: whatever the prior
          // said is not confirmed, so it is dropped (a wrong prior cannot outlive a refresh).
          d[x] = std::numeric_limits<float>::quiet_NaN();
          age[x] = kAgeNone;
        }
      }
    }
  }
  stats_.prior_hits = hits;
  stats_.prior_misses = misses;
  if (have_narrowed) narrowed_.setTo(0);
  ++frame_count_;
  // Most narrowed searches failing means the priors describe another scene: whatever a few of them
  // accepted is suspect too, so all are dropped rather than left to fail pixel by pixel.
  const int64_t judged = hits + misses;
  if (params_.min_prior_hit_share > 0.0 && judged > 0 && judged >= size_.area() / 20 &&
      double(hits) < params_.min_prior_hit_share * double(judged)) {
    dropAll();
  }
}

double TemporalPrior::hitShare(const cv::Mat& disparity, int64_t* judged) const {
  checkDisparity(disparity, "TemporalPrior::hitShare");
  int64_t n = 0, hits = 0;
  if (!narrowed_.empty() && narrowed_.size() == disparity.size()) {
    for (int y = 0; y < disparity.rows; ++y) {
      const float* d = disparity.ptr<float>(y);
      const uint8_t* narrowed = narrowed_.ptr<uint8_t>(y);
      for (int x = 0; x < disparity.cols; ++x) {
        if (!narrowed[x]) continue;
        ++n;
        hits += std::isfinite(d[x]);
      }
    }
  }
  if (judged) *judged = n;
  return n ? double(hits) / double(n) : 1.0;
}

bool TemporalPrior::sceneChanged(const cv::Mat& disparity) const {
  if (!(params_.min_prior_hit_share > 0.0)) return false;
  int64_t judged = 0;
  const double share = hitShare(disparity, &judged);
  return judged > 0 && judged >= disparity.total() / 20 && share < params_.min_prior_hit_share;
}

void TemporalPrior::dropAll() {
  if (!last_disparity_.empty()) {
    last_disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.setTo(kAgeNone);
    failures_.setTo(0);
  }
  if (!narrowed_.empty()) narrowed_.setTo(0);
  stats_.scene_change = true;
}

// ------------------------------------------------------------------------------------------------
TemporalFusion::TemporalFusion(int max_age_frames) { setMaxAge(max_age_frames); }

void TemporalFusion::setMaxAge(int max_age_frames) {
  if (max_age_frames < 0 || max_age_frames > 65534) {
    throw std::invalid_argument(rangeMessage("fused_max_age_frames", "[0, 65534]", max_age_frames));
  }
  max_age_frames_ = max_age_frames;
}

void TemporalFusion::reset() {
  disparity_.release();
  age_.release();
}

void TemporalFusion::update(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalFusion::update");
  if (disparity_.size() != disparity.size()) {
    disparity_.create(disparity.size(), CV_32FC1);
    disparity_.setTo(std::numeric_limits<float>::quiet_NaN());
    age_.create(disparity.size(), CV_16UC1);
    age_.setTo(kAgeNone);
  }
  const uint16_t max_age = uint16_t(max_age_frames_);
  for (int y = 0; y < disparity.rows; ++y) {
    const float* in = disparity.ptr<float>(y);
    float* d = disparity_.ptr<float>(y);
    uint16_t* age = age_.ptr<uint16_t>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      if (std::isfinite(in[x])) {
        d[x] = in[x];
        age[x] = 0;
      } else if (age[x] != kAgeNone) {
        age[x] = uint16_t(age[x] + 1);
        if (age[x] > max_age) {
          age[x] = kAgeNone;
          d[x] = std::numeric_limits<float>::quiet_NaN();
        }
      }
    }
  }
}

// ------------------------------------------------------------------------------------------------
CoverageTracker::CoverageTracker(int within_frames) { setWithinFrames(within_frames); }

void CoverageTracker::setWithinFrames(int within_frames) {
  if (within_frames < 1 || within_frames > 65534) {
    throw std::invalid_argument(rangeMessage("coverage_within_frames", "[1, 65534]", within_frames));
  }
  within_frames_ = within_frames;
}

void CoverageTracker::reset() {
  frames_ = 0;
  current_.release();
  longest_.release();
  ever_.release();
}

void CoverageTracker::update(const cv::Mat& disparity) {
  checkDisparity(disparity, "CoverageTracker::update");
  if (current_.size() != disparity.size()) {
    reset();
    current_ = cv::Mat::zeros(disparity.size(), CV_16UC1);
    longest_ = cv::Mat::zeros(disparity.size(), CV_16UC1);
    ever_ = cv::Mat::zeros(disparity.size(), CV_8UC1);
  }
  for (int y = 0; y < disparity.rows; ++y) {
    const float* in = disparity.ptr<float>(y);
    uint16_t* cur = current_.ptr<uint16_t>(y);
    uint16_t* lng = longest_.ptr<uint16_t>(y);
    uint8_t* ever = ever_.ptr<uint8_t>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      if (std::isfinite(in[x])) {
        cur[x] = 0;
        ever[x] = 1;
      } else {
        cur[x] = saturatingIncrement(cur[x]);
        lng[x] = std::max(lng[x], cur[x]);
      }
    }
  }
  ++frames_;
}

cv::Rect CoverageTracker::centralRegion(cv::Size size) {
  const double s = 1.0 / std::sqrt(2.0);
  const int w = int(std::lround(size.width * s));
  const int h = int(std::lround(size.height * s));
  return cv::Rect((size.width - w) / 2, (size.height - h) / 2, w, h);
}

CoverageStats CoverageTracker::stats() const {
  CoverageStats s;
  s.frames = frames_;
  s.within_frames = within_frames_;
  if (longest_.empty()) return s;
  s.central_region = centralRegion(longest_.size());
  auto share = [&](const cv::Rect& roi, double* within, double* never) {
    int64_t n_within = 0, n_never = 0;
    for (int y = roi.y; y < roi.y + roi.height; ++y) {
      const uint16_t* lng = longest_.ptr<uint16_t>(y);
      const uint8_t* ever = ever_.ptr<uint8_t>(y);
      for (int x = roi.x; x < roi.x + roi.width; ++x) {
        // A pixel never updated was not updated within N frames, however short the sequence.
        n_within += ever[x] != 0 && lng[x] < within_frames_;
        n_never += ever[x] == 0;
      }
    }
    const double n = double(roi.area());
    *within = n > 0 ? double(n_within) / n : 0.0;
    *never = n > 0 ? double(n_never) / n : 0.0;
  };
  share(s.central_region, &s.central_share, &s.central_never);
  share(cv::Rect(cv::Point(0, 0), longest_.size()), &s.overall_share, &s.overall_never);
  return s;
}

cv::Mat CoverageTracker::colorImage() const {
  if (longest_.empty()) return cv::Mat();
  // Longest run mapped linearly onto 0..2N; at N the colour map is half way (green/yellow).
  const double top = 2.0 * within_frames_;
  cv::Mat scaled;
  longest_.convertTo(scaled, CV_8UC1, 255.0 / top);  // saturates above 2N
  cv::Mat color;
  cv::applyColorMap(scaled, color, cv::COLORMAP_TURBO);
  color.setTo(cv::Scalar::all(0), ever_ == 0);
  cv::rectangle(color, centralRegion(longest_.size()), cv::Scalar::all(255), 1);
  return color;
}

// ------------------------------------------------------------------------------------------------
TemporalTracker::TemporalTracker(const TemporalParams& params)
    : params_(params),
      detector_(params.max_gap_s),
      prior_(params),
      fusion_(params.fused_max_age_frames),
      coverage_(params.coverage_within_frames) {}

void TemporalTracker::setParams(const TemporalParams& params) {
  const std::string error = params.validate();
  if (!error.empty()) throw std::invalid_argument(error);
  params_ = params;
  detector_.setMaxGap(params.max_gap_s);
  prior_.setParams(params);
  fusion_.setMaxAge(params.fused_max_age_frames);
  coverage_.setWithinFrames(params.coverage_within_frames);
  if (!params.enabled) prior_.reset();
}

void TemporalTracker::reset() {
  pending_reason_.clear();
  detector_.reset();
  prior_.reset();
  fusion_.reset();
  coverage_.reset();
  range_.lo.release();
  range_.hi.release();
  priors_used_ = false;
  frame_open_ = false;
}

const SearchRange* TemporalTracker::beginFrame(const TemporalFrameInfo& info,
                                               std::string* reset_reason) {
  std::string reason = detector_.check(info);
  if (!reason.empty()) {
    prior_.reset();
    fusion_.reset();
    coverage_.reset();
  } else {
    reason = pending_reason_;
  }
  pending_reason_.clear();
  if (reset_reason) *reset_reason = reason;
  frame_open_ = true;
  priors_used_ = false;
  if (!params_.enabled) {
    range_.lo.release();
    range_.hi.release();
    return nullptr;
  }
  priors_used_ =
      prior_.buildRange(info.size, info.min_disparity, info.max_disparity, range_, info.left_gray);
  return priors_used_ ? &range_ : nullptr;
}

bool TemporalTracker::rejectPriors(const cv::Mat& disparity) {
  checkDisparity(disparity, "TemporalTracker::rejectPriors");
  if (!params_.enabled || !priors_used_ || !frame_open_) return false;
  int64_t judged = 0;
  const double share = prior_.hitShare(disparity, &judged);
  if (!prior_.sceneChanged(disparity)) return false;
  std::ostringstream os;
  os << "scene change: " << std::lround(100.0 * share) << "% of " << judged
     << " narrowed searches found a disparity (< " << 100.0 * params_.min_prior_hit_share
     << "%); priors and fused disparities dropped, frame matched again over the full range";
  pending_reason_ = os.str();
  prior_.dropAll();
  fusion_.reset();
  priors_used_ = false;
  return true;
}

void TemporalTracker::endFrame(const cv::Mat& disparity, bool fuse, bool track_coverage) {
  checkDisparity(disparity, "TemporalTracker::endFrame");
  if (params_.enabled && frame_open_) {
    prior_.update(disparity);
    const TemporalPriorStats& s = prior_.stats();
    if (s.scene_change && pending_reason_.empty()) {
      std::ostringstream os;
      os << "scene change: " << s.prior_hits << " of " << (s.prior_hits + s.prior_misses)
         << " narrowed searches found a disparity (< " << params_.min_prior_hit_share
         << "); priors and fused disparities dropped";
      pending_reason_ = os.str();
      fusion_.reset();
    }
  }
  if (fuse) fusion_.update(disparity);
  if (track_coverage) coverage_.update(disparity);
  frame_open_ = false;
}

}  // namespace endo_stereo
