// Private to the core: one row at one window size - which pixels are matched, which engine
// searches them, and the paper's criteria deciding each of them.
#pragma once

#include "matcher_internal.hpp"
#include "search_full_range.hpp"
#include "search_narrowed.hpp"
#include "search_sparse.hpp"

namespace endo_stereo {
namespace detail {

/// All scratch of one worker, reused between rows, stripes, window sizes and frames: the row's
/// state and each engine's own buffers.
struct WorkerScratch : RowScratch, FullRangeScratch, NarrowedScratch, SparseScratch {
  /// Size every buffer for rows of width @p w and @p nd disparities (no-op when unchanged).
  void ensure(int w, int nd);
  /// Forget all window sums (new stripe or new window size).
  void resetSums();
};

/// Match the open pixels of row y at the window size of @p c: the structure criterion on the
/// left patch, a search engine for the peak analysis, then the criteria in the paper's order
/// (structure of the right patch, peak gap and least NCC, left-right consistency). Writes only
/// row y of the outputs (disparity, code, confidence, state, window index).
void matchRow(const WindowLevel& c, int y, WorkerScratch& s);

}  // namespace detail
}  // namespace endo_stereo
