#pragma once
/// The odometry's registration model: a mean-surface layer of the cells tracked so far, hashed
/// by voxel in the odometry's world frame. Each voxel keeps the running mean of the cell means
/// that fell into it and of their normals (a local plane averaged over every frame that saw
/// it). A new keyframe is registered against as the model sees it: each of its cells that lies
/// near a confident model plane takes that plane (its mean moved along its ray onto the plane,
/// the plane's normal), so the frames after it are registered against the surface averaged
/// over the run instead of one frame's noise (frame-to-model tracking on cells). The occupancy
/// map (VoxelMap, `.bt`) stays the map of record; this layer is the tracker's own. ROS-free
/// core; not thread-safe.
#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_noise.hpp"

namespace depth_track {

struct SurfaceModelConfig {
  /// Register keyframes against the model (off: frame-to-keyframe on the frames' own cells).
  /// On by default since 2026-12-03: it meets the D435 targets the frames' own cells miss and
  /// nearly halves fr1/xyz's error, at 4 % on teddy (docs/tracking.md, "Registration model").
  bool enabled = true;
  /// Voxel edge, metres: finer than a cell's footprint at working depths, so the steps between
  /// parallel faces that pin the translation along them are not averaged away (2 cm voxels let
  /// the rendered wall_slide run slide 54 mm where 1 cm ones keep it at 25 mm).
  double voxel_m = 0.01;
  /// Frames after which a voxel's running means stop weighting older ones more (the model then
  /// follows each new frame with weight 1/max_weight). One frame is one observation of a voxel:
  /// the mean of its cells in it.
  int max_weight = 64;
  int min_weight = 3;  ///< frames that saw a voxel before its plane refines a keyframe cell
  /// A keyframe cell farther than this from the model plane along its normal keeps its own
  /// mean and normal (the gate against a model that disagrees with the view), metres.
  double max_offset_m = 0.02;
  /// ... and, with the sensor's depth noise sigma(z) known (`noise`; auto_noise sets it),
  /// farther than max_offset_sigmas sigma(z): a voxel
  /// straddling two parallel faces a few noise widths apart (a picture on a wall, a cabinet
  /// front) holds a plane between them that fits neither, and the step between them is what
  /// pins the translation along them.
  double max_offset_sigmas = 3.0;
  DepthNoiseModel noise;
  double cos_min = 0.9;  ///< ... and one whose normal differs more than this from the plane's
  /// The odometry drops the voxels farther than this from the camera every prune_every frames
  /// (0 = keeps everything): the layer then holds the surroundings, not the whole run, and its
  /// memory stays bounded on a long run. Metres.
  double keep_radius_m = 8.0;
  int prune_every = 100;  ///< frames

  std::vector<std::string> validate() const;
};

/// What SurfaceModel::refine did to one keyframe.
struct ModelRefineStats {
  int cells = 0;              ///< cells of the keyframe
  int refined = 0;            ///< cells that took the model's plane
  int no_model = 0;           ///< no confident voxel where the cell lies
  int rejected = 0;           ///< a voxel, but its plane failed the offset or normal gate
  double rms_offset_m = 0.0;  ///< RMS distance of the refined cells' means to the model planes
};

class SurfaceModel {
 public:
  /// Throws std::invalid_argument listing every problem of the config.
  explicit SurfaceModel(const SurfaceModelConfig& config = {});

  /// Adds the cells (camera frame) seen from T_W_C.
  void integrate(const CellCloud& cells, const Eigen::Isometry3d& T_W_C);
  /// A copy of `cells` (camera frame, seen from T_W_C) with the model's plane in place of each
  /// cell's own where the model is confident and agrees (SurfaceModelConfig gates).
  /// `took_model`, when given, gets one flag per cell: 1 where the cell took the model's plane.
  /// `reach_m` > 0 widens the search along each cell's normal to that distance: the nearest
  /// voxel whose plane agrees within reach_m is the centre of the averaging, and the offset gate
  /// becomes reach_m (a first, coarse round after drift; 0 = the voxel and its two neighbours).
  CellCloud refine(const CellCloud& cells, const Eigen::Isometry3d& T_W_C,
                   ModelRefineStats* stats = nullptr,
                   std::vector<std::uint8_t>* took_model = nullptr, double reach_m = 0.0) const;
  void clear();
  /// Drops every voxel whose mean lies farther than radius_m from centre_W (world, metres) and
  /// shrinks the table to what is left. Returns the number dropped.
  std::size_t prune(const Eigen::Vector3d& centre_W, double radius_m);
  /// Replaces the gates and weights, keeping the voxels (a runtime reconfiguration). Throws
  /// std::invalid_argument listing every problem, or for another voxel_m (that needs a new model).
  void setConfig(const SurfaceModelConfig& config);

  std::size_t voxelCount() const { return size_; }
  /// Bytes the layer holds: its open-addressing table (key and record per slot; from 2^16
  /// slots, doubling when 70 % full, so 1.4 to 2.9 slots per voxel once past the first table).
  std::size_t memoryBytes() const;
  /// memoryBytes() per voxel (0 when empty).
  double bytesPerVoxel() const;
  const SurfaceModelConfig& config() const { return config_; }

  /// One voxel: running means of the cell means (world, metres) and unit normals.
  struct Voxel {
    float mean[3] = {0.f, 0.f, 0.f};
    float normal[3] = {0.f, 0.f, 0.f};
    std::uint16_t weight = 0;  ///< observations, saturating at max_weight
  };

 private:
  std::uint64_t keyOf(const Eigen::Vector3f& p_W) const;
  /// The voxel of `key`, or null.
  const Voxel* find(std::uint64_t key) const;
  /// The voxel of `key`, inserted empty (weight 0) when missing.
  Voxel& findOrInsert(std::uint64_t key);
  std::size_t slotOf(std::uint64_t key) const;
  /// Asks the cache for the home slot of `key` (a table of at least one slot).
  void prefetchSlot(std::uint64_t key) const;
  void grow();
  /// Re-inserts the occupied slots of (keys, slots) into a fresh table of 2^bits slots, keeping
  /// those `keep` accepts.
  template <class Keep>
  void rehash(int bits, Keep keep);

  SurfaceModelConfig config_;
  float inv_voxel_ = 50.f;
  // Open addressing with linear probing: keys_[i] == kEmpty marks a free slot.
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
  std::vector<std::uint64_t> keys_;
  std::vector<Voxel> slots_;
  std::size_t size_ = 0;
  int bits_ = 0;
  /// integrate()'s per-frame scratch: each cell's voxel key, world mean and world normal.
  struct CellSample {
    std::uint64_t key;
    Eigen::Vector3f p, n;
  };
  std::vector<CellSample> frame_cells_;
  /// integrate()'s per-frame grouping: an open-addressing table of the frame's voxel keys (the
  /// index of the key's first sample in frame_cells_, -1 = empty), and each group's cell count.
  std::vector<std::int32_t> group_slot_;
  std::vector<std::uint32_t> group_count_;
};

}  // namespace depth_track
