// Post-processing of the robust matcher (docs/method.md section 3): isolated-outlier removal and
// the filling of holes one or two pixels wide. Both functions decide every pixel from the input map
// alone (never from pixels changed in the same pass), so the result does not depend on the order
// in which pixels are visited.
#include "endo_stereo/core/post_filter.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <opencv2/core/utility.hpp>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "endo_stereo/core/matcher.hpp"
#include "simd.hpp"

namespace endo_stereo {

std::string PostFilterParams::validate() const {
  std::ostringstream msg;
  if (outlier_window_px < 3 || outlier_window_px % 2 == 0 || outlier_window_px > 31) {
    msg << "filter.outlier_window_px = " << outlier_window_px << " must be odd and in [3, 31]";
  } else if (!(outlier_disparity_tol_px > 0.0) || !std::isfinite(outlier_disparity_tol_px)) {
    msg << "filter.outlier_disparity_tol_px = " << outlier_disparity_tol_px
        << " must be finite and > 0";
  } else if (!(outlier_min_share >= 0.0 && outlier_min_share <= 1.0)) {
    msg << "filter.outlier_min_share = " << outlier_min_share << " must be in [0, 1]";
  } else if (fill_max_hole_px < 1 || fill_max_hole_px > 2) {
    msg << "filter.fill_max_hole_px = " << fill_max_hole_px << " must be in [1, 2]";
  }
  return msg.str();
}

namespace {

void checkMaps(const cv::Mat& disparity, const cv::Mat& code, const char* fn) {
  if (disparity.type() != CV_32FC1) {
    throw std::invalid_argument(std::string(fn) + ": disparity must be CV_32FC1");
  }
  if (!code.empty() && (code.type() != CV_8UC1 || code.size() != disparity.size())) {
    throw std::invalid_argument(std::string(fn) +
                                ": code must be empty or CV_8UC1 of the disparity's size");
  }
}

/// The removal verdicts of one row (rm[x] = 1: remove): agreeing neighbours counted over the
/// rows nrows[0 .. num_rows) (nrows[centre] is the row itself, s), the pixel itself excluded.
/// Eight columns at a time with the count kept in a register across all offsets. |n - s| < tol
/// is written as (n - s < tol) && (s - n < tol): the same truth value (negation is exact, NaN
/// fails both), without an absolute value.
ES_KERNEL void outlierRow(const float* const* nrows, int num_rows, int centre, int cols, int half,
                          float tol, int need, uint8_t* rm, float* __restrict cmin,
                          float* __restrict cmax, float* __restrict ccnt) {
  using namespace simd;
  const float* s = nrows[centre];
  auto scalar = [&](int x) {
    int agree = 0;
    for (int r = 0; r < num_rows; ++r) {
      for (int dx = -half; dx <= half; ++dx) {
        if ((r == centre && dx == 0) || x + dx < 0 || x + dx >= cols) continue;
        agree += std::fabs(nrows[r][x + dx] - s[x]) < tol ? 1 : 0;
      }
    }
    rm[x] = (s[x] == s[x] && agree < need) ? 1 : 0;
  };
  const V8f tv = splat8(tol);
  // The pixel itself is counted too (0 < tol, and only non-NaN pixels can be removed), so the
  // count must reach need + 1: no test for the centre offset in the loop.
  const V8i need_self = {need + 1, need + 1, need + 1, need + 1,
                         need + 1, need + 1, need + 1, need + 1};
  // A sufficient test first: when the measured values of a pixel's window (itself included) span
  // less than tol and there are more than need of them, every measured neighbour agrees (for a
  // neighbour n, |n - s| <= max - min, and rounding is monotone, so the rounded differences stay
  // below tol): the pixel is kept without counting. Per column the least and greatest measured
  // value over the rows and their number, then per pixel over the window's columns.
  const float inf = std::numeric_limits<float>::infinity();
  const V8f vinf = splat8(inf), vninf = splat8(-inf), one = splat8(1.f), zero = splat8(0.f);
  int c = 0;
  for (; c + 8 <= cols; c += 8) {
    V8f lo = vinf, hi = vninf, n = zero;
    for (int r = 0; r < num_rows; ++r) {
      const V8f v = load8(nrows[r] + c);
      const V8i ok = v == v;
      lo = ok ? (v < lo ? v : lo) : lo;
      hi = ok ? (v > hi ? v : hi) : hi;
      n += ok ? one : zero;
    }
    store8(cmin + c, lo);
    store8(cmax + c, hi);
    store8(ccnt + c, n);
  }
  for (; c < cols; ++c) {
    float lo = inf, hi = -inf, n = 0.f;
    for (int r = 0; r < num_rows; ++r) {
      const float v = nrows[r][c];
      if (v != v) continue;
      lo = std::min(lo, v);
      hi = std::max(hi, v);
      n += 1.f;
    }
    cmin[c] = lo;
    cmax[c] = hi;
    ccnt[c] = n;
  }
  const V8f vneed = splat8(static_cast<float>(need) + 1.f);  // the pixel itself is in the count
  auto quickKeep = [&](int x0, V8f sv) {
    V8f lo = load8(cmin + x0 - half), hi = load8(cmax + x0 - half), n = load8(ccnt + x0 - half);
    for (int dx = -half + 1; dx <= half; ++dx) {
      const V8f l = load8(cmin + x0 + dx), h = load8(cmax + x0 + dx);
      lo = l < lo ? l : lo;
      hi = h > hi ? h : hi;
      n += load8(ccnt + x0 + dx);
    }
    return ((hi - lo < tv) & (n >= vneed)) | (sv != sv);
  };
  int x = 0;
  for (; x < std::min(half, cols); ++x) scalar(x);
  for (; x + 16 + half <= cols; x += 16) {
    const V8f s0 = load8(s + x), s1 = load8(s + x + 8);
    const V8i q0 = quickKeep(x, s0), q1 = quickKeep(x + 8, s1);
    if (!anyLane(~(q0 & q1))) {
      std::memset(rm + x, 0, 16);
      continue;
    }
    V8i a0 = {0, 0, 0, 0, 0, 0, 0, 0}, a1 = a0;
    for (int r = 0; r < num_rows; ++r) {
      const float* n = nrows[r] + x;
      for (int dx = -half; dx <= half; ++dx) {
        const V8f d0 = load8(n + dx) - s0, d1 = load8(n + dx + 8) - s1;
        a0 -= (d0 < tv) & (-d0 < tv);  // a true lane is -1
        a1 -= (d1 < tv) & (-d1 < tv);
      }
    }
    const V8i k0 = (a0 >= need_self) | (s0 != s0), k1 = (a1 >= need_self) | (s1 != s1);
    for (int i = 0; i < 8; ++i) {  // a kept lane is -1: -1 + 1 = 0, a removed one 0 + 1 = 1
      rm[x + i] = static_cast<uint8_t>(k0[i] + 1);
      rm[x + 8 + i] = static_cast<uint8_t>(k1[i] + 1);
    }
  }
  for (; x < cols; ++x) scalar(x);
}

}  // namespace

int64_t removeIsolatedOutliers(cv::Mat& disparity, cv::Mat& code, const PostFilterParams& params) {
  checkMaps(disparity, code, "removeIsolatedOutliers");
  const std::string err = params.validate();
  if (!err.empty()) throw std::invalid_argument("removeIsolatedOutliers: " + err);
  const int rows = disparity.rows, cols = disparity.cols;
  const int half = params.outlier_window_px / 2;
  const float tol = static_cast<float>(params.outlier_disparity_tol_px);
  // N / window^2 < mu, with N counting the agreeing neighbours (the pixel itself excluded) and the
  // denominator fixed at window^2 also at the image border, as docs/method.md writes it. N is an
  // integer, so "N < need" is "N < ceil(need)".
  const double need =
      params.outlier_min_share * params.outlier_window_px * params.outlier_window_px;
  const int need_int = static_cast<int>(std::ceil(need));
  // Decided on the input map: first a removal mask from the untouched map (fixed row blocks over
  // the threads; every verdict reads only the input, so the thread count cannot matter), then the
  // removals. No copy of the map is needed.
  cv::Mat remove(rows, cols, CV_8UC1);
  constexpr int kBlockRows = 16;
  const int num_blocks = (rows + kBlockRows - 1) / kBlockRows;
  const cv::Mat& src = disparity;
  cv::parallel_for_(cv::Range(0, num_blocks), [&](const cv::Range& rg) {
    std::vector<const float*> nrows(2 * half + 1);
    std::vector<float> cmin(cols + 8), cmax(cols + 8), ccnt(cols + 8);
    for (int y = rg.start * kBlockRows; y < std::min(rows, rg.end * kBlockRows); ++y) {
      // NaN (unmatched) never compares below the tolerance, so it never agrees.
      const int y0 = std::max(0, y - half), y1 = std::min(rows - 1, y + half);
      for (int yy = y0; yy <= y1; ++yy) nrows[yy - y0] = src.ptr<float>(yy);
      outlierRow(nrows.data(), y1 - y0 + 1, y - y0, cols, half, tol, need_int,
                 remove.ptr<uint8_t>(y), cmin.data(), cmax.data(), ccnt.data());
    }
  });
  int64_t removed = 0;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < rows; ++y) {
    const uint8_t* rm = remove.ptr<uint8_t>(y);
    float* dst = disparity.ptr<float>(y);
    uint8_t* cd = code.empty() ? nullptr : code.ptr<uint8_t>(y);
    for (int x = 0; x < cols; ++x) {
      if (!rm[x]) continue;
      dst[x] = nan;
      if (cd) cd[x] = kCodeRejectOutlier;
      ++removed;
    }
  }
  return removed;
}

