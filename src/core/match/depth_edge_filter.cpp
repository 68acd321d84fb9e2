// Our measure against foreground fattening at depth edges (docs/matcher_design.md): run by
// RobustMatcher::compute after matching, before the post-filters. Two stages: a map test (this
// file) flags pixels whose accepting window holds a disparity jump; a second chance, looking at the
// images, keeps the flagged pixels that every small window around them confirms
// (depth_edge_second_chance.cpp) (a fattened pixel loses
// in the windows lying wholly on its true surface, a true foreground pixel next to the edge
// does not).
#include "depth_edge_filter.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "depth_edge_second_chance.hpp"
#include "endo_stereo/core/post_filter.hpp"
#include "simd.hpp"

namespace endo_stereo {

using detail::Flagged;

namespace {
using namespace simd;

// ---------------------------------------------------------------------------------------------
// Our measure against fattening at depth edges (see the top of this file and
// docs/matcher_design.md). A pixel accepted with a window of width w is flagged when the accepted
// disparities within (w - 1) / 2 + edge_margin_px of it (judged on the map before this step) go
// more than edge_disparity_jump_px below its own, or more than edge_disparity_jump_above_px above
// it: its window straddles a depth edge. Below = the pixel may carry a nearer surface's
// disparity onto the farther one (the usual foreground fattening, measured as almost all of the
// remaining errors); above = it may carry the farther surface's disparity into the nearer one's
// edge (rarer; a looser threshold keeps the density). The margin reaches the last fattened pixels
// whose own window just misses the surface behind. Min and max over each window size are
// grey-level erosions/dilations of the map (invalid pixels neutral): O(pixels) per window size.
// Flagged pixels are rejected, or, with edge_verify_radius_px > 0, verified
// (everyWindowPrefersOwnDisparity).
// ---------------------------------------------------------------------------------------------
/// Least of lo_src and greatest of hi_src over columns [x0, x1] and rows [y0, y1]. Neither
/// holds NaN, so min and max are exact in any order and may see a value twice: eight lanes (a
/// row's last, partial vector overlapping the one before), then the lanes folded.
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
    if (xx <= x1 && x1 + 1 - x0 >= 8) {
      const V8f l = load8(ls + x1 - 7), h = load8(hs + x1 - 7);
      va = l < va ? l : va;
      vb = h > vb ? h : vb;
      continue;
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
                           const float* b, int W, int level, float below, float above,
                           uint8_t* hits) {
  for (int x = 0; x < W; ++x) {
    const bool mine = (c[x] >= kCodeAcceptedBase) & (k[x] == level);
    const bool jump = (d[x] - a[x] > below) | (b[x] - d[x] > above);
    hits[x] = static_cast<uint8_t>(mine & jump);
  }
}

/// The map test's sources for one row of disparities @p d: a = d, b = d where valid, a = +inf,
/// b = -inf where NaN (neutral for min / max). Branch-free (vectorised).
ES_KERNEL void boundsRow(const float* d, int n, float* a, float* b) {
  const float inf = std::numeric_limits<float>::infinity();
  const V8f pinf = splat8(inf), ninf = splat8(-inf);
  int x = 0;
  for (; x + 8 <= n; x += 8) {
    const V8f v = load8(d + x);
    const V8i valid = v == v;
    const V8f va = valid ? v : pinf, vb = valid ? v : ninf;
    std::memcpy(a + x, &va, sizeof(va));
    std::memcpy(b + x, &vb, sizeof(vb));
  }
  for (; x < n; ++x) {
    const bool valid = d[x] == d[x];
    a[x] = valid ? d[x] : inf;
    b[x] = valid ? d[x] : -inf;
  }
}

/// For one row: sel[x] = 1 where pixel x is accepted with a window larger than the first
/// (window index @p k > 0), else 0; returns how many are accepted with the first window.
/// Branch-free (vectorised).
ES_KERNEL int acceptedRow(const uint8_t* c, const uint8_t* k, int n, uint8_t* sel) {
  int first = 0;
  for (int x = 0; x < n; ++x) {
    const bool accepted = c[x] >= kCodeAcceptedBase;
    sel[x] = static_cast<uint8_t>(accepted & (k[x] != 0));
    first += accepted & (k[x] == 0);
  }
  return first;
}

/// Calls fn(x) for each x < n with mask[x] != 0, in increasing order, skipping eight clear bytes
/// at a time (set bytes are rare here). mask is readable up to the next multiple of 8 past n.
template <typename Fn>
inline void forEachSet(const uint8_t* mask, int n, Fn&& fn) {
  for (int x0 = 0; x0 < n; x0 += 8) {
    uint64_t word;
    std::memcpy(&word, mask + x0, sizeof(word));
    if (word == 0) continue;
    for (int x = x0; x < std::min(n, x0 + 8); ++x) {
      if (mask[x]) fn(x);
    }
  }
}

constexpr int kMaxHalf = 32 / 2 + 16;  // widest map-test neighbourhood: window 32, margin 16

/// The slope-tolerant form of the map test (MatcherParams::edge_slope_tolerant; docs/method.md,
/// section 5): whether some neighbour of the flagged pixel within its square (half width
/// f.half) shows a depth edge once the surface's slope is taken out. A neighbour q is paired
/// with its mirror image q' = 2 p - q: on a plane, d(q) - d(p) = d(p) - d(q'), so the second
/// difference e = d(q) + d(q') - 2 d(p) is zero however steep the plane, while a step of s
/// between q and p gives e = -s (q farther) or +s (q nearer). The pixel stays flagged when
/// -e > below or e > above for some pair, or, where only one of q, q' holds a disparity, when
/// that one fails the plain test (d - d(q) > below or d(q) - d > above). @p fwd is the map
/// framed in NaN (pad columns and rows on each side), @p mir the same rows mirrored
/// (mir(y, c) = fwd(y, wp - 1 - c), wp = W + 2 pad), both with 8 spare columns. Rows dy <= 0
/// visit every unordered pair {q, q'}. Eight neighbours per vector; NaN compares false.
ES_KERNEL bool slopeStraddles(const cv::Mat& fwd, const cv::Mat& mir, int pad, int wp, int x,
                              int y, int half, float d, float below, float above) {
  const int side = 2 * half + 1;
  const V8f vd = splat8(d), vbelow = splat8(below), vabove = splat8(above);
  const V8f two_d = splat8(2.f * d);
  const V8i lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8i sidev = {side, side, side, side, side, side, side, side};
  for (int dy = -half; dy <= 0; ++dy) {
    const float* q = fwd.ptr<float>(pad + y + dy) + pad + x - half;
    const float* qm = mir.ptr<float>(pad + y - dy) + (wp - 1 - pad - x - half);
    for (int i = 0; i < side; i += 8) {
      const V8f a = load8(q + i), b = load8(qm + i);
      const V8i in = (lane + i) < sidev;
      const V8i va = a == a, vb = b == b;
      const V8f e = a + b - two_d;
      const V8i pair = va & vb & ((-e > vbelow) | (e > vabove));
      const V8i one_a = va & ~vb & ((vd - a > vbelow) | (a - vd > vabove));
      const V8i one_b = vb & ~va & ((vd - b > vbelow) | (b - vd > vabove));
      if (anyLane(in & (pair | one_a | one_b))) return true;
    }
  }
  return false;
}

constexpr int kRowBlock = 32;  // rows per task of the per-row passes over the threads

/// What the steps of rejectEdgeStraddlers read: the inputs, the thresholds and the geometry of
/// the map test (the neighbourhood of each window size).
struct EdgeTest {
  EdgeTest(const MatcherParams& mp_, const cv::Mat& left_, const cv::Mat& right_, int num_levels_,
           const cv::Mat& window_idx_, const MatchResult& out_)
      : mp(mp_),
        left(left_),
        right(right_),
        window_idx(window_idx_),
        out(out_),
        H(out_.disparity.rows),
        W(out_.disparity.cols),
        num_levels(num_levels_),
        num_blocks((H + kRowBlock - 1) / kRowBlock),
        on(mp_.edge_disparity_jump_px > 0.0),
        below(on ? static_cast<float>(mp_.edge_disparity_jump_px)
                 : std::numeric_limits<float>::infinity()),
        above(!on ? std::numeric_limits<float>::infinity()
                  : static_cast<float>(mp_.edge_disparity_jump_above_px > 0.0
                                           ? mp_.edge_disparity_jump_above_px
                                           : mp_.edge_disparity_jump_px)),
        margin(mp_.edge_margin_px),
        // Pixels flagged by their own window's test get a second chance
        // (everyWindowPrefersOwnDisparity) when edge_verify_radius_px > 0; they are listed by the
        // map test and judged after it.
        verify(mp_.edge_verify_radius_px > 0 && left_.type() == CV_8UC1 &&
               right_.type() == CV_8UC1 && left_.size() == out_.disparity.size() &&
               right_.size() == out_.disparity.size()),
        // With edge_slope_tolerant, flagged pixels are judged again with the slope taken out
        // (slopeStraddles) before their second chance; those it clears are kept.
        slope(on && mp_.edge_slope_tolerant) {}

