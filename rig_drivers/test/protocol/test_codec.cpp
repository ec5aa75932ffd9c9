#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <string>

#include "rig_drivers/protocol/codec.hpp"

namespace rp = rig_drivers::protocol;
using rp::BoardId;
using rp::DecodeError;
using rp::MsgId;

namespace {

std::vector<rp::Frame> framesOf(const std::vector<rp::DecodeEvent>& ev) {
  std::vector<rp::Frame> out;
  for (const auto& e : ev)
    if (e.error == DecodeError::kNone) out.push_back(e.frame);
  return out;
}

size_t countErrors(const std::vector<rp::DecodeEvent>& ev, DecodeError err) {
  size_t n = 0;
  for (const auto& e : ev) n += e.error == err;
  return n;
}

// Encodes p, decodes it through the stream decoder and the typed payload decoder.
template <class P>
P roundTrip(const P& p, BoardId board, uint32_t seq) {
  const auto bytes = rp::encodeMessage(board, seq, p);
  EXPECT_EQ(bytes.size(), rp::kHeaderSize + P::kSize + rp::kCrcSize);
  rp::StreamDecoder dec;
  const auto frames = framesOf(rp::feed(dec, bytes));
  EXPECT_EQ(frames.size(), 1u);
  P out;
  if (frames.size() != 1) return out;
  EXPECT_EQ(frames[0].board, board);
  EXPECT_EQ(frames[0].id, P::kId);
  EXPECT_EQ(frames[0].seq, seq);
  EXPECT_EQ(frames[0].version, rp::kProtocolVersion);
  EXPECT_EQ(rp::decodePayload(frames[0], out), DecodeError::kNone);
  EXPECT_EQ(rp::frameBytes(frames[0]), bytes);
  return out;
}

std::vector<uint8_t> trackStateFrame(uint32_t seq, int32_t pos_um) {
  rp::TrackStatePayload s;
  s.board_time_ms = seq * 33;
  s.pos_um = pos_um;
  s.pos_steps = pos_um * 10 / 186;
  s.state = rp::TrackStateCode::kMoving;
  s.flags = rp::TrackStatePayload::kHomed;
  return rp::encodeMessage(BoardId::kTrack, seq, s);
}

}  // namespace

TEST(Crc16, CcittFalseCheckValue) {
  const char* s = "123456789";
  EXPECT_EQ(rp::crc16(reinterpret_cast<const uint8_t*>(s), 9), 0x29B1);
}

TEST(Codec, FrameLayoutIsAsDocumented) {
  rp::CmdMode m;
  m.mode = 2;
  const auto b = rp::encodeMessage(BoardId::kTrack, 0x01020304u, m);
  ASSERT_EQ(b.size(), 13u);
  EXPECT_EQ(b[0], 0xA5);
  EXPECT_EQ(b[1], 0x5A);
  EXPECT_EQ(b[2], 1);  // payload length
  EXPECT_EQ(b[3], rp::kProtocolVersion);
  EXPECT_EQ(b[4], 1);     // board
  EXPECT_EQ(b[5], 0x02);  // mode
  EXPECT_EQ(b[6], 0x04);  // seq, little endian
  EXPECT_EQ(b[9], 0x01);
  EXPECT_EQ(b[10], 2);
  const uint16_t crc = rp::crc16(b.data() + 2, 9);
  EXPECT_EQ(b[11], crc & 0xFF);
  EXPECT_EQ(b[12], crc >> 8);
}

