#pragma once
/// Voxel occupancy map (thesis §2.14, §5.1): full-resolution depth frames fused at a pose into a
/// blocked, hashed log-odds grid, flushed into an octomap::OcTree (the map of record, saved as
/// `.bt`), and ray-cast back into virtual depth images (§3.14). ROS-free core.
///
/// VoxelMap is the storage; fusion (MapFuser, map_fuser.hpp) and ray casting (MapRayCaster,
/// map_raycaster.hpp) are stages over it, so a fusion thread and a loop-closure thread can share
/// one map. Thread safety: one writer or many readers at a time, through a shared mutex taken by
/// every public call (fuse, flush, save and placeRegion write; the rest read), so a reader sees
/// the map between two whole frames. A call holds the lock for its duration only: a reader that
/// needs several calls to agree (count, then keys) must not run beside a writer.
///
/// Layout: voxels of `voxel_size_m` are grouped in blocks of 8^3 voxels, blocks in chunks of 8^3
/// blocks (64^3 voxels, 32 cm at 5 mm). Chunks are found through a dense index over the bounding
/// box of allocated chunks, so no lookup hashes. Every block keeps bit masks of its observed and
/// occupied voxels; counts of occupied voxels per block and occupied blocks per chunk let ray
/// traversal skip empty space a chunk or a block at a time.
///
/// Update models: kHitOnly (the thesis's: a hit raises a voxel's log-odds, nothing lowers it) and
/// kProbabilistic (OctoMap's hit/miss model: rays carve free space in front of each return, so pose
/// errors and moved objects heal). As in OctoMap's discretised insertion, a voxel takes at most one
/// update per frame and a hit wins over a miss. Carving walks every `carve_stride_px`-th pixel
/// (offset rotating frame to frame, so all pixels are covered over stride^2 frames) and only
/// through blocks that already hold a return: empty space far from any surface stays "unknown",
/// which is what keeps memory and time bounded.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

namespace octomap {
class OcTree;
}