  /// Half width of the map test's neighbourhood at a window size: the window's, plus the margin.
  int half(int level) const { return (mp.window_min_px + level * mp.window_step_px) / 2 + margin; }
  int side(int level) const { return 2 * half(level) + 1; }
  /// Many pixels: erosion/dilation of the whole map; few: a direct scan of each one's window.
  bool scanDirectly(int level, size_t count) const {
    const size_t s = static_cast<size_t>(side(level));
    return !(count * s * s > static_cast<size_t>(H) * W * 8);
  }

  const MatcherParams& mp;
  const cv::Mat& left;
  const cv::Mat& right;
  const cv::Mat& window_idx;
  const MatchResult& out;
  const int H, W;
  const int num_levels;
  const int num_blocks;
  const bool on;
  const float below, above;
  const int margin;
  const bool verify;
  const bool slope;
};

/// The map test's verdicts, in judging order. Rejections are applied after all window sizes are
/// judged, so every test sees the same map (a pixel may be listed twice; applying is
/// idempotent).
struct Verdicts {
  std::vector<cv::Point> rejected;
  std::vector<Flagged> flagged;  // waiting for the slope test and / or the second chance

  /// The map test's verdict on pixel (x, y), judged at window size @p level with the least
  /// (@p a) and greatest (@p b) disparity of its neighbourhood: a straddler of its own window
  /// size is flagged (when a later test may clear it) or rejected.
  void judge(const EdgeTest& t, int level, int x, int y, float a, float b) {
    const float d = t.out.disparity.at<float>(y, x);
    if (!(d - a > t.below || b - d > t.above)) return;
    const int k = t.window_idx.at<uint8_t>(y, x);
    if (k == level) {
      if (t.verify || t.slope) {
        flagged.push_back(Flagged{x, y, t.half(level)});
      } else {
        rejected.push_back(cv::Point(x, y));
      }
    }
  }
};

/// Accepted pixels listed per window size; count[level] how many there are (the first
/// window's are counted here, and listed only when few enough to be scanned directly).
struct PixelsByLevel {
  std::vector<std::vector<cv::Point>> pixels;
  std::vector<size_t> count;
};

/// The map the test looks at: with edge_support_share > 0, the accepted disparities without a
/// surface's support (the outlier filter's count, window 2 edge_support_radius_px + 1,
/// tolerance edge_disparity_jump_px) left out; otherwise the result's map itself.
cv::Mat supportedMap(const EdgeTest& t) {
  cv::Mat supported = t.out.disparity;
  if (t.on && t.mp.edge_support_share > 0.0) {
    PostFilterParams sp;
    sp.outlier_window_px = 2 * t.mp.edge_support_radius_px + 1;
    sp.outlier_disparity_tol_px = t.mp.edge_disparity_jump_px;
    sp.outlier_min_share = t.mp.edge_support_share;
    supported = t.out.disparity.clone();
    cv::Mat no_code;
    removeIsolatedOutliers(supported, no_code, sp);
  }
  return supported;
}

/// Pixels accepted per window size (the first window: nearly all of them; the larger ones: few),
/// in one pass: the larger windows' pixels listed (and counted by their list), the first
/// window's counted; its pixels are listed (listFirstWindowPixels) only when few enough to be
/// scanned directly. With the map test's sources (boundsRow of @p supported into @p lo_src,
/// @p hi_src), in row blocks over the threads; each block lists its own pixels, and the blocks'
/// lists are joined in row order (the order a serial pass gives).
void listAcceptedPixels(const EdgeTest& t, const cv::Mat& supported, cv::Mat& lo_src,
                        cv::Mat& hi_src, PixelsByLevel& lists) {
  const int H = t.H, W = t.W;
  std::vector<std::vector<std::vector<cv::Point>>> block_lists(
      t.num_blocks, std::vector<std::vector<cv::Point>>(t.num_levels));
  std::vector<size_t> block_first(t.num_blocks, 0);
  cv::parallel_for_(cv::Range(0, t.num_blocks), [&](const cv::Range& rg) {
    std::vector<uint8_t> sel(W + 8, 0);
    for (int blk = rg.start; blk < rg.end; ++blk) {
      for (int y = blk * kRowBlock; y < std::min(H, (blk + 1) * kRowBlock); ++y) {
        boundsRow(supported.ptr<float>(y), W, lo_src.ptr<float>(y), hi_src.ptr<float>(y));
        const uint8_t* k = t.window_idx.ptr<uint8_t>(y);
        block_first[blk] += acceptedRow(t.out.code.ptr<uint8_t>(y), k, W, sel.data());
        // The larger windows' pixels are few.
        forEachSet(sel.data(), W,
                   [&](int x) { block_lists[blk][k[x]].push_back(cv::Point(x, y)); });
      }
    }
  });
  for (int blk = 0; blk < t.num_blocks; ++blk) {
    lists.count[0] += block_first[blk];
    for (int level = 1; level < t.num_levels; ++level) {
      const std::vector<cv::Point>& l = block_lists[blk][level];
      lists.pixels[level].insert(lists.pixels[level].end(), l.begin(), l.end());
    }
  }
  for (int level = 1; level < t.num_levels; ++level) {
    lists.count[level] = lists.pixels[level].size();
  }
}

/// The first window's pixels listed in row order, when few enough to be scanned directly.
void listFirstWindowPixels(const EdgeTest& t, PixelsByLevel& lists) {
  if (!(lists.count[0] > 0 && t.scanDirectly(0, lists.count[0]))) return;
  lists.pixels[0].reserve(lists.count[0]);
  for (int y = 0; y < t.H; ++y) {
    const uint8_t* c = t.out.code.ptr<uint8_t>(y);
    const uint8_t* k = t.window_idx.ptr<uint8_t>(y);
    for (int x = 0; x < t.W; ++x) {
      if (c[x] >= kCodeAcceptedBase && k[x] == 0) lists.pixels[0].push_back(cv::Point(x, y));
    }
  }
}

/// Half width of the frame around the map (lo / hi, the slope test, the second chance): the
/// widest neighbourhood of any window size.
int framePad(const EdgeTest& t) {
  int pad = 0;
  for (int level = 0; level < t.num_levels; ++level) pad = std::max(pad, t.side(level) / 2);
  return pad;
}

/// A pixel of the map test whose neighbourhood straddles its disparity, with the
/// neighbourhood's least (a) and greatest (b) disparity.
struct Hit {
  int x, y;
  float a, b;
};

/// The hits of rows [y0, y1) at window size @p level, in row order, appended to @p found;
/// @p hits is a row of scratch (W + 8 bytes).
void findHitsInRows(const EdgeTest& t, int level, const cv::Mat& lo_map, const cv::Mat& hi_map,
                    int y0, int y1, std::vector<uint8_t>& hits, std::vector<Hit>& found) {
  for (int y = y0; y < y1; ++y) {
    const float* a = lo_map.ptr<float>(y);
    const float* b = hi_map.ptr<float>(y);
    straddleRow(t.out.code.ptr<uint8_t>(y), t.window_idx.ptr<uint8_t>(y),
                t.out.disparity.ptr<float>(y), a, b, t.W, level, t.below, t.above, hits.data());
    // Hits are rare.
    forEachSet(hits.data(), t.W, [&](int x) { found.push_back(Hit{x, y, a[x], b[x]}); });
  }
}

/// The map test at window size @p level for many pixels: separable erosion and dilation of the
/// whole map (@p lo_src / @p hi_src into @p lo_map / @p hi_map, written in place), then the
/// rows' hits found in row blocks over the threads and judged in row order.
void testByErosion(const EdgeTest& t, int level, const cv::Mat& lo_src, const cv::Mat& hi_src,
                   cv::Mat& lo_map, cv::Mat& hi_map, Verdicts& v) {
  const float inf = std::numeric_limits<float>::infinity();
  const int side = t.side(level);
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side, side));
  const uchar* lo_data = lo_map.data;
  const uchar* hi_data = hi_map.data;
  // The two as concurrent tasks (OpenCV runs each one's own loop inline when nested).
  cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& rg) {
    for (int i = rg.start; i < rg.end; ++i) {
      if (i == 0) {
        cv::erode(lo_src, lo_map, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT,
                  cv::Scalar(inf));
      } else {
        cv::dilate(hi_src, hi_map, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT,
                   cv::Scalar(-inf));
      }
    }
  });
  CV_Assert(lo_map.data == lo_data && hi_map.data == hi_data);  // written in place
  std::vector<std::vector<Hit>> block_hits(t.num_blocks);
  cv::parallel_for_(cv::Range(0, t.num_blocks), [&](const cv::Range& rg) {
    std::vector<uint8_t> hits(t.W + 8, 0);
    for (int blk = rg.start; blk < rg.end; ++blk) {
      findHitsInRows(t, level, lo_map, hi_map, blk * kRowBlock,
                     std::min(t.H, (blk + 1) * kRowBlock), hits, block_hits[blk]);
    }
  });
  for (const std::vector<Hit>& hs : block_hits) {
    for (const Hit& h : hs) v.judge(t, level, h.x, h.y, h.a, h.b);
  }
}

