#include "depth_track/core/camera_check.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <sstream>

#include "depth_track/core/angles.hpp"

namespace depth_track {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// A plane in inverse depth: 1/z = g + a x + b y, x and y normalised image coordinates.
struct InvPlane {
  double g = 0.0, a = 0.0, b = 0.0;
  double depth(double x, double y) const {
    const double w = g + a * x + b * y;
    return w > 0.0 ? 1.0 / w : 0.0;
  }
};

struct PlaneSample {
  double x, y, z;
};

struct PlaneFit {
  bool ok = false;
  InvPlane plane;
  double sigma_m = 0.0;  ///< sd of the kept depths about the plane (3 degrees of freedom removed)
  std::size_t used = 0;
};

double medianOf(std::vector<double> v) {
  if (v.empty()) return kNaN;
  const std::size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + mid, v.end());
  double m = v[mid];
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + mid));
  return m;
}

/// Least squares in depth: a linear start in inverse depth (weights z^4 turn its residual into
/// roughly the depth residual, since d(1/z) = -dz / z^2), then Gauss-Newton on the depth residuals
/// themselves. The start alone is biased by about 3 sigma^2 / z (the weights follow the noisy
/// depths): 1.9 mm at 3 m for 43 mm of stereo noise.
bool solvePlane(const std::vector<PlaneSample>& s, const std::vector<char>& keep, InvPlane* out) {
  auto solve = [](const Eigen::Matrix3d& A, const Eigen::Vector3d& rhs, Eigen::Vector3d* p) {
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(A);
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 1e-12 * A.trace()))
      return false;
    *p = ldlt.solve(rhs);
    return p->allFinite();
  };
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
  std::size_t n = 0;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (!keep[i]) continue;
    const double z2 = s[i].z * s[i].z, w = z2 * z2;
    const Eigen::Vector3d j(1.0, s[i].x, s[i].y);
    A += w * j * j.transpose();
    rhs += w * j / s[i].z;
    ++n;
  }
  Eigen::Vector3d p;
  if (n < 3 || !solve(A, rhs, &p) || !(p(0) > 0.0)) return false;
  for (int it = 0; it < 3; ++it) {
    A.setZero();
    rhs.setZero();
    for (std::size_t i = 0; i < s.size(); ++i) {
      if (!keep[i]) continue;
      const Eigen::Vector3d j(1.0, s[i].x, s[i].y);
      const double w = p.dot(j);
      if (!(w > 0.0)) return false;
      const double d = 1.0 / w, d2 = d * d;
      A += d2 * d2 * j * j.transpose();
      rhs -= d2 * (s[i].z - d) * j;
    }
    Eigen::Vector3d step;
    if (!solve(A, rhs, &step)) return false;
    p += step;
    if (step.norm() < 1e-12 * p.norm()) break;
  }
  out->g = p(0), out->a = p(1), out->b = p(2);
  return out->g > 0.0;
}

/// Plane fit that leaves out gross outliers: refits twice keeping residuals within 4 robust
/// sigmas (MAD), so a stray return does not tilt the plane, while a Gaussian loses < 0.01 %.
PlaneFit fitPlaneRobust(const std::vector<PlaneSample>& s) {
  PlaneFit f;
  if (s.size() < 12) return f;
  std::vector<char> keep(s.size(), 1);
  if (!solvePlane(s, keep, &f.plane)) return f;
  std::vector<double> r(s.size());
  for (int round = 0; round < 2; ++round) {
    for (std::size_t i = 0; i < s.size(); ++i) r[i] = s[i].z - f.plane.depth(s[i].x, s[i].y);
    const double med = medianOf(r);
    std::vector<double> dev(r.size());
    for (std::size_t i = 0; i < r.size(); ++i) dev[i] = std::abs(r[i] - med);
    // Quantised depths can make most residuals equal, and the MAD collapse: fall back to the RMS.
    const double mad_sigma = 1.4826 * medianOf(dev);
    double rms = 0.0;
    for (double e : r) rms += e * e;
    rms = std::sqrt(rms / r.size());
    const double limit = 4.0 * std::max(mad_sigma > 0.25 * rms ? mad_sigma : rms, 1e-6);
    for (std::size_t i = 0; i < s.size(); ++i) keep[i] = std::abs(r[i]) <= limit;
    if (!solvePlane(s, keep, &f.plane)) return f;
  }
  double ss = 0.0;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (!keep[i]) continue;
    const double e = s[i].z - f.plane.depth(s[i].x, s[i].y);
    ss += e * e;
    ++f.used;
  }
  if (f.used < 4) return f;
  f.sigma_m = std::sqrt(ss / static_cast<double>(f.used - 3));
  f.ok = true;
  return f;
}

/// Least-squares circle (u - uc)^2 + (w - wc)^2 = R^2 through points (algebraic fit; the outline
/// points are spread round the circle, where its bias is negligible).
struct Circle {
  bool ok = false;
  double uc = 0.0, wc = 0.0, r = 0.0, rms = 0.0;
};

Circle fitCircle(const std::vector<Eigen::Vector2d>& p, const std::vector<char>* keep = nullptr) {
  Circle c;
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
  std::size_t n = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (keep && !(*keep)[i]) continue;
    const Eigen::Vector3d j(p[i].x(), p[i].y(), 1.0);
    A += j * j.transpose();
    rhs += j * p[i].squaredNorm();
    ++n;
  }
  if (n < 5) return c;
  const Eigen::Vector3d s = A.ldlt().solve(rhs);
  c.uc = 0.5 * s(0), c.wc = 0.5 * s(1);
  const double r2 = s(2) + c.uc * c.uc + c.wc * c.wc;
  if (!(r2 > 0.0) || !s.allFinite()) return c;
  c.r = std::sqrt(r2);
  double ss = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (keep && !(*keep)[i]) continue;
    const double e = (p[i] - Eigen::Vector2d(c.uc, c.wc)).norm() - c.r;
    ss += e * e;
  }
  c.rms = std::sqrt(ss / n);
  c.ok = true;
  return c;
}

/// Circle fit that drops points more than 3 robust sigmas (at least 0.3 px) off the first fit:
/// sectors where a support or an occluder meets the outline.
Circle fitCircleRobust(const std::vector<Eigen::Vector2d>& p, std::vector<char>* keep_out) {
  std::vector<char> keep(p.size(), 1);
  Circle c = fitCircle(p, &keep);
  for (int round = 0; round < 2 && c.ok; ++round) {
    std::vector<double> r(p.size());
    for (std::size_t i = 0; i < p.size(); ++i)
      r[i] = std::abs((p[i] - Eigen::Vector2d(c.uc, c.wc)).norm() - c.r);
    const double limit = std::max(3.0 * 1.4826 * medianOf(r), 0.3);
    for (std::size_t i = 0; i < p.size(); ++i) keep[i] = r[i] <= limit;
    c = fitCircle(p, &keep);
  }
  if (keep_out) *keep_out = keep;
  return c;
}

/// A sample of the edge: signed distance from the outline, returns on the face, all returns.
struct EdgeSample {
  double s;
  float fg, ret;
};

/// Non-increasing isotonic regression (pool adjacent violators) of the face share over samples
/// sorted by s, weighted by their returns. Returns the blocks as (first s, last s, value).
struct Block {
  double s_first, s_last, fg, ret;
  double value() const { return fg / ret; }
};

