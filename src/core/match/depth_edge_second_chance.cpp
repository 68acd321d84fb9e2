// The second chance of the depth-edge filter (depth_edge_filter.cpp): a pixel the map test
// flagged is kept when every small window around it confirms its disparity against the
// disparities of the neighbours that flagged it (a fattened pixel loses in the windows lying
// wholly on its true surface, a true foreground pixel next to the edge does not). Window values
// are shared between the flagged pixels through a tile cache (WindowCache).
#include "depth_edge_second_chance.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <opencv2/core/utility.hpp>
#include <vector>

#include "simd.hpp"

namespace endo_stereo {
namespace detail {
namespace {
using namespace simd;

// Whether any lane of a comparison mask is set (simd::anyLane, the mask by reference: no note
// from GCC about the ABI of 32-byte vector arguments in the baseline clones).
ES_INLINE bool anySet(const V8i& m) {
  // The two halves folded first (one vector OR), then the two 64-bit words of the result.
  typedef int V4i __attribute__((vector_size(16)));
  const V4i h =
      __builtin_shufflevector(m, m, 0, 1, 2, 3) | __builtin_shufflevector(m, m, 4, 5, 6, 7);
  uint64_t w[2];
  std::memcpy(w, &h, sizeof(w));
  return (w[0] | w[1]) != 0;
}

constexpr int kMaxVerifyRadius = 6;                 // MatcherParams::validate()
constexpr int kMaxSide = 2 * kMaxVerifyRadius + 1;  // window width

// WindowCache tiles: a block of kTile rows x kTileW columns of window corners, each tile row
// also holding the 2 r corners right of its block, so that the 2 r + 1 windows of one pixel in a
// row are contiguous in one tile (read as 16 lanes from column 0 .. kTileW - 1: kTileStride >=
// kTileW + 15). 32 block columns rather than 16 (measured: 4% fewer instructions for the whole
// step on the surgical sequence, 24 gave 1%, 48 no more; 8 was 20% worse).
constexpr int kTile = 16;                         // window corner rows per tile
constexpr int kTileW = 32;                        // block columns per tile
constexpr int kTileCols = kTileW + kMaxSide - 1;  // window corners per tile row, at most
constexpr int kTileStride = 48;                   // row stride of a tile's window values
constexpr int kTileSpan = kTile + kMaxSide - 1;   // pixel rows a tile reads
constexpr int kTileLanes = (kTileCols + kMaxSide - 1 + 7) / 8 * 8;  // pixel columns, whole lanes
constexpr int kRowLanes = 16;  // lanes per window row of one pixel
static_assert(kTileStride >= kTileW - 1 + kRowLanes && kTileStride >= kTileCols, "tile layout");
static_assert(kRowLanes >= kMaxSide, "one pixel's window row in 16 lanes");
static_assert((kTileCols + 7) / 8 * 8 <= kTileStride, "blockSums writes whole vectors");

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
/// vl = n sll - sl^2, vr = n srr - sr^2, cov = n slr - sl sr and the ZNCC
/// cov / sqrt(vl vr) (-2 for a flat patch: vl <= 0 or vr <= 0) of @p count windows of n pixels
/// from their exact sums. Every product fits in int32 for windows up to 13 x 13
/// (n^2 255^2 < 2^31), hence kMaxVerifyRadius = 6. Branch-free (vectorised; the square root and
/// the division are IEEE-exact in any lane width, so the values do not depend on it).
ES_KERNEL void windowParts(int32_t n, const int32_t* sl, const int32_t* sll, const int32_t* sr,
                           const int32_t* srr, const int32_t* slr, int count,
                           int32_t* __restrict vl, int32_t* __restrict vr, int32_t* __restrict cov,
                           float* __restrict ncc) {
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
    ncc[i] = ((vl[i] > 0) & (vr[i] > 0)) ? ncc[i] : -2.f;
  }
}

/// Sums (v, v^2, v * l) of every K x K window whose top-left corner lies in a rows_out x
/// cols_out block: column sums over K rows first, eight block columns per vector and carried
/// down the rows (one row in, one row out), then the horizontal sums from running sums along
/// each row of column sums. lv and rv hold the block's pixel rows (kTileLanes ints each, zero
/// beyond the block); outputs have a row stride of kTileStride. With rv = lv: (l, l^2, l^2).
/// Exact.
ES_KERNEL void blockSums(const int32_t* lv, const int32_t* rv, int rows_out, int cols_out, int K,
                         int lanes, int32_t* s1, int32_t* s2, int32_t* s3) {
  const int nv = lanes / 8;
  // Column sums of one output row, in place; the horizontal sums read up to K - 1 + 7 lanes
  // past the last vector used: two more vectors, zero.
  V8i a1[kTileLanes / 8 + 2], a2[kTileLanes / 8 + 2], a3[kTileLanes / 8 + 2];
  const V8i zero = {0, 0, 0, 0, 0, 0, 0, 0};
  const char* c1 = reinterpret_cast<const char*>(a1);
  const char* c2 = reinterpret_cast<const char*>(a2);
  const char* c3 = reinterpret_cast<const char*>(a3);
  auto row = [&](int j, int v, V8i* r1, V8i* r2, V8i* r3) {
    V8i r, l;
    std::memcpy(&r, rv + j * kTileLanes + 8 * v, sizeof(r));
    std::memcpy(&l, lv + j * kTileLanes + 8 * v, sizeof(l));
    *r1 = r;
    *r2 = r * r;
    *r3 = r * l;
  };
  for (int v = 0; v < nv + 2; ++v) a1[v] = a2[v] = a3[v] = zero;
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
    // Horizontal sums eight windows at a time, K shifted loads each (exact integers: the same
    // values as running sums); lanes past cols_out (up to the row stride) are never read.
    int32_t* o1 = s1 + oy * kTileStride;
    int32_t* o2 = s2 + oy * kTileStride;
    int32_t* o3 = s3 + oy * kTileStride;
    for (int ox = 0; ox < cols_out; ox += 8) {
      V8i t1 = zero, t2 = zero, t3 = zero;
      for (int i = 0; i < K; ++i) {
        V8i u1, u2, u3;
        const size_t at = sizeof(int32_t) * (ox + i);
        std::memcpy(&u1, c1 + at, sizeof(u1));
        std::memcpy(&u2, c2 + at, sizeof(u2));
        std::memcpy(&u3, c3 + at, sizeof(u3));
        t1 += u1;
        t2 += u2;
        t3 += u3;
      }
      std::memcpy(o1 + ox, &t1, sizeof(t1));
      std::memcpy(o2 + ox, &t2, sizeof(t2));
      std::memcpy(o3 + ox, &t3, sizeof(t3));
    }
  }
}

/// rows x lanes pixels from @p src (rows @p step bytes apart) to @p dst as int32 (rows kTileLanes
/// apart), lanes >= @p cols set to zero; lanes is a multiple of 8.
ES_KERNEL void widenRows(const uint8_t* src, size_t step, int rows, int lanes, int cols,
                         int32_t* dst) {
  for (int j = 0; j < rows; ++j) {
    // Through a local copy: GCC leaves the loop scalar when the bytes may alias the output.
    uint8_t b[kTileLanes];
    std::memcpy(b, src + j * step, lanes);
    int32_t* d = dst + j * kTileLanes;
    for (int i = 0; i < lanes; ++i) d[i] = b[i];
    for (int i = cols; i < lanes; ++i) d[i] = 0;
  }
}

/// Per window of one tile: for the left image (key disparity kLeftKey) a = sum l, b = sum l^2;
/// for a disparity q, a = vl, b = vr, c = cov of windowParts and ncc its value (-2 where the
/// right window leaves the image or a patch is flat). Index oy * kTileStride + ox.
struct TileSums {
  int32_t a[kTile * kTileStride], b[kTile * kTileStride], c[kTile * kTileStride];
  float ncc[kTile * kTileStride];
};

/// Window values of the second chance shared between flagged pixels: windows of width
/// K = 2 r + 1 are grouped by their top-left corner into kTile x kTileW blocks, a tile holding a
/// block and the 2 r corners right of it (a pixel's windows are in one tile column), and each
/// (tile, disparity) is computed once, on first use, with separable integer sums (exact, so
/// every value equals the one computed for a single pixel's windows). Flagged pixels come in
/// bands along depth edges, whose windows overlap heavily.
class WindowCache {
 public:
  static constexpr int kLeftKey = -1;

