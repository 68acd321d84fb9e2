// One row at one window size (see row_decisions.hpp). The paper's criteria, in its order, for
// each pixel still open at this window:
//   1. structure (gamma): the left patch's Laplacian deviation must exceed gamma_min (denseActive
//      and the sparse loop of activatePixels, before any search), then the right patch's at the
//      best peak;
//   2. discrimination (delta): the best NCC peak must exceed the second by more than delta_min,
//      and (ours) reach min_ncc (min_ncc_narrowed for a narrowed range);
//   3. left-right consistency (epsilon): |d_LR + d_RL| < epsilon, with d_RL the best disparity of
//      the right pixel's own profile (rl_best_d; disparities counted positive both ways, so the
//      test reads |best_d - rl_best_d| < epsilon).
// The first failure gives the pixel's code; a pixel that passes all three is accepted at this
// window, a pixel that fails goes on to the next window (window growth). decide (scalar) and
// decideDense (eight columns at a time) are the same expressions.

#include "row_decisions.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "simd.hpp"
#include "window_statistics.hpp"

namespace endo_stereo {
namespace detail {

using namespace simd;

namespace {

/// Inputs of the decisions of a dense row (see decideRow).
struct DecideArgs {
  int x0, x1;  // columns [x0, x1)
  const float* act;
  const float *best, *second, *best_d, *best_l, *best_r;
  const float *gamma_r, *rl_best_d;  // indexed by the right pixel q = x - best_d
  const int *rlo, *rhi;
  int dmin, dmax, level;
  float gmin, delta_min, min_ncc_full, min_ncc_narrow, eps;
  bool subpixel;
  uint8_t *code, *stw, *widx;
  float *disp, *conf;
};

/// The decisions of a dense row, eight columns at a time: the expressions of decideRow's
/// per-pixel decision lane by lane (the same IEEE operations, so the same values), the two
/// right-pixel values gathered, and every output written through a select that keeps the old
/// value outside the active pixels. Columns from x0 + 8 * floor((x1 - x0) / 8) on are left to
/// the caller.
ES_KERNEL int decideDense(const DecideArgs& a) {
  const V8f vzero = splat8(0.f), vone = splat8(1.f), vninf = splat8(kNegInf);
  const V8f vgmin = splat8(a.gmin), vdelta = splat8(a.delta_min), veps = splat8(a.eps);
  const V8f vfull = splat8(a.min_ncc_full), vnarrow = splat8(a.min_ncc_narrow);
  const V8i vdmin = V8i{} + a.dmin, vdmax = V8i{} + a.dmax;
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i c_nopeak = V8i{} + static_cast<int>(kCodeNoPeak);
  const V8i c_struct = V8i{} + static_cast<int>(kCodeRejectStructure);
  const V8i c_gap = V8i{} + static_cast<int>(kCodeRejectPeakGap);
  const V8i c_lr = V8i{} + static_cast<int>(kCodeRejectLeftRight);
  const V8i c_acc = V8i{} + (static_cast<int>(kCodeAcceptedBase) + a.level);
  const V8u8 v_level8 = V8u8{} + static_cast<uint8_t>(a.level), v_one8 = V8u8{} + 1;
  int x = a.x0;
  for (; x + 8 <= a.x1; x += 8) {
    const V8i active = load8(a.act + x) > vzero;
    if (!anyLane(active)) continue;
    const V8f b = load8(a.best + x);
    const V8f bdf = load8(a.best_d + x);
    const V8i bd = __builtin_convertvector(bdf, V8i);
    const V8i q = (lane + x) - bd;
    V8f gr, rl_d;
    for (int i = 0; i < 8; ++i) {
      gr[i] = a.gamma_r[q[i]];
      rl_d[i] = a.rl_best_d[q[i]];
    }
    const V8f sec = load8(a.second + x);
    const V8f comp = sec == vninf ? splat8(-1.f) : sec;
    const V8f delta = b - comp;
    V8i rl, rh;
    std::memcpy(&rl, a.rlo + x, sizeof(rl));
    std::memcpy(&rh, a.rhi + x, sizeof(rh));
    const V8f min_ncc = ((rl > vdmin) | (rh < vdmax)) ? vnarrow : vfull;
    const V8i no_peak = b == vninf;
    const V8i flat = ~(gr > vgmin);
    const V8i gap = ~(delta > vdelta) | (b < min_ncc);
    const V8f diff = __builtin_convertvector(bd, V8f) - rl_d;
    const V8f adiff = diff < vzero ? -diff : diff;
    const V8i lr = ~(adiff < veps);
    const V8i cd = no_peak ? c_nopeak : (flat ? c_struct : (gap ? c_gap : (lr ? c_lr : c_acc)));
    // Byte outputs selected as bytes (the masks narrowed once, not every byte row widened).
    V8u8 cb;
    std::memcpy(&cb, a.code + x, 8);
    const V8s8 active8 = __builtin_convertvector(active, V8s8);
    const V8u8 new_code = active8 ? __builtin_convertvector(cd, V8u8) : cb;
    std::memcpy(a.code + x, &new_code, 8);
    const V8i acc = active & (cd == c_acc);
    if (!anyLane(acc)) continue;
    V8f sub = vzero;
    if (a.subpixel) {
      const V8f bl = load8(a.best_l + x), br = load8(a.best_r + x);
      const V8f den = bl - 2.f * b + br;
      V8f t = (0.5f * (bl - br)) / den;
      t = t < splat8(-0.5f) ? splat8(-0.5f) : t;
      t = splat8(0.5f) < t ? splat8(0.5f) : t;
      sub = den < vzero ? t : vzero;
    }
    const V8f dv = __builtin_convertvector(bd, V8f) + sub;
    V8f cf = delta < vzero ? vzero : delta;
    cf = vone < cf ? vone : cf;
    store8(a.disp + x, acc ? dv : load8(a.disp + x));
    store8(a.conf + x, acc ? cf : load8(a.conf + x));
    V8u8 sb, wb;
    std::memcpy(&sb, a.stw + x, 8);
    std::memcpy(&wb, a.widx + x, 8);
    const V8s8 acc8 = __builtin_convertvector(acc, V8s8);
    const V8u8 ns = acc8 ? v_one8 : sb;
    const V8u8 nw = acc8 ? v_level8 : wb;
    std::memcpy(a.stw + x, &ns, 8);
    std::memcpy(a.widx + x, &nw, 8);
  }
  return x;
}

/// Effective range of each pixel of a dense row at one window size: its requested range
/// [rlo, rhi], cut so that both windows lie inside the images (empty - kEmptyLo > kEmptyHi, and
/// 1e9 > -1e9 as floats - outside [r, W - r) or when nothing is left). Branch-free (vectorised).
ES_KERNEL void denseRanges(int W, int r, const int* __restrict rlo, const int* __restrict rhi,
                           int* __restrict eff_lo, int* __restrict eff_hi,
                           float* __restrict eff_lo_f, float* __restrict eff_hi_f) {
  for (int x = 0; x < W; ++x) {
    const bool inside = (x >= r) & (x < W - r);
    int lo = std::max(rlo[x], x - (W - 1 - r));
    int hi = std::min(rhi[x], x - r);
    const bool ok = inside & (lo <= hi);
    lo = ok ? lo : kEmptyLo;
    hi = ok ? hi : kEmptyHi;
    eff_lo[x] = lo;
    eff_hi[x] = hi;
    eff_lo_f[x] = ok ? static_cast<float>(lo) : 1e9f;
    eff_hi_f[x] = ok ? static_cast<float>(hi) : -1e9f;
  }
}

/// The open pixels of a row at its first sparse window size, in column order into out (returns
/// how many): columns of [x0, x1) with a requested range (lo <= hi) and not accepted yet
/// (st == 0). Eight columns at a time; a group without an open pixel is skipped.
ES_KERNEL int openColumns(int x0, int x1, const int* __restrict rlo, const int* __restrict rhi,
                          const uint8_t* __restrict st, int* __restrict out) {
  using namespace simd;
  int n = 0, x = x0;
  for (; x + 8 <= x1; x += 8) {
    V8i lo, hi;
    std::memcpy(&lo, rlo + x, sizeof(lo));
    std::memcpy(&hi, rhi + x, sizeof(hi));
    const V8i sv = {st[x],     st[x + 1], st[x + 2], st[x + 3],
                    st[x + 4], st[x + 5], st[x + 6], st[x + 7]};
    const V8i m = (lo <= hi) & (sv == 0);
    if (!anyLane(m)) continue;
    for (int i = 0; i < 8; ++i) {
      out[n] = x + i;
      n += m[i] != 0;
    }
  }
  for (; x < x1; ++x) {
    out[n] = x;
    n += (rlo[x] <= rhi[x]) & (st[x] == 0);
  }
  return n;
}

/// The active pixels of a dense row (open at this window size: inside [r, W - r), a requested
/// range, not accepted yet; an effective range of at least 3 values; a left patch with
/// structure): act[x] = 1 (else 0); the open pixels that fail get their code. Returns how many
/// are active. Branch-free over the whole row.
ES_KERNEL int denseActive(int W, int r, const int* __restrict rlo, const int* __restrict rhi,
                          const uint8_t* __restrict st, const int* __restrict eff_lo,
                          const int* __restrict eff_hi, const float* __restrict gl, float gmin,
                          uint8_t* __restrict code, float* __restrict act) {
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i vr = V8i{} + r, vend = V8i{} + (W - r), two = V8i{} + 2;
  const V8f vgmin = splat8(gmin), vone = splat8(1.f), vzero = splat8(0.f);
  const V8u8 c_nopeak = V8u8{} + static_cast<uint8_t>(kCodeNoPeak);
  const V8u8 c_struct = V8u8{} + static_cast<uint8_t>(kCodeRejectStructure);
  V8i count = V8i{};
  int x = 0;
  // Eight columns at a time: the expressions of the loop below lane by lane, byte outputs
  // selected as bytes.
  for (; x + 8 <= W; x += 8) {
    V8i rl, rh, lo, hi;
    std::memcpy(&rl, rlo + x, sizeof(rl));
    std::memcpy(&rh, rhi + x, sizeof(rh));
    std::memcpy(&lo, eff_lo + x, sizeof(lo));
    std::memcpy(&hi, eff_hi + x, sizeof(hi));
    V8u8 sb, cb;
    std::memcpy(&sb, st + x, 8);
    std::memcpy(&cb, code + x, 8);
    const V8i xs = lane + x;
    const V8i unaccepted = __builtin_convertvector(sb == V8u8{}, V8i);
    const V8i searched = (xs >= vr) & (xs < vend) & (rl <= rh) & unaccepted & (lo <= hi);
    const V8i narrow = (hi - lo) < two;
    const V8i flat = ~(load8(gl + x) > vgmin);
    const V8s8 s8 = __builtin_convertvector(searched, V8s8);
    const V8s8 n8 = __builtin_convertvector(narrow, V8s8);
    const V8s8 f8 = __builtin_convertvector(flat, V8s8);
    const V8u8 nc = s8 ? (n8 ? c_nopeak : (f8 ? c_struct : cb)) : cb;
    std::memcpy(code + x, &nc, 8);
    const V8i a = searched & ~narrow & ~flat;
    store8(act + x, a ? vone : vzero);
    count -= a;  // -1 in active lanes
  }
  int na = 0;
  for (int i = 0; i < 8; ++i) na += count[i];
  for (; x < W; ++x) {
    const bool is_open = (x >= r) & (x < W - r) & (rlo[x] <= rhi[x]) & (st[x] == 0);
    const int lo = eff_lo[x], hi = eff_hi[x];
    const bool searched = is_open & (lo <= hi);  // else outside the matchable area: code stays
    const bool narrow = hi - lo < 2;
    const bool flat = !(gl[x] > gmin);
    const uint8_t keep = code[x];
    code[x] = !searched
                  ? keep
                  : (narrow ? uint8_t{kCodeNoPeak} : (flat ? uint8_t{kCodeRejectStructure} : keep));
    const bool a = searched & !narrow & !flat;
    act[x] = a ? 1.f : 0.f;
    na += a;
  }
  return na;
}

}  // namespace

void RowScratch::ensure(int w, int nd) {
  width = w;
  num_d = nd;
  dpad = (nd + 7) / 8 * 8;
  for (auto* vec : {&eff_lo_f, &eff_hi_f, &act, &best, &best_d, &best_l, &best_r, &second,
                    &rl_best_v, &rl_best_d, &maps.mean_l, &maps.inv_l, &maps.sum_r, &maps.inv_r,
                    &maps.gamma_l, &maps.gamma_r, &maps.sum_r_rev, &maps.inv_r_rev}) {
    vec->assign(w + 64, 0.f);
  }
  maps.stamp_l.assign(w, -1);
  maps.stamp_r.assign(w, -1);
  maps.stamp_gl.assign(w, -1);
  maps.stamp_gr.assign(w, -1);
  eff_lo.assign(w, 0);
  eff_hi.assign(w, 0);
}

void WorkerScratch::ensure(int w, int nd) {
  if (w == width && nd == num_d) return;
  RowScratch::ensure(w, nd);
  NarrowedScratch::ensure(w, nd);
  SparseScratch::ensure(w, nd, dpad);
  FullRangeScratch::ensure(w, dpad);
}

void WorkerScratch::resetSums() {
  NarrowedScratch::resetSums();
  SparseScratch::resetSums();
  FullRangeScratch::resetSums();
}
namespace {

/// Row y at one window size: its inputs and the thresholds of the criteria, shared by matchRow's
/// steps.
struct RowJob {
  /// Also points s.rlo_row, s.rhi_row at the row's requested ranges.
  RowJob(const WindowLevel& level, int row, WorkerScratch& scratch);

