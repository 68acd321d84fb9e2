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

/// Patch centres whose whole search (+-kPatchMaxDy rows, the disparity range's columns) stays
/// inside the image: rows y_lo .. y_hi, columns x_lo .. x_hi.
struct PatchCentres {
  int y_lo, y_hi, x_lo, x_hi;
  bool empty() const { return y_lo > y_hi || x_lo > x_hi; }
};

PatchCentres patchCentres(int W, int H) {
  const int h = kPatchHalf, V = kPatchMaxDy;
  return PatchCentres{h + V, H - 1 - h - V, h + 1, W - 2 - h};
}

// The squared central differences in x and in y, once per pixel, into gx2 and gy2 (zeroed by
// the caller; exact integers; rows 0 and H - 1 and the border columns stay unused).
void squaredDifferences(const cv::Mat& left_gray, cv::Mat& gx2, cv::Mat& gy2) {
  const int W = left_gray.cols, H = left_gray.rows;
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
}

// Structure of every candidate centre: the patch sums of the squared central differences in x
// and in y (column sums, then a running sum along the row); the score is the smaller mean. A
// patch is usable when both are large: texture in y fixes the vertical offset, texture in x the
// disparity.
cv::Mat structureScores(const cv::Mat& left_gray, const PatchCentres& c) {
  const int W = left_gray.cols, H = left_gray.rows;
  const int h = kPatchHalf, n = kPatchSide * kPatchSide;
  cv::Mat gx2(H, W, CV_32F, cv::Scalar(0.f)), gy2(H, W, CV_32F, cv::Scalar(0.f));
  squaredDifferences(left_gray, gx2, gy2);
  const int cw = W - 2;  // columns 1 .. W - 2 have central differences
  std::vector<double> gx_col(size_t(cw), 0.0), gy_col(size_t(cw), 0.0);
  cv::Mat score(H, W, CV_32F, cv::Scalar(0.f));
  for (int y = c.y_lo - h; y <= c.y_hi + h; ++y) {
    const float* gx = gx2.ptr<float>(y);
    const float* gy = gy2.ptr<float>(y);
    for (int x = 1; x < W - 1; ++x) {
      gx_col[size_t(x - 1)] += gx[x];
      gy_col[size_t(x - 1)] += gy[x];
    }
    const int yo = y - 2 * h - 1;  // the row that leaves the column window
    if (yo >= c.y_lo - h) {
      const float* ox = gx2.ptr<float>(yo);
      const float* oy = gy2.ptr<float>(yo);
      for (int x = 1; x < W - 1; ++x) {
        gx_col[size_t(x - 1)] -= ox[x];
        gy_col[size_t(x - 1)] -= oy[x];
      }
    }
    const int yc = y - h;  // the centre row whose window is complete
    if (yc < c.y_lo) continue;
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
  return score;
}

/// The best-structured centre of the grid cell whose top-left centre is (cx, cy), when one
/// scores above kPatchMinGradSq.
bool bestCentreOfCell(const cv::Mat& score, const PatchCentres& c, int cx, int cy, int cell,
                      int* bx, int* by) {
  *bx = *by = -1;
  float best_score = float(kPatchMinGradSq);
  for (int y = cy; y <= std::min(c.y_hi, cy + cell - 1); ++y) {
    const float* sc = score.ptr<float>(y);
    for (int x = cx; x <= std::min(c.x_hi, cx + cell - 1); ++x) {
      if (sc[x] > best_score) {
        best_score = sc[x];
        *bx = x;
        *by = y;
      }
    }
  }
  return *bx >= 0;
}

/// The buffers of the patch searches, kept from one patch to the next: the zero-mean left patch,
/// the ZNCC table, the band of right pixels a patch is searched in, and one offset's sums for
/// every disparity (patchSums), in whole vectors.
struct PatchSearch {
  int min_disparity, max_disparity;
  int band_rows, band_stride;
  std::vector<float> lp, ncc, band, cross, rs, rs2;

  PatchSearch(int min_d, int max_d) : min_disparity(min_d), max_disparity(max_d) {
    const int nd_pad = (std::max(0, max_d - min_d + 1) + 7) / 8 * 8;
    band_rows = 2 * (kPatchMaxDy + kPatchHalf) + 1;
    band_stride = nd_pad + 2 * kPatchHalf + 8;
    lp.assign(size_t(kPatchSide * kPatchSide), 0.f);
    band.resize(static_cast<size_t>(band_rows) * band_stride);
    cross.resize(static_cast<size_t>(nd_pad));
    rs = cross;
    rs2 = cross;
  }
};

/// The left patch centred on (bx, by), zero-mean, into s.lp; @return its squared norm.
double zeroMeanLeftPatch(const cv::Mat& left_gray, int bx, int by, PatchSearch& s) {
  const int h = kPatchHalf, n = kPatchSide * kPatchSide;
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
      s.lp[size_t(k)] = float(r[bx + dx]) - lmean;
      lnorm2 += double(s.lp[size_t(k)]) * s.lp[size_t(k)];
    }
  }
  return lnorm2;
}

