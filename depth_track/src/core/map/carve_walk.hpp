#pragma once
// Ray traversal for free-space carving in VoxelMap::fuse (voxel_map.cpp). Private to the map;
// test_fusion checks it against VoxelMap::Impl::walk<false>.
#include <Eigen/Core>
#include <algorithm>
#include <limits>

#include "voxel_map_impl.hpp"

namespace depth_track {
namespace map_detail {

// Calls f(chunk, block index, block, voxel index) for every voxel of an allocated block that the
// ray P(t) = o + t d (world metres) passes for t in [0, t1), in ray order, skipping missing
// chunks and blocks whole: the voxels Impl::walk<false>(o, d, 0, t1, ...) visits. Where walk<false>
// re-derives the voxel and its chunk from the ray point at every voxel step, this steps voxel to
// voxel by integer increments (the next boundary of the stepped axis recomputed from the ray
// origin, exactly as walk<false> computes it), and only looks the chunk up when the ray crosses
// into another chunk. Unallocated blocks and chunks are skipped as in walk<false> (exit distance
// of the block/chunk, then the voxel re-derived). The two differ only where the ray passes within
// 1e-9 (in t) of a voxel edge or corner: walk<false> may then cross two faces in one step, this
// crosses them one after the other.
// Axis of the nearest boundary (the first of equals).
inline int argmin3(const double t[3]) {
  return t[0] < t[1] ? (t[0] < t[2] ? 0 : 2) : (t[1] < t[2] ? 1 : 2);
}

template <class F>
void walkCarve(const VoxelMap::Impl& m, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
               double t1, F&& f) {
  const Eigen::Vector3d O = o * m.inv_s;
  const Eigen::Vector3d D = d * m.inv_s;
  const double inf = std::numeric_limits<double>::infinity();
  const double invD[3] = {D.x() != 0.0 ? 1.0 / D.x() : inf, D.y() != 0.0 ? 1.0 / D.y() : inf,
                          D.z() != 0.0 ? 1.0 / D.z() : inf};
  const bool pos[3] = {D.x() >= 0.0, D.y() >= 0.0, D.z() >= 0.0};
  // Voxel step per axis, the matching step of the in-block voxel index, and the offset of the
  // boundary ahead from the voxel's lower corner.
  const int step[3] = {pos[0] ? 1 : -1, pos[1] ? 1 : -1, pos[2] ? 1 : -1};
  const int di[3] = {step[0], 8 * step[1], 64 * step[2]};
  const int ahead[3] = {pos[0] ? 1 : 0, pos[1] ? 1 : 0, pos[2] ? 1 : 0};
  constexpr double kEps = 1e-9;  // as walk<false>
  double t = 0.0;
  while (t < t1) {
    int q[3] = {fastFloor(O.x() + t * D.x()), fastFloor(O.y() + t * D.y()),
                fastFloor(O.z() + t * D.z())};
    Chunk* c = m.chunkAt(q[0] >> kChunkShift, q[1] >> kChunkShift, q[2] >> kChunkShift);
    if (!c) {
      // Missing chunk: step chunk to chunk until one exists, then re-derive the voxel there.
      int k[3] = {q[0] >> kChunkShift, q[1] >> kChunkShift, q[2] >> kChunkShift};
      double t_next[3];
      for (int a = 0; a < 3; ++a) t_next[a] = ((k[a] + ahead[a]) * 64 - O[a]) * invD[a];
      while (true) {
        const int a = argmin3(t_next);
        t = std::max(t_next[a], t) + kEps;
        if (t >= t1) return;
        k[a] += step[a];
        t_next[a] = ((k[a] + ahead[a]) * 64 - O[a]) * invD[a];
        if (m.chunkAt(k[0], k[1], k[2])) break;
      }
      continue;
    }
    int bi = blockInChunk(q[0], q[1], q[2]);
    Block* b = c->blocks[bi].get();
    if (!b) {
      // Missing block: step block to block inside the chunk until one exists or the ray leaves
      // the chunk, then re-derive the voxel there.
      int k[3] = {q[0] >> kBlockShift, q[1] >> kBlockShift, q[2] >> kBlockShift};
      double t_next[3];
      for (int a = 0; a < 3; ++a) t_next[a] = ((k[a] + ahead[a]) * 8 - O[a]) * invD[a];
      while (true) {
        const int a = argmin3(t_next);
        t = std::max(t_next[a], t) + kEps;
        if (t >= t1) return;
        const int before = k[a];
        k[a] += step[a];
        t_next[a] = ((k[a] + ahead[a]) * 8 - O[a]) * invD[a];
        if ((k[a] >> 3) != (before >> 3)) break;
        if (c->blocks[(k[0] & 7) | ((k[1] & 7) << 3) | ((k[2] & 7) << 6)]) break;
      }
      continue;
    }
    // Allocated block: integer stepping through it and through allocated neighbours.
    double t_next[3];
    for (int a = 0; a < 3; ++a) t_next[a] = ((q[a] + ahead[a]) - O[a]) * invD[a];
    int i = voxelInBlock(q[0], q[1], q[2]);
    while (true) {
      const int a = argmin3(t_next);
      f(*c, bi, *b, i);
      t = std::max(t_next[a], t) + kEps;
      if (t >= t1) return;
      // Step to the voxel holding the ray at t: across the nearest face, and across any other
      // face the ray also passed by t (an edge or corner), as walk<false>'s re-derivation does.
      int moved = 0;  // bit 0: left the block, bit 1: left the chunk
      auto cross = [&](int e) {
        const int before = q[e];
        q[e] += step[e];
        t_next[e] = ((q[e] + ahead[e]) - O[e]) * invD[e];
        i += di[e];
        moved |= ((q[e] >> kBlockShift) != (before >> kBlockShift)) |
                 (((q[e] >> kChunkShift) != (before >> kChunkShift)) << 1);
      };
      cross(a);
      const int a1 = a == 2 ? 0 : a + 1, a2 = a == 0 ? 2 : a - 1;
      if (t_next[a1] < t) cross(a1);
      if (t_next[a2] < t) cross(a2);
      if (!moved) continue;
      if (moved & 2) {
        c = m.chunkAt(q[0] >> kChunkShift, q[1] >> kChunkShift, q[2] >> kChunkShift);
        if (!c) break;
      }
      bi = blockInChunk(q[0], q[1], q[2]);
      b = c->blocks[bi].get();
      if (!b) break;  // re-derived at t and skipped above
      i = voxelInBlock(q[0], q[1], q[2]);
    }
  }
}

}  // namespace map_detail
}  // namespace depth_track
