// /diagnostics of the ROS side, and the explanation of a silent input. See reconstruction.hpp.
#include "endo_stereo/ros/reconstruction.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <vector>

namespace endo_stereo {
namespace {

// Latencies kept for the median / p90 in the diagnostics (about 10 s at 25 fps).
constexpr size_t kLatencyWindow = 250;

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return std::nan("");
  const size_t k = static_cast<size_t>(std::round(q * (v.size() - 1)));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

}  // namespace

void Reconstruction::recordFigures(const Pair& pair, const ros::WallTime& t_process,
                                   const ros::WallTime& t_publish, const ros::WallTime& t_done) {
  const double latency_ms = (t_done - pair.arrival).toSec() * 1e3;
  if (!first_pair_logged_) {
    // The first pair is the slowest (full-range search, fresh buffers, threads started): say
    // where its time went, once, since the pairs behind it wait for it.
    first_pair_logged_ = true;
    ROS_INFO("%s: first pair out %.1f ms after it arrived: waited %.1f, pipeline %.1f "
             "(preprocess %.1f, rectify %.1f, match %.1f, temporal %.1f, cloud %.1f), "
             "publishing %.1f ms; later pairs are faster",
             name_.c_str(), latency_ms, (t_process - pair.arrival).toSec() * 1e3,
             out_.total_ms, out_.preprocess_ms, out_.rectify_ms, out_.match_ms, out_.temporal_ms,
             out_.cloud_ms, (t_done - t_publish).toSec() * 1e3);
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  latencies_ms_.push_back(latency_ms);
  if (latencies_ms_.size() > kLatencyWindow) latencies_ms_.pop_front();
  pipeline_ms_.push_back(out_.total_ms);
  if (pipeline_ms_.size() > kLatencyWindow) pipeline_ms_.pop_front();
  last_density_ = out_.match.stats.density();
  if (out_.rect_quality.valid || out_.rect_quality.misaligned) last_quality_ = out_.rect_quality;
  last_priors_used_ = out_.priors_used;
  last_prior_stats_ = out_.prior_stats;
  // The temporal state a frame used: a reset before it (any reason) starts a new run at 1.
  frames_since_reset_ = out_.priors_reset ? 1 : frames_since_reset_ + 1;
}

std::string Reconstruction::explainSilence(double silent_s) const {
  std::string left = nh_.resolveName(left_topic_), right = nh_.resolveName(right_topic_);
  if (ros_params_.image_transport != "raw") {
    left += " (transport " + ros_params_.image_transport + ")";
    right += " (transport " + ros_params_.image_transport + ")";
  }
  std::ostringstream m;
  m.precision(1);
  m << std::fixed << "no image on " << left << " or " << right << " for " << silent_s
    << " s although outputs have subscribers (rectify mode " << toString(mode_) << ")";
  ros::master::V_TopicInfo topics;
  if (!ros::master::getTopics(topics)) return m.str();
  auto published = [&](const std::string& relative) {
    const std::string name = nh_.resolveName(relative);
    for (const auto& t : topics) {
      if (t.name == name) return true;
    }
    return false;
  };
  const bool ours = published(left_topic_) || published(right_topic_);
  if (mode_ != RectifyMode::kPassThrough &&
      (published("left/image_rect") || published("left/image_rect_color"))) {
    m << "; " << nh_.resolveName(published("left/image_rect") ? "left/image_rect"
                                                              : "left/image_rect_color")
      << " is published: for rectified input set rectify_mode:=pass_through (~rectify/mode "
         "pass_through)";
  } else if (mode_ == RectifyMode::kPassThrough && published("left/image_raw")) {
    m << "; " << nh_.resolveName("left/image_raw")
      << " is published: for raw input set rectify_mode:=calibrated (with camera_info) or "
         "uncalibrated";
  } else if (ours) {
    m << "; the topics are advertised but send nothing: is the source paused (rosbag play "
         "--pause, a stopped /clock) or on another image_transport (~image_transport "
      << ros_params_.image_transport << ")?";
  } else {
    m << "; nothing publishes them: remap " << left_topic_ << " and " << right_topic_
      << " to the camera's topics (endo_stereo.launch: left_image:=..., right_image:=...)";
  }
  return m.str();
}

void Reconstruction::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  const ros::WallTime now = ros::WallTime::now();
  // Silence: subscribed, and no image on either side for no_input_warn_s. The explanation asks
  // the master, so the scheduler says when it is due (and when the log line is).
  SilenceCheck silence;
  size_t waiting = 0;
  {
    std::lock_guard<std::mutex> lock(sched_mutex_);
    silence = scheduler_.checkSilence(now.toSec());
    waiting = scheduler_.waiting();
  }
  const double silent_s = silence.silent_s;
  const bool silent = silence.silent;
  if (silent) {
    if (silence.explain) silence_message_ = explainSilence(silent_s);
    if (silence.log) ROS_WARN("%s: %s", name_.c_str(), silence_message_.c_str());
  } else {
    silence_message_.clear();
  }
  const ReconstructionCounters c = counters();
  std::lock_guard<std::mutex> lock(stats_mutex_);
  const double dt = std::max(1e-6, (now - diag_prev_time_).toSec());
  const double in_rate = (c.pairs_received - diag_prev_.pairs_received) / dt;
  const double out_rate = (c.pairs_processed - diag_prev_.pairs_processed) / dt;
  const int64_t new_drops = c.pairs_dropped - diag_prev_.pairs_dropped;
  const int64_t new_rejects = c.pairs_rejected - diag_prev_.pairs_rejected;
  const std::vector<double> lat(latencies_ms_.begin(), latencies_ms_.end());
  const std::vector<double> pipe(pipeline_ms_.begin(), pipeline_ms_.end());
  const bool subscribed = subscribed_.load();
  const std::string frozen = frozen_views_->message();
  std::string step_state = "off (~step_check_period_frames 0)", step_offset = "unknown";
  bool out_of_step = false;
  {
    std::lock_guard<std::mutex> step_lock(step_mutex_);
    if (step_) {
      step_state = step_->describe();
      if (step_->verdictKnown()) {
        step_offset = std::to_string(step_->offset());
        out_of_step = step_->offset() != 0;
      }
    }
  }

  if (!subscribed) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "idle: no subscribers to the outputs");
  } else if (new_rejects > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "input rejected: " + last_error_);
  } else if (!frozen.empty()) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, frozen);
  } else if (out_of_step) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "views " + step_state);
  } else if (silent) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no input: " + silence_message_);
  } else if (new_drops > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 "overloaded: " + std::to_string(new_drops) + " pairs dropped");
  } else if (last_quality_.valid && last_quality_.warning) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "rectification residual high");
  } else if (last_quality_.misaligned) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                 "rectification: no row alignment found: " + last_quality_.message);
  } else if (c.pairs_received == diag_prev_.pairs_received &&
             (c.left_images != diag_prev_.left_images || c.right_images != diag_prev_.right_images)) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "images do not pair: " + last_error_);
  } else {
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "ok");
  }
  stat.add("inputs subscribed", subscribed);
  stat.add("seconds without input", silent_s);
  stat.add("input pair rate (Hz)", in_rate);
  stat.add("output rate (Hz)", out_rate);
  stat.add("left images", c.left_images);
  stat.add("right images", c.right_images);
  stat.add("pairs received", c.pairs_received);
  stat.add("pairs processed", c.pairs_processed);
  stat.add("pairs dropped", c.pairs_dropped);
  stat.add("pairs rejected", c.pairs_rejected);
  stat.add("pairs waiting", static_cast<int>(waiting));
  stat.add("stream restarts", c.restarts);
  stat.add("tf failures", c.tf_failures);
  stat.add("pairs withheld (frozen view)", c.pairs_frozen);
  stat.add("geometry changes", c.geometry_changes);
  stat.add("temporal resets", c.temporal_resets);
  stat.add("last temporal reset", last_reset_reason_);
  stat.add("frames since temporal reset", frames_since_reset_);
  stat.add("left view unchanged (pairs)", frozen_views_->unchangedRun(true));
  stat.add("right view unchanged (pairs)", frozen_views_->unchangedRun(false));
  stat.add("right frame offset", step_offset);
  stat.add("views in step", step_state);
  stat.add("latency median (ms)", percentile(lat, 0.5));
  stat.add("latency p90 (ms)", percentile(lat, 0.9));
  // The core's share of the latency (Pipeline::process); the rest is waiting in the backlog,
  // conversions and publishing.
  stat.add("pipeline median (ms)", percentile(pipe, 0.5));
  stat.add("density", last_density_);
  stat.add("priors used", last_priors_used_);
  {
    // What the last frame searched: narrowed around priors, the full range, or nothing yet
    // (deferred: TemporalParams::full_range_period_frames).
    const TemporalPriorStats& ps = last_prior_stats_;
    const double n = double(ps.narrowed_pixels + ps.full_range_pixels + ps.deferred_pixels);
    stat.add("pixels narrowed by priors (share)", n > 0 ? double(ps.narrowed_pixels) / n : 0.0);
    stat.add("pixels deferred (share)", n > 0 ? double(ps.deferred_pixels) / n : 0.0);
  }
  stat.add("rectification residual median (px)",
           last_quality_.valid ? last_quality_.median_offset_px : std::nan(""));
  stat.add("rectification residual p90 (px)",
           last_quality_.valid ? last_quality_.p90_offset_px : std::nan(""));
  stat.add("last error", last_error_);
  diag_prev_ = c;
  diag_prev_time_ = now;
}

}  // namespace endo_stereo