std::vector<Block> isotonicDecreasing(const std::vector<EdgeSample>& sorted) {
  std::vector<Block> b;
  for (const EdgeSample& e : sorted) {
    if (e.ret <= 0.0f) continue;
    b.push_back({e.s, e.s, e.fg, e.ret});
    while (b.size() > 1 && b[b.size() - 2].value() < b.back().value()) {
      Block& prev = b[b.size() - 2];
      prev.s_last = b.back().s_last;
      prev.fg += b.back().fg;
      prev.ret += b.back().ret;
      b.pop_back();
    }
  }
  return b;
}

/// The area-equivalent edge of an isotonic fit over [s_lo, s_hi]: where a sharp step from 1 to 0
/// would hold the same share of face returns. Equal to the 50 % point for a symmetric blur; for
/// an edge that bleeds to one side it stays defined where a 50 % point is not (a plateau at half
/// the face share), and the constant pixel offset it then carries is what the focal fit removes.
/// The step runs between the fit's innermost and outermost levels, so a face share a little below
/// 1 inside (or above 0 outside) does not move it.
double equivalentEdge(const std::vector<Block>& b, double s_lo, double s_hi) {
  if (b.empty()) return kNaN;
  const double in = b.front().value(), out = b.back().value();
  if (!(in - out > 0.1)) return kNaN;
  double area = 0.0;
  for (std::size_t i = 0; i < b.size(); ++i) {
    const double from = i == 0 ? s_lo : 0.5 * (b[i - 1].s_last + b[i].s_first);
    const double to = i + 1 == b.size() ? s_hi : 0.5 * (b[i].s_last + b[i + 1].s_first);
    area += (b[i].value() - out) * (to - from);
  }
  return s_lo + area / (in - out);
}

/// Where the isotonic fit falls below `level`: midway between the last sample above and the first
/// below (a sharp edge then reads as a step, not as the width of its blocks). NaN if it never does.
double crossing(const std::vector<Block>& b, double level) {
  for (std::size_t i = 1; i < b.size(); ++i)
    if (b[i - 1].value() >= level && b[i].value() < level)
      return 0.5 * (b[i - 1].s_last + b[i].s_first);
  return kNaN;
}

/// 4-connected flood fill over a w x h image: `seeds(add)` calls add(u, v) for each start pixel;
/// `take(u, v)` marks a pixel and returns true if it joins the fill (and is expanded from).
template <class Take, class Seeds>
void floodFill(int w, int h, Take&& take, Seeds&& seeds) {
  std::deque<std::pair<int, int>> q;
  auto add = [&](int u, int v) {
    if (take(u, v)) q.emplace_back(u, v);
  };
  seeds(add);
  while (!q.empty()) {
    const auto [u, v] = q.front();
    q.pop_front();
    if (u > 0) add(u - 1, v);
    if (u + 1 < w) add(u + 1, v);
    if (v > 0) add(u, v - 1);
    if (v + 1 < h) add(u, v + 1);
  }
}

/// One line of n pixels `stride` apart: out = 1 where every pixel within r along the line (clipped
/// at its ends) is set.
void erodeLine(const char* in, char* out, int n, std::size_t stride, int r) {
  std::vector<int> prefix(n + 1, 0);
  for (int i = 0; i < n; ++i) prefix[i + 1] = prefix[i] + (in[i * stride] ? 1 : 0);
  for (int i = 0; i < n; ++i) {
    const int lo = std::max(0, i - r), hi = std::min(n - 1, i + r);
    out[i * stride] = prefix[hi + 1] - prefix[lo] == hi - lo + 1;
  }
}

/// Chessboard erosion of a mask by r pixels; pixels outside the image count as set (a target
/// clipped by the image border keeps its face up to the border). Separable: rows, then columns.
std::vector<char> erode(const std::vector<char>& m, int w, int h, int r) {
  if (r <= 0) return m;
  std::vector<char> rows(m.size(), 0), out(m.size(), 0);
  for (int v = 0; v < h; ++v)
    erodeLine(&m[static_cast<std::size_t>(v) * w], &rows[static_cast<std::size_t>(v) * w], w, 1, r);
  for (int u = 0; u < w; ++u) erodeLine(&rows[u], &out[u], h, w, r);
  return out;
}

/// Chessboard dilation of a mask by r pixels.
std::vector<char> dilate(const std::vector<char>& m, int w, int h, int r) {
  std::vector<char> inv(m.size());
  for (std::size_t i = 0; i < m.size(); ++i) inv[i] = !m[i];
  std::vector<char> e = erode(inv, w, h, r);
  // Outside the image counts as set for erode; for the complement that means "not set", which
  // is what a dilation wants at the border.
  for (std::size_t i = 0; i < e.size(); ++i) e[i] = !e[i];
  return e;
}

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

/// Everything measureSegment derives from the frames before the per-frame fits.
struct Geometry {
  int w = 0, h = 0;
  std::vector<double> xs, ys;  ///< normalised coordinates of columns and rows
  PlaneSample sample(int u, int v, double z) const { return {xs[u], ys[v], z}; }
};

void checkInputs(const SegmentFrames& seg, const PinholeIntrinsics& K, const CameraCheckConfig& c) {
  const auto kp = K.validate();
  if (!kp.empty()) throw std::invalid_argument("camera_check intrinsics: " + joinProblems(kp));
  const auto cp = c.validate();
  if (!cp.empty()) throw std::invalid_argument("CameraCheckConfig: " + joinProblems(cp));
  if (seg.frames.empty())
    throw CameraCheckError("segment '" + seg.label +
                           "' has no frames (is the time range inside the recording?)");
  for (std::size_t i = 0; i < seg.frames.size(); ++i) {
    const DepthImage& f = seg.frames[i];
    if (f.width != K.width || f.height != K.height ||
        f.data.size() != static_cast<std::size_t>(f.width) * f.height) {
      std::ostringstream s;
      s << "segment '" << seg.label << "': frame " << i << " is " << f.width << "x" << f.height
        << " px (" << f.data.size() << " values) but the camera is " << K.width << "x" << K.height;
      throw CameraCheckError(s.str());
    }
  }
}

}  // namespace

std::vector<std::string> CameraCheckConfig::validate() const {
  std::vector<std::string> p;
  if (!(std::isfinite(target_diameter_m) && target_diameter_m >= 0.0))
    p.push_back("target_diameter_m must be >= 0 (0 = no round target)");
  if (seed_radius_px < 2 || seed_radius_px > 50) p.push_back("seed_radius_px must be in 2..50");
  if (interior_margin_px < 0 || interior_margin_px > 50)
    p.push_back("interior_margin_px must be in 0..50");
  if (wall_window_px < 5) p.push_back("wall_window_px must be >= 5");
  if (edge_window_px < 3 || edge_window_px > 40) p.push_back("edge_window_px must be in 3..40");
  if (edge_sectors < 8 || edge_sectors > 720) p.push_back("edge_sectors must be in 8..720");
  if (!(face_tolerance_sigmas >= 3.0 && face_tolerance_sigmas <= 20.0))
    p.push_back("face_tolerance_sigmas must be in 3..20");
  if (!(std::isfinite(depth_unit_m) && depth_unit_m >= 0.0 && depth_unit_m < 0.05))
    p.push_back("depth_unit_m must be in [0, 0.05) m");
  return p;
}