/// The map test at window size @p level for few pixels, the first window's erosion and dilation
/// at hand (@p lo_map / @p hi_map): the neighbourhood [x - half, x + half] (clipped to the map)
/// is covered by n squares of side s0 per axis whose centres lie inside it, the last ones flush
/// with its ends; a centre beyond the map is moved to its border, which keeps the square
/// (clipped) inside the clipped neighbourhood (half >= h0) and still covers what it covered
/// inside the map. Min and max are exact in any order and may see a value twice: the same values
/// as a scan.
void testFromFirstWindowMaps(const EdgeTest& t, int level, const std::vector<cv::Point>& pixels,
                             const cv::Mat& lo_map, const cv::Mat& hi_map, Verdicts& v) {
  const float inf = std::numeric_limits<float>::infinity();
  const int W = t.W, H = t.H;
  const int half = t.half(level), side = t.side(level);
  const int h0 = t.side(0) / 2, s0 = 2 * h0 + 1;
  const int n = (side + s0 - 1) / s0;
  int cx[2 * kMaxHalf + 2], cy[2 * kMaxHalf + 2];
  for (const cv::Point& p : pixels) {
    for (int i = 0; i < n; ++i) {
      const int o = i + 1 < n ? h0 - half + s0 * i : half - h0;
      cx[i] = std::min(std::max(p.x + o, 0), W - 1);
      cy[i] = std::min(std::max(p.y + o, 0), H - 1);
    }
    float a = inf, b = -inf;
    for (int j = 0; j < n; ++j) {
      const float* l = lo_map.ptr<float>(cy[j]);
      const float* h = hi_map.ptr<float>(cy[j]);
      for (int i = 0; i < n; ++i) {
        a = std::min(a, l[cx[i]]);
        b = std::max(b, h[cx[i]]);
      }
    }
    v.judge(t, level, p.x, p.y, a, b);
  }
}

