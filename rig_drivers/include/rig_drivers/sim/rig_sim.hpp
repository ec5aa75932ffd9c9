#pragma once
/// Rig simulator (ROS-free): runs the boards' firmware logic (TrackDRV, CarDRV, TruckDRV) on a
/// fixed-step clock against physical models of the rigs, and reports the exact camera pose
/// separately from what the boards send (which carries the modelled sensor errors).
///
/// Two ways to drive it:
///  - scripted host (RigSimConfig::scripted_host): the simulator also plays the host side of the
///    scenario (init, mode, moves, servo demands, mode 2 steps) through the codec, as the bag
///    generator does offline;
///  - external host: bytes from real host programs (the driver nodes on ptys) enter through
///    hostSend(); with `autopilot` the scenario's motion still runs in mode 1, its own acks
///    filtered out of what the external host sees.
#include <Eigen/Geometry>
#include <cstdint>
#include <deque>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "depth_track/core/servotrack_kinematics.hpp"
#include "rig_drivers/protocol/codec.hpp"
#include "rig_drivers/sim/physics_models.hpp"
#include "rig_drivers/sim/rig_sim_scenario.hpp"
#include "rig_drivers/sim/rig_sim_truck.hpp"

namespace rig_drivers {

/// Physical models of the rig and their errors (models in physics_models.hpp). Defaults follow
/// the thesis (ch. 4.2, 5.4, appendices A3 and B).
struct RigSimConfig {
  double physics_rate_hz = 2000.0;  ///< fixed step of the physics and the firmware loops, Hz
  /// Carriage on its belt (fig. 5.23: ~9 Hz longitudinal vibration).
  protocol::BeltCarriageConfig belt;
  /// Gimbal servos (figs. B4/B5: friction-bound, lagging the demand).
  protocol::ServoModelConfig pitch_servo;
  protocol::ServoModelConfig yaw_servo;
  /// Servo pulse calibration error: true angle = CarDRV's intended angle * (1 + gain) + offset.
  double servo_gain_error = 0.02;  ///< (1)
  double servo_offset_deg = 0.3;   ///< deg
  /// Gimbal potentiometers read by the 10-bit ADC (noise, quantisation).
  protocol::AdcConfig adc;
  /// Pot calibration error: for a true angle a, CarDRV's calibrated reading (before noise and
  /// quantisation) is a * (1 + gain) + offset.
  double pitch_sensor_gain_error = 0.015;  ///< (1) (Table B1: +0.32 deg at 21 deg)
  double pitch_sensor_offset_deg = -0.6;   ///< deg (Table B1: -0.637 deg zero reading)
  double yaw_sensor_gain_error = -0.03;    ///< (1) (Table B2: 20.36 read for 21.0 deg)
  double yaw_sensor_offset_deg = -0.5;     ///< deg (Table B2: -0.49 deg zero reading)
  /// MPU6050 per axis, g (noise and quantisation of the +/-2 g range).
  protocol::SensorNoiseConfig accel{1.0, 0.0, 0.01, 1.0 / 16384.0, -2.0, 2.0};
  /// Time-of-flight position sensor, m (reading = gain * true + bias + noise, mm resolution).
  protocol::SensorNoiseConfig tof{1.0, 0.004, 0.002, 0.001, 0.0, 2.0};
  /// Links (appendix A3.1): USB serial for the track and the truck, ZigBee for the carriage.
  protocol::LinkConfig track_link = protocol::LinkConfig::usbSerial();
  protocol::LinkConfig car_link = protocol::LinkConfig::zigbee();
  protocol::LinkConfig truck_link = protocol::LinkConfig::usbSerial();
  /// Camera frame clock offset against the boards' frame clocks (unsynchronised), s.
  double camera_phase_s = 0.011;
  /// Carriage start position before init (homing runs from here to the far sensor), m.
  double carriage_power_on_m = 0.02;
  /// Geometry of the ServoTrack rig (shared with evaluation).
  depth_track::TrackGeometry track_geometry;
  TruckModelConfig truck;
  bool scripted_host = true;  ///< see the file comment
  bool autopilot = true;      ///< external-host mode: run the scenario's mode 1 motion itself

