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

// ---- the wire table of docs/rigs.md, written out byte by byte ------------------------------
// The round trips above use one code for both directions, so a field order shared by encoder
// and decoder would pass them. Here the expected bytes are spelled from the documented table
// alone (header, little-endian fields in the listed order, CRC over bytes 2 .. 9+n); the
// encoder must produce them and the decoder must read the documented values out of them.
namespace {

struct WireBytes {
  std::vector<uint8_t> b;
  WireBytes& u8(uint32_t v) {
    b.push_back(static_cast<uint8_t>(v));
    return *this;
  }
  WireBytes& u16(uint32_t v) { return u8(v & 0xFF).u8((v >> 8) & 0xFF); }
  WireBytes& u32(uint32_t v) { return u16(v & 0xFFFF).u16(v >> 16); }
  WireBytes& i16(int32_t v) { return u16(static_cast<uint16_t>(static_cast<int16_t>(v))); }
  WireBytes& i32(int32_t v) { return u32(static_cast<uint32_t>(v)); }
  WireBytes& text(const char* s, size_t len) {  // NUL padded
    const size_t n = std::strlen(s);
    for (size_t i = 0; i < len; ++i) u8(i < n ? static_cast<uint8_t>(s[i]) : 0);
    return *this;
  }
};

// Header | payload | CRC as the table lays them out; the CRC routine itself is pinned by
// Crc16.CcittFalseCheckValue.
std::vector<uint8_t> documentedFrame(uint8_t board, uint8_t id, uint32_t seq,
                                     const std::vector<uint8_t>& payload) {
  WireBytes w;
  w.u8(0xA5).u8(0x5A).u8(static_cast<uint32_t>(payload.size())).u8(1).u8(board).u8(id).u32(seq);
  w.b.insert(w.b.end(), payload.begin(), payload.end());
  const uint16_t crc = rp::crc16(w.b.data() + 2, w.b.size() - 2);
  return w.u16(crc).b;
}

// The encoder must write the documented frame; the decoder must accept the documented frame.
template <class P>
P checkWire(const P& p, BoardId board, uint8_t doc_board, uint8_t doc_id, uint32_t seq,
            const WireBytes& doc_payload) {
  EXPECT_EQ(static_cast<uint8_t>(P::kId), doc_id);
  EXPECT_EQ(doc_payload.b.size(), P::kSize) << "payload size in the table";
  const auto doc = documentedFrame(doc_board, doc_id, seq, doc_payload.b);
  EXPECT_EQ(rp::encodeMessage(board, seq, p), doc) << rp::msgName(P::kId) << " encoded";
  rp::StreamDecoder dec;
  const auto frames = framesOf(rp::feed(dec, doc));
  P out;
  EXPECT_EQ(frames.size(), 1u) << rp::msgName(P::kId) << " decoded";
  if (frames.size() != 1) return out;
  EXPECT_EQ(static_cast<uint8_t>(frames[0].board), doc_board);
  EXPECT_EQ(frames[0].seq, seq);
  EXPECT_EQ(rp::decodePayload(frames[0], out), DecodeError::kNone);
  return out;
}

}  // namespace

TEST(Codec, CommandsMatchTheWireTable) {
  // Commands without payload: the ids of the table.
  const std::pair<MsgId, uint8_t> bare[] = {{MsgId::kInit, 0x01},  {MsgId::kStart, 0x03},
                                            {MsgId::kStop, 0x04},  {MsgId::kReset, 0x05},
                                            {MsgId::kEnd, 0x06},   {MsgId::kVers, 0x07},
                                            {MsgId::kPara, 0x08}};
  for (const auto& [id, doc_id] : bare)
    EXPECT_EQ(rp::encodeCommand(BoardId::kCar, id, 0x0A0B0C0Du),
              documentedFrame(2, doc_id, 0x0A0B0C0Du, {}))
        << rp::msgName(id);
  {
    rp::CmdMode m;
    m.mode = 2;
    EXPECT_EQ(checkWire(m, BoardId::kTrack, 1, 0x02, 21, WireBytes().u8(2)).mode, 2);
  }
  {
    rp::CmdTrackMove m;
    m.target_um = -1234567;
    m.flags = rp::CmdTrackMove::kRelative;
    m.max_speed_mm_s = 0x1234;
    m.accel_mm_s2 = 0x0567;
    const auto r = checkWire(m, BoardId::kTrack, 1, 0x10, 22,
                             WireBytes().i32(-1234567).u8(1).u16(0x1234).u16(0x0567));
    EXPECT_EQ(r.target_um, -1234567);
    EXPECT_EQ(r.flags, 1);
    EXPECT_EQ(r.max_speed_mm_s, 0x1234);
    EXPECT_EQ(r.accel_mm_s2, 0x0567);
  }
  {
    rp::CmdServo m;
    m.pitch_cdeg = -2050;
    m.yaw_cdeg = 1525;
    m.flags = 0;
    const auto r =
        checkWire(m, BoardId::kCar, 2, 0x11, 23, WireBytes().i16(-2050).i16(1525).u8(0));
    EXPECT_EQ(r.pitch_cdeg, -2050);
    EXPECT_EQ(r.yaw_cdeg, 1525);
  }
  {
    rp::CmdPing m;
    m.host_time_ms = 0x89ABCDEFu;
    EXPECT_EQ(checkWire(m, BoardId::kCar, 2, 0x12, 24, WireBytes().u32(0x89ABCDEFu)).host_time_ms,
              0x89ABCDEFu);
  }
  {
    rp::CmdWait m;
    m.wait_ms = 70000;
    EXPECT_EQ(checkWire(m, BoardId::kTrack, 1, 0x13, 25, WireBytes().u32(70000)).wait_ms, 70000u);
  }
}

