// Our measure against foreground fattening at depth edges (docs/matcher_design.md): run by
// RobustMatcher::compute after matching, before the post-filters.
#include "edge_test.hpp"

#include <algorithm>
#include <cmath>
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
// docs/matcher_design.md). A pixel accepted with a window of width w is rejected when the accepted
// disparities within (w - 1) / 2 + edge_margin_px of it (judged on the map before this step) go
// more than edge_disparity_jump_px below its own, or more than edge_disparity_jump_above_px above
// it: its window straddles a depth edge. Below = the pixel may carry a nearer surface's
// disparity onto the farther one (the usual foreground fattening, measured as almost all of the
// remaining errors); above = it may carry the farther surface's disparity into the nearer one's
// edge (rarer; a looser threshold keeps the density). The margin reaches the last fattened pixels
// whose own window just misses the surface behind. With edge_window_max_px, pixels accepted with
// a wider window are also rejected when the w_min test fires. Min and max over each window size are
// grey-level erosions/dilations of the map (invalid pixels neutral): O(pixels) per window size.
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

}  // namespace

void rejectEdgeStraddlers(const MatcherParams& mp, const cv::Mat& /*left*/,
                          const cv::Mat& /*right*/,
                          int num_levels, const cv::Mat& window_idx,
                          MatchResult& out, cv::Mat& lo_src, cv::Mat& hi_src, cv::Mat& lo,
                          cv::Mat& hi, cv::Mat& reject) {
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
      if (k == level) reject.at<uint8_t>(y, x) = 1;
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
