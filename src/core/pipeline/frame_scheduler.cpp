// The backlog, drop policy, stamp order and input health of the stereo stream. See
// frame_scheduler.hpp.
#include "endo_stereo/core/frame_scheduler.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace endo_stereo {
namespace {

// Median of a rate window (at most kRateWindow values, not empty): the element at rank
// round(0.5 (n - 1)), the upper of the two middle ones for an even count.
double windowMedian(const std::deque<double>& d) {
  constexpr size_t kWindow = FrameSchedulerBase::kRateWindow;
  std::array<double, kWindow> v{};
  const size_t n = std::min(d.size(), kWindow);
  std::copy_n(d.begin(), n, v.begin());
  const size_t k = static_cast<size_t>(std::round(0.5 * (n - 1)));
  std::nth_element(v.begin(), v.begin() + k, v.begin() + n);
  return v[k];
}

void pushWindow(std::deque<double>& d, double value) {
  d.push_back(value);
  if (d.size() > FrameSchedulerBase::kRateWindow) d.pop_front();
}

int index(StereoSide side) { return side == StereoSide::kLeft ? 0 : 1; }

}  // namespace

std::string FrameSchedulerParams::validate() const {
  std::ostringstream m;
  if (backlog_pairs < 1 || backlog_pairs > 100) {
    m << "backlog_pairs: must be in [1, 100], got " << backlog_pairs;
  } else if (!(backlog_max_age_s > 0.0 && backlog_max_age_s <= 10.0)) {
    m << "backlog_max_age_s: must be in (0, 10] s, got " << backlog_max_age_s;
  } else if (!(restart_jump_back_s >= 0.0 && restart_jump_back_s <= 3600.0)) {
    m << "restart_jump_back_s: must be in [0, 3600] s, got " << restart_jump_back_s;
  } else if (!(unpaired_timeout_s > 0.0 && unpaired_timeout_s <= 60.0)) {
    m << "unpaired_timeout_s: must be in (0, 60] s, got " << unpaired_timeout_s;
  } else if (!(no_input_warn_s > 0.0 && no_input_warn_s <= 3600.0)) {
    m << "no_input_warn_s: must be in (0, 3600] s, got " << no_input_warn_s;
  }
  return m.str();
}

FrameSchedulerBase::FrameSchedulerBase(const FrameSchedulerParams& params) : params_(params) {
  const std::string e = params_.validate();
  if (!e.empty()) throw std::invalid_argument(e);
}

bool FrameSchedulerBase::overloaded() const {
  return measured_ >= kRateGrace && busy_ms_.size() >= kRateWindow &&
         intervals_ms_.size() >= kRateWindow &&
         windowMedian(busy_ms_) > windowMedian(intervals_ms_);
}

// --- Pairing.

UnpairedReport FrameSchedulerBase::imageArrived(StereoSide side, double stamp_s, double now_s) {
  const int s = index(side), o = 1 - s;
  ++(side == StereoSide::kLeft ? counters_.left_images : counters_.right_images);
  last_arrival_s_[s] = now_s;
  last_image_stamp_s_[s] = stamp_s;
  if (!unpaired_since_s_[s]) unpaired_since_s_[s] = now_s;
  UnpairedReport r;
  r.side = side;
  r.waiting_s = now_s - *unpaired_since_s_[s];
  r.left_stamp_s = last_image_stamp_s_[0];
  r.right_stamp_s = last_image_stamp_s_[1];
  // A side that keeps arriving while no pair forms: the other side is missing, or the stamps
  // never match (exact sync with offset stamps, or offsets above the tolerance).
  if (r.waiting_s > params_.unpaired_timeout_s) {
    const bool partner_recent =
        last_arrival_s_[o] && now_s - *last_arrival_s_[o] <= params_.unpaired_timeout_s;
    r.kind = partner_recent ? UnpairedReport::Kind::kStampsDoNotMatch
                            : UnpairedReport::Kind::kPartnerMissing;
  }
  return r;
}

void FrameSchedulerBase::pairFormed() {
  unpaired_since_s_[0].reset();
  unpaired_since_s_[1].reset();
}

