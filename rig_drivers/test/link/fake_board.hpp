#pragma once
// Test double of a rig board (TrackDRV / CarDRV / TruckDRV) on the master side of a
// pseudo-terminal: streams its state frame at 30 Hz, answers vers/para, acknowledges every command
// with its seq (Accepted, then Done when the simulated motion is over), and can be unplugged and
// replugged behind a stable symlink. Speaks the real codec; no ROS. Test code only.
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "rig_drivers/protocol/codec.hpp"

namespace rig_drivers {
namespace fake {

class FakeBoard {
 public:
  /// `link` = path of the symlink the driver opens (replaced on replug).
  FakeBoard(protocol::BoardId board, std::string link) : board_(board), link_(std::move(link)) {
    plug();
    running_ = true;
    thread_ = std::thread([this] { run(); });
  }
  ~FakeBoard() {
    running_ = false;
    if (thread_.joinable()) thread_.join();
    unplugNow();
    ::unlink(link_.c_str());
  }

  /// Closes the master side: the driver sees a hang-up and the device path disappears.
  void unplug() {
    std::lock_guard<std::mutex> lock(mutex_);
    unplugNow();
    ::unlink(link_.c_str());
  }
  /// A new pty behind the same symlink (as udev does for a re-enumerated USB board).
  void plug() {
    std::lock_guard<std::mutex> lock(mutex_);
    unplugNow();
    termios raw{};
    ::cfmakeraw(&raw);
    char name[256] = {0};
    if (::openpty(&master_, &slave_, name, &raw, nullptr) != 0) {
      master_ = slave_ = -1;
      return;
    }
    ::fcntl(master_, F_SETFL, ::fcntl(master_, F_GETFL) | O_NONBLOCK);
    ::unlink(link_.c_str());
    if (::symlink(name, link_.c_str()) != 0) unplugNow();
    decoder_.reset();
  }
  /// Stops (or resumes) the 30 Hz stream without closing the port.
  void setSilent(bool silent) { silent_ = silent; }

  int commandsReceived(protocol::MsgId id) const {
    std::lock_guard<std::mutex> lock(mutex_);
    int n = 0;
    for (const auto& c : received_) n += c.first == id;
    return n;
  }
  std::vector<std::uint32_t> seqsReceived() const {
    std::lock_guard<std::mutex> lock(mutex_);
    std::vector<std::uint32_t> s;
    for (const auto& c : received_) s.push_back(c.second);
    return s;
  }
  double positionMm() const { return pos_mm_.load(); }
  std::uint32_t framesSent() const { return frame_seq_.load(); }

 private:
  using Clock = std::chrono::steady_clock;
  struct Motion {
    bool active = false;
    std::uint32_t seq = 0;
    protocol::MsgId id = protocol::MsgId::kInit;
    double target_mm = 0;
    double speed_mm_s = 100;
    Clock::time_point until;  // for waits / servo moves / init
  };

