// Host part of the board configs: the text of every problem that problems() reports. The checks
// themselves run on the boards too (track_drv.cpp, car_drv.cpp, truck_drv.cpp); this file only
// words their bits, with the offending values, for exceptions and log lines. Not built for the
// boards.
#include <sstream>
#include <string>

#include "rig_drivers/firmware/car_drv.hpp"
#include "rig_drivers/firmware/track_drv.hpp"
#include "rig_drivers/firmware/truck_drv.hpp"

namespace rig_drivers {
namespace protocol {

namespace {

/// Joins "problem; problem" (no trailing separator).
std::string joined(const std::ostringstream& e) {
  std::string s = e.str();
  if (s.size() >= 2) s.resize(s.size() - 2);
  return s;
}

}  // namespace

std::string TrackDrvConfig::validate() const {
  const uint32_t p = problems();
  std::ostringstream e;
  if (p & kBadMPerStep)
    e << "m_per_step must be >= 0 (0 = from pulley_teeth), got " << m_per_step << "; ";
  if (p & kUnknownPulley)
    e << "pulley_teeth must be one of table B3 (20, 30, 36, 48), got " << pulley_teeth << "; ";
  const struct {
    Problem bit;
    const char* name;
    double value;
  } positives[] = {
      {kTrackLength, "track_length_m", track_length_m},
      {kMaxSpeed, "max_speed_mps", max_speed_mps},
      {kAccel, "accel_mps2", accel_mps2},
      {kSpeedLimit, "speed_limit_mps", speed_limit_mps},
      {kAccelLimit, "accel_limit_mps2", accel_limit_mps2},
      {kHomeSpeed, "home_speed_mps", home_speed_mps},
      {kHomeAccel, "home_accel_mps2", home_accel_mps2},
      {kHomeSearch, "home_search_m", home_search_m},
  };
  for (const auto& f : positives)
    if (p & f.bit) e << f.name << " must be > 0, got " << f.value << "; ";
  if (p & kSpeedOverLimit)
    e << "max_speed_mps (" << max_speed_mps << ") exceeds speed_limit_mps (" << speed_limit_mps
      << "); ";
  if (p & kAccelOverLimit)
    e << "accel_mps2 (" << accel_mps2 << ") exceeds accel_limit_mps2 (" << accel_limit_mps2
      << "); ";
  if (p & kHomeOverLimit) e << "home_speed_mps exceeds speed_limit_mps; ";
  if (p & kSoftMargin)
    e << "soft_margin_m must be in [0, track_length_m / 2), got " << soft_margin_m << "; ";
  if (p & kHomeSearchShort)
    e << "home_search_m (" << home_search_m << ") must be >= track_length_m (" << track_length_m
      << ") so homing can reach the far sensor from anywhere; ";
  return joined(e);
}

std::string CarDrvConfig::validate() const {
  const uint32_t p = problems();
  std::ostringstream e;
  auto axis = [&](const char* name, const AxisCalibration& a, uint32_t bits) {
    if (bits & kPulseCurve) e << name << ".pulse_us_of_deg needs >= 2 monotonic points; ";
    if (bits & kVoltsCurve) e << name << ".deg_of_volts needs >= 2 monotonic points; ";
    if (bits & kLimitsOrder) e << name << ": min_deg must be < max_deg; ";
    if (bits & kLimitsBeyondCurve)
      e << name << ": demand limits [" << a.min_deg << ", " << a.max_deg
        << "] deg exceed the calibrated range [" << a.pulse_us_of_deg.xMin() << ", "
        << a.pulse_us_of_deg.xMax() << "] deg; ";
    if (bits & kPulseRange)
      for (int i = 0; i < a.pulse_us_of_deg.size(); ++i)
        if (!pulseInServoRange(a.pulse_us_of_deg.y(i)))
          e << name << ": calibration pulse " << a.pulse_us_of_deg.y(i)
            << " us outside the servo range 500..2500 us; ";
    if (bits & kVoltsRange) e << name << ".deg_of_volts volts must lie within 0..adc_vref; ";
  };
  const uint32_t axis_mask = (1u << kYawShift) - 1;
  axis("pitch", pitch, p & axis_mask);
  axis("yaw", yaw, (p >> kYawShift) & axis_mask);
  if (p & kAdcVref) e << "adc_vref must be > 0, got " << adc_vref << "; ";
  if (p & kAdcBits) e << "adc_bits must be in [8, 16], got " << adc_bits << "; ";
  if (p & kAdcSamples) e << "adc_samples must be in [1, 64], got " << adc_samples << "; ";
  if (p & kImuScale) e << "imu_lsb_per_g must be > 0; ";
  if (p & kTofSign) e << "tof_sign must be +1 or -1, got " << tof_sign << "; ";
  if (p & kTofOffset) e << "tof_offset_m must be finite; ";
  if (p & kServoRate) e << "servo_rate_deg_s must be > 0; ";
  if (p & kSettle) e << "settle_s must be >= 0; ";
  return joined(e);
}

std::string TruckDrvConfig::validate() const {
  const uint32_t p = problems();
  std::ostringstream e;
  if (p & kHalfRange) e << "half_range_us must be > 0, got " << half_range_us << "; ";
  if (p & kDeadband) e << "deadband_us must be in [0, half_range_us), got " << deadband_us << "; ";
  if (p & kValidRange) e << "need min_valid_us < center_us < max_valid_us; ";
  if (p & kSwitchOn) e << "switch_on_us must lie between min_valid_us and max_valid_us; ";
  if (p & kSpeedCurve) e << "speed_curve needs >= 2 points with increasing signal and speed; ";
  if (p & kSpeedCurveSignal) e << "speed_curve signal values must lie in [0, 1]; ";
  if (p & kSpeedCurveNegative) e << "speed_curve speeds must be >= 0; ";
  return joined(e);
}

}  // namespace protocol
}  // namespace rig_drivers