namespace {

/// A hole pixel's fill value, written after every block is done.
struct Fill {
  int y, x;
  float v;
};

/// Whether any of the eight bytes from @p p on is set.
inline bool anyByte(const uint8_t* p) {
  uint64_t w;
  std::memcpy(&w, p, 8);
  return w != 0;
}

/// Per-thread buffers of the hole sweep (see markBlockHoles).
struct HoleSweep {
  explicit HoleSweep(int cols) : run_len(cols), close_len(cols), inv(cols + 8, 0) {}
  std::vector<int32_t> run_len;    // per column: invalid pixels in a row up to the current row
  std::vector<int32_t> close_len;  // per column: length of the run closing at the current row
  std::vector<uint8_t> inv;        // 1 = invalid (NaN); padded for 8-byte reads
};

/// One row y of the sweep, @p n columns, branch-free and vectorisable: the validity of each pixel
/// (iv) and the per-column run bookkeeping (rl). A run closes at this row when the pixel is valid
/// after 1..max_hole invalid ones that did not start at row 0: cl gets its length, else 0.
/// Returns nonzero when any run closes. (Sizes by value, outputs __restrict: otherwise the
/// compiler must assume the stores may change them, and the loop would not vectorise.)
inline int32_t sweepRow(const float* __restrict d, int n, int max_hole, int y,
                        uint8_t* __restrict iv, int32_t* __restrict rl, int32_t* __restrict cl) {
  int32_t any_close = 0;
  for (int c = 0; c < n; ++c) {
    const int32_t invalid = d[c] != d[c];
    const int32_t len = rl[c];
    iv[c] = static_cast<uint8_t>(invalid);
    const int32_t closing = (!invalid & (len > 0) & (len <= max_hole) & (len < y)) ? len : 0;
    cl[c] = closing;
    any_close |= closing;
    rl[c] = invalid ? len + 1 : 0;
  }
  return any_close;
}

/// Marks in @p h the horizontal holes of a row whose invalid pixels are @p iv: runs of at most
/// max_hole invalid pixels with a valid pixel at both ends, skipping valid stretches eight pixels
/// at a time.
inline void markRowHoles(const uint8_t* __restrict iv, int cols, int max_hole,
                         uint8_t* __restrict h) {
  int x = 0;
  while (x < cols) {
    if (x + 8 <= cols && !anyByte(iv + x)) {
      x += 8;
      continue;
    }
    if (!iv[x]) {
      ++x;
      continue;
    }
    int end = x;
    while (end < cols && iv[end]) ++end;
    if (x > 0 && end < cols && end - x <= max_hole) {
      for (int i = x; i < end; ++i) h[i] = 1;
    }
    x = end;
  }
}

/// Marks in @p hole the hole pixels of rows [y0, y1), horizontal and vertical runs found in one
/// row-major sweep: horizontal runs within the row, vertical runs through a per-column state
/// (where the column's current invalid run started), so memory is walked contiguously. The sweep
/// runs from max_hole + 1 rows above y0 to max_hole + 1 rows below y1 (halo) and marks holes only
/// in rows [y0, y1): a vertical run that can be a hole (at most max_hole long) is then seen whole,
/// and a run that began above the sweep is at least max_hole + 1 long when it reaches the block,
/// so it is never taken for one.
void markBlockHoles(const cv::Mat& disparity, int max_hole, int y0, int y1, HoleSweep& sw,
                    cv::Mat& hole) {
  const int rows = disparity.rows, cols = disparity.cols;
  const int ys = std::max(0, y0 - max_hole - 1), ye = std::min(rows, y1 + max_hole + 1);
  std::fill(sw.run_len.begin(), sw.run_len.end(), 0);
  const int32_t* cl = sw.close_len.data();
  for (int y = ys; y < ye; ++y) {
    const int32_t any_close = sweepRow(disparity.ptr<float>(y), cols, max_hole, y, sw.inv.data(),
                                       sw.run_len.data(), sw.close_len.data());
    if (y >= y0 && y < y1) markRowHoles(sw.inv.data(), cols, max_hole, hole.ptr<uint8_t>(y));
    // Vertical runs that closed at this row (rare), marked in the block's own rows.
    for (int c = 0; c < cols && any_close; ++c) {
      for (int i = std::max(y - cl[c], y0); i < std::min(y, y1); ++i) {
        hole.ptr<uint8_t>(i)[c] = 1;
      }
    }
  }
}

/// The fill value of hole (x, y): the median of the valid disparities among its 8 neighbours,
/// with an even count the lower of the two middle values, so the fill is always a disparity that
/// was measured (at a depth edge the hole takes one side's value, never an invented one in
/// between). false when no neighbour is valid.
inline bool lowerMedianOfNeighbours(const cv::Mat& disparity, int x, int y, float* median) {
  const int rows = disparity.rows, cols = disparity.cols;
  // The valid neighbours, padded with +inf to eight values and sorted by a fixed 19-comparator
  // network (branch-free); the padding sorts last, so index (n - 1) / 2 is the lower median of
  // the n valid values.
  const float inf = std::numeric_limits<float>::infinity();
  float v[8] = {inf, inf, inf, inf, inf, inf, inf, inf};
  int n = 0;
  for (int yy = std::max(0, y - 1); yy <= std::min(rows - 1, y + 1); ++yy) {
    const float* d = disparity.ptr<float>(yy);
    for (int xx = std::max(0, x - 1); xx <= std::min(cols - 1, x + 1); ++xx) {
      if (yy == y && xx == x) continue;  // the hole itself is invalid
      const float e = d[xx];
      if (e == e) v[n++] = e;
    }
  }
  if (n == 0) return false;
  static constexpr int kNet[19][2] = {{0, 2}, {1, 3}, {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6},
                                      {3, 7}, {0, 1}, {2, 3}, {4, 5}, {6, 7}, {2, 4}, {3, 5},
                                      {1, 4}, {3, 6}, {1, 2}, {3, 4}, {5, 6}};
  for (const auto& c : kNet) {
    const float a = v[c[0]], b = v[c[1]];
    v[c[0]] = std::min(a, b);
    v[c[1]] = std::max(a, b);
  }
  *median = v[(n - 1) / 2];
  return true;
}

/// The fills of the holes of rows [y0, y1) marked in @p hole, in row-major order. Values are read
/// from the input map (holes are invalid there), so the blocks and the order of the pixels do
/// not matter.
void blockFills(const cv::Mat& disparity, const cv::Mat& hole, int y0, int y1,
                std::vector<Fill>& fills) {
  const int cols = disparity.cols;
  fills.clear();
  for (int y = y0; y < y1; ++y) {
    const uint8_t* h = hole.ptr<uint8_t>(y);
    for (int x = 0; x < cols; ++x) {
      if (x + 8 <= cols && !anyByte(h + x)) {
        x += 7;
        continue;
      }
      if (!h[x]) continue;
      float v;
      // No valid neighbour cannot happen for a bounded run; kept for safety.
      if (lowerMedianOfNeighbours(disparity, x, y, &v)) fills.push_back(Fill{y, x, v});
    }
  }
}

/// Writes the fills into the map (and kCodeFilled into @p code unless empty); returns how many.
int64_t applyFills(const std::vector<std::vector<Fill>>& block_fills, cv::Mat& disparity,
                   cv::Mat& code) {
  int64_t filled = 0;
  for (const std::vector<Fill>& fills : block_fills) {
    filled += static_cast<int64_t>(fills.size());
    for (const Fill& f : fills) {
      disparity.ptr<float>(f.y)[f.x] = f.v;
      if (!code.empty()) code.ptr<uint8_t>(f.y)[f.x] = kCodeFilled;
    }
  }
  return filled;
}

}  // namespace