  /// Tiles a cache may hold at once with nd disparities (see tile()).
  static int capacity(int nd) { return kSoftMaxTiles + 2 * (nd + 3); }

  /// Starts a call: the images, the verification radius, the search range, and the memory of
  /// capacity(nd) tiles (@p arena; null: the cache allocates its own).
  void reset(const cv::Mat& left, const cv::Mat& right, int r, int min_disparity, int nd,
             TileSums* arena) {
    left_ = &left;
    right_ = &right;
    r_ = r;
    k_ = 2 * r + 1;
    lv_x_ = lv_y_ = -1;
    min_d_ = min_disparity;
    nd_ = nd;
    tiles_x_ = (left.cols + kTileW - 1) / kTileW;
    const int most = capacity(nd);
    if (arena != nullptr) {
      tiles_ = arena;
    } else {
      own_tiles_.reset(new TileSums[most]);
      tiles_ = own_tiles_.get();
    }
    hash_bits_ = 1;
    while ((1 << hash_bits_) < 2 * most) ++hash_bits_;
    keys_.resize(size_t{1} << hash_bits_);
    values_.resize(size_t{1} << hash_bits_);
    clear();
  }
  /// Forgets every tile (the memory is kept).
  void clear() {
    std::fill(keys_.begin(), keys_.end(), int64_t{-1});
    used_ = 0;
  }
  /// Called before each pixel: forgets every tile once many are held (the memory is kept), so
  /// the tiles a pixel fetches stay valid while it is judged: one pixel fetches at most two
  /// tiles per disparity and two left tiles, so never more than capacity(nd) are held.
  void beginPixel() {
    if (used_ > kSoftMaxTiles) clear();
  }
  /// The tile (tx, ty) at disparity q (kLeftKey: the left sums). Valid until beginPixel().
  const TileSums& tile(int tx, int ty, int q) {
    const int64_t key = (static_cast<int64_t>(ty) * tiles_x_ + tx) * (nd_ + 1) +
                        (q == kLeftKey ? 0 : q - min_d_ + 1);
    // Open addressing, linear probing (keys >= 0; -1 = empty slot).
    const size_t mask = keys_.size() - 1;
    size_t h = static_cast<size_t>((static_cast<uint64_t>(key) * 0x9E3779B97F4A7C15ull) >>
                                   (64 - hash_bits_));
    while (keys_[h] != -1) {
      if (keys_[h] == key) return tiles_[values_[h]];
      h = (h + 1) & mask;
    }
    const TileSums* l = q == kLeftKey ? nullptr : &tile(tx, ty, kLeftKey);
    if (l != nullptr) {
      // The left tile's insertion may have taken slot h: probe on to a free one.
      while (keys_[h] != -1) h = (h + 1) & mask;
    }
    CV_Assert(used_ < capacity(nd_));
    TileSums& t = tiles_[used_];
    if (l != nullptr) {
      buildRight(tx, ty, q, *l, t);
    } else {
      buildLeft(tx, ty, t);
    }
    keys_[h] = key;
    values_[h] = used_++;
    return t;
  }

