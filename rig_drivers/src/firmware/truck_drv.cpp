#include "rig_drivers/firmware/truck_drv.hpp"

#include <math.h>

namespace rig_drivers {
namespace protocol {

TruckDrvConfig TruckDrvConfig::defaults() {
  TruckDrvConfig c;
  const double signal[] = {0.08, 0.2, 0.4, 0.6, 0.8, 1.0};
  const double speed[] = {0.0, 0.3, 0.75, 1.15, 1.5, 1.8};
  c.speed_curve.set(signal, speed, 6, true);
  return c;
}

uint32_t TruckDrvConfig::problems() const {
  uint32_t p = 0;
  if (!(half_range_us > 0)) p |= kHalfRange;
  if (!(deadband_us >= 0 && deadband_us < half_range_us)) p |= kDeadband;
  if (!(min_valid_us < center_us && center_us < max_valid_us)) p |= kValidRange;
  if (!(switch_on_us > min_valid_us && switch_on_us < max_valid_us)) p |= kSwitchOn;
  if (!speed_curve.valid()) {
    p |= kSpeedCurve;
  } else {
    if (speed_curve.xMin() < 0 || speed_curve.xMax() > 1.0 + 1e-9) p |= kSpeedCurveSignal;
    if (speed_curve.y(0) < 0) p |= kSpeedCurveNegative;
  }
  return p;
}

TruckDrv::TruckDrv(const TruckDrvConfig& config, TruckHardware& hw)
    : FirmwareBoard(BoardId::kTruck, "TruckDRV", hw),
      config_(requireValid(config, "TruckDrvConfig")),
      hw_(hw) {}

double TruckDrv::normalise(uint16_t pulse_us, bool reversed) const {
  if (!valid(pulse_us)) return 0.0;
  double d = pulse_us - config_.center_us;
  if (fabs(d) <= config_.deadband_us) return 0.0;
  // Rescale so the output is continuous at the deadband edge and reaches 1 at full deflection.
  d = (d > 0 ? d - config_.deadband_us : d + config_.deadband_us) /
      (config_.half_range_us - config_.deadband_us);
  if (d > 1) d = 1;
  if (d < -1) d = -1;
  return reversed ? -d : d;
}

double TruckDrv::speedMps(double signal) const {
  const double m = fabs(signal);
  if (m < config_.speed_curve.xMin()) return 0.0;
  const double v = config_.speed_curve(m);
  return signal < 0 ? -v : v;
}

void TruckDrv::step(uint64_t now_us) {
  (void)now_us;
  for (int i = 0; i < 4; ++i) pulse_[i] = hw_.pulseUs(static_cast<RcChannel>(i));
  signal_ok_ = valid(pulse_[0]) && valid(pulse_[1]) && valid(pulse_[2]) && valid(pulse_[3]);
  steering_ = normalise(pulse_[0], config_.steering_reversed);
  speed_ = normalise(pulse_[1], config_.speed_reversed);
  // Failsafe: a lost receiver stops the truck and keeps the last switch positions off.
  running_ = signal_ok_ && pulse_[2] > config_.switch_on_us;
  recording_ = signal_ok_ && pulse_[3] > config_.switch_on_us;
  motor_ = (running_ && !host_stop_) ? speed_ : 0.0;
  hw_.setMotor(motor_);
  hw_.setSteering(signal_ok_ ? steering_ : 0.0);
}

bool TruckDrv::handleCommand(const Frame& f) {
  switch (f.id) {
    case MsgId::kInit:
    case MsgId::kStart:
      host_stop_ = false;
      sendAck(f.seq, f.id, AckStatus::kDone);
      return true;
    case MsgId::kStop:
    case MsgId::kEnd:
    case MsgId::kReset:
      host_stop_ = f.id != MsgId::kReset;
      if (host_stop_) {
        motor_ = 0;
        hw_.setMotor(0);
      }
      sendAck(f.seq, f.id, AckStatus::kDone);
      return true;
    default:
      return false;
  }
}

void TruckDrv::sendStream() {
  TruckRcPayload s;
  s.board_time_ms = nowMs();
  s.ch2_us = pulse_[0];
  s.ch3_us = pulse_[1];
  s.ch5_us = pulse_[2];
  s.ch7_us = pulse_[3];
  s.steering_permille = static_cast<int16_t>(lround(steering_ * 1000));
  s.speed_permille = static_cast<int16_t>(lround(speed_ * 1000));
  s.speed_mm_s = static_cast<int16_t>(lround(speedMps(motor_) * 1000));
  s.flags = (running_ ? TruckRcPayload::kRunning : 0) |
            (recording_ ? TruckRcPayload::kRecording : 0) |
            (signal_ok_ ? TruckRcPayload::kSignalOk : 0);
  send(s);
}

int TruckDrv::paramCount() const { return 4 + config_.speed_curve.size(); }

ParamValue TruckDrv::param(int i) const {
  const int n = paramCount();
  switch (i) {
    case 0:
      return makeParam(i, n, "center_us", config_.center_us, 1);
    case 1:
      return makeParam(i, n, "half_range_us", config_.half_range_us, 1);
    case 2:
      return makeParam(i, n, "deadband_us", config_.deadband_us, 1);
    case 3:
      return makeParam(i, n, "switch_on_us", config_.switch_on_us, 1);
    default: {
      // speed curve points: name carries the signal, value the speed
      const int k = i - 4;
      char name[kNameLen + 1] = "speed_mps_at_";
      const int permille = static_cast<int>(lround(config_.speed_curve.x(k) * 1000));
      name[13] = static_cast<char>('0' + (permille / 1000) % 10);
      name[14] = static_cast<char>('0' + (permille / 100) % 10);
      name[15] = static_cast<char>('0' + (permille / 10) % 10);
      name[16] = '\0';
      return makeParam(i, n, name, config_.speed_curve.y(k), 3);
    }
  }
}

}  // namespace protocol
}  // namespace rig_drivers