// ZNCC of the left patch (s.lp, squared norm lnorm2) over every vertical offset and the nd
// disparities d_hi - nd + 1 .. d_hi, into s.ncc (row v + V, column d - d_lo). The right patches
// of all of them lie in one band of rows and columns, widened to floats once: rows
// by - V - h .. by + V + h, columns from bx - d_hi - h, the patch at column bx - d_hi first
// (j = d_hi - d).
void patchNccTable(const cv::Mat& right_gray, int bx, int by, int d_hi, int nd, double lnorm2,
                   PatchSearch& s) {
  const int h = kPatchHalf, V = kPatchMaxDy, n = kPatchSide * kPatchSide;
  const int blocks = (nd + 7) / 8;
  for (int y = 0; y < s.band_rows; ++y) {
    const uint8_t* src = right_gray.ptr<uint8_t>(by - V - h + y) + (bx - d_hi - h);
    float* dst = s.band.data() + size_t(y) * s.band_stride;
    for (int x = 0; x < nd + 2 * h; ++x) dst[x] = src[x];
    std::fill(dst + nd + 2 * h, dst + s.band_stride, 0.f);
  }
  s.ncc.assign(size_t((2 * V + 1) * nd), -1.f);
  for (int v = -V; v <= V; ++v) {
    patchSums(s.band.data() + size_t(v + V) * s.band_stride, s.band_stride, s.lp.data(), blocks,
              s.cross.data(), s.rs.data(), s.rs2.data());
    for (int j = 0; j < nd; ++j) {
      const double var = double(s.rs2[size_t(j)]) - double(s.rs[size_t(j)]) * s.rs[size_t(j)] / n;
      s.ncc[size_t((v + V) * nd + (nd - 1 - j))] =
          var > 0.0 ? float(s.cross[size_t(j)] / std::sqrt(lnorm2 * var)) : -1.f;
    }
  }
}

/// The peak of a ZNCC table (2 kPatchMaxDy + 1 rows of nd): its score, row bv and column bd,
/// and the best score 3 or more disparities away from it (any offset).
struct NccPeak {
  float best = -2.f, other = -1.f;
  int bv = 0, bd = 0;
};

NccPeak nccPeak(const std::vector<float>& ncc, int nd) {
  const int V = kPatchMaxDy;
  NccPeak p;
  for (int v = 0; v < 2 * V + 1; ++v) {
    for (int d = 0; d < nd; ++d) {
      if (ncc[size_t(v * nd + d)] > p.best) {
        p.best = ncc[size_t(v * nd + d)];
        p.bv = v;
        p.bd = d;
      }
    }
  }
  for (int v = 0; v < 2 * V + 1; ++v) {
    for (int d = 0; d < nd; ++d) {
      if (std::abs(d - p.bd) >= 3) p.other = std::max(p.other, ncc[size_t(v * nd + d)]);
    }
  }
  return p;
}

/// The vertical offset of a peak, px: its row, refined by a parabola through the rows above and
/// below when both exist and it curves down (by at most half a row).
double subpixelOffset(const std::vector<float>& ncc, int nd, const NccPeak& p) {
  const int V = kPatchMaxDy;
  double off = double(p.bv - V);
  if (p.bv > 0 && p.bv < 2 * V) {
    const double a = ncc[size_t((p.bv - 1) * nd + p.bd)], b = p.best,
                 c = ncc[size_t((p.bv + 1) * nd + p.bd)];
    const double den = a - 2.0 * b + c;
    if (den < 0.0) off += std::clamp(0.5 * (a - c) / den, -0.5, 0.5);
  }
  return off;
}

