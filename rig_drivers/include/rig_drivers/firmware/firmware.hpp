#pragma once
// Shared parts of the portable rig firmware (TrackDRV, CarDRV, TruckDRV): the serial side of a
// board (decoding host commands, numbering its frames, acknowledging commands, vers/para/ping/wait,
// the 30 Hz frame clock) and the piecewise-linear calibration curve of appendix B.
//
// Nothing here includes Arduino headers or the C++ standard library: a board's hardware adapter
// (src/firmware/avr/ for avr-libc builds, the .ino sketches for the Arduino IDE) calls
//   board.receive(bytes, n);  board.update(micros());
// from its loop. The host simulator and the tests do exactly the same with an injected clock, so
// one code path runs on the bench and in simulation. Not thread-safe: one thread drives a board.
//
// Board configs are checked by problems() (one bit per problem, 0 when valid), which runs on the
// board; the host's validate() turns the bits into text (config_text.cpp), and on the host a
// board's constructor throws std::invalid_argument naming every problem of its config.

#include <stddef.h>
#include <stdint.h>

#include "rig_drivers/protocol/codec.hpp"

#if RIG_DRIVERS_HOST
#include <stdexcept>
#include <string>
#endif

namespace rig_drivers {
namespace protocol {

/// Byte sink of a board's serial port (Arduino Serial.write, a pty in the simulator, a test
/// buffer).
class SerialOut {
 public:
  virtual ~SerialOut() = default;
  /// Writes n bytes; must not block for long (115200 baud is ~11.5 bytes/ms).
  virtual void write(const uint8_t* data, size_t n) = 0;
};

/// Monotonic piecewise-linear map y(x) through up to kMaxPoints (x, y) points, used for the servo
/// (deg -> pulse us) and sensor (volts -> deg) calibrations of appendix B and the truck speed curve
/// (fig. 5.42). Outside the table the end segments are extrapolated (clamped if `clamp`).
class PiecewiseLinear {
 public:
  static constexpr int kMaxPoints = 12;
  PiecewiseLinear() = default;
  /// Sets the table; returns false (and leaves the curve empty) unless 2 <= n <= kMaxPoints and
  /// x strictly increases and y strictly increases or strictly decreases (invertible).
  bool set(const double* x, const double* y, int n, bool clamp = false);
  bool valid() const { return n_ >= 2; }
  int size() const { return n_; }
  double x(int i) const { return x_[i]; }
  double y(int i) const { return y_[i]; }
  /// y at x (clamped to the table's y range when clamp was set).
  double operator()(double x) const;
  /// x at y: the inverse map (the curve is monotonic).
  double inverse(double y) const;
  double xMin() const { return x_[0]; }
  double xMax() const { return x_[n_ - 1]; }
  /// Same curve with y' = y * gain + offset (a calibration error for the simulator).
  PiecewiseLinear scaled(double gain, double offset) const;

 private:
  static double interp(const double* xs, const double* ys, int n, double v, bool clamp);
  double x_[kMaxPoints] = {};
  double y_[kMaxPoints] = {};
  int n_ = 0;
  bool clamp_ = false;
};

/// Board time kept in 64 bits from a wrapping 32-bit microsecond counter (Arduino micros() wraps
/// after 71.6 minutes).
class BoardClock {
 public:
  /// Advances to the raw counter value; the first call defines time zero.
  void update(uint32_t now_us) {
    if (!started_) {
      started_ = true;
      last_ = now_us;
    }
    elapsed_us_ += static_cast<uint32_t>(now_us - last_);
    last_ = now_us;
  }
  uint64_t us() const { return elapsed_us_; }
  uint32_t ms() const { return static_cast<uint32_t>(elapsed_us_ / 1000u); }
  double seconds() const { return static_cast<double>(elapsed_us_) * 1e-6; }

 private:
  bool started_ = false;
  uint32_t last_ = 0;
  uint64_t elapsed_us_ = 0;
};

/// 30 Hz frame clock without drift: frame n is due at n * 100 ms / 3 (exact in integers).
class FrameClock {
 public:
  /// True once per frame period; call with the board time.
  bool due(uint64_t now_us) {
    const uint64_t next = (frame_ * 100000u) / 3u;
    if (now_us < next) return false;
    ++frame_;
    // Never bunch up more than one frame after a stall: skip the missed ones.
    while ((frame_ * 100000u) / 3u <= now_us) ++frame_;
    return true;
  }
  uint64_t framesDue() const { return frame_; }

