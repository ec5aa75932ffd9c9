#include "rig_drivers/firmware/firmware.hpp"

#include <math.h>

namespace rig_drivers {
namespace protocol {

// ---- PiecewiseLinear
// ---------------------------------------------------------------------------------

bool PiecewiseLinear::set(const double* x, const double* y, int n, bool clamp) {
  n_ = 0;
  if (n < 2 || n > kMaxPoints) return false;
  const bool increasing = y[1] > y[0];
  for (int i = 0; i < n; ++i) {
    if (!isfinite(x[i]) || !isfinite(y[i])) return false;
    if (i > 0) {
      if (!(x[i] > x[i - 1])) return false;
      if (increasing ? !(y[i] > y[i - 1]) : !(y[i] < y[i - 1])) return false;
    }
  }
  for (int i = 0; i < n; ++i) {
    x_[i] = x[i];
    y_[i] = y[i];
  }
  n_ = n;
  clamp_ = clamp;
  return true;
}

double PiecewiseLinear::interp(const double* xs, const double* ys, int n, double v, bool clamp) {
  // xs ascending; linear inside, end segments extrapolated (or clamped).
  if (v <= xs[0]) {
    if (clamp) return ys[0];
  } else if (v >= xs[n - 1]) {
    if (clamp) return ys[n - 1];
  }
  int i = 1;
  while (i < n - 1 && v > xs[i]) ++i;
  const double t = (v - xs[i - 1]) / (xs[i] - xs[i - 1]);
  return ys[i - 1] + t * (ys[i] - ys[i - 1]);
}

double PiecewiseLinear::operator()(double x) const {
  if (n_ < 2) return 0.0;
  return interp(x_, y_, n_, x, clamp_);
}

double PiecewiseLinear::inverse(double y) const {
  if (n_ < 2) return 0.0;
  if (y_[1] > y_[0]) return interp(y_, x_, n_, y, clamp_);
  // decreasing curve: search on reversed copies
  double ry[kMaxPoints], rx[kMaxPoints];
  for (int i = 0; i < n_; ++i) {
    ry[i] = y_[n_ - 1 - i];
    rx[i] = x_[n_ - 1 - i];
  }
  return interp(ry, rx, n_, y, clamp_);
}

PiecewiseLinear PiecewiseLinear::scaled(double gain, double offset) const {
  PiecewiseLinear out;
  double y[kMaxPoints];
  for (int i = 0; i < n_; ++i) y[i] = y_[i] * gain + offset;
  out.set(x_, y, n_, clamp_);
  return out;
}

// ---- FirmwareBoard
// -------------------------------------------------------------------------------------

FirmwareBoard::FirmwareBoard(BoardId board, const char* name, SerialOut& out)
    : board_(board), out_(out) {
  for (size_t i = 0; i < kNameLen && name[i] != '\0'; ++i) name_[i] = name[i];
}

void FirmwareBoard::receive(const uint8_t* data, size_t n) { decoder_.feed(data, n, *this); }

void FirmwareBoard::update(uint32_t now_us) {
  clock_.update(now_us);
  const uint64_t t = clock_.us();
  if (wait_active_ && t >= wait_until_us_) {
    wait_active_ = false;
    sendAck(wait_seq_, MsgId::kWait, AckStatus::kDone);
  }
  step(t);
  if (frames_.due(t)) sendStream();
}

FirmwareBoard::SeenCommand* FirmwareBoard::findSeen(uint32_t seq, MsgId id) {
  for (auto& c : seen_)
    if (c.used && c.seq == seq && c.id == id) return &c;
  return nullptr;
}

void FirmwareBoard::sendAck(uint32_t seq, MsgId id, AckStatus status) {
  if (SeenCommand* c = findSeen(seq, id)) c->status = status;
  Ack a;
  a.acked_seq = seq;
  a.acked_id = id;
  a.status = status;
  send(a);
}

ParamValue FirmwareBoard::makeParam(int index, int count, const char* name, double value,
                                    int decimals) {
  ParamValue p;
  p.index = static_cast<uint8_t>(index);
  p.count = static_cast<uint8_t>(count);
  double scaled = value;
  for (int i = 0; i < decimals; ++i) scaled *= 10.0;
  p.mantissa = static_cast<int32_t>(lround(scaled));
  p.exp10 = static_cast<int8_t>(-decimals);
  p.setName(name);
  return p;
}

void FirmwareBoard::onError(DecodeError e, size_t discarded) {
  // Corrupted host bytes are simply dropped; the host times out and resends. Counted in rxStats().
  (void)e;
  (void)discarded;
}

void FirmwareBoard::onFrame(const Frame& f) {
  if (f.board != board_) return;                   // for another board on a shared link
  if (static_cast<uint8_t>(f.id) >= 0x80) return;  // board->host frames are not commands
  // vers, para and ping only report: they run again on a repeat. Everything else runs once.
  if (f.id != MsgId::kVers && f.id != MsgId::kPara && f.id != MsgId::kPing) {
    if (const SeenCommand* c = findSeen(f.seq, f.id)) {
      Ack a;
      a.acked_seq = c->seq;
      a.acked_id = c->id;
      a.status = c->status;
      send(a);
      return;
    }
    SeenCommand& slot = seen_[seen_next_];
    seen_next_ = (seen_next_ + 1) % kSeenCommands;
    slot.used = true;
    slot.seq = f.seq;
    slot.id = f.id;
    slot.status = AckStatus::kAccepted;
  }
  switch (f.id) {
    case MsgId::kPing: {
      CmdPing ping;
      if (decodePayload(f, ping) != DecodeError::kNone) {
        // Unanswered, a malformed ping would look like a lost link to the host.
        sendAck(f.seq, f.id, AckStatus::kBadArgument);
        return;
      }
      Pong pong;
      pong.host_time_ms = ping.host_time_ms;
      pong.board_time_ms = nowMs();
      send(pong);
      return;
    }
    case MsgId::kVers: {
      VersionInfo v;
      v.major = kFirmwareMajor;
      v.minor = kFirmwareMinor;
      v.patch = kFirmwarePatch;
      v.setName(name_);
      send(v);
      sendAck(f.seq, f.id, AckStatus::kDone);
      return;
    }
    case MsgId::kPara: {
      const int n = paramCount();
      for (int i = 0; i < n; ++i) send(param(i));
      sendAck(f.seq, f.id, AckStatus::kDone);
      return;
    }
    case MsgId::kMode: {
      CmdMode m;
      if (decodePayload(f, m) != DecodeError::kNone) {
        sendAck(f.seq, f.id, AckStatus::kBadArgument);
      } else if (!modeChangeAllowed()) {
        sendAck(f.seq, f.id, AckStatus::kBusy);
      } else {
        mode_ = m.mode;
        sendAck(f.seq, f.id, AckStatus::kDone);
      }
      return;
    }
    case MsgId::kWait: {
      CmdWait w;
      if (decodePayload(f, w) != DecodeError::kNone) {
        sendAck(f.seq, f.id, AckStatus::kBadArgument);
      } else if (wait_active_) {
        sendAck(f.seq, f.id, AckStatus::kBusy);
      } else {
        wait_active_ = true;
        wait_seq_ = f.seq;
        wait_until_us_ = clock_.us() + static_cast<uint64_t>(w.wait_ms) * 1000u;
        sendAck(f.seq, f.id, AckStatus::kAccepted);
      }
      return;
    }
    default:
      break;
  }
  if (f.id == MsgId::kReset && wait_active_) {
    wait_active_ = false;
    sendAck(wait_seq_, MsgId::kWait, AckStatus::kAborted);
  }
  if (!handleCommand(f)) sendAck(f.seq, f.id, AckStatus::kUnsupported);
}

}  // namespace protocol
}  // namespace rig_drivers
