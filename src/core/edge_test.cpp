// Our measure against foreground fattening at depth edges (docs/matcher_design.md): run by
// RobustMatcher::compute after matching, before the post-filters. Two stages: a map test flags
// pixels whose accepting window holds a disparity jump; a second chance, looking at the images,
// keeps the flagged pixels that every small window around them confirms (a fattened pixel loses
// in the windows lying wholly on its true surface, a true foreground pixel next to the edge
// does not).
#include "edge_test.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <opencv2/imgproc.hpp>
#include <unordered_map>
#include <vector>

#include "simd.hpp"

namespace endo_stereo {
namespace {
using namespace simd;
}  // namespace

// ---------------------------------------------------------------------------------------------
// Our measure against fattening at depth edges (see the top of this file and
// docs/matcher_design.md). A pixel accepted with a window of width w is flagged when the accepted
// disparities within (w - 1) / 2 + edge_margin_px of it (judged on the map before this step) go
// more than edge_disparity_jump_px below its own, or more than edge_disparity_jump_above_px above
// it: its window straddles a depth edge. Below = the pixel may carry a nearer surface's
// disparity onto the farther one (the usual foreground fattening, measured as almost all of the
// remaining errors); above = it may carry the farther surface's disparity into the nearer one's
// edge (rarer; a looser threshold keeps the density). The margin reaches the last fattened pixels
// whose own window just misses the surface behind. With edge_window_max_px, pixels accepted with
// a wider window are also rejected when the w_min test fires. Min and max over each window size are
// grey-level erosions/dilations of the map (invalid pixels neutral): O(pixels) per window size.
// Flagged pixels are rejected, or, with edge_verify_radius_px > 0, verified (verifyFlagged).
// ---------------------------------------------------------------------------------------------
/// Least of lo_src and greatest of hi_src over columns [x0, x1] and rows [y0, y1]. Neither
/// holds NaN, so min and max are exact in any order: eight lanes, then the lanes folded.
namespace {
ES_KERNEL void windowMinMax(const cv::Mat& lo_src, const cv::Mat& hi_src, int x0, int x1, int y0,
                            int y1, float* lo, float* hi) {
  const float inf = std::numeric_limits<float>::infinity();
  V8f va = splat8(inf), vb = splat8(-inf);
  float a = inf, b = -inf;
  for (int yy = y0; yy <= y1; ++yy) {
    const float* ls = lo_src.ptr<float>(yy);
    const float* hs = hi_src.ptr<float>(yy);
    int xx = x0;
    for (; xx + 8 <= x1 + 1; xx += 8) {
      const V8f l = load8(ls + xx), h = load8(hs + xx);
      va = l < va ? l : va;
      vb = h > vb ? h : vb;
    }
    for (; xx <= x1; ++xx) {
      a = std::min(a, ls[xx]);
      b = std::max(b, hs[xx]);
    }
  }
  for (int i = 0; i < 8; ++i) {
    a = std::min(a, va[i]);
    b = std::max(b, vb[i]);
  }
  *lo = a;
  *hi = b;
}

/// hits[x] = 1 where pixel x of a row is accepted, judged at this level (any level with
/// @p all_levels) and its neighbourhood's least (@p a) or greatest (@p b) disparity straddles its
/// own (@p d, the map test's condition), else 0. Branch-free (vectorised).
ES_KERNEL void straddleRow(const uint8_t* c, const uint8_t* k, const float* d, const float* a,
                           const float* b, int W, int level, bool all_levels, float below,
                           float above, uint8_t* hits) {
  for (int x = 0; x < W; ++x) {
    const bool mine = (c[x] >= kCodeAcceptedBase) & (all_levels | (k[x] == level));
    const bool jump = (d[x] - a[x] > below) | (b[x] - d[x] > above);
    hits[x] = static_cast<uint8_t>(mine & jump);
  }
}

/// One pixel flagged by the map test, waiting for its second chance (see verifyFlagged).
struct Flagged {
  int x, y;
  int half;  ///< half width of the neighbourhood its test looked at, px
};

constexpr int kMaxHalf = 32 / 2 + 16;  // widest map-test neighbourhood: window 32, margin 16
constexpr int kMaxVerifyRadius = 6;    // MatcherParams::validate()
constexpr int kMaxSide = 2 * kMaxVerifyRadius + 1;  // window width

constexpr int kTile = 16;                         // window corners per tile side (WindowCache)
constexpr int kTileSpan = kTile + kMaxSide - 1;   // pixel rows / columns a tile reads
constexpr int kTileLanes = (kTileSpan + 7) / 8 * 8;  // tile columns rounded up to whole lanes

/// Whether a competitor's window (vl, vr, cov of windowParts) reaches a ZNCC >= @p own, without
/// square root or division (vectorisable): with c = cov and D = vl * vr > 0, ZNCC = c / sqrt(D);
/// for c >= 0 it is >= own when own <= 0 or c^2 >= own^2 D, and for c < 0 when own < 0 and
/// c^2 <= own^2 D. A flat patch (ZNCC -2 by definition) never reaches own >= -1. Every operand is
/// computed unconditionally and combined bitwise: no branch.
ES_INLINE bool beatsParts(int32_t vl, int32_t vr, int32_t cov, float own) {
  const float cf = static_cast<float>(cov);
  const float lhs = cf * cf;
  const float rhs = (own * own) * (static_cast<float>(vl) * static_cast<float>(vr));
  const bool valid = (vl > 0) & (vr > 0);
  const bool pos = cov >= 0;
  const bool up = (own <= 0.f) | (lhs >= rhs);
  const bool down = (own < 0.f) & (lhs <= rhs);
  return valid & ((pos & up) | (!pos & down));
}
/// Whether any of @p count windows (parts vl, vr, cov as in beatsParts) reaches @p own there.
ES_KERNEL bool anyBeats(const int32_t* vl, const int32_t* vr, const int32_t* cov,
                        const float* own, int count) {
  int any = 0;
  for (int i = 0; i < count; ++i) any |= beatsParts(vl[i], vr[i], cov[i], own[i]);
  return any != 0;
}

/// vl = n sll - sl^2, vr = n srr - sr^2, cov = n slr - sl sr and the ZNCC
/// cov / sqrt(vl vr) (-2 for a flat patch: vl <= 0 or vr <= 0) of @p count windows of n pixels
/// from their exact sums. Every product fits in int32 for windows up to 13 x 13
/// (n^2 255^2 < 2^31), hence kMaxVerifyRadius = 6. Branch-free (vectorised; the square root and
/// the division are IEEE-exact in any lane width, so the values do not depend on it).
ES_KERNEL void windowParts(int32_t n, const int32_t* sl, const int32_t* sll, const int32_t* sr,
                           const int32_t* srr, const int32_t* slr, int count,
                           int32_t* __restrict vl, int32_t* __restrict vr,
                           int32_t* __restrict cov, float* __restrict ncc) {
  for (int i = 0; i < count; ++i) {
    vl[i] = n * sll[i] - sl[i] * sl[i];
    vr[i] = n * srr[i] - sr[i] * sr[i];
    cov[i] = n * slr[i] - sl[i] * sr[i];
  }
  // Separate passes: GCC vectorises each of them, not the loop doing all three.
  for (int i = 0; i < count; ++i) {
    ncc[i] = static_cast<float>(cov[i]) /
             std::sqrt(static_cast<float>(vl[i]) * static_cast<float>(vr[i]));
  }
  for (int i = 0; i < count; ++i) {
    ncc[i] = (vl[i] > 0) & (vr[i] > 0) ? ncc[i] : -2.f;
  }
}

/// Sums (v, v^2, v * l) of every K x K window whose top-left corner lies in a rows_out x
/// cols_out block: column sums over K rows first, eight block columns per vector and carried
/// down the rows (one row in, one row out), then the horizontal sums from running sums along
/// each row of column sums. lv and rv hold the block's pixel rows (kTileLanes ints each, zero
/// beyond the block); outputs have a row stride of kTile. With rv = lv: (l, l^2, l^2). Exact.
ES_KERNEL void blockSums(const int32_t* lv, const int32_t* rv, int rows_out, int cols_out, int K,
                         int lanes, int32_t* s1, int32_t* s2, int32_t* s3) {
  const int nv = lanes / 8;
  V8i a1[kTileLanes / 8], a2[kTileLanes / 8], a3[kTileLanes / 8];
  const V8i zero = {0, 0, 0, 0, 0, 0, 0, 0};
  auto row = [&](int j, int v, V8i* r1, V8i* r2, V8i* r3) {
    V8i r, l;
    std::memcpy(&r, rv + j * kTileLanes + 8 * v, sizeof(r));
    std::memcpy(&l, lv + j * kTileLanes + 8 * v, sizeof(l));
    *r1 = r;
    *r2 = r * r;
    *r3 = r * l;
  };
  for (int v = 0; v < nv; ++v) a1[v] = a2[v] = a3[v] = zero;
  for (int j = 0; j < K; ++j) {
    for (int v = 0; v < nv; ++v) {
      V8i p1, p2, p3;
      row(j, v, &p1, &p2, &p3);
      a1[v] += p1;
      a2[v] += p2;
      a3[v] += p3;
    }
  }
  for (int oy = 0; oy < rows_out; ++oy) {
    if (oy > 0) {
      for (int v = 0; v < nv; ++v) {
        V8i i1, i2, i3, o1, o2, o3;
        row(oy + K - 1, v, &i1, &i2, &i3);
        row(oy - 1, v, &o1, &o2, &o3);
        a1[v] += i1 - o1;
        a2[v] += i2 - o2;
        a3[v] += i3 - o3;
      }
    }
    int32_t c1[kTileLanes], c2[kTileLanes], c3[kTileLanes];
    std::memcpy(c1, a1, sizeof(V8i) * nv);
    std::memcpy(c2, a2, sizeof(V8i) * nv);
    std::memcpy(c3, a3, sizeof(V8i) * nv);
    int32_t t1 = 0, t2 = 0, t3 = 0;
    for (int i = 0; i < K; ++i) {
      t1 += c1[i];
      t2 += c2[i];
      t3 += c3[i];
    }
    int32_t* o1 = s1 + oy * kTile;
    int32_t* o2 = s2 + oy * kTile;
    int32_t* o3 = s3 + oy * kTile;
    o1[0] = t1;
    o2[0] = t2;
    o3[0] = t3;
    for (int ox = 1; ox < cols_out; ++ox) {
      t1 += c1[ox + K - 1] - c1[ox - 1];
      t2 += c2[ox + K - 1] - c2[ox - 1];
      t3 += c3[ox + K - 1] - c3[ox - 1];
      o1[ox] = t1;
      o2[ox] = t2;
      o3[ox] = t3;
    }
  }
}

/// Per window of one tile: for the left image (key disparity kLeftKey) a = sum l, b = sum l^2;
/// for a disparity q, a = vl, b = vr, c = cov of windowParts and ncc its value (-2 where the
/// right window leaves the image or a patch is flat). Index oy * kTile + ox.
struct TileSums {
  int32_t a[kTile * kTile], b[kTile * kTile], c[kTile * kTile];
  float ncc[kTile * kTile];
};

/// Window values of the second chance shared between flagged pixels: windows of width
/// K = 2 r + 1 are grouped by their top-left corner into kTile x kTile tiles, and each
/// (tile, disparity) is computed once, on first use, with separable integer sums (exact, so
/// every value equals the one computed for a single pixel's windows). Flagged pixels come in
/// bands along depth edges, whose windows overlap heavily.
class WindowCache {
 public:
  static constexpr int kLeftKey = -1;

