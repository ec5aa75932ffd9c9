#pragma once
// CarDRV: firmware logic of the ServoTrack carriage Arduino (thesis 4.2.2, appendix B1).
// Gimbal pitch/yaw demands in degrees go through the servo calibration (deg -> Pololu pulse us,
// figs. B2/B3) open loop (no sensor feedback, as on the rig); the pitch/yaw potentiometer volts go
// through the sensor calibration (volts -> deg); the MPU6050 gives accelerations in g and the
// time-of-flight sensor the carriage position TFPos. Streams CarSensors at 30 Hz.

#include <stdint.h>

#include "rig_drivers/firmware/firmware.hpp"

namespace rig_drivers {
namespace protocol {

/// Calibration of one gimbal axis.
struct AxisCalibration {
  PiecewiseLinear pulse_us_of_deg;  ///< servo: demand (deg) -> pulse width (us)
  PiecewiseLinear deg_of_volts;     ///< sensor: potentiometer volts (V) -> angle (deg)
  double min_deg = -40.0;           ///< demand limits (deg)
  double max_deg = 40.0;
};

struct CarDrvConfig {
  AxisCalibration pitch;
  AxisCalibration yaw;
  double adc_vref = 5.0;           ///< ADC reference (V)
  int adc_bits = 10;               ///< Arduino Mega ADC
  int adc_samples = 4;             ///< readings averaged per axis per frame (1)
  double imu_lsb_per_g = 16384;    ///< MPU6050 at +-2 g full scale (LSB/g)
  double tof_offset_m = 0.0;       ///< TFPos = tof_offset_m + tof_sign * range (m)
  int tof_sign = 1;                ///< +1 or -1
  double servo_rate_deg_s = 60.0;  ///< assumed slew rate to time a mode 2 move (deg/s)
  double settle_s = 0.3;           ///< extra wait after the slew before a move is acknowledged (s)

  /// Defaults: curves shaped like thesis figs. B2/B3 (the text does not give their numbers;
  /// load the rig's own calibration from config/ for real hardware).
  static CarDrvConfig defaults();

  /// What problems() reports, one bit each. The per-axis bits are the pitch axis's; the yaw
  /// axis's are the same bits shifted left by kYawShift.
  enum Problem : uint32_t {
    kPulseCurve = 1ul << 0,         ///< pulse_us_of_deg has fewer than 2 monotonic points
    kVoltsCurve = 1ul << 1,         ///< deg_of_volts has fewer than 2 monotonic points
    kLimitsOrder = 1ul << 2,        ///< min_deg not < max_deg
    kLimitsBeyondCurve = 1ul << 3,  ///< demand limits outside the calibrated range
    kPulseRange = 1ul << 4,         ///< a calibration pulse outside the servo range
    kVoltsRange = 1ul << 5,         ///< a calibration voltage outside 0 .. adc_vref
    kAdcVref = 1ul << 12,           ///< adc_vref not > 0
    kAdcBits = 1ul << 13,           ///< adc_bits not in [8, 16]
    kAdcSamples = 1ul << 14,        ///< adc_samples not in [1, 64]
    kImuScale = 1ul << 15,          ///< imu_lsb_per_g not > 0
    kTofSign = 1ul << 16,           ///< tof_sign not +1 or -1
    kTofOffset = 1ul << 17,         ///< tof_offset_m not finite
    kServoRate = 1ul << 18,         ///< servo_rate_deg_s not > 0
    kSettle = 1ul << 19,            ///< settle_s not >= 0
  };
  static constexpr int kYawShift = 6;
  /// Pulse widths a hobby servo accepts (us).
  static bool pulseInServoRange(double us) { return us >= 500 && us <= 2500; }
  /// Every problem at once as Problem bits, 0 when valid. Runs on the board.
  uint32_t problems() const;
#if RIG_DRIVERS_HOST
  /// Every problem at once as text, "" when valid (host only, config_text.cpp).
  std::string validate() const;
#endif
};

enum class GimbalAxis : int { kPitch = 0, kYaw = 1 };

/// Hardware of the carriage electronics.
class CarHardware : public SerialOut {
 public:
  /// Pololu Maestro target pulse width for an axis (us).
  virtual void setServoPulse(GimbalAxis axis, double pulse_us) = 0;
  /// Raw ADC counts of an axis's position sensor (0 .. 2^bits - 1).
  virtual int readAdc(GimbalAxis axis) = 0;
  /// MPU6050 raw accelerations in camera axes (x lateral, y vertical, z longitudinal); false if
  /// the sensor did not answer.
  virtual bool readImu(int16_t raw[3]) = 0;
  /// Time-of-flight range (mm); false when there is no valid return.
  virtual bool readTof(uint16_t& range_mm) = 0;
};

/// Servo demands: in mode 1 (continuous) every demand is accepted and replaces a move still
/// slewing/settling (that one is acked "aborted"); in mode 2 (step sequence) a demand arriving
/// before the previous move's "done" is answered "busy".
class CarDrv : public FirmwareBoard {
 public:
  /// On the host, throws std::invalid_argument naming every bad field of an invalid config.
  CarDrv(const CarDrvConfig& config, CarHardware& hw);

  double pitchDemandDeg() const { return dem_deg_[0]; }
  double yawDemandDeg() const { return dem_deg_[1]; }
  /// Latest calibrated sensor angle (deg), refreshed at every stream frame.
  double pitchDeg() const { return meas_deg_[0]; }
  double yawDeg() const { return meas_deg_[1]; }
  const CarDrvConfig& config() const { return config_; }

 protected:
  bool handleCommand(const Frame& f) override;
  void step(uint64_t now_us) override;
  void sendStream() override;
  int paramCount() const override;
  ParamValue param(int index) const override;

 private:
  /// Sets both demands (deg), returns the time the move needs (s).
  double demand(double pitch_deg, double yaw_deg);
  double readAngle(GimbalAxis axis);

  CarDrvConfig config_;
  CarHardware& hw_;
  double dem_deg_[2] = {0, 0};
  double meas_deg_[2] = {0, 0};
  bool move_pending_ = false;
  uint32_t move_seq_ = 0;
  MsgId move_id_ = MsgId::kServo;
  uint64_t move_done_us_ = 0;
  uint64_t now_us_ = 0;
};

}  // namespace protocol
}  // namespace rig_drivers
