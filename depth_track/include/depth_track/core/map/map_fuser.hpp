#pragma once
/// The fusion stage over a voxel map (storage apart from the integrator, as voxblox keeps its
/// layers apart from its integrators): built once for one camera, it fuses full-resolution
/// depth frames at their poses into a VoxelMap it does not own. ROS-free core.
#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/running_stats.hpp"

namespace depth_track {

class MapFuser {
 public:
  /// Fuses frames of a camera with these intrinsics into `map`, which must outlive the fuser.
  /// Throws std::invalid_argument for bad intrinsics.
  MapFuser(VoxelMap& map, const PinholeIntrinsics& intrinsics);

  /// Fuses a frame (metres, 0 = no return) seen from T_W_C (VoxelMap's update model, one update
  /// per voxel and frame). Throws DepthInputError for a frame whose size does not match the
  /// intrinsics or that has no return, std::invalid_argument for a non-finite / non-rigid pose;
  /// on a throw the map is unchanged. Holds the map's write lock for the call: concurrent
  /// readers (ray casts on other threads) wait and never see a half-fused frame. Not
  /// thread-safe itself (one fuser per writing thread; its timing statistics).
  FuseStats fuse(const DepthImage& depth, const Eigen::Isometry3d& T_W_C);

  const PinholeIntrinsics& intrinsics() const { return intrinsics_; }
  /// ms per fuse() call (FuseStats::ms).
  const RunningStats& timing() const { return timing_; }

 private:
  VoxelMap& map_;
  PinholeIntrinsics intrinsics_;
  std::vector<float> ray_x_, ray_y_;  ///< (u - cx) / fx per column, (v - cy) / fy per row
  DepthImage snapped_;                ///< the frame with returns snapped (MapConfig::snap_cell_px)
  DepthImage edged_;  ///< the frame without the near sides of depth edges (edge_margin_px)
  std::vector<std::uint8_t> dropped_;  ///< 1 where a return was left out of the hits
  std::vector<float> edge_scratch_;      ///< the rows' window maxima
  RunningStats timing_;
};

}  // namespace depth_track
