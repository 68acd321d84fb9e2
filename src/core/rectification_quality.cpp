// The rectification quality measure: the median vertical offset between the rectified views,
// from SIFT matches (measureRowAlignment, uncalibrated mode) or from ZNCC patch matches on a grid
// (measureRowAlignmentPatches, calibrated and pass-through modes). StereoRectifier
// (rectification.cpp) runs it every quality_stride frames, inline or on a background thread.

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "endo_stereo/core/rectification.hpp"
#include "simd.hpp"
#include "uncalibrated_rectification.hpp"

namespace endo_stereo {

RectificationQuality measureRowAlignment(const cv::Mat& left_gray, const cv::Mat& right_gray,
                                         int max_features, double ratio_test,
                                         double ransac_threshold_px) {
  RectificationQuality q;
  detail::Matches m, inl;
  detail::siftMatches(left_gray, right_gray, max_features, ratio_test, &m);
  cv::Matx33d F;
  if (!detail::robustFundamental(m, ransac_threshold_px, 0.999, &F, &inl)) {
    q.message =
        "too few feature matches to measure the rectification (" + std::to_string(m.size()) + ")";
    return q;
  }
  std::vector<double> dy(inl.size());
  for (size_t i = 0; i < inl.size(); ++i) dy[i] = std::abs(inl.left[i].y - inl.right[i].y);
  detail::offsetStatistics(dy, &q.median_offset_px, &q.p90_offset_px);
  q.num_matches = int(inl.size());
  q.valid = true;
  return q;
}

// Patch measure (calibrated and pass-through modes). Plain loops only, no cv::parallel_for_ and
// no OpenCV call that may use it: OpenCV's parallel_for_ runs serially whenever another thread
// is inside one (a process-wide flag), so a measurement on a background thread that used it
// would turn the matcher's parallel loops serial for as long as it ran.
namespace {

constexpr int kPatchHalf = 5;            // 11 x 11 patches
constexpr int kPatchMaxDy = 8;           // vertical search +-8 px; larger offsets read as 8
constexpr float kPatchMinNcc = 0.8f;     // least ZNCC of a used match
constexpr float kPatchMinGap = 0.05f;    // over the best match 3 or more disparities away
constexpr double kPatchMinGradSq = 9.0;  // least mean squared gradient, both directions
constexpr int kPatchSide = 2 * kPatchHalf + 1;

// The sums a ZNCC needs for right patches side by side: band holds kPatchSide rows of pixel
// values (as floats, row stride `stride`), and the patch whose top-left pixel is band[j] gets
// s[j] = its pixel sum, s2[j] = its sum of squares and cross[j] = the sum over k of lp[k] times
// its pixel k (lp: the zero-mean left patch, row by row), for j < 8 * blocks (band is padded for
// whole vectors). The pixel sums are integers below 2^24, exact in float; cross is summed in the
// order of k, as a loop over one patch at a time would (the core builds with
// -ffp-contract=off), so no value depends on the vectors. Four vectors of patches at a time:
// independent chains of additions.
ES_KERNEL void patchSums(const float* band, int stride, const float* lp, int blocks, float* cross,
                         float* s, float* s2) {
  using namespace simd;
  constexpr int kGroup = 4;
  for (int b0 = 0; b0 < blocks; b0 += kGroup) {
    const int nb = std::min(kGroup, blocks - b0);
    V8f c[kGroup], a1[kGroup], a2[kGroup];
    for (int g = 0; g < kGroup; ++g) c[g] = a1[g] = a2[g] = splat8(0.f);
    for (int dy = 0, k = 0; dy < kPatchSide; ++dy) {
      const float* r = band + dy * stride + b0 * 8;
      for (int dx = 0; dx < kPatchSide; ++dx, ++k) {
        const V8f w = splat8(lp[k]);
        for (int g = 0; g < kGroup; ++g) {
          if (g < nb) {
            const V8f a = load8(r + dx + 8 * g);
            a1[g] += a;
            a2[g] += a * a;
            c[g] += w * a;
          }
        }
      }
    }
    for (int g = 0; g < nb; ++g) {
      store8(cross + (b0 + g) * 8, c[g]);
      store8(s + (b0 + g) * 8, a1[g]);
      store8(s2 + (b0 + g) * 8, a2[g]);
    }
  }
}

}  // namespace

int fitRowOffset(const std::vector<cv::Vec3d>& matches, cv::Vec3d* model) {
  *model = cv::Vec3d(0, 0, 0);
  if (matches.size() < 3) return 0;
  // Least squares for offset = c0 + c1 x + c2 y, twice: the second fit keeps the matches within
  // max(0.5 px, 3 x the median absolute residual) of the first (a patch on a specular highlight
  // or an instrument can match a wrong row). x and y centred and scaled for conditioning.
  double mx = 0, my = 0;
  for (const cv::Vec3d& m : matches) {
    mx += m[0];
    my += m[1];
  }
  mx /= double(matches.size());
  my /= double(matches.size());
  double s = 1.0;
  for (const cv::Vec3d& m : matches) s = std::max({s, std::abs(m[0] - mx), std::abs(m[1] - my)});
  std::vector<uint8_t> use(matches.size(), 1);
  cv::Vec3d c(0, 0, 0);  // in the centred, scaled coordinates
  int used = 0;
  for (int pass = 0; pass < 2; ++pass) {
    cv::Matx33d A = cv::Matx33d::zeros();
    cv::Vec3d b(0, 0, 0);
    used = 0;
    for (size_t i = 0; i < matches.size(); ++i) {
      if (!use[i]) continue;
      const cv::Vec3d r(1.0, (matches[i][0] - mx) / s, (matches[i][1] - my) / s);
      A += r * r.t();
      b += r * matches[i][2];
      ++used;
    }
    // A layout without spread in x or y (all matches on one line) leaves A singular: no fit.
    cv::Mat sol;
    if (used < 3 || !cv::solve(cv::Mat(A), cv::Mat(b), sol, cv::DECOMP_LU)) return 0;
    c = cv::Vec3d(sol.at<double>(0), sol.at<double>(1), sol.at<double>(2));
    if (pass == 1) break;
    std::vector<double> res(matches.size());
    for (size_t i = 0; i < matches.size(); ++i) {
      res[i] = std::abs(matches[i][2] - (c[0] + c[1] * (matches[i][0] - mx) / s +
                                         c[2] * (matches[i][1] - my) / s));
    }
    std::vector<double> sorted = res;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double keep = std::max(0.5, 3.0 * sorted[sorted.size() / 2]);
    for (size_t i = 0; i < matches.size(); ++i) use[i] = res[i] <= keep;
  }
  // Back to image coordinates: c0 + c1 (x - mx) / s + c2 (y - my) / s.
  *model = cv::Vec3d(c[0] - c[1] * mx / s - c[2] * my / s, c[1] / s, c[2] / s);
  return used;
}

RectificationQuality measureRowAlignmentPatches(const cv::Mat& left_gray, const cv::Mat& right_gray,
                                                int min_disparity, int max_disparity,
                                                int max_patches) {
  RectificationQuality q;
  if (left_gray.type() != CV_8UC1 || right_gray.type() != CV_8UC1 ||
      left_gray.size() != right_gray.size() || min_disparity > max_disparity) {
    q.message = "row alignment: needs two CV_8UC1 images of one size and min <= max disparity";
    return q;
  }
  const int W = left_gray.cols, H = left_gray.rows;
  const int h = kPatchHalf, V = kPatchMaxDy, n = (2 * h + 1) * (2 * h + 1);
  const int y_lo = h + V, y_hi = H - 1 - h - V;  // patch centres: the search stays inside
  const int x_lo = h + 1, x_hi = W - 2 - h;
  if (y_lo > y_hi || x_lo > x_hi) {
    q.message = "row alignment: images too small to measure";
    return q;
  }
  // Structure of every candidate centre: the patch sums of the squared central differences in x
  // and in y (column sums, then a running sum along the row). A patch is usable when both are
  // large: texture in y fixes the vertical offset, texture in x the disparity. The squared
  // differences once per pixel (exact integers; rows 0 and H - 1 and the border columns unused).
  cv::Mat gx2(H, W, CV_32F, cv::Scalar(0.f)), gy2(H, W, CV_32F, cv::Scalar(0.f));
  for (int y = 1; y < H - 1; ++y) {
    const uint8_t* up = left_gray.ptr<uint8_t>(y - 1);
    const uint8_t* row = left_gray.ptr<uint8_t>(y);
    const uint8_t* down = left_gray.ptr<uint8_t>(y + 1);
    float* gx = gx2.ptr<float>(y);
    float* gy = gy2.ptr<float>(y);
    for (int x = 1; x < W - 1; ++x) {
      const float dx = float(row[x + 1]) - float(row[x - 1]);
      const float dy = float(down[x]) - float(up[x]);
      gx[x] = dx * dx;
      gy[x] = dy * dy;
    }
  }
  const int cw = W - 2;  // columns 1 .. W - 2 have central differences
  std::vector<double> gx_col(size_t(cw), 0.0), gy_col(size_t(cw), 0.0);
  cv::Mat score(H, W, CV_32F, cv::Scalar(0.f));
  for (int y = y_lo - h; y <= y_hi + h; ++y) {
    const float* gx = gx2.ptr<float>(y);
    const float* gy = gy2.ptr<float>(y);
    for (int x = 1; x < W - 1; ++x) {
      gx_col[size_t(x - 1)] += gx[x];
      gy_col[size_t(x - 1)] += gy[x];
    }
    const int yo = y - 2 * h - 1;  // the row that leaves the column window
    if (yo >= y_lo - h) {
      const float* ox = gx2.ptr<float>(yo);
      const float* oy = gy2.ptr<float>(yo);
      for (int x = 1; x < W - 1; ++x) {
        gx_col[size_t(x - 1)] -= ox[x];
        gy_col[size_t(x - 1)] -= oy[x];
      }
    }
    const int yc = y - h;  // the centre row whose window is complete
    if (yc < y_lo) continue;
    float* sc = score.ptr<float>(yc);
    double sx = 0.0, sy = 0.0;
    for (int i = 0; i < 2 * h + 1; ++i) {
      sx += gx_col[size_t(i)];
      sy += gy_col[size_t(i)];
    }
    for (int x = 1 + h;; ++x) {  // window columns x - h .. x + h (difference columns 1 .. W - 2)
      sc[x] = float(std::min(sx, sy) / n);
      if (x + h + 1 > W - 2) break;
      sx += gx_col[size_t(x + h)] - gx_col[size_t(x - h - 1)];
      sy += gy_col[size_t(x + h)] - gy_col[size_t(x - h - 1)];
    }
  }

  // One patch per cell of a grid: the best-structured centre of the cell.
  const int target = max_patches > 0 ? max_patches : (W * H) / (16 * 16);
  const int cell = std::max(16, int(std::sqrt(double(W) * H / std::max(1, target))));
  std::vector<cv::Vec3d> matches;  // per reliable patch: right x, y, signed vertical offset
  int textured = 0;  // cells with a textured patch
  std::vector<float> lp(size_t(n), 0.f);
  std::vector<float> ncc;
  // The band of right pixels a patch is searched in, and one offset's sums for every disparity
  // (patchSums), in whole vectors.
  const int nd_pad = (std::max(0, max_disparity - min_disparity + 1) + 7) / 8 * 8;
  const int band_rows = 2 * (V + h) + 1, band_stride = nd_pad + 2 * h + 8;
  std::vector<float> band(static_cast<size_t>(band_rows) * band_stride);
  std::vector<float> cross(static_cast<size_t>(nd_pad)), rs(cross), rs2(cross);
  for (int cy = y_lo; cy <= y_hi; cy += cell) {
    for (int cx = x_lo; cx <= x_hi; cx += cell) {
      int bx = -1, by = -1;
      float best_score = float(kPatchMinGradSq);
      for (int y = cy; y <= std::min(y_hi, cy + cell - 1); ++y) {
        const float* sc = score.ptr<float>(y);
        for (int x = cx; x <= std::min(x_hi, cx + cell - 1); ++x) {
          if (sc[x] > best_score) {
            best_score = sc[x];
            bx = x;
            by = y;
          }
        }
      }
      if (bx < 0) continue;
      ++textured;
      // Disparities whose right patch lies inside the image.
      const int d_lo = std::max(min_disparity, bx - (W - 1 - h));
      const int d_hi = std::min(max_disparity, bx - h);
      const int nd = d_hi - d_lo + 1;
      if (nd < 3) continue;
      // The left patch, zero-mean, and its norm.
      double lsum = 0.0;
      for (int dy = -h; dy <= h; ++dy) {
        const uint8_t* r = left_gray.ptr<uint8_t>(by + dy);
        for (int dx = -h; dx <= h; ++dx) lsum += r[bx + dx];
      }
      const float lmean = float(lsum / n);
      double lnorm2 = 0.0;
      for (int dy = -h, k = 0; dy <= h; ++dy) {
        const uint8_t* r = left_gray.ptr<uint8_t>(by + dy);
        for (int dx = -h; dx <= h; ++dx, ++k) {
          lp[size_t(k)] = float(r[bx + dx]) - lmean;
          lnorm2 += double(lp[size_t(k)]) * lp[size_t(k)];
        }
      }
      if (!(lnorm2 > 0.0)) continue;
      // ZNCC over every vertical offset and disparity. The right patches of all of them lie in
      // one band of rows and columns, widened to floats once: rows by - V - h .. by + V + h,
      // columns from bx - d_hi - h, the patch at column bx - d_hi first (j = d_hi - d).
      const int blocks = (nd + 7) / 8;
      for (int y = 0; y < band_rows; ++y) {
        const uint8_t* src = right_gray.ptr<uint8_t>(by - V - h + y) + (bx - d_hi - h);
        float* dst = band.data() + size_t(y) * band_stride;
        for (int x = 0; x < nd + 2 * h; ++x) dst[x] = src[x];
        std::fill(dst + nd + 2 * h, dst + band_stride, 0.f);
      }
      ncc.assign(size_t((2 * V + 1) * nd), -1.f);
      for (int v = -V; v <= V; ++v) {
        patchSums(band.data() + size_t(v + V) * band_stride, band_stride, lp.data(), blocks,
                  cross.data(), rs.data(), rs2.data());
        for (int j = 0; j < nd; ++j) {
          const double var = double(rs2[size_t(j)]) - double(rs[size_t(j)]) * rs[size_t(j)] / n;
          ncc[size_t((v + V) * nd + (nd - 1 - j))] =
              var > 0.0 ? float(cross[size_t(j)] / std::sqrt(lnorm2 * var)) : -1.f;
        }
      }
      int bv = 0, bd = 0;
      float best = -2.f;
      for (int v = 0; v < 2 * V + 1; ++v) {
        for (int d = 0; d < nd; ++d) {
          if (ncc[size_t(v * nd + d)] > best) {
            best = ncc[size_t(v * nd + d)];
            bv = v;
            bd = d;
          }
        }
      }
      float other = -1.f;  // the best match 3 or more disparities away (any offset)
      for (int v = 0; v < 2 * V + 1; ++v) {
        for (int d = 0; d < nd; ++d) {
          if (std::abs(d - bd) >= 3) other = std::max(other, ncc[size_t(v * nd + d)]);
        }
      }
      if (best < kPatchMinNcc || best - other < kPatchMinGap) continue;
      if (bd == 0 || bd == nd - 1) continue;  // the disparity range cuts the peak
      double off = double(bv - V);
      if (bv > 0 && bv < 2 * V) {
        const double a = ncc[size_t((bv - 1) * nd + bd)], b = best,
                     c = ncc[size_t((bv + 1) * nd + bd)];
        const double den = a - 2.0 * b + c;
        if (den < 0.0) off += std::clamp(0.5 * (a - c) / den, -0.5, 0.5);
      }
      matches.push_back(cv::Vec3d(double(bx - (d_lo + bd)), double(by), off));
    }
  }
  if (matches.size() < 8) {
    std::ostringstream m;
    m << "too few reliable patch matches to measure the rectification (" << matches.size() << " of "
      << textured << " textured patches";
    if (textured >= 32 && int(matches.size()) * 4 < textured) {
      // Most textured patches found nothing within +-8 px rows and the disparity range: warn,
      // as for a large offset.
      m << "; rows misaligned by more than " << kPatchMaxDy
        << " px, views that differ, or disparities outside [" << min_disparity << ", "
        << max_disparity << "]";
      q.misaligned = true;
    }
    m << ")";
    q.message = m.str();
    return q;
  }
  q.num_matches = int(matches.size());
  std::vector<double> offsets(matches.size());
  for (size_t i = 0; i < matches.size(); ++i) offsets[i] = std::abs(matches[i][2]);
  detail::offsetStatistics(offsets, &q.median_offset_px, &q.p90_offset_px);
  q.row_offset_matches = fitRowOffset(matches, &q.row_offset);
  q.valid = true;
  return q;
}

void shiftRows(const cv::Mat& right, const cv::Vec3d& model, cv::Mat& out, cv::Mat& map_x,
               cv::Mat& map_y, cv::Vec3d& map_model, int interpolation) {
  if (map_x.size() != right.size() || map_y.size() != right.size() || map_model != model) {
    map_x.create(right.size(), CV_32F);
    map_y.create(right.size(), CV_32F);
    for (int y = 0; y < right.rows; ++y) {
      float* mx = map_x.ptr<float>(y);
      float* my = map_y.ptr<float>(y);
      for (int x = 0; x < right.cols; ++x) {
        mx[x] = float(x);
        my[x] = float(y + model[0] + model[1] * x + model[2] * y);
      }
    }
    map_model = model;
  }
  cv::remap(right, out, map_x, map_y, interpolation, cv::BORDER_REPLICATE);
}

}  // namespace endo_stereo
