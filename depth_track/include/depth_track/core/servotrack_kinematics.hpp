#pragma once
/// ServoTrack rig kinematics: camera pose from carriage position and gimbal angles (ROS-free core).
///
/// Chain (thesis ch. 4.2: a carriage on a straight track carrying a yaw-over-pitch servo table):
///   W -> K (carriage at track position s, x along the track, z up)
///     -> yaw stage (rotation about K's vertical z axis; yaw positive = camera turns LEFT)
///     -> pitch axis (offset forward/up from the yaw axis; rotation about the stage's y axis;
///        pitch positive = NOSE UP)
///     -> camera body B (x forward, y left, z up; optical centre offset from the pitch axis)
///     -> optical frame C (x right, y down, z forward).
/// At zero angles the optical z axis points along the track direction and the image rows are
/// horizontal.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "depth_track/core/tum_io.hpp"

namespace depth_track {

/// Geometry of the ServoTrack rig in the world frame W (REP 103: x forward, y left, z up, floor
/// z = 0). The thesis gives no drawing dimensions; the defaults are plausible for its bench rig
/// and put the optical centre at (0, 0, 0.80) m at track position 0 with zero angles.
struct TrackGeometry {
  /// Point where the yaw axis meets the carriage deck at track position 0, metres in W.
  Eigen::Vector3d origin_W{-0.045, 0.0, 0.62};
  /// Direction of travel for increasing track position (normalised on use; must be horizontal
  /// enough to define a level carriage, i.e. not parallel to z).
  Eigen::Vector3d direction_W{1.0, 0.0, 0.0};
  /// Height of the pitch axis above the deck, along the yaw axis, metres.
  double pitch_axis_height_m = 0.15;
  /// Forward offset of the pitch axis from the yaw axis (in the yawed stage), metres.
  double pitch_axis_forward_m = 0.0;
  /// Optical centre relative to the pitch axis in the camera body frame (x forward, y left,
  /// z up) at zero pitch, metres.
  Eigen::Vector3d camera_offset_m{0.045, 0.0, 0.03};

  /// Every problem with this geometry (empty = valid).
  std::vector<std::string> validate() const;
};

/// Camera pose T_W_C (optical frame: x right, y down, z forward) for carriage position
/// track_pos_m (metres along direction_W from origin_W), pitch_rad (positive = nose up) and
/// yaw_rad (positive = turn left, counter-clockwise seen from above). Throws
/// std::invalid_argument for an invalid geometry or a non-finite input. Thread-safe.
Eigen::Isometry3d cameraPoseOnTrack(double track_pos_m, double pitch_rad, double yaw_rad,
                                    const TrackGeometry& geometry = TrackGeometry{});

/// Rotation taking camera-body axes (x forward, y left, z up) to optical axes: R_B_C maps
/// optical-frame vectors into the body frame. Thread-safe.
Eigen::Matrix3d rotationBodyFromOptical();

// ---- references from the rigs' own sensors (thesis ch. 5: tracking is checked against them) ----

/// One TrackDRV reading (rig_msgs/TrackState).
struct TrackSensorSample {
  double stamp_s = 0.0;      ///< host receive time, s
  double track_pos_m = 0.0;  ///< TrackPos: carriage position from the stepper count, m
};

/// One CarDRV reading (rig_msgs/CarriageSensors): the calibrated gimbal potentiometers.
struct GimbalSensorSample {
  double stamp_s = 0.0;    ///< host receive time, s
  double pitch_deg = 0.0;  ///< Pitch, positive nose up, deg
  double yaw_deg = 0.0;    ///< Yaw, positive left, deg
};

/// One TruckDRV reading (rig_msgs/TruckRc).
struct TruckRcSample {
  double stamp_s = 0.0;    ///< host receive time, s
  double speed_mps = 0.0;  ///< forward speed from the RC speed calibration (< 0 reverse), m/s
  double steering = 0.0;   ///< CH2 normalised: -1 full left .. +1 full right
};

/// The ServoTruck as dead reckoning sees it: a kinematic bicycle about the rear axle, driven by
/// the RC demands through first-order lags. The truck's odometry is the RC demand, so these
/// numbers are the vehicle model the thesis (5.5) says the truck needs; the defaults are those of
/// the simulated truck (rig_drivers TruckModelConfig). The camera mount comes from the rig's
/// static transforms (base_link -> optical frame).
struct TruckGeometry {
  double wheelbase_m = 0.32;    ///< front to rear axle, m
  double max_steer_deg = 30.0;  ///< front wheel angle at full CH2 lock, deg
  double steer_lag_s = 0.08;    ///< steering servo behind CH2 (first-order time constant), s
  double speed_lag_s = 0.35;    ///< drive behind the speed demand (first-order), s
  /// Optical frame in base_link (rear axle centre on the floor, x forward, z up).
  Eigen::Isometry3d T_B_C = Eigen::Isometry3d::Identity();

  /// Every problem (empty = valid).
  std::vector<std::string> validate() const;
};

/// Geometry of both rigs, for whichever streams a run has.
struct RigGeometry {
  TrackGeometry track;
  TruckGeometry truck;
};

/// The sensor streams of one run (each in stamp order; empty when the rig has no such board).
struct RigSensorStreams {
  std::vector<TrackSensorSample> track;
  std::vector<GimbalSensorSample> gimbal;
  std::vector<TruckRcSample> truck;

  /// ServoTrack reference available: track position and gimbal angles.
  bool hasServoTrack() const { return !track.empty() && !gimbal.empty(); }
  /// ServoTruck reference available.
  bool hasServoTruck() const { return !truck.empty(); }
  /// Median interval of the stream the reference is driven by (track, else truck), s; 0 when
  /// there are fewer than two samples.
  double samplePeriod() const;
  /// "track_state + carriage_sensors", "truck_rc" or "" (what the reference is built from).
  std::string describe() const;
};

/// Camera poses T_W_C implied by the sensors at each of `stamps_s` (shifted by `shift_s`: the
/// reading taken shift_s after the frame; positive = the sensor stream lags the camera).
/// ServoTrack: track position and gimbal angles linearly interpolated, through
/// cameraPoseOnTrack; ServoTruck (when there is no ServoTrack stream): speed integrated along the
/// heading the steering turns (bicycle model, its lags settled on the first sample's demands;
/// W = base_link at the first sample). A stamp outside the streams' span gets no pose. The result
/// keeps the unshifted stamps, in the order given. Throws std::invalid_argument when there is no
/// stream, a stream is not in stamp order or holds a non-finite value, or the geometry is invalid.
/// Thread-safe.
Trajectory sensorTrajectory(const RigSensorStreams& streams, const std::vector<double>& stamps_s,
                            const RigGeometry& geometry, double shift_s = 0.0);

}  // namespace depth_track