/// The map test at window size @p level for few pixels: each one's window scanned directly on
/// the sources, over the threads in fixed chunks; then judged in list order.
void testByScan(const EdgeTest& t, int level, const std::vector<cv::Point>& pts,
                const cv::Mat& lo_src, const cv::Mat& hi_src, Verdicts& v) {
  const int W = t.W, H = t.H;
  const int half = t.half(level);
  std::vector<float> a(pts.size()), b(pts.size());
  constexpr int kScanChunk = 1024;
  const int num_chunks = static_cast<int>((pts.size() + kScanChunk - 1) / kScanChunk);
  cv::parallel_for_(cv::Range(0, num_chunks), [&](const cv::Range& rg) {
    const size_t e = std::min(pts.size(), static_cast<size_t>(rg.end) * kScanChunk);
    for (size_t i = static_cast<size_t>(rg.start) * kScanChunk; i < e; ++i) {
      const cv::Point& p = pts[i];
      windowMinMax(lo_src, hi_src, std::max(0, p.x - half), std::min(W - 1, p.x + half),
                   std::max(0, p.y - half), std::min(H - 1, p.y + half), &a[i], &b[i]);
    }
  });
  for (size_t i = 0; i < pts.size(); ++i) v.judge(t, level, pts[i].x, pts[i].y, a[i], b[i]);
}

