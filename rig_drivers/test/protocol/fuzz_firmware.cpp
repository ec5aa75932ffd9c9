// libFuzzer target for the firmware logic of the three rig boards (TrackDRV, CarDRV, TruckDRV):
// host commands, retransmissions, serial garbage, hardware inputs and the passing of board time
// all chosen by the input, with at most kMaxTicks loop ticks and kMaxBoardTimeUs of board time
// per input so a run stays fast. Built and run by rig_drivers/scripts/run_codec_fuzz.sh
// (clang-14, ASan + UBSan); the codec alone has its own, faster target (fuzz_codec.cpp).
//
// Input layout:
//   header (4 bytes): [0] bits 0-1 pulley (20/30/36/48 teeth), bits 2-7 loop tick - 1 (ms);
//                     [1..2] carriage start as a fraction of the track; [3] int8 offset of the
//                     near sensor from the configured track length (mm)
//   records:
//     0x00-0x3F  command. bits 0-1 link (1 track, 2 car, 3 truck, 0 all three). bit 2 set:
//                resend one of the last 8 commands of that link unchanged (bits 3-5 = how far
//                back); else [id][length % 65][payload], numbered by one host counter; bits 3-5
//                all set: addressed to another board than the link's
//     0x40-0x7F  let (op & 0x3F) + 1 loop ticks pass
//     0x80-0xBF  hardware: bit 0 e-stop pressed, bit 1 ToF no return, bit 2 IMU silent, bit 3
//                CH5 on, bit 4 CH7 on, bit 5 one RC channel without pulses; then [adc][ch2][ch3]
//     0xC0-0xFF  ((op >> 2) & 15) + 1 raw bytes onto link op & 3 (0 = all)
// The seed corpus (rig_drivers/test/fuzz/corpus/firmware) is the host commands of scenario bags.
//
// Properties (a model of the command protocol in codec.hpp/firmware.hpp, and the physics):
//  - every byte a board writes decodes: its own board id, frame counter +1 per frame, payload
//  valid;
//  - every command a board decodes (the harness decodes the same bytes) is answered at once:
//    ping by its pong, vers by VersionInfo + done, para by each parameter + done, anything else by
//    an ack for its seq: accepted (then exactly one final ack later) or final; a retransmission
//    still remembered gets only its latest ack again and has no effect; nothing else is written;
//  - no ack for a command never sent, no second final ack, no "accepted" after the first answer;
//  - at most one move, one stop and one wait open per board; other commands end in their answer;
//    a reset (e-stop released) ends every open command;
//  - track: never steps with the motor off, with the e-stop pressed, into an active end sensor, or
//    faster than the speed limit; once homed its step count is the true carriage position; init
//    done means at the far sensor, an absolute move done means at the target, end-of-track means
//    at a sensor; homing cannot fail (the far sensor is always within the search distance);
//    moving/homing exactly while a move or stop is open;
//  - car: demands within the limits, servo pulses within the calibrated range, a move done no
//    earlier than the settle time, in mode 2 a demand during a move is busy;
//  - truck: motor and steering in [-1, 1]; no motor on a lost receiver, with CH5 off or after a
//  host
//    stop; motor direction follows CH3;
//  - wait done after its time (within one tick); streams: 30 Hz, no frame lost while the loop runs
//    faster than the frame period (never more than one per period), board time = harness time
//    across the micros() wrap, stream fields equal to the board's state.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <utility>
#include <vector>

#include "fuzz_check.hpp"
#include "rig_drivers/firmware/car_drv.hpp"
#include "rig_drivers/firmware/track_drv.hpp"
#include "rig_drivers/firmware/truck_drv.hpp"
#include "rig_drivers/protocol/codec.hpp"

namespace rp = rig_drivers::protocol;
using rp::AckStatus;
using rp::DecodeError;
using rp::MsgId;
using rp::TrackStateCode;

namespace {

constexpr int kMaxTicks = 1500;
constexpr uint64_t kMaxBoardTimeUs = 10000000;            // homing plus a move end to end
constexpr uint32_t kClockStart = 0xFFFFFFFFu - 3000000u;  // micros() wraps 3 s into the run
constexpr double kTrackLengthM = 1.2;
constexpr double kSpeedLimitMps = 0.3;

// RIG_FUZZ_TRACE=1 when replaying one input prints what the harness sends and sees.
const bool kTrace = std::getenv("RIG_FUZZ_TRACE") != nullptr;
#define FUZZ_TRACE(...)                            \
  do {                                             \
    if (kTrace) std::fprintf(stderr, __VA_ARGS__); \
  } while (0)

const char* name(MsgId id) { return rp::msgName(id); }
const char* name(AckStatus s) { return rp::ackStatusName(s); }

/// Hardware inputs set by the input's hardware records.
struct Inputs {
  bool estop = false;
  bool tof_ok = true;
  bool imu_ok = true;
  int adc = 512;
  uint16_t ch[4] = {1500, 1500, 1900, 1100};  // CH2 steering, CH3 speed, CH5 run, CH7 record
};

/// Everything a board writes, decoded (a board writes whole frames).
class Capture {
 public:
  void write(const uint8_t* d, size_t n) {
    for (const auto& e : rp::feed(dec_, d, n)) {
      FUZZ_CHECK(e.error == DecodeError::kNone, "board wrote a bad frame: %s",
                 rp::errorName(e.error));
      frames_.push_back(e.frame);
    }
    FUZZ_CHECK(dec_.pending() == 0, "board wrote %zu bytes of a partial frame", dec_.pending());
  }
  std::vector<rp::Frame> take() { return std::move(frames_); }

