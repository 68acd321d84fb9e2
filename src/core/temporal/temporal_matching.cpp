// The matching passes of one frame with temporal priors. See temporal_matching.hpp.
#include "endo_stereo/core/temporal_matching.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

#include "match/depth_edge_filter.hpp"

namespace endo_stereo {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

PostFilterParams withoutPostFilter(PostFilterParams p) {
  p.remove_outliers = false;
  p.fill_holes = false;
  return p;
}

// The passes match only: the depth-edge measure runs on each pass's map here, as
// RobustMatcher::compute() runs it on its own, and the post-filter once on the frame's map.
MatcherParams withoutEdgeTest(MatcherParams p) {
  p.edge_disparity_jump_px = 0.0;
  return p;
}

bool edgeTestOn(const MatcherParams& p) {
  return p.edge_disparity_jump_px > 0.0;
}

}  // namespace

void applyPostFilter(MatchResult& result, const PostFilterParams& fp) {
  const auto t0 = Clock::now();
  cv::Mat& disparity = result.disparity;
  cv::Mat& code = result.code;
  cv::Mat& confidence = result.confidence;
  const int W = disparity.cols, H = disparity.rows;
  if (fp.remove_outliers) removeIsolatedOutliers(disparity, code, fp);
  if (fp.fill_holes) {
    const cv::Mat code_before = code.clone();
    fillSmallHoles(disparity, code, fp);
    setFilledConfidenceRows(code, code_before, confidence, 0, H);
  }
  // Counters after the filters; a rejected pixel has confidence 0.
  MatchStats& st = result.stats;
  st.rejected.fill(0);
  st.valid_pixels = 0;
  for (int y = 0; y < H; ++y) {
    const uint8_t* cd = code.ptr<uint8_t>(y);
    float* cf = confidence.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const bool filled = cd[x] == kCodeFilled;
      const bool rejected = (cd[x] < kNumRejectCodes) & !filled;
      if (cd[x] < kNumRejectCodes) ++st.rejected[cd[x]];
      cf[x] = rejected ? 0.f : cf[x];
      st.valid_pixels += (cd[x] >= kCodeAcceptedBase) | filled;
    }
  }
  st.filter_ms = msSince(t0);
}

TemporalMatcher::TemporalMatcher(const MatcherParams& matcher_params,
                                 const PostFilterParams& filter_params)
    : matcher_params_(matcher_params),
      filter_params_(filter_params),
      matcher_(withoutEdgeTest(matcher_params), withoutPostFilter(filter_params)) {}

void TemporalMatcher::setParams(const MatcherParams& matcher_params,
                                const PostFilterParams& filter_params) {
  // Validate everything first so that a throw leaves the old parameters in place.
  std::string err = matcher_params.validate();
  if (err.empty()) err = filter_params.validate();
  if (!err.empty()) throw std::invalid_argument(err);
  matcher_.setParams(withoutEdgeTest(matcher_params), withoutPostFilter(filter_params));
  matcher_params_ = matcher_params;
  filter_params_ = filter_params;
}

namespace {

// Accepted pixels per window size, from the codes (kCodeAcceptedBase + window index), before the
// post-filter (as RobustMatcher::compute() counts them).
void countAcceptedPerWindow(MatchResult& out) {
  out.stats.accepted_per_window.fill(0);
  for (int y = 0; y < out.code.rows; ++y) {
    const uint8_t* c = out.code.ptr<uint8_t>(y);
    for (int x = 0; x < out.code.cols; ++x) {
      if (c[x] >= kCodeAcceptedBase) {
        const int k = c[x] - kCodeAcceptedBase;
        if (k < int(out.stats.accepted_per_window.size())) {
          ++out.stats.accepted_per_window[size_t(k)];
        }
      }
    }
  }
}

}  // namespace

// One matching pass over @p range (nullptr: the full range), then the depth-edge measure on its
// map, as RobustMatcher::compute() runs it after matching.
void TemporalMatcher::matchPass(const cv::Mat& left, const cv::Mat& right,
                                const SearchRange* range, MatchResult& out, PassTimes& times) {
  matcher_.compute(left, right, out, range);
  times.match_ms += out.stats.match_ms;
  times.prepare_ms += out.stats.prepare_ms;
  times.edge_ms += out.stats.edge_ms;
  if (!edgeTestOn(matcher_params_)) return;
  const auto t = Clock::now();
  // The window index of each accepted pixel, from its code (kCodeAcceptedBase + index).
  window_idx_.create(out.code.size(), CV_8UC1);
  for (int y = 0; y < out.code.rows; ++y) {
    const uint8_t* c = out.code.ptr<uint8_t>(y);
    uint8_t* w = window_idx_.ptr<uint8_t>(y);
    for (int x = 0; x < out.code.cols; ++x) {
      w[x] = c[x] >= kCodeAcceptedBase ? uint8_t(c[x] - kCodeAcceptedBase) : uint8_t(0);
    }
  }
  const MatcherParams& mp = matcher_params_;
  const int num_levels = (mp.window_max_px - mp.window_min_px) / mp.window_step_px + 1;
  rejectEdgeStraddlers(mp, left, right, num_levels, window_idx_, out, edge_tmp_[0], edge_tmp_[1],
                       edge_tmp_[2], edge_tmp_[3], edge_tmp_[4]);
  const double ms = msSince(t);
  times.match_ms += ms;
  times.edge_ms += ms;
}

void TemporalMatcher::compute(const cv::Mat& left, const cv::Mat& right,
                              TemporalTracker& temporal, const SearchRange* range,
                              MatchResult& out, TemporalMatchReport* report) {
  TemporalMatchReport r;
  PassTimes times;
  // No usable prior (range == nullptr: the first frame, after a reset): the full range.
  matchPass(left, right, range, out, times);
  if (range && temporal.rejectPriors(out.disparity)) {
    // The priors described another scene: the frame again over the full range.
    r.priors_rejected = true;
    range = nullptr;
    matchPass(left, right, range, out, times);
  }
  r.priors_used = range != nullptr;
  countAcceptedPerWindow(out);
  applyPostFilter(out, filter_params_);
  // Matching time of all passes (the post-filter is filter_ms).
  out.stats.match_ms = times.match_ms;
  out.stats.prepare_ms = times.prepare_ms;
  out.stats.edge_ms = times.edge_ms;
  if (report) *report = r;
}

}  // namespace endo_stereo
