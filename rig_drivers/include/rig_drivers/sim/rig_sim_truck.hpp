#pragma once
/// ServoTruck plant for the rig simulator: kinematic bicycle model on a flat floor and the camera
/// mount (ROS-free). World frame W: REP 103 (x forward, y left, z up, floor z = 0).
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace rig_drivers {

/// Geometry and dynamics of the truck. The thesis gives no dimensions; defaults are those of a
/// 1:10 RC truck with the depth camera on the upper electronics tray.
struct TruckModelConfig {
  double wheelbase_m = 0.32;            ///< front to rear axle, m
  double max_steer_deg = 30.0;          ///< front wheel angle at full CH2 lock, degrees
  double steer_time_constant_s = 0.08;  ///< steering servo first-order lag, s
  double speed_time_constant_s = 0.35;  ///< drive (motor + inertia) first-order lag, s
  double max_speed_mps = 1.0;           ///< thesis 4.3.1 constraint 2.3, m/s
  double speed_scale_error = 0.04;      ///< true speed / calibrated speed - 1 (calibration error)
  double camera_forward_m = 0.12;       ///< optical centre ahead of the rear axle, m
  double camera_height_m = 0.35;        ///< optical centre above the floor, m
  double camera_pitch_deg = 0.0;        ///< camera nose-up tilt, degrees
  /// Every problem with this configuration (empty = valid).
  std::vector<std::string> validate() const;
};

/// Planar truck state: rear-axle centre on the floor, heading counter-clockwise from +x.
struct TruckState {
  double x_m = 0.0, y_m = 0.0, heading_rad = 0.0;
  double speed_mps = 0.0;   ///< true forward speed (negative = reverse), m/s
  double steer_rad = 0.0;   ///< true front wheel angle, positive = left, rad
  double odometer_m = 0.0;  ///< distance driven, m
};

/// Kinematic bicycle model with first-order lags on speed and steering.
class TruckModel {
 public:
  /// Throws std::invalid_argument naming every problem of `config`.
  explicit TruckModel(const TruckModelConfig& config, const TruckState& start = TruckState{});
  /// Advances dt_s with demanded speed (m/s, from the speed calibration of the motor signal) and
  /// normalised steering (-1 full left .. 1 full right, as RC CH2). Exact integration of the
  /// arc for constant speed and steering over the step. Not thread-safe.
  void step(double dt_s, double demanded_speed_mps, double steering);
  const TruckState& state() const { return state_; }
  /// Pose of base_link (rear axle centre, on the floor, x forward, z up) in W.
  Eigen::Isometry3d T_W_B() const;
  /// Pose of the optical frame (x right, y down, z forward) in base_link.
  Eigen::Isometry3d T_B_C() const;
  /// True camera pose T_W_C (optical frame) in W.
  Eigen::Isometry3d T_W_C() const { return T_W_B() * T_B_C(); }
  /// Turning radius of the rear axle centre at full lock, m.
  double minTurnRadius() const;
  const TruckModelConfig& config() const { return config_; }

 private:
  TruckModelConfig config_;
  TruckState state_;
};

}  // namespace rig_drivers
