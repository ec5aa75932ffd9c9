#include "rig_drivers/firmware/car_drv.hpp"

#include <math.h>

namespace rig_drivers {
namespace protocol {

CarDrvConfig CarDrvConfig::defaults() {
  CarDrvConfig c;
  // Servo: ~10.5 us/deg around 1500 us with a slight stiffening towards the ends; the yaw servo
  // turns the other way. Sensor: potentiometer ~0.044 V/deg around mid-rail, slightly nonlinear.
  const double deg[] = {-40, -20, 0, 20, 40};
  const double pitch_us[] = {1078, 1292, 1500, 1712, 1930};
  const double yaw_us[] = {1925, 1710, 1500, 1291, 1074};
  const double volts[] = {0.70, 1.62, 2.50, 3.36, 4.30};
  const double pitch_deg[] = {-41.0, -20.3, 0.0, 19.6, 40.5};
  const double yaw_deg[] = {40.2, 19.9, 0.0, -20.4, -41.3};
  c.pitch.pulse_us_of_deg.set(deg, pitch_us, 5);
  c.yaw.pulse_us_of_deg.set(deg, yaw_us, 5);
  c.pitch.deg_of_volts.set(volts, pitch_deg, 5);
  c.yaw.deg_of_volts.set(volts, yaw_deg, 5);
  return c;
}

namespace {
uint32_t axisProblems(const AxisCalibration& a, double adc_vref) {
  uint32_t p = 0;
  if (!a.pulse_us_of_deg.valid()) p |= CarDrvConfig::kPulseCurve;
  if (!a.deg_of_volts.valid()) p |= CarDrvConfig::kVoltsCurve;
  if (!(a.min_deg < a.max_deg)) p |= CarDrvConfig::kLimitsOrder;
  if (a.pulse_us_of_deg.valid()) {
    // Demands are never extrapolated beyond the calibrated range.
    if (a.min_deg < a.pulse_us_of_deg.xMin() || a.max_deg > a.pulse_us_of_deg.xMax())
      p |= CarDrvConfig::kLimitsBeyondCurve;
    for (int i = 0; i < a.pulse_us_of_deg.size(); ++i)
      if (!CarDrvConfig::pulseInServoRange(a.pulse_us_of_deg.y(i))) p |= CarDrvConfig::kPulseRange;
  }
  if (a.deg_of_volts.valid() && (a.deg_of_volts.xMin() < 0 || a.deg_of_volts.xMax() > adc_vref))
    p |= CarDrvConfig::kVoltsRange;
  return p;
}
}  // namespace

uint32_t CarDrvConfig::problems() const {
  uint32_t p = axisProblems(pitch, adc_vref) | (axisProblems(yaw, adc_vref) << kYawShift);
  if (!(adc_vref > 0)) p |= kAdcVref;
  if (adc_bits < 8 || adc_bits > 16) p |= kAdcBits;
  if (adc_samples < 1 || adc_samples > 64) p |= kAdcSamples;
  if (!(imu_lsb_per_g > 0)) p |= kImuScale;
  if (tof_sign != 1 && tof_sign != -1) p |= kTofSign;
  if (!isfinite(tof_offset_m)) p |= kTofOffset;
  if (!(servo_rate_deg_s > 0)) p |= kServoRate;
  if (!(settle_s >= 0)) p |= kSettle;
  return p;
}

namespace {
int16_t clampI16(double v) {
  if (v > 32767) return 32767;
  if (v < -32768) return -32768;
  return static_cast<int16_t>(lround(v));
}
}  // namespace

CarDrv::CarDrv(const CarDrvConfig& config, CarHardware& hw)
    : FirmwareBoard(BoardId::kCar, "CarDRV", hw),
      config_(requireValid(config, "CarDrvConfig")),
      hw_(hw) {}

double CarDrv::demand(double pitch_deg, double yaw_deg) {
  const double slew = fmax(fabs(pitch_deg - dem_deg_[0]), fabs(yaw_deg - dem_deg_[1]));
  dem_deg_[0] = pitch_deg;
  dem_deg_[1] = yaw_deg;
  hw_.setServoPulse(GimbalAxis::kPitch, config_.pitch.pulse_us_of_deg(pitch_deg));
  hw_.setServoPulse(GimbalAxis::kYaw, config_.yaw.pulse_us_of_deg(yaw_deg));
  return slew / config_.servo_rate_deg_s + config_.settle_s;
}

double CarDrv::readAngle(GimbalAxis axis) {
  long sum = 0;
  for (int i = 0; i < config_.adc_samples; ++i) sum += hw_.readAdc(axis);
  const double counts = static_cast<double>(sum) / config_.adc_samples;
  // counts c cover [c, c+1) LSB: the middle of the interval is the unbiased voltage
  const double volts = (counts + 0.5) * config_.adc_vref / (1 << config_.adc_bits);
  const AxisCalibration& cal = axis == GimbalAxis::kPitch ? config_.pitch : config_.yaw;
  return cal.deg_of_volts(volts);
}

void CarDrv::step(uint64_t now_us) {
  now_us_ = now_us;
  if (move_pending_ && now_us >= move_done_us_) {
    move_pending_ = false;
    sendAck(move_seq_, move_id_, AckStatus::kDone);
  }
}

bool CarDrv::handleCommand(const Frame& f) {
  auto startMove = [&](double seconds) {
    if (move_pending_) sendAck(move_seq_, move_id_, AckStatus::kAborted);
    sendAck(f.seq, f.id, AckStatus::kAccepted);
    move_pending_ = true;
    move_seq_ = f.seq;
    move_id_ = f.id;
    move_done_us_ = now_us_ + static_cast<uint64_t>(seconds * 1e6 + 0.5);  // seconds >= 0
  };
  switch (f.id) {
    case MsgId::kServo: {
      CmdServo s;
      if (decodePayload(f, s) != DecodeError::kNone) {
        sendAck(f.seq, f.id, AckStatus::kBadArgument);
        return true;
      }
      // Mode 2 (step sequence): one move at a time, the host waits for its "done". Mode 1
      // (continuous): demands stream at the frame rate, the newest replaces a move still settling
      // (startMove acks the superseded one "aborted").
      if (move_pending_ && mode_ != 1) {
        sendAck(f.seq, f.id, AckStatus::kBusy);
        return true;
      }
      double p = s.pitch_cdeg * 0.01, y = s.yaw_cdeg * 0.01;
      if (s.flags & CmdServo::kRelative) {
        p += dem_deg_[0];
        y += dem_deg_[1];
      }
      if (p < config_.pitch.min_deg || p > config_.pitch.max_deg || y < config_.yaw.min_deg ||
          y > config_.yaw.max_deg) {
        sendAck(f.seq, f.id, AckStatus::kBadArgument);
        return true;
      }
      startMove(demand(p, y));
      return true;
    }
    case MsgId::kInit:
      startMove(demand(0.0, 0.0));  // centre the gimbal
      return true;
    case MsgId::kReset:
      if (move_pending_) {
        move_pending_ = false;
        sendAck(move_seq_, move_id_, AckStatus::kAborted);
      }
      demand(0.0, 0.0);
      sendAck(f.seq, f.id, AckStatus::kDone);
      return true;
    case MsgId::kStop:
    case MsgId::kEnd:
      // Open-loop servos cannot be stopped mid-slew; the host gets the pending move aborted.
      if (move_pending_) {
        move_pending_ = false;
        sendAck(move_seq_, move_id_, AckStatus::kAborted);
      }
      sendAck(f.seq, f.id, AckStatus::kDone);
      return true;
    case MsgId::kStart:
      sendAck(f.seq, f.id, AckStatus::kDone);
      return true;
    default:
      return false;
  }
}

void CarDrv::sendStream() {
  meas_deg_[0] = readAngle(GimbalAxis::kPitch);
  meas_deg_[1] = readAngle(GimbalAxis::kYaw);
  CarSensorsPayload s;
  s.board_time_ms = nowMs();
  s.pitch_dem_cdeg = clampI16(dem_deg_[0] * 100);
  s.pitch_cdeg = clampI16(meas_deg_[0] * 100);
  s.yaw_dem_cdeg = clampI16(dem_deg_[1] * 100);
  s.yaw_cdeg = clampI16(meas_deg_[1] * 100);
  int16_t raw[3] = {0, 0, 0};
  if (hw_.readImu(raw)) {
    s.acc_x_mg = clampI16(raw[0] * 1000.0 / config_.imu_lsb_per_g);
    s.acc_y_mg = clampI16(raw[1] * 1000.0 / config_.imu_lsb_per_g);
    s.acc_z_mg = clampI16(raw[2] * 1000.0 / config_.imu_lsb_per_g);
  }
  uint16_t range = 0;
  if (hw_.readTof(range)) {
    const double pos_mm =
        config_.tof_offset_m * 1e3 + config_.tof_sign * static_cast<double>(range);
    if (pos_mm >= 0 && pos_mm <= 65535) {
      s.tof_mm = static_cast<uint16_t>(lround(pos_mm));
      s.flags |= CarSensorsPayload::kTofValid;
    }
  }
  send(s);
}

int CarDrv::paramCount() const { return 8; }

ParamValue CarDrv::param(int i) const {
  const int n = paramCount();
  switch (i) {
    case 0:
      return makeParam(i, n, "pitch_min_deg", config_.pitch.min_deg, 2);
    case 1:
      return makeParam(i, n, "pitch_max_deg", config_.pitch.max_deg, 2);
    case 2:
      return makeParam(i, n, "yaw_min_deg", config_.yaw.min_deg, 2);
    case 3:
      return makeParam(i, n, "yaw_max_deg", config_.yaw.max_deg, 2);
    case 4:
      return makeParam(i, n, "adc_samples", config_.adc_samples, 0);
    case 5:
      return makeParam(i, n, "imu_lsb_per_g", config_.imu_lsb_per_g, 0);
    case 6:
      return makeParam(i, n, "tof_offset_mm", config_.tof_offset_m * 1e3, 1);
    default:
      return makeParam(i, n, "settle_ms", config_.settle_s * 1e3, 0);
  }
}

}  // namespace protocol
}  // namespace rig_drivers
