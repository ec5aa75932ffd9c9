#pragma once
// Private layout of VoxelMap, shared by voxel_map.cpp (fusion, flush, I/O) and raycast.cpp.
#include <octomap/OcTree.h>

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "depth_track/core/depth_noise.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/se3.hpp"

namespace depth_track {
namespace map_detail {

constexpr int kBlockShift = 3;  // 8 voxels per block edge
constexpr int kChunkShift = 6;  // 64 voxels (8 blocks) per chunk edge
constexpr int kBlockVoxels = 512;
constexpr int kChunkBlocks = 512;
constexpr int kKeyLimit = 32766;                  // OctoMap keys are index + 32768 in 16 bits
constexpr std::size_t kMaxChunkIndex = 1u << 24;  // dense chunk index entries (128 MB of pointers)

// Throws std::invalid_argument when T is not a finite rigid transform.
// The 1e-3 tolerance admits the rounding of a tracked pose, a product of many increments.
inline void checkPose(const Eigen::Isometry3d& T, const char* what) {
  if (!T.matrix().allFinite())
    throw std::invalid_argument(std::string(what) + ": pose T_W_C is not finite");
  if (!isRigid(T, 1e-3)) {
    std::ostringstream s;
    s << what
      << ": pose T_W_C has no valid rotation (|R^T R - I| = " << orthonormalityError(T.linear())
      << ", det = " << T.linear().determinant() << ")";
    throw std::invalid_argument(s.str());
  }
}

// A readers-writer lock that lets a waiting writer in before new readers. std::shared_mutex
// (glibc's rwlock) prefers readers: two threads ray-casting back to back kept the fuser waiting
// 20 s for 10 frames in test_map_stages. Here a fuse waits at most for the casts already
// running. Meets SharedMutex, so std::unique_lock / std::shared_lock take it.
class SharedMutex {
 public:
  void lock() {
    std::unique_lock<std::mutex> l(m_);
    ++writers_waiting_;
    write_cv_.wait(l, [this] { return !writing_ && readers_ == 0; });
    --writers_waiting_;
    writing_ = true;
  }
  void unlock() {
    {
      const std::lock_guard<std::mutex> l(m_);
      writing_ = false;
    }
    write_cv_.notify_one();
    read_cv_.notify_all();
  }
  void lock_shared() {
    std::unique_lock<std::mutex> l(m_);
    read_cv_.wait(l, [this] { return !writing_ && writers_waiting_ == 0; });
    ++readers_;
  }
  void unlock_shared() {
    bool last;
    {
      const std::lock_guard<std::mutex> l(m_);
      last = --readers_ == 0;
    }
    if (last) write_cv_.notify_one();
  }

 private:
  std::mutex m_;
  std::condition_variable read_cv_, write_cv_;
  int readers_ = 0, writers_waiting_ = 0;
  bool writing_ = false;
};
using ReadLock = std::shared_lock<SharedMutex>;
using WriteLock = std::unique_lock<SharedMutex>;

inline int voxelInBlock(int x, int y, int z) { return (x & 7) | ((y & 7) << 3) | ((z & 7) << 6); }
inline int blockInChunk(int x, int y, int z) {
  return ((x >> 3) & 7) | (((y >> 3) & 7) << 3) | (((z >> 3) & 7) << 6);
}
// floor() without a libm call (the default x86-64 target has no rounding instruction).
inline int fastFloor(double x) {
  const int i = static_cast<int>(x);
  return i - (x < i);
}
inline int fastFloor(float x) {
  const int i = static_cast<int>(x);
  return i - (x < i);
}

// Per-voxel flags of 64 voxels side by side, so one voxel's flags share a cache line.
struct Masks {
  std::uint64_t touched = 0;   // updated in frame `touch_frame`
  std::uint64_t observed = 0;  // log_odds is meaningful
  std::uint64_t occupied = 0;
  std::uint64_t dirty = 0;  // changed since the last flush
};
using Flag = std::uint64_t Masks::*;

struct Block {
  std::uint32_t touch_frame = 0;
  int n_occupied = 0;
  bool any_dirty = false;
  std::array<Masks, 8> mask{};
  std::array<float, kBlockVoxels> log_odds{};  // meaningful where `observed` is set

  bool has(Flag f, int i) const { return (mask[i >> 6].*f >> (i & 63)) & 1u; }
  void set(Flag f, int i) { mask[i >> 6].*f |= std::uint64_t{1} << (i & 63); }
  void clear(Flag f, int i) { mask[i >> 6].*f &= ~(std::uint64_t{1} << (i & 63)); }
};

struct Chunk {
  Eigen::Vector3i coord;  // chunk index (voxel index >> 6)
  std::array<std::unique_ptr<Block>, kChunkBlocks> blocks;
  int occupied_blocks = 0;  // blocks with n_occupied > 0
  // Dense copies of the blocks' occupancy (bits and counts) for ray traversal: a block's 512
  // occupancy bits are one cache line here, instead of being spread over its 2 KB of state.
  alignas(64) std::array<std::array<std::uint64_t, 8>, kChunkBlocks> occ{};
  std::array<std::uint16_t, kChunkBlocks> n_occ{};
  std::array<std::uint32_t, kChunkBlocks> born{};  // frame in which each block was allocated
  bool occupiedAt(int bi, int i) const { return (occ[bi][i >> 6] >> (i & 63)) & 1u; }
};

}  // namespace map_detail

struct VoxelMap::Impl {
  using Block = map_detail::Block;
  using Chunk = map_detail::Chunk;

  // One writer (MapFuser::fuse, flush, save, placeRegion) or any number of readers (ray casts,
  // queries). Taken by the public entry points only, never by these members.
  mutable map_detail::SharedMutex mutex;

