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

namespace {

void checkInputs(const cv::Mat& left, const cv::Mat& right, const MatcherParams& p) {
  const std::string err = p.validate();
  if (!err.empty()) throw std::invalid_argument("referenceMatch: " + err);
  if (left.empty() || right.empty() || left.type() != CV_8UC1 || right.type() != CV_8UC1 ||
      left.size() != right.size()) {
    throw std::invalid_argument("referenceMatch: left and right must be CV_8UC1 of one size");
  }
}

/// The requested range of each pixel in @p lo, @p hi (CV_32S, set to the whole search range): @p
/// range where given, clamped to [min_disparity, max_disparity]. Counts the pixels a non-empty
/// range narrows into stats.prior_pixels.
void requestedRanges(const MatcherParams& p, const SearchRange* range, cv::Mat& lo, cv::Mat& hi,
                     MatchStats& stats) {
  if (!range || range->empty()) return;
  for (int y = 0; y < lo.rows; ++y) {
    for (int x = 0; x < lo.cols; ++x) {
      const int l = range->lo.at<int16_t>(y, x), h = range->hi.at<int16_t>(y, x);
      lo.at<int>(y, x) = std::max(l, p.min_disparity);
      hi.at<int>(y, x) = std::min(h, p.max_disparity);
      const int cl = lo.at<int>(y, x), ch = hi.at<int>(y, x);
      stats.prior_pixels += l <= h && cl <= ch && (cl > p.min_disparity || ch < p.max_disparity);
    }
  }
}

/// The outputs before matching: no disparity (NaN), code kCodeNotSearched, confidence 0.
void initOutputs(int W, int H, MatchResult& out) {
  out.disparity.create(H, W, CV_32F);
  out.disparity.setTo(std::numeric_limits<float>::quiet_NaN());
  out.code.create(H, W, CV_8U);
  out.code.setTo(kCodeNotSearched);
  out.confidence.create(H, W, CV_32F);
  out.confidence.setTo(0.f);
}

/// The 3x3 Laplacian of a 0..255 image (CV_16S, |g| <= 1020).
cv::Mat laplacian(const cv::Mat& img) {
  cv::Mat lap;
  cv::Laplacian(img, lap, CV_16S, 1);
  return lap;
}

/// Everything the per-pixel steps read: the images, their Laplacians, the requested ranges and
/// the thresholds of the criteria.
struct Reference {
  const cv::Mat& left;
  const cv::Mat& right;
  const MatcherParams& p;
  int W, H;
  Requested req;
  cv::Mat lap_l, lap_r;  // 3x3 Laplacian of the 0..255 images (|g| <= 1020)
  float gamma_min, delta_min, eps, min_ncc_full, min_ncc_narrow;
};

/// The peaks of a profile S: the best, the highest interior local maximum (the first of equal
/// values; -1: none), and the second, the highest other peak or a range end where S rises towards
/// the end (kNegInf: none).
struct Peaks {
  int best;
  float second;
};

Peaks findPeaks(const std::vector<float>& s) {
  const int n = static_cast<int>(s.size());
  auto isPeak = [&](int i) { return s[i] > s[i - 1] && s[i] >= s[i + 1]; };
  int bi = -1;
  for (int i = 1; i + 1 < n; ++i) {
    if (isPeak(i) && (bi < 0 || s[i] > s[bi])) bi = i;
  }
  if (bi < 0) return Peaks{-1, kNegInf};
  float second = kNegInf;
  for (int i = 1; i + 1 < n; ++i) {
    if (i != bi && isPeak(i)) second = std::max(second, s[i]);
  }
  if (s[0] > s[1]) second = std::max(second, s[0]);
  if (s[n - 1] > s[n - 2]) second = std::max(second, s[n - 1]);
  return Peaks{bi, second};
}

/// Criterion 3's d_RL: the best disparity of the right pixel q along row y at half width r, over
/// the left pixels q + d that search d (ties: the smallest d).
int rightToLeftDisparity(const Reference& ref, int q, int y, int r) {
  const MatcherParams& p = ref.p;
  float rl_best = kNegInf;
  int d_rl = 0;
  for (int d = p.min_disparity; d <= p.max_disparity; ++d) {
    int a2, b2;
    if (!effectiveRange(ref.req, ref.W, ref.H, q + d, y, r, &a2, &b2) || d < a2 || d > b2) continue;
    const float v = referenceNcc(ref.left, ref.right, q + d, y, d, r);
    if (v > rl_best) {
      rl_best = v;
      d_rl = d;
    }
  }
  return d_rl;
}

/// Ours: the sub-pixel offset of the peak s[bi] from the parabola through it and its two
/// neighbours (0 unless the parabola opens downwards), in [-0.5, 0.5].
float subpixelOffset(const std::vector<float>& s, int bi) {
  const float den = s[bi - 1] - 2.f * s[bi] + s[bi + 1];
  return den < 0.f ? std::clamp(0.5f * (s[bi - 1] - s[bi + 1]) / den, -0.5f, 0.5f) : 0.f;
}

/// The criteria, in the paper's order, for pixel (x, y) at half width r over its effective range
/// [a, b] (@p narrowed: its requested range is narrower than the search range). Returns its code
/// (@p accepted when it passes them all); an accepted pixel gets *disparity and *confidence.
uint8_t matchPixel(const Reference& ref, int x, int y, int r, int a, int b, bool narrowed,
                   uint8_t accepted, float* disparity, float* confidence) {
  // An interior maximum needs two neighbours: at least 3 disparities.
  if (b - a < 2) return kCodeNoPeak;
  // Criterion 1, left patch: structure gamma > gamma_min.
  if (!(structure(ref.lap_l, x, y, r) > ref.gamma_min)) return kCodeRejectStructure;
  // The profile S(d), d = a .. b, and its peaks.
  std::vector<float> s;
  for (int d = a; d <= b; ++d) s.push_back(referenceNcc(ref.left, ref.right, x, y, d, r));
  const Peaks pk = findPeaks(s);
  if (pk.best < 0) return kCodeNoPeak;
  const int bi = pk.best;
  const int d_lr = a + bi;
  // Criterion 1, right patch at the best peak.
  if (!(structure(ref.lap_r, x - d_lr, y, r) > ref.gamma_min)) return kCodeRejectStructure;
  // Criterion 2: delta = S(best) - S(second) > delta_min (a single peak against -1, the lowest
  // NCC), and, ours, S(best) >= min_ncc (min_ncc_narrowed for a narrowed range).
  const float delta = s[bi] - (pk.second == kNegInf ? -1.f : pk.second);
  if (!(delta > ref.delta_min) || s[bi] < (narrowed ? ref.min_ncc_narrow : ref.min_ncc_full)) {
    return kCodeRejectPeakGap;
  }
  // Criterion 3: match back from the right pixel q = x - d_lr along the same row; its best
  // disparity d_RL must agree: |d_LR - d_RL| < epsilon (the paper's |d_LR + d_RL| with d_RL
  // counted negative).
  const int d_rl = rightToLeftDisparity(ref, x - d_lr, y, r);
  if (!(std::fabs(static_cast<float>(d_lr) - static_cast<float>(d_rl)) < ref.eps)) {
    return kCodeRejectLeftRight;
  }
  // Accepted. Ours: sub-pixel disparity; confidence = delta clamped to [0, 1].
  const float sub = ref.p.subpixel ? subpixelOffset(s, bi) : 0.f;
  *disparity = static_cast<float>(d_lr) + sub;
  *confidence = std::clamp(delta, 0.f, 1.f);
  return accepted;
}

/// One window size of the growth sequence (index @p level, width w): every pixel not accepted
/// yet with a non-empty effective range gets the code of matchPixel; accepted ones are marked in
/// @p accepted.
void matchWindow(const Reference& ref, int level, int w, cv::Mat& accepted, MatchResult& out) {
  const MatcherParams& p = ref.p;
  const int r = w / 2;
  const uint8_t accepted_code = static_cast<uint8_t>(kCodeAcceptedBase + level);
  for (int y = 0; y < ref.H; ++y) {
    for (int x = 0; x < ref.W; ++x) {
      int a, b;
      if (accepted.at<uint8_t>(y, x) || !effectiveRange(ref.req, ref.W, ref.H, x, y, r, &a, &b)) {
        continue;
      }
      const bool narrowed = ref.req.lo->at<int>(y, x) > p.min_disparity ||
                            ref.req.hi->at<int>(y, x) < p.max_disparity;
      uint8_t& code = out.code.at<uint8_t>(y, x);
      code = matchPixel(ref, x, y, r, a, b, narrowed, accepted_code, &out.disparity.at<float>(y, x),
                        &out.confidence.at<float>(y, x));
      if (code == accepted_code) accepted.at<uint8_t>(y, x) = 1;
    }
  }
}

}  // namespace

