#pragma once
// TrackDRV: firmware logic of the ServoTrack track electronics (Arduino Mega + stepper driver).
// Thesis 4.2.2 and appendix B2: stepper with trapezoidal velocity profiles, 0.0186 mm per step with
// the 20-tooth pulley (table B3), homing to the far proximity sensor on init, end-of-track
// protection, emergency stop, and the 30 Hz frame clock of the whole rig.
//
// Track axis: position 0 is the far proximity sensor (the homing reference); positive positions go
// towards the near end. The hardware adapter turns step(+1/-1) into a direction pin + step pulse.

#include <stdint.h>

#include "rig_drivers/firmware/firmware.hpp"

namespace rig_drivers {
namespace protocol {

/// Drive pulleys of table B3 (teeth -> mm per step as measured).
enum class Pulley : uint8_t { kTeeth20 = 20, kTeeth30 = 30, kTeeth36 = 36, kTeeth48 = 48 };
/// Distance per step of a table B3 pulley (m/step); 0 for an unknown pulley.
double pulleyMetresPerStep(int teeth);

struct TrackDrvConfig {
  int pulley_teeth = 20;          ///< table B3 pulley; sets m_per_step unless m_per_step > 0
  double m_per_step = 0.0;        ///< override of the table value (m/step, 0 = from the pulley)
  double track_length_m = 1.2;    ///< far sensor to near sensor (m)
  double max_speed_mps = 0.2;     ///< default profile speed (m/s), RT1 set speed 200 mm/s
  double accel_mps2 = 0.4;        ///< default profile acceleration (m/s^2)
  double speed_limit_mps = 0.3;   ///< hard limit for requested speeds (m/s)
  double accel_limit_mps2 = 2.0;  ///< hard limit for requested accelerations (m/s^2)
  double home_speed_mps = 0.02;   ///< slow homing speed towards the far sensor (m/s)
  double home_accel_mps2 = 0.2;   ///< homing ramp and sensor-stop deceleration bound (m/s^2)
  double home_search_m = 1.5;     ///< give up homing after this travel (m) -> fault
  double soft_margin_m = 0.0;     ///< targets must lie in [margin, length - margin] (m)

  /// Metres per step in effect.
  double metresPerStep() const {
    return m_per_step > 0 ? m_per_step : pulleyMetresPerStep(pulley_teeth);
  }
  /// What problems() reports, one bit each.
  enum Problem : uint32_t {
    kBadMPerStep = 1ul << 0,       ///< m_per_step < 0 or not finite
    kUnknownPulley = 1ul << 1,     ///< m_per_step == 0 and pulley_teeth not in table B3
    kTrackLength = 1ul << 2,       ///< track_length_m not > 0
    kMaxSpeed = 1ul << 3,          ///< max_speed_mps not > 0
    kAccel = 1ul << 4,             ///< accel_mps2 not > 0
    kSpeedLimit = 1ul << 5,        ///< speed_limit_mps not > 0
    kAccelLimit = 1ul << 6,        ///< accel_limit_mps2 not > 0
    kHomeSpeed = 1ul << 7,         ///< home_speed_mps not > 0
    kHomeAccel = 1ul << 8,         ///< home_accel_mps2 not > 0
    kHomeSearch = 1ul << 9,        ///< home_search_m not > 0
    kSpeedOverLimit = 1ul << 10,   ///< max_speed_mps > speed_limit_mps
    kAccelOverLimit = 1ul << 11,   ///< accel_mps2 > accel_limit_mps2
    kHomeOverLimit = 1ul << 12,    ///< home_speed_mps > speed_limit_mps
    kSoftMargin = 1ul << 13,       ///< soft_margin_m not in [0, track_length_m / 2)
    kHomeSearchShort = 1ul << 14,  ///< home_search_m < track_length_m
  };
  /// Every problem at once as Problem bits, 0 when valid. Runs on the board.
  uint32_t problems() const;
#if RIG_DRIVERS_HOST
  /// Every problem at once as text, "" when valid (host only, config_text.cpp).
  std::string validate() const;
#endif
};

/// Hardware of the track electronics module.
class TrackHardware : public SerialOut {
 public:
  /// One step pulse; dir = +1 towards the near end, -1 towards the far sensor.
  virtual void step(int dir) = 0;
  virtual bool farSensor() = 0;     ///< far end-of-track proximity sensor active
  virtual bool nearSensor() = 0;    ///< near end-of-track proximity sensor active
  virtual bool estopPressed() = 0;  ///< emergency stop button on the electronics module
  virtual void enableMotor(bool on) { (void)on; }
};

/// Trapezoidal (or triangular, for short moves) velocity profile from rest to rest, in steps.
/// Position is analytic in time, so a stepper emits floor(position(t)) steps whatever its loop
/// rate.
class TrapezoidProfile {
 public:
  /// Plans start -> target (steps) with speed vmax (steps/s) and acceleration amax (steps/s^2).
  void plan(int32_t start, int32_t target, double vmax, double amax);
  /// Plans a stop from speed v0 (steps/s, signed) at position p0 (steps, fractional) with amax.
  void planStop(double p0, double v0, double amax);
  /// Position (steps, fractional) at time t (s) since the start of the profile.
  double position(double t) const;
  /// Velocity (steps/s, signed) at time t.
  double velocity(double t) const;
  double duration() const { return t_total_; }
  double peakSpeed() const { return v_peak_; }
  /// Final position (steps, fractional for a stop profile).
  double end() const { return p0_ + dir_ * distance_; }

