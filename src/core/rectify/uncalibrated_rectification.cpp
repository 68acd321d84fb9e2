// Uncalibrated rectification: SIFT matching, robust F, and the two rectifications of the paper
// (Pollefeys, Koch, Van Gool 1999 polar; Hartley 1999 projective) plus PolarRectification's
// mappings. The per-frame state machine that uses them lives in rectification.cpp.
#include "uncalibrated_rectification.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <sstream>

namespace endo_stereo {
namespace detail {

namespace {

constexpr double kPi = 3.14159265358979323846;
/// Epipoles farther than this from the image centre are clamped (px): lines through a point
/// 1e9 px away deviate from the true (parallel) epipolar lines by < w*h/1e9 px, and double
/// precision keeps 1e-7 px at that distance.
constexpr double kFarEpipolePx = 1e9;

double wrapAngle(double a) {
  while (a > kPi) a -= 2 * kPi;
  while (a <= -kPi) a += 2 * kPi;
  return a;
}

cv::Matx33d cross(const cv::Vec3d& e) {
  return cv::Matx33d(0, -e[2], e[1], e[2], 0, -e[0], -e[1], e[0], 0);
}

/// A finite stand-in for a homogeneous epipole (clamped to kFarEpipolePx from the centre).
cv::Point2d finiteEpipole(const cv::Vec3d& e, const cv::Point2d& centre) {
  const double planar = std::hypot(e[0], e[1]);
  cv::Point2d dir(e[0], e[1]);
  if (planar > 0) dir *= 1.0 / planar;
  if (std::abs(e[2]) * kFarEpipolePx > planar) {
    const cv::Point2d p(e[0] / e[2], e[1] / e[2]);
    const cv::Point2d d = p - centre;
    const double n = std::hypot(d.x, d.y);
    if (n <= kFarEpipolePx) return p;
    return centre + d * (kFarEpipolePx / n);
  }
  // At (or numerically at) infinity: either side is the same projective point.
  const double sgn = e[2] < 0 ? -1.0 : 1.0;
  return centre + dir * (sgn * kFarEpipolePx);
}

bool insideImage(const cv::Point2d& p, const cv::Size& s) {
  return p.x >= 0 && p.y >= 0 && p.x <= s.width - 1 && p.y <= s.height - 1;
}

/// Parameter interval [r0, r1] (r >= 0) of the ray e + r u inside [0,w-1]x[0,h-1].
bool rayInterval(const cv::Point2d& e, const cv::Point2d& u, const cv::Size& s, double* r0,
                 double* r1) {
  double lo = 0.0, hi = std::numeric_limits<double>::infinity();
  const double mins[2] = {0.0, 0.0}, maxs[2] = {s.width - 1.0, s.height - 1.0};
  const double o[2] = {e.x, e.y}, d[2] = {u.x, u.y};
  for (int k = 0; k < 2; ++k) {
    if (std::abs(d[k]) < 1e-300) {
      if (o[k] < mins[k] || o[k] > maxs[k]) return false;
      continue;
    }
    double t0 = (mins[k] - o[k]) / d[k], t1 = (maxs[k] - o[k]) / d[k];
    if (t0 > t1) std::swap(t0, t1);
    lo = std::max(lo, t0);
    hi = std::min(hi, t1);
  }
  if (!(hi >= lo)) return false;
  *r0 = lo;
  *r1 = hi;
  return true;
}

/// Fractional index of value v in a monotonic array (increasing or decreasing); false outside.
bool fractionalIndex(const std::vector<double>& a, double v, double* idx) {
  const size_t n = a.size();
  if (n == 0) return false;
  if (n == 1) {
    if (v != a[0]) return false;
    *idx = 0;
    return true;
  }
  const bool inc = a.back() > a.front();
  const double lo = inc ? a.front() : a.back(), hi = inc ? a.back() : a.front();
  if (v < lo || v > hi) return false;
  size_t i;
  if (inc) {
    i = size_t(std::upper_bound(a.begin(), a.end(), v) - a.begin());
  } else {
    i = size_t(std::upper_bound(a.begin(), a.end(), v, std::greater<double>()) - a.begin());
  }
  if (i == 0) i = 1;
  if (i >= n) i = n - 1;
  const double a0 = a[i - 1], a1 = a[i];
  const double t = a1 != a0 ? (v - a0) / (a1 - a0) : 0.0;
  *idx = double(i - 1) + t;
  return true;
}

}  // namespace

void siftMatches(const cv::Mat& left, const cv::Mat& right, int max_features, double ratio,
                 Matches* out) {
  out->left.clear();
  out->right.clear();
  cv::Ptr<cv::SIFT> sift = cv::SIFT::create(max_features);
  std::vector<cv::KeyPoint> kl, kr;
  cv::Mat dl, dr;
  sift->detectAndCompute(left, cv::noArray(), kl, dl);
  sift->detectAndCompute(right, cv::noArray(), kr, dr);
  if (kl.size() < 2 || kr.size() < 2) return;
  cv::BFMatcher matcher(cv::NORM_L2);
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(dl, dr, knn, 2);
  // Uniqueness: a right keypoint claimed by two left keypoints is ambiguous; keep neither.
  std::vector<int> claims(kr.size(), 0);
  std::vector<const cv::DMatch*> kept;
  for (const auto& k : knn) {
    if (k.size() < 2) continue;
    if (k[0].distance < ratio * k[1].distance) {
      kept.push_back(&k[0]);
      ++claims[size_t(k[0].trainIdx)];
    }
  }
  for (const cv::DMatch* m : kept) {
    if (claims[size_t(m->trainIdx)] != 1) continue;
    out->left.emplace_back(kl[size_t(m->queryIdx)].pt);
    out->right.emplace_back(kr[size_t(m->trainIdx)].pt);
  }
}

bool robustFundamental(const Matches& m, double threshold_px, double confidence, cv::Matx33d* F,
                       Matches* inliers) {
  if (m.size() < 8) return false;
  std::vector<cv::Point2f> pl(m.left.begin(), m.left.end()), pr(m.right.begin(), m.right.end());
  std::vector<uchar> mask;
  cv::Mat f;
  try {
    f = cv::findFundamentalMat(pl, pr, cv::USAC_ACCURATE, threshold_px, confidence, 10000, mask);
  } catch (const std::exception&) {
    return false;
  }
  if (f.rows != 3 || f.cols != 3) return false;
  f.convertTo(f, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) (*F)(r, c) = f.at<double>(r, c);
  inliers->left.clear();
  inliers->right.clear();
  for (size_t i = 0; i < mask.size(); ++i) {
    if (!mask[i]) continue;
    inliers->left.push_back(m.left[i]);
    inliers->right.push_back(m.right[i]);
  }
  return inliers->size() >= 8;
}

double homographyShare(const Matches& m, double threshold_px) {
  if (m.size() < 4) return 1.0;
  std::vector<cv::Point2f> pl(m.left.begin(), m.left.end()), pr(m.right.begin(), m.right.end());
  std::vector<uchar> mask;
  try {
    const cv::Mat H = cv::findHomography(pl, pr, cv::RANSAC, threshold_px, mask, 2000, 0.999);
    if (H.empty()) return 0.0;
  } catch (const std::exception&) {
    return 0.0;
  }
  return double(cv::countNonZero(mask)) / double(m.size());
}

void epipoles(const cv::Matx33d& F, cv::Vec3d* e_left, cv::Vec3d* e_right) {
  cv::Mat w, u, vt;
  cv::SVD::compute(cv::Mat(F), w, u, vt, cv::SVD::FULL_UV);
  for (int i = 0; i < 3; ++i) {
    (*e_left)[i] = vt.at<double>(2, i);
    (*e_right)[i] = u.at<double>(i, 2);
  }
}

double epipoleDistance(const cv::Vec3d& e, const cv::Size& size) {
  const double diag = std::hypot(double(size.width), double(size.height));
  const double planar = std::hypot(e[0], e[1]);
  if (std::abs(e[2]) * 1e12 <= planar) return std::numeric_limits<double>::infinity();
  const double x = e[0] / e[2] - (size.width - 1) / 2.0;
  const double y = e[1] / e[2] - (size.height - 1) / 2.0;
  return std::hypot(x, y) / diag;
}

void offsetStatistics(std::vector<double> v, double* median, double* p90) {
  if (v.empty()) {
    *median = *p90 = 0.0;
    return;
  }
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + long(mid), v.end());
  *median = v[mid];
  const size_t k = std::min(v.size() - 1, size_t(std::ceil(0.9 * double(v.size()))) - 1);
  std::nth_element(v.begin(), v.begin() + long(k), v.end());
  *p90 = v[k];
}

// ---------------------------------------------------------------------------------------------
// Hartley 1999. Work in normalised coordinates (centre at 0, scale 1 / max(w, h)) so that the
// least-squares fit below weighs rotation and translation entries alike.
bool homographyRectification(const cv::Matx33d& F, const Matches& inliers, const cv::Size& size,
                             cv::Matx33d* H_left, cv::Matx33d* H_right, std::string* error) {
  const double cx = (size.width - 1) / 2.0, cy = (size.height - 1) / 2.0;
  const double s = 1.0 / std::max(size.width, size.height);
  const cv::Matx33d N(s, 0, -s * cx, 0, s, -s * cy, 0, 0, 1);
  const cv::Matx33d Ninv = N.inv();
  cv::Matx33d Fn = Ninv.t() * F * Ninv;
  Fn *= 1.0 / cv::norm(Fn);
  cv::Vec3d el, er;
  epipoles(Fn, &el, &er);
  er *= 1.0 / cv::norm(er);

  // Right image: rotate the epipole onto the x axis (by the smaller of the two rotations, so
  // the image is never turned upside down), then send it to infinity with G.
  const double planar = std::hypot(er[0], er[1]);
  const bool at_infinity = std::abs(er[2]) * 1e12 <= planar;
  const double px = at_infinity ? er[0] : er[0] / er[2];
  const double py = at_infinity ? er[1] : er[1] / er[2];
  double rot = -std::atan2(py, px);
  if (rot > kPi / 2) rot -= kPi;
  if (rot < -kPi / 2) rot += kPi;
  const cv::Matx33d Rz(std::cos(rot), -std::sin(rot), 0, std::sin(rot), std::cos(rot), 0, 0, 0, 1);
  cv::Matx33d G = cv::Matx33d::eye();
  if (!at_infinity) {
    const double f = std::cos(rot) * px - std::sin(rot) * py;
    if (std::abs(f) < 1.5) {
      // Within ~1.5 half-widths of the centre the image would cross the line at infinity.
      if (error) *error = "epipole too close to the image for a homography (use polar)";
      return false;
    }
    G(2, 0) = -1.0 / f;
  }
  const cv::Matx33d Hr = G * Rz;

  // Left image: any homography compatible with F is H_r (A + e' v^T) with A = -[e']x F, and
  // since H_r e' is the point at infinity along x, v changes only the x row of the result. Its
  // y and w rows come from F (that is what aligns the rows). Hartley fits the x row to minimise
  // disparity; we choose it instead so that the left warp has no shear at the image centre (its
  // Jacobian there is a rotation and scale), then shift it so that the median rectified
  // disparity of the inliers equals their median raw horizontal disparity: the left image is
  // warped like a camera rotation rather than sheared, and disparities keep their raw meaning
  // (positive, zero at infinity for a parallel rig).
  const cv::Matx33d A = -(cross(er) * Fn);
  cv::Matx33d Hl = Hr * A;
  {
    const double d = Hl(1, 0), e = Hl(1, 1), f = Hl(1, 2);
    const double g = Hl(2, 0), h = Hl(2, 1), i = Hl(2, 2);
    if (!(std::abs(i) > 1e-12)) {
      if (error) *error = "degenerate matching transform (image centre at infinity)";
      return false;
    }
    const double y0 = f / i;  // rectified y of the image centre (x0 = 0 with c = 0)
    Hl(0, 0) = e - y0 * h;
    Hl(0, 1) = -(d - y0 * g);
    Hl(0, 2) = 0.0;
    if (!(std::hypot(Hl(0, 0), Hl(0, 1)) > 1e-12)) {
      if (error) *error = "degenerate matching transform (zero scale)";
      return false;
    }
    std::vector<double> raw_d, rect_d;
    for (size_t k = 0; k < inliers.size(); ++k) {
      const cv::Vec3d ql = Hl * (N * cv::Vec3d(inliers.left[k].x, inliers.left[k].y, 1.0));
      const cv::Vec3d qr = Hr * (N * cv::Vec3d(inliers.right[k].x, inliers.right[k].y, 1.0));
      if (!(std::abs(ql[2]) > 1e-12) || !(std::abs(qr[2]) > 1e-12)) continue;
      rect_d.push_back(ql[0] / ql[2] - qr[0] / qr[2]);
      raw_d.push_back(s * (inliers.left[k].x - inliers.right[k].x));
    }
    if (!raw_d.empty()) {
      double m_raw, m_rect, unused;
      offsetStatistics(raw_d, &m_raw, &unused);
      offsetStatistics(rect_d, &m_rect, &unused);
      // Adding delta * (w row) to the x row shifts every rectified x by exactly delta.
      const double delta = m_raw - m_rect;
      for (int c = 0; c < 3; ++c) Hl(0, c) += delta * Hl(2, c);
    }
  }

  // Both images must stay on one side of their line at infinity.
  const cv::Point2d corners[4] = {
      {0, 0}, {size.width - 1.0, 0}, {size.width - 1.0, size.height - 1.0}, {0, size.height - 1.0}};
  cv::Point2d mapped[4];
  for (int img = 0; img < 2; ++img) {
    const cv::Matx33d H = (img == 0 ? Hl : Hr) * N;
    double sign = 0;
    for (int k = 0; k < 4; ++k) {
      const cv::Vec3d q = H * cv::Vec3d(corners[k].x, corners[k].y, 1.0);
      if (sign == 0) sign = q[2] > 0 ? 1 : -1;
      if (q[2] * sign <= 1e-9) {
        if (error) *error = "an image would cross the line at infinity (use polar)";
        return false;
      }
      if (img == 0) mapped[k] = cv::Point2d(q[0] / q[2], q[1] / q[2]);
    }
  }
  // A common scale and shift for both (rows and disparity ratios are kept): the rectified left
  // image has the raw area and is centred in the output.
  double area = 0;
  cv::Point2d centroid(0, 0);
  for (int k = 0; k < 4; ++k) {
    const cv::Point2d& a = mapped[k];
    const cv::Point2d& b = mapped[(k + 1) % 4];
    area += a.x * b.y - b.x * a.y;
    centroid += a * 0.25;
  }
  area *= 0.5;
  if (!(area > 0)) {
    if (error) *error = "rectifying homography mirrors the image (degenerate estimate)";
    return false;
  }
  const double k = std::sqrt(double(size.width) * size.height / area);
  const cv::Matx33d S(k, 0, cx - k * centroid.x, 0, k, cy - k * centroid.y, 0, 0, 1);
  *H_left = S * Hl * N;
  *H_right = S * Hr * N;
  *H_left *= 1.0 / (*H_left)(2, 2);
  *H_right *= 1.0 / (*H_right)(2, 2);
  return true;
}

// ---------------------------------------------------------------------------------------------
// Pollefeys, Koch, Van Gool 1999.
namespace {

/// What the half-line transfer of a polar rectification needs: the fundamental matrix, the
/// image centre, the finite epipoles, the orientation sign and the radius of the left samples.
struct PolarTransfer {
  explicit PolarTransfer(const cv::Matx33d& fundamental) : F(fundamental) {}
  const cv::Matx33d& F;
  cv::Point2d centre, el, er;
  double flip = 1.0;
  double rho_l = 0.0;
  bool right_near = true;
};

/// Orientation of the half-line transfer (oriented epipolar geometry: e' x x' ~ +F x for all
/// true correspondences, with one global sign), voted by the inliers. @return false with fewer
/// than 8 votes.
bool orientTransfer(const cv::Matx33d& F, const Matches& inliers, const cv::Point2d& er,
                    double* flip) {
  int pos = 0, neg = 0;
  for (size_t i = 0; i < inliers.size(); ++i) {
    const cv::Vec3d l = F * cv::Vec3d(inliers.left[i].x, inliers.left[i].y, 1.0);
    const cv::Point2d d(l[1], -l[0]);
    const double s = d.dot(inliers.right[i] - er);
    (s >= 0 ? pos : neg)++;
  }
  if (pos + neg < 8) return false;
  *flip = neg > pos ? -1.0 : 1.0;
  return true;
}

/// Angle (unwrapped near @p prev) of the right half-line corresponding to left angle theta.
bool transferAngle(const PolarTransfer& g, double theta, double prev, double* phi) {
  const cv::Point2d p = g.el + g.rho_l * cv::Point2d(std::cos(theta), std::sin(theta));
  const cv::Vec3d l = g.F * cv::Vec3d(p.x, p.y, 1.0);
  const double ln = std::hypot(l[0], l[1]);
  if (!(ln > 0)) return false;
  const cv::Point2d d = cv::Point2d(l[1], -l[0]) * (g.flip / ln);
  double a;
  if (g.right_near) {
    a = std::atan2(d.y, d.x);
  } else {
    // Far epipole: the ray from the (clamped) epipole through the line's point nearest the
    // image centre, so that the clamping does not tilt the line.
    const double dist = (l[0] * g.centre.x + l[1] * g.centre.y + l[2]) / ln;
    const cv::Point2d q = g.centre - cv::Point2d(l[0], l[1]) * (dist / ln);
    const cv::Point2d v = q - g.er;
    a = std::atan2(v.y, v.x);
  }
  *phi = prev + wrapAngle(a - prev);
  return true;
}

/// The angular range [t_begin, t_end] of the left half-lines: the full circle around an inner
/// epipole (in_l), else the wedge of the corners; and the distances of the farthest corner from
/// each epipole.
void leftAngularRange(const cv::Size& size, const PolarTransfer& g, bool in_l, double* t_begin,
                      double* t_end, double* r_far_l, double* r_far_r) {
  const cv::Point2d corners[4] = {
      {0, 0}, {size.width - 1.0, 0}, {size.width - 1.0, size.height - 1.0}, {0, size.height - 1.0}};
  *r_far_l = 0;
  *r_far_r = 0;
  for (const auto& c : corners) {
    *r_far_l = std::max(*r_far_l, cv::norm(c - g.el));
    *r_far_r = std::max(*r_far_r, cv::norm(c - g.er));
  }
  if (in_l) {
    *t_begin = -kPi;
    *t_end = kPi;
    return;
  }
  const double a_c = std::atan2(g.centre.y - g.el.y, g.centre.x - g.el.x);
  double lo = 0, hi = 0;
  for (const auto& c : corners) {
    const double d = wrapAngle(std::atan2(c.y - g.el.y, c.x - g.el.x) - a_c);
    lo = std::min(lo, d);
    hi = std::max(hi, d);
  }
  *t_begin = a_c + lo;
  *t_end = a_c + hi;
}

/// The rows of a polar rectification: per row the left and right half-line angles and the
/// intervals of distance [r0, r1] along each half-line that lie inside its image.
struct PolarRows {
  std::vector<double> th, ph;
  std::vector<double> rl0, rl1, rr0, rr1;
};

// March over the left angles: each step moves the farthest image point by at most one pixel
// in both images (Pollefeys' rule, with the farthest corner as a conservative bound). Keeps the
// angles whose half-lines cross both images. @return false with the reason in @p why.
bool marchAngles(const PolarTransfer& g, const cv::Size& size, double t_begin, double t_end,
                 double r_far_l, double r_far_r, PolarRows* rows, std::string* why) {
  const size_t max_rows = size_t(20) * size_t(size.width + size.height);
  double theta = t_begin, phi_prev = 0;
  if (!transferAngle(g, theta, 0.0, &phi_prev)) {
    *why = "degenerate fundamental matrix";
    return false;
  }
  while (theta <= t_end) {
    double phi;
    if (!transferAngle(g, theta, phi_prev, &phi)) {
      *why = "degenerate fundamental matrix";
      return false;
    }
    const cv::Point2d ul(std::cos(theta), std::sin(theta)), ur(std::cos(phi), std::sin(phi));
    double a0, a1, b0, b1;
    if (rayInterval(g.el, ul, size, &a0, &a1) && rayInterval(g.er, ur, size, &b0, &b1)) {
      rows->th.push_back(theta);
      rows->ph.push_back(phi);
      rows->rl0.push_back(a0);
      rows->rl1.push_back(a1);
      rows->rr0.push_back(b0);
      rows->rr1.push_back(b1);
      if (rows->th.size() > max_rows) {
        *why = "polar rectification would exceed 20 (w+h) rows";
        return false;
      }
    }
    double step = 1.0 / r_far_l;
    for (int it = 0; it < 3; ++it) {
      double phi_next;
      if (!transferAngle(g, theta + step, phi, &phi_next)) break;
      const double moved = std::abs(phi_next - phi) * r_far_r;
      if (moved <= 1.0) break;
      step *= 0.999 / moved;
    }
    phi_prev = phi;
    theta += step;
  }
  return true;
}

/// The column references of @p p (its epipoles set): with both epipoles outside the images,
/// columns grow with raw x and the image centres land on the same column; else a column is the
/// distance from the epipole.
void columnReferences(const cv::Point2d& centre, bool in_l, bool in_r, PolarRectification& p) {
  if (!in_l && !in_r) {
    const cv::Point2d dl = centre - p.epipole_left, dr = centre - p.epipole_right;
    p.sign_left = dl.x >= 0 ? 1.0 : -1.0;
    p.sign_right = dr.x >= 0 ? 1.0 : -1.0;
    p.r_ref_left = cv::norm(dl);
    p.r_ref_right = cv::norm(dr);
  } else {
    p.sign_left = p.sign_right = 1.0;
    p.r_ref_left = p.r_ref_right = 0.0;
  }
}

/// The inliers decide whether distances grow the same way along corresponding half-lines (else
/// the right column sign flips).
void orientRightColumns(const Matches& inliers, PolarRectification& p) {
  const cv::Point2d el = p.epipole_left, er = p.epipole_right;
  double mean_l = 0, mean_r = 0, cov = 0;
  const size_t n = inliers.size();
  std::vector<double> cl(n), cr(n);
  for (size_t i = 0; i < n; ++i) {
    cl[i] = p.sign_left * (cv::norm(inliers.left[i] - el) - p.r_ref_left);
    cr[i] = p.sign_right * (cv::norm(inliers.right[i] - er) - p.r_ref_right);
    mean_l += cl[i] / double(n);
    mean_r += cr[i] / double(n);
  }
  for (size_t i = 0; i < n; ++i) cov += (cl[i] - mean_l) * (cr[i] - mean_r);
  if (cov < 0) p.sign_right = -p.sign_right;
}

/// The reference column and the width of @p p: every row's interval in both images fits.
/// @return false (with the reason in @p why) when the result would be too large.
bool columnRange(const PolarRows& rows, const cv::Size& size, PolarRectification& p,
                 std::string* why) {
  double cmin = std::numeric_limits<double>::infinity(), cmax = -cmin;
  for (size_t i = 0; i < rows.th.size(); ++i) {
    for (double r : {rows.rl0[i], rows.rl1[i]}) {
      const double c = p.sign_left * (r - p.r_ref_left);
      cmin = std::min(cmin, c);
      cmax = std::max(cmax, c);
    }
    for (double r : {rows.rr0[i], rows.rr1[i]}) {
      const double c = p.sign_right * (r - p.r_ref_right);
      cmin = std::min(cmin, c);
      cmax = std::max(cmax, c);
    }
  }
  p.c_ref = -std::floor(cmin);
  p.width = int(std::ceil(cmax - std::floor(cmin))) + 1;
  if (p.width > 8 * std::max(size.width, size.height) ||
      double(p.width) * double(rows.th.size()) > 32e6) {
    std::ostringstream m;
    m << "polar rectification would be " << p.width << "x" << rows.th.size() << " px (too large)";
    *why = m.str();
    return false;
  }
  return true;
}

/// Rows grow with raw y in the left image (away from an outer epipole), so that the output is
/// upright: a 180 degree turn together with the column sign, never a mirror. @return whether
/// the rows must be reversed.
bool rowsReversed(const PolarTransfer& g, bool in_l) {
  if (in_l) return false;
  const double a_c = std::atan2(g.centre.y - g.el.y, g.centre.x - g.el.x);
  return std::cos(a_c) < 0;
}

}  // namespace

bool polarRectification(const cv::Matx33d& F, const Matches& inliers, const cv::Size& size,
                        PolarRectification* out, std::string* error) {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  PolarTransfer g(F);
  g.centre = cv::Point2d((size.width - 1) / 2.0, (size.height - 1) / 2.0);
  const double diag = std::hypot(double(size.width), double(size.height));
  cv::Vec3d el_h, er_h;
  epipoles(F, &el_h, &er_h);
  g.el = finiteEpipole(el_h, g.centre);
  g.er = finiteEpipole(er_h, g.centre);
  const bool in_l = insideImage(g.el, size), in_r = insideImage(g.er, size);
  if (!orientTransfer(F, inliers, g.er, &g.flip)) {
    return fail("too few inliers to orient the epipolar lines");
  }
  g.rho_l = std::max(cv::norm(g.centre - g.el), diag / 4);
  g.right_near = cv::norm(g.er - g.centre) < 10 * diag;

  double t_begin, t_end, r_far_l, r_far_r;
  leftAngularRange(size, g, in_l, &t_begin, &t_end, &r_far_l, &r_far_r);
  PolarRows rows;
  std::string why;
  if (!marchAngles(g, size, t_begin, t_end, r_far_l, r_far_r, &rows, &why)) return fail(why);
  if (rows.th.size() < 2) return fail("the epipolar lines of the two images do not overlap");

  PolarRectification p;
  p.epipole_left = g.el;
  p.epipole_right = g.er;
  columnReferences(g.centre, in_l, in_r, p);
  orientRightColumns(inliers, p);
  if (!columnRange(rows, size, p, &why)) return fail(why);
  if (rowsReversed(g, in_l)) {
    std::reverse(rows.th.begin(), rows.th.end());
    std::reverse(rows.ph.begin(), rows.ph.end());
  }
  p.theta = std::move(rows.th);
  p.phi = std::move(rows.ph);
  *out = std::move(p);
  return true;
}

void polarMaps(const PolarRectification& p, bool left, cv::Mat& map_x, cv::Mat& map_y) {
  const int rows = int(p.theta.size());
  map_x.create(rows, p.width, CV_32FC1);
  map_y.create(rows, p.width, CV_32FC1);
  const cv::Point2d e = left ? p.epipole_left : p.epipole_right;
  const std::vector<double>& ang = left ? p.theta : p.phi;
  const double sign = left ? p.sign_left : p.sign_right;
  const double r_ref = left ? p.r_ref_left : p.r_ref_right;
  cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      const double cs = std::cos(ang[size_t(i)]), sn = std::sin(ang[size_t(i)]);
      float* mx = map_x.ptr<float>(i);
      float* my = map_y.ptr<float>(i);
      for (int c = 0; c < p.width; ++c) {
        const double r = r_ref + sign * (c - p.c_ref);
        if (r < 0) {
          mx[c] = my[c] = -1.f;
          continue;
        }
        mx[c] = float(e.x + r * cs);
        my[c] = float(e.y + r * sn);
      }
    }
  });
}

}  // namespace detail