  const WindowLevel& c;
  WorkerScratch& s;
  int y, W, r;
  const int* rlo;  // requested range of each column
  const int* rhi;
  const uint8_t* st;  // 1 = accepted with a smaller window
  uint8_t* code;
  int dmin, dmax;
  float gmin, delta_min, min_ncc_full, min_ncc_narrow;

  /// A per-pixel range narrower than [dmin, dmax] (the test behind min_ncc_narrowed too).
  ES_INLINE bool narrowed(int x) const { return (rlo[x] > dmin) | (rhi[x] < dmax); }
  /// A pixel whose per-pixel range narrows the search has lost the competitors outside it, so
  /// its best peak must be stronger (min_ncc_narrowed): a prior must not weaken the criteria.
  ES_INLINE float minNcc(int x) const { return narrowed(x) ? min_ncc_narrow : min_ncc_full; }
  /// The discrimination test's margin: best peak minus the second (a single peak is measured
  /// against the lowest NCC, -1).
  ES_INLINE float peakGap(int x) const {
    const float comp = s.second[x] == kNegInf ? -1.f : s.second[x];
    return s.best[x] - comp;
  }
};

RowJob::RowJob(const WindowLevel& level, int row, WorkerScratch& scratch)
    : c(level),
      s(scratch),
      y(row),
      W(level.width),
      r(level.r),
      rlo(level.im->range_lo.ptr<int>(level.uniform_ranges ? 0 : row)),
      rhi(level.im->range_hi.ptr<int>(level.uniform_ranges ? 0 : row)),
      st(level.state->ptr<uint8_t>(row)),
      code(level.out->code.ptr<uint8_t>(row)),
      dmin(level.dmin),
      dmax(level.dmax),
      gmin(static_cast<float>(level.mp->gamma_min)),
      delta_min(static_cast<float>(level.mp->delta_min)),
      min_ncc_full(static_cast<float>(level.mp->min_ncc)),
      min_ncc_narrow(std::max(min_ncc_full, static_cast<float>(level.mp->min_ncc_narrowed))) {
  s.rlo_row = rlo;
  s.rhi_row = rhi;
}

/// How many pixels of the row are open at this level. Pixel x is open when it lies inside the
/// window's border, has a requested range and was not accepted with a smaller window. The first
/// window counts the requested pixels (n_req_rows) and builds no list. Sparse rows keep the open
/// pixels as a list: built from the row at the row's first sparse level, then filtered from level
/// to level (a row never turns dense again: its open pixels only get fewer).
int countOpenPixels(const RowJob& j) {
  const WindowLevel& c = j.c;
  const int W = j.W, r = j.r;
  const int* rlo = j.rlo;
  const int* rhi = j.rhi;
  const uint8_t* st = j.st;
  std::vector<int>& open = (*c.open_rows)[j.y];
  if (c.level == 0) {
    int n_open = 0;
    for (int x = r; x < W - r; ++x) n_open += rlo[x] <= rhi[x];
    (*c.n_req_rows)[j.y] = n_open;
    return n_open;
  }
  if ((*c.open_level)[j.y] == c.level - 1) {
    // Drop the pixels accepted with the smaller windows and those the larger window's border
    // excludes (it only grows).
    size_t kept = 0;
    for (const int x : open) {
      open[kept] = x;
      kept += (st[x] == 0) & (x >= r) & (x < W - r);
    }
    open.resize(kept);
    (*c.open_level)[j.y] = c.level;
    return static_cast<int>(kept);
  }
  open.resize(W);
  const int n_open = openColumns(r, W - r, rlo, rhi, st, open.data());
  open.resize(n_open);
  return n_open;
}

/// The window statistics the row's search needs. Dense: the effective range of each pixel (its
/// requested range, cut so that both windows lie inside the images; empty outside [r, W - r)),
/// also for pixels that are not matched themselves (their ranges bound the right-to-left
/// profiles), and every column's statistics. Sparse with uniform ranges: the NCC statistics of
/// the columns any open pixel's profiles or right-to-left checks can touch (within the disparity
/// span of an open pixel), vectorised; structure values lazily. With per-pixel ranges (narrow:
/// priors) few columns are touched: computed lazily instead.
void prepareStatistics(const RowJob& j, bool dense) {
  const WindowLevel& c = j.c;
  WorkerScratch& s = j.s;
  const int W = j.W, r = j.r, y = j.y;
  if (dense) {
    denseRanges(W, r, j.rlo, j.rhi, s.eff_lo.data(), s.eff_hi.data(), s.eff_lo_f.data(),
                s.eff_hi_f.data());
    computeRowMaps(c, s, y);
    return;
  }
  if (!c.uniform_ranges) return;
  // Open pixel x reads right statistics at x - d and, through the right-to-left profile of
  // x - d, left statistics at x - d + d' (d, d' in the range): columns x + lo_off .. x +
  // hi_off. Merged over the open pixels, so gaps between clusters of open pixels are skipped.
  const int lo_off = std::min({0, -c.dmax, c.dmin - c.dmax});
  const int hi_off = std::max({0, -c.dmin, c.dmax - c.dmin});
  int ia = -1, ib = -2;
  for (const int x : (*c.open_rows)[y]) {
    const int a = x + lo_off, b = x + hi_off;
    if (a > ib + 1) {
      if (ia <= ib) computeRowMaps(c, s, y, false, std::max(r, ia), std::min(W - 1 - r, ib));
      ia = a;
    }
    ib = std::max(ib, b);
  }
  if (ia <= ib) computeRowMaps(c, s, y, false, std::max(r, ia), std::min(W - 1 - r, ib));
}

/// Selects the active pixels: open, an effective range of at least 3 values (an interior maximum
/// needs two neighbours), a left patch with structure; the other open pixels get their code
/// here. Dense rows mark them in act (branch-free over the whole row: the effective ranges and
/// structure values are all at hand), sparse rows list them in s.active. Resets the peak
/// analysis of the active pixels. Returns whether any pixel is active.
bool activatePixels(const RowJob& j, bool dense) {
  const WindowLevel& c = j.c;
  WorkerScratch& s = j.s;
  const int W = j.W;
  uint8_t* code = j.code;
  s.active.clear();
  if (dense) {
    const int na = denseActive(W, j.r, j.rlo, j.rhi, j.st, s.eff_lo.data(), s.eff_hi.data(),
                               s.maps.gamma_l.data(), j.gmin, code, s.act.data());
    if (na == 0) return false;
    std::fill(s.best.begin(), s.best.begin() + W, kNegInf);
    std::fill(s.second.begin(), s.second.begin() + W, kNegInf);
    std::fill(s.best_d.begin(), s.best_d.begin() + W, 0.f);
    std::fill(s.best_l.begin(), s.best_l.begin() + W, 0.f);
    std::fill(s.best_r.begin(), s.best_r.begin() + W, 0.f);
    return true;
  }
  const float gmin = j.gmin;
  for (const int x : (*c.open_rows)[j.y]) {
    int lo, hi;
    if (!effectiveRange(c, s, x, &lo, &hi)) continue;
    if (hi - lo < 2) {
      code[x] = kCodeNoPeak;
      continue;
    }
    needGammaL(c, s, x, j.y);
    if (!(s.maps.gamma_l[x] > gmin)) {
      code[x] = kCodeRejectStructure;
      continue;
    }
    s.active.push_back(x);
  }
  if (s.active.empty()) return false;
  for (int x : s.active) {
    s.best[x] = s.second[x] = kNegInf;
    s.best_d[x] = s.best_l[x] = s.best_r[x] = 0.f;
  }
  return true;
}

/// The peak analysis of the active pixels by the row's engine (the choice only decides speed:
/// every engine gives the same values), and the right-to-left best disparities the decisions
/// read. A sparse row computes right-to-left profiles only where a pixel passes everything but
/// the left-right check.
void searchRow(const RowJob& j, bool dense) {
  const WindowLevel& c = j.c;
  WorkerScratch& s = j.s;
  const int y = j.y;
  if (dense) {
    if (c.uniform_ranges) {
      fullRangeRow(c, s, s, y);
    } else {
      narrowedRow(c, s, s, y);
    }
    return;
  }
  sparseRow(c, s, s, y);
  const float gmin = j.gmin, delta_min = j.delta_min;
  s.cand_q.clear();
  for (int x : s.active) {
    if (s.best[x] == kNegInf) continue;
    const int q = x - static_cast<int>(s.best_d[x]);
    needGammaR(c, s, q, y);
    if (!(s.maps.gamma_r[q] > gmin) || !(j.peakGap(x) > delta_min) || s.best[x] < j.minNcc(x)) {
      continue;
    }
    s.cand_q.push_back(q);
  }
  std::sort(s.cand_q.begin(), s.cand_q.end());
  s.cand_q.erase(std::unique(s.cand_q.begin(), s.cand_q.end()), s.cand_q.end());
  for (int q : s.cand_q) sparseRightToLeft(c, s, s, q, y);
}

/// Row y's outputs that an accepted pixel writes (and code, which every decision writes).
struct RowOutputs {
  uint8_t* code;
  float* disp;
  float* conf;
  uint8_t* stw;   // state: 1 = accepted
  uint8_t* widx;  // window index
};

/// decideDense's arguments for the columns [r, W - r) of a dense row.
DecideArgs denseDecideArgs(const RowJob& j, const RowOutputs& o, float eps, bool subpixel) {
  const WorkerScratch& s = j.s;
  DecideArgs g;
  g.x0 = j.r;
  g.x1 = j.W - j.r;
  g.act = s.act.data();
  g.best = s.best.data();
  g.second = s.second.data();
  g.best_d = s.best_d.data();
  g.best_l = s.best_l.data();
  g.best_r = s.best_r.data();
  g.gamma_r = s.maps.gamma_r.data();
  g.rl_best_d = s.rl_best_d.data();
  g.rlo = j.rlo;
  g.rhi = j.rhi;
  g.dmin = j.dmin;
  g.dmax = j.dmax;
  g.level = j.c.level;
  g.gmin = j.gmin;
  g.delta_min = j.delta_min;
  g.min_ncc_full = j.min_ncc_full;
  g.min_ncc_narrow = j.min_ncc_narrow;
  g.eps = eps;
  g.subpixel = subpixel;
  g.code = o.code;
  g.stw = o.stw;
  g.widx = o.widx;
  g.disp = o.disp;
  g.conf = o.conf;
  return g;
}

/// Decides each active pixel, criteria in the paper's order, without branches on the criteria.
/// Every value a decision depends on is at hand: dense rows computed the whole row, sparse rows
/// the structure values of every peak's right pixel and the right-to-left profiles of every
/// pixel that passes all but the left-right check. Other reads (the right pixel of a pixel
/// without a peak - best_d 0, so inside the row -, a right-to-left value behind a failed
/// criterion) cannot change the code, which takes the first failure.
void decideRow(const RowJob& j, bool dense) {
  const WindowLevel& c = j.c;
  const WorkerScratch& s = j.s;
  const int y = j.y;
  const RowOutputs o{j.code, c.out->disparity.ptr<float>(y), c.out->confidence.ptr<float>(y),
                     c.state->ptr<uint8_t>(y), c.window_idx->ptr<uint8_t>(y)};
  const float eps = static_cast<float>(c.mp->epsilon_px);
  const float gmin = j.gmin, delta_min = j.delta_min;
  const uint8_t accepted = static_cast<uint8_t>(kCodeAcceptedBase + c.level);
  const bool subpixel = c.mp->subpixel;
  auto decide = [&](int x) {
    const float b = s.best[x];
    const int bd = static_cast<int>(s.best_d[x]);
    const int q = x - bd;
    const float delta = j.peakGap(x);
    const bool no_peak = b == kNegInf;
    const bool flat = !(s.maps.gamma_r[q] > gmin);
    const bool gap = !(delta > delta_min) || b < j.minNcc(x);
    const bool lr = !(std::fabs(static_cast<float>(bd) - s.rl_best_d[q]) < eps);
    const uint8_t cd = no_peak ? uint8_t{kCodeNoPeak}
                       : flat  ? uint8_t{kCodeRejectStructure}
                       : gap   ? uint8_t{kCodeRejectPeakGap}
                       : lr    ? uint8_t{kCodeRejectLeftRight}
                               : accepted;
    o.code[x] = cd;
    if (cd != accepted) return;
    float sub = 0.f;
    if (subpixel) {
      const float den = s.best_l[x] - 2.f * b + s.best_r[x];
      if (den < 0.f) sub = std::clamp(0.5f * (s.best_l[x] - s.best_r[x]) / den, -0.5f, 0.5f);
    }
    o.disp[x] = static_cast<float>(bd) + sub;
    o.conf[x] = std::clamp(delta, 0.f, 1.f);
    o.stw[x] = 1;
    o.widx[x] = static_cast<uint8_t>(c.level);
  };
  if (dense) {
    // The active pixels span the row: eight columns at a time, the rest one by one.
    const int done = decideDense(denseDecideArgs(j, o, eps, subpixel));
    for (int x = done; x < j.W - j.r; ++x) {
      if (s.act[x] > 0.f) decide(x);
    }
  } else {
    for (const int x : s.active) decide(x);
  }
}

}  // namespace

/// Match the active pixels of row y at one window size; writes only row y of the outputs.
void matchRow(const WindowLevel& c, int y, WorkerScratch& s) {
  if (y < c.r || y >= c.height - c.r) return;
  ++s.stamp;
  const RowJob j(c, y, s);
  const int n_open = countOpenPixels(j);
  // Dense when most of the row is open (the first window): every column's range and statistics
  // are then needed and computed row-wide, and openness is tested row-wide too.
  const bool dense = n_open > 0 && 2 * n_open >= (*c.n_req_rows)[y];
  if (!dense && c.level > 0) (*c.open_level)[y] = c.level;  // the list just built or filtered
  if (n_open == 0) return;
  prepareStatistics(j, dense);
  if (!activatePixels(j, dense)) return;
  searchRow(j, dense);
  decideRow(j, dense);
}

}  // namespace detail
}  // namespace endo_stereo