TEST(Codec, BoardMessagesMatchTheWireTable) {
  {
    rp::Ack m;
    m.acked_seq = 0x01020304u;
    m.acked_id = MsgId::kTrackMove;
    m.status = rp::AckStatus::kEndOfTrack;  // 7 in the table
    const auto r =
        checkWire(m, BoardId::kTrack, 1, 0x80, 31, WireBytes().u32(0x01020304u).u8(0x10).u8(7));
    EXPECT_EQ(r.acked_seq, 0x01020304u);
    EXPECT_EQ(r.acked_id, MsgId::kTrackMove);
    EXPECT_EQ(r.status, rp::AckStatus::kEndOfTrack);
  }
  {
    rp::TrackStatePayload m;
    m.board_time_ms = 0x00ABCDEF;
    m.pos_steps = 53763;
    m.pos_um = 1000001;
    m.vel_um_s = -95000;
    m.state = rp::TrackStateCode::kMoving;  // 3
    m.flags = 0x08 | 0x01;                  // homed, near sensor
    m.mode = 2;
    const auto r = checkWire(m, BoardId::kTrack, 1, 0x81, 32,
                             WireBytes().u32(0x00ABCDEF).i32(53763).i32(1000001).i32(-95000)
                                 .u8(3).u8(0x09).u8(2).u8(0));
    EXPECT_EQ(r.board_time_ms, 0x00ABCDEFu);
    EXPECT_EQ(r.pos_steps, 53763);
    EXPECT_EQ(r.pos_um, 1000001);
    EXPECT_EQ(r.vel_um_s, -95000);
    EXPECT_EQ(r.state, rp::TrackStateCode::kMoving);
    EXPECT_EQ(r.flags, 0x09);
    EXPECT_EQ(r.mode, 2);
  }
  {
    rp::CarSensorsPayload m;
    m.board_time_ms = 3333;
    m.pitch_dem_cdeg = 1001;
    m.pitch_cdeg = 968;
    m.yaw_dem_cdeg = -502;
    m.yaw_cdeg = -576;
    m.acc_x_mg = -12;
    m.acc_y_mg = -1003;
    m.acc_z_mg = 45;
    m.tof_mm = 1234;
    m.flags = 1;
    const WireBytes doc = WireBytes().u32(3333).i16(1001).i16(968).i16(-502).i16(-576).i16(-12)
                              .i16(-1003).i16(45).u16(1234).u8(1);
    const auto r = checkWire(m, BoardId::kCar, 2, 0x82, 33, doc);
    EXPECT_EQ(r.board_time_ms, 3333u);
    EXPECT_EQ(r.pitch_dem_cdeg, 1001);
    EXPECT_EQ(r.pitch_cdeg, 968);
    EXPECT_EQ(r.yaw_dem_cdeg, -502);
    EXPECT_EQ(r.yaw_cdeg, -576);
    EXPECT_EQ(r.acc_x_mg, -12);
    EXPECT_EQ(r.acc_y_mg, -1003);
    EXPECT_EQ(r.acc_z_mg, 45);
    EXPECT_EQ(r.tof_mm, 1234);
    EXPECT_EQ(r.flags, 1);
    // "33 bytes, 2.9 ms on the wire, about 9 % of the line at 30 Hz": 10 bits a byte at 8N1.
    const auto frame = rp::encodeMessage(BoardId::kCar, 1, m);
    ASSERT_EQ(frame.size(), 33u);
    EXPECT_NEAR(frame.size() * 10.0 / 115200.0 * 1e3, 2.9, 0.05);
    EXPECT_NEAR(frame.size() * 10.0 * 30.0 / 115200.0, 0.09, 0.005);
  }
  {
    rp::TruckRcPayload m;
    m.board_time_ms = 77;
    m.ch2_us = 1401;
    m.ch3_us = 1802;
    m.ch5_us = 1903;
    m.ch7_us = 1104;
    m.steering_permille = -205;
    m.speed_permille = 606;
    m.speed_mm_s = 1207;
    m.flags = 0x01 | 0x04;  // running, signal ok
    const WireBytes doc = WireBytes().u32(77).u16(1401).u16(1802).u16(1903).u16(1104).i16(-205)
                              .i16(606).i16(1207).u8(0x05);
    const auto r = checkWire(m, BoardId::kTruck, 3, 0x83, 34, doc);
    EXPECT_EQ(r.ch2_us, 1401);
    EXPECT_EQ(r.ch3_us, 1802);
    EXPECT_EQ(r.ch5_us, 1903);
    EXPECT_EQ(r.ch7_us, 1104);
    EXPECT_EQ(r.steering_permille, -205);
    EXPECT_EQ(r.speed_permille, 606);
    EXPECT_EQ(r.speed_mm_s, 1207);
    EXPECT_EQ(r.flags, 0x05);
  }
  {
    rp::VersionInfo m;
    m.major = 4;
    m.minor = 5;
    m.patch = 6;
    m.setName("CarDRV");
    const auto r = checkWire(m, BoardId::kCar, 2, 0x84, 35,
                             WireBytes().u8(4).u8(5).u8(6).u8(1).text("CarDRV", 16));
    EXPECT_EQ(r.major, 4);
    EXPECT_EQ(r.minor, 5);
    EXPECT_EQ(r.patch, 6);
    EXPECT_EQ(r.protocol, 1);
    EXPECT_EQ(std::string(r.name), "CarDRV");
  }
  {
    rp::ParamValue m;
    m.index = 2;
    m.count = 7;
    m.mantissa = -186;
    m.exp10 = -4;
    m.setName("m_per_step");
    const auto r = checkWire(m, BoardId::kTrack, 1, 0x85, 36,
                             WireBytes().u8(2).u8(7).i32(-186).u8(0xFC).text("m_per_step", 16));
    EXPECT_EQ(r.index, 2);
    EXPECT_EQ(r.count, 7);
    EXPECT_EQ(r.mantissa, -186);
    EXPECT_EQ(r.exp10, -4);
    EXPECT_EQ(std::string(r.name), "m_per_step");
  }
  {
    rp::Pong m;
    m.host_time_ms = 0x11223344u;
    m.board_time_ms = 0x55667788u;
    const auto r = checkWire(m, BoardId::kCar, 2, 0x86, 37,
                             WireBytes().u32(0x11223344u).u32(0x55667788u));
    EXPECT_EQ(r.host_time_ms, 0x11223344u);
    EXPECT_EQ(r.board_time_ms, 0x55667788u);
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

// docs/rigs.md: "1000 frames with 100 random bytes between each still all decode". Unlike the
// test above the garbage is unrestricted, sync bytes included: a false candidate it opens must
// fail its CRC and be rescanned from its next byte without swallowing the real frame after it.
TEST(Codec, ThousandFramesWithHundredRandomBytesBetweenAllDecode) {
  std::mt19937 rng(2024);
  std::vector<uint8_t> bytes;
  for (uint32_t i = 0; i < 1000; ++i) {
    rp::CarSensorsPayload s;
    s.board_time_ms = i * 33;
    s.pitch_cdeg = static_cast<int16_t>(i % 4000);
    const auto f = rp::encodeMessage(BoardId::kCar, i, s);
    bytes.insert(bytes.end(), f.begin(), f.end());
    for (int g = 0; g < 100; ++g) bytes.push_back(static_cast<uint8_t>(rng()));
  }
  rp::StreamDecoder dec;
  const auto frames = framesOf(rp::feed(dec, bytes));
  ASSERT_EQ(frames.size(), 1000u);
  for (uint32_t i = 0; i < 1000; ++i) EXPECT_EQ(frames[i].seq, i);
  // Every garbage byte is either discarded or still pending as a possible frame start.
  EXPECT_EQ(dec.stats().bytes_discarded + dec.pending(), 1000u * 100u);
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

TEST(Codec, ExpireGivesUpAFalseStartAndDeliversTheFrameBehindIt) {
  // Garbage ending in a plausible frame start (sync, length 60) swallows the frame that follows
  // while the decoder waits for 60 payload bytes; once the line is quiet, expire() rescans.
  const auto a = trackStateFrame(7, 100);
  std::vector<uint8_t> bytes = {0x13, 0x37, rp::kSync0, rp::kSync1, 60, rp::kProtocolVersion};
  bytes.insert(bytes.end(), a.begin(), a.end());
  rp::StreamDecoder dec;
  EXPECT_TRUE(framesOf(rp::feed(dec, bytes)).empty());
  EXPECT_EQ(dec.pending(), bytes.size() - 2);
  std::vector<rp::Frame> frames;
  size_t truncated = 0;
  struct Sink : rp::FrameSink {
    std::vector<rp::Frame>* frames;
    size_t* truncated;
    void onFrame(const rp::Frame& f) override { frames->push_back(f); }
    void onError(DecodeError e, size_t) override { *truncated += e == DecodeError::kTruncated; }
  } sink;
  sink.frames = &frames;
  sink.truncated = &truncated;
  dec.expire(sink);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].seq, 7u);
  EXPECT_EQ(truncated, 1u);  // the one false start
  EXPECT_EQ(dec.pending(), 0u);
  EXPECT_EQ(dec.stats().truncated, 1u);
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
