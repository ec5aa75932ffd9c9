#pragma once
/// The ray-cast stage over a voxel map: built once for one virtual camera (intrinsics, range,
/// workers), it casts virtual depth images from a VoxelMap it does not own while a fuser may be
/// writing it on another thread. ROS-free core.
#include <Eigen/Geometry>
#include <memory>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/worker_pool.hpp"

namespace depth_track {

class MapRayCaster {
 public:
  /// Casts images of this camera and range from `map`, which must outlive the caster. Throws
  /// std::invalid_argument for bad intrinsics or range. A null pool casts on the calling thread.
  MapRayCaster(const VoxelMap& map, const PinholeIntrinsics& intrinsics, const DepthRange& range,
               std::shared_ptr<const WorkerPool> pool = nullptr);
  ~MapRayCaster();
  MapRayCaster(MapRayCaster&&) noexcept;
  MapRayCaster(const MapRayCaster&) = delete;
  MapRayCaster& operator=(const MapRayCaster&) = delete;

  /// Virtual depth image (metres, 0 = no hit) at T_W_C, as VoxelMap::raycast describes (the
  /// same pixels bit for bit); blocks first observed fewer than min_age_frames fused frames ago
  /// left out. Holds the map's read lock for the call: other readers run alongside, a fuse
  /// waits, so the image shows the map between two whole frames. Keeps its scratch (~5 MB at
  /// 640x480) between calls; not thread-safe itself (one caster per reading thread).
  DepthImage cast(const Eigen::Isometry3d& T_W_C, int min_age_frames = 0);

  const PinholeIntrinsics& intrinsics() const { return intrinsics_; }
  const DepthRange& range() const { return range_; }
  /// ms per cast() call.
  const RunningStats& timing() const { return timing_; }

  struct Scratch;  ///< defined in src/core/map/raycast.cpp

 private:
  const VoxelMap* map_;
  PinholeIntrinsics intrinsics_;
  DepthRange range_;
  std::shared_ptr<const WorkerPool> pool_;
  std::unique_ptr<Scratch> scratch_;
  RunningStats timing_;
};

}  // namespace depth_track