TEST(Codec, RoundTripEveryMessage) {
  for (MsgId id : {MsgId::kInit, MsgId::kStart, MsgId::kStop, MsgId::kReset, MsgId::kEnd,
                   MsgId::kVers, MsgId::kPara}) {
    const auto b = rp::encodeCommand(BoardId::kCar, id, 77);
    rp::StreamDecoder dec;
    const auto f = framesOf(rp::feed(dec, b));
    ASSERT_EQ(f.size(), 1u) << rp::msgName(id);
    EXPECT_EQ(f[0].id, id);
    EXPECT_EQ(f[0].length, 0);
    EXPECT_EQ(f[0].seq, 77u);
  }
  {
    rp::CmdMode m;
    m.mode = 2;
    EXPECT_EQ(roundTrip(m, BoardId::kTrack, 1).mode, 2);
  }
  {
    rp::CmdTrackMove m;
    m.target_um = -123456;
    m.flags = rp::CmdTrackMove::kRelative;
    m.max_speed_mm_s = 200;
    m.accel_mm_s2 = 400;
    const auto r = roundTrip(m, BoardId::kTrack, 2);
    EXPECT_EQ(r.target_um, -123456);
    EXPECT_EQ(r.flags, rp::CmdTrackMove::kRelative);
    EXPECT_EQ(r.max_speed_mm_s, 200);
    EXPECT_EQ(r.accel_mm_s2, 400);
  }
  {
    rp::CmdServo m;
    m.pitch_cdeg = -2000;
    m.yaw_cdeg = 1550;
    const auto r = roundTrip(m, BoardId::kCar, 3);
    EXPECT_EQ(r.pitch_cdeg, -2000);
    EXPECT_EQ(r.yaw_cdeg, 1550);
    EXPECT_EQ(r.flags, 0);
  }
  {
    rp::CmdPing m;
    m.host_time_ms = 0xDEADBEEF;
    EXPECT_EQ(roundTrip(m, BoardId::kCar, 4).host_time_ms, 0xDEADBEEFu);
  }
  {
    rp::CmdWait m;
    m.wait_ms = 1500;
    EXPECT_EQ(roundTrip(m, BoardId::kTrack, 5).wait_ms, 1500u);
  }
  {
    rp::Ack m;
    m.acked_seq = 4000000000u;
    m.acked_id = MsgId::kTrackMove;
    m.status = rp::AckStatus::kEndOfTrack;
    const auto r = roundTrip(m, BoardId::kTrack, 6);
    EXPECT_EQ(r.acked_seq, 4000000000u);
    EXPECT_EQ(r.acked_id, MsgId::kTrackMove);
    EXPECT_EQ(r.status, rp::AckStatus::kEndOfTrack);
  }
  {
    rp::TrackStatePayload m;
    m.board_time_ms = 123456;
    m.pos_steps = 53763;
    m.pos_um = 1000000;
    m.vel_um_s = -95000;
    m.state = rp::TrackStateCode::kEndOfTrack;
    m.flags = rp::TrackStatePayload::kNearSensor | rp::TrackStatePayload::kHomed;
    m.mode = 2;
    const auto r = roundTrip(m, BoardId::kTrack, 7);
    EXPECT_EQ(r.board_time_ms, 123456u);
    EXPECT_EQ(r.pos_steps, 53763);
    EXPECT_EQ(r.pos_um, 1000000);
    EXPECT_EQ(r.vel_um_s, -95000);
    EXPECT_EQ(r.state, rp::TrackStateCode::kEndOfTrack);
    EXPECT_EQ(r.flags, m.flags);
    EXPECT_EQ(r.mode, 2);
  }
  {
    rp::CarSensorsPayload m;
    m.board_time_ms = 99;
    m.pitch_dem_cdeg = 1000;
    m.pitch_cdeg = 968;
    m.yaw_dem_cdeg = -500;
    m.yaw_cdeg = -576;
    m.acc_x_mg = -12;
    m.acc_y_mg = -1003;
    m.acc_z_mg = 45;
    m.tof_mm = 1234;
    m.flags = rp::CarSensorsPayload::kTofValid;
    const auto r = roundTrip(m, BoardId::kCar, 8);
    EXPECT_EQ(r.pitch_dem_cdeg, 1000);
    EXPECT_EQ(r.pitch_cdeg, 968);
    EXPECT_EQ(r.yaw_dem_cdeg, -500);
    EXPECT_EQ(r.yaw_cdeg, -576);
    EXPECT_EQ(r.acc_x_mg, -12);
    EXPECT_EQ(r.acc_y_mg, -1003);
    EXPECT_EQ(r.acc_z_mg, 45);
    EXPECT_EQ(r.tof_mm, 1234);
    EXPECT_EQ(r.flags, m.flags);
  }
  {
    rp::TruckRcPayload m;
    m.board_time_ms = 5;
    m.ch2_us = 1400;
    m.ch3_us = 1800;
    m.ch5_us = 1900;
    m.ch7_us = 1100;
    m.steering_permille = -200;
    m.speed_permille = 600;
    m.speed_mm_s = 1234;
    m.flags = rp::TruckRcPayload::kRunning | rp::TruckRcPayload::kSignalOk;
    const auto r = roundTrip(m, BoardId::kTruck, 9);
    EXPECT_EQ(r.ch2_us, 1400);
    EXPECT_EQ(r.ch3_us, 1800);
    EXPECT_EQ(r.ch5_us, 1900);
    EXPECT_EQ(r.ch7_us, 1100);
    EXPECT_EQ(r.steering_permille, -200);
    EXPECT_EQ(r.speed_permille, 600);
    EXPECT_EQ(r.speed_mm_s, 1234);
    EXPECT_EQ(r.flags, m.flags);
  }
  {
    rp::VersionInfo m;
    m.major = 1;
    m.minor = 2;
    m.patch = 3;
    m.setName("TrackDRV-with-a-too-long-name");
    const auto r = roundTrip(m, BoardId::kTrack, 10);
    EXPECT_EQ(r.major, 1);
    EXPECT_EQ(r.minor, 2);
    EXPECT_EQ(r.patch, 3);
    EXPECT_EQ(r.protocol, rp::kProtocolVersion);
    EXPECT_EQ(std::string(r.name), "TrackDRV-with-a-");  // clipped to kNameLen
  }
  {
    rp::ParamValue m;
    m.index = 1;
    m.count = 5;
    m.mantissa = 186;
    m.exp10 = -4;
    m.setName("m_per_step");
    const auto r = roundTrip(m, BoardId::kTrack, 11);
    EXPECT_EQ(std::string(r.name), "m_per_step");
    EXPECT_DOUBLE_EQ(r.value(), 0.0186);
    EXPECT_EQ(r.index, 1);
    EXPECT_EQ(r.count, 5);
  }
  {
    rp::Pong m;
    m.host_time_ms = 42;
    m.board_time_ms = 4242;
    const auto r = roundTrip(m, BoardId::kCar, 12);
    EXPECT_EQ(r.host_time_ms, 42u);
    EXPECT_EQ(r.board_time_ms, 4242u);
  }
}