/// The map test, window size by window size: erosion / dilation when many pixels have the size,
/// else the first window's maps when at hand and small enough, else a direct scan. @p lo and
/// @p hi (the caller's, at the framed size) hold the erosion and dilation.
void mapTest(const EdgeTest& t, const PixelsByLevel& lists, const cv::Mat& lo_src,
             const cv::Mat& hi_src, cv::Mat& lo, cv::Mat& hi, Verdicts& v) {
  cv::Mat lo_map = lo(cv::Rect(0, 0, t.W, t.H));
  cv::Mat hi_map(t.H, t.W, CV_32F, hi.data, hi.step);  // float view of hi's memory
  // Whether lo_map / hi_map hold the first window's erosion / dilation (side t.side(0)): a
  // larger neighbourhood is then the union of a few of those squares, read instead of scanned.
  bool base_maps = false;
  for (int level = 0; level < t.num_levels; ++level) {
    if (lists.count[level] == 0) continue;
    if (!t.scanDirectly(level, lists.count[level])) {
      testByErosion(t, level, lo_src, hi_src, lo_map, hi_map, v);
      base_maps = level == 0;
    } else if (base_maps && t.half(level) >= t.side(0) / 2) {
      testFromFirstWindowMaps(t, level, lists.pixels[level], lo_map, hi_map, v);
    } else {
      testByScan(t, level, lists.pixels[level], lo_src, hi_src, v);
    }
  }
}

