// Private to the core: the types the matcher's files share (not installed, not part of the API).
//
// RobustMatcher::compute (matcher.cpp) prepares the two views into a FrameData, then matches
// stripes of rows, each row at each window size of the growth sequence (a WindowLevel) with
// matchRow (row_decisions.cpp). matchRow picks one of three search engines for the row - they
// differ in speed only, never in the values they give:
//   search_full_range.cpp  most of the row still open, every pixel searching [dmin, dmax];
//   search_narrowed.cpp    most of the row still open, per-pixel ranges (temporal priors);
//   search_sparse.cpp      few pixels left open (the larger windows).
// Each engine fills the row's peak analysis (RowScratch::best, second, ...) and the right-to-left
// best disparities (RowScratch::rl_best_d); matchRow then applies the paper's criteria. The
// window statistics (means, deviations, structure) come from window_statistics.cpp, the shared
// vector helpers and the peak rule from ncc_kernels.hpp.
#pragma once

#include <cstdint>
#include <limits>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_stereo/core/matcher.hpp"

namespace endo_stereo {
namespace detail {

constexpr float kNegInf = -std::numeric_limits<float>::infinity();
// Fixed stripes of rows, so the work split never depends on the thread count.
constexpr int kStripeRows = 32;
// Sentinel of an empty effective range.
constexpr int kEmptyLo = std::numeric_limits<int>::max() / 2;
constexpr int kEmptyHi = std::numeric_limits<int>::min() / 2;

struct Interval {
  int a, b;  // inclusive
};

/// Per-frame images shared (read-only) by the workers.
struct FrameData {
  cv::Mat lf, rf;        // CV_32F value - 128
  cv::Mat rf_rev;        // CV_32F rf mirrored left-right, padded (sparse and full-range engines)
  int rev_pad = 0;       // columns of padding on the left of rf_rev
  cv::Mat lf_pad;        // CV_32F lf with zero columns around it (right-indexed column sums)
  int l_pad = 0;         // columns of padding on the left of lf_pad
  cv::Mat int_l, int_r;  // CV_32S integral images of the 8-bit views
  cv::Mat lap_l, lap_r;  // CV_16S 3x3 Laplacian on 0..255 (|value| <= 1020)
  // Integral images of the squares, of the Laplacian and of its square, CV_32S taken modulo
  // 2^32 (wrappedIntegrals): read only through window differences (boxAt, statsRowInt,
  // gammaRowInt), which are exact.
  cv::Mat sq_l, sq_r, int_lap_l, int_lap_r, sq_lap_l, sq_lap_r;
  // CV_32S requested range per pixel (clamped), lo > hi = none; with a full search one row that
  // every row shares (no per-frame fill of two whole images).
  cv::Mat range_lo, range_hi;
};

/// One window size of the growth sequence (w_min, w_min + dw, ...): everything a row needs to be
/// matched at it.
struct WindowLevel {
  const MatcherParams* mp;
  const FrameData* im;
  bool uniform_ranges;  // no per-pixel range: every pixel searches [dmin, dmax] (cut at borders)
  int level;            // index in the growth sequence (0 = w_min)
  int w, r;             // window width and half width
  int width, height;
  int dmin, dmax;
  cv::Mat* state;  // 1 = accepted earlier
  cv::Mat* window_idx;
  // Per row: the columns still open (requested range, not accepted), sorted; built at the
  // row's first sparse window size, filtered at each later one, so the larger windows never scan
  // whole rows; open_level = the window size (level) the list is for (-1: none yet).
  std::vector<std::vector<int>>* open_rows;
  std::vector<int>* open_level;
  std::vector<int>* n_req_rows;  // per row: pixels with a requested range (first window)
  MatchResult* out;
};

/// Per-row window statistics at one window size (index = column).
struct RowMaps {
  std::vector<float> mean_l;  // window mean of L - 128
  std::vector<float> inv_l;   // sqrt(n / (n sum L^2 - (sum L)^2)), 0 where flat
  std::vector<float> sum_r;   // window sum of R - 128
  std::vector<float> inv_r;
  std::vector<float> gamma_l;  // stdev of the Laplacian over the window
  std::vector<float> gamma_r;
  std::vector<float> sum_r_rev, inv_r_rev;                // mirrored: index W - 1 - x
  std::vector<int> stamp_l, stamp_r, stamp_gl, stamp_gr;  // sparse rows: computed for this stamp
};

/// The state of the row being matched, shared by the engines and the decisions: its window
/// statistics, effective ranges, active pixels, and the peak analysis the engines fill.
struct RowScratch {
  int width = 0;
  int num_d = 0;
  int dpad = 0;                  // num_d rounded up to a multiple of 8
  int stamp = 0;                 // increases with every processed row
  const int* rlo_row = nullptr;  // requested ranges of the row being processed
  const int* rhi_row = nullptr;
  RowMaps maps;
  // Effective range of each pixel (its requested range cut so that both windows fit; empty:
  // lo > hi), as int and as float, and activity (1 = matched at this window), dense rows.
  std::vector<int> eff_lo, eff_hi;
  std::vector<float> eff_lo_f, eff_hi_f, act;
  std::vector<int> active;  // the active pixels of a sparse row, in column order
  std::vector<int> cand_q;  // right pixels whose right-to-left profile a sparse row needs
  // Peak analysis per pixel: the best interior maximum of S (best, at disparity best_d, with its
  // neighbours best_l / best_r for the parabola) and the second (see ncc_kernels.hpp).
  std::vector<float> best, best_d, best_l, best_r, second;
  // Right-to-left check per right pixel q: the best S_RL(q, d) and its disparity.
  std::vector<float> rl_best_v, rl_best_d;

  void ensure(int w, int nd);
};

/// Effective range of pixel (x, y) at this window: its requested range, cut so that both windows
/// lie inside the images. @return false when empty (also outside [r, W - r)).
inline bool effectiveRange(const WindowLevel& c, const RowScratch& s, int x, int* lo, int* hi) {
  if (x < c.r || x >= c.width - c.r) return false;
  *lo = std::max(s.rlo_row[x], x - (c.width - 1 - c.r));
  *hi = std::min(s.rhi_row[x], x - c.r);
  return *lo <= *hi;
}

}  // namespace detail
}  // namespace endo_stereo
