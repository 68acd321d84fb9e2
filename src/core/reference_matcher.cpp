// The matching step of the paper, one pixel at a time (see reference_matcher.hpp). Read it next to
// docs/method.md section 2: each block below is one step there.

#include "endo_stereo/core/reference_matcher.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>

namespace endo_stereo {

namespace {

constexpr float kNegInf = -std::numeric_limits<float>::infinity();

/// Sums over the window of width 2 r + 1 centred on (x, y) of v, v^2 (v the 8-bit value).
void windowSums(const cv::Mat& img, int x, int y, int r, int64_t* sum, int64_t* sq) {
  *sum = *sq = 0;
  for (int yy = y - r; yy <= y + r; ++yy) {
    for (int xx = x - r; xx <= x + r; ++xx) {
      const int64_t v = img.at<uint8_t>(yy, xx);
      *sum += v;
      *sq += v * v;
    }
  }
}

/// 1 / the window's standard deviation (as sqrt((n sum v^2 - (sum v)^2) / n) / ... normalised the
/// way the NCC needs it), 0 for a flat window. n sum v^2 - (sum v)^2 is an exact integer.
float inverseDeviation(double n, double sum, double sq) {
  const double a = n * sq - sum * sum;
  return a > 0.5 ? 1.f / std::sqrt(static_cast<float>(a) / static_cast<float>(n)) : 0.f;
}

/// gamma: the standard deviation of the 3x3 Laplacian @p lap (CV_16S, of the 0..255 image) over
/// the window of width 2 r + 1 centred on (x, y): sqrt(n sum g^2 - (sum g)^2) / n.
float structure(const cv::Mat& lap, int x, int y, int r) {
  double sum = 0, sq = 0;
  for (int yy = y - r; yy <= y + r; ++yy) {
    for (int xx = x - r; xx <= x + r; ++xx) {
      const double g = lap.at<int16_t>(yy, xx);
      sum += g;
      sq += g * g;
    }
  }
  const double n = static_cast<double>(2 * r + 1) * (2 * r + 1);
  const double a = n * sq - sum * sum;
  return std::sqrt(std::max(0.f, static_cast<float>(a))) / static_cast<float>(n);
}

struct Requested {
  const cv::Mat* lo;  // CV_32S, clamped to [min_disparity, max_disparity]; lo > hi: none
  const cv::Mat* hi;
};

/// The disparities pixel (x, y) searches at half width r: its requested range, cut so that both
/// windows lie inside the images. false when empty.
bool effectiveRange(const Requested& q, int W, int H, int x, int y, int r, int* a, int* b) {
  if (x < r || x >= W - r || y < r || y >= H - r) return false;
  *a = std::max(q.lo->at<int>(y, x), x - (W - 1 - r));
  *b = std::min(q.hi->at<int>(y, x), x - r);
  return *a <= *b;
}

}  // namespace

float referenceNcc(const cv::Mat& left, const cv::Mat& right, int x, int y, int d, int r) {
  const double n = static_cast<double>(2 * r + 1) * (2 * r + 1);
  int64_t sum_l, sq_l, sum_r, sq_r;
  windowSums(left, x, y, r, &sum_l, &sq_l);
  windowSums(right, x - d, y, r, &sum_r, &sq_r);
  // Sum of (L - 128)(R - 128): an exact integer, below 2^24 in magnitude for windows up to 32 x 32,
  // so exact in float too.
  int64_t h = 0;
  for (int yy = y - r; yy <= y + r; ++yy) {
    for (int xx = x - r; xx <= x + r; ++xx) {
      h += (int64_t{left.at<uint8_t>(yy, xx)} - 128) *
           (int64_t{right.at<uint8_t>(yy, xx - d)} - 128);
    }
  }
  // S = (sum L'R' - mean L' * sum R') / (n sd_L sd_R) with L' = L - 128, R' = R - 128, evaluated as
  // (h - mean_l sum_r) * inv_l * inv_r with inv = 1 / (sqrt(n) sd), in float, in this order.
  const float mean_l = static_cast<float>((static_cast<double>(sum_l) - 128.0 * n) / n);
  const float sum_r_c = static_cast<float>(static_cast<double>(sum_r) - 128.0 * n);
  const float inv_l = inverseDeviation(n, static_cast<double>(sum_l), static_cast<double>(sq_l));
  const float inv_r = inverseDeviation(n, static_cast<double>(sum_r), static_cast<double>(sq_r));
  return (static_cast<float>(h) - mean_l * sum_r_c) * inv_l * inv_r;
}

void referenceMatch(const cv::Mat& left, const cv::Mat& right, const MatcherParams& p,
                    const SearchRange* range, MatchResult& out) {
  const std::string err = p.validate();
  if (!err.empty()) throw std::invalid_argument("referenceMatch: " + err);
  if (left.empty() || right.empty() || left.type() != CV_8UC1 || right.type() != CV_8UC1 ||
      left.size() != right.size()) {
    throw std::invalid_argument("referenceMatch: left and right must be CV_8UC1 of one size");
  }
  const int W = left.cols, H = left.rows;
  // The requested range of each pixel, clamped to [min_disparity, max_disparity].
  cv::Mat lo(H, W, CV_32S, cv::Scalar(p.min_disparity));
  cv::Mat hi(H, W, CV_32S, cv::Scalar(p.max_disparity));
  out.stats = MatchStats{};
  out.stats.total_pixels = static_cast<int64_t>(W) * H;
  if (range && !range->empty()) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const int l = range->lo.at<int16_t>(y, x), h = range->hi.at<int16_t>(y, x);
        lo.at<int>(y, x) = std::max(l, p.min_disparity);
        hi.at<int>(y, x) = std::min(h, p.max_disparity);
        const int cl = lo.at<int>(y, x), ch = hi.at<int>(y, x);
        out.stats.prior_pixels +=
            l <= h && cl <= ch && (cl > p.min_disparity || ch < p.max_disparity);
      }
    }
  }
  const Requested req{&lo, &hi};
  cv::Mat lap_l, lap_r;  // 3x3 Laplacian of the 0..255 images (|g| <= 1020)
  cv::Laplacian(left, lap_l, CV_16S, 1);
  cv::Laplacian(right, lap_r, CV_16S, 1);
  out.disparity.create(H, W, CV_32F);
  out.disparity.setTo(std::numeric_limits<float>::quiet_NaN());
  out.code.create(H, W, CV_8U);
  out.code.setTo(kCodeNotSearched);
  out.confidence.create(H, W, CV_32F);
  out.confidence.setTo(0.f);
  cv::Mat accepted(H, W, CV_8U, cv::Scalar(0));
  const float gamma_min = static_cast<float>(p.gamma_min);
  const float delta_min = static_cast<float>(p.delta_min);
  const float eps = static_cast<float>(p.epsilon_px);
  const float min_ncc_full = static_cast<float>(p.min_ncc);
  const float min_ncc_narrow = std::max(min_ncc_full, static_cast<float>(p.min_ncc_narrowed));

  // Window growth: w = w_min, w_min + dw, ... <= w_max; a pixel that fails every criterion at one
  // width is tried again at the next.
  for (int level = 0; p.window_min_px + level * p.window_step_px <= p.window_max_px; ++level) {
    const int w = p.window_min_px + level * p.window_step_px;
    const int r = w / 2;
    if (w > W || w > H) break;
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        int a, b;
        if (accepted.at<uint8_t>(y, x) || !effectiveRange(req, W, H, x, y, r, &a, &b)) continue;
        const bool narrowed =
            lo.at<int>(y, x) > p.min_disparity || hi.at<int>(y, x) < p.max_disparity;
        // Ours: a narrowed pixel is tried up to window_max_narrowed_px only (the first window
        // always); it keeps the code of its last window.
        if (narrowed && level > 0 && p.window_max_narrowed_px > 0 && w > p.window_max_narrowed_px) {
          continue;
        }
        uint8_t& code = out.code.at<uint8_t>(y, x);
        // An interior maximum needs two neighbours: at least 3 disparities.
        if (b - a < 2) {
          code = kCodeNoPeak;
          continue;
        }
        // Criterion 1, left patch: structure gamma > gamma_min.
        if (!(structure(lap_l, x, y, r) > gamma_min)) {
          code = kCodeRejectStructure;
          continue;
        }
        // The profile S(d), d = a .. b.
        std::vector<float> s;
        for (int d = a; d <= b; ++d) s.push_back(referenceNcc(left, right, x, y, d, r));
        const int n = static_cast<int>(s.size());
        auto isPeak = [&](int i) { return s[i] > s[i - 1] && s[i] >= s[i + 1]; };
        // The best peak: the highest interior local maximum, the first of equal values.
        int bi = -1;
        for (int i = 1; i + 1 < n; ++i) {
          if (isPeak(i) && (bi < 0 || s[i] > s[bi])) bi = i;
        }
        if (bi < 0) {
          code = kCodeNoPeak;
          continue;
        }
        // The second: the highest other peak, or a range end where S rises towards the end.
        float second = kNegInf;
        for (int i = 1; i + 1 < n; ++i) {
          if (i != bi && isPeak(i)) second = std::max(second, s[i]);
        }
        if (s[0] > s[1]) second = std::max(second, s[0]);
        if (s[n - 1] > s[n - 2]) second = std::max(second, s[n - 1]);
        const int d_lr = a + bi;
        // Criterion 1, right patch at the best peak.
        if (!(structure(lap_r, x - d_lr, y, r) > gamma_min)) {
          code = kCodeRejectStructure;
          continue;
        }
        // Criterion 2: delta = S(best) - S(second) > delta_min (a single peak against -1, the
        // lowest NCC), and, ours, S(best) >= min_ncc (min_ncc_narrowed for a narrowed range).
        const float delta = s[bi] - (second == kNegInf ? -1.f : second);
        if (!(delta > delta_min) || s[bi] < (narrowed ? min_ncc_narrow : min_ncc_full)) {
          code = kCodeRejectPeakGap;
          continue;
        }
        // Criterion 3: match back from the right pixel q = x - d_lr along the same row; its best
        // disparity d_RL over the left pixels q + d that search d (ties: the smallest d) must
        // agree: |d_LR - d_RL| < epsilon (the paper's |d_LR + d_RL| with d_RL counted negative).
        const int q = x - d_lr;
        float rl_best = kNegInf;
        int d_rl = 0;
        for (int d = p.min_disparity; d <= p.max_disparity; ++d) {
          int a2, b2;
          if (!effectiveRange(req, W, H, q + d, y, r, &a2, &b2) || d < a2 || d > b2) continue;
          const float v = referenceNcc(left, right, q + d, y, d, r);
          if (v > rl_best) {
            rl_best = v;
            d_rl = d;
          }
        }
        if (!(std::fabs(static_cast<float>(d_lr) - static_cast<float>(d_rl)) < eps)) {
          code = kCodeRejectLeftRight;
          continue;
        }
        // Accepted. Ours: sub-pixel disparity from the parabola through the peak and its two
        // neighbours; confidence = delta clamped to [0, 1].
        float sub = 0.f;
        if (p.subpixel) {
          const float den = s[bi - 1] - 2.f * s[bi] + s[bi + 1];
          if (den < 0.f) sub = std::clamp(0.5f * (s[bi - 1] - s[bi + 1]) / den, -0.5f, 0.5f);
        }
        out.disparity.at<float>(y, x) = static_cast<float>(d_lr) + sub;
        out.confidence.at<float>(y, x) = std::clamp(delta, 0.f, 1.f);
        code = static_cast<uint8_t>(kCodeAcceptedBase + level);
        accepted.at<uint8_t>(y, x) = 1;
      }
    }
  }
}

}  // namespace endo_stereo