  void reset(const cv::Mat& left, const cv::Mat& right, int r, int min_disparity, int nd) {
    left_ = &left;
    right_ = &right;
    r_ = r;
    k_ = 2 * r + 1;
    min_d_ = min_disparity;
    nd_ = nd;
    tiles_x_ = (left.cols + kTile - 1) / kTile;
    clear();
  }
  /// Forgets every tile (the memory is kept).
  void clear() {
    index_.clear();
    used_ = 0;
  }
  /// Called before each pixel: forgets every tile once many are held (the memory is kept), so
  /// the tiles a pixel fetches stay valid while it is judged.
  void beginPixel() {
    if (used_ > kSoftMaxTiles) clear();
  }
  /// The tile (tx, ty) at disparity q (kLeftKey: the left sums). Valid until beginPixel().
  const TileSums& tile(int tx, int ty, int q) {
    const int64_t key = (static_cast<int64_t>(ty) * tiles_x_ + tx) * (nd_ + 1) +
                        (q == kLeftKey ? 0 : q - min_d_ + 1);
    const auto it = index_.find(key);
    if (it != index_.end()) return *pool_[it->second];
    const TileSums* l = q == kLeftKey ? nullptr : &tile(tx, ty, kLeftKey);
    if (used_ == static_cast<int>(pool_.size())) pool_.emplace_back(new TileSums);
    TileSums& t = *pool_[used_];
    if (l != nullptr) {
      buildRight(tx, ty, q, *l, t);
    } else {
      buildLeft(tx, ty, t);
    }
    index_.emplace(key, used_++);
    return t;
  }

