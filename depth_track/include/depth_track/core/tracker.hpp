#pragma once
/// Frame-to-reference camera tracker: prediction, registration, failure detection, pose
/// compounding (thesis eq. 2.48–2.52, written as T_W_C). ROS-free core; not thread-safe (one
/// instance per camera stream).
#include <Eigen/Geometry>
#include <optional>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/prefilter.hpp"
#include "depth_track/core/registration.hpp"

namespace depth_track {

struct TrackerConfig {
  PrefilterConfig prefilter;
  PcaConfig pca;
  RegistrationConfig registration;
  /// Reference refresh: N >= 1 refreshes every N frames (the thesis's ICPFrames); 0 keeps a
  /// keyframe until the camera has moved keyframe_dist_m or turned keyframe_angle_deg from it,
  /// or fewer than keyframe_min_overlap of its cells still find a partner. Registering against
  /// a keyframe instead of the previous frame stops per-registration errors adding up at rest
  /// and at slow speed.
  int icp_frames = 0;
  double keyframe_dist_m = 0.10;
  double keyframe_angle_deg = 5.0;
  double keyframe_min_overlap = 0.5;
  double max_error_rms_m = 0.02;  ///< larger residual = failed frame, metres
  double max_jump_m = 0.15;       ///< larger correction of the prediction = failed frame, metres
  double max_jump_deg = 15.0;     ///< ... degrees
  bool constant_velocity = true;  ///< predict with the last motion (else: no motion)
  int threads = 1;                ///< TBB workers for the reduction

  std::vector<std::string> validate(const PinholeIntrinsics& intrinsics) const;
};

/// Per-frame outcome.
struct FrameStatus {
  double stamp_s = 0.0;
  bool tracked = false;  ///< false = pose is the prediction (frame flagged)
  std::string failure;   ///< reason when !tracked
  int cells = 0;
  int candidates = 0, matches = 0, fm_matches = 0, duplicates_broken = 0, iterations = 0;
  double error_rms_m = 0.0;
  double ms_prefilter = 0.0, ms_reduce = 0.0, ms_register = 0.0, ms_total = 0.0;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
};

class Tracker {
 public:
  /// Throws std::invalid_argument listing every problem of the config or intrinsics.
  Tracker(const PinholeIntrinsics& intrinsics, const TrackerConfig& config,
          const Eigen::Isometry3d& T_W_C0 = Eigen::Isometry3d::Identity());

  /// Tracks one frame (metres, 0 = no return). A frame of the wrong size throws
  /// DepthInputError; an unusable frame (empty, too few matches) is flagged, never a NaN pose.
  /// `prior_T_Wprev_Wcur` optionally replaces the constant-velocity guess with an external
  /// motion prior expressed as the camera's motion T_Cprev_Ccur.
  FrameStatus track(const DepthImage& depth, double stamp_s,
                    const std::optional<Eigen::Isometry3d>& prior_T_Cprev_Ccur = std::nullopt);

  /// Current camera pose in the world.
  const Eigen::Isometry3d& pose() const { return T_W_C_; }
  /// Replaces the current pose (e.g. after a loop-closure correction); keeps the velocity and
  /// moves the reference frame's pose with it.
  void correctPose(const Eigen::Isometry3d& T_W_C);
  /// Cells of the last tracked frame (camera frame).
  const CellCloud& lastCells() const { return last_cells_; }
  const TrackerConfig& config() const { return config_; }
  const PinholeIntrinsics& intrinsics() const { return intrinsics_; }

 private:
  PinholeIntrinsics intrinsics_;
  TrackerConfig config_;
  Eigen::Isometry3d T_W_C_;
  Eigen::Isometry3d T_W_Cref_;               ///< pose of the reference frame
  Eigen::Isometry3d velocity_T_Cprev_Ccur_;  ///< last frame-to-frame motion
  CellCloud reference_;
  CellCloud last_cells_;
  bool have_reference_ = false;
  int frames_since_refresh_ = 0;
};

}  // namespace depth_track
