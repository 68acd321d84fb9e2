// Private to the core: the search engine for sparse rows, the pixels that failed with the smaller
// windows. The vertical window sums are kept per column for all disparities at once (so a failed
// region that spans many rows is updated by running sums), the profile of each active pixel is
// built from them, and the right-to-left profile is computed only for the right pixels that the
// surviving peaks point at, from column sums indexed by the right column (w columns per profile).
#pragma once

#include <vector>

#include "matcher_internal.hpp"

namespace endo_stereo {
namespace detail {

/// Scratch of the sparse engine, one per worker.
struct SparseScratch {
  // Vertical window sums of one column for all disparities, [column][dpad]; per column the row
  // they hold, the disparity indices held, the row last used and the stamp of the last request.
  std::vector<float> colsum;
  std::vector<int> col_row, col_k0, col_k1, col_used, col_done, hot;
  std::vector<int> req_stamp, req_k0, req_k1, run_lo, run_hi, rl_ok;
  std::vector<int> vh_lo, vh_hi, vh_glo, vh_ghi;  // runRequests' sliding minimum / maximum
  // Right-to-left profiles: vertical window sums indexed by the RIGHT column q, [q][dpad]:
  // colsum_r[q][k] = sum over the window's rows of L(y', q + d_k) R(y', q). The profile of right
  // pixel q is then the sum of w whole columns (q - r .. q + r), not a diagonal through 64 + w
  // left columns. Same bookkeeping as the left columns.
  std::vector<float> colsum_r;
  std::vector<int> colr_row, colr_k0, colr_k1, colr_used, colr_done, hot_r;
  std::vector<float> hvec, prof;
  // Right-to-left profiles: the window sums hr of right pixel rl_q on the disparity indices
  // [rl_k0, rl_k1]; in uniform rows slid to the next right pixel when it is rl_q + 1 in the same
  // row (rl_stamp).
  std::vector<float> hr;
  int rl_q = -10, rl_k0 = 0, rl_k1 = -1, rl_stamp = -1;
  float* prof0 = nullptr;  // profile buffer, index 0 = first disparity of the range

  void ensure(int w, int nd, int dpad);
  /// Forget all window sums (new stripe or new window size).
  void resetSums();
};

/// Peak analysis (RowScratch::best ...) of the active pixels RowScratch::active of row y.
void sparseRow(const WindowLevel& c, RowScratch& s, SparseScratch& e, int y);

/// Right-to-left check of right pixel q of row y: RowScratch::rl_best_d[q] = the d that
/// maximises S(q + d, d) over the left pixels q + d whose effective range holds d (ties: the
/// smallest d).
void sparseRightToLeft(const WindowLevel& c, RowScratch& s, SparseScratch& e, int q, int y);

}  // namespace detail
}  // namespace endo_stereo
