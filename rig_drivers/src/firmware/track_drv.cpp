#include "rig_drivers/firmware/track_drv.hpp"

#include <math.h>

namespace rig_drivers {
namespace protocol {

double pulleyMetresPerStep(int teeth) {
  // Table B3, as measured on the rig (mm per step).
  switch (teeth) {
    case 20:
      return 0.0186e-3;
    case 30:
      return 0.0297e-3;
    case 36:
      return 0.03348e-3;
    case 48:
      return 0.04464e-3;
    default:
      return 0.0;
  }
}

uint32_t TrackDrvConfig::problems() const {
  uint32_t p = 0;
  if (m_per_step < 0 || !isfinite(m_per_step)) p |= kBadMPerStep;
  if (m_per_step == 0 && pulleyMetresPerStep(pulley_teeth) == 0) p |= kUnknownPulley;
  auto positive = [&p](double v, Problem bit) {
    if (!(v > 0) || !isfinite(v)) p |= bit;
  };
  positive(track_length_m, kTrackLength);
  positive(max_speed_mps, kMaxSpeed);
  positive(accel_mps2, kAccel);
  positive(speed_limit_mps, kSpeedLimit);
  positive(accel_limit_mps2, kAccelLimit);
  positive(home_speed_mps, kHomeSpeed);
  positive(home_accel_mps2, kHomeAccel);
  positive(home_search_m, kHomeSearch);
  if (max_speed_mps > speed_limit_mps) p |= kSpeedOverLimit;
  if (accel_mps2 > accel_limit_mps2) p |= kAccelOverLimit;
  if (home_speed_mps > speed_limit_mps) p |= kHomeOverLimit;
  if (!(soft_margin_m >= 0) || 2 * soft_margin_m >= track_length_m) p |= kSoftMargin;
  if (home_search_m < track_length_m) p |= kHomeSearchShort;
  return p;
}

// ---- TrapezoidProfile
// ----------------------------------------------------------------------------------

void TrapezoidProfile::plan(int32_t start, int32_t target, double vmax, double amax) {
  p0_ = start;
  v0_ = 0;
  dir_ = target >= start ? 1 : -1;
  distance_ = fabs(static_cast<double>(target) - static_cast<double>(start));
  a_ = amax;
  const double d_acc = vmax * vmax / (2 * amax);
  if (2 * d_acc >= distance_) {  // triangular: never reaches vmax
    v_peak_ = sqrt(amax * distance_);
    t_acc_ = v_peak_ / amax;
    t_cruise_ = 0;
  } else {
    v_peak_ = vmax;
    t_acc_ = vmax / amax;
    t_cruise_ = (distance_ - 2 * d_acc) / vmax;
  }
  t_total_ = 2 * t_acc_ + t_cruise_;
}

void TrapezoidProfile::planStop(double p0, double v0, double amax) {
  p0_ = p0;
  dir_ = v0 >= 0 ? 1 : -1;
  v0_ = fabs(v0);
  a_ = amax;
  v_peak_ = v0_;
  t_acc_ = 0;
  t_cruise_ = 0;
  t_total_ = v0_ / amax;
  distance_ = v0_ * v0_ / (2 * amax);
}

double TrapezoidProfile::position(double t) const {
  if (t <= 0) return p0_;
  if (t >= t_total_) return p0_ + dir_ * distance_;
  double s;
  if (v0_ > 0) {
    s = v0_ * t - 0.5 * a_ * t * t;
  } else if (t < t_acc_) {
    s = 0.5 * a_ * t * t;
  } else if (t < t_acc_ + t_cruise_) {
    s = 0.5 * a_ * t_acc_ * t_acc_ + v_peak_ * (t - t_acc_);
  } else {
    const double r = t_total_ - t;
    s = distance_ - 0.5 * a_ * r * r;
  }
  return p0_ + dir_ * s;
}

double TrapezoidProfile::velocity(double t) const {
  if (t <= 0 && v0_ == 0) return 0;
  if (t >= t_total_) return 0;
  double v;
  if (v0_ > 0) {
    v = v0_ - a_ * (t > 0 ? t : 0);
  } else if (t < t_acc_) {
    v = a_ * t;
  } else if (t < t_acc_ + t_cruise_) {
    v = v_peak_;
  } else {
    v = a_ * (t_total_ - t);
  }
  return dir_ * v;
}

// ---- TrackDrv
// ------------------------------------------------------------------------------------------

TrackDrv::TrackDrv(const TrackDrvConfig& config, TrackHardware& hw)
    : FirmwareBoard(BoardId::kTrack, "TrackDRV", hw),
      config_(requireValid(config, "TrackDrvConfig")),
      hw_(hw),
      m_per_step_(config.metresPerStep()),
      track_steps_(static_cast<int32_t>(lround(config.track_length_m / m_per_step_))) {}

double TrackDrv::velocityMps() const {
  if (motion_ == Motion::kIdle) return 0.0;
  const double t = static_cast<double>(now_us_ - profile_t0_us_) * 1e-6;
  return profile_.velocity(t) * m_per_step_;
}

bool TrackDrv::modeChangeAllowed() const { return !moving(); }

void TrackDrv::startProfile(int32_t target_steps, double vmax_sps, double amax_sps2) {
  profile_.plan(pos_steps_, target_steps, vmax_sps, amax_sps2);
  profile_t0_us_ = now_us_;
  stopping_ = false;
  hw_.enableMotor(true);
}

void TrackDrv::startStop() {
  const double t = static_cast<double>(now_us_ - profile_t0_us_) * 1e-6;
  const double v = profile_.velocity(t);
  const double p = profile_.position(t);
  const double a = motion_ == Motion::kHoming ? config_.home_accel_mps2 / m_per_step_
                                              : config_.accel_mps2 / m_per_step_;
  profile_.planStop(p, v, a);
  profile_t0_us_ = now_us_;
  stopping_ = true;
}

void TrackDrv::hardStop(TrackStateCode new_state, AckStatus status) {
  motion_ = Motion::kIdle;
  cmd_pos_m_ = pos_steps_ * m_per_step_;
  stopping_ = false;
  state_ = new_state;
  finishMove(status);
}

void TrackDrv::finishMove(AckStatus status) {
  if (move_pending_) {
    move_pending_ = false;
    sendAck(move_seq_, move_id_, status);
  }
  if (stop_pending_) {
    stop_pending_ = false;
    // The stop itself succeeded whatever ended the motion, unless the e-stop cut it.
    sendAck(stop_seq_, stop_id_,
            status == AckStatus::kEStop ? AckStatus::kEStop : AckStatus::kDone);
  }
}

// Emits single steps until the stepper count reaches the profile position (floor towards the
// direction of travel), checking the end-of-track sensor ahead before every step.
void TrackDrv::emitStepsTo(double target_pos) {
  while (motion_ != Motion::kIdle) {
    int dir = 0;
    if (target_pos >= pos_steps_ + 1)
      dir = 1;
    else if (target_pos <= pos_steps_ - 1)
      dir = -1;
    if (dir == 0) return;
    if (motion_ == Motion::kHoming) {
      if (hw_.farSensor()) return;  // handled by step()
    } else if ((dir > 0 && hw_.nearSensor()) || (dir < 0 && hw_.farSensor())) {
      hardStop(TrackStateCode::kEndOfTrack, AckStatus::kEndOfTrack);
      return;
    }
    hw_.step(dir);
    pos_steps_ += dir;
    if (motion_ == Motion::kHoming) {
      home_travel_steps_ += 1;
      if (hw_.farSensor()) return;
    }
  }
}

void TrackDrv::step(uint64_t now_us) {
  now_us_ = now_us;
  if (hw_.estopPressed()) {
    if (state_ != TrackStateCode::kEStop) {
      hw_.enableMotor(false);
      hardStop(TrackStateCode::kEStop, AckStatus::kEStop);
    }
    return;
  }
  if (motion_ == Motion::kIdle) return;
  const double t = static_cast<double>(now_us - profile_t0_us_) * 1e-6;
  double p = profile_.position(t);
  // Round away the last ulp so the final step of an exact integer target is always taken.
  p += (p > pos_steps_ ? 1e-9 : -1e-9);
  emitStepsTo(p);
  if (motion_ == Motion::kIdle) return;  // end-of-track stop inside emitStepsTo

  if (motion_ == Motion::kHoming) {
    if (hw_.farSensor()) {
      // The far sensor defines zero; the slow homing speed allows an immediate stop.
      motion_ = Motion::kIdle;
      pos_steps_ = 0;
      cmd_pos_m_ = 0;
      homed_ = true;
      state_ = TrackStateCode::kReady;
      finishMove(stopping_ ? AckStatus::kAborted : AckStatus::kDone);
      return;
    }
    if (t >= profile_.duration()) {
      motion_ = Motion::kIdle;
      state_ = stopping_ ? TrackStateCode::kUninitialised : TrackStateCode::kFault;
      finishMove(stopping_ ? AckStatus::kAborted : AckStatus::kFailed);
    }
    return;
  }
  if (t >= profile_.duration()) {
    emitStepsTo(profile_.end() + (profile_.end() > pos_steps_ ? 1e-9 : -1e-9));
    if (motion_ == Motion::kIdle) return;
    motion_ = Motion::kIdle;
    state_ = TrackStateCode::kReady;
    if (stopping_) cmd_pos_m_ = pos_steps_ * m_per_step_;
    finishMove(stopping_ ? AckStatus::kAborted : AckStatus::kDone);
  }
}

bool TrackDrv::handleCommand(const Frame& f) {
  const bool estop = state_ == TrackStateCode::kEStop;
  switch (f.id) {
    case MsgId::kInit: {
      if (estop) {
        sendAck(f.seq, f.id, AckStatus::kEStop);
      } else if (moving()) {
        sendAck(f.seq, f.id, AckStatus::kBusy);
      } else {
        sendAck(f.seq, f.id, AckStatus::kAccepted);
        move_pending_ = true;
        move_seq_ = f.seq;
        move_id_ = f.id;
        if (hw_.farSensor()) {
          pos_steps_ = 0;
          cmd_pos_m_ = 0;
          homed_ = true;
          state_ = TrackStateCode::kReady;
          finishMove(AckStatus::kDone);
        } else {
          homed_ = false;
          state_ = TrackStateCode::kHoming;
          motion_ = Motion::kHoming;
          home_travel_steps_ = 0;
          const int32_t search = static_cast<int32_t>(lround(config_.home_search_m / m_per_step_));
          startProfile(pos_steps_ - search, config_.home_speed_mps / m_per_step_,
                       config_.home_accel_mps2 / m_per_step_);
        }
      }
      return true;
    }
    case MsgId::kTrackMove: {
      CmdTrackMove m;
      if (decodePayload(f, m) != DecodeError::kNone) {
        sendAck(f.seq, f.id, AckStatus::kBadArgument);
        return true;
      }
      if (estop) {
        sendAck(f.seq, f.id, AckStatus::kEStop);
        return true;
      }
      if (!homed_ || state_ == TrackStateCode::kFault) {
        sendAck(f.seq, f.id, AckStatus::kNotReady);
        return true;
      }
      if (moving()) {
        sendAck(f.seq, f.id, AckStatus::kBusy);
        return true;
      }
      const double v = m.max_speed_mm_s > 0 ? m.max_speed_mm_s * 1e-3 : config_.max_speed_mps;
      const double a = m.accel_mm_s2 > 0 ? m.accel_mm_s2 * 1e-3 : config_.accel_mps2;
      // Relative targets add to the last commanded position (not the rounded step count), so a
      // sequence of 100 x 10 mm lands on 1 m instead of accumulating step rounding.
      const double target_m = (m.flags & CmdTrackMove::kRelative) ? cmd_pos_m_ + m.target_um * 1e-6
                                                                  : m.target_um * 1e-6;
      // Rounded to steps only once known to lie near the track: a board's long has 32 bits.
      const double target_steps = target_m / m_per_step_;
      const int32_t lo = static_cast<int32_t>(lround(config_.soft_margin_m / m_per_step_));
      const int32_t hi = track_steps_ - lo;
      const bool near_track = target_steps > lo - 1.0 && target_steps < hi + 1.0;
      const int32_t target = near_track ? static_cast<int32_t>(lround(target_steps)) : lo - 1;
      if (target < lo || target > hi || v > config_.speed_limit_mps ||
          a > config_.accel_limit_mps2) {
        sendAck(f.seq, f.id, AckStatus::kBadArgument);
        return true;
      }
      const int dir = target > pos_steps_ ? 1 : (target < pos_steps_ ? -1 : 0);
      if ((dir > 0 && hw_.nearSensor()) || (dir < 0 && hw_.farSensor())) {
        sendAck(f.seq, f.id, AckStatus::kEndOfTrack);  // would drive further into the end stop
        return true;
      }
      sendAck(f.seq, f.id, AckStatus::kAccepted);
      cmd_pos_m_ = target_m;
      move_pending_ = true;
      move_seq_ = f.seq;
      move_id_ = f.id;
      if (dir == 0) {
        state_ = TrackStateCode::kReady;
        finishMove(AckStatus::kDone);
        return true;
      }
      state_ = TrackStateCode::kMoving;
      motion_ = Motion::kProfile;
      startProfile(static_cast<int32_t>(target), v / m_per_step_, a / m_per_step_);
      return true;
    }
    case MsgId::kStop:
    case MsgId::kEnd: {
      if (!moving()) {
        sendAck(f.seq, f.id, estop ? AckStatus::kEStop : AckStatus::kDone);
        return true;
      }
      sendAck(f.seq, f.id, AckStatus::kAccepted);
      if (move_pending_) {
        move_pending_ = false;
        sendAck(move_seq_, move_id_, AckStatus::kAborted);
      }
      // A stop already decelerating is superseded: each command gets exactly one final ack.
      if (stop_pending_) sendAck(stop_seq_, stop_id_, AckStatus::kAborted);
      stop_pending_ = true;
      stop_seq_ = f.seq;
      stop_id_ = f.id;
      if (!stopping_) startStop();
      return true;
    }
    case MsgId::kReset: {
      if (hw_.estopPressed()) {
        sendAck(f.seq, f.id, AckStatus::kEStop);
        return true;
      }
      if (moving()) {
        motion_ = Motion::kIdle;
        stopping_ = false;
        finishMove(AckStatus::kAborted);
      }
      homed_ = false;
      state_ = TrackStateCode::kUninitialised;
      hw_.enableMotor(true);
      sendAck(f.seq, f.id, AckStatus::kDone);
      return true;
    }
    case MsgId::kStart:
      sendAck(f.seq, f.id, estop ? AckStatus::kEStop : AckStatus::kDone);
      return true;
    default:
      return false;  // kServo etc.: unsupported on the track board
  }
}

void TrackDrv::sendStream() {
  TrackStatePayload s;
  s.board_time_ms = nowMs();
  s.pos_steps = pos_steps_;
  s.pos_um = static_cast<int32_t>(lround(pos_steps_ * m_per_step_ * 1e6));
  s.vel_um_s = static_cast<int32_t>(lround(velocityMps() * 1e6));
  s.state = state_;
  s.flags =
      (hw_.nearSensor() ? TrackStatePayload::kNearSensor : 0) |
      (hw_.farSensor() ? TrackStatePayload::kFarSensor : 0) |
      (state_ == TrackStateCode::kEStop || hw_.estopPressed() ? TrackStatePayload::kEStopFlag : 0) |
      (homed_ ? TrackStatePayload::kHomed : 0);
  s.mode = mode_;
  send(s);
}

int TrackDrv::paramCount() const { return 8; }

ParamValue TrackDrv::param(int i) const {
  const int n = paramCount();
  switch (i) {
    case 0:
      return makeParam(i, n, "pulley_teeth", config_.pulley_teeth, 0);
    case 1:
      return makeParam(i, n, "mm_per_step", m_per_step_ * 1e3, 6);
    case 2:
      return makeParam(i, n, "track_len_mm", config_.track_length_m * 1e3, 1);
    case 3:
      return makeParam(i, n, "max_speed_mm_s", config_.max_speed_mps * 1e3, 1);
    case 4:
      return makeParam(i, n, "accel_mm_s2", config_.accel_mps2 * 1e3, 1);
    case 5:
      return makeParam(i, n, "home_speed_mm_s", config_.home_speed_mps * 1e3, 1);
    case 6:
      return makeParam(i, n, "soft_margin_mm", config_.soft_margin_m * 1e3, 1);
    default:
      return makeParam(i, n, "frame_rate_hz", 30.0, 0);
  }
}

}  // namespace protocol
}  // namespace rig_drivers