SegmentResult measureSegment(const SegmentFrames& seg, const PinholeIntrinsics& K,
                             const CameraCheckConfig& cfg) {
  checkInputs(seg, K, cfg);
  const int w = K.width, h = K.height;
  const std::size_t npx = static_cast<std::size_t>(w) * h;
  const std::size_t nf = seg.frames.size();
  const std::string who = "segment '" + seg.label + "'";
  Geometry geo;
  geo.w = w, geo.h = h;
  for (int u = 0; u < w; ++u) geo.xs.push_back((u - K.cx) / K.fx);
  for (int v = 0; v < h; ++v) geo.ys.push_back((v - K.cy) / K.fy);

  SegmentResult res;
  res.label = seg.label;
  res.t_start_s = seg.t_start_s, res.t_end_s = seg.t_end_s;
  res.frames = static_cast<int>(nf);
  res.reference_distance_m = seg.reference_distance_m;

  // Per-pixel median over the frames that have a return in at least half of them: the region is
  // found on this image, so single-frame noise and drop-outs do not cut it.
  std::vector<float> med(npx, 0.0f);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    std::vector<float> buf;
    buf.reserve(nf);
    for (int v = r.begin(); v < r.end(); ++v)
      for (int u = 0; u < w; ++u) {
        const std::size_t i = static_cast<std::size_t>(v) * w + u;
        buf.clear();
        for (const DepthImage& f : seg.frames)
          if (f.data[i] > 0.0f) buf.push_back(f.data[i]);
        if (buf.empty() || 2 * buf.size() < nf) continue;
        std::nth_element(buf.begin(), buf.begin() + buf.size() / 2, buf.end());
        med[i] = buf[buf.size() / 2];
      }
  });

  // ---- seed plane: the window around the seed pixel
  const int su = static_cast<int>(std::lround(std::isfinite(cfg.seed_u_px) ? cfg.seed_u_px : K.cx));
  const int sv = static_cast<int>(std::lround(std::isfinite(cfg.seed_v_px) ? cfg.seed_v_px : K.cy));
  const int sr = cfg.seed_radius_px;
  if (su - sr < 0 || sv - sr < 0 || su + sr >= w || sv + sr >= h)
    throw std::invalid_argument(who + ": seed pixel (" + std::to_string(su) + ", " +
                                std::to_string(sv) + ") is too close to the image border");
  auto seedSamples = [&](const std::vector<float>& z) {
    std::vector<PlaneSample> s;
    for (int v = sv - sr; v <= sv + sr; ++v)
      for (int u = su - sr; u <= su + sr; ++u) {
        const float d = z[static_cast<std::size_t>(v) * w + u];
        if (d > 0.0f) s.push_back(geo.sample(u, v, d));
      }
    return s;
  };
  const std::size_t seed_px = static_cast<std::size_t>(2 * sr + 1) * (2 * sr + 1);
  const std::vector<PlaneSample> seed = seedSamples(med);
  std::ostringstream where;
  where << who << ": no planar region at pixel (" << su << ", " << sv << ")";
  if (2 * seed.size() < seed_px)
    throw CameraCheckError(where.str() + ": only " + std::to_string(seed.size()) + " of the " +
                           std::to_string(seed_px) +
                           " pixels around it return a depth in most frames (is anything in "
                           "range in front of the camera?)");
  const PlaneFit seed_fit = fitPlaneRobust(seed);
  const double seed_z = seed_fit.ok ? seed_fit.plane.depth(geo.xs[su], geo.ys[sv]) : 0.0;
  if (!seed_fit.ok)
    throw CameraCheckError(where.str() + ": the depths around it do not determine a plane");
  if (seed_fit.sigma_m > 0.02 * seed_z || 2 * seed_fit.used < seed.size())
    throw CameraCheckError(where.str() + ": the depths around it do not lie on a plane (" +
                           fmt("%.1f", 1e3 * seed_fit.sigma_m) + " mm about the best plane at " +
                           fmt("%.3f", seed_z) + " m)");

  // Single-frame noise sets the tolerance of "on the face": the seed window of a few frames.
  std::vector<double> frame_sigmas;
  for (std::size_t f = 0; f < std::min<std::size_t>(nf, 5); ++f) {
    const PlaneFit pf = fitPlaneRobust(seedSamples(seg.frames[f].data));
    if (pf.ok) frame_sigmas.push_back(pf.sigma_m);
  }
  const double sigma1 = frame_sigmas.empty() ? seed_fit.sigma_m : medianOf(frame_sigmas);
  const double floor_m = 0.002 + 2.0 * cfg.depth_unit_m;
  const double tol = std::max(cfg.face_tolerance_sigmas * sigma1, floor_m);
  // The median image scatters less than a frame: its own tolerance keeps a stand or a wall a
  // little behind the target out of the region even when one frame's noise would not.
  const double tol_med = std::max(cfg.face_tolerance_sigmas * seed_fit.sigma_m, floor_m);

  // ---- region: pixels connected to the seed window whose median depth lies on the plane
  auto grow = [&](const InvPlane& plane) {
    std::vector<char> in(npx, 0);
    floodFill(
        w, h,
        [&](int u, int v) {
          const std::size_t i = static_cast<std::size_t>(v) * w + u;
          if (in[i] || med[i] <= 0.0f) return false;
          if (std::abs(med[i] - plane.depth(geo.xs[u], geo.ys[v])) >= tol_med) return false;
          in[i] = 1;
          return true;
        },
        [&](auto&& seed) {
          for (int v = sv - sr; v <= sv + sr; ++v)
            for (int u = su - sr; u <= su + sr; ++u) seed(u, v);
        });
    return in;
  };
  // Plane samples of a mask on an image, at most ~40 000 (evenly strided) to bound the fit's cost.
  auto maskSamples = [&](const std::vector<char>& m, const std::vector<float>& z) {
    const std::size_t count = static_cast<std::size_t>(std::count(m.begin(), m.end(), 1));
    const std::size_t stride = std::max<std::size_t>(1, count / 40000);
    std::vector<PlaneSample> s;
    std::size_t k = 0;
    for (std::size_t i = 0; i < npx; ++i) {
      if (!m[i] || z[i] <= 0.0f) continue;
      if (k++ % stride) continue;
      s.push_back(geo.sample(static_cast<int>(i % w), static_cast<int>(i / w), z[i]));
    }
    return s;
  };
  std::vector<char> region = grow(seed_fit.plane);
  PlaneFit region_fit = fitPlaneRobust(maskSamples(region, med));
  if (region_fit.ok) region = grow(region_fit.plane);
  if (!region_fit.ok) region_fit = seed_fit;

  // Filled region: the region and every hole it encloses (drop-outs on the face).
  std::vector<char> filled(npx, 1);
  floodFill(
      w, h,
      [&](int u, int v) {
        const std::size_t i = static_cast<std::size_t>(v) * w + u;
        if (!filled[i] || region[i]) return false;
        filled[i] = 0;
        return true;
      },
      [&](auto&& seed) {
        for (int u = 0; u < w; ++u) seed(u, 0), seed(u, h - 1);
        for (int v = 0; v < h; ++v) seed(0, v), seed(w - 1, v);
      });

  // ---- is it a bounded round target? Outline pixels inside the image, background behind them.
  const double aspect = K.fx / K.fy;  // rows scaled to columns: a frontal disc is a circle
  std::vector<Eigen::Vector2d> outline;
  for (int v = 1; v + 1 < h; ++v)
    for (int u = 1; u + 1 < w; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * w + u;
      if (filled[i] && (!filled[i - 1] || !filled[i + 1] || !filled[i - w] || !filled[i + w]))
        outline.emplace_back(u, v * aspect);
    }
  Circle circle;
  {
    std::string reason;
    if (outline.size() < 24) {
      reason =
          "the plane around the centre has no outline inside the image (a wall filling the view)";
    } else {
      const std::vector<char> ring_outer = dilate(filled, w, h, cfg.edge_window_px / 2);
      std::size_t valid = 0, behind = 0;
      for (std::size_t i = 0; i < npx; ++i) {
        if (!ring_outer[i] || filled[i] || med[i] <= 0.0f) continue;
        ++valid;
        const int u = static_cast<int>(i % w), v = static_cast<int>(i / w);
        if (med[i] > region_fit.plane.depth(geo.xs[u], geo.ys[v]) + tol_med) ++behind;
      }
      circle = fitCircle(outline);
      if (valid > 0 && behind < 0.8 * valid) {
        reason =
            "the plane around the centre is not bounded by a step to a background behind it (" +
            fmt("%.0f", 100.0 * (valid - behind) / valid) +
            " % of the returns around it lie level or nearer: a wall, or a target touching "
            "something)";
      } else if (!circle.ok || circle.rms > std::max(2.0, 0.05 * circle.r)) {
        reason = "the plane around the centre is bounded but not round (outline " +
                 fmt("%.1f", circle.ok ? circle.rms : kNaN) + " px RMS about its best circle)";
      }
    }
    res.target_found = reason.empty();
    res.target_note = res.target_found ? "round target found" : reason;
  }

  // ---- the face whose statistics are measured
  std::vector<char> face;
  if (res.target_found) {
    face = erode(filled, w, h, cfg.interior_margin_px);
  } else {
    face = erode(filled, w, h, cfg.interior_margin_px);
    const int r = cfg.wall_window_px;
    for (int v = 0; v < h; ++v)
      for (int u = 0; u < w; ++u)
        if (std::abs(u - su) > r || std::abs(v - sv) > r)
          face[static_cast<std::size_t>(v) * w + u] = 0;
  }
  std::vector<std::size_t> face_idx;
  for (std::size_t i = 0; i < npx; ++i)
    if (face[i]) face_idx.push_back(i);
  if (face_idx.size() < 50)
    throw CameraCheckError(where.str() + ": the planar region is only " +
                           std::to_string(face_idx.size()) +
                           " pixels once its edges are left out (target too small or too far?)");
  res.face_pixels = static_cast<int>(face_idx.size());
  const PlaneFit face_fit = fitPlaneRobust(maskSamples(face, med));
  const InvPlane plane = face_fit.ok ? face_fit.plane : region_fit.plane;
  {
    const Eigen::Vector3d n(plane.a, plane.b, plane.g);
    res.tilt_deg = std::acos(std::min(1.0, std::abs(plane.g) / n.norm())) * kRadToDeg;
  }
  std::vector<float> plane_z(face_idx.size());
  for (std::size_t k = 0; k < face_idx.size(); ++k)
    plane_z[k] = static_cast<float>(plane.depth(geo.xs[face_idx[k] % w], geo.ys[face_idx[k] / w]));

  // ---- per frame: plane fit of the face, its depth on the axis, spread and drop-outs
  std::vector<PlaneFit> fits(nf);
  std::vector<double> dropout(nf, 0.0);
  // Up to ~40 000 pixels per fit: the plane's depth is then known to 0.5 % of sigma and sigma to
  // 0.3 %, far inside what is reported, at a fraction of the cost of a near target's 170 000.
  const std::size_t fit_stride = std::max<std::size_t>(1, face_idx.size() / 40000);
  tbb::parallel_for(std::size_t(0), nf, [&](std::size_t f) {
    const std::vector<float>& z = seg.frames[f].data;
    std::vector<PlaneSample> s;
    s.reserve(face_idx.size() / fit_stride + 1);
    std::size_t returns = 0;
    for (std::size_t k = 0; k < face_idx.size(); ++k) {
      const float d = z[face_idx[k]];
      if (!(d > 0.0f)) continue;
      ++returns;
      if (k % fit_stride == 0 && std::abs(d - plane_z[k]) < tol)
        s.push_back(
            geo.sample(static_cast<int>(face_idx[k] % w), static_cast<int>(face_idx[k] / w), d));
    }
    dropout[f] = 1.0 - static_cast<double>(returns) / face_idx.size();
    fits[f] = fitPlaneRobust(s);
  });
  std::vector<double> axis_depth;
  double var_sum = 0.0;
  for (std::size_t f = 0; f < nf; ++f) {
    if (!fits[f].ok) continue;
    axis_depth.push_back(1.0 / fits[f].plane.g);
    var_sum += fits[f].sigma_m * fits[f].sigma_m;
  }
  if (axis_depth.empty())
    throw CameraCheckError(where.str() +
                           ": no frame has enough returns on the face to fit its plane");
  const double n_ok = static_cast<double>(axis_depth.size());
  res.camera_depth_m = std::accumulate(axis_depth.begin(), axis_depth.end(), 0.0) / n_ok;
  double sd = 0.0;
  for (double d : axis_depth) sd += (d - res.camera_depth_m) * (d - res.camera_depth_m);
  res.camera_depth_sd_m = axis_depth.size() > 1 ? std::sqrt(sd / (n_ok - 1.0)) : 0.0;
  res.sigma_spatial_m = std::sqrt(var_sum / n_ok);
  res.dropout_share = std::accumulate(dropout.begin(), dropout.end(), 0.0) / nf;
  if (std::isfinite(seg.reference_distance_m) && seg.reference_distance_m > 0.0)
    res.error_pct =
        100.0 * (res.camera_depth_m - seg.reference_distance_m) / seg.reference_distance_m;

  // ---- temporal: each face pixel's spread over the frames, pooled
  if (nf >= 2) {
    double ss = 0.0, dof = 0.0;
    for (std::size_t k = 0; k < face_idx.size(); ++k) {
      double mean = 0.0, m2 = 0.0;
      int n = 0;
      for (const DepthImage& f : seg.frames) {
        const float d = f.data[face_idx[k]];
        if (!(d > 0.0f) || std::abs(d - plane_z[k]) >= tol) continue;
        ++n;
        const double delta = d - mean;
        mean += delta / n;
        m2 += delta * (d - mean);
      }
      if (n >= 2) ss += m2, dof += n - 1;
    }
    if (dof > 0.0) res.sigma_temporal_m = std::sqrt(ss / dof);
  }

  if (!res.target_found) return res;

  // ---- outline: located sector by sector at the equivalent edge of the share of face returns
  const int win = cfg.edge_window_px;
  const double r0 = circle.r;
  struct EdgePixel {
    int u, v;
    float fg, ret;
  };
  std::vector<EdgePixel> edge_px;
  const double reach = win + 3.0 + 0.02 * r0;  // the circle may still move while it is refined
  for (int v = 1; v + 1 < h; ++v)
    for (int u = 1; u + 1 < w; ++u) {
      const double rho = std::hypot(u - circle.uc, v * aspect - circle.wc);
      if (std::abs(rho - r0) > reach) continue;
      const std::size_t i = static_cast<std::size_t>(v) * w + u;
      const double pz = plane.depth(geo.xs[u], geo.ys[v]);
      float fg = 0.0f, ret = 0.0f;
      for (const DepthImage& f : seg.frames) {
        const float d = f.data[i];
        if (!(d > 0.0f)) continue;
        ret += 1.0f;
        if (std::abs(d - pz) < tol) fg += 1.0f;
      }
      if (ret > 0.0f) edge_px.push_back({u, v, fg, ret});
    }

  const int nsec = cfg.edge_sectors;
  std::vector<char> sector_ok;
  std::vector<Eigen::Vector2d> points;
  std::vector<int> point_sector;
  std::vector<char> keep;
  auto sectorInside = [&](double uc, double wc, double r, double theta) {
    const double u = uc + r * std::cos(theta), v = (wc + r * std::sin(theta)) / aspect;
    return u >= win + 1 && v >= win + 1 && u <= w - win - 2 && v <= h - win - 2;
  };
  for (int iter = 0; iter < 6; ++iter) {
    std::vector<std::vector<EdgeSample>> sec(nsec);
    for (const EdgePixel& p : edge_px) {
      const double du = p.u - circle.uc, dw = p.v * aspect - circle.wc;
      const double s = std::hypot(du, dw) - circle.r;
      if (std::abs(s) > win) continue;
      int k = static_cast<int>(std::floor((std::atan2(dw, du) + M_PI) / (2.0 * M_PI) * nsec));
      k = std::clamp(k, 0, nsec - 1);
      sec[k].push_back({s, p.fg, p.ret});
    }
    points.clear();
    point_sector.clear();
    sector_ok.assign(nsec, 0);
    for (int k = 0; k < nsec; ++k) {
      const double theta = -M_PI + (k + 0.5) * 2.0 * M_PI / nsec;
      if (sec[k].size() < 8 || !sectorInside(circle.uc, circle.wc, circle.r, theta)) continue;
      std::sort(sec[k].begin(), sec[k].end(),
                [](const EdgeSample& a, const EdgeSample& b) { return a.s < b.s; });
      const std::vector<Block> b = isotonicDecreasing(sec[k]);
      if (b.size() < 2 || b.front().value() < 0.8 || b.back().value() > 0.2) continue;
      const double se = equivalentEdge(b, -win, win);
      if (!std::isfinite(se)) continue;
      sector_ok[k] = 1;
      const double r = circle.r + se;
      points.emplace_back(circle.uc + r * std::cos(theta), circle.wc + r * std::sin(theta));
      point_sector.push_back(k);
    }
    const Circle next = fitCircleRobust(points, &keep);
    if (!next.ok) break;
    const double moved = std::max({std::abs(next.uc - circle.uc), std::abs(next.wc - circle.wc),
                                   std::abs(next.r - circle.r)});
    circle = next;
    if (moved < 0.002) break;
  }
  int used_sectors = 0;
  for (std::size_t j = 0; j < keep.size() && j < point_sector.size(); ++j)
    if (keep[j])
      ++used_sectors;
    else
      sector_ok[point_sector[j]] = 0;
  if (used_sectors < std::max(6, nsec / 6)) {
    res.target_found = false;
    res.target_note = "a bounded region was found but its outline could be located in only " +
                      std::to_string(used_sectors) + " of " + std::to_string(nsec) +
                      " directions (a round target needs a sixth of its outline in view)";
    return res;
  }
  res.outline_coverage_deg = 360.0 * used_sectors / nsec;
  res.outline_rms_px = circle.rms;
  res.centre_u_px = circle.uc;
  res.centre_v_px = circle.wc / aspect;

  // Edge-spread function over the located sectors, relative to the circle. The sectors fix the
  // centre; the radius is then moved to the equivalent edge of all their samples pooled, which
  // locates it several times more precisely than the fit through the sectors' own (noisier)
  // crossings.
  std::vector<EdgeSample> all;
  std::vector<Block> esf;
  double s88 = kNaN, s50 = kNaN, s12 = kNaN;
  for (int pass = 0; pass < 2; ++pass) {
    all.clear();
    for (const EdgePixel& p : edge_px) {
      const double du = p.u - circle.uc, dw = p.v * aspect - circle.wc;
      const double s = std::hypot(du, dw) - circle.r;
      if (std::abs(s) > win) continue;
      int k = static_cast<int>(std::floor((std::atan2(dw, du) + M_PI) / (2.0 * M_PI) * nsec));
      k = std::clamp(k, 0, nsec - 1);
      if (sector_ok[k]) all.push_back({s, p.fg, p.ret});
    }
    std::sort(all.begin(), all.end(),
              [](const EdgeSample& a, const EdgeSample& b) { return a.s < b.s; });
    esf = isotonicDecreasing(all);
    s88 = crossing(esf, 0.88), s50 = crossing(esf, 0.5), s12 = crossing(esf, 0.12);
    const double se = equivalentEdge(esf, -win, win);
    if (pass == 0 && std::isfinite(se) && std::abs(se) < 2.0) circle.r += se;
  }
  res.diameter_px = 2.0 * circle.r;
  if (std::isfinite(s88) && std::isfinite(s12)) {
    res.edge_spread_px = std::max(0.0, s12 - s88);
    res.edge_spread_mm_per_m = 1e3 * res.edge_spread_px / K.fx;
    // A sharp edge (under half a pixel) has no sides to compare.
    if (res.edge_spread_px >= 0.5 && s12 - s50 > 1e-6)
      res.edge_asymmetry = (s50 - s88) / (s12 - s50);
  }
  const double bin = 0.25;
  const int nbins = static_cast<int>(std::lround(2.0 * win / bin));
  std::vector<EdgeSpreadBin> bins(nbins);
  for (int j = 0; j < nbins; ++j) bins[j].s_px = -win + (j + 0.5) * bin;
  for (const EdgeSample& e : all) {
    const int j = std::clamp(static_cast<int>(std::floor((e.s + win) / bin)), 0, nbins - 1);
    bins[j].face_share += e.fg;
    bins[j].returns += e.ret;
  }
  for (EdgeSpreadBin& b : bins)
    if (b.returns > 0.0) {
      b.face_share /= b.returns;
      res.edge_spread.push_back(b);
    }

  const double z_k = std::isfinite(seg.reference_distance_m) && seg.reference_distance_m > 0.0
                         ? seg.reference_distance_m
                         : res.camera_depth_m;
  if (cfg.target_diameter_m > 0.0) {
    res.cam_k_px = res.diameter_px * z_k / cfg.target_diameter_m;
    res.diameter_est_m = res.diameter_px * res.camera_depth_m / K.fx;
    res.diameter_error_pct = 100.0 * (res.diameter_est_m / cfg.target_diameter_m - 1.0);
  }
  return res;
}

