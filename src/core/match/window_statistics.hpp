// Private to the core: the window statistics of the matcher. The NCC needs, per window, the mean
// and the inverse deviation of the left patch and the sum and inverse deviation of the right
// patch; the structure criterion needs gamma, the standard deviation of the 3x3 Laplacian over
// the window. All come from integral images (int32 taken modulo 2^32, exact through boxAt),
// either row-wide and vectorised (computeRowMaps, rowMapsR, ensureMapsL) or one column at a
// time (need*), with the same expressions, so the values are identical either way.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <opencv2/core.hpp>

#include "matcher_internal.hpp"

namespace endo_stereo {
namespace detail {

// Window box sum of a CV_32S integral image at (x, y), half width r. The integral may have
// wrapped modulo 2^32 (wrappedIntegrals): every window sum of this matcher (at most 32 x 32 terms
// of magnitude <= 1020^2) lies in (-2^31, 2^31), so the four-corner difference taken modulo 2^32
// is the exact sum.
inline double boxAt(const cv::Mat& integral, int x, int y, int r) {
  const uint32_t* top = integral.ptr<uint32_t>(y - r);
  const uint32_t* bot = integral.ptr<uint32_t>(y + r + 1);
  return static_cast<double>(
      static_cast<int32_t>((bot[x + r + 1] - top[x + r + 1]) - (bot[x - r] - top[x - r])));
}

/// Left statistics of column x of row y (inside the border), into s.maps. The same expressions
/// as statsRowInt/gammaRowInt, so lazily and row-wide computed values are identical.
// n * sum(x^2) - sum(x)^2 is exact in double (integers below 2^53); the rest runs in float,
// which vectorises twice as wide. Every path uses these two functions, so values agree.
inline float invStd(double n, double sum, double sq) {
  const double a = n * sq - sum * sum;
  return a > 0.5 ? 1.f / std::sqrt(static_cast<float>(a) / static_cast<float>(n)) : 0.f;
}
inline float gammaOf(double n, double sum, double sq) {
  const double a = n * sq - sum * sum;  // n^2 times the variance of the Laplacian
  return std::sqrt(std::max(0.f, static_cast<float>(a))) / static_cast<float>(n);
}

inline void computeMapL(const WindowLevel& c, RowScratch& s, int x, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  const double sum = boxAt(c.im->int_l, x, y, c.r);
  const double sq = boxAt(c.im->sq_l, x, y, c.r);
  s.maps.mean_l[x] = static_cast<float>((sum - 128.0 * n) / n);
  s.maps.inv_l[x] = invStd(n, sum, sq);
}
inline void computeGammaL(const WindowLevel& c, RowScratch& s, int x, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  s.maps.gamma_l[x] =
      gammaOf(n, boxAt(c.im->int_lap_l, x, y, c.r), boxAt(c.im->sq_lap_l, x, y, c.r));
}
inline void computeMapR(const WindowLevel& c, RowScratch& s, int q, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  const double sum = boxAt(c.im->int_r, q, y, c.r);
  const double sq = boxAt(c.im->sq_r, q, y, c.r);
  s.maps.sum_r[q] = static_cast<float>(sum - 128.0 * n);
  s.maps.inv_r[q] = invStd(n, sum, sq);
}
inline void computeGammaR(const WindowLevel& c, RowScratch& s, int q, int y) {
  const double n = static_cast<double>(c.w) * c.w;
  s.maps.gamma_r[q] =
      gammaOf(n, boxAt(c.im->int_lap_r, q, y, c.r), boxAt(c.im->sq_lap_r, q, y, c.r));
}

// The row-wide statistics are the same expressions as invStd/gammaOf, split into passes that

inline void needMapL(const WindowLevel& c, RowScratch& s, int x, int y) {
  if (s.maps.stamp_l[x] != s.stamp) {
    computeMapL(c, s, x, y);
    s.maps.stamp_l[x] = s.stamp;
  }
}
inline void needMapR(const WindowLevel& c, RowScratch& s, int q, int y) {
  if (s.maps.stamp_r[q] != s.stamp) {
    computeMapR(c, s, q, y);
    s.maps.stamp_r[q] = s.stamp;
  }
}
inline void needGammaL(const WindowLevel& c, RowScratch& s, int x, int y) {
  if (s.maps.stamp_gl[x] != s.stamp) {
    computeGammaL(c, s, x, y);
    s.maps.stamp_gl[x] = s.stamp;
  }
}
inline void needGammaR(const WindowLevel& c, RowScratch& s, int q, int y) {
  if (s.maps.stamp_gr[q] != s.stamp) {
    computeGammaR(c, s, q, y);
    s.maps.stamp_gr[q] = s.stamp;
  }
}

/// Integral images (CV_32S, (H + 1) x (W + 1), zero first row and column) of v and v^2 for the
/// 8-bit image @p img and of g and g^2 for its Laplacian @p lap (CV_16S), all modulo 2^32.
void wrappedIntegrals(const cv::Mat& img, const cv::Mat& lap, cv::Mat& sum, cv::Mat& sq,
                      cv::Mat& int_lap, cv::Mat& sq_lap);

/// All statistics of row y (columns r .. W - 1 - r), as computeMapL/R give them one by one.
/// With @p with_gamma false only the NCC statistics are computed, on columns [x0, x1] (the
/// structure values are then computed lazily where needed).
void computeRowMaps(const WindowLevel& c, RowScratch& s, int y, bool with_gamma = true, int x0 = -1,
                    int x1 = -1);

/// Right NCC statistics of row y on columns [x0, x1] (inside the border), with their mirrored
/// copies, marked computed for this row.
void rowMapsR(const WindowLevel& c, RowScratch& s, int y, int x0, int x1);

/// Left NCC statistics of row y on the columns of [x0, x1] (inside the border) not yet computed
/// for this row, marked computed.
void ensureMapsL(const WindowLevel& c, RowScratch& s, int y, int x0, int x1);

}  // namespace detail
}  // namespace endo_stereo
