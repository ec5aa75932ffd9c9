#pragma once
/// The mapping stages composed for one camera stream: the map storage with a fuser, a ray caster
/// and a loop closer over it; loop closure every CLStep frames, then fusion of the full frame at
/// the (corrected) pose; ray casting on request; `.bt` save; per-stage timings. Used the same
/// way by the offline tool and the graph. ROS-free core; not thread-safe (one instance per
/// camera stream; the graph shares map() between its own fusion and loop-closure stages).
#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/map/map_fuser.hpp"
#include "depth_track/core/map/map_raycaster.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/running_stats.hpp"

namespace depth_track {

struct MapperConfig {
  MapConfig map;
  LoopClosureConfig loop;
  DepthRange range;     ///< sensor range used for ray casting (virtual images), metres
  int flush_every = 0;  ///< frames between flushes into the OcTree (0 = only when saving)

  std::vector<std::string> validate(const PinholeIntrinsics& intrinsics) const;
};

/// Outcome of Mapper::process for one frame.
struct MapperFrame {
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();  ///< pose the frame was fused at
  bool loop_attempted = false;
  LoopClosureResult loop;  ///< meaningful when loop_attempted
  /// processOdom: the map -> odom correction in force after the frame, stamped with the frame it
  /// was computed for. process(), whose caller moves the tracker instead: this frame's own
  /// correction (identity unless one was accepted).
  MapCorrection correction;
  FuseStats fuse;
};

class Mapper {
 public:
  /// Places the map region around the start pose T_W_C0. Throws std::invalid_argument listing
  /// every problem of the config or intrinsics.
  Mapper(const PinholeIntrinsics& intrinsics, const MapperConfig& config,
         const Eigen::Isometry3d& T_W_C0 = Eigen::Isometry3d::Identity());
  Mapper(const Mapper&) = delete;  // the stages hold the map by reference
  Mapper& operator=(const Mapper&) = delete;

  /// One tracked frame: on every cl_step-th frame (loop closure enabled, map not empty) corrects
  /// T_W_C against the map, then fuses the frame at the resulting pose. If a correction was
  /// accepted the caller should hand the returned pose to Tracker::correctPose(). Errors as
  /// VoxelMap::fuse (the map is unchanged on a throw).
  MapperFrame process(const DepthImage& depth, const Eigen::Isometry3d& T_W_C);
  /// One tracked frame as the graph runs it: the tracker stays in its odometry frame (T_O_C, not
  /// corrected), the mapper keeps the map -> odom correction T_M_O, predicts T_M_O T_O_C, lets
  /// loop closure update T_M_O (stamped stamp_s) and fuses at the map-frame pose. The poses
  /// equal process() with corrections fed back into the tracker, up to rounding. Errors as
  /// process().
  MapperFrame processOdom(const DepthImage& depth, double stamp_s, const Eigen::Isometry3d& T_O_C);
  /// Fuses a frame at a known pose (no loop closure), e.g. a ground-truth trajectory.
  FuseStats fuse(const DepthImage& depth, const Eigen::Isometry3d& T_W_C);
  /// Virtual depth image of the map at T_W_C with the camera's intrinsics and range (timed).
  DepthImage raycast(const Eigen::Isometry3d& T_W_C);
  /// Flushes into the OcTree and writes `path` (.bt); throws MapIoError naming the path.
  void save(const std::string& path);

  const VoxelMap& map() const { return map_; }
  VoxelMap& map() { return map_; }
  const MapperConfig& config() const { return config_; }
  /// The map -> odom correction kept by processOdom (identity until one is accepted).
  const MapCorrection& correction() const { return correction_; }
  int loopAttempts() const { return loop_attempts_; }
  int loopAccepted() const { return loop_accepted_; }
  /// Median wall time of the last RunningStats::kDefaultWindow fuse calls / ray casts, ms (0
  /// when none).
  double fuseMedianMs() const { return fuse_ms_.median(); }
  double raycastMedianMs() const { return raycast_ms_.median(); }
  /// ms per fuse call and per ray cast (loop closure's and raycast()'s).
  const RunningStats& fuseTiming() const { return fuse_ms_; }
  const RunningStats& raycastTiming() const { return raycast_ms_; }
  /// The loop-closure stage (loop closure enabled), else null.
  const LoopCloser* loopCloser() const { return loop_.get(); }
  /// "fuse_median_ms=X raycast_median_ms=Y loop_median_ms=Z loop_closures=A/B" (Z: median ms
  /// per attempt; A/B accepted/attempted).
  std::string summary() const;

 private:
  MapperFrame step(const DepthImage& depth, double stamp_s, const Eigen::Isometry3d& T_O_C,
                   const Eigen::Isometry3d& T_M_O);

  PinholeIntrinsics intrinsics_;
  MapperConfig config_;
  VoxelMap map_;
  MapFuser fuser_;
  MapRayCaster raycaster_;
  std::unique_ptr<LoopCloser> loop_;  ///< when loop closure is enabled
  MapCorrection correction_;
  int frames_ = 0;
  int loop_attempts_ = 0, loop_accepted_ = 0;
  RunningStats fuse_ms_, raycast_ms_;
};

}  // namespace depth_track
