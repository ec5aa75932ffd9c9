#pragma once
/// Depth-frame camera tracker: the prefilter, cell reduction and cell odometry stages composed
/// over one worker pool, depth in, pose out. The ROS graph runs the same stages one per
/// nodelet; this class is their composition for the offline tools and the tests. ROS-free
/// core; not thread-safe (one instance per camera stream).
#include <Eigen/Geometry>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/cell_reducer.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/noise_model.hpp"
#include "depth_track/core/prefilter.hpp"
#include "depth_track/core/prefilter_stage.hpp"
#include "depth_track/core/registration.hpp"
#include "depth_track/core/worker_pool.hpp"

namespace depth_track {

/// The odometry's parameters (registration, keyframes, gates) plus the front end's. Derived
/// rather than nested so every parameter keeps its one name (config.icp_frames,
/// config.registration.method) in the parameter table, the YAML files and the tools.
struct TrackerConfig : CellOdometryConfig {
  PrefilterConfig prefilter;
  PcaConfig pca;
  int threads = 1;  ///< workers of the shared pool (prefilter and reduction)
  /// Estimate the depth noise on the first usable frame (NoiseEstimator) and set from it, before
  /// the first registration: the edge test's noise term, normal pooling (normal_radius,
  /// normal_merge_dist), min_valid_fraction, cos_min, huber_delta and max_error (adaptToNoise).
  /// Off: those parameters are used as given (the presets in config/ switch it off).
  bool auto_noise = true;

  std::vector<std::string> validate(const PinholeIntrinsics& intrinsics) const;
  /// The reduction as the tracker runs it: inverse square roots only when Cell Search's
  /// Förstner–Moonen gate reads them.
  PcaConfig reducerConfig() const;
  /// The odometry as the tracker runs it: the Förstner–Moonen regulariser is the reduction's.
  CellOdometryConfig odometryConfig() const;
};

class Tracker {
 public:
  /// Throws std::invalid_argument listing every problem of the config or intrinsics.
  Tracker(const PinholeIntrinsics& intrinsics, const TrackerConfig& config,
          const Eigen::Isometry3d& T_W_C0 = Eigen::Isometry3d::Identity());

  /// Tracks one frame (metres, 0 = no return). A frame of the wrong size throws
  /// DepthInputError; an unusable frame (empty, too few matches) is flagged, never a NaN pose.
  /// `prior_T_Cprev_Ccur` optionally replaces the constant-velocity guess with an external
  /// motion prior expressed as the camera's motion T_Cprev_Ccur; `hold`, an IMU's part for the
  /// directions the view does not fix (CellOdometry::track).
  FrameStatus track(const DepthImage& depth, double stamp_s,
                    const std::optional<Eigen::Isometry3d>& prior_T_Cprev_Ccur = std::nullopt,
                    const std::optional<InertialHold>& hold = std::nullopt);

  /// Current camera pose in the world.
  const Eigen::Isometry3d& pose() const { return odometry_.pose(); }
  /// Replaces the current pose (e.g. after a loop-closure correction); keeps the velocity and
  /// moves the reference frame's pose with it.
  void correctPose(const Eigen::Isometry3d& T_W_C) { odometry_.correctPose(T_W_C); }
  /// Cells of the last frame (camera frame); empty before the first.
  const CellCloud& lastCells() const;
  const TrackerConfig& config() const { return config_; }
  const PinholeIntrinsics& intrinsics() const { return intrinsics_; }

  /// The stages (reset, relocalise and state live on the odometry).
  const PrefilterStage& prefilter() const { return prefilter_; }
  const CellReducer& reducer() const { return reducer_; }
  CellOdometry& odometry() { return odometry_; }
  const CellOdometry& odometry() const { return odometry_; }
  /// ms per track() call, whole frame.
  const RunningStats& timing() const { return timing_; }
  /// With auto_noise: what the first frame's noise measurement gave and set (nullopt before
  /// it, and without auto_noise).
  const std::optional<NoiseCalibration>& noiseCalibration() const { return calibration_; }

 private:
  PinholeIntrinsics intrinsics_;
  TrackerConfig config_;
  std::shared_ptr<const WorkerPool> pool_;
  PrefilterStage prefilter_;
  CellReducer reducer_;
  CellOdometry odometry_;
  RunningStats timing_;
  Eigen::Isometry3d T_W_C0_;
  std::optional<NoiseCalibration> calibration_;
  /// Keeps `calibration` and, when it measured the noise, rebuilds reducer and odometry with
  /// its settings (before the first frame only: nothing is tracked yet).
  void applyCalibration(const NoiseCalibration& calibration);
};

}  // namespace depth_track