/// The slope-tolerant test (slopeStraddles) of the flagged pixels: those it clears are dropped;
/// without a second chance to follow, the rest are rejected. The map the test looked at
/// (@p supported), framed in NaN, and its rows mirrored, in @p lo and @p hi (free until the
/// second chance rebuilds them). Each pixel's verdict reads only these maps: fixed chunks over
/// the threads give the same list whatever their number.
void slopeTest(const EdgeTest& t, const cv::Mat& supported, int pad, cv::Mat& lo, cv::Mat& hi,
               Verdicts& v) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<Flagged>& flagged = v.flagged;
  const int wp = t.W + 2 * pad;
  cv::Mat fwd = lo, mir(hi.rows, hi.cols, CV_32F, hi.data, hi.step);
  // Written in place: lo already has the framed size (W + 2 pad + 8) x (H + 2 pad).
  cv::copyMakeBorder(supported, fwd, pad, pad, pad, pad + 8, cv::BORDER_CONSTANT, cv::Scalar(nan));
  cv::flip(fwd.colRange(0, wp), mir.colRange(0, wp), 1);
  mir.colRange(wp, mir.cols).setTo(nan);
  CV_Assert(fwd.data == lo.data && mir.data == hi.data);
  std::vector<uint8_t> still(flagged.size(), 0);
  constexpr int kSlopeChunk = 512;
  const int chunks = static_cast<int>((flagged.size() + kSlopeChunk - 1) / kSlopeChunk);
  cv::parallel_for_(cv::Range(0, chunks), [&](const cv::Range& rg) {
    const size_t e = std::min(flagged.size(), static_cast<size_t>(rg.end) * kSlopeChunk);
    for (size_t i = static_cast<size_t>(rg.start) * kSlopeChunk; i < e; ++i) {
      const Flagged& f = flagged[i];
      still[i] = slopeStraddles(fwd, mir, pad, wp, f.x, f.y, f.half,
                                t.out.disparity.at<float>(f.y, f.x), t.below, t.above);
    }
  });
  size_t n = 0;
  for (size_t i = 0; i < flagged.size(); ++i) {
    if (still[i]) flagged[n++] = flagged[i];
  }
  flagged.resize(n);
  if (!t.verify) {
    for (const Flagged& f : flagged) v.rejected.push_back(cv::Point(f.x, f.y));
    flagged.clear();
  }
}

