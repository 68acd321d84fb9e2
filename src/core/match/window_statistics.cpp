// The window statistics of the matcher (see window_statistics.hpp): integral images of the views,
// of their squares, of the Laplacian and of its square, and the row-wide statistics from them.

#include "window_statistics.hpp"

#if defined(__SSE2__)
#include <immintrin.h>
#endif
#include <algorithm>
#include <cmath>
#include <cstring>

#include "simd.hpp"

namespace endo_stereo {
namespace detail {

using namespace simd;

namespace {

/// Inclusive prefix sum over the 8 lanes of @p v (three shifted adds), plus @p carry in every lane.
ES_INLINE V8u lanePrefix(V8u v, V8u carry) {
  const V8u z = {0, 0, 0, 0, 0, 0, 0, 0};
  v += __builtin_shufflevector(z, v, 0, 8, 9, 10, 11, 12, 13, 14);
  v += __builtin_shufflevector(z, v, 0, 1, 8, 9, 10, 11, 12, 13);
  v += __builtin_shufflevector(z, v, 0, 1, 2, 3, 8, 9, 10, 11);
  return v + carry;
}
ES_INLINE V8u lastLane(V8u v) { return __builtin_shufflevector(v, v, 7, 7, 7, 7, 7, 7, 7, 7); }

/// One row of the four integral images (see wrappedIntegrals): out[x + 1] = out_above[x + 1] +
/// the row's prefix sum up to x, for v, v^2, g, g^2; modulo 2^32. Eight columns at a time (the
/// row's prefix sums within a vector by shifted adds, the running total carried from vector to
/// vector), the rest one by one; unsigned 32-bit additions, so the same values in any order.
ES_KERNEL void integralRow(int W, const uint8_t* __restrict v, const int16_t* __restrict g,
                           const uint32_t* __restrict pv, const uint32_t* __restrict ps,
                           const uint32_t* __restrict pg, const uint32_t* __restrict pq,
                           uint32_t* __restrict ov, uint32_t* __restrict os,
                           uint32_t* __restrict og, uint32_t* __restrict oq) {
  typedef uint8_t V8b __attribute__((vector_size(8)));
  typedef int16_t V8s __attribute__((vector_size(16)));
  typedef int32_t V8i32 __attribute__((vector_size(32)));
  ov[0] = os[0] = og[0] = oq[0] = 0;
  V8u cv = {0, 0, 0, 0, 0, 0, 0, 0}, cs = cv, cg = cv, cq = cv;
  auto put = [](uint32_t* o, const uint32_t* p, V8u sum) {
    V8u above;
    std::memcpy(&above, p, sizeof(above));
    const V8u out = sum + above;
    std::memcpy(o, &out, sizeof(out));
  };
  int x = 0;
  for (; x + 8 <= W; x += 8) {
    V8b vb;
    V8s gs;
    std::memcpy(&vb, v + x, sizeof(vb));
    std::memcpy(&gs, g + x, sizeof(gs));
    const V8u a = __builtin_convertvector(vb, V8u);
    const V8i32 gi = __builtin_convertvector(gs, V8i32);
    cv = lanePrefix(a, cv);
    cs = lanePrefix(a * a, cs);
    cg = lanePrefix(reinterpret_cast<V8u>(gi), cg);
    cq = lanePrefix(reinterpret_cast<V8u>(gi * gi), cq);
    put(ov + x + 1, pv + x + 1, cv);
    put(os + x + 1, ps + x + 1, cs);
    put(og + x + 1, pg + x + 1, cg);
    put(oq + x + 1, pq + x + 1, cq);
    cv = lastLane(cv);
    cs = lastLane(cs);
    cg = lastLane(cg);
    cq = lastLane(cq);
  }
  uint32_t rv = cv[0], rs = cs[0], rg = cg[0], rq = cq[0];
  for (; x < W; ++x) {
    const uint32_t vv = v[x];
    const int32_t gg = g[x];
    rv += vv;
    rs += vv * vv;
    rg += static_cast<uint32_t>(gg);
    rq += static_cast<uint32_t>(gg * gg);
    ov[x + 1] = rv + pv[x + 1];
    os[x + 1] = rs + ps[x + 1];
    og[x + 1] = rg + pg[x + 1];
    oq[x + 1] = rq + pq[x + 1];
  }
}

/// Integral images (CV_32S, (H + 1) x (W + 1), zero first row and column) of v and v^2 for the
/// 8-bit image @p img and of g and g^2 for its Laplacian @p lap (CV_16S), all modulo 2^32 (the
/// sum of v is cv::integral's CV_32S result wherever that does not overflow), in one pass: half
/// the memory of double integrals, and box sums in 8-lane integer vectors. Exact through boxAt

}  // namespace

/// and the row kernels (see boxAt).
void wrappedIntegrals(const cv::Mat& img, const cv::Mat& lap, cv::Mat& sum, cv::Mat& sq,
                      cv::Mat& int_lap, cv::Mat& sq_lap) {
  const int H = img.rows, W = img.cols;
  sum.create(H + 1, W + 1, CV_32S);
  sq.create(H + 1, W + 1, CV_32S);
  int_lap.create(H + 1, W + 1, CV_32S);
  sq_lap.create(H + 1, W + 1, CV_32S);
  std::fill(sum.ptr<uint32_t>(0), sum.ptr<uint32_t>(0) + W + 1, 0u);
  std::fill(sq.ptr<uint32_t>(0), sq.ptr<uint32_t>(0) + W + 1, 0u);
  std::fill(int_lap.ptr<uint32_t>(0), int_lap.ptr<uint32_t>(0) + W + 1, 0u);
  std::fill(sq_lap.ptr<uint32_t>(0), sq_lap.ptr<uint32_t>(0) + W + 1, 0u);
  for (int y = 0; y < H; ++y) {
    integralRow(W, img.ptr<uint8_t>(y), lap.ptr<int16_t>(y), sum.ptr<uint32_t>(y),
                sq.ptr<uint32_t>(y), int_lap.ptr<uint32_t>(y), sq_lap.ptr<uint32_t>(y),
                sum.ptr<uint32_t>(y + 1), sq.ptr<uint32_t>(y + 1), int_lap.ptr<uint32_t>(y + 1),
                sq_lap.ptr<uint32_t>(y + 1));
  }
}

namespace {

// vectorise: the double part, then the float square roots with SSE (the scalar std::sqrt keeps
// an errno branch that blocks vectorisation). IEEE division, square root and conversions are
// correctly rounded in vector and scalar form alike, so the values are bit-identical to the
// lazily computed ones.
/// p[i] := p[i] > 0 ? 1 / sqrt(p[i]) : 0, and (second form) p[i] := sqrt(p[i]) / den (p >= 0).
void invSqrtRow(int n, float* p) {
  int i = 0;
#if defined(__SSE2__)
  const __m128 one = _mm_set1_ps(1.f), zero = _mm_setzero_ps();
  for (; i + 4 <= n; i += 4) {
    const __m128 v = _mm_loadu_ps(p + i);
    const __m128 r = _mm_div_ps(one, _mm_sqrt_ps(v));
    _mm_storeu_ps(p + i, _mm_and_ps(_mm_cmpgt_ps(v, zero), r));
  }
#endif
  for (; i < n; ++i) p[i] = p[i] > 0.f ? 1.f / std::sqrt(p[i]) : 0.f;
}
void sqrtDivRow(int n, float* p, float den) {
  int i = 0;
#if defined(__SSE2__)
  const __m128 dv = _mm_set1_ps(den);
  for (; i + 4 <= n; i += 4) {
    _mm_storeu_ps(p + i, _mm_div_ps(_mm_sqrt_ps(_mm_loadu_ps(p + i)), dv));
  }
#endif
  for (; i < n; ++i) p[i] = std::sqrt(p[i]) / den;
}

/// First pass of the NCC statistics of row y, columns [x0, x1], window sums read from the
/// integral images as boxAt reads them: mean (left) or sum (right) of the window, and in @p inv
/// the quotient (n sum L^2 - (sum L)^2) / n where it exceeds the flatness threshold, else 0;
/// invSqrtRow turns it into the value of invStd. a > 0.5 gives a quotient of at least
/// 0.5 / 1024 (windows up to 32 x 32): > 0 marks it.
template <bool kAsMean>
ES_INLINE void statsRowIntImpl(const cv::Mat& int_sum, const cv::Mat& int_sq, int y, int r, int x0,
                               int x1, double n, float* __restrict mean_or_sum,
                               float* __restrict inv) {
  const uint32_t* __restrict ts = int_sum.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bs = int_sum.ptr<uint32_t>(y + r + 1);
  const uint32_t* __restrict tq = int_sq.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bq = int_sq.ptr<uint32_t>(y + r + 1);
  const float nf = static_cast<float>(n);
  for (int x = x0; x <= x1; ++x) {
    const double sum = static_cast<double>(
        static_cast<int32_t>((bs[x + r + 1] - ts[x + r + 1]) - (bs[x - r] - ts[x - r])));
    const double sq = static_cast<double>(
        static_cast<int32_t>((bq[x + r + 1] - tq[x + r + 1]) - (bq[x - r] - tq[x - r])));
    const double a = n * sq - sum * sum;
    const float q = static_cast<float>(a) / nf;  // unconditional: the loop vectorises
    inv[x] = a > 0.5 ? q : 0.f;
    mean_or_sum[x] =
        kAsMean ? static_cast<float>((sum - 128.0 * n) / n) : static_cast<float>(sum - 128.0 * n);
  }
}
ES_KERNEL void statsRowInt(const cv::Mat& int_sum, const cv::Mat& int_sq, int y, int r, int x0,
                           int x1, double n, float* mean_or_sum, float* inv, bool as_mean) {
  if (as_mean) {
    statsRowIntImpl<true>(int_sum, int_sq, y, r, x0, x1, n, mean_or_sum, inv);
  } else {
    statsRowIntImpl<false>(int_sum, int_sq, y, r, x0, x1, n, mean_or_sum, inv);
  }
}
/// First pass of the structure values of row y: max(0, n sum G^2 - (sum G)^2) as float;
/// sqrtDivRow turns it into the value of gammaOf.
ES_KERNEL void gammaRowInt(const cv::Mat& int_sum, const cv::Mat& int_sq, int y, int r, int x0,
                           int x1, double n, float* __restrict g) {
  const uint32_t* __restrict ts = int_sum.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bs = int_sum.ptr<uint32_t>(y + r + 1);
  const uint32_t* __restrict tq = int_sq.ptr<uint32_t>(y - r);
  const uint32_t* __restrict bq = int_sq.ptr<uint32_t>(y + r + 1);
  for (int x = x0; x <= x1; ++x) {
    const double sum = static_cast<double>(
        static_cast<int32_t>((bs[x + r + 1] - ts[x + r + 1]) - (bs[x - r] - ts[x - r])));
    const double sq = static_cast<double>(
        static_cast<int32_t>((bq[x + r + 1] - tq[x + r + 1]) - (bq[x - r] - tq[x - r])));
    const double a = n * sq - sum * sum;
    g[x] = std::max(0.f, static_cast<float>(a));
  }
}

/// All statistics of row y (columns r .. W - 1 - r), as computeMapL/R give them one by one.

}  // namespace

/// With @p with_gamma false only the NCC statistics are computed, on columns [x0, x1] (the
/// structure values are then computed lazily where needed).
void computeRowMaps(const WindowLevel& c, RowScratch& s, int y, bool with_gamma, int x0, int x1) {
  const int r = c.r;
  if (x0 < 0) {
    x0 = r;
    x1 = c.width - 1 - r;
  }
  const double n = static_cast<double>(c.w) * c.w;
  statsRowInt(c.im->int_l, c.im->sq_l, y, r, x0, x1, n, s.maps.mean_l.data(), s.maps.inv_l.data(),
              true);
  invSqrtRow(x1 - x0 + 1, s.maps.inv_l.data() + x0);
  statsRowInt(c.im->int_r, c.im->sq_r, y, r, x0, x1, n, s.maps.sum_r.data(), s.maps.inv_r.data(),
              false);
  invSqrtRow(x1 - x0 + 1, s.maps.inv_r.data() + x0);
  if (!with_gamma) {
    // Mirrored copies for the sparse engine's profiles: R statistics at x - d for increasing d.
    const int W = c.width;
    for (int x = x0; x <= x1; ++x) {
      s.maps.sum_r_rev[W - 1 - x] = s.maps.sum_r[x];
      s.maps.inv_r_rev[W - 1 - x] = s.maps.inv_r[x];
    }
    return;
  }
  gammaRowInt(c.im->int_lap_l, c.im->sq_lap_l, y, r, x0, x1, n, s.maps.gamma_l.data());
  sqrtDivRow(x1 - x0 + 1, s.maps.gamma_l.data() + x0, static_cast<float>(n));
  gammaRowInt(c.im->int_lap_r, c.im->sq_lap_r, y, r, x0, x1, n, s.maps.gamma_r.data());
  sqrtDivRow(x1 - x0 + 1, s.maps.gamma_r.data() + x0, static_cast<float>(n));
}

/// Right NCC statistics of row y on columns [x0, x1] (inside the border), vectorised, with their
/// mirrored copies, marked computed for this row: the same values needMapR gives one by one.
void rowMapsR(const WindowLevel& c, RowScratch& s, int y, int x0, int x1) {
  if (x0 > x1) return;
  const double n = static_cast<double>(c.w) * c.w;
  statsRowInt(c.im->int_r, c.im->sq_r, y, c.r, x0, x1, n, s.maps.sum_r.data(), s.maps.inv_r.data(),
              false);
  invSqrtRow(x1 - x0 + 1, s.maps.inv_r.data() + x0);
  const int W = c.width;
  for (int x = x0; x <= x1; ++x) {
    s.maps.sum_r_rev[W - 1 - x] = s.maps.sum_r[x];
    s.maps.inv_r_rev[W - 1 - x] = s.maps.inv_r[x];
    s.maps.stamp_r[x] = s.stamp;
  }
}

/// Left NCC statistics of row y on the columns of [x0, x1] (inside the border) not yet computed
/// for this row, vectorised per run of such columns, marked computed: the same values needMapL
/// gives one by one (the lazy form cost a scalar box sum per column and was the larger part of
/// the sparse rows' right-to-left profiles with per-pixel ranges).
void ensureMapsL(const WindowLevel& c, RowScratch& s, int y, int x0, int x1) {
  const double n = static_cast<double>(c.w) * c.w;
  int* stamp = s.maps.stamp_l.data();
  int x = x0;
  while (x <= x1) {
    if (stamp[x] == s.stamp) {
      ++x;
      continue;
    }
    int e = x;
    while (e + 1 <= x1 && stamp[e + 1] != s.stamp) ++e;
    statsRowInt(c.im->int_l, c.im->sq_l, y, c.r, x, e, n, s.maps.mean_l.data(), s.maps.inv_l.data(),
                true);
    invSqrtRow(e - x + 1, s.maps.inv_l.data() + x);
    std::fill(stamp + x, stamp + e + 1, s.stamp);
    x = e + 1;
  }
}

}  // namespace detail
}  // namespace endo_stereo
