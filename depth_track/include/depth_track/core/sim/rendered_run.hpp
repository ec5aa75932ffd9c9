#pragma once
/// Rendered test runs: a scene, the L515 camera and a ground-truth camera trajectory at 30 Hz
/// (ROS-free, library depth_track_sim). Frames are rendered on demand with a noise model.
#include <Eigen/Geometry>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/scene.hpp"

namespace depth_track {
namespace sim {

/// The thesis's L515 depth camera (table 4.3): 640x480, isotropic K = 458 px, centre (W/2, H/2).
PinholeIntrinsics l515Intrinsics();

/// ServoTrack rig readings of one frame (what the rig's sensors would report, exact here).
struct RigSample {
  double track_pos_m = 0.0;  ///< carriage position along the track
  double pitch_rad = 0.0;    ///< positive = nose up
  double yaw_rad = 0.0;      ///< positive = left
};

struct RenderedRun {
  std::string name;
  std::string description;
  Scene scene;
  PinholeIntrinsics intrinsics = l515Intrinsics();
  DepthRange range;                      ///< L515 as configured in the thesis, 0.53-4.0 m
  std::vector<double> stamps_s;          ///< capture times, 30 Hz
  std::vector<Eigen::Isometry3d> T_W_C;  ///< ground-truth camera (optical frame) poses
  bool on_track = false;                 ///< ServoTrack run: `track` and `rig` are meaningful
  TrackGeometry track;                   ///< rig geometry used for T_W_C (ServoTrack runs)
  std::vector<RigSample> rig;            ///< per-frame rig readings (ServoTrack runs)
  /// Camera pose T_W_C at any time t (seconds) for runs whose camera moves while a frame is
  /// captured (continuous ServoTrack and all ServoTruck runs); empty for stepped runs.
  std::function<Eigen::Isometry3d(double t_s)> pose_at;
  /// Time to scan one frame from the top row to the bottom row, seconds. 0 (default) renders
  /// every row at the frame's stamp; > 0 (the L515's MEMS raster takes most of the 33 ms frame
  /// period) renders row v at stamp + scan_time_s * ((v + 0.5) / height - 0.5), so T_W_C is the
  /// pose of the middle row. Ignored when pose_at is empty.
  double scan_time_s = 0.0;

  std::size_t size() const { return stamps_s.size(); }
  /// Renders frame `i` (row-scanned when scan_time_s > 0) with the given noise; the noise seed
  /// is frameSeed(run_seed, i), so a frame is the same whatever order frames are rendered in.
  /// Throws std::out_of_range for a bad index. Thread-safe.
  DepthImage renderFrame(std::size_t i, const NoiseConfig& noise, std::uint64_t run_seed,
                         int threads = 0) const;
  /// renderFrame encoded as a 16UC1 buffer in the noise model's native unit
  /// (nativeDepthScale(noise.model): L515 0.25 mm, D435 1 mm, none 0.2 mm). Thread-safe.
  RawDepth16 renderFrameRaw(std::size_t i, const NoiseConfig& noise, std::uint64_t run_seed,
                            int threads = 0) const;
  /// The true surface frame i sees: its noise-free render back-projected every step_px pixels
  /// in u and v, world frame (metres), within the run's depth range. For map completeness
  /// (surfaceQuality). Throws std::out_of_range for a bad index, std::invalid_argument for
  /// step_px < 1. Thread-safe.
  std::vector<Eigen::Vector3d> visibleSurface(std::size_t i, int step_px, int threads = 0) const;
};

/// Parameters of a ServoTrack run: still frames, then either stepped motion (Mode 2: one
/// frame after each step) or continuous motion at 30 Hz (Mode 1) with an optional sinusoidal
/// gimbal input angle(t) = amplitude * sin(2 pi f t).
struct TrackRunSpec {
  enum class Axis { kNone, kPitch, kYaw };
  std::string name;
  std::string description;
  double rate_hz = 30.0;
  int still_frames = 0;
  double start_pos_m = 0.0;
  double step_m = 0.0;  ///< > 0 selects stepped mode
  int steps = 0;
  double speed_mps = 0.0;  ///< continuous mode: carriage speed
  double duration_s = 0.0;
  Axis axis = Axis::kNone;
  double amplitude_deg = 0.0;
  double frequency_hz = 0.0;

  std::vector<std::string> validate() const;
};

/// Builds a ServoTrack run in `scene`. Throws std::invalid_argument listing spec problems.
RenderedRun makeTrackRun(const TrackRunSpec& spec, const Scene& scene,
                         const TrackGeometry& track = TrackGeometry{});

/// One piece of a ServoTruck drive: forward speed and yaw rate held for a duration.
struct TruckSegment {
  double duration_s = 0.0;
  double speed_mps = 0.0;
  double yaw_rate_radps = 0.0;  ///< positive = turning left (anti-clockwise from above)
};

/// Parameters of a ServoTruck run: a unicycle path on the floor, integrated exactly (arcs),
/// with the camera level (plus a fixed pitch) at a fixed height above the floor.
struct TruckRunSpec {
  std::string name;
  std::string description;
  double rate_hz = 30.0;
  Eigen::Vector2d start_xy_m = Eigen::Vector2d::Zero();  ///< truck reference point in W
  double start_heading_rad = 0.0;                        ///< heading from W's x axis, CCW
  double camera_height_m = 0.35;
  double camera_forward_m = 0.12;  ///< optical centre ahead of the reference point
  double camera_pitch_rad = 0.0;   ///< positive = nose up
  int still_frames = 3;
  std::vector<TruckSegment> segments;

  std::vector<std::string> validate() const;
};

/// Builds a ServoTruck run in `scene`. Throws std::invalid_argument listing spec problems.
RenderedRun makeTruckRun(const TruckRunSpec& spec, const Scene& scene);

/// Names accepted by makeRun.
std::vector<std::string> knownRuns();

/// The named run: "xtest1_05_chair" (3 still frames, 100 steps of 10 mm towards the chair),
/// "chair_still" (90 frames at rest at the xtest1 start pose: drift under noise alone),
/// "rt1".."rt6" (thesis table 5.4 at the achieved speeds), "chair3", "room3", "hall1"
/// (ServoTruck), "wall_slide" (degenerate view: 3 s square on to a wall and a parallel cabinet).
/// Throws std::invalid_argument naming an unknown name and listing known ones.
RenderedRun makeRun(const std::string& name);

}  // namespace sim
}  // namespace depth_track