 private:
  // Bounds the memory (4 KiB a tile: 16 MiB per thread); the speed scene (960x540, 12k flagged
  // pixels) builds about 1900 tiles in all.
  static constexpr int kSoftMaxTiles = 4096;

  /// The tile's first window corner, its window counts and its left pixels (zero-padded).
  void block(int tx, int ty, int* wx0, int* wy0, int* nx, int* ny) const {
    *wx0 = tx * kTile;
    *wy0 = ty * kTile;
    *nx = std::min(kTile, left_->cols - k_ + 1 - *wx0);
    *ny = std::min(kTile, left_->rows - k_ + 1 - *wy0);
  }
  void leftPixels(int wx0, int wy0, int nx, int ny, int lanes) {
    for (int j = 0; j < ny + k_ - 1; ++j) {
      const uint8_t* lp = left_->ptr<uint8_t>(wy0 + j) + wx0;
      const int cols = nx + k_ - 1;
      if (wx0 + lanes <= left_->cols) {
        for (int i = 0; i < lanes; ++i) lv_[j][i] = lp[i];
        for (int i = cols; i < lanes; ++i) lv_[j][i] = 0;
      } else {
        for (int i = 0; i < lanes; ++i) lv_[j][i] = i < cols ? lp[i] : 0;
      }
    }
  }
  void buildLeft(int tx, int ty, TileSums& t) {
    int wx0, wy0, nx, ny;
    block(tx, ty, &wx0, &wy0, &nx, &ny);
    const int lanes = (nx + k_ - 1 + 7) / 8 * 8;
    leftPixels(wx0, wy0, nx, ny, lanes);
    blockSums(&lv_[0][0], &lv_[0][0], ny, nx, k_, lanes, t.a, t.b, t.c);
  }
  void buildRight(int tx, int ty, int q, const TileSums& l, TileSums& t) {
    int wx0, wy0, nx, ny;
    block(tx, ty, &wx0, &wy0, &nx, &ny);
    const int W = right_->cols;
    const int cols = nx + k_ - 1;
    const int lanes = (cols + 7) / 8 * 8;
    leftPixels(wx0, wy0, nx, ny, lanes);
    const int x0 = wx0 - q;  // first right column of the block
    for (int j = 0; j < ny + k_ - 1; ++j) {
      const uint8_t* rp = right_->ptr<uint8_t>(wy0 + j);
      if (x0 >= 0 && x0 + lanes <= W) {
        for (int i = 0; i < lanes; ++i) rv_[j][i] = rp[x0 + i];
        for (int i = cols; i < lanes; ++i) rv_[j][i] = 0;
      } else {
        // Columns outside the right image are clamped; the windows reading them are zeroed.
        for (int i = 0; i < lanes; ++i) {
          rv_[j][i] = i < cols ? rp[std::min(std::max(x0 + i, 0), W - 1)] : 0;
        }
      }
    }
    int32_t sr[kTile * kTile], srr[kTile * kTile], slr[kTile * kTile];
    blockSums(&lv_[0][0], &rv_[0][0], ny, nx, k_, lanes, sr, srr, slr);
    // Windows whose right window leaves the image get zero right sums (vr = 0: ZNCC -2, never
    // beating anything).
    const int ox_lo = std::max(0, -x0), ox_hi = std::min(nx, W - k_ + 1 - x0);
    if (ox_lo > 0 || ox_hi < nx) {
      for (int oy = 0; oy < ny; ++oy) {
        for (int ox = 0; ox < nx; ++ox) {
          if (ox >= ox_lo && ox < ox_hi) continue;
          sr[oy * kTile + ox] = srr[oy * kTile + ox] = 0;
        }
      }
    }
    const int32_t n = k_ * k_;
    if (nx == kTile) {
      windowParts(n, l.a, l.b, sr, srr, slr, ny * kTile, t.a, t.b, t.c, t.ncc);
    } else {
      for (int oy = 0; oy < ny; ++oy) {
        const int o = oy * kTile;
        windowParts(n, l.a + o, l.b + o, sr + o, srr + o, slr + o, nx, t.a + o, t.b + o, t.c + o,
                    t.ncc + o);
      }
    }
  }