cv::Point2d PolarRectification::toRaw(bool left, double col, double row) const {
  const std::vector<double>& ang = left ? theta : phi;
  if (ang.empty()) return cv::Point2d(std::numeric_limits<double>::quiet_NaN(), 0);
  const double rr = std::min(std::max(row, 0.0), double(ang.size() - 1));
  const size_t i0 = size_t(std::floor(rr));
  const size_t i1 = std::min(i0 + 1, ang.size() - 1);
  const double t = rr - double(i0);
  const double a = ang[i0] * (1 - t) + ang[i1] * t;
  const double r =
      (left ? r_ref_left : r_ref_right) + (left ? sign_left : sign_right) * (col - c_ref);
  const cv::Point2d e = left ? epipole_left : epipole_right;
  return e + r * cv::Point2d(std::cos(a), std::sin(a));
}

bool PolarRectification::toRectified(bool left, const cv::Point2d& raw, cv::Point2d* rect) const {
  const std::vector<double>& ang = left ? theta : phi;
  if (ang.size() < 2) return false;
  const cv::Point2d e = left ? epipole_left : epipole_right;
  const cv::Point2d d = raw - e;
  double a = std::atan2(d.y, d.x);
  // Bring the angle next to the table's range (it may extend past +-pi after unwrapping).
  const double lo = std::min(ang.front(), ang.back());
  while (a < lo) a += 2 * 3.14159265358979323846;
  while (a - 2 * 3.14159265358979323846 >= lo) a -= 2 * 3.14159265358979323846;
  double row;
  if (!detail::fractionalIndex(ang, a, &row)) return false;
  const double r = std::hypot(d.x, d.y);
  const double col =
      c_ref + (r - (left ? r_ref_left : r_ref_right)) / (left ? sign_left : sign_right);
  *rect = cv::Point2d(col, row);
  return true;
}

}  // namespace endo_stereo
