#pragma once
// TruckDRV: firmware logic of the ServoTruck Arduino Leonardo (thesis 4.3): reads the RC receiver
// (CH2 steering, CH3 speed/direction, CH5 start/stop, CH7 depth camera recording), drives the DC
// motor amplifier and steering, and streams the channels at 30 Hz with a forward speed estimate
// from the speed calibration of fig. 5.42 (a configurable curve).

#include <stdint.h>

#include "rig_drivers/firmware/firmware.hpp"

namespace rig_drivers {
namespace protocol {

enum class RcChannel : int { kCh2 = 0, kCh3 = 1, kCh5 = 2, kCh7 = 3 };

struct TruckDrvConfig {
  double center_us = 1500;     ///< stick centre pulse (us)
  double half_range_us = 500;  ///< centre to full deflection (us)
  double deadband_us = 20;     ///< |pulse - centre| below this reads 0 (us)
  double min_valid_us = 800;   ///< pulses outside [min, max] are treated as no signal (us)
  double max_valid_us = 2200;
  double switch_on_us = 1500;  ///< CH5/CH7 switch reads on above this (us)
  bool steering_reversed = false;
  bool speed_reversed = false;
  /// Fig. 5.42: forward speed (m/s) against the non-dimensional |CH3| signal (0..1). Below the
  /// first point the truck does not move (motor stiction). Placeholder shape; the figure's numbers
  /// are not in the text: calibrate on the rig's own 8.5 m runs.
  PiecewiseLinear speed_curve;

  static TruckDrvConfig defaults();

  /// What problems() reports, one bit each.
  enum Problem : uint32_t {
    kHalfRange = 1ul << 0,           ///< half_range_us not > 0
    kDeadband = 1ul << 1,            ///< deadband_us not in [0, half_range_us)
    kValidRange = 1ul << 2,          ///< not min_valid_us < center_us < max_valid_us
    kSwitchOn = 1ul << 3,            ///< switch_on_us not between min_valid_us and max_valid_us
    kSpeedCurve = 1ul << 4,          ///< speed_curve has fewer than 2 increasing points
    kSpeedCurveSignal = 1ul << 5,    ///< speed_curve signal values outside [0, 1]
    kSpeedCurveNegative = 1ul << 6,  ///< speed_curve speeds below 0
  };
  /// Every problem at once as Problem bits, 0 when valid. Runs on the board.
  uint32_t problems() const;
#if RIG_DRIVERS_HOST
  /// Every problem at once as text, "" when valid (host only, config_text.cpp).
  std::string validate() const;
#endif
};

class TruckHardware : public SerialOut {
 public:
  /// Latest pulse width on a receiver channel (us); 0 when no pulse arrived recently.
  virtual uint16_t pulseUs(RcChannel ch) = 0;
  /// Motor amplifier command, -1 (full reverse) .. +1 (full forward).
  virtual void setMotor(double command) = 0;
  /// Steering servo command, -1 (full left) .. +1 (full right).
  virtual void setSteering(double command) = 0;
};

class TruckDrv : public FirmwareBoard {
 public:
  /// On the host, throws std::invalid_argument naming every bad field of an invalid config.
  TruckDrv(const TruckDrvConfig& config, TruckHardware& hw);

  /// Stick position of a proportional channel pulse, -1..1 with the deadband applied.
  double normalise(uint16_t pulse_us, bool reversed) const;
  /// Forward speed (m/s, signed) for a normalised CH3 signal, from the speed curve.
  double speedMps(double signal) const;
  bool running() const { return running_; }
  bool recording() const { return recording_; }
  bool signalOk() const { return signal_ok_; }
  double motorCommand() const { return motor_; }
  const TruckDrvConfig& config() const { return config_; }

 protected:
  bool handleCommand(const Frame& f) override;
  void step(uint64_t now_us) override;
  void sendStream() override;
  int paramCount() const override;
  ParamValue param(int index) const override;

 private:
  bool valid(uint16_t us) const { return us >= config_.min_valid_us && us <= config_.max_valid_us; }

  TruckDrvConfig config_;
  TruckHardware& hw_;
  uint16_t pulse_[4] = {0, 0, 0, 0};
  double steering_ = 0, speed_ = 0, motor_ = 0;
  bool running_ = false, recording_ = false, signal_ok_ = false;
  bool host_stop_ = false;  ///< host stop/end holds the motor off until start
};

}  // namespace protocol
}  // namespace rig_drivers