TEST(Codec, GarbagePrefixIsSkipped) {
  std::vector<uint8_t> bytes = {0x00, 0xA5, 0xA5, 0x13, 0x5A, 0xFF, 0xA5};
  const size_t garbage = bytes.size();
  const auto f1 = trackStateFrame(1, 1000);
  bytes.insert(bytes.end(), f1.begin(), f1.end());
  rp::StreamDecoder dec;
  const auto ev = rp::feed(dec, bytes);
  const auto frames = framesOf(ev);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].seq, 1u);
  EXPECT_EQ(dec.stats().bytes_discarded, garbage);
  EXPECT_EQ(dec.pending(), 0u);
}

TEST(Codec, RandomGarbageBetweenFramesLosesNoFrame) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255), gap(0, 40);
  std::vector<uint8_t> bytes;
  const int n = 200;
  for (int i = 0; i < n; ++i) {
    for (int g = gap(rng); g > 0; --g) {
      // Garbage that never contains a sync pair cannot open a false candidate that swallows
      // the next frame; sync-rich garbage is covered by the bad-CRC/fuzz tests.
      uint8_t b = static_cast<uint8_t>(byte(rng));
      bytes.push_back(b == rp::kSync0 ? 0 : b);
    }
    const auto f = trackStateFrame(static_cast<uint32_t>(i), i * 100);
    bytes.insert(bytes.end(), f.begin(), f.end());
  }
  rp::StreamDecoder dec;
  const auto frames = framesOf(rp::feed(dec, bytes));
  ASSERT_EQ(frames.size(), static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) EXPECT_EQ(frames[i].seq, static_cast<uint32_t>(i));
}