 private:
  rp::StreamDecoder dec_;
  std::vector<rp::Frame> frames_;
};

/// Rigid carriage between the far sensor (position 0) and the near sensor (steps).
class SimTrack : public rp::TrackHardware {
 public:
  SimTrack(const Inputs& in, int64_t pos, int64_t near) : in_(in), pos_(pos), near_(near) {}
  void step(int dir) override {
    FUZZ_CHECK(dir == 1 || dir == -1, "step direction %d", dir);
    FUZZ_CHECK(motor_on_, "step with the motor disabled");
    FUZZ_CHECK(!in_.estop, "step while the e-stop is pressed");
    FUZZ_CHECK(!(dir < 0 && farSensor()) && !(dir > 0 && nearSensor()),
               "step %+d into the end sensor at %lld (near sensor at %lld)", dir,
               static_cast<long long>(pos_), static_cast<long long>(near_));
    const TrackStateCode s = drv->state();
    FUZZ_CHECK(s == TrackStateCode::kHoming || s == TrackStateCode::kMoving, "step in state %d",
               static_cast<int>(s));
    pos_ += dir;
    ++steps_;
  }
  bool farSensor() override { return pos_ <= 0; }
  bool nearSensor() override { return pos_ >= near_; }
  bool estopPressed() override { return in_.estop; }
  void enableMotor(bool on) override { motor_on_ = on; }
  void write(const uint8_t* d, size_t n) override { out.write(d, n); }

  int64_t pos() const { return pos_; }
  int64_t near() const { return near_; }
  bool motorOn() const { return motor_on_; }
  int64_t takeSteps() { return std::exchange(steps_, 0); }

  Capture out;
  const rp::TrackDrv* drv = nullptr;

 private:
  const Inputs& in_;
  int64_t pos_;
  int64_t near_;
  int64_t steps_ = 0;
  bool motor_on_ = true;
};

class SimCar : public rp::CarHardware {
 public:
  SimCar(const Inputs& in, const rp::CarDrvConfig& c) : in_(in) {
    const rp::AxisCalibration* axes[2] = {&c.pitch, &c.yaw};
    for (int a = 0; a < 2; ++a) {
      const double p0 = axes[a]->pulse_us_of_deg(axes[a]->min_deg);
      const double p1 = axes[a]->pulse_us_of_deg(axes[a]->max_deg);
      lo_[a] = std::fmin(p0, p1) - 1e-6;
      hi_[a] = std::fmax(p0, p1) + 1e-6;
    }
  }
  void setServoPulse(rp::GimbalAxis axis, double us) override {
    const int a = static_cast<int>(axis);
    FUZZ_CHECK(us >= lo_[a] && us <= hi_[a], "axis %d pulse %.3f us outside [%.1f, %.1f]", a, us,
               lo_[a], hi_[a]);
  }
  int readAdc(rp::GimbalAxis) override { return in_.adc; }
  bool readImu(int16_t raw[3]) override {
    raw[0] = static_cast<int16_t>(in_.adc * 64 - 32768);
    raw[1] = static_cast<int16_t>(32767 - in_.adc * 64);
    raw[2] = static_cast<int16_t>(in_.adc * 16);
    return in_.imu_ok;
  }
  bool readTof(uint16_t& mm) override {
    mm = static_cast<uint16_t>(in_.adc * 64);
    return in_.tof_ok;
  }
  void write(const uint8_t* d, size_t n) override { out.write(d, n); }

  Capture out;

 private:
  const Inputs& in_;
  double lo_[2], hi_[2];
};

class SimTruck : public rp::TruckHardware {
 public:
  explicit SimTruck(const Inputs& in) : in_(in) {}
  uint16_t pulseUs(rp::RcChannel ch) override { return in_.ch[static_cast<int>(ch)]; }
  void setMotor(double c) override {
    FUZZ_CHECK(c >= -1 && c <= 1, "motor command %g", c);
    motor = c;
  }
  void setSteering(double c) override {
    FUZZ_CHECK(c >= -1 && c <= 1, "steering command %g", c);
    steering = c;
  }
  void write(const uint8_t* d, size_t n) override { out.write(d, n); }

  Capture out;
  double motor = 0, steering = 0;

 private:
  const Inputs& in_;
};

/// One execution of a command with side effects, as the model sees it.
struct Exec {
  bool answered = false;   ///< an ack for it was seen
  bool open = false;       ///< accepted, final ack still due
  bool ambiguous = false;  ///< re-run while an earlier run of the same seq/id was open
  uint64_t t_accept_us = 0;
  uint32_t wait_ms = 0;
  bool track_move = false;  ///< a valid CmdTrackMove: where it must end is known once accepted
  rp::CmdTrackMove move;
  bool has_target = false;
  int64_t target_steps = 0;
};

/// The board's memory of recent commands (firmware.hpp: executed once per seq and id).
struct Remembered {
  bool used = false;
  uint32_t seq = 0;
  MsgId id = MsgId::kInit;
  AckStatus status = AckStatus::kAccepted;
};

uint64_t key(uint32_t seq, MsgId id) {
  return (static_cast<uint64_t>(seq) << 8) | static_cast<uint8_t>(id);
}

template <class P>
DecodeError decodeAs(const rp::Frame& f) {
  P p;
  return rp::decodePayload(f, p);
}

bool isMove(MsgId id) {
  return id == MsgId::kInit || id == MsgId::kTrackMove || id == MsgId::kServo;
}
bool isStop(MsgId id) { return id == MsgId::kStop || id == MsgId::kEnd; }

enum class Kind { kTrack, kCar, kTruck };

/// Model of one link: what the harness sent, what the board must have answered.
struct Link {
  Kind kind;
  rp::FirmwareBoard* board;
  Capture* out;
  const char* board_name;
  int param_count;
  rp::StreamDecoder mirror;  ///< decodes what the board receives, as the board does
  std::array<Remembered, 16> ring;
  int ring_next = 0;
  std::map<uint64_t, Exec> execs;
  uint32_t tx_seq = 0;
  uint64_t streams = 0;
  bool host_stopped = false;  ///< truck: stop/end done, start/init/reset not yet
  std::vector<std::vector<uint8_t>> sent;