 private:
  // Bounds the memory (12 KiB a tile: about 26 MiB per thread with 64 disparities); the flagged
  // pixels come in tile-major order, so the tiles still needed are those of the last few block
  // rows.
  static constexpr int kSoftMaxTiles = 2048;

  /// The tile's first window corner, its window counts and its left pixels (zero-padded).
  void block(int tx, int ty, int* wx0, int* wy0, int* nx, int* ny) const {
    *wx0 = tx * kTileW;
    *wy0 = ty * kTile;
    *nx = std::min(kTileW + k_ - 1, left_->cols - k_ + 1 - *wx0);
    *ny = std::min(kTile, left_->rows - k_ + 1 - *wy0);
  }
  /// Loads the block's left pixels into lv_ unless they are there already (the right tiles of
  /// one block at several disparities are usually built one after the other).
  void leftPixels(int wx0, int wy0, int nx, int ny, int lanes) {
    if (wx0 == lv_x_ && wy0 == lv_y_ && lanes == lv_lanes_) return;
    lv_x_ = wx0;
    lv_y_ = wy0;
    lv_lanes_ = lanes;
    const int cols = nx + k_ - 1;
    if (wx0 + lanes <= left_->cols) {
      widenRows(left_->ptr<uint8_t>(wy0) + wx0, left_->step[0], ny + k_ - 1, lanes, cols,
                &lv_[0][0]);
      return;
    }
    for (int j = 0; j < ny + k_ - 1; ++j) {
      const uint8_t* lp = left_->ptr<uint8_t>(wy0 + j) + wx0;
      for (int i = 0; i < lanes; ++i) lv_[j][i] = i < cols ? lp[i] : 0;
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
    if (x0 >= 0 && x0 + lanes <= W) {
      widenRows(right_->ptr<uint8_t>(wy0) + x0, right_->step[0], ny + k_ - 1, lanes, cols,
                &rv_[0][0]);
    } else {
      // Columns outside the right image are clamped; the windows reading them are zeroed.
      for (int j = 0; j < ny + k_ - 1; ++j) {
        const uint8_t* rp = right_->ptr<uint8_t>(wy0 + j);
        for (int i = 0; i < lanes; ++i) {
          rv_[j][i] = i < cols ? rp[std::min(std::max(x0 + i, 0), W - 1)] : 0;
        }
      }
    }
    int32_t sr[kTile * kTileStride], srr[kTile * kTileStride], slr[kTile * kTileStride];
    blockSums(&lv_[0][0], &rv_[0][0], ny, nx, k_, lanes, sr, srr, slr);
    // Windows whose right window leaves the image get zero right sums (vr = 0: ZNCC -2, never
    // beating anything).
    const int ox_lo = std::max(0, -x0), ox_hi = std::min(nx, W - k_ + 1 - x0);
    if (ox_lo > 0 || ox_hi < nx) {
      for (int oy = 0; oy < ny; ++oy) {
        for (int ox = 0; ox < nx; ++ox) {
          if (ox >= ox_lo && ox < ox_hi) continue;
          sr[oy * kTileStride + ox] = srr[oy * kTileStride + ox] = 0;
        }
      }
    }
    const int32_t n = k_ * k_;
    for (int oy = 0; oy < ny; ++oy) {
      const int o = oy * kTileStride;
      windowParts(n, l.a + o, l.b + o, sr + o, srr + o, slr + o, nx, t.a + o, t.b + o, t.c + o,
                  t.ncc + o);
      // Lanes past the windows are read (masked) as whole rows by ownRows / anyCandidate.
      std::fill(t.ncc + o + nx, t.ncc + o + kTileStride, 0.f);
    }
  }

  const cv::Mat* left_ = nullptr;
  const cv::Mat* right_ = nullptr;
  int r_ = 0, k_ = 1, min_d_ = 0, nd_ = 1, tiles_x_ = 1, used_ = 0;
  // Hash table of the tiles held: 2^hash_bits_ slots, at least twice the most tiles ever held
  // (kSoftMaxTiles plus one pixel's fetches: 2 per tested disparity, with the left tiles).
  int hash_bits_ = 0;
  std::vector<int64_t> keys_;
  std::vector<int32_t> values_;
  TileSums* tiles_ = nullptr;                 // capacity(nd_) tiles
  std::unique_ptr<TileSums[]> own_tiles_;     // without an arena
  int lv_x_ = -1, lv_y_ = -1, lv_lanes_ = 0;  // the block whose left pixels lv_ holds
  alignas(32) int32_t lv_[kTileSpan][kTileLanes];
  alignas(32) int32_t rv_[kTileSpan][kTileLanes];
};

/// One pixel's K x K windows in the tiles of one disparity: window row oy starts at
/// base[oy < split_y ? 0 : 1] + offset[oy] (a ZNCC row of a TileSums, read as kRowLanes lanes).
struct PixelRows {
  const int* offset;
  int split_y, K;
  ES_INLINE const float* row(const float* const* base, int oy) const {
    return base[oy < split_y ? 0 : 1] + offset[oy];
  }
};

/// A pixel's own ZNCC in each of its K x K windows: row oy, lane i < K of @p own (row stride
/// kRowLanes) = the greater of lo and hi there (hi null: lo alone), as std::max. Rows are read
/// as kRowLanes lanes; lanes >= K are masked. @p own_m gets own - kCandidateSlack (+inf in lanes
/// >= K) for anyCandidate. Returns whether every window has own >= @p min_ncc and own > -2
/// (not flat).
constexpr float kCandidateSlack = 1e-4f;
ES_KERNEL bool ownRows(const PixelRows& pr, const float* const* lo, const float* const* hi,
                       float min_ncc, float* own, float* own_m) {
  const int K = pr.K;
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i zero = {0, 0, 0, 0, 0, 0, 0, 0};
  const V8f vmin = splat8(min_ncc), flat = splat8(-2.f), slack = splat8(kCandidateSlack);
  const V8f inf = splat8(std::numeric_limits<float>::infinity());
  V8i bad = zero;
  for (int oy = 0; oy < K; ++oy) {
    const float* lo_row = pr.row(lo, oy);
    const float* hi_row = hi != nullptr ? pr.row(hi, oy) : nullptr;
    for (int h = 0; h < kRowLanes; h += 8) {
      V8f v = load8(lo_row + h);
      if (hi_row != nullptr) {
        const V8f w = load8(hi_row + h);
        v = v < w ? w : v;
      }
      const V8i in = (lane + h) < K;
      bad |= in & ~((v >= vmin) & ~(v <= flat));
      const V8f m = in ? v - slack : inf;
      std::memcpy(own + oy * kRowLanes + h, &v, sizeof(v));
      std::memcpy(own_m + oy * kRowLanes + h, &m, sizeof(m));
    }
  }
  return !anySet(bad);
}

/// Whether any window of a competitor (tile ZNCC rows @p base, as in ownRows) has a ZNCC >=
/// own_m = own - kCandidateSlack. A cheap necessary condition for beatsParts: where beatsParts
/// holds, the true ZNCC is >= own up to a relative 1e-6 (its float squares and products) and the
/// stored ZNCC is within 1e-6 of the true one, far inside the slack; a flat window (-2) never
/// passes against own > -2 + slack. So a competitor without a candidate window never beats.
ES_KERNEL bool anyCandidate(const PixelRows& pr, const float* const* base, const float* own_m) {
  const V8i zero = {0, 0, 0, 0, 0, 0, 0, 0};
  V8i any = zero;
  for (int oy = 0; oy < pr.K; ++oy) {
    const float* row = pr.row(base, oy);
    for (int h = 0; h < kRowLanes; h += 8) {
      any |= load8(row + h) >= load8(own_m + oy * kRowLanes + h);
    }
  }
  return anySet(any);
}

/// Slot of one disparity for the competitor scans (see slotRow).
ES_INLINE int32_t slotOf(float v, float v_lo, float v_hi, int slot_off) {
  float x = v == v ? v : 0.f;
  x = x < v_lo ? v_lo : x;
  x = x > v_hi ? v_hi : x;
  const bool neg = x < 0.f;
  const int mag = static_cast<int>((neg ? -x : x) + 0.5f);
  return (neg ? -mag : mag) + slot_off;
}

/// Slot of each disparity of a map row for the competitor scans: its value clamped to
/// [v_lo, v_hi], rounded half away from zero (std::lround: |v| + 0.5 is exact here, then
/// truncation) to c, and c + slot_off. NaN (never triggering, its slot is never read) gives
/// slot_off. Eight lanes, the same operations as slotOf.
ES_KERNEL void slotRow(const float* v, int n, float v_lo, float v_hi, int slot_off, int32_t* out) {
  const V8f lo = splat8(v_lo), hi = splat8(v_hi), half = splat8(0.5f), zero = splat8(0.f);
  const V8i off = {slot_off, slot_off, slot_off, slot_off, slot_off, slot_off, slot_off, slot_off};
  int i = 0;
  for (; i + 8 <= n; i += 8) {
    V8f x = load8(v + i);
    x = x == x ? x : zero;
    x = x < lo ? lo : x;
    x = x > hi ? hi : x;
    const V8i neg = x < zero;
    const V8i mag = __builtin_convertvector((neg ? -x : x) + half, V8i);
    const V8i slot = (neg ? -mag : mag) + off;
    std::memcpy(out + i, &slot, sizeof(slot));
  }
  for (; i < n; ++i) out[i] = slotOf(v[i], v_lo, v_hi, slot_off);
}

/// Constants of one flagged pixel's competitor scan (see everyWindowPrefersOwnDisparity).
struct ScanArgs {
  float d, below, above;  ///< the pixel's disparity and the map test's thresholds
};

/// The whole competitor scan of one pixel, eight neighbours per vector, rows of @p len
/// neighbours read from @p base and their slots (slotRow) from @p slot_base (both @p stride
/// elements apart; the map padded with NaN, which never triggers, so no clamping to the image;
/// lanes past len are masked out). The slot of every triggering neighbour is marked in @p mark
/// (and slot 0 for the other lanes of a vector holding one; cleared by the caller). The
/// triggering neighbours' offsets (dx0 + i, dy0 + row) are summed into *sum_dx, *sum_dy.
/// Column by column (eight columns, all rows): the column offsets are then summed once per
/// column from per-lane counts, and a lane's mask past len is computed once.
ES_KERNEL void scanBlock(const ScanArgs& a, const float* base, const int32_t* slot_base,
                         size_t stride, int rows, int len, int dx0, int dy0, uint8_t* mark,
                         int* sum_dx, int* sum_dy) {
  const V8f d = splat8(a.d), below = splat8(a.below), above = splat8(a.above);
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i lenv = {len, len, len, len, len, len, len, len};
  const V8i zero = {0, 0, 0, 0, 0, 0, 0, 0};
  const V8i one = {1, 1, 1, 1, 1, 1, 1, 1};
  const V8i dy_first = {dy0, dy0, dy0, dy0, dy0, dy0, dy0, dy0};
  V8i vdx = zero, vdy = zero;
  for (int i = 0; i < len; i += 8) {
    const V8i idx = lane + i;
    const V8i in = idx < lenv;
    V8i count = zero, dy = dy_first;
    for (int j = 0; j < rows; ++j) {
      const V8f v = load8(base + j * stride + i);
      V8i s;
      std::memcpy(&s, slot_base + j * stride + i, sizeof(s));
      // NaN: both comparisons false.
      const V8i t = ((d - v > below) | (v - d > above)) & in;
      count -= t;  // t is -1 in triggering lanes
      vdy += t & dy;
      dy += one;
      if (anySet(t)) {
        alignas(32) int32_t slots[8];
        const V8i slot = t & s;
        std::memcpy(slots, &slot, sizeof(slot));
        for (int k = 0; k < 8; ++k) mark[slots[k]] = 1;
      }
    }
    vdx += count * (idx + dx0);
  }
  for (int i = 0; i < 8; ++i) {
    *sum_dx += vdx[i];
    *sum_dy += vdy[i];
  }
}

/// Reusable per-thread buffers of everyWindowPrefersOwnDisparity.
struct VerifyScratch {
  std::vector<uint8_t> seen;               // per disparity of the search range: already listed
  std::vector<int> alts;                   // competing disparities of one pixel
  std::vector<const TileSums*> alt_tiles;  // their two tiles each
  std::vector<uint8_t> mark;  // per rounded neighbour disparity: seen among the triggering ones
  WindowCache cache;          // window values shared between the pixels
};

/// Where the windows of one flagged pixel (x, y) of width K = 2 r + 1 lie in the WindowCache's
/// tiles: every window containing the pixel (top-left corners x - 2 r .. x, y - 2 r .. y) is in
/// tile column tx (a tile row holds its block's corners and the 2 r after them), in tile rows
/// ty0 (window rows oy < split_y) and ty1.
struct PixelWindows {
  PixelWindows(int x, int y, int r) : K(2 * r + 1) {
    const int wx0 = x - 2 * r, wy0 = y - 2 * r;
    tx = wx0 / kTileW;
    ty0 = wy0 / kTile;
    ty1 = y / kTile;
    split_y = std::min(K, (ty0 + 1) * kTile - wy0);
    for (int oy = 0; oy < K; ++oy) {
      const int wy = wy0 + oy;
      offset[oy] = (wy - (oy < split_y ? ty0 : ty1) * kTile) * kTileStride + (wx0 - tx * kTileW);
    }
  }
  /// The tiles of tile rows ty0 and ty1 at disparity q into t.
  ES_INLINE void fetch(WindowCache& cache, int q, const TileSums* t[2]) const {
    t[0] = &cache.tile(tx, ty0, q);
    t[1] = ty1 != ty0 ? &cache.tile(tx, ty1, q) : t[0];
  }
  /// The tile of window row oy among the two fetched ones.
  ES_INLINE const TileSums* tileOf(const TileSums* const t[2], int oy) const {
    return t[oy < split_y ? 0 : 1];
  }
  PixelRows rows() const { return PixelRows{offset, split_y, K}; }