namespace depth_track {

/// Thrown when a map cannot be saved or loaded; the message names the file and the reason.
class MapIoError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class UpdateModel {
  kHitOnly,        ///< thesis: occupancy only rises with hits, no free space
  kProbabilistic,  ///< OctoMap: hits and misses, free space carved along rays
};

/// "hit_only" | "probabilistic" -> model; throws std::invalid_argument naming the bad value.
UpdateModel parseUpdateModel(const std::string& name);
std::string toString(UpdateModel model);

/// Configuration of the voxel map. Probabilities are OctoMap's defaults, except the occupancy
/// threshold.
struct MapConfig {
  double voxel_size_m = 0.005;  ///< voxel edge, metres (thesis: 5 mm)
  bool bounded = true;          ///< false = unbounded (limited only by OctoMap's 16-bit keys)
  /// Region size along the start camera's x (right), y (down), z (forward) axes, metres
  /// (thesis: 4 m wide, 3 m high, 4 m deep).
  Eigen::Vector3d region_size_m{4.0, 3.0, 4.0};
  /// Position of the start camera inside the region, measured from the region's corner on the
  /// start camera's -x, -y, -z side, metres (thesis: middle of the width and height, at the front).
  Eigen::Vector3d start_in_region_m{2.0, 1.5, 0.0};
  UpdateModel model = UpdateModel::kProbabilistic;
  double prob_hit = 0.7;             ///< occupancy probability after a hit (OctoMap default)
  double prob_miss = 0.4;            ///< ... after a miss
  double clamp_min = 0.1192;         ///< lower clamp of the probability
  double clamp_max = 0.971;          ///< upper clamp of the probability
  /// Probability above which a voxel is occupied. 0.8 takes hits in two frames (logit 1.39
  /// against 0.85 per hit; OctoMap's 0.5 takes one): a return that lands in a voxel once, a noise
  /// tail or edge bleed, does not make a surface (docs/mapping.md, "The occupancy threshold").
  double occupancy_threshold = 0.8;
  /// Carve along every n-th pixel ray in u and v (1 = all); the offset rotates, so every pixel is
  /// carved once per n^2 frames. Fusing a 640x480 frame of the chair run at 5 mm takes ~8 ms on
  /// one core with 8 (~5 ms hit-only, ~6 ms with 12; dt_bench_fusion); with 12 the loop-closure
  /// revisit test accepted a bad correction (max error 32 -> 66 mm), so 8 stays the default.
  int carve_stride_px = 8;
  double carve_margin_m = 0.01;  ///< stop carving this far in front of a return (noise), m
  /// Returns deeper than this along the optical axis are neither fused nor carved along, metres
  /// (0 = every return of the depth range). The tracker still uses them: a D435's far returns
  /// carry centimetres of noise that spread each wall over a thick shell of voxels and cost most
  /// of its fusion time, yet the far walls are what pins its pose (docs/mapping.md, Speed).
  double max_fuse_depth_m = 0.0;
  /// Returns whose depth noise sigma(z) exceeds this many voxels are neither fused nor carved
  /// along either (0 = off): their hits scatter over a shell several times their noise deep
  /// instead of marking the surface, and with a D435's quadratic noise they cost most of the
  /// fusion time. sigma(z) is measured on the first frames the map fuses (the estimator of the
  /// tracker's auto_noise), which sets the depth where it reaches the limit once: 6 voxels of
  /// 5 mm put it at 2.4 m for a rendered D435, beyond the 4 m range for a Kinect or an L515
  /// (docs/mapping.md, "The noise limit"). The lower of this depth and max_fuse_depth_m applies.
  /// With snap_cell_px, a snapped return is cut at its cell's plane (the cells near the limit
  /// fitted with returns up to 3 sigma beyond it), not where it was measured: cut return by
  /// return, the noise's near side alone would be fused there.
  double max_fuse_noise_voxels = 6.0;
  /// Returns fused at their cell's plane (0 = off: every return fused where it was measured).
  /// One-hit occupancy marks every voxel a noisy return lands in, so a wall becomes a shell
  /// several sigma(z) deep. Each cell's returns are fitted with a plane (inverse depth is linear
  /// in the pixel ray for a plane), and where the cell is one plane within its noise (RMS within
  /// 1.5 sigma(z)), its returns within 3 sigma(z) of the plane are fused at the plane's depth.
  /// Cells start at this many pixels square and are quartered down to 4 px: to the smallest
  /// size whose plane is known to half a voxel (sigma / sqrt(n) <= voxel / 2), and where a cell
  /// is not one plane (an edge, a crease, a small object); what is left is fused as measured.
  /// Needs sigma(z), measured on the first frames as for max_fuse_noise_voxels; frames before
  /// it is known are fused as measured (docs/mapping.md, "Snapping returns to their cell's plane").
  int snap_cell_px = 16;
  /// snap_cell_px: where sigma(z) exceeds a voxel, a cell is one plane only if its inliers' mean
  /// residual in each of its four quarters, four column bands and four row bands lies within
  /// this many standard errors (sigma / sqrt(n)) of the fitted plane (0 = off: the RMS test
  /// alone, before 2026-12-06). Under a D435's centimetres of noise a corner or a step of a few
  /// centimetres passes the RMS test, and its returns would be snapped onto a plane between the
  /// two surfaces; a corner leaves quarters off the plane, a straight step (which the plane's
  /// tilt mostly takes up) the bands beside it (docs/mapping.md, "Depth edges and cells too small
  /// to place").
  double snap_step_sigmas = 3.0;
  /// Returns on the near side of a depth edge are not fused as hits (0 = off): a return with
  /// another within this many pixels (chessboard) that lies deeper by more than edge_jump of its
  /// depth (and by more than 6 sigma(z) once the noise is measured). Stereo edge fattening and a
  /// spot's lateral spread put foreground depths on background pixels: such returns sit in free
  /// space beside the object, off every surface, and frames seen from a little apart mark
  /// different voxels. Their rays still carve. The far side's returns are kept (docs/mapping.md,
  /// "Depth edges").
  int edge_margin_px = 2;
  /// The relative depth step that makes a depth edge for edge_margin_px (0.1 = 10 %).
  double edge_jump = 0.1;
  /// With snap_cell_px: the returns of a cell with too few returns to place its plane to half a
  /// voxel (n < 4 (sigma / voxel)^2: a noisy sensor's edges, small objects, holed patches) are
  /// not fused as hits (false: snapped when the cell is planar, else fused as measured). At a
  /// sigma(z) of several voxels either way puts them off the surface; their rays still carve.
  bool drop_unplaced = true;