/// The second chance (depth_edge_second_chance.cpp) of the flagged pixels: those it does not
/// keep are rejected. Every verdict reads only the images and the flagged pixel's own entry, so
/// fixed chunks over the threads give the same result whatever their number.
void secondChanceTest(const EdgeTest& t, int pad, cv::Mat& lo, cv::Mat& hi, cv::Mat& reject,
                      Verdicts& v) {
  std::vector<uint8_t> keep;
  detail::secondChance(t.mp, t.left, t.right, t.out.disparity, pad, t.below, t.above, v.flagged, lo,
                       hi, reject, keep);
  for (size_t i = 0; i < v.flagged.size(); ++i) {
    if (!keep[i]) v.rejected.push_back(cv::Point(v.flagged[i].x, v.flagged[i].y));
  }
}

/// The rejections applied: code kCodeRejectEdge, disparity NaN, confidence 0.
void applyRejections(const std::vector<cv::Point>& rejected, MatchResult& out) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const cv::Point& p : rejected) {
    out.disparity.at<float>(p.y, p.x) = nan;
    out.confidence.at<float>(p.y, p.x) = 0.f;
    out.code.at<uint8_t>(p.y, p.x) = kCodeRejectEdge;
  }
}

}  // namespace

void rejectEdgeStraddlers(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                          int num_levels, const cv::Mat& window_idx, MatchResult& out,
                          cv::Mat& lo_src, cv::Mat& hi_src, cv::Mat& lo, cv::Mat& hi,
                          cv::Mat& reject) {
  const EdgeTest t(mp, left, right, num_levels, window_idx, out);
  lo_src.create(t.H, t.W, CV_32F);
  hi_src.create(t.H, t.W, CV_32F);
  // Counted here, not taken from the result's stats, which a merged map (such as the temporal
  // fallback's) does not carry.
  PixelsByLevel lists{std::vector<std::vector<cv::Point>>(num_levels),
                      std::vector<size_t>(num_levels, 0)};
  const cv::Mat supported = supportedMap(t);
  listAcceptedPixels(t, supported, lo_src, hi_src, lists);
  listFirstWindowPixels(t, lists);

  // @p lo and @p hi (kept by the caller from frame to frame) hold the erosion and dilation of
  // the map and, after the map test, the map framed in NaN and its slots for the competitor
  // scans (everyWindowPrefersOwnDisparity), at a size that does not change between calls: no fresh
  // pages each frame. The frame is as wide as the widest neighbourhood of any level.
  const int pad = framePad(t);
  const cv::Size padded_size(t.W + 2 * pad + 8, t.H + 2 * pad);
  if (lo.size() != padded_size || lo.type() != CV_32F) lo.create(padded_size, CV_32F);
  if (hi.size() != padded_size || hi.type() != CV_32S) hi.create(padded_size, CV_32S);

  Verdicts v;
  mapTest(t, lists, lo_src, hi_src, lo, hi, v);
  if (t.slope && !v.flagged.empty()) slopeTest(t, supported, pad, lo, hi, v);
  if (!v.flagged.empty()) secondChanceTest(t, pad, lo, hi, reject, v);
  applyRejections(v.rejected, out);
}

}  // namespace endo_stereo
