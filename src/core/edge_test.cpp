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
#include <opencv2/imgproc.hpp>
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

/// One pixel flagged by the map test, waiting for its second chance (see verifyFlagged).
struct Flagged {
  int x, y;
  int half;  ///< half width of the neighbourhood its test looked at, px
};

constexpr int kMaxHalf = 32 / 2 + 16;  // widest map-test neighbourhood: window 32, margin 16
constexpr int kMaxVerifyRadius = 6;    // MatcherParams::validate()
constexpr int kMaxSpan = 4 * kMaxVerifyRadius + 1;  // region holding every window
constexpr int kMaxSide = 2 * kMaxVerifyRadius + 1;  // window width

/// Reusable per-thread buffers of verifyFlagged.
struct VerifyScratch {
  std::vector<uint8_t> seen;  // per disparity of the search range: already listed
  std::vector<int> alts;      // competing disparities of one pixel
  std::vector<uint8_t> mark;  // per rounded neighbour disparity: seen among the triggering ones
};

constexpr int kLanes = (kMaxSpan + 7) / 8 * 8;  // region columns rounded up to whole lanes

/// ZNCC of one window from its exact sums (n pixels): -2 for a flat patch. Every product fits
/// in int32 for windows up to 13 x 13 (n^2 255^2 < 2^31), hence kMaxVerifyRadius = 6. The one
/// float expression shared by the probe and the full evaluation, so both give identical values.
ES_INLINE float nccFromSums(int32_t n, int32_t sl, int32_t sll, int32_t sr, int32_t srr,
                            int32_t slr) {
  const int32_t vl = n * sll - sl * sl;
  const int32_t vr = n * srr - sr * sr;
  const int32_t cov = n * slr - sl * sr;
  if (vl <= 0 || vr <= 0) return -2.f;
  return static_cast<float>(cov) / std::sqrt(static_cast<float>(vl) * static_cast<float>(vr));
}

/// nccFromSums over @p count windows.
void nccMany(int32_t n, const int32_t* sl, const int32_t* sll, const int32_t* sr,
             const int32_t* srr, const int32_t* slr, int count, float* out) {
  for (int i = 0; i < count; ++i) out[i] = nccFromSums(n, sl[i], sll[i], sr[i], srr[i], slr[i]);
}

/// Whether a competitor's window (exact sums) reaches a ZNCC >= @p own, decided without square
/// root or division (vectorisable): with c = cov and D = vl * vr > 0, ZNCC = c / sqrt(D), so for
/// c >= 0 it is >= own when own <= 0 or c^2 >= own^2 D, and for c < 0 when own < 0 and
/// c^2 <= own^2 D. A flat patch (ZNCC -2 by definition) never reaches own >= -1. Every operand is
/// computed unconditionally and combined bitwise: no branch.
ES_INLINE bool beats(int32_t n, int32_t sl, int32_t sll, int32_t sr, int32_t srr, int32_t slr,
                     float own) {
  const int32_t vl = n * sll - sl * sl;
  const int32_t vr = n * srr - sr * sr;
  const int32_t cov = n * slr - sl * sr;
  const float cf = static_cast<float>(cov);
  const float lhs = cf * cf;
  const float rhs = (own * own) * (static_cast<float>(vl) * static_cast<float>(vr));
  const bool valid = (vl > 0) & (vr > 0);
  const bool pos = cov >= 0;
  const bool up = (own <= 0.f) | (lhs >= rhs);
  const bool down = (own < 0.f) & (lhs <= rhs);
  return valid & ((pos & up) | (!pos & down));
}

/// Whether any of @p count windows' competitor sums beats() the pixel's own ZNCC there.
ES_KERNEL bool anyBeats(int32_t n, const int32_t* sl, const int32_t* sll, const int32_t* sr,
                        const int32_t* srr, const int32_t* slr, const float* own, int count) {
  int any = 0;
  for (int i = 0; i < count; ++i) any |= beats(n, sl[i], sll[i], sr[i], srr[i], slr[i], own[i]);
  return any != 0;
}

