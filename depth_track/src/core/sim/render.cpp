#include "depth_track/core/sim/render.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>

namespace depth_track {
namespace sim {

namespace {

/// Surfaces nearer than this along z are ignored: they are behind or at the optical centre and
/// would only produce numerical noise. Far below any sensor's minimum range.
constexpr double kNearZ_m = 1e-3;

/// A primitive prepared for one frame: pose relative to the camera and its screen-space bounds.
struct FramePrimitive {
  const Primitive* prim = nullptr;
  Eigen::Matrix3d R_P_C;
  Eigen::Vector3d o_P;  ///< camera centre in the primitive frame
  double z_min = 0.0;   ///< lower bound on the z-depth of any of its points in front of the camera
  int u0 = 0, u1 = -1, v0 = 0, v1 = -1;  ///< inclusive pixel bounds (empty when u1 < u0)
};

void validateInputs(const Scene& scene, const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                    const DepthRange& range) {
  std::vector<std::string> problems = scene.validate();
  for (const auto& p : K.validate()) problems.push_back(p);
  for (const auto& p : range.validate()) problems.push_back(p);
  if (!T_W_C.matrix().allFinite()) problems.push_back("camera pose T_W_C is not finite");
  if (!problems.empty()) throw std::invalid_argument("renderDepth: " + joinProblems(problems));
}

/// Bounding-box corners of a primitive in its own frame (a conservative hull of the shape).
void localCorners(const Primitive& p, Eigen::Vector3d corners[8]) {
  const Eigen::Vector3d& h = p.half_extents;
  for (int i = 0; i < 8; ++i)
    corners[i] = Eigen::Vector3d((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(),
                                 (i & 4) ? h.z() : -h.z());
}

/// Projects the part of the primitive's bounding box in front of z = kNearZ_m and returns its
/// pixel bounds. The box is convex, so the hull of its clipped corners and edge crossings
/// bounds the projection of everything in front of the near plane.
FramePrimitive prepare(const Primitive& prim, const Eigen::Isometry3d& T_C_W,
                       const PinholeIntrinsics& K) {
  FramePrimitive f;
  f.prim = &prim;
  const Eigen::Isometry3d T_C_P = T_C_W * prim.T_W_P;
  f.R_P_C = T_C_P.linear().transpose();
  f.o_P = -f.R_P_C * T_C_P.translation();

  Eigen::Vector3d c_P[8], c_C[8];
  localCorners(prim, c_P);
  for (int i = 0; i < 8; ++i) c_C[i] = T_C_P * c_P[i];

  std::vector<Eigen::Vector3d> front;
  front.reserve(20);
  for (int i = 0; i < 8; ++i)
    if (c_C[i].z() >= kNearZ_m) front.push_back(c_C[i]);
  for (int i = 0; i < 8; ++i)
    for (int bit = 1; bit < 8; bit <<= 1) {
      const int j = i | bit;
      if (j == i) continue;
      const double zi = c_C[i].z() - kNearZ_m, zj = c_C[j].z() - kNearZ_m;
      if ((zi < 0.0) != (zj < 0.0)) {
        const double s = zi / (zi - zj);
        front.push_back(c_C[i] + s * (c_C[j] - c_C[i]));
      }
    }
  if (front.empty()) return f;  // entirely behind the camera: empty bounds

  double umin = std::numeric_limits<double>::infinity(), umax = -umin;
  double vmin = umin, vmax = -umin, zmin = umin;
  for (const auto& p : front) {
    const double z = std::max(p.z(), kNearZ_m);
    const double u = K.fx * p.x() / z + K.cx, v = K.fy * p.y() / z + K.cy;
    umin = std::min(umin, u);
    umax = std::max(umax, u);
    vmin = std::min(vmin, v);
    vmax = std::max(vmax, v);
    zmin = std::min(zmin, p.z());
  }
  f.z_min = zmin;
  // Pixel centres are at integers; widen by one pixel for rounding safety.
  const double big = 1e6;
  f.u0 = static_cast<int>(std::max(0.0, std::floor(std::max(umin, -big)) - 1));
  f.u1 = static_cast<int>(std::min<double>(K.width - 1, std::ceil(std::min(umax, big)) + 1));
  f.v0 = static_cast<int>(std::max(0.0, std::floor(std::max(vmin, -big)) - 1));
  f.v1 = static_cast<int>(std::min<double>(K.height - 1, std::ceil(std::min(vmax, big)) + 1));
  return f;
}

/// Nearest z-depth along the pixel ray d_C = (xn, yn, 1) over the candidate primitives; with
/// this ray scaling the ray parameter t equals the z-depth. With `cos_incidence` set, also the
/// |cos| of the angle between the ray and the normal of the surface hit (0 if none).
double castRay(const std::vector<const FramePrimitive*>& candidates, int u, double xn, double yn,
               double* cos_incidence) {
  const Eigen::Vector3d d_C(xn, yn, 1.0);
  double best = std::numeric_limits<double>::infinity();
  const FramePrimitive* hit = nullptr;
  for (const FramePrimitive* f : candidates) {
    if (u < f->u0 || u > f->u1 || f->z_min >= best) continue;
    const Eigen::Vector3d d_P = f->R_P_C * d_C;
    const auto t = intersectLocal(*f->prim, f->o_P, d_P, kNearZ_m, best);
    if (t) {
      best = *t;
      hit = f;
    }
  }
  if (cos_incidence) {
    *cos_incidence = 0.0;
    if (hit) {
      const Eigen::Vector3d d_P = hit->R_P_C * d_C;
      const Eigen::Vector3d n_P = surfaceNormalLocal(*hit->prim, hit->o_P + best * d_P);
      *cos_incidence = std::min(1.0, std::abs(n_P.dot(d_P)) / d_P.norm());
    }
  }
  return best;
}

float toDepth(double z, const DepthRange& range) {
  return (std::isfinite(z) && z >= range.min_m && z <= range.max_m) ? static_cast<float>(z) : 0.0f;
}

/// Primitives prepared for the pose shared by one band of rows, nearest first.
std::vector<FramePrimitive> prepareBand(const Scene& scene, const Eigen::Isometry3d& T_W_C,
                                        const PinholeIntrinsics& K) {
  const Eigen::Isometry3d T_C_W = T_W_C.inverse();
  std::vector<FramePrimitive> prims;
  prims.reserve(scene.primitives.size());
  for (const auto& p : scene.primitives) {
    FramePrimitive f = prepare(p, T_C_W, K);
    if (f.u1 >= f.u0 && f.v1 >= f.v0) prims.push_back(f);
  }
  // Nearest first, so the z_min test skips hidden primitives early.
  std::sort(prims.begin(), prims.end(),
            [](const FramePrimitive& a, const FramePrimitive& b) { return a.z_min < b.z_min; });
  return prims;
}

/// Renders rows in bands of band_rows rows, band b seen from band_poses[b].
RenderedDepth renderImpl(const Scene& scene, const PinholeIntrinsics& K,
                         const std::vector<Eigen::Isometry3d>& band_poses, int band_rows,
                         const DepthRange& range, int threads, bool incidence) {
  for (const auto& T : band_poses) validateInputs(scene, K, T, range);
  std::vector<std::vector<FramePrimitive>> bands;
  bands.reserve(band_poses.size());
  for (const auto& T : band_poses) bands.push_back(prepareBand(scene, T, K));

  RenderedDepth result;
  result.depth = DepthImage(K.width, K.height);
  if (incidence) result.cos_incidence.assign(result.depth.data.size(), 0.0f);
  DepthImage& out = result.depth;
  auto rows = [&](const tbb::blocked_range<int>& r) {
    std::vector<const FramePrimitive*> candidates;
    for (int v = r.begin(); v < r.end(); ++v) {
      const auto& prims = bands[std::min<std::size_t>(v / band_rows, bands.size() - 1)];
      candidates.clear();
      for (const auto& f : prims)
        if (v >= f.v0 && v <= f.v1) candidates.push_back(&f);
      const double yn = (v - K.cy) / K.fy;
      float* row = out.data.data() + static_cast<std::size_t>(v) * K.width;
      float* cos_row =
          incidence ? result.cos_incidence.data() + static_cast<std::size_t>(v) * K.width : nullptr;
      for (int u = 0; u < K.width; ++u) {
        double c = 0.0;
        row[u] =
            toDepth(castRay(candidates, u, (u - K.cx) / K.fx, yn, incidence ? &c : nullptr), range);
        if (cos_row) cos_row[u] = row[u] > 0.0f ? static_cast<float>(c) : 0.0f;
      }
    }
  };
  if (threads == 1) {
    rows(tbb::blocked_range<int>(0, K.height));
  } else if (threads > 1) {
    // A private arena limits this call only, not other TBB users in the process.
    tbb::task_arena arena(threads);
    arena.execute([&] { tbb::parallel_for(tbb::blocked_range<int>(0, K.height, 8), rows); });
  } else {
    tbb::parallel_for(tbb::blocked_range<int>(0, K.height, 8), rows);
  }
  return result;
}

}  // namespace

DepthImage renderDepth(const Scene& scene, const PinholeIntrinsics& K,
                       const Eigen::Isometry3d& T_W_C, const DepthRange& range, int threads) {
  const int h = std::max(K.height, 1);
  return renderImpl(scene, K, {T_W_C}, h, range, threads, false).depth;
}

RenderedDepth renderDepthWithIncidence(const Scene& scene, const PinholeIntrinsics& K,
                                       const Eigen::Isometry3d& T_W_C, const DepthRange& range,
                                       int threads) {
  const int h = std::max(K.height, 1);
  return renderImpl(scene, K, {T_W_C}, h, range, threads, true);
}

RenderedDepth renderDepthScanned(const Scene& scene, const PinholeIntrinsics& K,
                                 const std::function<Eigen::Isometry3d(double row)>& T_W_C_at_row,
                                 const DepthRange& range, int threads, int band_rows) {
  if (!T_W_C_at_row) throw std::invalid_argument("renderDepthScanned: no pose function given");
  if (band_rows < 1) throw std::invalid_argument("renderDepthScanned: band_rows must be >= 1");
  const auto k_problems = K.validate();
  if (!k_problems.empty())
    throw std::invalid_argument("renderDepthScanned: " + joinProblems(k_problems));
  std::vector<Eigen::Isometry3d> poses;
  for (int v0 = 0; v0 < K.height; v0 += band_rows) {
    const int v1 = std::min(K.height, v0 + band_rows) - 1;
    poses.push_back(T_W_C_at_row(0.5 * (v0 + v1)));
  }
  return renderImpl(scene, K, poses, band_rows, range, threads, true);
}

DepthImage renderDepthReference(const Scene& scene, const PinholeIntrinsics& K,
                                const Eigen::Isometry3d& T_W_C, const DepthRange& range) {
  validateInputs(scene, K, T_W_C, range);
  const Eigen::Isometry3d T_C_W = T_W_C.inverse();
  DepthImage out(K.width, K.height);
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d d_C((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      double best = std::numeric_limits<double>::infinity();
      for (const auto& p : scene.primitives) {
        const Eigen::Isometry3d T_P_C = (T_C_W * p.T_W_P).inverse();
        const auto t = intersectLocal(p, T_P_C.translation(), T_P_C.linear() * d_C, kNearZ_m, best);
        if (t) best = *t;
      }
      out.at(u, v) = toDepth(best, range);
    }
  return out;
}

}  // namespace sim
}  // namespace depth_track