  Remembered* remembered(uint32_t seq, MsgId id) {
    for (auto& r : ring)
      if (r.used && r.seq == seq && r.id == id) return &r;
    return nullptr;
  }
  void remember(uint32_t seq, MsgId id) {
    ring[ring_next] = {true, seq, id, AckStatus::kAccepted};
    ring_next = (ring_next + 1) % static_cast<int>(ring.size());
  }
  bool hasAmbiguous() const {
    for (const auto& e : execs)
      if (e.second.ambiguous) return true;
    return false;
  }
  int openCount(bool (*pred)(MsgId)) const {
    int n = 0;
    for (const auto& e : execs)
      if (e.second.open && !e.second.ambiguous && pred(static_cast<MsgId>(e.first & 0xFF))) ++n;
    return n;
  }
};

class Rig {
 public:
  Rig(const uint8_t* h)
      : track_cfg_(trackConfig(h[0] & 3)),
        car_cfg_(rp::CarDrvConfig::defaults()),
        truck_cfg_(rp::TruckDrvConfig::defaults()),
        tick_us_(1000u * (1u + (h[0] >> 2))),
        mps_(track_cfg_.metresPerStep()),
        near_steps_(std::llround((kTrackLengthM + static_cast<int8_t>(h[3]) * 1e-3) / mps_)),
        track_hw_(in_, static_cast<int64_t>((h[1] | (h[2] << 8)) / 65535.0 * near_steps_),
                  near_steps_),
        car_hw_(in_, car_cfg_),
        truck_hw_(in_),
        track_(track_cfg_, track_hw_),
        car_(car_cfg_, car_hw_),
        truck_(truck_cfg_, truck_hw_) {
    track_hw_.drv = &track_;
    setLink(links_[0], Kind::kTrack, track_, track_hw_.out, "TrackDRV", 8);
    setLink(links_[1], Kind::kCar, car_, car_hw_.out, "CarDRV", 8);
    setLink(links_[2], Kind::kTruck, truck_, truck_hw_.out, "TruckDRV",
            4 + truck_cfg_.speed_curve.size());
    update();  // board time zero for all three
  }

  void run(const uint8_t* d, size_t n) {
    size_t i = 0;
    while (i < n) {
      const uint8_t op = d[i++];
      if (op < 0x40) {
        if (op & 4) {
          for (Link* l : targets(op)) {
            if (l->sent.empty()) continue;
            const size_t back = std::min<size_t>((op >> 3) & 7, l->sent.size() - 1);
            const std::vector<uint8_t> frame = l->sent[l->sent.size() - 1 - back];
            deliver(*l, frame);
          }
          continue;
        }
        if (i + 2 > n) return;
        const uint8_t id = d[i];
        const size_t len = std::min<size_t>(d[i + 1] % (rp::kMaxPayload + 1), n - i - 2);
        const uint8_t* payload = d + i + 2;
        i += 2 + len;
        const uint32_t seq = next_seq_++;
        const bool misaddressed = ((op >> 3) & 7) == 7;
        for (Link* l : targets(op)) {
          const uint8_t b = static_cast<uint8_t>(l->board->board());
          const auto addr = static_cast<rp::BoardId>(misaddressed ? (b + 1) % 4 : b);
          std::vector<uint8_t> frame(rp::kMaxFrameSize);
          frame.resize(rp::encodeFrame(addr, static_cast<MsgId>(id), seq, payload, len,
                                       frame.data(), frame.size()));
          l->sent.push_back(frame);
          deliver(*l, frame);
        }
      } else if (op < 0x80) {
        for (int t = 0; t <= (op & 0x3F); ++t) tick();
      } else if (op < 0xC0) {
        if (i + 3 > n) return;
        in_.estop = op & 1;
        in_.tof_ok = !(op & 2);
        in_.imu_ok = !(op & 4);
        in_.adc = d[i] * 4 + 3;
        in_.ch[0] = static_cast<uint16_t>(700 + d[i + 1] * 6);
        in_.ch[1] = static_cast<uint16_t>(700 + d[i + 2] * 6);
        in_.ch[2] = (op & 8) ? 1900 : 1100;
        in_.ch[3] = (op & 16) ? 1900 : 1100;
        if (op & 32) in_.ch[d[i] & 3] = 0;
        i += 3;
        FUZZ_TRACE("%8.3f s  hardware: e-stop %d, adc %d, ch %u %u %u %u\n", t_us_ * 1e-6,
                   in_.estop, in_.adc, in_.ch[0], in_.ch[1], in_.ch[2], in_.ch[3]);
        for (Link& l : links_) checkState(l);
      } else {
        const size_t len = std::min<size_t>(((op >> 2) & 15) + 1, n - i);
        const std::vector<uint8_t> raw(d + i, d + i + len);
        i += len;
        for (Link* l : targets(op)) deliver(*l, raw);
      }
    }
  }

