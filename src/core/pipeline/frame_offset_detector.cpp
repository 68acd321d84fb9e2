// Out-of-step views. See frame_offset_detector.hpp.
#include "endo_stereo/core/frame_offset_detector.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

namespace endo_stereo {

std::string FrameOffsetParams::validate() const {
  std::ostringstream m;
  if (target_width < 16 || target_width > 4096) {
    m << "target_width: must be in [16, 4096], got " << target_width;
  } else if (max_offset < 1 || max_offset > 3) {
    m << "max_offset: must be in [1, 3], got " << max_offset;
  } else if (window_frames < 1) {
    m << "window_frames: must be >= 1, got " << window_frames;
  } else if (period_frames < window_frames) {
    m << "period_frames: must be >= window_frames (" << window_frames << "), got " << period_frames;
  } else if (min_votes < 1) {
    m << "min_votes: must be >= 1, got " << min_votes;
  } else if (!(agreement > 0.5 && agreement <= 1.0)) {
    m << "agreement: must be in (0.5, 1], got " << agreement;
  } else if (!(clear_margin > 0.0 && clear_margin < 10.0)) {
    m << "clear_margin: must be in (0, 10), got " << clear_margin;
  } else if (!(gap_factor > 1.0)) {
    m << "gap_factor: must be > 1, got " << gap_factor;
  }
  return m.str();
}

FrameOffsetDetector::FrameOffsetDetector(int min_disparity, int max_disparity,
                                         const FrameOffsetParams& params)
    : p_(params), min_d_(min_disparity), max_d_(max_disparity) {
  const std::string e = p_.validate();
  if (!e.empty()) throw std::invalid_argument(e);
  if (min_disparity > max_disparity) throw std::invalid_argument("min_disparity > max_disparity");
  restart();
}

void FrameOffsetDetector::restart() {
  left_.clear();
  right_.clear();
  intervals_.clear();
  has_stamp_ = false;
  frames_ = 0;
  check_started_ = 0;
  checking_ = true;
  evaluations_ = 0;
  votes_.assign(static_cast<size_t>(2 * p_.max_offset + 1), 0);
  known_ = false;
  offset_ = 0;
  undecided_ = 0;
  last_costs_.clear();
}

void FrameOffsetDetector::recheck() {
  left_.clear();
  right_.clear();
  intervals_.clear();
  has_stamp_ = false;
  checking_ = true;
  check_started_ = frames_;
  evaluations_ = 0;
  std::fill(votes_.begin(), votes_.end(), 0);
}

void FrameOffsetDetector::setDisparityRange(int min_disparity, int max_disparity) {
  if (min_disparity > max_disparity) return;
  min_d_ = min_disparity;
  max_d_ = max_disparity;
}

cv::Mat FrameOffsetDetector::prepare(const cv::Mat& image) const {
  cv::Mat gray;
  if (image.depth() == CV_16U) {
    image.convertTo(gray, CV_8U, 1.0 / 256.0);
  } else {
    gray = image;
  }
  if (gray.channels() == 3) {
    cv::cvtColor(gray, gray, cv::COLOR_BGR2GRAY);
  } else if (gray.channels() == 4) {
    cv::cvtColor(gray, gray, cv::COLOR_BGRA2GRAY);
  }
  const int scale = std::max(1, static_cast<int>(std::lround(double(image.cols) / p_.target_width)));
  cv::Mat small, f, blur;
  cv::resize(gray, small, cv::Size(std::max(1, image.cols / scale), std::max(1, image.rows / scale)),
             0, 0, cv::INTER_AREA);
  small.convertTo(f, CV_32F);
  // High-pass: the local mean (7x7) removed, so a brightness difference between the views does
  // not count as a mismatch.
  cv::boxFilter(f, blur, CV_32F, cv::Size(7, 7), cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  return f - blur;
}

double FrameOffsetDetector::matchCost(const cv::Mat& left, const cv::Mat& right, int dmin,
                                      int dmax) {
  const int w = left.cols, h = left.rows;
  dmin = std::max(0, dmin);
  dmax = std::min(dmax, w - 8);
  if (dmax < dmin || h < 5) return std::nan("");
  // Columns where every disparity has a partner: x >= dmax.
  const int x0 = dmax, cols = w - dmax;
  cv::Mat best(h, cols, CV_32F, cv::Scalar(std::numeric_limits<float>::max()));
  cv::Mat diff, agg;
  for (int d = dmin; d <= dmax; ++d) {
    cv::absdiff(left(cv::Rect(x0, 0, cols, h)), right(cv::Rect(x0 - d, 0, cols, h)), diff);
    cv::boxFilter(diff, agg, CV_32F, cv::Size(5, 5), cv::Point(-1, -1), true, cv::BORDER_REFLECT);
    best = cv::min(best, agg);
  }
  // The border rows and columns of the box filter mirror pixels: left out.
  const cv::Rect inner(2, 2, std::max(1, cols - 4), std::max(1, h - 4));
  return cv::mean(best(inner))[0];
}

void FrameOffsetDetector::evaluate() {
  const int n = 2 * p_.max_offset + 1;
  const cv::Mat& l = left_[static_cast<size_t>(p_.max_offset)];  // the middle left frame
  std::vector<double> cost(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    // right_[i] is right(t + i - max_offset) for the middle frame t.
    cost[static_cast<size_t>(i)] = matchCost(l, right_[static_cast<size_t>(i)], dmin_s_, dmax_s_);
  }
  last_costs_ = cost;
  ++evaluations_;
  int best = 0;
  for (int i = 1; i < n; ++i) {
    if (cost[static_cast<size_t>(i)] < cost[static_cast<size_t>(best)]) best = i;
  }
  double runner_up = std::numeric_limits<double>::infinity();
  for (int i = 0; i < n; ++i) {
    if (i != best) runner_up = std::min(runner_up, cost[static_cast<size_t>(i)]);
  }
  const double b = cost[static_cast<size_t>(best)];
  if (std::isfinite(b) && b > 0.0 && runner_up > b * (1.0 + p_.clear_margin)) {
    ++votes_[static_cast<size_t>(best)];
  }
}

bool FrameOffsetDetector::update(const cv::Mat& left, const cv::Mat& right, double stamp_s) {
  if (left.empty() || right.empty() || left.size() != right.size()) return false;
  // Consecutive frames only: a gap (a lost pair) starts the history again.
  if (has_stamp_) {
    const double dt = stamp_s - last_stamp_;
    bool gap = !(dt > 0.0);
    if (!gap && intervals_.size() >= 3) {
      std::vector<double> v(intervals_.begin(), intervals_.end());
      std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
      gap = dt > p_.gap_factor * v[v.size() / 2];
    }
    if (gap) {
      left_.clear();
      right_.clear();
    } else {
      intervals_.push_back(dt);
      if (intervals_.size() > 9) intervals_.pop_front();
    }
  }
  last_stamp_ = stamp_s;
  has_stamp_ = true;
  ++frames_;
  if (!checking_) {
    if (frames_ - check_started_ < p_.period_frames) return false;
    checking_ = true;
    check_started_ = frames_;
    evaluations_ = 0;
    std::fill(votes_.begin(), votes_.end(), 0);
    left_.clear();
    right_.clear();
  }
  const size_t n = static_cast<size_t>(2 * p_.max_offset + 1);
  cv::Mat l = prepare(left), r = prepare(right);
  if (!left_.empty() && l.size() != left_.back().size()) {
    // A new image size: the history is of another geometry.
    left_.clear();
    right_.clear();
  }
  left_.push_back(l);
  right_.push_back(r);
  while (left_.size() > n) left_.pop_front();
  while (right_.size() > n) right_.pop_front();
  const int scale = std::max(1, static_cast<int>(std::lround(double(left.cols) / p_.target_width)));
  dmin_s_ = static_cast<int>(std::floor(double(min_d_) / scale));
  dmax_s_ = static_cast<int>(std::ceil(double(max_d_) / scale));
  // Every other pair during a check: half the cost, and two evaluations share no middle frame.
  if (left_.size() == n && (frames_ - check_started_) % 2 == 0) evaluate();

  int votes = 0, top = 0;
  for (size_t i = 0; i < votes_.size(); ++i) {
    votes += votes_[i];
    if (votes_[i] > votes_[static_cast<size_t>(top)]) top = static_cast<int>(i);
  }
  if (votes >= p_.min_votes && votes_[static_cast<size_t>(top)] >= p_.agreement * votes) {
    known_ = true;
    offset_ = top - p_.max_offset;
    checking_ = false;
    return true;
  }
  if (frames_ - check_started_ >= p_.window_frames) {
    checking_ = false;
    ++undecided_;
  }
  return false;
}

std::string FrameOffsetDetector::describe() const {
  std::ostringstream m;
  if (known_) {
    if (offset_ == 0) {
      m << "in step (left frame t matches right frame t best)";
    } else {
      m << "out of step by " << (offset_ > 0 ? "+" : "") << offset_ << " frame"
        << (std::abs(offset_) > 1 ? "s" : "") << ": left frame t matches right frame t"
        << (offset_ > 0 ? "+" : "") << offset_ << " best (the right view is " << std::abs(offset_)
        << " frame" << (std::abs(offset_) > 1 ? "s" : "") << (offset_ > 0 ? " late" : " early")
        << ")";
    }
  } else if (checking_) {
    m << "unknown: checking";
  } else {
    m << "unknown: the scene moved too little to tell (" << undecided_ << " check"
      << (undecided_ == 1 ? "" : "s") << " without a verdict)";
  }
  return m.str();
}

}  // namespace endo_stereo