  int K;
  int tx, ty0, ty1, split_y;
  int offset[kMaxSide];  // offset of window row oy's first window in its tile
};

/// The pixel's own ZNCC in each of its windows at disparity @p d, the better of the two integers
/// around it, into own and own_m (see ownRows). Returns whether every window has own >= min_ncc
/// (and is not flat).
ES_INLINE bool ownPassesEveryWindow(WindowCache& cache, const PixelWindows& pw, float d,
                                    float min_ncc, float* own, float* own_m) {
  const int q_lo = static_cast<int>(std::floor(d)), q_hi = static_cast<int>(std::ceil(d));
  const TileSums* t[2];
  const float* lo_base[2];
  const float* hi_base[2];
  pw.fetch(cache, q_lo, t);
  lo_base[0] = t[0]->ncc;
  lo_base[1] = t[1]->ncc;
  if (q_hi != q_lo) {
    pw.fetch(cache, q_hi, t);
    hi_base[0] = t[0]->ncc;
    hi_base[1] = t[1]->ncc;
  }
  return ownRows(pw.rows(), lo_base, q_hi != q_lo ? hi_base : nullptr, min_ncc, own, own_m);
}

/// The competitors of flagged pixel @p f (disparity sa.d) into sc.alts, from the neighbourhood
/// the map test looked at, and where its triggering neighbours lie relative to it (summed
/// offsets *sum_dx, *sum_dy). The rounded disparities of the triggering neighbours are marked in
/// a table (a set: the pixels' order cannot matter), in a branch-free pass; then each marked
/// value is widened by +-1, kept within the search range and at least 2 px from the pixel's own.
/// Slots: 0 = not triggering, c - min_disparity + 3 for a rounded disparity c (valid centres
/// min - 1 .. max + 1 are slots 2 .. nd + 3; values beyond are clamped into slots 1 and nd + 4,
/// which give no competitor).
ES_INLINE void listCompetitors(const MatcherParams& mp, const cv::Mat& padded,
                               const cv::Mat& padded_slot, int pad, const Flagged& f,
                               const ScanArgs& sa, VerifyScratch& sc, int* sum_dx, int* sum_dy) {
  sc.alts.clear();
  const int nd = mp.max_disparity - mp.min_disparity + 1;
  const int mark_words = (nd + 5 + 7) / 8;  // the table in whole 8-byte words
  if (static_cast<int>(sc.seen.size()) != nd) {
    sc.mark.assign(8 * mark_words, 0);
    sc.seen.assign(nd, 0);
  }
  const int slot_off = 3 - mp.min_disparity;
  uint8_t* mark = sc.mark.data();
  scanBlock(sa, padded.ptr<float>(pad + f.y - f.half) + pad + f.x - f.half,
            padded_slot.ptr<int32_t>(pad + f.y - f.half) + pad + f.x - f.half, padded.step1(),
            2 * f.half + 1, 2 * f.half + 1, -f.half, -f.half, mark, sum_dx, sum_dy);
  // Marked slots 2 .. nd + 3 in increasing order, eight at a time (most words are clear).
  mark[0] = mark[1] = 0;
  for (int wi = 0; wi < mark_words; ++wi) {
    uint64_t word;
    std::memcpy(&word, mark + 8 * wi, sizeof(word));
    if (word == 0) continue;
    std::memset(mark + 8 * wi, 0, sizeof(word));
    for (int slot = 8 * wi; slot < std::min(8 * wi + 8, nd + 4); ++slot) {
      if (!(word >> (8 * (slot - 8 * wi)) & 0xff)) continue;
      const int c = slot - slot_off;
      for (int q = std::max(c - 1, mp.min_disparity); q <= std::min(c + 1, mp.max_disparity); ++q) {
        if (sc.seen[q - mp.min_disparity] || std::fabs(static_cast<float>(q) - sa.d) < 2.f) {
          continue;
        }
        sc.seen[q - mp.min_disparity] = 1;
        sc.alts.push_back(q);
      }
    }
  }
  for (int q : sc.alts) sc.seen[q - mp.min_disparity] = 0;
}

/// Fetches the tiles of every competitor into sc.alt_tiles (valid for the whole pixel), testing
/// each in the window (probe_x, probe_y) first, where a competitor usually wins if it wins
/// anywhere. Returns false as soon as one beats the pixel's own ZNCC there.
ES_INLINE bool noCompetitorWinsProbe(WindowCache& cache, const PixelWindows& pw, int probe_x,
                                     int probe_y, const float* own, VerifyScratch& sc) {
  const float own_probe = own[probe_y * kRowLanes + probe_x];
  const int ip = pw.offset[probe_y] + probe_x;
  sc.alt_tiles.resize(2 * sc.alts.size());
  for (size_t i = 0; i < sc.alts.size(); ++i) {
    const TileSums** t = &sc.alt_tiles[2 * i];
    pw.fetch(cache, sc.alts[i], t);
    const TileSums* tp = pw.tileOf(t, probe_y);
    if (beatsParts(tp->a[ip], tp->b[ip], tp->c[ip], own_probe)) return false;
  }
  return true;
}

/// Whether no competitor (tiles fetched by noCompetitorWinsProbe) beats the pixel's own ZNCC in
/// any window: a cheap necessary condition over all windows first (anyCandidate), the exact
/// comparison only where it holds.
ES_INLINE bool noCompetitorWinsAnywhere(const PixelWindows& pw, const float* own,
                                        const float* own_m, const VerifyScratch& sc) {
  const PixelRows pr = pw.rows();
  const int K = pw.K;
  for (size_t i = 0; i < sc.alts.size(); ++i) {
    const TileSums* const* t = &sc.alt_tiles[2 * i];
    const float* q_base[2] = {t[0]->ncc, t[1]->ncc};
    if (!anyCandidate(pr, q_base, own_m)) continue;
    for (int oy = 0; oy < K; ++oy) {
      const TileSums* tq = pw.tileOf(t, oy);
      const int o = pw.offset[oy];
      for (int ox = 0; ox < K; ++ox) {
        if (beatsParts(tq->a[o + ox], tq->b[o + ox], tq->c[o + ox], own[oy * kRowLanes + ox])) {
          return false;
        }
      }
    }
  }
  return true;
}

/// The second chance of one flagged pixel (MatcherParams::edge_verify_radius_px). Competitors:
/// the disparities measured on the other side of the jump, i.e. those of the neighbours that
/// triggered the test (rounded, +-1 px, within the search range, at least 2 px from the pixel's
/// own). The pixel is kept when every window of width 2 r + 1 containing it gives its own
/// disparity (the better of the two integers around the sub-pixel value) a ZNCC >= min_ncc and a
/// higher ZNCC than every competitor. Reads only the images and the map before the step.
bool everyWindowPrefersOwnDisparity(const MatcherParams& mp, const cv::Mat& left,
                                    const cv::Mat& disparity, const cv::Mat& padded,
                                    const cv::Mat& padded_slot, int pad, const Flagged& f,
                                    float below, float above, VerifyScratch& sc) {
  const int r = mp.edge_verify_radius_px;
  const int W = left.cols, H = left.rows;
  if (f.x - 2 * r < 0 || f.x + 2 * r > W - 1 || f.y - 2 * r < 0 || f.y + 2 * r > H - 1) {
    return false;  // some windows containing the pixel leave the image: no full verdict
  }
  const float d = disparity.at<float>(f.y, f.x);
  // The verdict is a conjunction over windows and disparities, so its terms go cheapest and
  // most decisive first: the own ZNCC of every window (needs no competitors; a fattened pixel
  // usually fails it in the windows lying on its true surface), then the competitors.
  const PixelWindows pw(f.x, f.y, r);
  sc.cache.beginPixel();
  alignas(32) float own[kMaxSide * kRowLanes];
  alignas(32) float own_m[kMaxSide * kRowLanes];
  const float min_ncc = static_cast<float>(mp.edge_verify_min_ncc);
  if (!ownPassesEveryWindow(sc.cache, pw, d, min_ncc, own, own_m)) return false;
  int sum_dx = 0, sum_dy = 0;
  listCompetitors(mp, padded, padded_slot, pad, f, ScanArgs{d, below, above}, sc, &sum_dx, &sum_dy);
  // Each competitor first in the window shifted furthest towards the triggering neighbours, then
  // in every window.
  const int probe_y = sum_dy > 0 ? 2 * r : sum_dy < 0 ? 0 : r;
  const int probe_x = sum_dx > 0 ? 2 * r : sum_dx < 0 ? 0 : r;
  return noCompetitorWinsProbe(sc.cache, pw, probe_x, probe_y, own, sc) &&
         noCompetitorWinsAnywhere(pw, own, own_m, sc);
}

}  // namespace

void secondChance(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                  const cv::Mat& disparity, int pad, float below, float above,
                  std::vector<Flagged>& flagged, cv::Mat& lo, cv::Mat& hi, cv::Mat& reject,
                  std::vector<uint8_t>& keep) {
  const int H = disparity.rows, W = disparity.cols;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  constexpr int kRowBlock = 32;  // rows per task of the per-row passes over the threads
  keep.assign(flagged.size(), 0);
  // For the competitor scans, in row blocks over the threads: in lo the map framed in NaN
  // (never triggering: no clamping to the image, and whole vectors may read past a row's end,
  // 8 columns more on the right; every flagged pixel's neighbourhood, half <= pad, lies
  // inside), in hi the slot of each of its values (slotRow; valid centres min - 1 .. max + 1
  // in slots 2 .. nd + 3), once per map pixel instead of once per scan.
  const cv::Mat& padded = lo;
  const cv::Mat& padded_slot = hi;
  CV_Assert(padded_slot.step1() == padded.step1());
  cv::parallel_for_(
      cv::Range(0, (padded.rows + kRowBlock - 1) / kRowBlock), [&](const cv::Range& rg) {
        for (int y = rg.start * kRowBlock; y < std::min(padded.rows, rg.end * kRowBlock); ++y) {
          float* row = lo.ptr<float>(y);
          if (y < pad || y >= pad + H) {
            std::fill(row, row + padded.cols, nan);
          } else {
            std::fill(row, row + pad, nan);
            std::memcpy(row + pad, disparity.ptr<float>(y - pad), sizeof(float) * W);
            std::fill(row + pad + W, row + padded.cols, nan);
          }
          slotRow(row, padded.cols, static_cast<float>(mp.min_disparity - 2),
                  static_cast<float>(mp.max_disparity + 2), 3 - mp.min_disparity,
                  hi.ptr<int32_t>(y));
        }
      });
  // Flagged pixels in tile-major order (kTile x kTile blocks, row-major within a block), so
  // that a chunk's pixels share the WindowCache's tiles; a counting sort (stable).
  {
    const int bx = (W + kTile - 1) / kTile;
    const int nb = bx * ((H + kTile - 1) / kTile);
    std::vector<int> start(nb + 1, 0);
    for (const Flagged& f : flagged) ++start[(f.y / kTile) * bx + f.x / kTile + 1];
    for (int b = 0; b < nb; ++b) start[b + 1] += start[b];
    std::vector<Flagged> sorted(flagged.size());
    for (const Flagged& f : flagged) sorted[start[(f.y / kTile) * bx + f.x / kTile]++] = f;
    flagged.swap(sorted);
  }
  // The scratch (above all its window cache, valid for the whole call: same images) is handed
  // from one chunk to the next instead of being rebuilt for every stripe OpenCV hands out.
  std::mutex scratch_mutex;
  std::vector<std::unique_ptr<VerifyScratch>> scratch_pool;
  // The tiles' memory: @p reject (not needed as a mask), one row per cache, for one cache per
  // thread. The caller keeps it from frame to frame, so its pages stay mapped instead of being
  // returned to the system and faulted in again at every call (fresh memory per call cost up
  // to a quarter of this step's time in page faults on the surgical sequence). Caches beyond
  // it allocate their own.
  const int nd = mp.max_disparity - mp.min_disparity + 1;
  const int cache_bytes = WindowCache::capacity(nd) * static_cast<int>(sizeof(TileSums));
  constexpr int kChunk = 256;
  const int num_chunks = static_cast<int>((flagged.size() + kChunk - 1) / kChunk);
  const int arena_caches = std::max(1, std::min(cv::getNumThreads(), num_chunks));
  if (!(reject.type() == CV_8U && reject.cols == cache_bytes && reject.rows >= arena_caches)) {
    reject.create(arena_caches, cache_bytes, CV_8U);
  }
  int arena_used = 0;
  cv::parallel_for_(cv::Range(0, num_chunks), [&](const cv::Range& rg) {
    std::unique_ptr<VerifyScratch> sc;
    TileSums* tiles = nullptr;
    {
      std::lock_guard<std::mutex> lock(scratch_mutex);
      if (!scratch_pool.empty()) {
        sc = std::move(scratch_pool.back());
        scratch_pool.pop_back();
      } else if (arena_used < reject.rows) {
        // Trivial types (arrays of int32 and float) in memory aligned for them.
        tiles = reinterpret_cast<TileSums*>(reject.ptr(arena_used++));
      }
    }
    if (!sc) {
      sc.reset(new VerifyScratch);
      sc->cache.reset(left, right, mp.edge_verify_radius_px, mp.min_disparity, nd, tiles);
    }
    for (int c = rg.start; c < rg.end; ++c) {
      const size_t e = std::min(flagged.size(), static_cast<size_t>(c + 1) * kChunk);
      for (size_t i = static_cast<size_t>(c) * kChunk; i < e; ++i) {
        keep[i] = everyWindowPrefersOwnDisparity(mp, left, disparity, padded, padded_slot, pad,
                                                 flagged[i], below, above, *sc);
      }
    }
    std::lock_guard<std::mutex> lock(scratch_mutex);
    scratch_pool.push_back(std::move(sc));
  });
}

}  // namespace detail
}  // namespace endo_stereo