  /// Frames whose hits an unobserved voxel needs to become occupied (1 at OctoMap's 0.5, 2 at
  /// the default 0.8).
  int hitsToOccupy() const;
  /// Every problem at once (empty = valid).
  std::vector<std::string> validate() const;
};

/// What one fusion call did.
struct FuseStats {
  int valid_pixels = 0;       ///< pixels with a return
  int fused_pixels = 0;       ///< returns inside the region that updated (or re-hit) a voxel
  int outside_region = 0;     ///< returns outside the bounded region (or the key range)
  int beyond_fuse_depth = 0;  ///< returns deeper than the fuse depth limit (not fused)
  /// The depth limit the call applied (the lower of max_fuse_depth_m and the noise limit),
  /// metres; 0 = none.
  double fuse_depth_limit_m = 0.0;
  int snapped_pixels = 0;     ///< returns fused at their cell's plane (MapConfig::snap_cell_px)
  /// Returns on the near side of a depth edge, not fused as hits (MapConfig::edge_margin_px);
  /// counted in valid_pixels, and their rays carve.
  int edge_dropped = 0;
  /// Returns of cells too small to place their plane (MapConfig::drop_unplaced), not fused as
  /// hits; counted in valid_pixels, and their rays carve.
  int unplaced_dropped = 0;
  /// Returns within the fuse depth limit (those fusion considered, snapping included).
  int returnsWithinFuseDepth() const { return valid_pixels - beyond_fuse_depth; }
  int hit_updates = 0;        ///< voxels updated as hit
  int miss_updates = 0;       ///< voxels updated as miss (carving)
  int carve_rays = 0;         ///< rays walked for carving
  double ms = 0.0;            ///< wall time of the fusion, ms (after the write lock was taken)
  double ms_lock_wait = 0.0;  ///< time spent waiting for the write lock (readers casting), ms
  /// Time the noise limit spent measuring the frame's noise before the lock (on the map's first
  /// frames only, until measured), ms; not part of `ms`.
  double ms_noise = 0.0;
};

/// Occupancy state of one voxel.
enum class VoxelState { kUnknown, kFree, kOccupied };

/// Integer voxel index: voxel (i, j, k) spans [i, i+1) * voxel_size_m along each world axis.
using VoxelKey = Eigen::Vector3i;

class VoxelMap {
 public:
  /// Throws std::invalid_argument listing every problem of the config.
  explicit VoxelMap(const MapConfig& config);
  ~VoxelMap();
  VoxelMap(VoxelMap&&) noexcept;
  VoxelMap& operator=(VoxelMap&&) noexcept;
  VoxelMap(const VoxelMap&) = delete;
  VoxelMap& operator=(const VoxelMap&) = delete;

  /// Places the bounded region around the start camera pose T_W_C0 (world AABB enclosing the
  /// region box of the config in C0). Until called, a bounded map uses the region around the
  /// world origin with identity orientation. Throws std::invalid_argument for a corrupt pose.
  void placeRegion(const Eigen::Isometry3d& T_W_C0);
  /// World AABB of the region (min, max), metres; unbounded maps return the key range.
  Eigen::AlignedBox3d region() const;

  /// Fuses a full-resolution depth frame (metres, 0 = no return) seen from T_W_C. Throws
  /// DepthInputError for a frame whose size does not match the intrinsics or that has no return,
  /// and std::invalid_argument for bad intrinsics or a non-finite / non-rigid pose; on a throw the
  /// map is unchanged. MapFuser(*this, intrinsics).fuse(depth, T_W_C): takes the write lock.
  FuseStats fuse(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                 const Eigen::Isometry3d& T_W_C);