void FrameSchedulerBase::withhold() {
  ++counters_.pairs_received;
  ++counters_.pairs_withheld;
}

// --- Backlog.

size_t FrameSchedulerBase::admit(double arrival_s) {
  if (last_push_s_) pushWindow(intervals_ms_, (arrival_s - *last_push_s_) * 1e3);
  last_push_s_ = arrival_s;
  arrivals_.push_back(arrival_s);
  ++counters_.pairs_received;
  size_t out = 0;
  while (arrivals_.size() > static_cast<size_t>(params_.backlog_pairs)) {
    arrivals_.pop_front();  // the oldest waiting pair makes room for the newest
    ++out;
  }
  counters_.pairs_dropped += static_cast<int64_t>(out);
  return out;
}

size_t FrameSchedulerBase::select(double now_s) {
  // Frames come faster than they are processed: only the newest pair is worth processing.
  // Otherwise the waiting pairs are caught up in order, except those that waited too long.
  const bool newest = overloaded();
  size_t skipped = 0;
  while (arrivals_.size() > 1 &&
         (newest || now_s - arrivals_.front() > params_.backlog_max_age_s)) {
    arrivals_.pop_front();
    ++skipped;
  }
  arrivals_.pop_front();  // taken
  ++in_progress_;
  counters_.pairs_dropped += static_cast<int64_t>(skipped);
  return skipped;
}

// --- Processing.

void FrameSchedulerBase::finished(PairOutcome outcome, double busy_s) {
  if (in_progress_ > 0) --in_progress_;
  ++(outcome == PairOutcome::kProcessed ? counters_.pairs_processed : counters_.pairs_rejected);
  pushWindow(busy_ms_, busy_s * 1e3);
  ++measured_;
}

void FrameSchedulerBase::failed() {
  if (in_progress_ > 0) --in_progress_;
  ++counters_.pairs_rejected;
}

StampCheck FrameSchedulerBase::checkStamp(double stamp_s) {
  StampCheck c;
  if (!last_stamp_s_) return c;
  c.last_stamp_s = *last_stamp_s_;
  if (stamp_s > *last_stamp_s_) return c;
  c.back_s = *last_stamp_s_ - stamp_s;
  if (c.back_s > params_.restart_jump_back_s) {
    c.verdict = StampCheck::Verdict::kRestart;
    ++counters_.restarts;
  } else {
    c.verdict = StampCheck::Verdict::kOutOfOrder;
  }
  return c;
}

void FrameSchedulerBase::stampProcessed(double stamp_s) {
  // An unset stamp (0) is no reference: the pair after it is in order.
  if (stamp_s == 0.0) {
    last_stamp_s_.reset();
  } else {
    last_stamp_s_ = stamp_s;
  }
}

// --- Subscription and silence.

void FrameSchedulerBase::inputsSubscribed(double now_s) {
  subscribed_ = true;
  subscribed_since_s_ = now_s;
  pairFormed();  // neither side waits for a partner from an earlier subscription
}

void FrameSchedulerBase::inputsUnsubscribed() { subscribed_ = false; }

SilenceCheck FrameSchedulerBase::checkSilence(double now_s) {
  SilenceCheck c;
  if (subscribed_ && subscribed_since_s_) {
    double last = *subscribed_since_s_;
    for (const auto& a : last_arrival_s_) {
      if (a) last = std::max(last, *a);
    }
    c.silent_s = now_s - last;
  }
  c.silent = c.silent_s > params_.no_input_warn_s;
  if (!c.silent) {
    // The next silence is explained and logged at once.
    explained_s_.reset();
    logged_s_.reset();
    return c;
  }
  c.explain = !explained_s_ || now_s - *explained_s_ > kSilenceExplainPeriodS;
  if (c.explain) explained_s_ = now_s;
  c.log = !logged_s_ || now_s - *logged_s_ > kSilenceLogPeriodS;
  if (c.log) logged_s_ = now_s;
  return c;
}

}  // namespace endo_stereo
