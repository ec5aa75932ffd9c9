#pragma once
/// The prefilter as a pipeline stage: built once with its config and the camera's image size,
/// depth in, depth out, timed. ROS-free core; not thread-safe (timing statistics; one instance
/// per stream).
#include <memory>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/prefilter.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/worker_pool.hpp"

namespace depth_track {

class PrefilterStage {
 public:
  /// Throws std::invalid_argument listing every problem of the config for the intrinsics' image
  /// size. A null pool runs on the calling thread.
  PrefilterStage(const PinholeIntrinsics& intrinsics, const PrefilterConfig& config,
                 std::shared_ptr<const WorkerPool> pool = nullptr);

  /// True when the stage passes frames unchanged (type none): callers may skip apply().
  bool passthrough() const { return config_.type == PrefilterType::kNone; }
  /// Filtered copy of a frame in metres (0 = no return). Throws DepthInputError for a frame of
  /// another size than the intrinsics'.
  DepthImage apply(const DepthImage& depth);

  const PrefilterConfig& config() const { return config_; }
  /// ms per apply() call.
  const RunningStats& timing() const { return timing_; }

 private:
  PinholeIntrinsics intrinsics_;
  PrefilterConfig config_;
  std::shared_ptr<const WorkerPool> pool_;
  RunningStats timing_;
};

}  // namespace depth_track
