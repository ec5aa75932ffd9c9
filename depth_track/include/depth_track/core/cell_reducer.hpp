#pragma once
/// The PCA cell reduction as a pipeline stage: built once with its config and intrinsics, a
/// depth frame in, a shared immutable cell cloud out (stamped with the frame's time and optical
/// frame), so the odometry, the graph's publisher and a mapper thread can all hold the same
/// cells without copies. ROS-free core; not thread-safe (timing statistics; one instance per
/// stream); the clouds it returns are safe to read from any thread.
#include <memory>
#include <string>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/worker_pool.hpp"

namespace depth_track {

class CellReducer {
 public:
  /// Throws std::invalid_argument listing every problem of the config or intrinsics. A null
  /// pool runs on the calling thread.
  CellReducer(const PinholeIntrinsics& intrinsics, const PcaConfig& config,
              std::shared_ptr<const WorkerPool> pool = nullptr);

  /// Cells of a frame (metres, 0 = no return) seen at stamp_s (seconds) in optical frame
  /// frame_id. Throws DepthInputError for a frame of another size than the intrinsics'.
  std::shared_ptr<const CellCloud> reduce(const DepthImage& depth, double stamp_s,
                                          const std::string& frame_id = {});

  const PcaConfig& config() const { return config_; }
  const PinholeIntrinsics& intrinsics() const { return intrinsics_; }
  /// ms per reduce() call.
  const RunningStats& timing() const { return timing_; }

 private:
  PinholeIntrinsics intrinsics_;
  PcaConfig config_;
  std::shared_ptr<const WorkerPool> pool_;
  RunningStats timing_;
};

}  // namespace depth_track