// ---- fits over the segments ---------------------------------------------------------------------

namespace {

/// Number of distinct depths (1 cm apart) among zs.
int distinctDepths(std::vector<double> zs) {
  std::sort(zs.begin(), zs.end());
  int n = 0;
  for (std::size_t i = 0; i < zs.size(); ++i)
    if (i == 0 || zs[i] - zs[i - 1] > 0.01) ++n;
  return n;
}

/// Least squares y = p0 + p1 x; returns false for fewer than two distinct x.
bool fitLine(const std::vector<double>& x, const std::vector<double>& y, double* p0, double* p1,
             double* rms, double* se_p1) {
  const std::size_t n = x.size();
  if (n < 2) return false;
  const double mx = std::accumulate(x.begin(), x.end(), 0.0) / n;
  const double my = std::accumulate(y.begin(), y.end(), 0.0) / n;
  double sxx = 0.0, sxy = 0.0;
  for (std::size_t i = 0; i < n; ++i)
    sxx += (x[i] - mx) * (x[i] - mx), sxy += (x[i] - mx) * (y[i] - my);
  if (!(sxx > 0.0)) return false;
  *p1 = sxy / sxx;
  *p0 = my - *p1 * mx;
  double ss = 0.0;
  for (std::size_t i = 0; i < n; ++i) ss += std::pow(y[i] - *p0 - *p1 * x[i], 2);
  *rms = std::sqrt(ss / n);
  *se_p1 = n > 2 ? std::sqrt(ss / (n - 2) / sxx) : kNaN;
  return true;
}

}  // namespace

