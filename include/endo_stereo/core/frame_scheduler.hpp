/**
 * @file frame_scheduler.hpp
 * @brief Which stereo pair is processed next, and what became of every pair: the bounded backlog
 * between the image callbacks and the processing thread, the drop policy, the stamp order, and
 * the input's health (images that find no partner, silence).
 *
 * A state machine without threads and without ROS: the caller passes times in as plain seconds
 * and pairs as an opaque payload, and serialises the calls (the nodelet, reconstruction.hpp,
 * calls it under one mutex from its callbacks, its processing thread and its diagnostics).
 * `now_s` and `arrival_s` are on one wall clock of the caller's choice; `stamp_s` are the
 * capture stamps of the pairs. Stamps of the epoch's scale (1.7e9 s) are resolved to about
 * 0.5 us as doubles, far below any frame interval.
 *
 * Pairing: the pairs themselves are formed by stamp outside (exact or approximate
 * synchronisation); the scheduler is told of every image (imageArrived()) and every pair formed
 * (pairFormed()), and reports a side whose images keep arriving without forming a pair for
 * longer than `unpaired_timeout_s`: its partner is missing (no image of the other side within
 * that time) or the two sides arrive but their stamps never match.
 *
 * Backlog and drop policy:
 * - push(): at most `backlog_pairs` pairs wait, oldest first; a pair pushed while that many
 *   wait pushes out the oldest (dropped).
 * - next(): while the processing keeps up with the input it takes the oldest waiting pair, so a
 *   short stall (the first frame's full-range search) is caught up without loss, skipping pairs
 *   that waited longer than `backlog_max_age_s`. It is overloaded when the median of the last
 *   kRateWindow processing times (finished()) exceeds the median of the last kRateWindow
 *   intervals between pushed pairs, once kRateGrace pairs were finished (the first frames are
 *   slower: the first searches the full range, the next ones fill their priors); then it takes
 *   the newest and skips the others. A skipped pair is dropped; the newest waiting pair is never
 *   skipped.
 * - Every pair formed is counted once as received and ends as exactly one of: withheld
 *   (withhold(): never queued), dropped, processed or rejected (finished() / failed()); until
 *   then it is waiting or in progress (taken, not finished). Nothing queues without limit.
 *
 * Stamp order: checkStamp() judges a taken pair's stamp against the last processed one
 * (stampProcessed()): after it, in order; not after it by at most `restart_jump_back_s`, out of
 * order (the caller rejects the pair, so outputs come in stamp order); further back, a restart
 * of the stream (a looping bag, a restarted driver), counted, after which the pair is processed
 * (the caller resets its temporal state first).
 *
 * Silence: checkSilence() reports, while the inputs are subscribed, how long no image arrived on
 * either side (since the later of the subscription and the last image); longer than
 * `no_input_warn_s` is silence, which the caller explains at most every kSilenceExplainPeriodS
 * and logs at most every kSilenceLogPeriodS.
 *
 * Thread safety: not thread-safe; the caller serialises every call.
 */
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <utility>

namespace endo_stereo {

struct FrameSchedulerParams {
  /// Pairs that may wait for the processing thread, in [1, 100] (`~backlog_pairs`).
  int backlog_pairs = 3;
  /// A waiting pair older than this (since it was pushed) is skipped when a newer one waits,
  /// s, in (0, 10] (`~backlog_max_age_s`).
  double backlog_max_age_s = 0.25;
  /// A stamp further back than this from the last processed one restarts the stream; less far
  /// back (or equal) is out of order. s, in [0, 3600] (`~restart_jump_back_s`).
  double restart_jump_back_s = 1.0;
  /// Images of one side arriving this long without forming a pair are reported, s, in (0, 60]
  /// (`~unpaired_timeout_s`).
  double unpaired_timeout_s = 1.0;
  /// No image on either side for longer than this while subscribed is silence, s, in
  /// (0, 3600] (`~no_input_warn_s`).
  double no_input_warn_s = 5.0;