  /// Virtual depth image (metres, 0 = no hit) seen by the camera at T_W_C: per pixel, the depth
  /// along the optical axis of the evidence-weighted centre of the first run of consecutive
  /// occupied voxels along the pixel ray (run capped at 6 voxel lengths), between range.min_m
  /// and range.max_m. The occupied voxels of each visible block are boxed per 4x4x4-voxel octant
  /// and each pixel ray is marched from where it enters the nearest of those boxes (not at all
  /// if it meets none), skipping chunks and blocks without an occupied voxel. With
  /// min_age_frames > 0 only blocks first observed at least that many fused frames ago count (the
  /// consolidated model, for loop closure). Takes the read lock; keeps ~5 MB of scratch per
  /// calling thread for a 640x480 image; `threads` > 1 splits rows over TBB workers. The same
  /// image as MapRayCaster::cast, which keeps its scratch and worker pool per caster.
  DepthImage raycast(const PinholeIntrinsics& intrinsics, const Eigen::Isometry3d& T_W_C,
                     const DepthRange& range, int threads = 1, int min_age_frames = 0) const;
  /// Reference ray cast: every ray marched from range.min_m voxel by voxel through the same
  /// occupancy test, without skipping. Slow; kept to check raycast() against. Takes the read lock.
  DepthImage raycastReference(const PinholeIntrinsics& intrinsics, const Eigen::Isometry3d& T_W_C,
                              const DepthRange& range) const;

  /// Voxel index containing world point p_W (metres). Thread-safe.
  VoxelKey keyOf(const Eigen::Vector3d& p_W) const;
  /// World centre of a voxel, metres. Thread-safe.
  Eigen::Vector3d centerOf(const VoxelKey& key) const;
  /// State of a voxel. Takes the read lock.
  VoxelState state(const VoxelKey& key) const;
  /// Log-odds of a voxel (0 when unknown). Takes the read lock.
  float logOdds(const VoxelKey& key) const;
  /// Calls f(key) for every occupied voxel, holding the read lock: f may use keyOf / centerOf
  /// but must not call the map's other members (a waiting writer would deadlock them).
  void forEachOccupied(const std::function<void(const VoxelKey&)>& f) const;
  /// Occupied voxel keys (unordered).
  std::vector<VoxelKey> occupiedKeys() const;

  /// Number of occupied voxels, blocks of 8^3 voxels allocated, and voxels ever observed.
  std::size_t occupiedCount() const;
  std::size_t blockCount() const;
  std::size_t observedCount() const;
  /// Heap bytes of the working grid (blocks, chunk index), excluding the OcTree.
  std::size_t memoryBytes() const;
  /// Heap bytes of the OcTree after the last flush (OctoMap's own memoryUsage()).
  std::size_t octreeMemoryBytes() const;
  const MapConfig& config() const { return config_; }
  /// What the map's noise limit (MapConfig::max_fuse_noise_voxels) measured so far: empty while
  /// the limit is off or no frame has been measured yet; else one line with the sensor's
  /// sigma(z) and the depth limit it set (or why none was set).
  std::string fuseNoiseSummary() const;
  /// The noise limit's depth, metres; 0 while none is set.
  double noiseFuseDepth() const;
  int framesFused() const;

  /// Pushes every voxel changed since the last flush into the OcTree (log-odds set key by key,
  /// inner nodes updated, tree pruned) and returns it. Takes the write lock; the tree returned is
  /// only stable until the next flush() or save().
  const octomap::OcTree& flush();
  /// Flushes and writes the OcTree as an OctoMap binary `.bt` file (occupied/free per leaf, read
  /// by octovis and octomap-tools). Written to a temporary file and renamed, so a failure leaves
  /// an existing file and the map untouched; throws MapIoError naming the path on failure.
  void save(const std::string& path_bt);
  /// Occupied leaf voxels of an OctoMap file (.bt or .ot) with this map's voxel size, as keys of
  /// this map's grid; throws MapIoError when the file cannot be read or its resolution differs.
  std::vector<VoxelKey> loadOccupiedKeys(const std::string& path) const;

  struct Impl;  ///< defined in src/core/map/voxel_map_impl.hpp

 private:
  friend class MapFuser;
  friend class MapRayCaster;
  const octomap::OcTree& flushLocked();

  MapConfig config_;
  std::unique_ptr<Impl> impl_;
  int frames_fused_ = 0;
};

}  // namespace depth_track