TEST(Codec, BadChecksumIsReportedAndNextFrameRecovered) {
  auto bad = trackStateFrame(1, 500);
  bad[12] ^= 0x10;  // flip one payload bit
  const auto good = trackStateFrame(2, 600);
  std::vector<uint8_t> bytes = bad;
  bytes.insert(bytes.end(), good.begin(), good.end());
  rp::StreamDecoder dec;
  const auto ev = rp::feed(dec, bytes);
  EXPECT_EQ(countErrors(ev, DecodeError::kBadCrc), 1u);
  const auto frames = framesOf(ev);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].seq, 2u);
  EXPECT_EQ(dec.stats().bad_crc, 1u);
}

TEST(Codec, EverySingleBitFlipIsDetected) {
  const auto good = trackStateFrame(3, 700);
  // CRC-16 detects every single-bit error; a flipped sync/length bit must not yield a frame either.
  for (size_t i = 0; i < good.size() * 8; ++i) {
    auto b = good;
    b[i / 8] ^= static_cast<uint8_t>(1u << (i % 8));
    rp::StreamDecoder dec;
    auto ev = rp::feed(dec, b);
    EXPECT_TRUE(framesOf(ev).empty()) << "bit " << i;
  }
}

TEST(Codec, TruncatedFrameThenValidFrame) {
  const auto a = trackStateFrame(1, 100);
  const auto b = trackStateFrame(2, 200);
  std::vector<uint8_t> bytes(a.begin(), a.begin() + 15);  // cut inside the payload
  bytes.insert(bytes.end(), b.begin(), b.end());
  rp::StreamDecoder dec;
  const auto ev = rp::feed(dec, bytes);
  const auto frames = framesOf(ev);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].seq, 2u);
  EXPECT_GE(countErrors(ev, DecodeError::kBadCrc), 1u);
}

TEST(Codec, TruncatedAtEndIsReportedOnFlush) {
  const auto a = trackStateFrame(1, 100);
  rp::StreamDecoder dec;
  auto ev = rp::feed(dec, a.data(), a.size() - 3);
  EXPECT_TRUE(ev.empty());
  EXPECT_EQ(dec.pending(), a.size() - 3);
  std::vector<rp::DecodeEvent> flushed;
  struct Sink : rp::FrameSink {
    std::vector<rp::DecodeEvent>* out;
    void onFrame(const rp::Frame&) override { ADD_FAILURE() << "no frame expected"; }
    void onError(DecodeError e, size_t n) override { out->push_back({e, n, {}}); }
  } sink;
  sink.out = &flushed;
  dec.flush(sink);
  ASSERT_EQ(flushed.size(), 1u);
  EXPECT_EQ(flushed[0].error, DecodeError::kTruncated);
  EXPECT_EQ(flushed[0].discarded, a.size() - 3);
  EXPECT_EQ(dec.pending(), 0u);
}

TEST(Codec, SplitFramesByteByByteAndRandomChunks) {
  std::vector<uint8_t> bytes;
  for (uint32_t i = 0; i < 50; ++i) {
    const auto f = trackStateFrame(i, static_cast<int32_t>(i) * 37);
    bytes.insert(bytes.end(), f.begin(), f.end());
  }
  {
    rp::StreamDecoder dec;
    std::vector<rp::Frame> frames;
    for (uint8_t b : bytes) {
      auto f = framesOf(rp::feed(dec, &b, 1));
      frames.insert(frames.end(), f.begin(), f.end());
    }
    ASSERT_EQ(frames.size(), 50u);
    for (uint32_t i = 0; i < 50; ++i) EXPECT_EQ(frames[i].seq, i);
  }
  {
    std::mt19937 rng(3);
    std::uniform_int_distribution<size_t> chunk(1, 60);
    rp::StreamDecoder dec;
    std::vector<rp::Frame> frames;
    for (size_t pos = 0; pos < bytes.size();) {
      const size_t n = std::min(chunk(rng), bytes.size() - pos);
      auto f = framesOf(rp::feed(dec, bytes.data() + pos, n));
      frames.insert(frames.end(), f.begin(), f.end());
      pos += n;
    }
    ASSERT_EQ(frames.size(), 50u);
    for (uint32_t i = 0; i < 50; ++i) EXPECT_EQ(frames[i].seq, i);
  }
}