void referenceMatch(const cv::Mat& left, const cv::Mat& right, const MatcherParams& p,
                    const SearchRange* range, MatchResult& out) {
  checkInputs(left, right, p);
  const int W = left.cols, H = left.rows;
  out.stats = MatchStats{};
  out.stats.total_pixels = static_cast<int64_t>(W) * H;
  // The requested range of each pixel, clamped to [min_disparity, max_disparity].
  cv::Mat lo(H, W, CV_32S, cv::Scalar(p.min_disparity));
  cv::Mat hi(H, W, CV_32S, cv::Scalar(p.max_disparity));
  requestedRanges(p, range, lo, hi, out.stats);
  const float min_ncc_full = static_cast<float>(p.min_ncc);
  const Reference ref{left,
                      right,
                      p,
                      W,
                      H,
                      Requested{&lo, &hi},
                      laplacian(left),
                      laplacian(right),
                      static_cast<float>(p.gamma_min),
                      static_cast<float>(p.delta_min),
                      static_cast<float>(p.epsilon_px),
                      min_ncc_full,
                      std::max(min_ncc_full, static_cast<float>(p.min_ncc_narrowed))};
  initOutputs(W, H, out);
  cv::Mat accepted(H, W, CV_8U, cv::Scalar(0));
  // Window growth: w = w_min, w_min + dw, ... <= w_max; a pixel that fails every criterion at one
  // width is tried again at the next.
  for (int level = 0; p.window_min_px + level * p.window_step_px <= p.window_max_px; ++level) {
    const int w = p.window_min_px + level * p.window_step_px;
    if (w > W || w > H) break;
    matchWindow(ref, level, w, accepted, out);
  }
}

}  // namespace endo_stereo
