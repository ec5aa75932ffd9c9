#pragma once
// Ray traversal for free-space carving in VoxelMap::fuse (voxel_map.cpp). Private to the map;
// test_fusion checks it against VoxelMap::Impl::walk<false>.
#include <Eigen/Core>
#include <algorithm>
#include <limits>

#include "voxel_map_impl.hpp"

namespace depth_track {
namespace map_detail {

// Axis of the nearest boundary, t0 < t1 ? (t0 < t2 ? 0 : 2) : (t1 < t2 ? 1 : 2) written as
// selects so that it compiles without branches (which axis comes next is data dependent).
inline int argmin3(const double t[3]) {
  const bool first = t[0] < t[1];
  const double m = first ? t[0] : t[1];
  const int a = first ? 0 : 1;
  return m < t[2] ? a : 2;
}

// Calls f(chunk, block index, block, voxel index) for every voxel of an allocated block that the
// ray P(t) = o + t d (world metres) passes for t in [0, t1), in ray order, skipping missing
// chunks and blocks whole: the voxels Impl::walk<false>(o, d, 0, t1, ...) visits. walk<false>
// re-derives the voxel, its chunk and block from the ray point at every step (t just past the
// nearest boundary). This one re-derives the voxel only on entering an allocated block (and
// after a skip); inside allocated blocks it steps voxel to voxel by integer increments, through
// unallocated space chunk to chunk or block to block. Boundary distances use walk<false>'s
// expression, (boundary - O) * (1 / D), and are computed one boundary ahead so that a step does
// not wait for them. Where the ray passes a voxel edge or corner (several boundaries within
// walk's 1e-9 step), it crosses all of them at once, as walk<false>'s re-derivation does; the
// voxel sequences then agree exactly (test_fusion compares them on the rendered chair run,
// whose poses put many steps exactly on edges).
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
  // Steps the ray cell to cell over the grid of (1 << shift)-voxel cells, from the cell holding
  // voxel q, until found(k, before) accepts the cell k just entered (before: the left cell's
  // index along the axis crossed). False when the ray runs out first.
  auto skip = [&](int shift, const int q[3], auto&& found) {
    const int size = 1 << shift;
    int k[3] = {q[0] >> shift, q[1] >> shift, q[2] >> shift};
    auto bound = [&](int a, int k_a) { return ((k_a + ahead[a]) * size - O[a]) * invD[a]; };
    double t_next[3], t_after[3];
    for (int a = 0; a < 3; ++a) {
      t_next[a] = bound(a, k[a]);
      t_after[a] = bound(a, k[a] + step[a]);
    }
    while (true) {
      const int a = argmin3(t_next);
      t = std::max(t_next[a], t) + kEps;
      if (t >= t1) return false;
      const int before = k[a];
      k[a] += step[a];
      t_next[a] = t_after[a];
      t_after[a] = bound(a, k[a] + step[a]);
      if (found(k, a, before)) return true;
    }
  };
  while (t < t1) {
    int q[3] = {fastFloor(O.x() + t * D.x()), fastFloor(O.y() + t * D.y()),
                fastFloor(O.z() + t * D.z())};
    Chunk* c = m.chunkAt(q[0] >> kChunkShift, q[1] >> kChunkShift, q[2] >> kChunkShift);
    if (!c) {
      // Missing chunk: chunk to chunk until one exists, then re-derive the voxel there.
      if (!skip(kChunkShift, q,
                [&](const int* k, int, int) { return m.chunkAt(k[0], k[1], k[2]) != nullptr; }))
        return;
      continue;
    }
    int bi = blockInChunk(q[0], q[1], q[2]);
    Block* b = c->blocks[bi].get();
    if (!b) {
      // Missing block: block to block inside the chunk until one exists or the ray leaves the
      // chunk, then re-derive the voxel there.
      if (!skip(kBlockShift, q, [&](const int* k, int a, int before) {
            return (k[a] >> 3) != (before >> 3) ||
                   c->blocks[(k[0] & 7) | ((k[1] & 7) << 3) | ((k[2] & 7) << 6)];
          }))
        return;
      continue;
    }
    // Allocated block: integer stepping through it and through allocated neighbours.
    auto bound = [&](int a, int q_a) { return ((q_a + ahead[a]) - O[a]) * invD[a]; };
    double t_next[3], t_after[3];
    for (int a = 0; a < 3; ++a) {
      t_next[a] = bound(a, q[a]);
      t_after[a] = bound(a, q[a] + step[a]);
    }
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
        t_next[e] = t_after[e];
        t_after[e] = bound(e, q[e] + step[e]);
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
