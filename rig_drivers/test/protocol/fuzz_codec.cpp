// libFuzzer target for the rig serial codec (built by scripts/run_codec_fuzz.sh with clang).
// Properties checked on arbitrary input, fed in input-chosen chunk sizes:
//  - no crash / sanitizer report;
//  - every frame the decoder returns re-encodes to bytes that occur verbatim in the input;
//  - every payload that decodes re-encodes to the identical payload bytes;
//  - chunking does not change the result (same frames as feeding everything at once);
//  - the three firmware boards take the same bytes as host commands without crashing, every
//    frame they answer with decodes, and the track never steps outside its travel.
#include <algorithm>
#include <cstdlib>
#include <string>
#include <vector>

#include "rig_drivers/protocol/car_drv.hpp"
#include "rig_drivers/protocol/codec.hpp"
#include "rig_drivers/protocol/track_drv.hpp"
#include "rig_drivers/protocol/truck_drv.hpp"

namespace rp = rig_drivers::protocol;

namespace {

void check(bool ok) {
  if (!ok) std::abort();
}

template <class P>
void payloadRoundTrip(const rp::Frame& f) {
  P p;
  if (rp::decodePayload(f, p) != rp::DecodeError::kNone) return;
  uint8_t buf[P::kSize];
  p.encode(buf);
  check(f.length == P::kSize);
  for (size_t i = 0; i < P::kSize; ++i) check(buf[i] == f.payload[i]);
}

void checkFrame(const rp::Frame& f, const uint8_t* data, size_t n) {
  const auto bytes = rp::frameBytes(f);
  check(!bytes.empty());
  const std::string hay(reinterpret_cast<const char*>(data), n);
  const std::string needle(bytes.begin(), bytes.end());
  check(hay.find(needle) != std::string::npos);
  payloadRoundTrip<rp::CmdMode>(f);
  payloadRoundTrip<rp::CmdTrackMove>(f);
  payloadRoundTrip<rp::CmdServo>(f);
  payloadRoundTrip<rp::CmdPing>(f);
  payloadRoundTrip<rp::CmdWait>(f);
  payloadRoundTrip<rp::Ack>(f);
  payloadRoundTrip<rp::TrackStatePayload>(f);
  payloadRoundTrip<rp::CarSensorsPayload>(f);
  payloadRoundTrip<rp::TruckRcPayload>(f);
  payloadRoundTrip<rp::VersionInfo>(f);
  payloadRoundTrip<rp::ParamValue>(f);
  payloadRoundTrip<rp::Pong>(f);
}

// Hardware stubs: sensors from the fuzz input, outputs checked for sanity.
struct NullTrack : rp::TrackHardware {
  void step(int dir) override {
    check(dir == 1 || dir == -1);
    pos += dir;
  }
  bool farSensor() override { return pos <= -1000; }
  bool nearSensor() override { return false; }
  bool estopPressed() override { return estop; }
  void write(const uint8_t* d, size_t n) override { sink(d, n); }
  void sink(const uint8_t* d, size_t n) {
    for (const auto& e : rp::feed(dec, d, n)) check(e.error == rp::DecodeError::kNone);
  }
  int64_t pos = 0;
  bool estop = false;
  rp::StreamDecoder dec;
};
struct NullCar : rp::CarHardware {
  void setServoPulse(rp::GimbalAxis, double us) override { check(us >= 500 && us <= 2500); }
  int readAdc(rp::GimbalAxis) override { return adc; }
  bool readImu(int16_t raw[3]) override {
    raw[0] = raw[1] = raw[2] = static_cast<int16_t>(adc * 64);
    return true;
  }
  bool readTof(uint16_t& mm) override {
    mm = static_cast<uint16_t>(adc * 60);
    return true;
  }
  void write(const uint8_t* d, size_t n) override {
    for (const auto& e : rp::feed(dec, d, n)) check(e.error == rp::DecodeError::kNone);
  }
  int adc = 512;
  rp::StreamDecoder dec;
};
struct NullTruck : rp::TruckHardware {
  uint16_t pulseUs(rp::RcChannel) override { return pulse; }
  void setMotor(double c) override { check(c >= -1 && c <= 1); }
  void setSteering(double c) override { check(c >= -1 && c <= 1); }
  void write(const uint8_t* d, size_t n) override {
    for (const auto& e : rp::feed(dec, d, n)) check(e.error == rp::DecodeError::kNone);
  }
  uint16_t pulse = 1500;
  rp::StreamDecoder dec;
};

// Re-addresses every decoded command frame to each board in turn so all three see commands.
void driveBoards(const std::vector<rp::DecodeEvent>& events, const uint8_t* data, size_t n) {
  rp::TrackDrvConfig tc;
  tc.home_speed_mps = 0.3;  // fast homing keeps the runs short
  tc.max_speed_mps = 0.3;
  NullTrack th;
  rp::TrackDrv track(tc, th);
  NullCar ch;
  rp::CarDrv car(rp::CarDrvConfig::defaults(), ch);
  NullTruck uh;
  rp::TruckDrv truck(rp::TruckDrvConfig::defaults(), uh);
  rp::FirmwareBoard* boards[3] = {&track, &car, &truck};
  uint32_t now = 0xFFFF0000u;  // cross the 32-bit micros() wrap during the run
  size_t k = 0;
  for (const auto& e : events) {
    if (e.error != rp::DecodeError::kNone) continue;
    const uint8_t knob = n > 0 ? data[k++ % n] : 0;
    th.estop = (knob & 0xF0) == 0xF0;
    ch.adc = knob * 4;
    uh.pulse = static_cast<uint16_t>(900 + knob * 5);
    for (auto* b : boards) {
      uint8_t buf[rp::kMaxFrameSize];
      const size_t m = rp::encodeFrame(b->board(), e.frame.id, e.frame.seq, e.frame.payload,
                                       e.frame.length, buf, sizeof buf);
      b->receive(buf, m);
    }
    // let the boards run for up to 15 s of board time in 10 ms ticks
    const int ticks = 1 + (knob & 0x0F) * 100;
    for (int t = 0; t < ticks; ++t) {
      now += 10000;
      for (auto* b : boards) b->update(now);
    }
    const int64_t track_steps = static_cast<int64_t>(tc.track_length_m / tc.metresPerStep()) + 1;
    check(track.positionSteps() >= -track_steps && track.positionSteps() <= track_steps + 1000);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  // First byte: bits 0-4 choose the chunk size of the streamed feed (1..32 bytes); bit 7 selects
  // structured mode, where the rest is read as records [id, length, payload...] that are encoded
  // as valid frames (so the boards see every command with any payload despite the CRC), with a
  // garbage byte between records when bit 6 is set.
  const size_t chunk = 1 + (data[0] & 31);
  std::vector<uint8_t> built;
  if (data[0] & 0x80) {
    uint32_t seq = 1;
    for (size_t i = 1; i + 1 < size;) {
      const uint8_t id = data[i];
      const size_t len = std::min<size_t>(data[i + 1] % (rp::kMaxPayload + 1), size - i - 2);
      uint8_t buf[rp::kMaxFrameSize];
      const size_t m = rp::encodeFrame(rp::BoardId::kTrack, static_cast<rp::MsgId>(id), seq++,
                                       data + i + 2, len, buf, sizeof buf);
      built.insert(built.end(), buf, buf + m);
      if (data[0] & 0x40) built.push_back(id);
      i += 2 + len;
    }
  } else {
    built.assign(data + 1, data + size);
  }
  const uint8_t* stream = built.data();
  const size_t n = built.size();

  rp::StreamDecoder whole;
  const auto ev_whole = rp::feed(whole, stream, n);

  rp::StreamDecoder split;
  std::vector<rp::DecodeEvent> ev_split;
  for (size_t pos = 0; pos < n; pos += chunk) {
    const size_t m = pos + chunk <= n ? chunk : n - pos;
    auto ev = rp::feed(split, stream + pos, m);
    ev_split.insert(ev_split.end(), ev.begin(), ev.end());
  }
  check(ev_whole.size() == ev_split.size());
  for (size_t i = 0; i < ev_whole.size(); ++i) {
    check(ev_whole[i].error == ev_split[i].error);
    if (ev_whole[i].error != rp::DecodeError::kNone) continue;
    check(rp::frameBytes(ev_whole[i].frame) == rp::frameBytes(ev_split[i].frame));
    checkFrame(ev_whole[i].frame, stream, n);
  }
  check(whole.pending() == split.pending());
  check(whole.pending() < rp::kMaxFrameSize);
  // Boards run only on structured inputs so raw-mode inputs keep the codec fuzzing fast.
  if (data[0] & 0x80) driveBoards(ev_whole, stream, n);
  return 0;
}