 private:
  double p0_ = 0, v0_ = 0;  // v0_ > 0 only for a stop (deceleration-only) profile
  int dir_ = 1;
  double distance_ = 0, v_peak_ = 0, a_ = 1, t_acc_ = 0, t_cruise_ = 0, t_total_ = 0;
};

class TrackDrv : public FirmwareBoard {
 public:
  /// On the host, throws std::invalid_argument naming every bad field of an invalid config; a
  /// board's adapter checks config.problems() before it constructs the board.
  TrackDrv(const TrackDrvConfig& config, TrackHardware& hw);

  TrackStateCode state() const { return state_; }
  int32_t positionSteps() const { return pos_steps_; }
  double positionM() const { return pos_steps_ * m_per_step_; }
  /// Commanded profile velocity now (m/s).
  double velocityMps() const;
  bool homed() const { return homed_; }
  const TrackDrvConfig& config() const { return config_; }

 protected:
  bool handleCommand(const Frame& f) override;
  void step(uint64_t now_us) override;
  void sendStream() override;
  int paramCount() const override;
  ParamValue param(int index) const override;
  bool modeChangeAllowed() const override;

 private:
  enum class Motion : uint8_t { kIdle, kHoming, kProfile };
  void startProfile(int32_t target_steps, double vmax_sps, double amax_sps2);
  void startStop();
  void emitStepsTo(double target_pos);
  void finishMove(AckStatus status);
  void hardStop(TrackStateCode new_state, AckStatus status);
  bool moving() const { return motion_ != Motion::kIdle; }

  TrackDrvConfig config_;
  TrackHardware& hw_;
  double m_per_step_;
  int32_t track_steps_;
  TrackStateCode state_ = TrackStateCode::kUninitialised;
  bool homed_ = false;
  int32_t pos_steps_ = 0;  ///< steps emitted, relative to the far sensor once homed
  double cmd_pos_m_ = 0;   ///< last commanded target (m), base of relative moves
  Motion motion_ = Motion::kIdle;
  TrapezoidProfile profile_;
  uint64_t profile_t0_us_ = 0;
  int32_t profile_origin_ = 0;  ///< pos_steps_ at profile start (profile positions are absolute)
  double home_travel_steps_ = 0;
  bool stopping_ = false;  ///< a controlled stop profile is running
  bool move_pending_ = false;
  uint32_t move_seq_ = 0;
  MsgId move_id_ = MsgId::kTrackMove;
  bool stop_pending_ = false;
  uint32_t stop_seq_ = 0;
  MsgId stop_id_ = MsgId::kStop;
  uint64_t now_us_ = 0;
};

}  // namespace protocol
}  // namespace rig_drivers