int64_t fillSmallHoles(cv::Mat& disparity, cv::Mat& code, const PostFilterParams& params) {
  checkMaps(disparity, code, "fillSmallHoles");
  const std::string err = params.validate();
  if (!err.empty()) throw std::invalid_argument("fillSmallHoles: " + err);
  const int rows = disparity.rows, cols = disparity.cols;
  const int max_hole = params.fill_max_hole_px;
  // A hole pixel is an invalid pixel inside a horizontal or a vertical run of at most max_hole
  // invalid pixels bounded by valid pixels at both ends. Runs touching the image border are not
  // bounded and are left alone, as is anything wider: later frames fill those. Row blocks in
  // parallel, each marking its holes (markBlockHoles) and computing their fills from the input
  // map; the fills are written after every block is done.
  cv::Mat hole(rows, cols, CV_8UC1, cv::Scalar(0));
  constexpr int kBlockRows = 32;
  const int num_blocks = (rows + kBlockRows - 1) / kBlockRows;
  std::vector<std::vector<Fill>> block_fills(num_blocks);
  cv::parallel_for_(cv::Range(0, num_blocks), [&](const cv::Range& rg) {
    HoleSweep sweep(cols);
    for (int blk = rg.start; blk < rg.end; ++blk) {
      const int y0 = blk * kBlockRows, y1 = std::min(rows, y0 + kBlockRows);
      markBlockHoles(disparity, max_hole, y0, y1, sweep, hole);
      blockFills(disparity, hole, y0, y1, block_fills[blk]);
    }
  });
  return applyFills(block_fills, disparity, code);
}

void setFilledConfidenceRows(const cv::Mat& code, const cv::Mat& code_before, cv::Mat& confidence,
                             int y0, int y1) {
  const int W = code.cols, H = code.rows;
    for (int y = y0; y < y1; ++y) {
      const uint8_t* cd = code.ptr<uint8_t>(y);
      const uint8_t* cb0 = code_before.ptr<uint8_t>(y);
      for (int x = 0; x < W; ++x) {
        if (cd[x] != kCodeFilled || cb0[x] == kCodeFilled) continue;
        float cmin = 1.f;
        for (int yy = std::max(0, y - 1); yy <= std::min(H - 1, y + 1); ++yy) {
          const uint8_t* cb = code_before.ptr<uint8_t>(yy);
          const float* cf = confidence.ptr<float>(yy);
          for (int xx = std::max(0, x - 1); xx <= std::min(W - 1, x + 1); ++xx) {
            if (cb[xx] >= kCodeAcceptedBase) cmin = std::min(cmin, cf[xx]);
          }
        }
        confidence.ptr<float>(y)[x] = cmin;
      }
    }
}

}  // namespace endo_stereo