TEST(Codec, VersionMismatchIsTypedError) {
  auto f = trackStateFrame(1, 100);
  f[3] = rp::kProtocolVersion + 1;
  const uint16_t crc = rp::crc16(f.data() + 2, f.size() - 4);  // valid CRC for the other version
  f[f.size() - 2] = crc & 0xFF;
  f[f.size() - 1] = crc >> 8;
  const auto good = trackStateFrame(2, 200);
  f.insert(f.end(), good.begin(), good.end());
  rp::StreamDecoder dec;
  const auto ev = rp::feed(dec, f);
  ASSERT_EQ(ev.size(), 2u);
  EXPECT_EQ(ev[0].error, DecodeError::kVersionMismatch);
  EXPECT_EQ(ev[1].error, DecodeError::kNone);
  EXPECT_EQ(ev[1].frame.seq, 2u);
  EXPECT_EQ(dec.stats().version_mismatch, 1u);
}

TEST(Codec, UnknownIdsAndBadLengthAreTyped) {
  uint8_t payload[2] = {1, 2};
  uint8_t buf[rp::kMaxFrameSize];
  size_t n =
      rp::encodeFrame(BoardId::kTrack, static_cast<MsgId>(0x7F), 1, payload, 2, buf, sizeof buf);
  rp::StreamDecoder dec;
  auto ev = rp::feed(dec, buf, n);
  ASSERT_EQ(ev.size(), 1u);
  EXPECT_EQ(ev[0].error, DecodeError::kUnknownMessage);
  n = rp::encodeFrame(static_cast<BoardId>(9), MsgId::kInit, 1, nullptr, 0, buf, sizeof buf);
  ev = rp::feed(dec, buf, n);
  ASSERT_EQ(ev.size(), 1u);
  EXPECT_EQ(ev[0].error, DecodeError::kUnknownBoard);
  const uint8_t too_long[] = {rp::kSync0, rp::kSync1, 200};
  ev = rp::feed(dec, too_long, sizeof too_long);
  ASSERT_EQ(ev.size(), 1u);
  EXPECT_EQ(ev[0].error, DecodeError::kBadLength);
  EXPECT_EQ(dec.pending(), 0u);
  // encoder refuses oversize payloads and small buffers instead of overrunning them
  uint8_t big[rp::kMaxPayload + 1] = {};
  EXPECT_EQ(rp::encodeFrame(BoardId::kTrack, MsgId::kInit, 1, big, sizeof big, buf, sizeof buf),
            0u);
  EXPECT_EQ(rp::encodeCommand(BoardId::kTrack, MsgId::kInit, 1, buf, 5), 0u);
}

TEST(Codec, PayloadValidation) {
  rp::Frame f;
  f.id = MsgId::kMode;
  f.length = 1;
  f.payload[0] = 3;
  rp::CmdMode m;
  EXPECT_EQ(rp::decodePayload(f, m), DecodeError::kBadValue);
  f.length = 2;
  EXPECT_EQ(rp::decodePayload(f, m), DecodeError::kPayloadSize);
  rp::Ack a;
  EXPECT_EQ(rp::decodePayload(f, a), DecodeError::kWrongMessage);
  rp::VersionInfo v;
  f.id = MsgId::kVersionInfo;
  f.length = rp::VersionInfo::kSize;
  std::memset(f.payload, 0, sizeof f.payload);
  f.payload[4] = 'A';
  f.payload[5] = 0;
  f.payload[6] = 'B';  // printable after the terminating NUL
  EXPECT_EQ(rp::decodePayload(f, v), DecodeError::kBadValue);
  f.payload[6] = 0;
  EXPECT_EQ(rp::decodePayload(f, v), DecodeError::kNone);
  EXPECT_STREQ(v.name, "A");
}

TEST(Codec, ErrorNamesAreDistinct) {
  EXPECT_STREQ(rp::errorName(DecodeError::kBadCrc), "bad CRC");
  EXPECT_STRNE(rp::errorName(DecodeError::kVersionMismatch), rp::errorName(DecodeError::kBadCrc));
  EXPECT_STREQ(rp::ackStatusName(rp::AckStatus::kDone), "done");
}