  const cv::Mat* left_ = nullptr;
  const cv::Mat* right_ = nullptr;
  int r_ = 0, k_ = 1, min_d_ = 0, nd_ = 1, tiles_x_ = 1, used_ = 0;
  std::unordered_map<int64_t, int> index_;
  std::vector<std::unique_ptr<TileSums>> pool_;
  alignas(32) int32_t lv_[kTileSpan][kTileLanes];
  alignas(32) int32_t rv_[kTileSpan][kTileLanes];
};

/// Constants of one flagged pixel's competitor scan (see verifyFlagged).
struct ScanArgs {
  float d, below, above;  ///< the pixel's disparity and the map test's thresholds
  float v_lo, v_hi;       ///< disparities are clamped to these before rounding
  int slot_off;           ///< slot of rounded disparity c = c + slot_off
  int no_slot;            ///< larger than any slot
};

/// The whole competitor scan of one pixel, eight neighbours per vector, rows of @p len
/// neighbours read from @p base (@p stride floats apart; the map padded with NaN, which never
/// triggers, so no clamping to the image and whole vectors past len read only padding or are
/// masked out). slot of neighbour i = 0 when it does not trigger the test, else c + slot_off for
/// its rounded disparity c; every row's slots are marked in @p mark (slot 0 included, cleared by
/// the caller). The triggering neighbours' offsets (dx0 + i, dy0 + row) are summed into *sum_dx,
/// *sum_dy and their slot range kept in *slot_min / *slot_max.
ES_KERNEL void scanBlock(const ScanArgs& a, const float* base, size_t stride, int rows, int len,
                         int dx0, int dy0, uint8_t* mark, int* sum_dx, int* sum_dy, int* slot_min,
                         int* slot_max) {
  const V8f d = splat8(a.d), below = splat8(a.below), above = splat8(a.above);
  const V8f v_lo = splat8(a.v_lo), v_hi = splat8(a.v_hi), half = splat8(0.5f), zero_f = splat8(0.f);
  const V8i slot_off = {a.slot_off, a.slot_off, a.slot_off, a.slot_off,
                        a.slot_off, a.slot_off, a.slot_off, a.slot_off};
  const V8i no_slot = {a.no_slot, a.no_slot, a.no_slot, a.no_slot,
                       a.no_slot, a.no_slot, a.no_slot, a.no_slot};
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i lenv = {len, len, len, len, len, len, len, len};
  const V8i zero = {0, 0, 0, 0, 0, 0, 0, 0};
  V8i vmin = no_slot, vmax = zero, vdx = zero;
  int sdy = 0;
  alignas(32) int32_t slots[2 * (kMaxHalf + 1) + 8];
  for (int j = 0; j < rows; ++j) {
    const float* row = base + j * stride;
    V8i cnt = zero;
    for (int i = 0; i < len; i += 8) {
      const V8f v = load8(row + i);
      const V8i idx = lane + i;
      // NaN: both comparisons false.
      const V8i t = ((d - v > below) | (v - d > above)) & (idx < lenv);
      V8f vc = t ? v : d;
      vc = vc < v_lo ? v_lo : vc;
      vc = vc > v_hi ? v_hi : vc;
      // std::lround (half away from zero): |vc| + 0.5 is exact here, then truncation.
      const V8i neg = vc < zero_f;
      const V8i mag = __builtin_convertvector((neg ? -vc : vc) + half, V8i);
      const V8i c = neg ? -mag : mag;
      const V8i slot = t ? c + slot_off : zero;
      std::memcpy(slots + i, &slot, sizeof(slot));
      cnt -= t;  // t is -1 in triggering lanes
      vdx += t & (idx + dx0);
      vmin = (t ? slot : no_slot) < vmin ? (t ? slot : no_slot) : vmin;
      vmax = slot > vmax ? slot : vmax;
    }
    const int row_count =
        cnt[0] + cnt[1] + cnt[2] + cnt[3] + cnt[4] + cnt[5] + cnt[6] + cnt[7];
    if (row_count == 0) continue;
    sdy += row_count * (dy0 + j);
    for (int i = 0; i < len; ++i) mark[slots[i]] = 1;
  }
  int smin = *slot_min, smax = *slot_max;
  for (int i = 0; i < 8; ++i) {
    smin = std::min(smin, vmin[i]);
    smax = std::max(smax, vmax[i]);
    *sum_dx += vdx[i];
  }
  *sum_dy += sdy;
  *slot_min = smin;
  *slot_max = smax;
}

/// Reusable per-thread buffers of verifyFlagged.
struct VerifyScratch {
  std::vector<uint8_t> seen;  // per disparity of the search range: already listed
  std::vector<int> alts;      // competing disparities of one pixel
  std::vector<uint8_t> mark;  // per rounded neighbour disparity: seen among the triggering ones
  WindowCache cache;          // window values shared between the pixels
};

/// The second chance of one flagged pixel (MatcherParams::edge_verify_radius_px). Competitors:
/// the disparities measured on the other side of the jump, i.e. those of the neighbours that
/// triggered the test (rounded, +-1 px, within the search range, at least 2 px from the pixel's
/// own). The pixel is kept when every window of width 2 r + 1 containing it gives its own
/// disparity (the better of the two integers around the sub-pixel value) a ZNCC >= min_ncc and a
/// higher ZNCC than every competitor. Reads only the images and the map before the step.
bool verifyFlagged(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& disparity,
                   const cv::Mat& padded, int pad, const Flagged& f, float below, float above,
                   VerifyScratch& sc) {
  const int r = mp.edge_verify_radius_px;
  const int W = left.cols, H = left.rows;
  if (f.x - 2 * r < 0 || f.x + 2 * r > W - 1 || f.y - 2 * r < 0 || f.y + 2 * r > H - 1) {
    return false;  // some windows containing the pixel leave the image: no full verdict
  }
  const float d = disparity.at<float>(f.y, f.x);
  const int q_lo = static_cast<int>(std::floor(d)), q_hi = static_cast<int>(std::ceil(d));
  const float min_ncc = static_cast<float>(mp.edge_verify_min_ncc);
  // The verdict is a conjunction over windows and disparities, so its terms go cheapest and
  // most decisive first: the own ZNCC of every window (needs no competitors; a fattened pixel
  // usually fails it in the windows lying on its true surface), then the competitors.
  //
  // Every window containing the pixel: top-left corners (x - 2 r .. x, y - 2 r .. y), lying in
  // at most 2 x 2 tiles (2 r + 1 < kTile).
  const int K = 2 * r + 1;
  const int wx0 = f.x - 2 * r, wy0 = f.y - 2 * r;
  const int tx0 = wx0 / kTile, ty0 = wy0 / kTile;
  const int ntx = f.x / kTile - tx0 + 1, nty = f.y / kTile - ty0 + 1;
  WindowCache& cache = sc.cache;
  cache.beginPixel();
  const TileSums* t[2][2];
  auto fetch = [&](int q) {
    for (int j = 0; j < nty; ++j) {
      for (int i = 0; i < ntx; ++i) t[j][i] = &cache.tile(tx0 + i, ty0 + j, q);
    }
  };
  // Row oy of the pixel's windows in at most two tile-aligned segments: windows ox < split lie in
  // tile column 0 (from index *i0), the others in tile column 1 (from index *i1).
  const int split = std::min(K, (tx0 + 1) * kTile - wx0);
  auto segments = [&](int oy, int* j, int* i0, int* i1) {
    const int wy = wy0 + oy;
    *j = wy / kTile - ty0;
    const int row = (wy - (ty0 + *j) * kTile) * kTile;
    *i0 = row + (wx0 - tx0 * kTile);
    *i1 = row - split;  // tile column 1 starts at window ox = split
  };
  float own[kMaxSide * kMaxSide];
  fetch(q_lo);
  for (int oy = 0; oy < K; ++oy) {
    int j, i0, i1;
    segments(oy, &j, &i0, &i1);
    for (int ox = 0; ox < split; ++ox) own[oy * K + ox] = t[j][0]->ncc[i0 + ox];
    for (int ox = split; ox < K; ++ox) own[oy * K + ox] = t[j][1]->ncc[i1 + ox];
  }
  if (q_hi != q_lo) {
    fetch(q_hi);
    for (int oy = 0; oy < K; ++oy) {
      int j, i0, i1;
      segments(oy, &j, &i0, &i1);
      float* o = own + oy * K;
      for (int ox = 0; ox < split; ++ox) o[ox] = std::max(o[ox], t[j][0]->ncc[i0 + ox]);
      for (int ox = split; ox < K; ++ox) o[ox] = std::max(o[ox], t[j][1]->ncc[i1 + ox]);
    }
  }
  for (int i = 0; i < K * K; ++i) {
    if (!(own[i] >= min_ncc) || own[i] <= -2.f) return false;
  }

  // Competitors from the neighbourhood the map test looked at. The rounded disparities of the
  // triggering neighbours are marked in a table (a set: the pixels' order cannot matter), in a
  // branch-free pass; then each marked value is widened by +-1. Slots: 0 = not triggering,
  // c - min_disparity + 3 for a rounded disparity c (valid centres min - 1 .. max + 1 are slots
  // 2 .. nd + 3; values beyond are clamped into slots 1 and nd + 4, which give no competitor).
  sc.alts.clear();
  const int nd = mp.max_disparity - mp.min_disparity + 1;
  if (static_cast<int>(sc.mark.size()) != nd + 5) {
    sc.mark.assign(nd + 5, 0);
    sc.seen.assign(nd, 0);
  }
  const float v_lo = static_cast<float>(mp.min_disparity - 2);
  const float v_hi = static_cast<float>(mp.max_disparity + 2);
  const int slot_off = 3 - mp.min_disparity;
  int sum_dx = 0, sum_dy = 0;  // where the triggering neighbours lie, relative to the pixel
  int slot_min = nd + 5, slot_max = 0;
  uint8_t* mark = sc.mark.data();
  const ScanArgs sa{d, below, above, v_lo, v_hi, slot_off, nd + 5};
  scanBlock(sa, padded.ptr<float>(pad + f.y - f.half) + pad + f.x - f.half, padded.step1(),
            2 * f.half + 1, 2 * f.half + 1, -f.half, -f.half, mark, &sum_dx, &sum_dy, &slot_min,
            &slot_max);
  for (int slot = std::max(2, slot_min); slot <= std::min(nd + 3, slot_max); ++slot) {
    if (!mark[slot]) continue;
    const int c = slot - slot_off;
    for (int q = std::max(c - 1, mp.min_disparity); q <= std::min(c + 1, mp.max_disparity); ++q) {
      if (sc.seen[q - mp.min_disparity] || std::fabs(static_cast<float>(q) - d) < 2.f) continue;
      sc.seen[q - mp.min_disparity] = 1;
      sc.alts.push_back(q);
    }
  }
  mark[0] = 0;
  for (int slot = slot_min; slot <= slot_max; ++slot) mark[slot] = 0;
  for (int q : sc.alts) sc.seen[q - mp.min_disparity] = 0;

  // Each competitor first in the window shifted furthest towards the triggering neighbours
  // (where a competitor usually wins if it wins anywhere), then in every window.
  const int probe = (sum_dy > 0 ? 2 * r : sum_dy < 0 ? 0 : r) * K +
                    (sum_dx > 0 ? 2 * r : sum_dx < 0 ? 0 : r);
  const int probe_y = probe / K, probe_x = probe % K;
  for (int q : sc.alts) {
    fetch(q);
    int j, i0, i1;
    segments(probe_y, &j, &i0, &i1);
    const TileSums* tp = probe_x < split ? t[j][0] : t[j][1];
    const int ip = probe_x < split ? i0 + probe_x : i1 + probe_x;
    if (beatsParts(tp->a[ip], tp->b[ip], tp->c[ip], own[probe])) return false;
  }
  for (int q : sc.alts) {
    fetch(q);
    for (int oy = 0; oy < K; ++oy) {
      int j, i0, i1;
      segments(oy, &j, &i0, &i1);
      const TileSums* a = t[j][0];
      if (anyBeats(a->a + i0, a->b + i0, a->c + i0, own + oy * K, split)) return false;
      if (split < K) {
        const TileSums* b = t[j][1];
        // (i1 + split) first: i1 alone may be negative, and a pointer before the array is UB.
        const int ib = i1 + split;
        if (anyBeats(b->a + ib, b->b + ib, b->c + ib, own + oy * K + split, K - split)) {
          return false;
        }
      }
    }
  }
  return true;
}

}  // namespace

void rejectEdgeStraddlers(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                          int num_levels, const cv::Mat& window_idx, MatchResult& out,
                          cv::Mat& lo_src, cv::Mat& hi_src, cv::Mat& lo, cv::Mat& hi,
                          cv::Mat& reject) {
  const int H = out.disparity.rows, W = out.disparity.cols;
  const float inf = std::numeric_limits<float>::infinity();
  lo_src.create(H, W, CV_32F);
  hi_src.create(H, W, CV_32F);
  for (int y = 0; y < H; ++y) {
    const float* d = out.disparity.ptr<float>(y);
    float* a = lo_src.ptr<float>(y);
    float* b = hi_src.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const bool v = !std::isnan(d[x]);
      a[x] = v ? d[x] : inf;
      b[x] = v ? d[x] : -inf;
    }
  }
  const bool on = mp.edge_disparity_jump_px > 0.0;
  const float below = on ? static_cast<float>(mp.edge_disparity_jump_px) : inf;
  const float above = !on ? inf
                          : static_cast<float>(mp.edge_disparity_jump_above_px > 0.0
                                                   ? mp.edge_disparity_jump_above_px
                                                   : mp.edge_disparity_jump_px);
  const int margin = mp.edge_margin_px;
  const int limit_w = mp.edge_window_max_px;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // Rejections are applied after all window sizes are judged, so every test sees the same map.
  reject.create(H, W, CV_8U);
  reject.setTo(0);
  // Pixels accepted per window size (the first window: nearly all of them; the larger ones: few).
  // Counted first; the pixels themselves are listed only for the levels scanned directly.
  std::vector<size_t> level_count(num_levels, 0);
  for (int y = 0; y < H; ++y) {
    const uint8_t* c = out.code.ptr<uint8_t>(y);
    const uint8_t* k = window_idx.ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) {
      if (c[x] >= kCodeAcceptedBase) ++level_count[k[x]];
    }
  }
  auto levelCount = [&](int level) -> size_t {
    // The w_min test also serves edge_window_max_px for the pixels of every window size.
    return level == 0 && limit_w > 0 ? static_cast<size_t>(out.stats.total_pixels)
                                     : level_count[level];
  };
  auto levelSide = [&](int level) {
    return 2 * ((mp.window_min_px + level * mp.window_step_px) / 2 + margin) + 1;
  };
  // Many pixels: erosion/dilation of the whole map; few: a direct scan of each one's window.
  auto scanDirectly = [&](int level) {
    const size_t side = static_cast<size_t>(levelSide(level));
    return !(levelCount(level) * side * side > static_cast<size_t>(H) * W * 8);
  };
  std::vector<std::vector<cv::Point>> by_level(num_levels);
  std::vector<uint8_t> listed(num_levels, 0);
  bool any_listed = false;
  for (int level = 0; level < num_levels; ++level) {
    listed[level] = levelCount(level) > 0 && scanDirectly(level);
    if (listed[level]) by_level[level].reserve(level_count[level]);
    any_listed = any_listed || listed[level];
  }
  for (int y = 0; y < H && any_listed; ++y) {
    const uint8_t* c = out.code.ptr<uint8_t>(y);
    const uint8_t* k = window_idx.ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) {
      if (c[x] >= kCodeAcceptedBase && listed[k[x]]) by_level[k[x]].push_back(cv::Point(x, y));
    }
  }
  auto straddles = [&](float d, float a, float b) { return d - a > below || b - d > above; };
  // Pixels flagged by their own window's test get a second chance (verifyFlagged) when
  // edge_verify_radius_px > 0; they are listed here and judged after the map test.
  const bool verify = mp.edge_verify_radius_px > 0 && left.type() == CV_8UC1 &&
                      right.type() == CV_8UC1 && left.size() == out.disparity.size() &&
                      right.size() == out.disparity.size();
  std::vector<Flagged> flagged;
  for (int level = 0; level < num_levels; ++level) {
    const int w = mp.window_min_px + level * mp.window_step_px;
    const int half = w / 2 + margin;
    const int side = levelSide(level);
    const bool all_levels = level == 0 && limit_w > 0;
    if (levelCount(level) == 0) continue;
    auto judge = [&](int x, int y, float a, float b) {
      const float d = out.disparity.at<float>(y, x);
      if (!straddles(d, a, b)) return;
      const int k = window_idx.at<uint8_t>(y, x);
      if (k == level) {
        if (verify) {
          flagged.push_back(Flagged{x, y, half});
        } else {
          reject.at<uint8_t>(y, x) = 1;
        }
      }
      if (all_levels && mp.window_min_px + k * mp.window_step_px > limit_w) {
        reject.at<uint8_t>(y, x) = 1;
      }
    };
    if (!scanDirectly(level)) {
      // Many pixels: separable erosion and dilation of the whole map.
      const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side, side));
      cv::erode(lo_src, lo, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(inf));
      cv::dilate(hi_src, hi, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(-inf));
      std::vector<uint8_t> hits(W + 8, 0);
      for (int y = 0; y < H; ++y) {
        const float* a = lo.ptr<float>(y);
        const float* b = hi.ptr<float>(y);
        straddleRow(out.code.ptr<uint8_t>(y), window_idx.ptr<uint8_t>(y),
                    out.disparity.ptr<float>(y), a, b, W, level, all_levels, below, above,
                    hits.data());
        // Hits are rare: skip eight clear pixels at a time.
        for (int x0 = 0; x0 < W; x0 += 8) {
          uint64_t word;
          std::memcpy(&word, hits.data() + x0, sizeof(word));
          if (word == 0) continue;
          for (int x = x0; x < std::min(W, x0 + 8); ++x) {
            if (hits[x]) judge(x, y, a[x], b[x]);
          }
        }
      }
    } else {
      // Few pixels: scan each one's window directly.
      for (const cv::Point& p : by_level[level]) {
        float a, b;
        windowMinMax(lo_src, hi_src, std::max(0, p.x - half), std::min(W - 1, p.x + half),
                     std::max(0, p.y - half), std::min(H - 1, p.y + half), &a, &b);
        judge(p.x, p.y, a, b);
      }
    }
  }
  if (!flagged.empty()) {
    // Every verdict reads only the images and the flagged pixel's own entry, so fixed chunks
    // over the threads give the same result whatever their number.
    std::vector<uint8_t> keep(flagged.size(), 0);
    // The map framed in NaN (never triggering) for the competitor scans: no clamping to the
    // image, and whole vectors may read past a row's end (8 columns more on the right).
    int pad = 0;
    for (const Flagged& f : flagged) pad = std::max(pad, f.half);
    cv::Mat padded(H + 2 * pad, W + 2 * pad + 8, CV_32F, cv::Scalar(nan));
    out.disparity.copyTo(padded(cv::Rect(pad, pad, W, H)));
    constexpr int kChunk = 256;
    const int num_chunks = static_cast<int>((flagged.size() + kChunk - 1) / kChunk);
    cv::parallel_for_(cv::Range(0, num_chunks), [&](const cv::Range& rg) {
      VerifyScratch sc;
      sc.cache.reset(left, right, mp.edge_verify_radius_px, mp.min_disparity,
                     mp.max_disparity - mp.min_disparity + 1);
      for (int c = rg.start; c < rg.end; ++c) {
        const size_t e = std::min(flagged.size(), static_cast<size_t>(c + 1) * kChunk);
        for (size_t i = static_cast<size_t>(c) * kChunk; i < e; ++i) {
          keep[i] = verifyFlagged(mp, left, out.disparity, padded, pad, flagged[i], below,
                                  above, sc);
        }
      }
    });
    for (size_t i = 0; i < flagged.size(); ++i) {
      if (!keep[i]) reject.at<uint8_t>(flagged[i].y, flagged[i].x) = 1;
    }
  }
  for (int y = 0; y < H; ++y) {
    const uint8_t* rj = reject.ptr<uint8_t>(y);
    float* d = out.disparity.ptr<float>(y);
    float* cf = out.confidence.ptr<float>(y);
    uint8_t* c = out.code.ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) {
      if (!rj[x]) continue;
      d[x] = nan;
      cf[x] = 0.f;
      c[x] = kCodeRejectEdge;
    }
  }
}

}  // namespace endo_stereo