  void unplugNow() {
    if (master_ >= 0) ::close(master_);
    if (slave_ >= 0) ::close(slave_);
    master_ = slave_ = -1;
  }
  std::uint32_t boardMs() const {
    return static_cast<std::uint32_t>(
        std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - t0_).count());
  }
  void send(const std::vector<std::uint8_t>& bytes) {
    if (master_ < 0) return;
    std::size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t n = ::write(master_, bytes.data() + done, bytes.size() - done);
      if (n <= 0) return;  // buffer full (nobody reading): drop, like a UART would
      done += static_cast<std::size_t>(n);
    }
  }
  void ack(std::uint32_t seq, protocol::MsgId id, protocol::AckStatus st) {
    protocol::Ack a;
    a.acked_seq = seq;
    a.acked_id = id;
    a.status = st;
    send(protocol::encodeMessage(board_, seq, a));
  }
  void handle(const protocol::Frame& f) {
    using protocol::AckStatus;
    using protocol::MsgId;
    received_.push_back({f.id, f.seq});
    switch (f.id) {
      case MsgId::kVers: {
        protocol::VersionInfo v;
        v.major = 0;
        v.minor = 9;
        v.patch = 1;
        v.setName(board_ == protocol::BoardId::kTrack ? "FakeTrackDRV"
                  : board_ == protocol::BoardId::kCar ? "FakeCarDRV"
                                                      : "FakeTruckDRV");
        send(protocol::encodeMessage(board_, f.seq, v));
        ack(f.seq, f.id, AckStatus::kDone);
        break;
      }
      case MsgId::kPara: {
        const char* names[] = {"mm_per_step", "max_speed_mm_s", "frame_period_ms"};
        const int mant[] = {186, 200, 33};
        const int8_t ex[] = {-4, 0, 0};
        for (int i = 0; i < 3; ++i) {
          protocol::ParamValue p;
          p.index = static_cast<std::uint8_t>(i);
          p.count = 3;
          p.mantissa = mant[i];
          p.exp10 = ex[i];
          p.setName(names[i]);
          send(protocol::encodeMessage(board_, f.seq, p));
        }
        ack(f.seq, f.id, AckStatus::kDone);
        break;
      }
      case MsgId::kInit:
        ack(f.seq, f.id, AckStatus::kAccepted);
        startTimed(f, 150);
        break;
      case MsgId::kMode: {
        protocol::CmdMode m;
        if (protocol::decodePayload(f, m) != protocol::DecodeError::kNone) {
          ack(f.seq, f.id, AckStatus::kBadArgument);
          break;
        }
        mode_ = m.mode;
        ack(f.seq, f.id, AckStatus::kDone);
        break;
      }
      case MsgId::kTrackMove: {
        protocol::CmdTrackMove m;
        if (board_ != protocol::BoardId::kTrack) {
          ack(f.seq, f.id, AckStatus::kUnsupported);
          break;
        }
        if (protocol::decodePayload(f, m) != protocol::DecodeError::kNone) {
          ack(f.seq, f.id, AckStatus::kBadArgument);
          break;
        }
        if (motion_.active) {
          ack(f.seq, f.id, AckStatus::kBusy);
          break;
        }
        const double target = (m.flags & protocol::CmdTrackMove::kRelative)
                                  ? pos_mm_ + m.target_um * 1e-3
                                  : m.target_um * 1e-3;
        if (target < 0 || target > 1200) {
          ack(f.seq, f.id, AckStatus::kBadArgument);
          break;
        }
        ack(f.seq, f.id, AckStatus::kAccepted);
        motion_ = Motion{};
        motion_.active = true;
        motion_.seq = f.seq;
        motion_.id = f.id;
        motion_.target_mm = target;
        motion_.speed_mm_s = m.max_speed_mm_s ? m.max_speed_mm_s : 200.0;
        break;
      }
      case MsgId::kServo: {
        protocol::CmdServo s;
        if (protocol::decodePayload(f, s) != protocol::DecodeError::kNone) {
          ack(f.seq, f.id, AckStatus::kBadArgument);
          break;
        }
        pitch_cdeg_ = s.pitch_cdeg;
        yaw_cdeg_ = s.yaw_cdeg;
        ack(f.seq, f.id, AckStatus::kAccepted);
        startTimed(f, 60);
        break;
      }
      case MsgId::kWait: {
        protocol::CmdWait w;
        if (protocol::decodePayload(f, w) != protocol::DecodeError::kNone) {
          ack(f.seq, f.id, AckStatus::kBadArgument);
          break;
        }
        ack(f.seq, f.id, AckStatus::kAccepted);
        startTimed(f, static_cast<int>(w.wait_ms));
        break;
      }
      case MsgId::kStart:
      case MsgId::kStop:
      case MsgId::kReset:
      case MsgId::kEnd:
        if (f.id != MsgId::kStart) motion_.active = false;
        ack(f.seq, f.id, AckStatus::kAccepted);
        ack(f.seq, f.id, AckStatus::kDone);
        break;
      default:
        ack(f.seq, f.id, AckStatus::kUnsupported);
    }
  }
  void startTimed(const protocol::Frame& f, int ms) {
    motion_ = Motion{};
    motion_.active = true;
    motion_.seq = f.seq;
    motion_.id = f.id;
    motion_.target_mm = pos_mm_;
    motion_.until = Clock::now() + std::chrono::milliseconds(ms);
  }
  void step(double dt) {
    if (!motion_.active) return;
    if (motion_.id == protocol::MsgId::kTrackMove) {
      const double d = motion_.target_mm - pos_mm_;
      const double s = motion_.speed_mm_s * dt;
      if (std::fabs(d) <= s) {
        pos_mm_ = motion_.target_mm;
        motion_.active = false;
        ack(motion_.seq, motion_.id, protocol::AckStatus::kDone);
      } else {
        pos_mm_ = pos_mm_ + (d > 0 ? s : -s);
      }
    } else if (Clock::now() >= motion_.until) {
      motion_.active = false;
      if (motion_.id == protocol::MsgId::kInit) {
        homed_ = true;
        pos_mm_ = 0;
      }
      ack(motion_.seq, motion_.id, protocol::AckStatus::kDone);
    }
  }
  void sendState() {
    const std::uint32_t seq = frame_seq_++;
    if (board_ == protocol::BoardId::kTrack) {
      protocol::TrackStatePayload t;
      t.board_time_ms = boardMs();
      t.pos_um = static_cast<std::int32_t>(std::lround(pos_mm_ * 1000));
      t.pos_steps = static_cast<std::int32_t>(std::lround(pos_mm_ / 0.0186));
      t.state = motion_.active ? protocol::TrackStateCode::kMoving
                : homed_       ? protocol::TrackStateCode::kReady
                               : protocol::TrackStateCode::kUninitialised;
      t.flags = homed_ ? protocol::TrackStatePayload::kHomed : 0;
      t.mode = mode_;
      send(protocol::encodeMessage(board_, seq, t));
    } else if (board_ == protocol::BoardId::kCar) {
      protocol::CarSensorsPayload c;
      c.board_time_ms = boardMs();
      c.pitch_dem_cdeg = c.pitch_cdeg = pitch_cdeg_;
      c.yaw_dem_cdeg = c.yaw_cdeg = yaw_cdeg_;
      c.acc_y_mg = 1000;
      c.tof_mm = 500;
      c.flags = protocol::CarSensorsPayload::kTofValid;
      send(protocol::encodeMessage(board_, seq, c));
    } else {
      protocol::TruckRcPayload r;
      r.board_time_ms = boardMs();
      r.ch2_us = r.ch3_us = 1500;
      r.ch5_us = r.ch7_us = 1000;
      r.flags = protocol::TruckRcPayload::kSignalOk;
      send(protocol::encodeMessage(board_, seq, r));
    }
  }
  void run() {
    auto next = Clock::now();
    auto last = Clock::now();
    while (running_) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        if (master_ >= 0) {
          std::uint8_t buf[256];
          const ssize_t n = ::read(master_, buf, sizeof buf);
          if (n > 0)
            for (const auto& ev : protocol::feed(decoder_, buf, static_cast<std::size_t>(n)))
              if (ev.error == protocol::DecodeError::kNone) handle(ev.frame);
          const auto now = Clock::now();
          step(std::chrono::duration<double>(now - last).count());
          last = now;
          if (now >= next) {
            next += std::chrono::microseconds(33333);  // 30 Hz frame clock
            if (!silent_) sendState();
          }
        } else {
          last = next = Clock::now();
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  }

  protocol::BoardId board_;
  std::string link_;
  mutable std::mutex mutex_;
  int master_ = -1, slave_ = -1;
  protocol::StreamDecoder decoder_;
  std::thread thread_;
  std::atomic<bool> running_{false};
  std::atomic<bool> silent_{false};
  std::vector<std::pair<protocol::MsgId, std::uint32_t>> received_;
  Motion motion_;
  std::atomic<double> pos_mm_{0.0};
  std::int16_t pitch_cdeg_ = 0, yaw_cdeg_ = 0;
  bool homed_ = false;
  std::uint8_t mode_ = 1;
  std::atomic<std::uint32_t> frame_seq_{0};
  Clock::time_point t0_ = Clock::now();
};

}  // namespace fake
}  // namespace rig_drivers
