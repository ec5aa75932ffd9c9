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
#include <optional>
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
/// heading the steering turns (TruckOdometry: bicycle model, its lags settled on the first
/// sample's demands, W = base_link at the first sample; integrated reading to reading, so a pose
/// does not depend on which other stamps are asked for). A stamp outside the streams' span gets no pose. The result
/// keeps the unshifted stamps, in the order given. Throws std::invalid_argument when there is no
/// stream, a stream is not in stamp order or holds a non-finite value, or the geometry is invalid.
/// Thread-safe.
Trajectory sensorTrajectory(const RigSensorStreams& streams, const std::vector<double>& stamps_s,
                            const RigGeometry& geometry, double shift_s = 0.0);

/// The ServoTruck's dead reckoning one TruckDRV reading at a time: sensorTrajectory's truck
/// reference, and a live odometry source (wheel odometry for the tracker's motion prior,
/// rig_odometry). A kinematic bicycle about the rear axle through the drive's and the steering's
/// first-order lags; base_link poses T_W_B with W = base_link at the first reading.
class TruckOdometry {
 public:
  /// Throws std::invalid_argument listing the geometry's problems.
  explicit TruckOdometry(const TruckGeometry& geometry);
  /// Adds the next reading and returns T_W_B at its stamp (the previous reading's demands held
  /// until then; the first reading starts the lags settled on its demands). Throws
  /// std::invalid_argument for a non-finite value or a stamp before the last reading's; the
  /// odometry is then unchanged.
  Eigen::Isometry3d add(const TruckRcSample& reading);
  /// T_W_B at stamp_s, no earlier than the last reading, with its demands held (nullopt before
  /// the first reading or for an earlier stamp); the odometry itself stays at the last reading.
  std::optional<Eigen::Isometry3d> predict(double stamp_s) const;
  /// Readings added.
  std::size_t readings() const { return readings_; }

  /// Planar state: rear axle position and heading (counter-clockwise) in W, the lagged speed and
  /// wheel angle, and its time.
  struct State {
    double x = 0.0, y = 0.0, heading = 0.0, speed = 0.0, steer = 0.0, t = 0.0;
  };
  /// The state at the last reading.
  const State& state() const { return state_; }
  const TruckGeometry& geometry() const { return g_; }

 private:
  TruckGeometry g_;
  State state_;
  TruckRcSample last_;
  std::size_t readings_ = 0;
};

/// The rigs' sensors as a motion prior for Tracker::track (what the graph's ~guess_frame takes
/// from tf, for offline runs): the camera's motion T_Cprev_Ccur between consecutive frames as the
/// sensors see it. ServoTrack: track position and gimbal angles interpolated (sensorTrajectory);
/// ServoTruck: TruckOdometry's poses at the readings either side of each frame, interpolated
/// (position linear, rotation slerp) as tf2 interpolates the graph's rig_odometry tf.
class SensorMotionPrior {
 public:
  /// Throws std::invalid_argument when there is no stream, a stream is out of order or not
  /// finite, or the geometry is invalid (as sensorTrajectory).
  SensorMotionPrior(RigSensorStreams streams, const RigGeometry& geometry);
  /// The motion from the previous call's stamp to stamp_s (increasing); nullopt on the first
  /// call, after a stamp the streams do not cover, and for such a stamp.
  std::optional<Eigen::Isometry3d> next(double stamp_s);

 private:
  RigSensorStreams streams_;
  RigGeometry geometry_;
  std::optional<TruckOdometry> truck_;
  std::size_t fed_ = 0;  // truck readings given to truck_
  Eigen::Isometry3d before_ = Eigen::Isometry3d::Identity(),  // T_W_B at readings fed_ - 2, - 1
      after_ = Eigen::Isometry3d::Identity();
  std::optional<Eigen::Isometry3d> last_T_W_C_;
  double last_stamp_s_ = -1e300;
  std::optional<Eigen::Isometry3d> cameraPose(double stamp_s);
};

}  // namespace depth_track
