// Synthetic surgical stereo video with exact ground truth. See surgical_scene.hpp.
//
// Coordinates: the world frame has +Z along the endoscope's viewing direction and +Y down, like an
// optical frame; the rig (both cameras) only translates over time. The tissue is a height field
// Z = h(X, Y, t); instruments are capsules. Every pixel of each view is a ray C + s * dir, where
// dir comes from a per-pixel table built once (so a distorted lens costs nothing per frame).
#include "endo_stereo/synthetic/surgical_scene.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace endo_stereo {

namespace {

constexpr double kPi = 3.14159265358979323846;

std::string fieldError(const char* field, const char* range, double value) {
  std::ostringstream os;
  os << "surgical_scene." << field << " must be in " << range << " (got " << value << ")";
  return os.str();
}

// SplitMix64: derives independent seeds from (seed, stream) without correlation.
uint64_t mixSeed(uint64_t seed, uint64_t stream) {
  uint64_t z = seed + 0x9E3779B97F4A7C15ull * (stream + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

inline double dot3(const cv::Vec3d& a, const cv::Vec3d& b) { return a.dot(b); }

struct Bump {
  double x, y, inv_s2, a;
};

struct Wave {
  double kx, ky, phase, amp, omega;
};

struct Capsule {
  cv::Vec3d a, b;  // axis end (outside the view) and tip
  double r = 0.0;
  cv::Vec3d u1, u2;  // unit vectors orthogonal to the axis (texture angle reference)
};

// Everything that changes with time, evaluated once per distinct time.
struct State {
  double t = 0.0;
  cv::Vec3d rig;  // translation of the rig (world position of the left optical centre)
  double z0 = 0.0, relief_scale = 1.0, heart = 0.0, stretch = 0.0;
  std::array<double, 2> wave_shift{};
  std::vector<Capsule> caps;
  cv::Vec3d light;
};

struct Hit {
  double s = -1.0;        // ray parameter
  int kind = -1;          // 0 tissue, 1 + i instrument i
  cv::Vec3d p;            // world point
  double hx = 0, hy = 0;  // tissue gradient at p
  cv::Vec3d n;            // instrument outward normal
};

// One camera as rendered (raw) and its ray table in the rig frame.
struct RawCamera {
  cv::Matx33d K;
  std::array<double, 5> D{};  // k1 k2 p1 p2 k3
  cv::Matx33d R_rig_cam = cv::Matx33d::eye();
  cv::Vec3d center_rig;
  std::vector<cv::Vec3d> dirs;  // per pixel, row-major
};

// Exact forward plumb_bob projection of a point in camera coordinates.
cv::Point2d projectPlumbBob(const RawCamera& c, const cv::Vec3d& pc) {
  const double x = pc[0] / pc[2], y = pc[1] / pc[2];
  const double r2 = x * x + y * y;
  const double radial = 1 + c.D[0] * r2 + c.D[1] * r2 * r2 + c.D[4] * r2 * r2 * r2;
  const double xd = x * radial + 2 * c.D[2] * x * y + c.D[3] * (r2 + 2 * x * x);
  const double yd = y * radial + c.D[2] * (r2 + 2 * y * y) + 2 * c.D[3] * x * y;
  return {c.K(0, 0) * xd + c.K(0, 2), c.K(1, 1) * yd + c.K(1, 2)};
}

// Inverse of the plumb_bob distortion by Newton on the 2x2 system, to 1e-14: the ray of a raw pixel
// then re-projects onto that pixel to far below 1e-6 px.
cv::Vec2d undistortNormalized(const RawCamera& c, double xd, double yd) {
  double x = xd, y = yd;
  for (int it = 0; it < 50; ++it) {
    const double r2 = x * x + y * y;
    const double radial = 1 + c.D[0] * r2 + c.D[1] * r2 * r2 + c.D[4] * r2 * r2 * r2;
    const double dradial = c.D[0] + 2 * c.D[1] * r2 + 3 * c.D[4] * r2 * r2;  // d radial / d r2
    const double fx = x * radial + 2 * c.D[2] * x * y + c.D[3] * (r2 + 2 * x * x) - xd;
    const double fy = y * radial + c.D[2] * (r2 + 2 * y * y) + 2 * c.D[3] * x * y - yd;
    if (std::abs(fx) < 1e-15 && std::abs(fy) < 1e-15) break;
    const double j11 = radial + x * dradial * 2 * x + 2 * c.D[2] * y + c.D[3] * 6 * x;
    const double j12 = x * dradial * 2 * y + 2 * c.D[2] * x + c.D[3] * 2 * y;
    const double j21 = y * dradial * 2 * x + c.D[2] * 2 * x + 2 * c.D[3] * y;
    const double j22 = radial + y * dradial * 2 * y + c.D[2] * 6 * y + 2 * c.D[3] * x;
    const double det = j11 * j22 - j12 * j21;
    x -= (j22 * fx - j12 * fy) / det;
    y -= (-j21 * fx + j11 * fy) / det;
  }
  return {x, y};
}

// Bilinear sample of a float image with clamped coordinates.
template <int CN>
inline void sampleBilinear(const cv::Mat& img, double fx, double fy, float* out) {
  fx = std::min(std::max(fx, 0.0), double(img.cols - 1) - 1e-9);
  fy = std::min(std::max(fy, 0.0), double(img.rows - 1) - 1e-9);
  const int x0 = int(fx), y0 = int(fy);
  const float ax = float(fx - x0), ay = float(fy - y0);
  const float* r0 = img.ptr<float>(y0) + x0 * CN;
  const float* r1 = img.ptr<float>(y0 + 1) + x0 * CN;
  for (int c = 0; c < CN; ++c) {
    const float top = r0[c] + ax * (r0[CN + c] - r0[c]);
    const float bot = r1[c] + ax * (r1[CN + c] - r1[c]);
    out[c] = top + ay * (bot - top);
  }
}

// Smooth random field of unit standard deviation with features about spacing_px apart.
cv::Mat noiseField(cv::RNG& rng, cv::Size size, double spacing_px) {
  const int gw = std::max(2, int(std::ceil(size.width / spacing_px)) + 3);
  const int gh = std::max(2, int(std::ceil(size.height / spacing_px)) + 3);
  cv::Mat coarse(gh, gw, CV_32FC1);
  rng.fill(coarse, cv::RNG::NORMAL, 0.0, 1.0);
  cv::Mat fine;
  cv::resize(coarse, fine, size, 0, 0, cv::INTER_CUBIC);
  cv::Scalar mean, stddev;
  cv::meanStdDev(fine, mean, stddev);
  fine = (fine - mean[0]) / std::max(1e-6, stddev[0]);
  return fine;
}

// sin and cos to ~1e-10 without libm: Cody-Waite reduction to [-pi/4, pi/4], Taylor polynomials
// and a branch-free quadrant fix-up. The scene only needs a smooth periodic function evaluated
// identically for both views and the ground truth; this one is several times faster than
// std::sin + std::cos on the hot path.
inline void fastSinCos(double x, double* sn, double* cs) {
  const double t = x * (2.0 / kPi);
  const double q = double(int64_t(t + (t >= 0 ? 0.5 : -0.5)));  // round, inline (no libm call)
  const double r = (x - q * 1.57079632679489655800e+00) - q * 6.12323399573676603587e-17;
  const double r2 = r * r;
  const double s =
      r * (1 + r2 * (-1.0 / 6 +
                     r2 * (1.0 / 120 +
                           r2 * (-1.0 / 5040 + r2 * (1.0 / 362880 + r2 * (-1.0 / 39916800))))));
  const double c =
      1 +
      r2 * (-0.5 + r2 * (1.0 / 24 +
                         r2 * (-1.0 / 720 + r2 * (1.0 / 40320 + r2 * (-1.0 / 3628800 +
                                                                      r2 * (1.0 / 479001600.0))))));
  const int64_t quadrant = int64_t(q) & 3;
  const bool swap = quadrant & 1;
  const double ss = swap ? c : s, cc = swap ? s : c;
  *sn = (quadrant & 2) ? -ss : ss;
  *cs = ((quadrant + 1) & 2) ? -cc : cc;
}

inline double smoothstep(double a, double b, double x) {
  const double t = std::min(1.0, std::max(0.0, (x - a) / (b - a)));
  return t * t * (3 - 2 * t);
}

}  // namespace

std::string SurgicalSceneParams::validate() const {
  if (width < 32 || width > 8192) return fieldError("width", "[32, 8192]", width);
  if (height < 32 || height > 8192) return fieldError("height", "[32, 8192]", height);
  if (!(fps > 0)) return fieldError("fps", "(0, inf)", fps);
  if (!(hfov_deg > 10 && hfov_deg < 150)) return fieldError("hfov_deg", "(10, 150)", hfov_deg);
  if (!(baseline_m > 0)) return fieldError("baseline_m", "(0, inf)", baseline_m);
  if (!(tissue_distance_m > 0))
    return fieldError("tissue_distance_m", "(0, inf)", tissue_distance_m);
  if (!(tissue_relief_m >= 0 && tissue_relief_m < 0.25 * tissue_distance_m))
    return fieldError("tissue_relief_m", "[0, tissue_distance_m / 4)", tissue_relief_m);
  if (!(breathing_amplitude_m >= 0 && breathing_amplitude_m < 0.1 * tissue_distance_m))
    return fieldError("breathing_amplitude_m", "[0, tissue_distance_m / 10)",
                      breathing_amplitude_m);
  if (!(breathing_period_s > 0))
    return fieldError("breathing_period_s", "(0, inf)", breathing_period_s);
  if (!(heartbeat_amplitude_m >= 0 && heartbeat_amplitude_m < 0.05 * tissue_distance_m))
    return fieldError("heartbeat_amplitude_m", "[0, tissue_distance_m / 20)",
                      heartbeat_amplitude_m);
  if (!(heartbeat_period_s > 0))
    return fieldError("heartbeat_period_s", "(0, inf)", heartbeat_period_s);
  if (!(tissue_stretch_m >= 0)) return fieldError("tissue_stretch_m", "[0, inf)", tissue_stretch_m);
  if (!(camera_motion_m >= 0 && camera_motion_m < 0.2 * tissue_distance_m))
    return fieldError("camera_motion_m", "[0, tissue_distance_m / 5)", camera_motion_m);
  if (!(camera_motion_period_s > 0))
    return fieldError("camera_motion_period_s", "(0, inf)", camera_motion_period_s);
  if (!(vessel_density >= 0 && vessel_density <= 10))
    return fieldError("vessel_density", "[0, 10]", vessel_density);
  if (!(texture_contrast >= 0 && texture_contrast <= 5))
    return fieldError("texture_contrast", "[0, 5]", texture_contrast);
  if (!(specular_strength >= 0 && specular_strength <= 10))
    return fieldError("specular_strength", "[0, 10]", specular_strength);
  if (instruments < 0 || instruments > 2) return fieldError("instruments", "[0, 2]", instruments);
  if (!(instrument_radius_m > 0 && instrument_radius_m < 0.1 * tissue_distance_m))
    return fieldError("instrument_radius_m", "(0, tissue_distance_m / 10)", instrument_radius_m);
  if (!(instrument_speed >= 0 && instrument_speed <= 20))
    return fieldError("instrument_speed", "[0, 20]", instrument_speed);
  if (!(instrument_texture >= 0 && instrument_texture <= 1))
    return fieldError("instrument_texture", "[0, 1]", instrument_texture);
  if (!(noise_sigma >= 0 && noise_sigma <= 100))
    return fieldError("noise_sigma", "[0, 100]", noise_sigma);
  if (motion_blur_samples < 1 || motion_blur_samples > 16)
    return fieldError("motion_blur_samples", "[1, 16]", motion_blur_samples);
  if (!(exposure_s >= 0 && exposure_s <= 1)) return fieldError("exposure_s", "[0, 1]", exposure_s);
  return {};
}

// ================================================================================================
struct SurgicalScene::Impl {
  SurgicalSceneParams p;
  int W = 0, H = 0;
  double f = 0;      // nominal focal length, px
  RawCamera cam[2];  // raw left / right
  // Rectified left (ground-truth) rays and axis, in the rig frame.
  std::vector<cv::Vec3d> gt_dirs;
  cv::Vec3d gt_axis;  // unit optical axis of the rectified left camera
  double f_rect = 0, baseline = 0, doffs = 0;
  cv::Matx33d R1 = cv::Matx33d::eye(), R2 = cv::Matx33d::eye();  // camera -> rectified
  cv::Matx34d P1, P2;                                            // rectified projections
  // Tissue.
  double gx = 0, gy = 0;
  std::vector<Bump> bumps;
  Bump heart_bump{};
  std::array<Wave, 2> waves{};
  double breath_phase = 0, motion_phase[3] = {0, 0, 0};
  double stretch_kx = 0, stretch_ky = 0, stretch_phase[2] = {0, 0};
  // Texture atlas over material coordinates (X, Y), texel size tau metres.
  double tau = 0, atlas_x0 = 0, atlas_y0 = 0;
  cv::Mat albedo;     // CV_32FC3, linear RGB stored as B, G, R
  cv::Mat bump_grad;  // CV_32FC2, slope of the micro relief (shading only)
  // Instruments.
  struct InstrumentPath {
    cv::Vec3d entry, tip_centre, tip_amp;
    double omega[3], phase[3];
  };
  std::vector<InstrumentPath> paths;
  cv::Mat metal;  // CV_32FC1 brushed-metal table: rows = axial cells, cols = angle cells
  double metal_axial_cell = 0.0005;
  // Gamma lookup for linear [0, 1] -> 0..255.
  std::vector<float> gamma_lut;
  int min_d = 0, max_d = 0;

  explicit Impl(const SurgicalSceneParams& params) : p(params), W(params.width), H(params.height) {}

  // ---------------------------------------------------------------------------------------------
  State stateAt(double t) const {
    State s;
    s.t = t;
    const double cam_w = 2 * kPi / p.camera_motion_period_s;
    s.rig = cv::Vec3d(p.camera_motion_m * std::sin(cam_w * t + motion_phase[0]),
                      0.6 * p.camera_motion_m * std::sin(cam_w / 1.37 * t + motion_phase[1]),
                      0.5 * p.camera_motion_m * std::sin(cam_w / 0.83 * t + motion_phase[2]));
    const double b = std::sin(2 * kPi * t / p.breathing_period_s + breath_phase);
    s.z0 = p.tissue_distance_m + p.breathing_amplitude_m * b;
    s.relief_scale = 1.0 + 0.08 * b;
    s.stretch = p.tissue_stretch_m * b;
    double ph = std::fmod(t / p.heartbeat_period_s, 1.0);
    if (ph < 0) ph += 1.0;
    // Systolic peak then a smaller dicrotic one.
    s.heart = p.heartbeat_amplitude_m * (std::exp(-std::pow((ph - 0.15) / 0.07, 2)) +
                                         0.45 * std::exp(-std::pow((ph - 0.42) / 0.08, 2)));
    for (int i = 0; i < 2; ++i) s.wave_shift[i] = waves[i].omega * t;
    // The light sits at the tip between the two lenses, a little below them.
    s.light = s.rig + cv::Vec3d(0.5 * p.baseline_m, 0.0012, 0.0);
    for (const InstrumentPath& ip : paths) {
      Capsule c;
      const double ts = t * p.instrument_speed;
      cv::Vec3d tip = ip.tip_centre;
      for (int k = 0; k < 3; ++k)
        tip[k] += ip.tip_amp[k] * std::sin(ip.omega[k] * ts + ip.phase[k]);
      const cv::Vec3d axis = cv::normalize(tip - ip.entry);
      c.a = ip.entry - 0.06 * axis;  // the shaft continues out of view
      c.b = tip;
      c.r = p.instrument_radius_m;
      cv::Vec3d ref = std::abs(axis[1]) < 0.9 ? cv::Vec3d(0, 1, 0) : cv::Vec3d(1, 0, 0);
      c.u1 = cv::normalize(axis.cross(ref));
      c.u2 = axis.cross(c.u1);
      s.caps.push_back(c);
    }
    return s;
  }

  // Height of the tissue and its gradient at world (X, Y).
  inline double height(const State& s, double X, double Y, double* hx, double* hy) const {
    double h = s.z0 + gx * X + gy * Y;
    double dx = gx, dy = gy;
    double bs = 0, bdx = 0, bdy = 0;
    for (const Bump& b : bumps) {
      const double ex = X - b.x, ey = Y - b.y;
      const double q1 = 1.0 / (1.0 + (ex * ex + ey * ey) * b.inv_s2);
      const double q2 = q1 * q1;
      bs += b.a * q2;
      const double g = -4.0 * b.a * b.inv_s2 * q2 * q1;
      bdx += g * ex;
      bdy += g * ey;
    }
    h += s.relief_scale * bs;
    dx += s.relief_scale * bdx;
    dy += s.relief_scale * bdy;
    {
      const Bump& b = heart_bump;
      const double ex = X - b.x, ey = Y - b.y;
      const double q1 = 1.0 / (1.0 + (ex * ex + ey * ey) * b.inv_s2);
      const double q2 = q1 * q1;
      h += s.heart * q2;
      const double g = -4.0 * s.heart * b.inv_s2 * q2 * q1;
      dx += g * ex;
      dy += g * ey;
    }
    for (int i = 0; i < 2; ++i) {
      const Wave& w = waves[i];
      const double arg = w.kx * X + w.ky * Y + w.phase + s.wave_shift[i];
      double sn, cs;
      fastSinCos(arg, &sn, &cs);
      h += w.amp * sn;
      dx += w.amp * w.kx * cs;
      dy += w.amp * w.ky * cs;
    }
    *hx = dx;
    *hy = dy;
    return h;
  }

  // Newton on F(s) = Cz + s dz - h(Cx + s dx, Cy + s dy). Starts from s_init (the neighbour's
  // solution along the row); F' = dz - grad h . (dx, dy) stays > 0 for the gentle slopes used, so
  // the root is unique and Newton converges in a few steps.
  inline bool castTissue(const State& st, const cv::Vec3d& C, const cv::Vec3d& d, double s_init,
                         Hit* hit) const {
    double s = s_init;
    double hx = 0, hy = 0;
    for (int it = 0; it < 40; ++it) {
      const double X = C[0] + s * d[0], Y = C[1] + s * d[1];
      const double h = height(st, X, Y, &hx, &hy);
      const double F = C[2] + s * d[2] - h;
      const double dF = d[2] - hx * d[0] - hy * d[1];
      const double step = F / std::max(dF, 1e-3);
      s -= step;
      // 1e-11 m along the ray is < 1e-7 px of disparity; the gradient (for shading only) is the
      // one at the previous iterate, 1e-11 m away.
      if (std::abs(step) < 1e-11) {
        hit->s = s;
        hit->kind = 0;
        hit->p = C + s * d;
        hit->hx = hx;
        hit->hy = hy;
        return true;
      }
    }
    return false;
  }

  // Ray (origin C, unit direction u) against a capsule; returns the distance along u or -1.
  static double capsuleDistance(const Capsule& c, const cv::Vec3d& C, const cv::Vec3d& u) {
    const cv::Vec3d ba = c.b - c.a, oa = C - c.a;
    const double baba = dot3(ba, ba), bard = dot3(ba, u), baoa = dot3(ba, oa);
    const double rdoa = dot3(u, oa), oaoa = dot3(oa, oa);
    const double A = baba - bard * bard;
    double B = baba * rdoa - baoa * bard;
    double Cc = baba * oaoa - baoa * baoa - c.r * c.r * baba;
    double h = B * B - A * Cc;
    if (h < 0.0) return -1.0;
    const double t = (-B - std::sqrt(h)) / A;
    const double y = baoa + t * bard;
    if (y > 0.0 && y < baba) return t;
    const cv::Vec3d oc = (y <= 0.0) ? oa : C - c.b;
    B = dot3(u, oc);
    Cc = dot3(oc, oc) - c.r * c.r;
    h = B * B - Cc;
    if (h > 0.0) return -B - std::sqrt(h);
    return -1.0;
  }

  static cv::Vec3d capsuleNormal(const Capsule& c, const cv::Vec3d& P) {
    const cv::Vec3d ba = c.b - c.a;
    const double k = std::min(1.0, std::max(0.0, dot3(P - c.a, ba) / dot3(ba, ba)));
    return cv::normalize(P - (c.a + k * ba));
  }

  // Nearest hit of a ray among tissue and instruments. s_tissue carries the Newton start along the
  // row (in/out).
  inline bool cast(const State& st, const cv::Vec3d& C, const cv::Vec3d& d, double* s_tissue,
                   Hit* hit) const {
    Hit tissue;
    bool ok = castTissue(st, C, d, *s_tissue, &tissue);
    if (!ok) {
      // Restart from the mean depth (never seen with the shipped parameters).
      ok = castTissue(st, C, d, (st.z0 - C[2]) / d[2], &tissue);
    }
    if (ok) *s_tissue = tissue.s;
    *hit = tissue;
    const double dn = cv::norm(d);
    const cv::Vec3d u = d / dn;
    for (size_t i = 0; i < st.caps.size(); ++i) {
      const double tc = capsuleDistance(st.caps[i], C, u);
      if (tc > 0.0 && (!ok || hit->kind < 0 || tc / dn < hit->s)) {
        hit->s = tc / dn;
        hit->kind = int(i) + 1;
        hit->p = C + hit->s * d;
        hit->n = capsuleNormal(st.caps[i], hit->p);
        ok = true;
      }
    }
    return ok;
  }

  // Material (texture) coordinates of a tissue point: the tissue slides a little with breathing.
  inline void materialCoords(const State& st, double X, double Y, double* mx, double* my) const {
    double sx, cx, sy, cy;
    fastSinCos(stretch_kx * X + stretch_phase[0], &sx, &cx);
    fastSinCos(stretch_ky * Y + stretch_phase[1], &sy, &cy);
    *mx = X - st.stretch * sx;
    *my = Y - st.stretch * sy;
  }

  inline float gammaEncode(double linear) const {
    if (linear <= 0) return 0.0f;
    const double x = linear * 4096.0;
    if (x >= 4096.0) return 255.0f;
    const int i = int(x);
    const float a = float(x - i);
    return gamma_lut[i] + a * (gamma_lut[i + 1] - gamma_lut[i]);
  }

  // Shade a hit seen from camera centre C: linear radiance (R, G, B) as diffuse and specular parts.
  void shade(const State& st, const Hit& hit, const cv::Vec3d& C, cv::Vec3d* diffuse,
             cv::Vec3d* specular) const {
    const cv::Vec3d& P = hit.p;
    cv::Vec3d n;
    cv::Vec3d albedo_rgb;
    double ks, shininess;
    if (hit.kind == 0) {
      double mx, my;
      materialCoords(st, P[0], P[1], &mx, &my);
      const double ax = (mx - atlas_x0) / tau, ay = (my - atlas_y0) / tau;
      float bgr[3], g2[2];
      sampleBilinear<3>(albedo, ax, ay, bgr);
      sampleBilinear<2>(bump_grad, ax, ay, g2);
      albedo_rgb = cv::Vec3d(bgr[2], bgr[1], bgr[0]);
      // Surface Z - h = 0 seen from -Z: normal (hx, hy, -1), with the micro relief in the slope.
      n = cv::normalize(cv::Vec3d(hit.hx + g2[0], hit.hy + g2[1], -1.0));
      ks = 1.6 * p.specular_strength;
      shininess = 400.0;  // wet mucosa: small, sharp highlights
    } else {
      const Capsule& c = st.caps[hit.kind - 1];
      n = hit.n;
      const cv::Vec3d ba = c.b - c.a;
      const double len = std::sqrt(dot3(ba, ba));
      const double from_tip = len - dot3(P - c.a, ba) / len;  // metres from the tip along the axis
      const cv::Vec3d q = P - c.a;
      double ang = std::atan2(dot3(q, c.u2), dot3(q, c.u1)) / (2 * kPi);
      if (ang < 0) ang += 1.0;
      float m = 0.0f;
      sampleBilinear<1>(metal, ang * (metal.cols - 1),
                        std::min(from_tip / metal_axial_cell, double(metal.rows - 1)), &m);
      // Stainless steel under a coaxial light: bright but mostly below saturation.
      double g = 0.33 * (1.0 + 0.35 * p.instrument_texture * m);
      // Dark rings a few millimetres behind the tip, as printed on real instruments.
      if (p.instrument_texture > 0 &&
          ((from_tip > 0.009 && from_tip < 0.0105) || (from_tip > 0.014 && from_tip < 0.015)))
        g *= 0.25;
      albedo_rgb = cv::Vec3d(g, g * 1.01, g * 1.03);
      ks = 0.8;
      shininess = 35.0;
    }
    cv::Vec3d l = st.light - P;
    const double r2 = dot3(l, l);
    l /= std::sqrt(r2);
    // Spot profile of the light guide around the viewing axis, and 1/r^2 falloff (normalised to 1
    // on the axis at the mean tissue distance). Both depend on the light only: the same in both
    // views.
    const double cos_axis = std::max(0.0, -l[2]);
    const double irradiance =
        cos_axis * cos_axis * (p.tissue_distance_m * p.tissue_distance_m) / r2;
    const double ndl = std::max(0.0, dot3(n, l));
    *diffuse = albedo_rgb * (ndl * irradiance);
    *specular = cv::Vec3d(0, 0, 0);
    if (ks > 0 && ndl > 0) {
      const cv::Vec3d v = cv::normalize(C - P);
      const cv::Vec3d hv = cv::normalize(l + v);
      const double ndh = dot3(n, hv);
      // Below this the highlight is < 1e-4 of its peak: skip the pow.
      if (ndh > std::pow(1e-4, 1.0 / shininess)) {
        const double sp = ks * std::pow(ndh, shininess) * irradiance;
        *specular = cv::Vec3d(sp, sp * 0.97, sp * 0.95);  // warm-white light
      }
    }
  }

  // Ground truth of one rectified left pixel from the hit of its ray (CL: left centre, CR: right).
  void groundTruthPixel(const State& st, const Hit& hit, const cv::Vec3d& CL, const cv::Vec3d& CR,
                        bool ok, float* disp, float* depth, uint8_t* vis, uint8_t* inst) const {
    if (!ok) {
      *disp = *depth = std::numeric_limits<float>::quiet_NaN();
      *vis = kOutsideRightImage;
      *inst = 0;
      return;
    }
    const double z = dot3(hit.p - CL, gt_axis);
    *depth = float(z);
    *disp = float(f_rect * baseline / z + doffs);
    *inst = hit.kind > 0 ? 255 : 0;
    // Seen by the right camera? Inside its raw image, facing it, and not behind a capsule. (The
    // tissue cannot hide itself: its slopes keep every ray's intersection unique.)
    const RawCamera& right = cam[1];
    const cv::Vec3d pc = right.R_rig_cam.t() * (hit.p - CR);
    uint8_t code = kVisibleBoth;
    if (pc[2] <= 0) {
      code = kOutsideRightImage;
    } else {
      const cv::Point2d q = projectPlumbBob(right, pc);
      if (q.x < 0 || q.x > W - 1 || q.y < 0 || q.y > H - 1) code = kOutsideRightImage;
    }
    if (code == kVisibleBoth) {
      if (hit.kind > 0 && dot3(hit.n, CR - hit.p) <= 0) code = kOccludedInRight;
      const cv::Vec3d seg = hit.p - CR;
      const double len = cv::norm(seg);
      const cv::Vec3d u = seg / len;
      for (size_t i = 0; i < st.caps.size() && code == kVisibleBoth; ++i) {
        if (int(i) + 1 == hit.kind) continue;  // a convex capsule hides itself only by facing away
        const double tc = capsuleDistance(st.caps[i], CR, u);
        if (tc > 0 && tc < len - 1e-9) code = kOccludedInRight;
      }
    }
    *vis = code;
  }

  // Cast the rays of one view at per-row states (row_state[v] indexes states).
  // acc (CV_32FC3) != nullptr: shade and add w * colour, OR the specular mask into spec_mask.
  // gt != nullptr: the rays are the rectified left ones; write the ground truth.
  void castView(const RawCamera& camera, const std::vector<cv::Vec3d>& dirs_all,
                const std::vector<State>& states, const std::vector<int>& row_state, cv::Mat* acc,
                float w, cv::Mat* spec_mask, SurgicalFrame* gt) const {
    cv::parallel_for_(cv::Range(0, H), [&](const cv::Range& rows) {
      for (int v = rows.start; v < rows.end; ++v) {
        const State& st = states[row_state[v]];
        const cv::Vec3d C = st.rig + camera.center_rig;
        const cv::Vec3d CR = st.rig + cam[1].center_rig;
        const cv::Vec3d* dirs = &dirs_all[size_t(v) * W];
        float* out = acc ? acc->ptr<float>(v) : nullptr;
        uint8_t* sm = spec_mask ? spec_mask->ptr<uint8_t>(v) : nullptr;
        float* disp = gt ? gt->gt_disparity.ptr<float>(v) : nullptr;
        float* depth = gt ? gt->gt_depth_m.ptr<float>(v) : nullptr;
        uint8_t* vis = gt ? gt->visibility.ptr<uint8_t>(v) : nullptr;
        uint8_t* inst = gt ? gt->instrument_mask.ptr<uint8_t>(v) : nullptr;
        // Newton starts from the row's previous solutions, extrapolated linearly: ~1e-7 m off, so
        // two steps reach 1e-11 m instead of three.
        double s_prev = (st.z0 - C[2]) / dirs[0][2], s_prev2 = s_prev;
        for (int x = 0; x < W; ++x) {
          Hit hit;
          double s_t = x >= 2 ? 2.0 * s_prev - s_prev2 : s_prev;
          const bool ok = cast(st, C, dirs[x], &s_t, &hit);
          s_prev2 = s_prev;
          s_prev = s_t;
          if (gt) groundTruthPixel(st, hit, C, CR, ok, disp + x, depth + x, vis + x, inst + x);
          if (!out || !ok) continue;
          cv::Vec3d dif, spc;
          shade(st, hit, C, &dif, &spc);
          const double e = 0.8;  // exposure: bright tissue just below saturation
          for (int c = 0; c < 3; ++c)
            out[3 * x + c] += w * gammaEncode(e * (dif[2 - c] + spc[2 - c]));
          if (spc[1] > 0 && gammaEncode(e * (dif[1] + spc[1])) - gammaEncode(e * dif[1]) > 2.0f)
            sm[x] = 255;
        }
      }
    });
  }

  void build();
  void buildTexture(cv::RNG& rng);
};

void SurgicalScene::Impl::build() {
  cv::RNG rng(mixSeed(p.seed, 1));
  const double half = std::tan(0.5 * p.hfov_deg * kPi / 180.0);
  f = 0.5 * W / half;
  const double cx = 0.5 * (W - 1), cy = 0.5 * (H - 1);
  const double B = p.baseline_m;

  // Cameras (camera -> rig rotation, centre) and their lenses.
  for (int k = 0; k < 2; ++k) {
    RawCamera& c = cam[k];
    c.center_rig = cv::Vec3d(k == 0 ? 0.0 : B, 0.0, 0.0);
    if (!p.distorted) {
      c.K = cv::Matx33d(f, 0, cx, 0, f, cy, 0, 0, 1);
    } else {
      // Slightly different lenses, off-centre principal points and a few tenths of a degree of
      // misalignment: what a real stereo endoscope's calibration shows.
      const double fk = f * (k == 0 ? 1.0 : 1.004);
      c.K = cv::Matx33d(fk, 0, cx + (k == 0 ? 3.5 : -2.5), 0, fk * 1.001,
                        cy + (k == 0 ? -2.0 : 1.5), 0, 0, 1);
      c.D = k == 0 ? std::array<double, 5>{-0.21, 0.06, 0.0006, -0.0004, 0.0}
                   : std::array<double, 5>{-0.19, 0.05, -0.0005, 0.0003, 0.0};
      const cv::Vec3d rvec =
          k == 0 ? cv::Vec3d(0.004, -0.006, 0.003) : cv::Vec3d(-0.003, 0.005, -0.002);
      cv::Mat R;
      cv::Rodrigues(rvec, R);
      c.R_rig_cam = cv::Matx33d(R);
    }
  }
  // Rectification: the identity for the rectified rig; cv::stereoRectify for the distorted one.
  R1 = R2 = cv::Matx33d::eye();
  P1 = cv::Matx34d(f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0);
  P2 = cv::Matx34d(f, 0, cx, -f * B, 0, f, cy, 0, 0, 0, 1, 0);
  // Extrinsics in the stereoCalibrate convention: x_right = R x_left + T.
  const cv::Matx33d R_rl = cam[1].R_rig_cam.t() * cam[0].R_rig_cam;
  const cv::Vec3d T_rl = cam[1].R_rig_cam.t() * (cam[0].center_rig - cam[1].center_rig);
  if (p.distorted) {
    cv::Mat r1, r2, p1, p2, Q;
    std::vector<double> d0(cam[0].D.begin(), cam[0].D.end()), d1(cam[1].D.begin(), cam[1].D.end());
    cv::stereoRectify(cv::Mat(cam[0].K), d0, cv::Mat(cam[1].K), d1, cv::Size(W, H), cv::Mat(R_rl),
                      cv::Mat(T_rl), r1, r2, p1, p2, Q, cv::CALIB_ZERO_DISPARITY, 0.0);
    R1 = cv::Matx33d(r1);
    R2 = cv::Matx33d(r2);
    P1 = cv::Matx34d(p1);
    P2 = cv::Matx34d(p2);
  }
  f_rect = P1(0, 0);
  baseline = -P2(0, 3) / P2(0, 0);
  doffs = P1(0, 2) - P2(0, 2);

  // Ray tables.
  for (int k = 0; k < 2; ++k) {
    RawCamera& c = cam[k];
    c.dirs.resize(size_t(W) * H);
    for (int v = 0; v < H; ++v) {
      for (int x = 0; x < W; ++x) {
        const double xd = (x - c.K(0, 2)) / c.K(0, 0), yd = (v - c.K(1, 2)) / c.K(1, 1);
        const cv::Vec2d n = p.distorted ? undistortNormalized(c, xd, yd) : cv::Vec2d(xd, yd);
        c.dirs[size_t(v) * W + x] = c.R_rig_cam * cv::Vec3d(n[0], n[1], 1.0);
      }
    }
  }
  if (!p.distorted) {
    gt_dirs = cam[0].dirs;
  } else {
    gt_dirs.resize(size_t(W) * H);
    const cv::Matx33d to_rig = cam[0].R_rig_cam * R1.t();
    for (int v = 0; v < H; ++v)
      for (int x = 0; x < W; ++x)
        gt_dirs[size_t(v) * W + x] =
            to_rig * cv::Vec3d((x - P1(0, 2)) / P1(0, 0), (v - P1(1, 2)) / P1(1, 1), 1.0);
  }
  gt_axis = cam[0].R_rig_cam * R1.t() * cv::Vec3d(0, 0, 1);

  // Tissue shape: gentle tilt, a few broad bumps and folds, a pulsating spot, two waves.
  const double D = p.tissue_distance_m;
  const double vis_x = half * D, vis_y = half * D * H / W;
  gx = rng.uniform(-0.12, 0.12);
  gy = rng.uniform(-0.10, 0.10);
  bumps.clear();
  for (int i = 0; i < 7; ++i) {
    Bump b;
    b.x = rng.uniform(-1.2, 1.2) * vis_x;
    b.y = rng.uniform(-1.2, 1.2) * vis_y;
    const double sigma = rng.uniform(0.25, 0.5) * D;
    b.inv_s2 = 1.0 / (sigma * sigma);
    const double sign = rng.uniform(0.0, 1.0) < 0.65 ? -1.0 : 1.0;  // mostly bulging towards us
    b.a = sign * p.tissue_relief_m * rng.uniform(0.4, 1.0);
    bumps.push_back(b);
  }
  heart_bump.x = rng.uniform(-0.5, 0.5) * vis_x;
  heart_bump.y = rng.uniform(-0.5, 0.5) * vis_y;
  heart_bump.inv_s2 = 1.0 / std::pow(0.2 * D, 2);
  heart_bump.a = -1.0;  // scaled by State::heart, towards the camera
  for (int i = 0; i < 2; ++i) {
    const double wavelength = (i == 0 ? 0.85 : 0.6) * D;
    const double ang = rng.uniform(0.0, 2 * kPi);
    waves[i].kx = 2 * kPi / wavelength * std::cos(ang);
    waves[i].ky = 2 * kPi / wavelength * std::sin(ang);
    waves[i].phase = rng.uniform(0.0, 2 * kPi);
    waves[i].amp = (i == 0 ? 0.18 : 0.12) * p.tissue_relief_m;
    waves[i].omega = i == 0 ? 0.0 : 2 * kPi / 9.0;  // a slow peristaltic wave
  }
  breath_phase = rng.uniform(0.0, 2 * kPi);
  for (double& ph : motion_phase) ph = rng.uniform(0.0, 2 * kPi);
  stretch_kx = 2 * kPi / (0.7 * D);
  stretch_ky = 2 * kPi / (0.55 * D);
  stretch_phase[0] = rng.uniform(0.0, 2 * kPi);
  stretch_phase[1] = rng.uniform(0.0, 2 * kPi);

  // Instruments enter through the side of the view at ~0.55 D and hover above the tissue.
  paths.clear();
  for (int i = 0; i < p.instruments; ++i) {
    InstrumentPath ip;
    const double side = i == 0 ? -1.0 : 1.0;
    const double ze = 0.55 * D;
    ip.entry = cv::Vec3d(side * (half * ze + 2.5 * p.instrument_radius_m),
                         rng.uniform(-0.4, 0.4) * vis_y, ze);
    const double clearance = p.tissue_relief_m + p.breathing_amplitude_m + p.heartbeat_amplitude_m +
                             p.instrument_radius_m + 0.1 * D;
    ip.tip_centre =
        cv::Vec3d(side * 0.15 * vis_x, rng.uniform(-0.2, 0.2) * vis_y, D - clearance - 0.04 * D);
    ip.tip_amp = cv::Vec3d(0.3 * vis_x, 0.35 * vis_y, 0.04 * D);
    const double periods[3] = {5.3, 3.7, 6.1};
    for (int k = 0; k < 3; ++k) {
      ip.omega[k] = 2 * kPi / (periods[k] * rng.uniform(0.85, 1.15));
      ip.phase[k] = rng.uniform(0.0, 2 * kPi);
    }
    paths.push_back(ip);
  }

  gamma_lut.resize(4097);
  for (int i = 0; i <= 4096; ++i) gamma_lut[i] = float(255.0 * std::pow(i / 4096.0, 1.0 / 2.2));

  buildTexture(rng);

  // Disparity bounds from a coarse grid of rectified rays over the scene's periods.
  double dmin = 1e30, dmax = -1e30;
  const int gx_n = 48, gy_n = 27;
  for (int k = 0; k < 60; ++k) {
    const State st = stateAt(k * 0.37);
    const cv::Vec3d CL = st.rig + cam[0].center_rig;
    for (int j = 0; j < gy_n; ++j) {
      const int v = int(std::lround((H - 1) * (j + 0.5) / gy_n));
      double s_t = (st.z0 - CL[2]) / gt_dirs[size_t(v) * W][2];
      for (int i = 0; i < gx_n; ++i) {
        const int x = int(std::lround((W - 1) * (i + 0.5) / gx_n));
        Hit hit;
        if (!cast(st, CL, gt_dirs[size_t(v) * W + x], &s_t, &hit)) continue;
        const double d = f_rect * baseline / dot3(hit.p - CL, gt_axis) + doffs;
        dmin = std::min(dmin, d);
        dmax = std::max(dmax, d);
      }
    }
  }
  min_d = std::max(0, int(std::floor((dmin - 3.0) / 16.0)) * 16);
  max_d = int(std::ceil((dmax + 3.0 + 1.0) / 16.0)) * 16 - 1;
}

void SurgicalScene::Impl::buildTexture(cv::RNG& rng) {
  // Texels a little finer than the pixel footprint at the mean distance, so the texture is as
  // detailed as the camera can resolve at any image size.
  const double half = std::tan(0.5 * p.hfov_deg * kPi / 180.0);
  tau = 0.75 * p.tissue_distance_m / f;
  const double zmax = p.tissue_distance_m + 2.5 * p.tissue_relief_m + p.breathing_amplitude_m;
  const double margin = p.camera_motion_m + 2 * p.tissue_stretch_m + 0.1 * p.tissue_distance_m;
  const double hx = 1.25 * half * zmax + margin, hy = 1.25 * half * zmax * H / W + margin;
  atlas_x0 = -hx;
  atlas_y0 = -hy;
  const cv::Size size(int(std::ceil(2 * hx / tau)) + 2, int(std::ceil(2 * hy / tau)) + 2);
  const double mm = 0.001 / tau;  // texels per millimetre

  const cv::Mat n_fine = noiseField(rng, size, 2.5);
  const cv::Mat n_mid = noiseField(rng, size, 0.8 * mm);
  const cv::Mat n_large = noiseField(rng, size, 4.0 * mm);
  const cv::Mat n_colour = noiseField(rng, size, 15.0 * mm);
  const cv::Mat n_fat = noiseField(rng, size, 9.0 * mm);

  // Vessels: random walks with slowly turning direction, tapering and branching.
  cv::Mat vessels = cv::Mat::zeros(size, CV_8UC1);
  cv::Mat deep = cv::Mat::zeros(size, CV_8UC1);
  const double area_m2 = (2 * hx) * (2 * hy);
  const int count = int(std::lround(p.vessel_density * 700.0 * area_m2));
  struct Seg {
    cv::Point2d pos;
    double dir, width, opacity;
    int steps;
    bool deep;
  };
  std::vector<Seg> todo;
  for (int i = 0; i < count; ++i) {
    Seg s;
    s.pos =
        cv::Point2d(rng.uniform(0.0, double(size.width)), rng.uniform(0.0, double(size.height)));
    s.dir = rng.uniform(0.0, 2 * kPi);
    s.width = rng.uniform(0.25, 0.9) * mm;
    s.opacity = rng.uniform(0.5, 0.95);
    s.steps = rng.uniform(40, 120);
    s.deep = rng.uniform(0.0, 1.0) < 0.35;
    todo.push_back(s);
  }
  const int kMaxSegments = 20000;
  for (size_t k = 0; k < todo.size() && k < size_t(kMaxSegments); ++k) {
    Seg s = todo[k];
    for (int step = 0; step < s.steps && s.width > 0.5; ++step) {
      const double len = 0.6 * mm;
      const cv::Point2d next = s.pos + len * cv::Point2d(std::cos(s.dir), std::sin(s.dir));
      const int th = std::max(1, int(std::lround(s.width)));
      const double op = s.opacity * std::min(1.0, s.width);  // sub-texel vessels fade
      cv::Mat& target = s.deep ? deep : vessels;
      cv::line(target, cv::Point(int(s.pos.x * 16), int(s.pos.y * 16)),
               cv::Point(int(next.x * 16), int(next.y * 16)), cv::Scalar(255 * op), th, cv::LINE_AA,
               4);
      s.pos = next;
      s.dir += rng.gaussian(0.18);
      s.width *= 0.994;
      if (rng.uniform(0.0, 1.0) < 0.035 && todo.size() < size_t(kMaxSegments)) {
        Seg b = s;
        b.dir += (rng.uniform(0.0, 1.0) < 0.5 ? -1 : 1) * rng.uniform(0.4, 1.1);
        b.width *= rng.uniform(0.45, 0.75);
        b.steps = rng.uniform(15, 60);
        todo.push_back(b);
      }
    }
  }
  cv::Mat vf, df;
  vessels.convertTo(vf, CV_32F, 1.0 / 255);
  deep.convertTo(df, CV_32F, 1.0 / 255);
  cv::GaussianBlur(vf, vf, cv::Size(0, 0), 0.7);
  cv::GaussianBlur(df, df, cv::Size(0, 0), 1.6);

  albedo.create(size, CV_32FC3);
  const double c = p.texture_contrast;
  for (int y = 0; y < size.height; ++y) {
    float* a = albedo.ptr<float>(y);
    const float *nf = n_fine.ptr<float>(y), *nm = n_mid.ptr<float>(y), *nl = n_large.ptr<float>(y);
    const float *nc = n_colour.ptr<float>(y), *nt = n_fat.ptr<float>(y);
    const float *vv = vf.ptr<float>(y), *dv = df.ptr<float>(y);
    for (int x = 0; x < size.width; ++x) {
      // Linear RGB: pink mucosa to deeper red, yellowish fat patches, mottling, vessels.
      const double k = smoothstep(-1.5, 1.5, nc[x]);
      double r = 0.80 - 0.16 * k, g = 0.34 - 0.12 * k, b = 0.32 - 0.10 * k;
      const double fat = 0.55 * smoothstep(1.2, 2.2, nt[x]);
      r += fat * (0.86 - r);
      g += fat * (0.70 - g);
      b += fat * (0.40 - b);
      const double mottle = 1.0 + c * (0.09 * nf[x] + 0.08 * nm[x] + 0.06 * nl[x]);
      r *= mottle;
      g *= mottle;
      b *= mottle;
      const double dv_ = 0.55 * dv[x], vv_ = vv[x];
      r += dv_ * (0.38 - r);
      g += dv_ * (0.14 - g);
      b += dv_ * (0.30 - b);
      r += vv_ * (0.40 - r);
      g += vv_ * (0.06 - g);
      b += vv_ * (0.10 - b);
      a[3 * x + 0] = float(std::min(1.0, std::max(0.01, b)));
      a[3 * x + 1] = float(std::min(1.0, std::max(0.01, g)));
      a[3 * x + 2] = float(std::min(1.0, std::max(0.01, r)));
    }
  }
  // Micro relief (shading only): slopes of a fine random height field, rms slope ~0.06.
  cv::Mat relief = 0.6 * noiseField(rng, size, 2.0) + 0.4 * noiseField(rng, size, 5.0) + 0.8 * vf;
  cv::Mat sx, sy;
  cv::Sobel(relief, sx, CV_32F, 1, 0, 3, 1.0 / 8.0);
  cv::Sobel(relief, sy, CV_32F, 0, 1, 3, 1.0 / 8.0);
  cv::Scalar m1, s1, m2, s2;
  cv::meanStdDev(sx, m1, s1);
  cv::meanStdDev(sy, m2, s2);
  const double scale = 0.06 / std::max(1e-6, std::sqrt(0.5 * (s1[0] * s1[0] + s2[0] * s2[0])));
  std::vector<cv::Mat> ch{sx * scale, sy * scale};
  cv::merge(ch, bump_grad);

  // Brushed metal: streaks along the shaft (fine across the angle, coarse along the axis).
  // Rows = axial cells of metal_axial_cell metres from the tip, cols = angle around the axis.
  cv::Mat streaks;
  cv::resize(noiseField(rng, cv::Size(256, 24), 1.5), streaks, cv::Size(256, 480), 0, 0,
             cv::INTER_LINEAR);
  metal = 0.9 * streaks + 0.3 * noiseField(rng, cv::Size(256, 480), 2.0);
  metal_axial_cell = 0.00025;
}

// ================================================================================================
SurgicalScene::SurgicalScene(const SurgicalSceneParams& params) : params_(params) {
  const std::string error = params.validate();
  if (!error.empty()) throw std::invalid_argument(error);
  impl_ = std::make_unique<Impl>(params);
  impl_->build();

  // camera_info model.
  const Impl& m = *impl_;
  const char* frames[2] = {"endoscope_left_optical", "endoscope_right_optical"};
  for (int k = 0; k < 2; ++k) {
    CameraCalibration& c = k == 0 ? calibration_.left : calibration_.right;
    c.width = params.width;
    c.height = params.height;
    c.distortion_model = "plumb_bob";
    c.D.assign(m.cam[k].D.begin(), m.cam[k].D.end());
    c.K = m.cam[k].K;
    c.R = k == 0 ? m.R1 : m.R2;
    c.P = k == 0 ? m.P1 : m.P2;
    c.frame_id = frames[k];
  }
  calibration_.R_right_left = m.cam[1].R_rig_cam.t() * m.cam[0].R_rig_cam;
  calibration_.T_right_left = m.cam[1].R_rig_cam.t() * (m.cam[0].center_rig - m.cam[1].center_rig);
  calibration_.has_extrinsics = true;
}

SurgicalScene::~SurgicalScene() = default;

RectifiedGeometry SurgicalScene::geometry() const {
  RectifiedGeometry g;
  g.width = params_.width;
  g.height = params_.height;
  g.f_px = calibration_.left.P(0, 0);
  g.cx_left = calibration_.left.P(0, 2);
  g.cx_right = calibration_.right.P(0, 2);
  g.cy = calibration_.left.P(1, 2);
  g.baseline_m = impl_->baseline;
  g.metric = true;
  g.frame_id = calibration_.left.frame_id;
  return g;
}

void SurgicalScene::suggestedDisparityRange(int* min_disparity, int* max_disparity) const {
  if (min_disparity) *min_disparity = impl_->min_d;
  if (max_disparity) *max_disparity = impl_->max_d;
}

void SurgicalScene::render(int index, SurgicalFrame& out) const {
  if (index < 0) throw std::invalid_argument("SurgicalScene::render: index must be >= 0");
  const Impl& m = *impl_;
  const SurgicalSceneParams& p = params_;
  const int W = p.width, H = p.height;
  out.index = index;
  out.stamp_s = index / p.fps;
  out.gt_disparity.create(H, W, CV_32FC1);
  out.gt_depth_m.create(H, W, CV_32FC1);
  out.visibility.create(H, W, CV_8UC1);
  out.instrument_mask.create(H, W, CV_8UC1);
  out.left_specular = cv::Mat::zeros(H, W, CV_8UC1);
  out.right_specular = cv::Mat::zeros(H, W, CV_8UC1);

  const double field_dt = p.interlaced ? 0.5 / p.fps : 0.0;
  const int n = p.motion_blur_samples;
  // Ground truth belongs to the capture time of each row (the middle of its exposure). Without
  // blur and lens distortion the left rays are the rectified ones: one pass gives both.
  const bool gt_with_left = !p.distorted && n == 1;
  auto statesAt = [&](double t, std::vector<State>* states, std::vector<int>* row_state) {
    states->assign(1, m.stateAt(t));
    row_state->assign(H, 0);
    if (p.interlaced) {
      states->push_back(m.stateAt(t + field_dt));
      for (int v = 1; v < H; v += 2) (*row_state)[v] = 1;
    }
  };
  std::vector<State> states;
  std::vector<int> row_state;
  if (!gt_with_left) {
    statesAt(out.stamp_s, &states, &row_state);
    m.castView(m.cam[0], m.gt_dirs, states, row_state, nullptr, 0.0f, nullptr, &out);
  }
  cv::Mat acc[2];
  for (int view = 0; view < 2; ++view) {
    acc[view] = cv::Mat::zeros(H, W, CV_32FC3);
    for (int k = 0; k < n; ++k) {
      const double offset = n == 1 ? 0.0 : p.exposure_s * (double(k) / (n - 1) - 0.5);
      statesAt(out.stamp_s + offset, &states, &row_state);
      m.castView(m.cam[view], m.cam[view].dirs, states, row_state, &acc[view], 1.0f / n,
                 view == 0 ? &out.left_specular : &out.right_specular,
                 view == 0 && gt_with_left ? &out : nullptr);
    }
    if (p.noise_sigma > 0) {
      cv::RNG rng(mixSeed(p.seed, 1000003ull * uint64_t(index) + 17 + view));
      cv::Mat noise(H, W, CV_32FC3);
      rng.fill(noise, cv::RNG::NORMAL, 0.0, p.noise_sigma);
      acc[view] += noise;
    }
    acc[view].convertTo(view == 0 ? out.left : out.right, CV_8UC3);
  }
}

// ================================================================================================
double groundTruthWarpError(const SurgicalFrame& frame, double disparity_offset_px, int margin_px,
                            int64_t* count) {
  const cv::Mat& gt = frame.gt_disparity;
  cv::Mat lo, hi;
  const cv::Mat kernel =
      cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * margin_px + 1, 2 * margin_px + 1));
  cv::erode(gt, lo, kernel);
  cv::dilate(gt, hi, kernel);
  cv::Mat left, right;
  frame.left.convertTo(left, CV_32FC3);
  frame.right.convertTo(right, CV_32FC3);
  double sum = 0.0;
  int64_t n = 0;
  for (int y = 0; y < gt.rows; ++y) {
    const float* d = gt.ptr<float>(y);
    const float *l = lo.ptr<float>(y), *h = hi.ptr<float>(y);
    const uint8_t* vis = frame.visibility.ptr<uint8_t>(y);
    const uint8_t* ls = frame.left_specular.ptr<uint8_t>(y);
    const uint8_t* rs = frame.right_specular.ptr<uint8_t>(y);
    const float* lp = left.ptr<float>(y);
    for (int x = 0; x < gt.cols; ++x) {
      if (vis[x] != kVisibleBoth || ls[x] || !std::isfinite(d[x]) || h[x] - l[x] > 1.0f) continue;
      const double xr = x - (d[x] + disparity_offset_px);
      if (xr < 0 || xr >= gt.cols - 1) continue;
      const int x0 = int(xr);
      if (rs[x0] || rs[x0 + 1]) continue;
      const double a = xr - x0;
      const float* r0 = right.ptr<float>(y) + 3 * x0;
      for (int c = 0; c < 3; ++c) {
        const double v = (1 - a) * r0[c] + a * r0[3 + c];
        sum += std::abs(v - lp[3 * x + c]);
      }
      ++n;
    }
  }
  if (count) *count = n;
  return n ? sum / (3.0 * n) : 0.0;
}

}  // namespace endo_stereo