CameraCheckFit fitCameraModel(const std::vector<SegmentResult>& segs,
                              const CameraCheckConfig& cfg) {
  CameraCheckFit fit;
  // ---- sigma(z): non-negative least squares in relative error, by trying every subset of the
  // allowed terms (at most 7) and keeping the best one whose coefficients are all >= 0.
  std::vector<double> z, s;
  for (const SegmentResult& r : segs) {
    const double q2 = cfg.depth_unit_m * cfg.depth_unit_m / 12.0;
    const double v = r.sigma_spatial_m * r.sigma_spatial_m - q2;
    if (r.camera_depth_m > 0.0 && v > 0.0) z.push_back(r.camera_depth_m), s.push_back(std::sqrt(v));
  }
  const int distinct = distinctDepths(z);
  fit.sigma_terms = std::min(3, distinct);
  if (fit.sigma_terms > 0) {
    double best = std::numeric_limits<double>::infinity();
    Eigen::Vector3d best_c = Eigen::Vector3d::Zero();
    for (int mask = 1; mask < (1 << fit.sigma_terms); ++mask) {
      std::vector<int> cols;
      for (int j = 0; j < fit.sigma_terms; ++j)
        if (mask & (1 << j)) cols.push_back(j);
      Eigen::MatrixXd A(z.size(), cols.size());
      Eigen::VectorXd b(z.size());
      for (std::size_t i = 0; i < z.size(); ++i) {
        for (std::size_t c = 0; c < cols.size(); ++c) A(i, c) = std::pow(z[i], cols[c]) / s[i];
        b(i) = 1.0;
      }
      const Eigen::VectorXd x = A.colPivHouseholderQr().solve(b);
      if ((x.array() < 0.0).any() || !x.allFinite()) continue;
      const double cost = (A * x - b).squaredNorm();
      if (cost < best) {
        best = cost;
        best_c.setZero();
        for (std::size_t c = 0; c < cols.size(); ++c) best_c(cols[c]) = x(c);
      }
    }
    fit.sigma_const_m = best_c(0), fit.sigma_linear = best_c(1), fit.sigma_quad_per_m = best_c(2);
    fit.sigma_rms_rel = std::sqrt(best / z.size());
    if (fit.sigma_terms == 1)
      fit.notes.push_back("noise measured at one distance: sigma taken as constant");
    if (fit.sigma_terms == 2)
      fit.notes.push_back("noise measured at two distances: sigma fitted as a + b z only");
  } else {
    fit.notes.push_back("noise model not fitted: no segment with a measurable sigma");
  }

  // ---- depth response against the reference distances
  std::vector<double> ref, cam;
  for (const SegmentResult& r : segs)
    if (std::isfinite(r.reference_distance_m) && r.reference_distance_m > 0.0)
      ref.push_back(r.reference_distance_m), cam.push_back(r.camera_depth_m);
  double se = 0.0;
  if (distinctDepths(ref) >= 2 &&
      fitLine(ref, cam, &fit.depth_offset_m, &fit.depth_scale, &fit.depth_rms_m, &se)) {
    fit.depth_fitted = true;
  } else if (!ref.empty()) {
    double num = 0.0, den = 0.0;
    for (std::size_t i = 0; i < ref.size(); ++i) num += cam[i] * ref[i], den += ref[i] * ref[i];
    fit.depth_scale = num / den;
    fit.depth_offset_m = 0.0;
    double ss = 0.0;
    for (std::size_t i = 0; i < ref.size(); ++i)
      ss += std::pow(cam[i] - fit.depth_scale * ref[i], 2);
    fit.depth_rms_m = std::sqrt(ss / ref.size());
    fit.depth_fitted = true;
    fit.notes.push_back("one reference distance: depth response fitted as a scale only");
  } else {
    fit.notes.push_back("depth response not fitted: no reference distances given");
  }

  // ---- focal constant from the outline diameters
  std::vector<double> inv_z, dpx;
  bool camera_depths = false;
  for (const SegmentResult& r : segs) {
    if (!r.target_found || !std::isfinite(r.diameter_px)) continue;
    double zk = r.reference_distance_m;
    if (!(std::isfinite(zk) && zk > 0.0)) zk = r.camera_depth_m, camera_depths = true;
    inv_z.push_back(1.0 / zk);
    dpx.push_back(r.diameter_px);
  }
  if (!(cfg.target_diameter_m > 0.0)) {
    fit.notes.push_back("focal check skipped: no target diameter given");
  } else if (inv_z.empty()) {
    fit.notes.push_back("focal check skipped: no round target found in any segment");
  } else {
    if (camera_depths)
      fit.notes.push_back("focal check uses the camera's own depth where no reference is given");
    double a = 0.0, c = 0.0, rms = 0.0, se_a = kNaN;
    std::vector<double> zs;
    for (double v : inv_z) zs.push_back(1.0 / v);
    if (distinctDepths(zs) >= 2 && fitLine(inv_z, dpx, &c, &a, &rms, &se_a)) {
      fit.cam_k_px = a / cfg.target_diameter_m;
      fit.cam_k_se_px = se_a / cfg.target_diameter_m;
      fit.edge_offset_px = 0.5 * c;
    } else {
      double k = 0.0;
      for (std::size_t i = 0; i < dpx.size(); ++i) k += dpx[i] / inv_z[i] / cfg.target_diameter_m;
      fit.cam_k_px = k / dpx.size();
      fit.edge_offset_px = 0.0;
      fit.notes.push_back(
          "target seen at one distance: CAM_K assumes an unbiased outline (edge offset 0)");
    }
    fit.focal_fitted = true;
  }

  // ---- lateral resolution
  double sum_px = 0.0, sum_mm = 0.0;
  int n_edge = 0;
  fit.edge_symmetric = true;
  for (const SegmentResult& r : segs) {
    if (!std::isfinite(r.edge_spread_px)) continue;
    sum_px += r.edge_spread_px, sum_mm += r.edge_spread_mm_per_m, ++n_edge;
    // NaN: too sharp to tell sides apart, which is symmetric enough.
    if (r.edge_asymmetry < 0.67 || r.edge_asymmetry > 1.5) fit.edge_symmetric = false;
  }
  if (n_edge > 0) {
    fit.edge_spread_px = sum_px / n_edge;
    fit.edge_spread_mm_per_m = sum_mm / n_edge;
    if (!fit.edge_symmetric)
      fit.notes.push_back(
          "the edge spread is lopsided (one side of the outline bleeds or erodes): the noise "
          "model keeps its base's edge behaviour");
  } else {
    fit.edge_symmetric = false;
    fit.notes.push_back("lateral resolution not measured: no target outline");
  }
  for (const SegmentResult& r : segs)
    if (!r.target_found && cfg.target_diameter_m > 0.0)
      fit.notes.push_back("segment '" + r.label + "': no round target: " + r.target_note);
  return fit;
}