/// Right-image sums (v, v^2, v * l) of every K x K window of an S x S region (S = 2 K - 1):
/// column sums over K rows first, eight region columns per vector and carried down the rows
/// (one row in, one row out), then the K horizontal sums from prefix sums of each row of column
/// sums. lv and rv hold the region rows (kLanes ints each, zero-padded to @p lanes). Exact.
ES_KERNEL void rightRegionSums(const int32_t* lv, const int32_t* rv, int S, int K, int lanes,
                               int32_t* sr, int32_t* srr, int32_t* slr) {
  (void)S;
  const int nv = lanes / 8;
  V8i a1[kLanes / 8], a2[kLanes / 8], a3[kLanes / 8];
  const V8i zero = {0, 0, 0, 0, 0, 0, 0, 0};
  auto row = [&](int j, int v, V8i* r1, V8i* r2, V8i* r3) {
    V8i r, l;
    std::memcpy(&r, rv + j * kLanes + 8 * v, sizeof(r));
    std::memcpy(&l, lv + j * kLanes + 8 * v, sizeof(l));
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
  for (int oy = 0; oy < K; ++oy) {
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
    int32_t c1[kLanes], c2[kLanes], c3[kLanes];
    std::memcpy(c1, a1, sizeof(V8i) * nv);
    std::memcpy(c2, a2, sizeof(V8i) * nv);
    std::memcpy(c3, a3, sizeof(V8i) * nv);
    int32_t t1 = 0, t2 = 0, t3 = 0;
    for (int i = 0; i < K; ++i) {
      t1 += c1[i];
      t2 += c2[i];
      t3 += c3[i];
    }
    int32_t* o1 = sr + oy * K;
    int32_t* o2 = srr + oy * K;
    int32_t* o3 = slr + oy * K;
    o1[0] = t1;
    o2[0] = t2;
    o3[0] = t3;
    for (int ox = 1; ox < K; ++ox) {
      t1 += c1[ox + K - 1] - c1[ox - 1];
      t2 += c2[ox + K - 1] - c2[ox - 1];
      t3 += c3[ox + K - 1] - c3[ox - 1];
      o1[ox] = t1;
      o2[ox] = t2;
      o3[ox] = t3;
    }
  }
}

/// Window sums of every window of width K = 2 r + 1 that contains pixel (x, y): the (4 r + 1)^2
/// region around it is read once per disparity and summed separably (prefix sums along each
/// row, then running sums down the columns). Integers throughout: exact, order-independent.
class RegionWindows {
 public:
  RegionWindows(const cv::Mat& left, const cv::Mat& right, int x, int y, int r)
      : left_(left), right_(right), x_(x), y_(y), r_(r), k_(2 * r + 1), s_(4 * r + 1) {
    // Left sums, shared by every disparity.
    int32_t h1[kMaxSpan][kMaxSide], h2[kMaxSpan][kMaxSide];
    for (int j = 0; j < s_; ++j) {
      const uint8_t* lp = left_.ptr<uint8_t>(y_ - 2 * r_ + j) + (x_ - 2 * r_);
      int32_t p1[kMaxSpan + 1], p2[kMaxSpan + 1];
      p1[0] = p2[0] = 0;
      for (int i = s_; i < kLanes; ++i) lv_[j][i] = 0;
      for (int i = 0; i < s_; ++i) {
        const int32_t l = lp[i];
        lv_[j][i] = l;
        p1[i + 1] = p1[i] + l;
        p2[i + 1] = p2[i] + l * l;
      }
      for (int i = 0; i < k_; ++i) {
        h1[j][i] = p1[i + k_] - p1[i];
        h2[j][i] = p2[i + k_] - p2[i];
      }
    }
    verticalSums(h1, sl_);
    verticalSums(h2, sll_);
  }

  /// ZNCC of every window at disparity q into ncc[oy * K + ox] (window with top-left corner
  /// (ox, oy) in the region); -2 where the right window leaves the image or a patch is flat.
  void ncc(int q, float* ncc) const {
    int32_t sr[kMaxSide * kMaxSide], srr[kMaxSide * kMaxSide], slr[kMaxSide * kMaxSide];
    rightSums(q, sr, srr, slr);
    nccMany(k_ * k_, sl_, sll_, sr, srr, slr, k_ * k_, ncc);
  }

  /// Whether disparity q reaches the pixel's own ZNCC (@p own, as from ncc()) in any window.
  bool beatenAt(int q, const float* own) const {
    int32_t sr[kMaxSide * kMaxSide], srr[kMaxSide * kMaxSide], slr[kMaxSide * kMaxSide];
    rightSums(q, sr, srr, slr);
    return anyBeats(k_ * k_, sl_, sll_, sr, srr, slr, own, k_ * k_);
  }

 private:
  /// Right sums of every window at disparity q; windows whose right window leaves the image get
  /// zero sums (a flat patch: ZNCC -2, never beating anything).
  void rightSums(int q, int32_t* sr, int32_t* srr, int32_t* slr) const {
    const int W = right_.cols;
    const int x0 = x_ - 2 * r_ - q;  // first right column of the region
    const int lanes = (s_ + 7) / 8 * 8;
    alignas(32) int32_t rv[kMaxSpan][kLanes];
    for (int j = 0; j < s_; ++j) {
      const uint8_t* rp = right_.ptr<uint8_t>(y_ - 2 * r_ + j);
      if (x0 >= 0 && x0 + s_ <= W) {
        const uint8_t* src = rp + x0;
        for (int i = 0; i < s_; ++i) rv[j][i] = src[i];
        for (int i = s_; i < lanes; ++i) rv[j][i] = 0;
      } else {
        // Columns outside the right image are clamped; the windows reading them are zeroed.
        for (int i = 0; i < lanes; ++i) {
          rv[j][i] = i < s_ ? rp[std::min(std::max(x0 + i, 0), W - 1)] : 0;
        }
      }
    }
    rightRegionSums(&lv_[0][0], &rv[0][0], s_, k_, lanes, sr, srr, slr);
    for (int ox = 0; ox < k_; ++ox) {
      if (x0 + ox >= 0 && x0 + ox + k_ <= W) continue;
      for (int oy = 0; oy < k_; ++oy) sr[oy * k_ + ox] = srr[oy * k_ + ox] = 0;
    }
  }

  void verticalSums(const int32_t (*h)[kMaxSide], int32_t* out) const {
    for (int i = 0; i < k_; ++i) {
      int32_t acc = 0;
      for (int j = 0; j < k_; ++j) acc += h[j][i];
      out[i] = acc;
      for (int oy = 1; oy < k_; ++oy) {
        acc += h[oy + k_ - 1][i] - h[oy - 1][i];
        out[oy * k_ + i] = acc;
      }
    }
  }

  const cv::Mat& left_;
  const cv::Mat& right_;
  int x_, y_, r_, k_, s_;
  alignas(32) int32_t lv_[kMaxSpan][kLanes];  // left region, zero-padded to whole lanes
  int32_t sl_[kMaxSide * kMaxSide], sll_[kMaxSide * kMaxSide];
};

/// The single window of width 2 r + 1 centred on (cx, cy), for the probe: its left pixels and
/// sums once, then the right sums per disparity (the same exact integers RegionWindows computes
/// for that window). Pixels are copied into contiguous arrays so the sums are plain reductions.
class ProbeWindow {
 public:
  ProbeWindow(const cv::Mat& left, const cv::Mat& right, int cx, int cy, int r)
      : right_(right), cx_(cx), cy_(cy), r_(r), k_(2 * r + 1), n_(k_ * k_) {
    for (int j = 0; j < k_; ++j) {
      std::memcpy(lw_ + j * k_, left.ptr<uint8_t>(cy - r + j) + cx - r, k_);
    }
    int32_t sl = 0, sll = 0;
    for (int i = 0; i < n_; ++i) {
      const int32_t l = lw_[i];
      sl += l;
      sll += l * l;
    }
    sl_ = sl;
    sll_ = sll;
  }

  /// Exact sums (sl, sll, sr, srr, slr) at disparity q into @p sums; false where the right
  /// window leaves the image.
  bool sums(int q, int32_t* sums) const {
    if (cx_ - q - r_ < 0 || cx_ - q + r_ > right_.cols - 1) return false;
    uint8_t rw[kMaxSide * kMaxSide];
    for (int j = 0; j < k_; ++j) {
      std::memcpy(rw + j * k_, right_.ptr<uint8_t>(cy_ - r_ + j) + cx_ - q - r_, k_);
    }
    int32_t sr = 0, srr = 0, slr = 0;
    for (int i = 0; i < n_; ++i) {
      const int32_t v = rw[i];
      sr += v;
      srr += v * v;
      slr += v * lw_[i];
    }
    sums[0] = sl_;
    sums[1] = sll_;
    sums[2] = sr;
    sums[3] = srr;
    sums[4] = slr;
    return true;
  }

 private:
  const cv::Mat& right_;
  int cx_, cy_, r_, k_, n_;
  int32_t sl_ = 0, sll_ = 0;
  uint8_t lw_[kMaxSide * kMaxSide];
};

/// Constants of one flagged pixel's competitor scan (see verifyFlagged).
struct ScanArgs {
  float d, below, above;  ///< the pixel's disparity and the map test's thresholds
  float v_lo, v_hi;       ///< disparities are clamped to these before rounding
  int slot_off;           ///< slot of rounded disparity c = c + slot_off
  int no_slot;            ///< larger than any slot
};

/// One row of the competitor scan, branch-free (vectorised): slots[i] = the slot of neighbour i
/// (0 when it does not trigger the map test), the triggering neighbours' column offsets summed
/// into *sum_dx (dx0 = offset of the first), the slot range into *slot_min / *slot_max.
/// @return the number of triggering neighbours.
ES_KERNEL int scanRow(const ScanArgs& a, const float* row, int len, int dx0, int32_t* slots,
                      int* sum_dx, int* slot_min, int* slot_max) {
  const float d = a.d, below = a.below, above = a.above, v_lo = a.v_lo, v_hi = a.v_hi;
  const int slot_off = a.slot_off, no_slot = a.no_slot;
  int count = 0, sdx = 0, smin = *slot_min, smax = *slot_max;
  for (int i = 0; i < len; ++i) {
    const float v = row[i];
    const int t = (d - v > below) | (v - d > above);  // NaN: 0
    float vc = t ? v : d;
    vc = vc < v_lo ? v_lo : vc;
    vc = vc > v_hi ? v_hi : vc;
    // std::lround (half away from zero) without a library call: |vc| + 0.5 is exact here.
    const int mag = static_cast<int>(std::fabs(vc) + 0.5f);
    const int c = vc < 0.f ? -mag : mag;
    const int slot = t ? c + slot_off : 0;
    slots[i] = slot;
    count += t;
    sdx += t ? dx0 + i : 0;
    smin = std::min(smin, t ? slot : no_slot);
    smax = std::max(smax, slot);
  }
  *sum_dx += sdx;
  *slot_min = smin;
  *slot_max = smax;
  return count;
}

/// The second chance of one flagged pixel (MatcherParams::edge_verify_radius_px). Competitors:
/// the disparities measured on the other side of the jump, i.e. those of the neighbours that
/// triggered the test (rounded, +-1 px, within the search range, at least 2 px from the pixel's
/// own). The pixel is kept when every window of width 2 r + 1 containing it gives its own
/// disparity (the better of the two integers around the sub-pixel value) a ZNCC >= min_ncc and a
/// higher ZNCC than every competitor. Reads only the images and the map before the step.
bool verifyFlagged(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                   const cv::Mat& disparity, const Flagged& f, float below, float above,
                   VerifyScratch& sc) {
  const int r = mp.edge_verify_radius_px;
  const int W = left.cols, H = left.rows;
  if (f.x - 2 * r < 0 || f.x + 2 * r > W - 1 || f.y - 2 * r < 0 || f.y + 2 * r > H - 1) {
    return false;  // some windows containing the pixel leave the image: no full verdict
  }
  const float d = disparity.at<float>(f.y, f.x);
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
  const int x0 = std::max(0, f.x - f.half), x1 = std::min(W - 1, f.x + f.half);
  int32_t slots[2 * (kMaxHalf + 1)];
  const ScanArgs sa{d, below, above, v_lo, v_hi, slot_off, nd + 5};
  for (int yy = std::max(0, f.y - f.half); yy <= std::min(H - 1, f.y + f.half); ++yy) {
    const int len = x1 - x0 + 1;
    const int row_count = scanRow(sa, disparity.ptr<float>(yy) + x0, len, x0 - f.x, slots, &sum_dx,
                                  &slot_min, &slot_max);
    sum_dy += row_count * (yy - f.y);
    if (row_count == 0) continue;
    for (int i = 0; i < len; ++i) mark[slots[i]] = 1;
  }
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

  const int q_lo = static_cast<int>(std::floor(d)), q_hi = static_cast<int>(std::ceil(d));
  const float min_ncc = static_cast<float>(mp.edge_verify_min_ncc);
  {
    // Probe first the window shifted furthest towards the triggering neighbours: a fattened
    // pixel usually fails there (it lies wholly on the pixel's true surface), and one failing
    // window decides. Only the cost depends on this shortcut, never the verdict.
    const int cx = f.x + (sum_dx > 0 ? r : sum_dx < 0 ? -r : 0);
    const int cy = f.y + (sum_dy > 0 ? r : sum_dy < 0 ? -r : 0);
    const int n = (2 * r + 1) * (2 * r + 1);
    const ProbeWindow pw(left, right, cx, cy, r);
    int32_t m[5];
    auto ownAt = [&](int q) {
      return pw.sums(q, m) ? nccFromSums(n, m[0], m[1], m[2], m[3], m[4]) : -2.f;
    };
    float own_p = ownAt(q_lo);
    if (q_hi != q_lo) own_p = std::max(own_p, ownAt(q_hi));
    if (!(own_p >= min_ncc) || own_p <= -2.f) return false;
    for (int q : sc.alts) {
      if (pw.sums(q, m) && beats(n, m[0], m[1], m[2], m[3], m[4], own_p)) {
        return false;
      }
    }
  }
  const RegionWindows rw(left, right, f.x, f.y, r);
  const int n = (2 * r + 1) * (2 * r + 1);
  float own[kMaxSide * kMaxSide], alt[kMaxSide * kMaxSide];
  rw.ncc(q_lo, own);
  if (q_hi != q_lo) {
    rw.ncc(q_hi, alt);
    for (int i = 0; i < n; ++i) own[i] = std::max(own[i], alt[i]);
  }
  for (int i = 0; i < n; ++i) {
    if (!(own[i] >= min_ncc) || own[i] <= -2.f) return false;
  }
  for (int q : sc.alts) {
    if (rw.beatenAt(q, own)) return false;
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
      for (int y = 0; y < H; ++y) {
        const uint8_t* c = out.code.ptr<uint8_t>(y);
        const uint8_t* k = window_idx.ptr<uint8_t>(y);
        const float* a = lo.ptr<float>(y);
        const float* b = hi.ptr<float>(y);
        for (int x = 0; x < W; ++x) {
          if (c[x] >= kCodeAcceptedBase && (all_levels || k[x] == level)) judge(x, y, a[x], b[x]);
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
    constexpr int kChunk = 256;
    const int num_chunks = static_cast<int>((flagged.size() + kChunk - 1) / kChunk);
    cv::parallel_for_(cv::Range(0, num_chunks), [&](const cv::Range& rg) {
      VerifyScratch sc;
      for (int c = rg.start; c < rg.end; ++c) {
        const size_t e = std::min(flagged.size(), static_cast<size_t>(c + 1) * kChunk);
        for (size_t i = static_cast<size_t>(c) * kChunk; i < e; ++i) {
          keep[i] = verifyFlagged(mp, left, right, out.disparity, flagged[i], below, above, sc);
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
