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

}  // namespace

void rejectEdgeStraddlers(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                          int num_levels, const cv::Mat& window_idx, MatchResult& out,
                          cv::Mat& lo_src, cv::Mat& hi_src, cv::Mat& lo, cv::Mat& hi,
                          cv::Mat& reject) {
  const int H = out.disparity.rows, W = out.disparity.cols;
  const float inf = std::numeric_limits<float>::infinity();
  lo_src.create(H, W, CV_32F);
  hi_src.create(H, W, CV_32F);
  constexpr int kRowBlock = 32;  // rows per task of the per-row passes over the threads
  const int num_blocks = (H + kRowBlock - 1) / kRowBlock;
  const bool on = mp.edge_disparity_jump_px > 0.0;
  const float below = on ? static_cast<float>(mp.edge_disparity_jump_px) : inf;
  const float above = !on ? inf
                          : static_cast<float>(mp.edge_disparity_jump_above_px > 0.0
                                                   ? mp.edge_disparity_jump_above_px
                                                   : mp.edge_disparity_jump_px);
  const int margin = mp.edge_margin_px;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // Rejections are applied after all window sizes are judged, so every test sees the same map:
  // listed here (a pixel may be listed twice; applying is idempotent). @p reject serves as
  // memory for the second chance (below), not as a mask.
  std::vector<cv::Point> rejected;
  // Pixels accepted per window size (the first window: nearly all of them; the larger ones: few),
  // in one pass: the larger windows' pixels listed (and counted by their list), the first
  // window's counted; its pixels are listed below only when few enough to be scanned directly.
  // With the map test's sources, in row blocks over the threads; each block lists its own
  // pixels, and the blocks' lists are joined in row order (the order a serial pass gives).
  std::vector<std::vector<cv::Point>> by_level(num_levels);
  std::vector<size_t> level_count(num_levels, 0);
  // The map the test looks at: with edge_support_share > 0, the accepted disparities without a
  // surface's support (the outlier filter's count, window 2 edge_support_radius_px + 1,
  // tolerance edge_disparity_jump_px) left out.
  cv::Mat supported = out.disparity;
  if (on && mp.edge_support_share > 0.0) {
    PostFilterParams sp;
    sp.outlier_window_px = 2 * mp.edge_support_radius_px + 1;
    sp.outlier_disparity_tol_px = mp.edge_disparity_jump_px;
    sp.outlier_min_share = mp.edge_support_share;
    supported = out.disparity.clone();
    cv::Mat no_code;
    removeIsolatedOutliers(supported, no_code, sp);
  }
  {
    std::vector<std::vector<std::vector<cv::Point>>> block_lists(
        num_blocks, std::vector<std::vector<cv::Point>>(num_levels));
    std::vector<size_t> block_first(num_blocks, 0);
    cv::parallel_for_(cv::Range(0, num_blocks), [&](const cv::Range& rg) {
      std::vector<uint8_t> sel(W + 8, 0);
      for (int blk = rg.start; blk < rg.end; ++blk) {
        for (int y = blk * kRowBlock; y < std::min(H, (blk + 1) * kRowBlock); ++y) {
          boundsRow(supported.ptr<float>(y), W, lo_src.ptr<float>(y), hi_src.ptr<float>(y));
          const uint8_t* k = window_idx.ptr<uint8_t>(y);
          block_first[blk] += acceptedRow(out.code.ptr<uint8_t>(y), k, W, sel.data());
          // The larger windows' pixels are few.
          forEachSet(sel.data(), W,
                     [&](int x) { block_lists[blk][k[x]].push_back(cv::Point(x, y)); });
        }
      }
    });
    for (int blk = 0; blk < num_blocks; ++blk) {
      level_count[0] += block_first[blk];
      for (int level = 1; level < num_levels; ++level) {
        const std::vector<cv::Point>& l = block_lists[blk][level];
        by_level[level].insert(by_level[level].end(), l.begin(), l.end());
      }
    }
  }
  for (int level = 1; level < num_levels; ++level) level_count[level] = by_level[level].size();
  // Counted here, not taken from the result's stats, which a merged map (such as the temporal
  // fallback's) does not carry.
  auto levelCount = [&](int level) -> size_t { return level_count[level]; };
  auto levelSide = [&](int level) {
    return 2 * ((mp.window_min_px + level * mp.window_step_px) / 2 + margin) + 1;
  };
  // Many pixels: erosion/dilation of the whole map; few: a direct scan of each one's window.
  auto scanDirectly = [&](int level) {
    const size_t side = static_cast<size_t>(levelSide(level));
    return !(levelCount(level) * side * side > static_cast<size_t>(H) * W * 8);
  };
  if (levelCount(0) > 0 && scanDirectly(0)) {
    by_level[0].reserve(level_count[0]);
    for (int y = 0; y < H; ++y) {
      const uint8_t* c = out.code.ptr<uint8_t>(y);
      const uint8_t* k = window_idx.ptr<uint8_t>(y);
      for (int x = 0; x < W; ++x) {
        if (c[x] >= kCodeAcceptedBase && k[x] == 0) by_level[0].push_back(cv::Point(x, y));
      }
    }
  }
  auto straddles = [&](float d, float a, float b) { return d - a > below || b - d > above; };
  // Pixels flagged by their own window's test get a second chance (everyWindowPrefersOwnDisparity)
  // when edge_verify_radius_px > 0; they are listed here and judged after the map test.
  const bool verify = mp.edge_verify_radius_px > 0 && left.type() == CV_8UC1 &&
                      right.type() == CV_8UC1 && left.size() == out.disparity.size() &&
                      right.size() == out.disparity.size();
  // With edge_slope_tolerant, flagged pixels are judged again with the slope taken out
  // (slopeStraddles) before their second chance; those it clears are kept.
  const bool slope = on && mp.edge_slope_tolerant;
  std::vector<Flagged> flagged;
  // @p lo and @p hi (kept by the caller from frame to frame) hold the erosion and dilation of
  // the map and, after the map test, the map framed in NaN and its slots for the competitor
  // scans (everyWindowPrefersOwnDisparity), at a size that does not change between calls: no fresh
  // pages each frame. The frame is as wide as the widest neighbourhood of any level.
  int pad = 0;
  for (int level = 0; level < num_levels; ++level) pad = std::max(pad, levelSide(level) / 2);
  const cv::Size padded_size(W + 2 * pad + 8, H + 2 * pad);
  if (lo.size() != padded_size || lo.type() != CV_32F) lo.create(padded_size, CV_32F);
  if (hi.size() != padded_size || hi.type() != CV_32S) hi.create(padded_size, CV_32S);
  cv::Mat lo_map = lo(cv::Rect(0, 0, W, H));
  cv::Mat hi_map(H, W, CV_32F, hi.data, hi.step);  // float view of hi's memory
  // Whether lo_map / hi_map hold the first window's erosion / dilation (side levelSide(0)): a
  // larger neighbourhood is then the union of a few of those squares (see below), read instead
  // of scanned.
  bool base_maps = false;
  for (int level = 0; level < num_levels; ++level) {
    const int w = mp.window_min_px + level * mp.window_step_px;
    const int half = w / 2 + margin;
    const int side = levelSide(level);
    if (levelCount(level) == 0) continue;
    auto judge = [&](int x, int y, float a, float b) {
      const float d = out.disparity.at<float>(y, x);
      if (!straddles(d, a, b)) return;
      const int k = window_idx.at<uint8_t>(y, x);
      if (k == level) {
        if (verify || slope) {
          flagged.push_back(Flagged{x, y, half});
        } else {
          rejected.push_back(cv::Point(x, y));
        }
      }
    };
    if (!scanDirectly(level)) {
      // Many pixels: separable erosion and dilation of the whole map.
      const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(side, side));
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
      CV_Assert(lo_map.data == lo.data && hi_map.data == hi.data);  // written in place
      base_maps = level == 0;
      // The rows' hits found in row blocks over the threads, then judged in row order.
      struct Hit {
        int x, y;
        float a, b;
      };
      std::vector<std::vector<Hit>> block_hits(num_blocks);
      cv::parallel_for_(cv::Range(0, num_blocks), [&](const cv::Range& rg) {
        std::vector<uint8_t> hits(W + 8, 0);
        for (int blk = rg.start; blk < rg.end; ++blk) {
          for (int y = blk * kRowBlock; y < std::min(H, (blk + 1) * kRowBlock); ++y) {
            const float* a = lo_map.ptr<float>(y);
            const float* b = hi_map.ptr<float>(y);
            straddleRow(out.code.ptr<uint8_t>(y), window_idx.ptr<uint8_t>(y),
                        out.disparity.ptr<float>(y), a, b, W, level, below, above, hits.data());
            // Hits are rare.
            forEachSet(hits.data(), W, [&](int x) {
              block_hits[blk].push_back(Hit{x, y, a[x], b[x]});
            });
          }
        }
      });
      for (const std::vector<Hit>& hs : block_hits) {
        for (const Hit& h : hs) judge(h.x, h.y, h.a, h.b);
      }
    } else if (base_maps && half >= levelSide(0) / 2) {
      // Few pixels, the first window's erosion and dilation at hand: the neighbourhood
      // [x - half, x + half] (clipped to the map) is covered by n squares of side s0 per axis
      // whose centres lie inside it, the last ones flush with its ends; a centre beyond the
      // map is moved to its border, which keeps the square (clipped) inside the clipped
      // neighbourhood (half >= h0) and still covers what it covered inside the map. Min and
      // max are exact in any order and may see a value twice: the same values as a scan.
      const int h0 = levelSide(0) / 2, s0 = 2 * h0 + 1;
      const int n = (side + s0 - 1) / s0;
      int cx[2 * kMaxHalf + 2], cy[2 * kMaxHalf + 2];
      for (const cv::Point& p : by_level[level]) {
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
        judge(p.x, p.y, a, b);
      }
    } else {
      // Few pixels: scan each one's window directly, over the threads in fixed chunks; then
      // judged in list order.
      const std::vector<cv::Point>& pts = by_level[level];
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
      for (size_t i = 0; i < pts.size(); ++i) judge(pts[i].x, pts[i].y, a[i], b[i]);
    }
  }
  if (slope && !flagged.empty()) {
    // The map the test looked at, framed in NaN, and its rows mirrored, in @p lo and @p hi
    // (free until the second chance rebuilds them). Each pixel's verdict reads only these maps:
    // fixed chunks over the threads give the same list whatever their number.
    const int wp = W + 2 * pad;
    cv::Mat fwd = lo, mir(hi.rows, hi.cols, CV_32F, hi.data, hi.step);
    // Written in place: lo already has the framed size (W + 2 pad + 8) x (H + 2 pad).
    cv::copyMakeBorder(supported, fwd, pad, pad, pad, pad + 8, cv::BORDER_CONSTANT,
                       cv::Scalar(nan));
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
                                  out.disparity.at<float>(f.y, f.x), below, above);
      }
    });
    size_t n = 0;
    for (size_t i = 0; i < flagged.size(); ++i) {
      if (still[i]) flagged[n++] = flagged[i];
    }
    flagged.resize(n);
    if (!verify) {
      for (const Flagged& f : flagged) rejected.push_back(cv::Point(f.x, f.y));
      flagged.clear();
    }
  }
  if (!flagged.empty()) {
    // Every verdict reads only the images and the flagged pixel's own entry, so fixed chunks
    // over the threads give the same result whatever their number.
    std::vector<uint8_t> keep;
    detail::secondChance(mp, left, right, out.disparity, pad, below, above, flagged, lo, hi, reject,
                         keep);
    for (size_t i = 0; i < flagged.size(); ++i) {
      if (!keep[i]) rejected.push_back(cv::Point(flagged[i].x, flagged[i].y));
    }
  }
  for (const cv::Point& p : rejected) {
    out.disparity.at<float>(p.y, p.x) = nan;
    out.confidence.at<float>(p.y, p.x) = 0.f;
    out.code.at<uint8_t>(p.y, p.x) = kCodeRejectEdge;
  }
}

}  // namespace endo_stereo