double edgeCorrectedCamK(const SegmentResult& r, const CameraCheckFit& fit,
                         const CameraCheckConfig& cfg) {
  if (!fit.focal_fitted || !std::isfinite(r.diameter_px) || !(cfg.target_diameter_m > 0.0))
    return kNaN;
  const double z = std::isfinite(r.reference_distance_m) && r.reference_distance_m > 0.0
                       ? r.reference_distance_m
                       : r.camera_depth_m;
  return (r.diameter_px - 2.0 * fit.edge_offset_px) * z / cfg.target_diameter_m;
}

// ---- text and files
// ------------------------------------------------------------------------------

namespace {

std::string cell(double v, const char* f, int width) {
  char b[64];
  if (std::isfinite(v))
    std::snprintf(b, sizeof b, f, v);
  else
    std::snprintf(b, sizeof b, "-");
  std::string s(b);
  if (static_cast<int>(s.size()) < width) s = std::string(width - s.size(), ' ') + s;
  return s;
}

std::string yamlNum(double v) {
  if (std::isnan(v)) return ".nan";
  if (std::isinf(v)) return v > 0 ? ".inf" : "-.inf";
  char b[64];
  std::snprintf(b, sizeof b, "%.12g", v);
  return b;
}

std::string yamlStr(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    o += c;
  }
  return o + "\"";
}