  /// Releases the e-stop, resets every board and checks that nothing is left open.
  void finish() {
    in_.estop = false;
    for (Link& l : links_) {
      // Idle bytes first: a partial frame candidate left by garbage would swallow the reset.
      deliver(l, std::vector<uint8_t>(rp::kMaxFrameSize, 0));
      uint32_t seq = next_seq_++;
      while (l.remembered(seq, MsgId::kReset) || l.execs.count(key(seq, MsgId::kReset))) ++seq;
      const auto frame = rp::encodeCommand(l.board->board(), MsgId::kReset, seq);
      deliver(l, frame);
    }
    forced_tick_ = true;
    tick();
    for (Link& l : links_) {
      for (const auto& e : l.execs)
        FUZZ_CHECK(!e.second.open || e.second.ambiguous, "%s: %s seq %u still open after reset",
                   l.board_name, name(static_cast<MsgId>(e.first & 0xFF)),
                   static_cast<unsigned>(e.first >> 8));
    }
  }

 private:
  static rp::TrackDrvConfig trackConfig(int pulley) {
    rp::TrackDrvConfig c;
    const int teeth[4] = {20, 30, 36, 48};
    c.pulley_teeth = teeth[pulley];
    c.track_length_m = kTrackLengthM;
    // Fast homing and moves keep the board time an input needs short.
    c.max_speed_mps = kSpeedLimitMps;
    c.speed_limit_mps = kSpeedLimitMps;
    c.accel_mps2 = 1.0;
    c.accel_limit_mps2 = 2.0;
    c.home_speed_mps = kSpeedLimitMps;
    c.home_accel_mps2 = 1.0;
    c.home_search_m = 1.5;  // > track + the largest near sensor offset: homing always succeeds
    return c;
  }

  static void setLink(Link& l, Kind kind, rp::FirmwareBoard& board, Capture& out,
                      const char* board_name, int param_count) {
    l.kind = kind;
    l.board = &board;
    l.out = &out;
    l.board_name = board_name;
    l.param_count = param_count;
  }

  std::vector<Link*> targets(uint8_t op) {
    const int t = op & 3;
    if (t == 0) return {&links_[0], &links_[1], &links_[2]};
    return {&links_[t - 1]};
  }

  uint32_t boardMs() const { return static_cast<uint32_t>(t_us_ / 1000u); }

  void tick() {
    if (!forced_tick_ && (ticks_ >= kMaxTicks || t_us_ + tick_us_ > kMaxBoardTimeUs)) return;
    ++ticks_;
    t_us_ += tick_us_;
    update();
  }

  // Runs every board's loop at the harness time and checks what they did.
  void update() {
    const uint32_t now = static_cast<uint32_t>(kClockStart + t_us_);
    track_.update(now);
    car_.update(now);
    truck_.update(now);
    const int64_t steps = track_hw_.takeSteps();
    FUZZ_TRACE("%8.3f s  track state %d at %lld (board %d), %lld steps\n", t_us_ * 1e-6,
               static_cast<int>(track_.state()), static_cast<long long>(track_hw_.pos()),
               track_.positionSteps(), static_cast<long long>(steps));
    const double max_steps = kSpeedLimitMps * tick_us_ * 1e-6 / mps_ + 2;
    FUZZ_CHECK(std::fabs(static_cast<double>(steps)) <= max_steps,
               "%lld steps in a %u us tick (limit %.1f)", static_cast<long long>(steps), tick_us_,
               max_steps);
    for (Link& l : links_) {
      FUZZ_CHECK(std::fabs(l.board->timeSeconds() - t_us_ * 1e-6) < 1e-6,
                 "%s board time %.6f s, harness %.6f s", l.board_name, l.board->timeSeconds(),
                 t_us_ * 1e-6);
      const std::vector<rp::Frame> frames = l.out->take();
      checkTx(l, frames);
      int streams = 0;
      for (const rp::Frame& f : frames) {
        rp::Ack a;
        if (rp::decodePayload(f, a) == DecodeError::kNone) {
          onAck(l, a, false);
        } else {
          ++streams;
          checkStream(l, f);
        }
      }
      FUZZ_CHECK(streams <= 1, "%s sent %d stream frames in one tick", l.board_name, streams);
      // Frame n is due at n * 100 / 3 ms; with a loop faster than that none may be skipped.
      if (tick_us_ <= 33333)
        FUZZ_CHECK(l.streams == t_us_ * 3 / 100000 + 1, "%s: %llu stream frames by %.3f s",
                   l.board_name, static_cast<unsigned long long>(l.streams), t_us_ * 1e-6);
      checkState(l, true);
    }
  }