  /// Every problem at once (empty = valid), each naming its field.
  std::vector<std::string> validate() const;
};

/// Exact state of the rig at one instant.
struct RigTruth {
  double t_s = 0.0;                                         ///< simulation time, s
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();  ///< camera optical frame in W
  Eigen::Isometry3d T_W_B = Eigen::Isometry3d::Identity();  ///< base_link (carriage / truck) in W
  double track_pos_m = 0.0;    ///< carriage position along the track (0 = far sensor), m
  double motor_pos_m = 0.0;    ///< belt drive (stepper) position, m
  double pitch_deg = 0.0;      ///< true gimbal pitch, positive nose up, deg
  double yaw_deg = 0.0;        ///< true gimbal yaw, positive left, deg
  double pitch_dem_deg = 0.0;  ///< demand the servo is following, deg
  double yaw_dem_deg = 0.0;
  Eigen::Vector3d accel_C_g = Eigen::Vector3d::Zero();  ///< specific force in camera axes, g
  TruckState truck;
};

/// A camera exposure: frame index and the truth at its instant.
struct SimCameraFrame {
  int index = 0;
  RigTruth truth;
};

/// Bytes of one complete frame on a link, at the time they arrived at the other end.
struct SimLinkFrame {
  double t_s = 0.0;       ///< arrival time at the other end, s
  double sent_t_s = 0.0;  ///< time the sender wrote it (a board samples in that loop), s
  protocol::BoardId board = protocol::BoardId::kHost;  ///< board of the link
  bool outgoing = false;                               ///< true = host -> board
  std::vector<uint8_t> bytes;
};

class RigSimulator {
 public:
  /// Throws std::invalid_argument naming every problem of the config or the scenario.
  RigSimulator(const Scenario& scenario, const RigSimConfig& config = RigSimConfig{});
  ~RigSimulator();
  RigSimulator(const RigSimulator&) = delete;
  RigSimulator& operator=(const RigSimulator&) = delete;

  /// Boards of this rig (track + car for ServoTrack, truck for ServoTruck).
  std::vector<protocol::BoardId> boards() const;
  /// Bytes written by an external host to a board; they reach the board after the link delay.
  void hostSend(protocol::BoardId board, const uint8_t* data, std::size_t n);
  /// Advances the simulation by whole physics steps up to time t_s (s). Not thread-safe.
  void advanceTo(double t_s);
  /// Runs until the scenario is finished or t_max_s; returns true if finished.
  bool runToEnd(double t_max_s);
  double now() const;
  /// Board -> host bytes that have arrived at the host by now (external-host mode: what the
  /// pty should carry). Removes them from the simulator.
  std::vector<SimLinkFrame> takeHostBytes();
  /// Every frame on every link (both directions, scripted host included) since the last call,
  /// in arrival order: for raw frame recording.
  std::vector<SimLinkFrame> takeLinkLog();
  /// Camera exposures since the last call (30 Hz in mode 1 and for the truck; one per step in
  /// mode 2).
  std::vector<SimCameraFrame> takeCameraFrames();
  /// Exact state now.
  RigTruth truth() const;
  /// True when the scenario's last frame has been taken (scripted host / autopilot), or it failed.
  bool finished() const;
  /// True when a board refused or aborted one of the scripted host's commands (see takeEvents).
  bool failed() const;
  /// Camera frames taken so far.
  int framesTaken() const;
  const Scenario& scenario() const { return scenario_; }
  const RigSimConfig& config() const { return config_; }
  /// Problems seen so far (rejected acks, end-of-track stops...), for the log.
  std::vector<std::string> takeEvents();

  struct Impl;

 private:
  Scenario scenario_;
  RigSimConfig config_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace rig_drivers