  /// "" when valid, else the field and its accepted range.
  std::string validate() const;
};

/// Running totals (monotonic) of what the scheduler was told and decided.
struct FrameSchedulerCounters {
  int64_t left_images = 0;      ///< imageArrived(kLeft)
  int64_t right_images = 0;     ///< imageArrived(kRight)
  int64_t pairs_received = 0;   ///< pairs pushed or withheld
  int64_t pairs_withheld = 0;   ///< withhold()
  int64_t pairs_dropped = 0;    ///< pushed out of a full backlog or skipped by next()
  int64_t pairs_processed = 0;  ///< finished(kProcessed)
  int64_t pairs_rejected = 0;   ///< finished(kRejected) and failed()
  int64_t restarts = 0;         ///< checkStamp() verdicts kRestart
};

enum class StereoSide { kLeft, kRight };

/// What an image that keeps arriving without a partner means (imageArrived()).
struct UnpairedReport {
  enum class Kind {
    kNone,              ///< nothing to report
    kPartnerMissing,    ///< no image of the other side within unpaired_timeout_s
    kStampsDoNotMatch,  ///< both sides arrive, but their images do not pair
  };
  Kind kind = Kind::kNone;
  StereoSide side = StereoSide::kLeft;  ///< the side that arrived
  double waiting_s = 0.0;       ///< since the side's first image after the last pair
  double left_stamp_s = 0.0;    ///< the last left image's stamp (0 before the first)
  double right_stamp_s = 0.0;   ///< the last right image's stamp (0 before the first)
};

/// A taken pair's stamp against the last processed one (checkStamp()).
struct StampCheck {
  enum class Verdict {
    kInOrder,     ///< after the last processed stamp, or none processed yet
    kOutOfOrder,  ///< not after it, by at most restart_jump_back_s: reject the pair
    kRestart,     ///< further back: the stream restarted; reset, then process the pair
  };
  Verdict verdict = Verdict::kInOrder;
  double last_stamp_s = 0.0;  ///< the last processed stamp (0 when none)
  double back_s = 0.0;        ///< last_stamp_s - the pair's stamp (kOutOfOrder, kRestart)
};

/// Silence of the inputs (checkSilence()).
struct SilenceCheck {
  double silent_s = 0.0;  ///< s without an image while subscribed (0 while not subscribed)
  bool silent = false;    ///< silent_s > no_input_warn_s
  bool explain = false;   ///< silent, and the explanation is due (first, or the last is old)
  bool log = false;       ///< silent, and the log line is due
};

enum class PairOutcome { kProcessed, kRejected };

/// Everything of the scheduler but the payloads (frame_scheduler.cpp). Use FrameScheduler<P>.
class FrameSchedulerBase {
 public:
  /// Rate windows of the overload test, pairs.
  static constexpr size_t kRateWindow = 8;
  /// Pairs finished before the overload test applies.
  static constexpr int64_t kRateGrace = 10;
  /// Silence: a new explanation at most this often, s (it may ask the ROS master).
  static constexpr double kSilenceExplainPeriodS = 5.0;
  /// Silence: the log line at most this often, s.
  static constexpr double kSilenceLogPeriodS = 30.0;

  /// @throws std::invalid_argument when @p params fail validate().
  explicit FrameSchedulerBase(const FrameSchedulerParams& params = FrameSchedulerParams());

  const FrameSchedulerParams& params() const { return params_; }
  FrameSchedulerCounters counters() const { return counters_; }
  /// Pairs waiting in the backlog.
  size_t waiting() const { return arrivals_.size(); }
  /// Pairs taken by next() and not finished yet.
  int64_t inProgress() const { return in_progress_; }
  /// Whether next() would take the newest pair now (the overload test; see the file comment).
  bool overloaded() const;

  // --- Pairing.
  /// An image of @p side, stamped @p stamp_s, arrived at @p now_s (before the pair it may form
  /// is reported by pairFormed()). Counted.
  UnpairedReport imageArrived(StereoSide side, double stamp_s, double now_s);
  /// A pair was formed: neither side waits for a partner any more.
  void pairFormed();
  /// A formed pair is not queued (e.g. a frozen view): counted received and withheld.
  void withhold();