/// Writes text to path through path.part and a rename, so a failure leaves no half file.
void writeAtomically(const std::string& path, const std::string& text) {
  const std::string part = path + ".part";
  {
    std::ofstream out(part);
    out << text;
    out.close();
    if (!out) {
      std::error_code ec;
      std::filesystem::remove(part, ec);
      throw std::runtime_error("cannot write " + path);
    }
  }
  std::error_code ec;
  std::filesystem::rename(part, path, ec);
  if (ec) {
    std::filesystem::remove(part, ec);
    throw std::runtime_error("cannot write " + path + ": " + ec.message());
  }
}

}  // namespace

std::string formatCameraCheckTable(const std::vector<SegmentResult>& segs,
                                   const CameraCheckFit& fit, const CameraCheckConfig& cfg) {
  std::ostringstream o;
  o << "segment        frames  measured(m)  camera(m)  error%  sd_t(mm)  sd_s(mm)  drop%   D(px)  "
       "CAM_K  CAM_K*  diam.est(m)  diam.err%  edge(px)  edge(mm/m)\n";
  for (const SegmentResult& r : segs) {
    std::string label = r.label.substr(0, 14);
    label += std::string(14 - label.size(), ' ');
    o << label << cell(r.frames, "%.0f", 7) << cell(r.reference_distance_m, "%.3f", 13)
      << cell(r.camera_depth_m, "%.4f", 11) << cell(r.error_pct, "%+.2f", 8)
      << cell(1e3 * r.sigma_temporal_m, "%.2f", 10) << cell(1e3 * r.sigma_spatial_m, "%.2f", 10)
      << cell(100.0 * r.dropout_share, "%.2f", 7) << cell(r.diameter_px, "%.1f", 8)
      << cell(r.cam_k_px, "%.1f", 7) << cell(edgeCorrectedCamK(r, fit, cfg), "%.1f", 8)
      << cell(r.diameter_est_m, "%.4f", 13) << cell(r.diameter_error_pct, "%+.2f", 11)
      << cell(r.edge_spread_px, "%.2f", 10) << cell(r.edge_spread_mm_per_m, "%.2f", 12) << "\n";
  }
  o << "CAM_K* = CAM_K with the fitted edge offset removed; edge = 88-12 % width of the edge "
       "spread\n";
  if (fit.sigma_terms > 0)
    o << "noise model: sigma(z) = " << fmt("%.3f", 1e3 * fit.sigma_const_m) << " mm + "
      << fmt("%.3f", 1e3 * fit.sigma_linear) << " mm/m z + "
      << fmt("%.3f", 1e3 * fit.sigma_quad_per_m) << " mm/m^2 z^2 (RMS relative residual "
      << fmt("%.1f", 100.0 * fit.sigma_rms_rel) << " %)\n";
  if (fit.depth_fitted)
    o << "depth response: camera = " << fmt("%.5f", fit.depth_scale) << " x measured "
      << (fit.depth_offset_m < 0 ? "- " : "+ ") << fmt("%.2f", 1e3 * std::abs(fit.depth_offset_m))
      << " mm (scale error " << fmt("%+.3f", 100.0 * (fit.depth_scale - 1.0)) << " %, RMS "
      << fmt("%.2f", 1e3 * fit.depth_rms_m) << " mm)\n";
  if (fit.focal_fitted)
    o << "focal constant: CAM_K = " << fmt("%.1f", fit.cam_k_px) << " px"
      << (std::isfinite(fit.cam_k_se_px) ? " +- " + fmt("%.1f", fit.cam_k_se_px) : "")
      << " (edge offset " << fmt("%+.2f", fit.edge_offset_px) << " px per side)\n";
  if (std::isfinite(fit.edge_spread_px))
    o << "lateral resolution: " << fmt("%.2f", fit.edge_spread_px)
      << " px = " << fmt("%.2f", fit.edge_spread_mm_per_m) << " mm per metre of depth"
      << (fit.edge_symmetric ? "" : " (lopsided edge)") << "\n";
  for (const std::string& n : fit.notes) o << "note: " << n << "\n";
  return o.str();
}

