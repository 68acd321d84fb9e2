// The robust matcher of Bernhardt, Abi-Nahed and Abugharbieh (2012), docs/method.md, plus our
// measure against foreground fattening at depth edges (depth_edge_filter.cpp).
//
// RobustMatcher::compute: checks the input, prepares the two views (float copies as value - 128,
// the right view mirrored, integral images of the views, of their squares, of the 3x3 Laplacian
// and of its square), matches every row at every window size of the growth sequence
// (row_decisions.cpp, with the search engines of search_*.cpp), runs the depth-edge filter and the
// post-filters (post_filter.cpp), and counts.
//
// Why it is exact, and the same for any thread count:
// - Intensities are stored as float (value - 128), so every product lies in [-16384, 16384] and
//   every window sum of products of a window up to 32 x 32 stays below 2^24: window sums are exact
//   integers in float arithmetic. Running sums, fresh sums and any order of summation give
//   bit-identical values, so the output cannot depend on how rows are split between threads, nor
//   on which search engine computed a profile. Window means and variances come from integral
//   images (int32, exact: see boxAt in window_statistics.hpp).
// - Rows are processed in fixed stripes (cv::parallel_for_ over stripe indices that do not depend
//   on the thread count); a row's window sizes depend only on that row.
// - The core builds with -ffp-contract=off, so the AVX-512, AVX2 and baseline clones of the
//   kernels (simd.hpp) round alike (test_simd_clones checks it).
// - Only the pixels that failed with one window go on to the next; pixels whose left patch lacks
//   structure at a window are not matched with it at all.

#include "endo_stereo/core/matcher.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>

#include "depth_edge_filter.hpp"
#include "matcher_internal.hpp"
#include "row_decisions.hpp"
#include "simd.hpp"
#include "window_statistics.hpp"

namespace endo_stereo {

using detail::kStripeRows;

struct RobustMatcher::Impl : detail::FrameData {
  cv::Mat state;        // CV_8U: 0 = undecided/failed so far, 1 = accepted
  cv::Mat window_idx;   // CV_8U window index that accepted
  cv::Mat code_before;  // codes before hole filling (a filled pixel's confidence)
  // Reused buffers of the depth-edge filter (rejectEdgeStraddlers): the erosion / dilation
  // sources, their results, and the second chance's window cache.
  cv::Mat edge_lo_src, edge_hi_src, edge_lo, edge_hi, edge_cache;
  std::vector<std::vector<int>> open_rows;
  std::vector<int> open_level;
  std::vector<int> n_req_rows;

  std::mutex pool_mutex;
  std::vector<std::unique_ptr<detail::WorkerScratch>> pool;

  /// The window sizes of the growth sequence that fit the image, each with what a row needs to be
  /// matched at it.
  std::vector<detail::WindowLevel> windowLevels(const MatcherParams& mp, bool uniform, int W, int H,
                                                MatchResult& out);
  /// The search: every stripe of rows through every window size of @p levels.
  void matchStripes(const MatcherParams& mp, const std::vector<detail::WindowLevel>& levels, int W,
                    int H);

