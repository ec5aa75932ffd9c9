// Depth from the voxel map (thesis §3.14): one ray per pixel, first occupied voxel wins.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "depth_track/core/map/voxel_map.hpp"
#include "voxel_map_impl.hpp"

namespace depth_track {

using map_detail::Block;
using map_detail::Chunk;

namespace {

constexpr int kTile = 4;               // pixels per tile edge for the near/far bounds
constexpr double kRunCapVoxels = 6.0;  // longest occupied run averaged along a ray, voxels

void checkRaycastInput(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                       const DepthRange& range) {
  auto problems = K.validate();
  for (const auto& p : range.validate()) problems.push_back(p);
  if (!T_W_C.matrix().allFinite())
    problems.push_back("pose T_W_C is not finite");
  else if ((T_W_C.linear().transpose() * T_W_C.linear() - Eigen::Matrix3d::Identity()).norm() >
           1e-3)
    problems.push_back("pose T_W_C has no valid rotation");
  if (!problems.empty()) throw std::invalid_argument("raycast: " + joinProblems(problems));
}

// Surface depth along a pixel ray (the ray parameter is depth: d_C = (x, y, 1)). Noise makes a
// surface a shell a few voxels thick, and the first occupied voxel is its near face, biased
// towards the camera by about the noise; the depth returned is the evidence-weighted centre of
// the first run of consecutive occupied voxels, the run capped at `cap` (depth units) so that a
// ray grazing a floor does not slide along it.
struct HitDepth {
  double cap = 0.0;    // longest run averaged, depth units
  float l_occ = 0.0f;  // occupancy threshold, log-odds
  bool found = false;
  double t_first = 0.0, t_last = 0.0, sum_w = 0.0, sum_wt = 0.0;
  bool operator()(const Chunk& c, int bi, int i, double t_in, double t_out) {
    const bool occ = c.occupiedAt(bi, i);
    if (!found) {
      if (!occ) return false;
      found = true;
      t_first = t_last = t_in;
    } else if (!occ || t_in > t_last + 1e-6) {
      return true;  // the run ended (or a skipped gap)
    }
    // Weight by evidence above the threshold and by the chord length inside the run: voxels hit
    // most often lie nearest the surface.
    const double end = std::min(t_out, t_first + cap);
    const double w = (c.blocks[bi]->log_odds[i] - l_occ) * (end - t_in) + 1e-12;
    sum_w += w;
    sum_wt += w * 0.5 * (t_in + end);
    t_last = end;
    return t_last - t_first >= cap;
  }
  float depth() const { return static_cast<float>(sum_wt / sum_w); }
};

// Depth bounds of an axis-aligned world box of edge `size` at `lo_W` in the camera frame, and the
// pixel rectangle that can see it. Returns false when the box cannot be seen in [zmin, zmax].
struct BoxView {
  double z_lo, z_hi;
  int u0, u1, v0, v1;  // inclusive pixel range
};
bool viewBox(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_C_W,
             const Eigen::Vector3d& lo_W, double size, double zmin, double zmax, BoxView* out) {
  const Eigen::Vector3d base = T_C_W * lo_W;
  const Eigen::Matrix3d E = T_C_W.linear() * size;
  double z_lo = std::numeric_limits<double>::infinity(), z_hi = -z_lo;
  double u_lo = z_lo, u_hi = z_hi, v_lo = z_lo, v_hi = z_hi;
  bool all_front = true;
  for (int c = 0; c < 8; ++c) {
    Eigen::Vector3d p = base;
    if (c & 1) p += E.col(0);
    if (c & 2) p += E.col(1);
    if (c & 4) p += E.col(2);
    z_lo = std::min(z_lo, p.z());
    z_hi = std::max(z_hi, p.z());
    if (p.z() <= 1e-6) {
      all_front = false;
      continue;
    }
    const double u = K.fx * p.x() / p.z() + K.cx, v = K.fy * p.y() / p.z() + K.cy;
    u_lo = std::min(u_lo, u), u_hi = std::max(u_hi, u);
    v_lo = std::min(v_lo, v), v_hi = std::max(v_hi, v);
  }
  if (z_hi < zmin || z_lo > zmax) return false;
  out->z_lo = z_lo;
  out->z_hi = z_hi;
  if (!all_front) {  // straddles the camera plane: any pixel may see it
    out->u0 = 0, out->u1 = K.width - 1, out->v0 = 0, out->v1 = K.height - 1;
    return true;
  }
  // A pixel sees the box only if its centre lies in the hull of the projected corners; one pixel
  // of margin absorbs rounding.
  out->u0 = std::max(0, static_cast<int>(std::ceil(u_lo)) - 1);
  out->u1 = std::min(K.width - 1, static_cast<int>(std::floor(u_hi)) + 1);
  out->v0 = std::max(0, static_cast<int>(std::ceil(v_lo)) - 1);
  out->v1 = std::min(K.height - 1, static_cast<int>(std::floor(v_hi)) + 1);
  return out->u0 <= out->u1 && out->v0 <= out->v1;
}

}  // namespace

DepthImage VoxelMap::raycast(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                             const DepthRange& range, int threads, int min_age_frames) const {
  checkRaycastInput(K, T_W_C, range);
  if (min_age_frames < 0) throw std::invalid_argument("raycast: min_age_frames must be >= 0");
  const Impl& m = *impl_;
  const int w = K.width, h = K.height;
  DepthImage out(w, h, 0.0f);
  if (m.occupied_count == 0) return out;
  if (static_cast<std::uint32_t>(min_age_frames) >= m.frame) return out;
  const std::uint32_t born_max = m.frame - static_cast<std::uint32_t>(min_age_frames);

  // Near/far depth bounds per tile from the occupied blocks that project onto it: no occupied
  // voxel can be met before the nearest such block or after the farthest one.
  const int tw = (w + kTile - 1) / kTile, th = (h + kTile - 1) / kTile;
  std::vector<float> near(static_cast<std::size_t>(tw) * th,
                          std::numeric_limits<float>::infinity());
  std::vector<float> far(near.size(), 0.0f);
  const Eigen::Isometry3d T_C_W = T_W_C.inverse();
  const double chunk_m = 64 * m.s, block_m = 8 * m.s;
  for (const auto& ch : m.chunks) {
    if (ch->occupied_blocks == 0) continue;
    BoxView cv;
    const Eigen::Vector3d chunk_lo = ch->coord.cast<double>() * chunk_m;
    if (!viewBox(K, T_C_W, chunk_lo, chunk_m, range.min_m, range.max_m, &cv)) continue;
    for (int bi = 0; bi < map_detail::kChunkBlocks; ++bi) {
      if (ch->n_occ[bi] == 0 || ch->born[bi] > born_max) continue;
      BoxView bv;
      const Eigen::Vector3d lo =
          chunk_lo + Eigen::Vector3d(bi & 7, (bi >> 3) & 7, bi >> 6) * block_m;
      if (!viewBox(K, T_C_W, lo, block_m, range.min_m, range.max_m, &bv)) continue;
      const float zl = static_cast<float>(bv.z_lo), zh = static_cast<float>(bv.z_hi);
      for (int ty = bv.v0 / kTile; ty <= bv.v1 / kTile; ++ty) {
        float* nr = near.data() + static_cast<std::size_t>(ty) * tw;
        float* fr = far.data() + static_cast<std::size_t>(ty) * tw;
        for (int tx = bv.u0 / kTile; tx <= bv.u1 / kTile; ++tx) {
          nr[tx] = std::min(nr[tx], zl);
          fr[tx] = std::max(fr[tx], zh);
        }
      }
    }
  }

  const Eigen::Vector3d o = T_W_C.translation();
  const Eigen::Matrix3d R = T_W_C.linear();
  const double run_cap_m = kRunCapVoxels * m.s;
  auto rows = [&](int v_begin, int v_end) {
    for (int v = v_begin; v < v_end; ++v) {
      const double y = (v - K.cy) / K.fy;
      const float* nr = near.data() + static_cast<std::size_t>(v / kTile) * tw;
      const float* fr = far.data() + static_cast<std::size_t>(v / kTile) * tw;
      float* dst = out.data.data() + static_cast<std::size_t>(v) * w;
      for (int u = 0; u < w; ++u) {
        const float tn = nr[u / kTile];
        if (tn == std::numeric_limits<float>::infinity()) continue;
        const double t0 = std::max(range.min_m, static_cast<double>(tn));
        const double t1 = std::min(range.max_m, static_cast<double>(fr[u / kTile]) + 1e-6);
        if (t0 >= t1) continue;
        const Eigen::Vector3d d = R * Eigen::Vector3d((u - K.cx) / K.fx, y, 1.0);
        HitDepth hit;
        hit.cap = run_cap_m / d.norm();
        hit.l_occ = m.l_occ;
        m.walk<true>(o, d, t0, t1, hit, born_max);
        if (hit.found) dst[u] = hit.depth();
      }
    }
  };
  if (threads > 1) {
    tbb::task_arena arena(threads);
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<int>(0, h, 8),
                        [&](const tbb::blocked_range<int>& r) { rows(r.begin(), r.end()); });
    });
  } else {
    rows(0, h);
  }
  return out;
}

DepthImage VoxelMap::raycastReference(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                                      const DepthRange& range) const {
  checkRaycastInput(K, T_W_C, range);
  const Impl& m = *impl_;
  DepthImage out(K.width, K.height, 0.0f);
  const Eigen::Vector3d o = T_W_C.translation();
  const Eigen::Matrix3d R = T_W_C.linear();
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d d = R * Eigen::Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      HitDepth hit;
      hit.cap = kRunCapVoxels * m.s / d.norm();
      hit.l_occ = m.l_occ;
      m.walk<true, true>(o, d, range.min_m, range.max_m, hit);
      if (hit.found) out.at(u, v) = hit.depth();
    }
  }
  return out;
}

}  // namespace depth_track