  // Frames written by a board: its id, consecutive frame numbers, valid typed payloads.
  void checkTx(Link& l, const std::vector<rp::Frame>& frames) {
    for (const rp::Frame& f : frames) {
      FUZZ_CHECK(f.board == l.board->board(), "%s wrote a frame as board %u", l.board_name,
                 static_cast<unsigned>(f.board));
      FUZZ_CHECK(f.seq == l.tx_seq, "%s frame counter %u, expected %u", l.board_name, f.seq,
                 l.tx_seq);
      ++l.tx_seq;
      DecodeError e = DecodeError::kWrongMessage;  // also for another board's stream
      switch (f.id) {
        case MsgId::kAck:
          e = decodeAs<rp::Ack>(f);
          break;
        case MsgId::kTrackState:
          if (l.kind == Kind::kTrack) e = decodeAs<rp::TrackStatePayload>(f);
          break;
        case MsgId::kCarSensors:
          if (l.kind == Kind::kCar) e = decodeAs<rp::CarSensorsPayload>(f);
          break;
        case MsgId::kTruckRc:
          if (l.kind == Kind::kTruck) e = decodeAs<rp::TruckRcPayload>(f);
          break;
        case MsgId::kVersionInfo:
          e = decodeAs<rp::VersionInfo>(f);
          break;
        case MsgId::kParamValue:
          e = decodeAs<rp::ParamValue>(f);
          break;
        case MsgId::kPong:
          e = decodeAs<rp::Pong>(f);
          break;
        default:
          break;
      }
      FUZZ_CHECK(e == DecodeError::kNone, "%s wrote %s: %s", l.board_name, name(f.id),
                 rp::errorName(e));
    }
  }

  // Hands bytes to a board, cut after every byte that completes a frame so that each command is
  // checked against the board state right after it (a byte that completes several frames after
  // a failed candidate delivers them together: then only the state-free checks apply).
  void deliver(Link& l, const std::vector<uint8_t>& bytes) {
    size_t from = 0;
    for (size_t i = 0; i < bytes.size(); ++i) {
      const auto events = rp::feed(l.mirror, &bytes[i], 1);
      int commands = 0;
      for (const auto& e : events)
        commands += e.error == DecodeError::kNone && e.frame.board == l.board->board() &&
                    static_cast<uint8_t>(e.frame.id) < 0x80;
      if (commands == 0 && i + 1 < bytes.size()) continue;
      l.board->receive(bytes.data() + from, i + 1 - from);
      from = i + 1;
      const std::vector<rp::Frame> resp = l.out->take();
      FUZZ_TRACE("%8.3f s  %s: %zu bytes in, %d commands, %zu frames out\n", t_us_ * 1e-6,
                 l.board_name, i + 1 - from, commands, resp.size());
      checkTx(l, resp);
      FUZZ_CHECK(l.board->rxStats().frames == l.mirror.stats().frames &&
                     l.board->rxStats().bad_crc == l.mirror.stats().bad_crc,
                 "%s decoded %u frames, the same bytes hold %u", l.board_name,
                 l.board->rxStats().frames, l.mirror.stats().frames);
      batched_ = commands > 1;
      size_t p = 0;
      for (const auto& e : events) {
        if (e.error != DecodeError::kNone) continue;
        const rp::Frame& c = e.frame;
        FUZZ_TRACE("%8.3f s  -> %s: %s seq %u (%u bytes, board %u)\n", t_us_ * 1e-6, l.board_name,
                   name(c.id), c.seq, c.length, static_cast<unsigned>(c.board));
        if (c.board != l.board->board() || static_cast<uint8_t>(c.id) >= 0x80) continue;
        answer(l, c, resp, p);
      }
      batched_ = false;
      FUZZ_CHECK(p == resp.size(), "%s wrote %zu frames nothing asked for (first %s)", l.board_name,
                 resp.size() - p, name(resp[p].id));
      checkState(l);
    }
  }