void writeCameraCheckYaml(const std::string& path, const CameraCheckReport& rep) {
  const CameraCheckFit& f = rep.fit;
  const PinholeIntrinsics& K = rep.intrinsics;
  std::ostringstream o;
  o << "# camera_check: camera characterisation from " << rep.source << "\n"
    << "# camera_check: measurements and fits (docs/camera_check.md explains every field).\n"
    << "# noise_model: load with render_sequence / make_scenario_bag --noise-model FILE or the\n"
    << "#   depth_camera sim backend's ~noise_model_file; effects not measured come from the\n"
    << "#   preset named by base.\n"
    << "# depth_correction: load with track_sequence / evaluate_bag --depth-correction FILE or\n"
    << "#   the ingest nodelet's ~depth_correction; the tracker then reads true depth =\n"
    << "#   (reported - offset_m) / scale.\n";
  o << "camera_check:\n"
    << "  source: " << yamlStr(rep.source) << "\n"
    << "  intrinsics: {width: " << K.width << ", height: " << K.height << ", fx: " << yamlNum(K.fx)
    << ", fy: " << yamlNum(K.fy) << ", cx: " << yamlNum(K.cx) << ", cy: " << yamlNum(K.cy) << "}\n"
    << "  target_diameter_m: " << yamlNum(rep.config.target_diameter_m) << "\n"
    << "  depth_unit_m: " << yamlNum(rep.config.depth_unit_m) << "\n"
    << "  segments:\n";
  for (const SegmentResult& r : rep.segments) {
    o << "    - label: " << yamlStr(r.label) << "\n"
      << "      t_start_s: " << yamlNum(r.t_start_s) << "\n"
      << "      t_end_s: " << yamlNum(r.t_end_s) << "\n"
      << "      frames: " << r.frames << "\n"
      << "      reference_distance_m: " << yamlNum(r.reference_distance_m) << "\n"
      << "      camera_depth_m: " << yamlNum(r.camera_depth_m) << "\n"
      << "      camera_depth_sd_m: " << yamlNum(r.camera_depth_sd_m) << "\n"
      << "      error_pct: " << yamlNum(r.error_pct) << "\n"
      << "      sigma_temporal_m: " << yamlNum(r.sigma_temporal_m) << "\n"
      << "      sigma_spatial_m: " << yamlNum(r.sigma_spatial_m) << "\n"
      << "      dropout_share: " << yamlNum(r.dropout_share) << "\n"
      << "      tilt_deg: " << yamlNum(r.tilt_deg) << "\n"
      << "      face_pixels: " << r.face_pixels << "\n"
      << "      target_found: " << (r.target_found ? "true" : "false") << "\n"
      << "      target_note: " << yamlStr(r.target_note) << "\n"
      << "      centre_px: [" << yamlNum(r.centre_u_px) << ", " << yamlNum(r.centre_v_px) << "]\n"
      << "      diameter_px: " << yamlNum(r.diameter_px) << "\n"
      << "      outline_coverage_deg: " << yamlNum(r.outline_coverage_deg) << "\n"
      << "      outline_rms_px: " << yamlNum(r.outline_rms_px) << "\n"
      << "      cam_k_px: " << yamlNum(r.cam_k_px) << "\n"
      << "      cam_k_edge_corrected_px: " << yamlNum(edgeCorrectedCamK(r, f, rep.config)) << "\n"
      << "      diameter_est_m: " << yamlNum(r.diameter_est_m) << "\n"
      << "      diameter_error_pct: " << yamlNum(r.diameter_error_pct) << "\n"
      << "      edge_spread_px: " << yamlNum(r.edge_spread_px) << "\n"
      << "      edge_spread_mm_per_m: " << yamlNum(r.edge_spread_mm_per_m) << "\n"
      << "      edge_asymmetry: " << yamlNum(r.edge_asymmetry) << "\n";
  }
  o << "  fit:\n"
    << "    sigma_terms: " << f.sigma_terms << "\n"
    << "    sigma_const_m: " << yamlNum(f.sigma_const_m) << "\n"
    << "    sigma_linear: " << yamlNum(f.sigma_linear) << "\n"
    << "    sigma_quad_per_m: " << yamlNum(f.sigma_quad_per_m) << "\n"
    << "    sigma_rms_rel: " << yamlNum(f.sigma_rms_rel) << "\n"
    << "    depth_fitted: " << (f.depth_fitted ? "true" : "false") << "\n"
    << "    depth_scale: " << yamlNum(f.depth_scale) << "\n"
    << "    depth_offset_m: " << yamlNum(f.depth_offset_m) << "\n"
    << "    depth_rms_m: " << yamlNum(f.depth_rms_m) << "\n"
    << "    focal_fitted: " << (f.focal_fitted ? "true" : "false") << "\n"
    << "    cam_k_px: " << yamlNum(f.cam_k_px) << "\n"
    << "    cam_k_se_px: " << yamlNum(f.cam_k_se_px) << "\n"
    << "    edge_offset_px: " << yamlNum(f.edge_offset_px) << "\n"
    << "    edge_spread_px: " << yamlNum(f.edge_spread_px) << "\n"
    << "    edge_spread_mm_per_m: " << yamlNum(f.edge_spread_mm_per_m) << "\n"
    << "    edge_symmetric: " << (f.edge_symmetric ? "true" : "false") << "\n"
    << "  notes:" << (f.notes.empty() ? " []" : "") << "\n";
  for (const std::string& n : f.notes) o << "    - " << yamlStr(n) << "\n";
  o << "  reference_models:" << (rep.reference_models.empty() ? " {}" : "") << "\n";
  for (const ReferenceSigmaModel& m : rep.reference_models)
    o << "    " << m.name << ": {sigma_const_m: " << yamlNum(m.const_m)
      << ", sigma_linear: " << yamlNum(m.linear) << ", sigma_quad_per_m: " << yamlNum(m.quad_per_m)
      << "}\n";

  o << "noise_model:\n"
    << "  base: " << rep.base_model << "\n";
  if (f.sigma_terms > 0)
    o << "  sigma_const_m: " << yamlNum(f.sigma_const_m) << "\n"
      << "  sigma_linear: " << yamlNum(f.sigma_linear) << "\n"
      << "  sigma_quad_per_m: " << yamlNum(f.sigma_quad_per_m) << "\n";
  if (f.depth_fitted)
    o << "  depth_scale_bias: " << yamlNum(f.depth_scale - 1.0) << "\n"
      << "  depth_offset_m: " << yamlNum(f.depth_offset_m) << "\n";
  if (rep.config.depth_unit_m > 0.0)
    o << "  quantum_m: " << yamlNum(rep.config.depth_unit_m) << "\n";
  if (std::isfinite(f.edge_spread_px) && f.edge_symmetric) {
    // The renderer's lateral blur moves a pixel's sample by a Gaussian offset rounded to whole
    // pixels; the measured spread holds that rounding (1/12 px^2) on top of the Gaussian.
    const double sigma_edge = f.edge_spread_px / (2.0 * std::sqrt(2.0 * std::log(2.0)));
    const double sigma_spot = std::sqrt(std::max(0.0, sigma_edge * sigma_edge - 1.0 / 12.0));
    o << "  lateral_fwhm_px: " << yamlNum(2.0 * std::sqrt(2.0 * std::log(2.0)) * sigma_spot)
      << "\n";
  }
  if (f.depth_fitted)
    o << "depth_correction:\n"
      << "  scale: " << yamlNum(f.depth_scale) << "\n"
      << "  offset_m: " << yamlNum(f.depth_offset_m) << "\n";
  writeAtomically(path, o.str());
}

void writeEdgeSpreadCsv(const std::string& path, const std::vector<SegmentResult>& segs) {
  std::ostringstream o;
  o << "segment,s_px,face_share,returns\n";
  for (const SegmentResult& r : segs)
    for (const EdgeSpreadBin& b : r.edge_spread)
      o << yamlStr(r.label) << "," << yamlNum(b.s_px) << "," << yamlNum(b.face_share) << ","
        << yamlNum(b.returns) << "\n";
  writeAtomically(path, o.str());
}

double centralDepth(const DepthImage& d, const PinholeIntrinsics& K, int r) {
  const int cu = static_cast<int>(std::lround(K.cx)), cv = static_cast<int>(std::lround(K.cy));
  std::vector<double> z;
  for (int v = std::max(0, cv - r); v <= std::min(d.height - 1, cv + r); ++v)
    for (int u = std::max(0, cu - r); u <= std::min(d.width - 1, cu + r); ++u)
      if (d.at(u, v) > 0.0f) z.push_back(d.at(u, v));
  return z.empty() ? 0.0 : medianOf(z);
}

std::vector<StillPeriod> findStillPeriods(const std::vector<double>& t,
                                          const std::vector<double>& depth, double min_duration_s,
                                          double tol_rel, double tol_m) {
  if (t.size() != depth.size())
    throw std::invalid_argument("findStillPeriods: " + std::to_string(t.size()) + " stamps for " +
                                std::to_string(depth.size()) + " depths");
  std::vector<StillPeriod> out;
  std::vector<std::size_t> run;
  std::vector<double> anchor_vals;  // the run's first frames: its reference depth
  double anchor = 0.0;
  std::size_t stray = static_cast<std::size_t>(-1);
  auto close = [&]() {
    if (!run.empty() && t[run.back()] - t[run.front()] >= min_duration_s) {
      std::vector<double> d;
      for (std::size_t i : run) d.push_back(depth[i]);
      out.push_back({run.front(), run.back(), medianOf(d)});
    }
    run.clear();
    anchor_vals.clear();
    stray = static_cast<std::size_t>(-1);
  };
  auto add = [&](std::size_t i) {
    run.push_back(i);
    // The reference settles over the first 15 frames and then stays put, so a slow drift ends the
    // run instead of dragging its reference along.
    if (anchor_vals.size() < 15) {
      anchor_vals.push_back(depth[i]);
      anchor = medianOf(anchor_vals);
    }
  };
  for (std::size_t i = 0; i < depth.size(); ++i) {
    if (!(depth[i] > 0.0)) {
      close();
      continue;
    }
    if (run.empty()) {
      add(i);
      continue;
    }
    const double tol = std::max(tol_rel * anchor, tol_m);
    if (std::abs(depth[i] - anchor) <= tol) {
      stray = static_cast<std::size_t>(-1);
      add(i);
    } else if (stray == static_cast<std::size_t>(-1)) {
      stray = i;
    } else {
      const std::size_t first = stray;
      close();
      add(first);
      if (std::abs(depth[i] - depth[first]) <= std::max(tol_rel * depth[first], tol_m))
        add(i);
      else
        run.clear(), anchor_vals.clear(), add(i);
    }
  }
  close();
  return out;
}

}  // namespace depth_track