/// Searches the right image for the left patch centred on (bx, by); @return true with
/// @p match = (right x, y, signed vertical offset) for a reliable match.
bool matchPatch(const cv::Mat& left_gray, const cv::Mat& right_gray, int bx, int by, PatchSearch& s,
                cv::Vec3d* match) {
  const int W = left_gray.cols, h = kPatchHalf;
  // Disparities whose right patch lies inside the image.
  const int d_lo = std::max(s.min_disparity, bx - (W - 1 - h));
  const int d_hi = std::min(s.max_disparity, bx - h);
  const int nd = d_hi - d_lo + 1;
  if (nd < 3) return false;
  const double lnorm2 = zeroMeanLeftPatch(left_gray, bx, by, s);
  if (!(lnorm2 > 0.0)) return false;
  patchNccTable(right_gray, bx, by, d_hi, nd, lnorm2, s);
  const NccPeak p = nccPeak(s.ncc, nd);
  if (p.best < kPatchMinNcc || p.best - p.other < kPatchMinGap) return false;
  if (p.bd == 0 || p.bd == nd - 1) return false;  // the disparity range cuts the peak
  *match = cv::Vec3d(double(bx - (d_lo + p.bd)), double(by), subpixelOffset(s.ncc, nd, p));
  return true;
}

/// One patch per cell of a grid (about max_patches cells; 0: one per 16 x 16 px): the
/// best-structured centre of the cell, searched in the right image. Appends the reliable
/// matches to @p matches; @return the number of cells with a textured patch.
int matchGridPatches(const cv::Mat& left_gray, const cv::Mat& right_gray, const cv::Mat& score,
                     const PatchCentres& c, int min_disparity, int max_disparity, int max_patches,
                     std::vector<cv::Vec3d>* matches) {
  const int W = left_gray.cols, H = left_gray.rows;
  const int target = max_patches > 0 ? max_patches : (W * H) / (16 * 16);
  const int cell = std::max(16, int(std::sqrt(double(W) * H / std::max(1, target))));
  int textured = 0;  // cells with a textured patch
  PatchSearch search(min_disparity, max_disparity);
  for (int cy = c.y_lo; cy <= c.y_hi; cy += cell) {
    for (int cx = c.x_lo; cx <= c.x_hi; cx += cell) {
      int bx, by;
      if (!bestCentreOfCell(score, c, cx, cy, cell, &bx, &by)) continue;
      ++textured;
      cv::Vec3d m;
      if (matchPatch(left_gray, right_gray, bx, by, search, &m)) matches->push_back(m);
    }
  }
  return textured;
}

/// The message of a measurement with too few reliable matches; sets @p misaligned when most
/// textured patches found nothing.
std::string tooFewMatchesMessage(size_t matches, int textured, int min_disparity, int max_disparity,
                                 bool* misaligned) {
  std::ostringstream m;
  m << "too few reliable patch matches to measure the rectification (" << matches << " of "
    << textured << " textured patches";
  if (textured >= 32 && int(matches) * 4 < textured) {
    // Most textured patches found nothing within +-8 px rows and the disparity range: warn,
    // as for a large offset.
    m << "; rows misaligned by more than " << kPatchMaxDy
      << " px, views that differ, or disparities outside [" << min_disparity << ", "
      << max_disparity << "]";
    *misaligned = true;
  }
  m << ")";
  return m.str();
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

namespace {

/// The figures of a measurement from its matches: the |offset| statistics and the row offset
/// model (fitRowOffset).
void recordOffsets(const std::vector<cv::Vec3d>& matches, RectificationQuality& q) {
  q.num_matches = int(matches.size());
  std::vector<double> offsets(matches.size());
  for (size_t i = 0; i < matches.size(); ++i) offsets[i] = std::abs(matches[i][2]);
  detail::offsetStatistics(offsets, &q.median_offset_px, &q.p90_offset_px);
  q.row_offset_matches = fitRowOffset(matches, &q.row_offset);
  q.valid = true;
}

}  // namespace

RectificationQuality measureRowAlignmentPatches(const cv::Mat& left_gray, const cv::Mat& right_gray,
                                                int min_disparity, int max_disparity,
                                                int max_patches) {
  RectificationQuality q;
  if (left_gray.type() != CV_8UC1 || right_gray.type() != CV_8UC1 ||
      left_gray.size() != right_gray.size() || min_disparity > max_disparity) {
    q.message = "row alignment: needs two CV_8UC1 images of one size and min <= max disparity";
    return q;
  }
  const PatchCentres centres = patchCentres(left_gray.cols, left_gray.rows);
  if (centres.empty()) {
    q.message = "row alignment: images too small to measure";
    return q;
  }
  const cv::Mat score = structureScores(left_gray, centres);
  std::vector<cv::Vec3d> matches;  // per reliable patch: right x, y, signed vertical offset
  const int textured = matchGridPatches(left_gray, right_gray, score, centres, min_disparity,
                                        max_disparity, max_patches, &matches);
  if (matches.size() < 8) {
    q.message = tooFewMatchesMessage(matches.size(), textured, min_disparity, max_disparity,
                                     &q.misaligned);
    return q;
  }
  recordOffsets(matches, q);
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