  // Consumes the answer to command c from resp[p...].
  void answer(Link& l, const rp::Frame& c, const std::vector<rp::Frame>& resp, size_t& p) {
    auto next = [&](const char* what) -> const rp::Frame& {
      FUZZ_CHECK(p < resp.size(), "%s: no %s in answer to %s seq %u", l.board_name, what,
                 name(c.id), c.seq);
      return resp[p++];
    };
    auto expectAck = [&](AckStatus want) {
      rp::Ack a;
      const DecodeError e = rp::decodePayload(next("ack"), a);
      FUZZ_CHECK(
          e == DecodeError::kNone && a.acked_seq == c.seq && a.acked_id == c.id && a.status == want,
          "%s: %s seq %u answered by %s (want ack %s)", l.board_name, name(c.id), c.seq,
          name(resp[p - 1].id), name(want));
    };
    switch (c.id) {
      case MsgId::kPing: {
        rp::CmdPing ping;
        if (rp::decodePayload(c, ping) != DecodeError::kNone) {
          expectAck(AckStatus::kBadArgument);
          return;
        }
        rp::Pong pong;
        FUZZ_CHECK(rp::decodePayload(next("pong"), pong) == DecodeError::kNone &&
                       pong.host_time_ms == ping.host_time_ms && pong.board_time_ms == boardMs(),
                   "%s: ping %u answered by %s (%u, %u)", l.board_name, ping.host_time_ms,
                   name(resp[p - 1].id), pong.host_time_ms, pong.board_time_ms);
        return;
      }
      case MsgId::kVers: {
        rp::VersionInfo v;
        FUZZ_CHECK(rp::decodePayload(next("version"), v) == DecodeError::kNone &&
                       std::strcmp(v.name, l.board_name) == 0 &&
                       v.protocol == rp::kProtocolVersion && v.major == rp::kFirmwareMajor,
                   "%s: vers answered by %s '%s'", l.board_name, name(resp[p - 1].id), v.name);
        expectAck(AckStatus::kDone);
        return;
      }
      case MsgId::kPara: {
        for (int k = 0; k < l.param_count; ++k) {
          rp::ParamValue v;
          FUZZ_CHECK(rp::decodePayload(next("parameter"), v) == DecodeError::kNone &&
                         v.index == k && v.count == l.param_count,
                     "%s: para item %d is %s %u/%u", l.board_name, k, name(resp[p - 1].id), v.index,
                     v.count);
        }
        expectAck(AckStatus::kDone);
        return;
      }
      default:
        break;
    }
    if (const Remembered* r = l.remembered(c.seq, c.id)) {
      expectAck(r->status);  // a retransmission: the latest answer again, nothing else
      return;
    }
    l.remember(c.seq, c.id);
    Exec& x = l.execs[key(c.seq, c.id)];
    const bool ambiguous = x.open || x.ambiguous;  // an earlier run of this seq/id still open
    x = Exec();
    x.ambiguous = ambiguous;
    x.t_accept_us = t_us_;
    rp::CmdWait w;
    if (rp::decodePayload(c, w) == DecodeError::kNone) x.wait_ms = w.wait_ms;
    x.track_move = l.kind == Kind::kTrack && rp::decodePayload(c, x.move) == DecodeError::kNone;
    // CarDRV mode 2: one move at a time.
    rp::CmdServo s;
    const bool must_be_busy = !batched_ && l.kind == Kind::kCar && c.id == MsgId::kServo &&
                              rp::decodePayload(c, s) == DecodeError::kNone &&
                              l.board->mode() == 2 && l.openCount(isMove) > 0;
    int own = 0;
    bool own_final = false;
    while (p < resp.size()) {
      rp::Ack a;
      if (rp::decodePayload(resp[p], a) != DecodeError::kNone) break;
      if (a.acked_seq == c.seq && a.acked_id == c.id) {
        // after a final ack, or a second "accepted", it is a repeat's answer in the same batch
        if (own > 0 && (own_final || a.status == AckStatus::kAccepted)) break;
        own_final = a.status != AckStatus::kAccepted;
        if (own == 0 && must_be_busy && !ambiguous)
          FUZZ_CHECK(a.status == AckStatus::kBusy, "CarDRV mode 2: demand during a move got %s",
                     name(a.status));
        onAck(l, a, true);
        ++own;
      } else {
        // a command this one ended (superseded, stopped, reset)
        auto it = l.execs.find(key(a.acked_seq, a.acked_id));
        if (it == l.execs.end() || !it->second.open || a.status == AckStatus::kAccepted) break;
        onAck(l, a, false);
      }
      ++p;
    }
    FUZZ_CHECK(own >= 1, "%s: no ack for %s seq %u", l.board_name, name(c.id), c.seq);
    const Exec& done = l.execs[key(c.seq, c.id)];
    const bool may_stay_open = c.id == MsgId::kWait ||
                               (l.kind == Kind::kTrack && (isMove(c.id) || isStop(c.id))) ||
                               (l.kind == Kind::kCar && isMove(c.id));
    FUZZ_CHECK(!done.open || done.ambiguous || may_stay_open, "%s: %s seq %u left open",
               l.board_name, name(c.id), c.seq);
    FUZZ_CHECK(l.openCount(isMove) <= 1 && l.openCount(isStop) <= 1 &&
                   l.openCount([](MsgId id) { return id == MsgId::kWait; }) <= 1,
               "%s: %d moves, %d stops, %d waits open after %s seq %u", l.board_name,
               l.openCount(isMove), l.openCount(isStop),
               l.openCount([](MsgId id) { return id == MsgId::kWait; }), name(c.id), c.seq);
  }

  // An ack seen on the link; `own_answer` = part of the answer to its own command.
  void onAck(Link& l, const rp::Ack& a, bool own_answer) {
    FUZZ_TRACE("%8.3f s  <- %s: ack %s seq %u %s\n", t_us_ * 1e-6, l.board_name, name(a.acked_id),
               a.acked_seq, name(a.status));
    auto it = l.execs.find(key(a.acked_seq, a.acked_id));
    FUZZ_CHECK(it != l.execs.end(), "%s: ack %s for %s seq %u, never sent", l.board_name,
               name(a.status), name(a.acked_id), a.acked_seq);
    if (Remembered* r = l.remembered(a.acked_seq, a.acked_id)) r->status = a.status;
    Exec& x = it->second;
    if (x.ambiguous) {
      if (l.kind == Kind::kTrack) commanded_known_ = false;  // it may have moved the base
      return;
    }
    if (a.status == AckStatus::kAccepted) {
      FUZZ_CHECK(own_answer && !x.answered, "%s: %s seq %u accepted %s", l.board_name,
                 name(a.acked_id), a.acked_seq, x.answered ? "again" : "after its answer");
      x.answered = true;
      x.open = true;
      if (x.track_move) {
        // Relative targets add to the last commanded position (track_drv.hpp), not to the
        // rounded step count: the model keeps that position from what the board acknowledged.
        const bool rel = (x.move.flags & rp::CmdTrackMove::kRelative) != 0;
        const double target_m = (rel ? commanded_m_ : 0.0) + x.move.target_um * 1e-6;
        x.has_target = !rel || commanded_known_;
        x.target_steps = std::llround(target_m / mps_);
        commanded_m_ = target_m;
      }
      return;
    }
    FUZZ_CHECK(x.open || (own_answer && !x.answered), "%s: second final ack %s for %s seq %u",
               l.board_name, name(a.status), name(a.acked_id), a.acked_seq);
    const bool was_open = x.open;
    x.answered = true;
    x.open = false;
    checkFinal(l, a, x, was_open);
  }