  std::unique_ptr<detail::WorkerScratch> acquire() {
    std::lock_guard<std::mutex> lock(pool_mutex);
    if (pool.empty()) return std::make_unique<detail::WorkerScratch>();
    auto s = std::move(pool.back());
    pool.pop_back();
    return s;
  }
  void release(std::unique_ptr<detail::WorkerScratch> s) {
    std::lock_guard<std::mutex> lock(pool_mutex);
    pool.push_back(std::move(s));
  }
};

RobustMatcher::RobustMatcher(const MatcherParams& matcher_params,
                             const PostFilterParams& filter_params)
    : impl_(nullptr) {
  setParams(matcher_params, filter_params);
  impl_ = new Impl();
}

RobustMatcher::~RobustMatcher() { delete impl_; }

void RobustMatcher::setParams(const MatcherParams& matcher_params,
                              const PostFilterParams& filter_params) {
  std::string err = matcher_params.validate();
  if (!err.empty()) throw std::invalid_argument("RobustMatcher: " + err);
  err = filter_params.validate();
  if (!err.empty()) throw std::invalid_argument("RobustMatcher: " + err);
  matcher_params_ = matcher_params;
  filter_params_ = filter_params;
}

namespace {

using namespace simd;

/// Bytes of p[0..n) equal to v: 32 byte counters (each at most 255 between reductions), then
/// the lanes summed.
ES_KERNEL int64_t countEqual(const uint8_t* __restrict p, int n, int v) {
  typedef uint8_t V32u8 __attribute__((vector_size(32)));
  const uint8_t b = static_cast<uint8_t>(v);
  V32u8 vb;
  for (int i = 0; i < 32; ++i) vb[i] = b;
  int64_t total = 0;
  int x = 0;
  while (x + 32 <= n) {
    V32u8 acc = {};
    for (int k = 0; k < 255 && x + 32 <= n; ++k, x += 32) {
      V32u8 e;
      std::memcpy(&e, p + x, 32);
      acc -= reinterpret_cast<V32u8>(e == vb);  // a match is 0xff: -(-1) = +1
    }
    int sum = 0;
    for (int i = 0; i < 32; ++i) sum += acc[i];
    total += sum;
  }
  for (; x < n; ++x) total += p[x] == b;
  return total;
}

/// The valid pixels of a row (accepted or filled), counted; the confidence of every rejected
/// pixel (not filled) set to 0.
ES_KERNEL int64_t countValidZeroRejected(const uint8_t* __restrict cd, float* __restrict cf,
                                         int n) {
  int c = 0;
  for (int x = 0; x < n; ++x) {
    const bool filled = cd[x] == kCodeFilled;
    const bool rejected = (cd[x] < kNumRejectCodes) & !filled;
    cf[x] = rejected ? 0.f : cf[x];
    c += (cd[x] >= kCodeAcceptedBase) | filled;
  }
  return c;
}

// Sets the count only when it differs from the current one. With OpenCV's TBB backend every
// cv::setNumThreads() replaces the task arena, and the parallel_for_ calls of a compute() that
// follows one run almost entirely on the calling thread: setting the same count before and after
// every compute() (num_threads = the process's count) left a 2-thread run on one core (perf:
// 99% of the samples on the calling thread, 60% without the two calls). A count that differs
// from the process's still costs that (the documented set-and-restore).
class ThreadCountGuard {
 public:
  explicit ThreadCountGuard(int n) : old_(cv::getNumThreads()), active_(n > 0 && n != old_) {
    if (active_) cv::setNumThreads(n);
  }
  ~ThreadCountGuard() {
    if (active_) cv::setNumThreads(old_);
  }

