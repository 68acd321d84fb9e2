// Private to the core: the search engine for rows matched densely with per-pixel search ranges
// (temporal priors narrow each pixel's range). The row is cut into chunks of 8 columns (one
// vector); each chunk searches the union of its pixels' ranges (its band: priors are smooth, so
// the band is little wider than each range), disparity by disparity in increasing order, with
// the streaming peak trackers of its 8 pixels held in registers. The vertical window sums of a
// disparity are kept, for the columns of the chunks whose band holds it, from row to row (one
// row in, one out); each right pixel x - d receives S(x, d) in a right-to-left tracker.
#pragma once

#include <vector>

#include "matcher_internal.hpp"

namespace endo_stereo {
namespace detail {

/// Columns of the vertical window sums of one disparity that hold valid values, for the row
/// computed last (`cur_row`) and the row before it (`prev`), as sorted disjoint intervals.
struct VValidity {
  int cur_row = -10;
  std::vector<Interval> cur, prev;
};

/// Scratch of the narrowed-range engine, one per worker.
struct NarrowedScratch {
  // Vertical window sums: num_d rows of v_stride floats, column x at v_pad + x (the padding lets
  // a chunk's box sums read past the row's ends; those lanes are outside every range).
  std::vector<float> v;
  int v_stride = 0, v_pad = 0;
  std::vector<VValidity> valid;  // per disparity
  // Per chunk of 8 columns: the band (disparity indices, empty: lo > hi).
  std::vector<int> band_lo, band_hi;
  std::vector<int> run_from;         // per disparity index: first chunk of the open run
  std::vector<int> iv_count;         // per disparity index: intervals in iv_by_k
  std::vector<Interval> iv_by_k;     // per disparity index: its column intervals (iv_cap each)
  int iv_cap = 0;
  std::vector<Interval> pieces, merged;
  // Right statistics and right-to-left trackers of right column q = x - d at index
  // x - k + num_d + 7 (k = d - dmin: q + dmin + num_d + 7), inside the buffer for every lane x of
  // every chunk (0 <= x < W + 8) and every k; q_len entries.
  int q_len = 0;
  std::vector<float> sum_r_q, inv_r_q;
  // The right-to-left trackers: copies (one per disparity index mod 4, search_narrowed.cpp) of
  // the best values, then of their disparities, laid out as the full-range engine's 8
  // (layoutTrackers, search_full_range.hpp).
  std::vector<float> rl_trackers;
  int rl_copy_stride = 0, rl_d_offset = 0;

  void ensure(int w, int nd);
  /// Forget all window sums (new stripe or new window size).
  void resetSums();
};

/// Peak analysis (RowScratch::best ...) of the active pixels and right-to-left best disparities
/// of row y, per-pixel ranges, every pixel of the row with an effective range taking part.
void narrowedRow(const WindowLevel& c, RowScratch& s, NarrowedScratch& e, int y);

}  // namespace detail
}  // namespace endo_stereo