  // `was_open`: it had been accepted before this final ack.
  void checkFinal(Link& l, const rp::Ack& a, const Exec& x, bool was_open) {
    const MsgId id = a.acked_id;
    const bool done = a.status == AckStatus::kDone;
    if (id == MsgId::kWait && done) {
      const uint64_t due = x.t_accept_us + uint64_t{x.wait_ms} * 1000u;
      // done in the first loop tick at or after its time (and after the one that accepted it)
      const uint64_t prev_tick = t_us_ - tick_us_;
      FUZZ_CHECK(t_us_ >= due && (prev_tick < due || prev_tick == x.t_accept_us),
                 "%s: wait of %u ms done after %.3f s", l.board_name, x.wait_ms,
                 (t_us_ - x.t_accept_us) * 1e-6);
    }
    if (l.kind == Kind::kCar && isMove(id) && done)
      FUZZ_CHECK(t_us_ - x.t_accept_us >= static_cast<uint64_t>(car_cfg_.settle_s * 1e6),
                 "servo move done %.3f s after its start, settle time %.3f s",
                 (t_us_ - x.t_accept_us) * 1e-6, car_cfg_.settle_s);
    if (l.kind == Kind::kTruck && done) {
      if (isStop(id)) l.host_stopped = true;
      if (id == MsgId::kInit || id == MsgId::kStart || id == MsgId::kReset) l.host_stopped = false;
    }
    if (l.kind != Kind::kTrack) return;
    const int64_t pos = track_hw_.pos();  // steps happen in update() only, not in a batch
    // A move cut short (end of track, e-stop) or a stop that ended a motion leaves the commanded
    // position where the carriage is; homing sets it to zero.
    const bool init_done = id == MsgId::kInit && done;
    if ((isMove(id) && (a.status == AckStatus::kEndOfTrack || a.status == AckStatus::kEStop)) ||
        (isStop(id) && was_open && (done || a.status == AckStatus::kEStop)))
      commanded_m_ = pos * mps_;
    if (init_done) {
      commanded_m_ = 0;
      commanded_known_ = true;
    }
    if (batched_) return;  // below: the board state right after this command
    FUZZ_CHECK(!(id == MsgId::kInit && a.status == AckStatus::kFailed),
               "homing failed with the far sensor within reach (carriage at %lld)",
               static_cast<long long>(pos));
    if (init_done)
      FUZZ_CHECK(pos == 0 && track_.positionSteps() == 0 && track_.homed(),
                 "init done with the carriage at %lld, board at %d", static_cast<long long>(pos),
                 track_.positionSteps());
    if (id == MsgId::kTrackMove && done && x.has_target)
      FUZZ_CHECK(pos == x.target_steps, "%s move to %lld done at %lld",
                 (x.move.flags & rp::CmdTrackMove::kRelative) ? "relative" : "absolute",
                 static_cast<long long>(x.target_steps), static_cast<long long>(pos));
    if (a.status == AckStatus::kEndOfTrack)
      FUZZ_CHECK(pos <= 0 || pos >= track_hw_.near(), "end of track at %lld (sensors 0, %lld)",
                 static_cast<long long>(pos), static_cast<long long>(track_hw_.near()));
    if (a.status == AckStatus::kEStop)
      FUZZ_CHECK(in_.estop || track_.state() == TrackStateCode::kEStop,
                 "%s aborted by an e-stop that is not there (state %d)", name(id),
                 static_cast<int>(track_.state()));
  }

  void checkStream(Link& l, const rp::Frame& f) {
    uint32_t board_ms = 0;
    if (l.kind == Kind::kTrack) {
      rp::TrackStatePayload s;
      FUZZ_CHECK(rp::decodePayload(f, s) == DecodeError::kNone, "track streamed %s", name(f.id));
      board_ms = s.board_time_ms;
      const uint8_t flags = (track_hw_.nearSensor() ? rp::TrackStatePayload::kNearSensor : 0) |
                            (track_hw_.farSensor() ? rp::TrackStatePayload::kFarSensor : 0) |
                            (track_.homed() ? rp::TrackStatePayload::kHomed : 0);
      FUZZ_CHECK(s.pos_steps == track_.positionSteps() && s.state == track_.state() &&
                     s.mode == track_.mode() &&
                     (s.flags & ~rp::TrackStatePayload::kEStopFlag) == flags &&
                     ((s.flags & rp::TrackStatePayload::kEStopFlag) != 0) ==
                         (in_.estop || track_.state() == TrackStateCode::kEStop) &&
                     s.pos_um == std::lround(track_.positionSteps() * mps_ * 1e6),
                 "track stream (pos %d state %d flags %x) differs from the board", s.pos_steps,
                 static_cast<int>(s.state), s.flags);
    } else if (l.kind == Kind::kCar) {
      rp::CarSensorsPayload s;
      FUZZ_CHECK(rp::decodePayload(f, s) == DecodeError::kNone, "car streamed %s", name(f.id));
      board_ms = s.board_time_ms;
      FUZZ_CHECK(s.pitch_dem_cdeg == std::lround(car_.pitchDemandDeg() * 100) &&
                     s.yaw_dem_cdeg == std::lround(car_.yawDemandDeg() * 100) &&
                     ((s.flags & rp::CarSensorsPayload::kTofValid) != 0) == in_.tof_ok,
                 "car stream (demand %d %d) differs from the board", s.pitch_dem_cdeg,
                 s.yaw_dem_cdeg);
    } else {
      rp::TruckRcPayload s;
      FUZZ_CHECK(rp::decodePayload(f, s) == DecodeError::kNone, "truck streamed %s", name(f.id));
      board_ms = s.board_time_ms;
      const uint8_t flags = (truck_.running() ? rp::TruckRcPayload::kRunning : 0) |
                            (truck_.recording() ? rp::TruckRcPayload::kRecording : 0) |
                            (truck_.signalOk() ? rp::TruckRcPayload::kSignalOk : 0);
      const double motor = truck_.motorCommand();
      FUZZ_CHECK(s.ch2_us == in_.ch[0] && s.ch3_us == in_.ch[1] && s.ch5_us == in_.ch[2] &&
                     s.ch7_us == in_.ch[3] && s.flags == flags,
                 "truck stream (ch %u %u %u %u flags %x) differs from the board", s.ch2_us,
                 s.ch3_us, s.ch5_us, s.ch7_us, s.flags);
      // The speed estimate has the motor's sign, is zero with the motor off, and stays within
      // the speed curve.
      const double v_max_mm_s = truck_cfg_.speed_curve.y(truck_cfg_.speed_curve.size() - 1) * 1e3;
      FUZZ_CHECK((motor == 0 && s.speed_mm_s == 0) ||
                     (motor > 0 && s.speed_mm_s >= 0 && s.speed_mm_s <= v_max_mm_s + 0.5) ||
                     (motor < 0 && s.speed_mm_s <= 0 && s.speed_mm_s >= -v_max_mm_s - 0.5),
                 "truck speed %d mm/s for motor %g", s.speed_mm_s, motor);
    }
    FUZZ_CHECK(board_ms == boardMs(), "%s stream at %u ms, board time %u ms", l.board_name,
               board_ms, boardMs());
    ++l.streams;
    FUZZ_CHECK(l.streams <= t_us_ * 3 / 100000 + 1, "%s: %llu stream frames by %.3f s",
               l.board_name, static_cast<unsigned long long>(l.streams), t_us_ * 1e-6);
  }