  // --- Processing.
  /// The pair taken last went through processing in @p busy_s seconds (fed to the overload
  /// test), with @p outcome.
  void finished(PairOutcome outcome, double busy_s);
  /// The pair taken last failed without a measured time (an exception): counted rejected, not
  /// fed to the overload test.
  void failed();
  /// Judges a taken pair's stamp (see the file comment); a kRestart verdict is counted.
  StampCheck checkStamp(double stamp_s);
  /// A pair with @p stamp_s was processed: later stamps are judged against it (an unset stamp,
  /// 0, leaves nothing to judge against: the next pair is in order).
  void stampProcessed(double stamp_s);

  // --- Subscription and silence.
  /// The inputs were subscribed at @p now_s: silence is measured from now, and neither side
  /// waits for a partner.
  void inputsSubscribed(double now_s);
  void inputsUnsubscribed();
  bool subscribed() const { return subscribed_; }
  /// Silence at @p now_s; a due explanation or log line is taken as done.
  SilenceCheck checkSilence(double now_s);

 protected:
  /// A pair pushed at @p arrival_s joins the waiting ones: counted received; @return how many
  /// of the oldest waiting pairs (now including it) must leave to respect backlog_pairs
  /// (counted dropped). Only the FrameScheduler template calls it, in step with its payloads.
  size_t admit(double arrival_s);
  /// Chooses the pair to take at @p now_s (waiting() > 0): @return how many of the oldest waiting
  /// pairs are skipped (counted dropped); the one after them is taken (in progress).
  size_t select(double now_s);

 private:
  FrameSchedulerParams params_;
  FrameSchedulerCounters counters_;
  // Backlog: the arrival time of each waiting pair, oldest first (the payloads live beside it).
  std::deque<double> arrivals_;
  int64_t in_progress_ = 0;
  // Overload test: the last intervals between pushed pairs and the last processing times, ms.
  std::optional<double> last_push_s_;
  std::deque<double> intervals_ms_;
  std::deque<double> busy_ms_;
  int64_t measured_ = 0;  // pairs finished with a measured time
  // Stamp order.
  std::optional<double> last_stamp_s_;
  // Pairing: per side (0 left, 1 right) the last arrival and stamp, and the first arrival since
  // the last pair.
  std::optional<double> last_arrival_s_[2];
  double last_image_stamp_s_[2] = {0.0, 0.0};
  std::optional<double> unpaired_since_s_[2];
  // Subscription and silence.
  bool subscribed_ = false;
  std::optional<double> subscribed_since_s_;
  std::optional<double> explained_s_, logged_s_;
};

/**
 * The scheduler with its backlog's payloads (@p Payload: a movable pair, e.g. the messages).
 * @code
 *   FrameScheduler<Pair> s(params);
 *   s.pairFormed(); s.push(pair, now_s);                 // callback
 *   Pair p; if (s.next(now_s, &p)) { ... s.finished(PairOutcome::kProcessed, busy_s); }  // worker
 * @endcode
 */
template <typename Payload>
class FrameScheduler : public FrameSchedulerBase {
 public:
  using FrameSchedulerBase::FrameSchedulerBase;

  /// A formed pair, pushed at @p arrival_s, joins the backlog. Counted received.
  /// @return the waiting pairs it pushed out (counted dropped).
  size_t push(Payload pair, double arrival_s) {
    payloads_.push_back(std::move(pair));
    const size_t out = admit(arrival_s);
    for (size_t i = 0; i < out; ++i) payloads_.pop_front();
    return out;
  }

  /// Takes the next pair at @p now_s into @p pair (see the file comment); it is in progress
  /// until finished() or failed(). @return false when none waits.
  /// @param skipped  when not null, the waiting pairs skipped for it (counted dropped).
  bool next(double now_s, Payload* pair, size_t* skipped = nullptr) {
    if (payloads_.empty()) return false;
    const size_t skip = select(now_s);
    for (size_t i = 0; i < skip; ++i) payloads_.pop_front();
    *pair = std::move(payloads_.front());
    payloads_.pop_front();
    if (skipped) *skipped = skip;
    return true;
  }

 private:
  std::deque<Payload> payloads_;  // in step with the base's arrival times
};

}  // namespace endo_stereo
