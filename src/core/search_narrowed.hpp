// Private to the core: the search engine for rows matched densely with per-pixel search ranges
// (temporal priors narrow each pixel's range). Disparities are streamed in increasing order over
// the column intervals whose pixels search them; for each d the vertical window sums are updated
// by one row, summed horizontally, turned into the NCC slice S(., d) and fed to a per-pixel
// streaming peak tracker and to the right-to-left tracker of every right pixel x - d.
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
  std::vector<float> v;                           // vertical window sums, num_d rows of width
  std::vector<VValidity> valid;                   // per disparity
  std::vector<float> box_tmp_a, box_tmp_b, hsum;  // boxSumRow's passes and its result
  std::vector<int> cover;     // per block, per disparity: pixels whose range holds it
  std::vector<int> iv_start;  // per disparity: first index into ivs
  std::vector<Interval> ivs;  // the intervals of all disparities, grouped by disparity
  std::vector<Interval> pieces, merged, need;
  std::vector<int> block_a, block_b, blocks, pick;
  std::vector<int> block_k0, block_k1, iv_count;  // per block: disparity indices covered
  std::vector<Interval> iv_by_k;                  // per disparity index: up to one per block
  // The streaming peak tracker's last two values S(d - 1), S(d - 2) per pixel.
  std::vector<float> p1, p2;

  void ensure(int w, int nd);
  /// Forget all window sums (new stripe or new window size).
  void resetSums();
};

/// Peak analysis (RowScratch::best ...) of the active pixels and right-to-left best disparities
/// of row y, per-pixel ranges, every pixel of the row with an effective range taking part.
void narrowedRow(const WindowLevel& c, RowScratch& s, NarrowedScratch& e, int y);

}  // namespace detail
}  // namespace endo_stereo