  // `updated`: right after update(), when the outputs reflect the current inputs.
  void checkState(Link& l, bool updated = false) {
    if (l.kind == Kind::kTrack) {
      const TrackStateCode s = track_.state();
      if (track_.homed())
        FUZZ_CHECK(track_.positionSteps() == track_hw_.pos(),
                   "homed board at %d steps, carriage at %lld", track_.positionSteps(),
                   static_cast<long long>(track_hw_.pos()));
      FUZZ_CHECK(s != TrackStateCode::kReady || track_.homed(), "ready without homing");
      const bool motion = s == TrackStateCode::kHoming || s == TrackStateCode::kMoving;
      FUZZ_CHECK(!motion || track_hw_.motorOn(), "state %d with the motor disabled",
                 static_cast<int>(s));
      if (!l.hasAmbiguous())
        FUZZ_CHECK(motion == (l.openCount(isMove) + l.openCount(isStop) > 0),
                   "state %d with %d moves and %d stops open", static_cast<int>(s),
                   l.openCount(isMove), l.openCount(isStop));
    } else if (l.kind == Kind::kCar) {
      FUZZ_CHECK(car_.pitchDemandDeg() >= car_cfg_.pitch.min_deg &&
                     car_.pitchDemandDeg() <= car_cfg_.pitch.max_deg &&
                     car_.yawDemandDeg() >= car_cfg_.yaw.min_deg &&
                     car_.yawDemandDeg() <= car_cfg_.yaw.max_deg,
                 "demand %.2f %.2f deg outside the limits", car_.pitchDemandDeg(),
                 car_.yawDemandDeg());
    } else {
      const double motor = truck_.motorCommand();
      FUZZ_CHECK(truck_hw_.motor == motor, "motor %g, board says %g", truck_hw_.motor, motor);
      if (l.host_stopped) FUZZ_CHECK(motor == 0, "motor %g after a host stop", motor);
      if (!updated) return;
      if (!truck_.signalOk() || !truck_.running())
        FUZZ_CHECK(motor == 0, "motor %g without signal or with CH5 off", motor);
      if (!truck_.signalOk()) FUZZ_CHECK(truck_hw_.steering == 0, "steering without signal");
      if (motor != 0)
        FUZZ_CHECK((motor > 0) == (in_.ch[1] > truck_cfg_.center_us), "motor %g for CH3 %u us",
                   motor, in_.ch[1]);
    }
  }

  Inputs in_;
  rp::TrackDrvConfig track_cfg_;
  rp::CarDrvConfig car_cfg_;
  rp::TruckDrvConfig truck_cfg_;
  uint32_t tick_us_;
  double mps_;
  int64_t near_steps_;
  SimTrack track_hw_;
  SimCar car_hw_;
  SimTruck truck_hw_;
  rp::TrackDrv track_;
  rp::CarDrv car_;
  rp::TruckDrv truck_;
  std::array<Link, 3> links_;
  uint64_t t_us_ = 0;
  int ticks_ = 0;
  bool forced_tick_ = false;
  bool batched_ = false;          ///< several commands arrived in one receive()
  double commanded_m_ = 0;        ///< track: base of relative moves (model)
  bool commanded_known_ = false;  ///< ... valid since an init done
  uint32_t next_seq_ = 1;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  uint8_t header[4] = {0x24, 0, 0x80, 0};  // defaults: 20 teeth, 10 ms ticks, carriage mid-track
  const size_t h = size < 4 ? size : 4;
  std::memcpy(header, data, h);
  Rig rig(header);
  rig.run(data + h, size - h);
  rig.finish();
  return 0;
}