 private:
  uint64_t frame_ = 0;
};

#if RIG_DRIVERS_HOST
/// `config` itself when its problems() are 0; else throws std::invalid_argument("<what>: <every
/// problem>") (host only: a board's adapter checks problems() before it starts the board).
template <class Config>
const Config& requireValid(const Config& config, const char* what) {
  if (config.problems() != 0)
    throw std::invalid_argument(std::string(what) + ": " + config.validate());
  return config;
}
#else
template <class Config>
const Config& requireValid(const Config& config, const char*) {
  return config;
}
#endif

/// Version of the firmware logic in this library (reported by vers).
constexpr uint8_t kFirmwareMajor = 1;
constexpr uint8_t kFirmwareMinor = 0;
constexpr uint8_t kFirmwarePatch = 0;

/// Serial side common to all boards. A derived board implements handleCommand() for its own
/// commands and calls sendStream() from its update().
class FirmwareBoard : public FrameSink {
 public:
  FirmwareBoard(BoardId board, const char* name, SerialOut& out);
  ~FirmwareBoard() override = default;
  FirmwareBoard(const FirmwareBoard&) = delete;
  FirmwareBoard& operator=(const FirmwareBoard&) = delete;

  /// Feeds bytes received on the serial port; commands are handled at once.
  void receive(const uint8_t* data, size_t n);
  /// The host's line has been quiet for a while (the adapter's judgement): a frame still pending
  /// can never complete; complete commands buffered behind a false frame start are handled now.
  void lineIdle() { decoder_.expire(*this); }
  /// Received bytes of a frame not yet complete.
  size_t rxPending() const { return decoder_.pending(); }
  /// Runs the board's control logic at raw microsecond counter `now_us` (call often: every loop()).
  void update(uint32_t now_us);

  BoardId board() const { return board_; }
  uint8_t mode() const { return mode_; }
  /// Frames written so far (the seq of the next board frame).
  uint32_t framesSent() const { return tx_seq_; }
  const DecoderStats& rxStats() const { return decoder_.stats(); }
  double timeSeconds() const { return clock_.seconds(); }

 protected:
  /// Board-specific command. Return true if handled (the board sends its own acks).
  virtual bool handleCommand(const Frame& f) = 0;
  /// Board-specific periodic work at board time `now_us` (64-bit, never wraps).
  virtual void step(uint64_t now_us) = 0;
  /// Called for a 30 Hz frame: write the stream payload.
  virtual void sendStream() = 0;
  /// Parameters reported by para.
  virtual int paramCount() const { return 0; }
  virtual ParamValue param(int index) const {
    (void)index;
    return ParamValue();
  }
  /// Mode change request; return false to refuse (e.g. while moving).
  virtual bool modeChangeAllowed() const { return true; }

  void sendAck(uint32_t seq, MsgId id, AckStatus status);
  template <class P>
  void send(const P& payload) {
    uint8_t buf[kMaxFrameSize];
    const size_t n = encodeMessage(board_, tx_seq_++, payload, buf, sizeof buf);
    out_.write(buf, n);
  }
  /// Helper for para: value with `decimals` digits after the point.
  static ParamValue makeParam(int index, int count, const char* name, double value, int decimals);

  uint64_t nowUs() const { return clock_.us(); }
  uint32_t nowMs() const { return clock_.ms(); }
  uint8_t mode_ = 1;

 private:
  void onFrame(const Frame& f) override;
  void onError(DecodeError e, size_t discarded) override;

  /// Commands with side effects are executed once per seq: a retransmitted command (same seq and
  /// id, e.g. after a lost ack) only gets its latest ack again, so a relative move never runs
  /// twice.
  struct SeenCommand {
    bool used = false;
    uint32_t seq = 0;
    MsgId id = MsgId::kInit;
    AckStatus status = AckStatus::kAccepted;
  };
  static constexpr int kSeenCommands = 16;
  SeenCommand* findSeen(uint32_t seq, MsgId id);
  SeenCommand seen_[kSeenCommands];
  int seen_next_ = 0;

  BoardId board_;
  char name_[kNameLen + 1] = {};
  SerialOut& out_;
  StreamDecoder decoder_;
  BoardClock clock_;
  FrameClock frames_;
  uint32_t tx_seq_ = 0;
  // One pending wait step (mode 2 settle) at a time.
  bool wait_active_ = false;
  uint32_t wait_seq_ = 0;
  uint64_t wait_until_us_ = 0;
};

}  // namespace protocol
}  // namespace rig_drivers
