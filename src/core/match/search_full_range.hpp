// Private to the core: the search engine for rows matched densely over the full range
// [dmin, dmax] (no per-pixel ranges). Each column holds its vertical window sums of
// L(x, y') R(x - d, y') for all d, contiguous in d (8 disparities per vector), carried from row
// to row by one row in and one row out; a pixel's window sums slide along the row; its profile
// S(x, .) is formed 8 disparities at a time and analysed per lane (ncc_kernels.hpp), and offered
// to the right-to-left tracker of every right pixel x - d, held mirrored so that it is contiguous
// in d too: S_RL(q, d) = S_LR(q + d, d) is the left-right check without a second pass.
#pragma once

#include <vector>

#include "matcher_internal.hpp"

namespace endo_stereo {
namespace detail {

/// Scratch of the full-range engine, one per worker.
struct FullRangeScratch {
  // Vertical window sums of every column for the disparity groups it needs, [column][dpad],
  // carried down the stripe by running sums.
  std::vector<float> vsums;
  std::vector<int> vsum_g0, vsum_g1;  // per column: 8-lane groups held (g0 > g1: none)
  std::vector<int> span_lo, span_hi;
  int vsum_row = -10;    // row the sums hold (all columns), -10 = none
  int span_stripe = -1;  // stripe whose per-column groups vsum_g0/vsum_g1 were set for
  // Reversed, padded row arrays (index rpad + W - 1 - q for right column q, so that q = x - d for
  // increasing d is contiguous): right statistics and the right-to-left tracker.
  int rpad = 0;
  std::vector<float> sum_r_mirror, inv_r_mirror;
  std::vector<float> win_sums, profile_buf;  // one pixel's window sums and profile S(x, .)
  // The right-to-left trackers: 8 copies of the best values, then 8 of their disparities, in one
  // buffer laid out by layoutTrackers (search_full_range.cpp).
  std::vector<float> rl_trackers;
  int rl_copy_stride = 0;  // floats from one copy to the next
  int rl_d_offset = 0;     // floats from the values' first copy to the disparities' first copy

  void ensure(int w, int dpad);
  /// Forget all window sums (new stripe or new window size).
  void resetSums();
};

/// Layout of 8 copies of right-to-left trackers of @p used floats each (the dense engines'):
/// the stride from one copy to the next and the offset of the disparities' copies from the
/// values', chosen against 4K aliasing between the copies.
void layoutTrackers(int used, int* stride, int* d_off);

/// Merge the first @p copies (<= 8) right-to-left tracker copies (values @p rl_v, disparities
/// @p rl_d, @p stride floats apart, @p n entries each) into the first: the highest value, ties
/// to the smallest d.
void mergeTrackerCopies(float* rl_v, float* rl_d, int stride, int n, int copies);

/// Peak analysis (RowScratch::best ...) of the active pixels (RowScratch::act) and the
/// right-to-left best disparity of every right pixel (RowScratch::rl_best_d) of row y.
void fullRangeRow(const WindowLevel& c, RowScratch& s, FullRangeScratch& e, int y);

}  // namespace detail
}  // namespace endo_stereo
