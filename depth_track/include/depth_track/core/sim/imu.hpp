#pragma once
/// Simulated IMU readings for rendered runs (ROS-free, library depth_track_sim): what a
/// camera-mounted IMU would read along a run's continuous trajectory (RenderedRun::pose_at),
/// with white noise and a constant bias per axis. World frame z up (REP 103, scene.hpp).
#include <Eigen/Geometry>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

namespace depth_track {
namespace sim {

struct ImuNoiseConfig {
  double rate_hz = 200.0;
  double gyro_noise_rad_s = 0.0;   ///< white noise per reading, standard deviation per axis
  double accel_noise_m_s2 = 0.0;   ///< white noise per reading, standard deviation per axis
  double gyro_bias_rad_s = 0.0;    ///< constant bias per axis, drawn uniformly in +-this
  double accel_bias_m_s2 = 0.0;    ///< constant bias per axis, drawn uniformly in +-this

  /// Exact readings at 200 Hz.
  static ImuNoiseConfig none();
  /// A D435i's / D455's BMI055 at 200 Hz from its noise densities (gyro 0.014 deg/s/sqrt(Hz),
  /// accelerometer 150 ug/sqrt(Hz)), with biases as left after a calibration (0.5 deg/s,
  /// 0.1 m/s^2 per axis at most).
  static ImuNoiseConfig bmi055();
  /// Parses "none" or "bmi055"; throws std::invalid_argument naming the text.
  static ImuNoiseConfig parse(const std::string& name);
  std::vector<std::string> validate() const;
};

/// The readings of an IMU at T_C_I (its pose in the camera's optical frame) along the run, from
/// lead_s before its first frame (the camera still there, as pose_at holds the first pose) to
/// its last frame. Each reading is the mean angular rate and specific force over the interval to
/// the next (so integrating them without noise gives back the trajectory), plus noise and the
/// seed's biases. Throws std::invalid_argument for a run without pose_at (stepped runs), a
/// non-rigid T_C_I or a bad noise config.
std::vector<ImuSample> simulateImu(const RenderedRun& run, const Eigen::Isometry3d& T_C_I,
                                   const ImuNoiseConfig& noise, std::uint64_t seed,
                                   double lead_s = 0.5);

/// The same along any camera trajectory T_W_C(t) (world z up), readings stamped from t_first
/// to t_last (seconds). Throws std::invalid_argument for an empty function, t_last < t_first, a
/// non-rigid T_C_I or a bad noise config.
std::vector<ImuSample> simulateImu(const std::function<Eigen::Isometry3d(double)>& T_W_C,
                                   double t_first, double t_last, const Eigen::Isometry3d& T_C_I,
                                   const ImuNoiseConfig& noise, std::uint64_t seed);

}  // namespace sim
}  // namespace depth_track