  double s = 0.005, inv_s = 200.0;
  float l_hit = 0, l_miss = 0, l_min = 0, l_max = 0, l_occ = 0;
  Eigen::Vector3i key_lo{-map_detail::kKeyLimit, -map_detail::kKeyLimit, -map_detail::kKeyLimit};
  Eigen::Vector3i key_hi{map_detail::kKeyLimit, map_detail::kKeyLimit, map_detail::kKeyLimit};

  // Dense index over the box [index_lo, index_lo + index_dims) of chunk coordinates.
  Eigen::Vector3i index_lo{0, 0, 0}, index_dims{0, 0, 0};
  std::vector<Chunk*> index;
  std::vector<std::unique_ptr<Chunk>> chunks;

  std::unique_ptr<octomap::OcTree> tree;
  std::uint32_t frame = 0;
  // The noise limit (MapConfig::max_fuse_noise_voxels): frames measured so far, whether a
  // measurement settled it, the depth it set (infinity = none) and its one-line summary.
  int noise_frames = 0;
  bool noise_settled = false;
  double noise_depth_m = std::numeric_limits<double>::infinity();
  DepthNoiseModel noise_model;  // sigma(z) once measured (unknown: not measured)
  std::string noise_summary;
  std::size_t occupied_count = 0;
  std::size_t block_count = 0;

  Chunk* chunkAt(int cx, int cy, int cz) const {
    const unsigned x = static_cast<unsigned>(cx - index_lo.x());
    const unsigned y = static_cast<unsigned>(cy - index_lo.y());
    const unsigned z = static_cast<unsigned>(cz - index_lo.z());
    if (x >= static_cast<unsigned>(index_dims.x()) || y >= static_cast<unsigned>(index_dims.y()) ||
        z >= static_cast<unsigned>(index_dims.z()))
      return nullptr;
    return index[(static_cast<std::size_t>(z) * index_dims.y() + y) * index_dims.x() + x];
  }
  Block* blockAt(int x, int y, int z) const {
    const Chunk* c = chunkAt(x >> map_detail::kChunkShift, y >> map_detail::kChunkShift,
                             z >> map_detail::kChunkShift);
    return c ? c->blocks[map_detail::blockInChunk(x, y, z)].get() : nullptr;
  }
  bool inKeyRange(int x, int y, int z) const {
    return x >= key_lo.x() && y >= key_lo.y() && z >= key_lo.z() && x <= key_hi.x() &&
           y <= key_hi.y() && z <= key_hi.z();
  }

  // Walks the ray P(t) = o + t d (world metres; t need not be a distance) for t in [t0, t1) over
  // voxels of allocated blocks, skipping missing chunks/blocks whole; with kOccupiedOnly it skips
  // chunks and blocks without an occupied voxel instead (and may visit voxels of unallocated
  // blocks of a chunk when kNoSkip). f(chunk, block index, voxel index, t_in, t_out) returns
  // true to stop. With kOccupiedOnly, blocks allocated after frame `born_max` count as empty.
  // Returns false when the ray ran out. A plain march that re-derives the voxel and its chunk at
  // every step: the reference the fast traversals are checked against (raycastReference uses
  // walk<true, true> for VoxelMap::raycast, test_fusion walk<false> for carving's walkCarve).
  template <bool kOccupiedOnly, bool kNoSkip = false, class F>
  bool walk(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t0, double t1, F&& f,
            std::uint32_t born_max = std::numeric_limits<std::uint32_t>::max()) const {
    const Eigen::Vector3d O = o * inv_s;
    const Eigen::Vector3d D = d * inv_s;
    const double inf = std::numeric_limits<double>::infinity();
    const Eigen::Vector3d invD(D.x() != 0.0 ? 1.0 / D.x() : inf, D.y() != 0.0 ? 1.0 / D.y() : inf,
                               D.z() != 0.0 ? 1.0 / D.z() : inf);
    const bool pos[3] = {D.x() >= 0.0, D.y() >= 0.0, D.z() >= 0.0};
    constexpr double kEps = 1e-9;
    double t = t0;
    while (t < t1) {
      const int v[3] = {map_detail::fastFloor(O.x() + t * D.x()),
                        map_detail::fastFloor(O.y() + t * D.y()),
                        map_detail::fastFloor(O.z() + t * D.z())};
      int shift = 0;
      Chunk* c = chunkAt(v[0] >> map_detail::kChunkShift, v[1] >> map_detail::kChunkShift,
                         v[2] >> map_detail::kChunkShift);
      int bi = 0;
      if (!c || (kOccupiedOnly && c->occupied_blocks == 0)) {
        shift = map_detail::kChunkShift;
      } else {
        bi = map_detail::blockInChunk(v[0], v[1], v[2]);
        if (kOccupiedOnly ? (c->n_occ[bi] == 0 || c->born[bi] > born_max) : !c->blocks[bi])
          shift = map_detail::kBlockShift;
      }
      if (kNoSkip) shift = 0;
      double t_exit = inf;
      for (int a = 0; a < 3; ++a) {
        const int lo = (v[a] >> shift) << shift;
        const double bound = pos[a] ? lo + (1 << shift) : lo;
        const double te = (bound - O[a]) * invD[a];
        if (te < t_exit) t_exit = te;
      }
      t_exit = std::max(t_exit, t);
      if (shift == 0 && c && (kOccupiedOnly || c->blocks[bi])) {
        if (f(*c, bi, map_detail::voxelInBlock(v[0], v[1], v[2]), t, std::min(t_exit, t1)))
          return true;
      }
      t = t_exit + kEps;
    }
    return false;
  }
};

}  // namespace depth_track