 private:
  int old_;
  bool active_;
};

using Clock = std::chrono::steady_clock;

double millisecondsBetween(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

/// Window sizes of the growth sequence w_min, w_min + dw, ..., w_max.
int numWindowSizes(const MatcherParams& mp) {
  return (mp.window_max_px - mp.window_min_px) / mp.window_step_px + 1;
}

int numRowBlocks(int H) { return (H + kStripeRows - 1) / kStripeRows; }

// Whole-image loops run over fixed blocks of rows in parallel; counts are summed per block
// and then over blocks (integers: the totals do not depend on the split).
void forRowBlocks(int H, const std::function<void(int, int, int)>& fn) {
  const int num_blocks = numRowBlocks(H);
  cv::parallel_for_(
      cv::Range(0, num_blocks),
      [&](const cv::Range& rg) {
        for (int b = rg.start; b < rg.end; ++b) {
          fn(b, b * kStripeRows, std::min(H, (b + 1) * kStripeRows));
        }
      },
      num_blocks);
}

/// @throws std::invalid_argument on empty input, type or size mismatch (message names it).
void checkInputs(const cv::Mat& left, const cv::Mat& right, const SearchRange* range) {
  if (left.empty()) throw std::invalid_argument("RobustMatcher::compute: left image is empty");
  if (right.empty()) throw std::invalid_argument("RobustMatcher::compute: right image is empty");
  if (left.type() != CV_8UC1) {
    throw std::invalid_argument("RobustMatcher::compute: left image must be CV_8UC1 (gray)");
  }
  if (right.type() != CV_8UC1) {
    throw std::invalid_argument("RobustMatcher::compute: right image must be CV_8UC1 (gray)");
  }
  if (left.size() != right.size()) {
    throw std::invalid_argument("RobustMatcher::compute: left and right image sizes differ");
  }
  if (range && !range->empty()) {
    if (range->lo.type() != CV_16SC1 || range->hi.type() != CV_16SC1) {
      throw std::invalid_argument("RobustMatcher::compute: range.lo and range.hi must be CV_16SC1");
    }
    if (range->lo.size() != left.size() || range->hi.size() != left.size()) {
      throw std::invalid_argument(
          "RobustMatcher::compute: range.lo and range.hi must have the image size");
    }
  }
}

/// The outputs and the per-pixel state sized W x H and reset (nothing searched yet), the stats
/// cleared.
void resetOutputs(int W, int H, MatchResult& out, cv::Mat& state, cv::Mat& window_idx) {
  out.disparity.create(H, W, CV_32FC1);
  out.code.create(H, W, CV_8UC1);
  out.confidence.create(H, W, CV_32FC1);
  state.create(H, W, CV_8UC1);
  window_idx.create(H, W, CV_8UC1);
  forRowBlocks(H, [&](int, int y0, int y1) {
    const cv::Range rows(y0, y1);
    out.disparity.rowRange(rows).setTo(std::numeric_limits<float>::quiet_NaN());
    out.code.rowRange(rows).setTo(kCodeNotSearched);
    out.confidence.rowRange(rows).setTo(0.f);
    state.rowRange(rows).setTo(0);
    window_idx.rowRange(rows).setTo(0);
  });
  out.stats = MatchStats{};
  out.stats.total_pixels = static_cast<int64_t>(W) * H;
}

/// The left view as value - 128, converted straight into its padded buffer (lf is a view of it):
/// only the padding columns are cleared, and no second copy is written. Then its Laplacian and
/// the integral images.
void prepareLeftView(const cv::Mat& left, int pad_w, detail::FrameData& im) {
  const int W = left.cols, H = left.rows;
  im.lf_pad.create(H, im.l_pad + W + pad_w, CV_32F);
  if (im.l_pad > 0) im.lf_pad.colRange(0, im.l_pad).setTo(0.f);
  im.lf_pad.colRange(im.l_pad + W, im.lf_pad.cols).setTo(0.f);
  im.lf = im.lf_pad(cv::Rect(im.l_pad, 0, W, H));
  left.convertTo(im.lf, CV_32F, 1.0, -128.0);
  cv::Laplacian(left, im.lap_l, CV_16S, 1);
  detail::wrappedIntegrals(left, im.lap_l, im.int_l, im.sq_l, im.int_lap_l, im.sq_lap_l);
}

/// The right view as value - 128, mirrored into its padded buffer; then its Laplacian and the
/// integral images.
void prepareRightView(const cv::Mat& right, int pad_w, detail::FrameData& im) {
  const int W = right.cols, H = right.rows;
  right.convertTo(im.rf, CV_32F, 1.0, -128.0);
  im.rf_rev.create(H, im.rev_pad + W + pad_w, CV_32F);
  if (im.rev_pad > 0) im.rf_rev.colRange(0, im.rev_pad).setTo(0.f);
  im.rf_rev.colRange(im.rev_pad + W, im.rf_rev.cols).setTo(0.f);
  cv::flip(im.rf, im.rf_rev(cv::Rect(im.rev_pad, 0, W, H)), 1);
  cv::Laplacian(right, im.lap_r, CV_16S, 1);
  detail::wrappedIntegrals(right, im.lap_r, im.int_r, im.sq_r, im.int_lap_r, im.sq_lap_r);
}

// The two views are prepared in parallel (two fixed tasks: the result does not depend on the
// thread count). Intensities as value - 128 (float, exact products); the right view mirrored
// and padded so that every disparity of the range can be read for every column (sparse and
// dense engines), the left view padded for the right-indexed column sums (the padding is
// zero; those disparities are outside the ranges); integral images of the views, of their
// squares, of the 3x3 Laplacian and of its square (window statistics and structure).
void prepareViews(const MatcherParams& mp, const cv::Mat& left, const cv::Mat& right,
                  detail::FrameData& im) {
  im.rev_pad = std::max(0, -mp.min_disparity);
  im.l_pad = std::max(0, -mp.min_disparity);
  const int nd = mp.max_disparity - mp.min_disparity + 1;
  const int dpad = (nd + 7) / 8 * 8;
  const int pad_w = std::max(0, mp.min_disparity + dpad) + 8;
  cv::parallel_for_(
      cv::Range(0, 2),
      [&](const cv::Range& views) {
        for (int v = views.start; v < views.end; ++v) {
          if (v == 0) {
            prepareLeftView(left, pad_w, im);
          } else {
            prepareRightView(right, pad_w, im);
          }
        }
      },
      2);
}

/// Rows [y0, y1) of the requested ranges clamped to [dmin, dmax] into @p range_lo / @p range_hi;
/// returns how many of their pixels have a range narrower than [dmin, dmax] (and not empty).
/// The sizes and bounds come as values (locals, not references) so that the stores cannot alias
/// them: vectorises.
int64_t clampRangeRows(const SearchRange& range, int y0, int y1, int w, int dmin, int dmax,
                       cv::Mat& range_lo, cv::Mat& range_hi) {
  int64_t n = 0;
  for (int y = y0; y < y1; ++y) {
    const int16_t* __restrict lo = range.lo.ptr<int16_t>(y);
    const int16_t* __restrict hi = range.hi.ptr<int16_t>(y);
    int* __restrict olo = range_lo.ptr<int>(y);
    int* __restrict ohi = range_hi.ptr<int>(y);
    int row_n = 0;
    for (int x = 0; x < w; ++x) {
      const int l = std::max<int>(lo[x], dmin), h = std::min<int>(hi[x], dmax);
      olo[x] = l;
      ohi[x] = h;
      row_n += (lo[x] <= hi[x]) & (l <= h) & ((l > dmin) | (h < dmax));
    }
    n += row_n;
  }
  return n;
}

/// The search ranges: @p range clamped per pixel (returns the pixels whose range it narrows), or,
/// without one, [dmin, dmax] in one row that every row shares (returns 0).
int64_t setSearchRanges(const MatcherParams& mp, const SearchRange* range, int W, int H,
                        detail::FrameData& im) {
  if (!range || range->empty()) {
    im.range_lo.create(1, W, CV_32S);
    im.range_hi.create(1, W, CV_32S);
    im.range_lo.setTo(mp.min_disparity);
    im.range_hi.setTo(mp.max_disparity);
    return 0;
  }
  im.range_lo.create(H, W, CV_32S);
  im.range_hi.create(H, W, CV_32S);
  std::vector<int64_t> block_prior(numRowBlocks(H), 0);
  forRowBlocks(H, [&](int b, int y0, int y1) {
    block_prior[b] = clampRangeRows(*range, y0, y1, W, mp.min_disparity, mp.max_disparity,
                                    im.range_lo, im.range_hi);
  });
  int64_t prior_pixels = 0;
  for (const int64_t n : block_prior) prior_pixels += n;
  return prior_pixels;
}

/// Per block: the pixels accepted at each of the first @p n_levels window sizes.
void countAcceptedPerWindow(const cv::Mat& code, int n_levels,
                            std::vector<MatchStats>& block_stats) {
  const int W = code.cols;
  forRowBlocks(code.rows, [&](int b, int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      const uint8_t* cd = code.ptr<uint8_t>(y);
      for (int l = 0; l < n_levels; ++l) {
        block_stats[b].accepted_per_window[l] += countEqual(cd, W, kCodeAcceptedBase + l);
      }
    }
  });
}

// A filled pixel gets the lowest confidence of the measured neighbours it was filled from
// (reads accepted pixels' confidence only, writes filled pixels' only: blocks are independent).
void setFilledConfidence(const cv::Mat& code, const cv::Mat& code_before, cv::Mat& confidence) {
  forRowBlocks(code.rows, [&](int, int y0, int y1) {
    setFilledConfidenceRows(code, code_before, confidence, y0, y1);
  });
}

/// The post-filters (post_filter.cpp): isolated outliers removed, small holes filled (with the
/// codes before filling kept in @p code_before for the filled pixels' confidence).
void applyPostFilters(const PostFilterParams& fp, MatchResult& out, cv::Mat& code_before) {
  if (fp.remove_outliers) removeIsolatedOutliers(out.disparity, out.code, fp);
  if (fp.fill_holes) {
    out.code.copyTo(code_before);
    fillSmallHoles(out.disparity, out.code, fp);
    setFilledConfidence(out.code, code_before, out.confidence);
  }
}

/// Per block: rejections per criterion and valid pixels; the confidence of rejected pixels set
/// to 0.
void countRejectedAndValid(MatchResult& out, std::vector<MatchStats>& block_stats) {
  const int W = out.code.cols;
  forRowBlocks(out.code.rows, [&](int b, int y0, int y1) {
    MatchStats& st = block_stats[b];
    for (int y = y0; y < y1; ++y) {
      const uint8_t* cd = out.code.ptr<uint8_t>(y);
      for (int i = 0; i < kNumRejectCodes; ++i) st.rejected[i] += countEqual(cd, W, i);
      st.valid_pixels += countValidZeroRejected(cd, out.confidence.ptr<float>(y), W);
    }
  });
}

/// The blocks' counts summed into @p stats.
void addBlockStats(const std::vector<MatchStats>& block_stats, MatchStats& stats) {
  for (const MatchStats& st : block_stats) {
    for (size_t i = 0; i < st.rejected.size(); ++i) stats.rejected[i] += st.rejected[i];
    for (size_t i = 0; i < st.accepted_per_window.size(); ++i) {
      stats.accepted_per_window[i] += st.accepted_per_window[i];
    }
    stats.valid_pixels += st.valid_pixels;
  }
}

}  // namespace

std::vector<detail::WindowLevel> RobustMatcher::Impl::windowLevels(const MatcherParams& mp,
                                                                   bool uniform, int W, int H,
                                                                   MatchResult& out) {
  const int num_levels = numWindowSizes(mp);
  open_rows.resize(H);
  open_level.assign(H, -1);
  n_req_rows.assign(H, 0);
  std::vector<detail::WindowLevel> levels;
  for (int level = 0; level < num_levels; ++level) {
    const int w = mp.window_min_px + level * mp.window_step_px;
    if (w > W || w > H) break;
    levels.push_back(detail::WindowLevel{&mp, this, uniform, level, w, w / 2, W, H,
                                         mp.min_disparity, mp.max_disparity, &state, &window_idx,
                                         &open_rows, &open_level, &n_req_rows, &out});
  }
  return levels;
}

// A row's window sizes depend only on that row (its open pixels, its requested ranges and the
// images), so each stripe runs through all window sizes on its own: no barrier between window
// sizes, and the stripes' uneven costs (highlights and instrument edges need the larger
// windows) even out over the whole frame. Same rows, same order per row: same output.
void RobustMatcher::Impl::matchStripes(const MatcherParams& mp,
                                       const std::vector<detail::WindowLevel>& levels, int W,
                                       int H) {
  const int nd = mp.max_disparity - mp.min_disparity + 1;
  const int num_stripes = (H + kStripeRows - 1) / kStripeRows;
  cv::parallel_for_(
      cv::Range(0, num_stripes),
      [&](const cv::Range& rg) {
        std::unique_ptr<detail::WorkerScratch> s = acquire();
        s->ensure(W, nd);
        for (int stripe = rg.start; stripe < rg.end; ++stripe) {
          const int y_end = std::min(H, (stripe + 1) * kStripeRows);
          for (const detail::WindowLevel& c : levels) {
            s->resetSums();
            for (int y = stripe * kStripeRows; y < y_end; ++y) detail::matchRow(c, y, *s);
          }
        }
        release(std::move(s));
      },
      num_stripes);
}

// The matcher's steps in order (docs/method.md, sections 2, 5.1 and 3). The stats' times:
// prepare_ms (buffers, views, ranges), edge_ms (the depth-edge filter), match_ms (from the start
// through the depth-edge filter), filter_ms (the post-filters and the counters).
void RobustMatcher::compute(const cv::Mat& left, const cv::Mat& right, MatchResult& out,
                            const SearchRange* range) {
  checkInputs(left, right, range);
  const auto t0 = Clock::now();
  const MatcherParams& mp = matcher_params_;
  Impl& im = *impl_;
  ThreadCountGuard thread_guard(mp.num_threads);
  const int W = left.cols, H = left.rows;
  const bool uniform = !(range && !range->empty());

  resetOutputs(W, H, out, im.state, im.window_idx);
  prepareViews(mp, left, right, im);
  out.stats.prior_pixels = setSearchRanges(mp, range, W, H, im);
  const auto t_prepared = Clock::now();

  const std::vector<detail::WindowLevel> levels = im.windowLevels(mp, uniform, W, H, out);
  im.matchStripes(mp, levels, W, H);
  const auto t_matched = Clock::now();

  if (mp.edge_disparity_jump_px > 0.0) {
    rejectEdgeStraddlers(mp, left, right, numWindowSizes(mp), im.window_idx, out, im.edge_lo_src,
                         im.edge_hi_src, im.edge_lo, im.edge_hi, im.edge_cache);
  }
  const auto t1 = Clock::now();

  // Per block: accepted per window size (before the post-filters), then rejections and valid
  // pixels (after); summed over blocks.
  std::vector<MatchStats> block_stats(numRowBlocks(H));
  countAcceptedPerWindow(out.code, static_cast<int>(levels.size()), block_stats);
  applyPostFilters(filter_params_, out, im.code_before);
  countRejectedAndValid(out, block_stats);
  addBlockStats(block_stats, out.stats);
  const auto t2 = Clock::now();

  out.stats.match_ms = millisecondsBetween(t0, t1);
  out.stats.filter_ms = millisecondsBetween(t1, t2);
  out.stats.prepare_ms = millisecondsBetween(t0, t_prepared);
  out.stats.edge_ms = millisecondsBetween(t_matched, t1);
}

}  // namespace endo_stereo
