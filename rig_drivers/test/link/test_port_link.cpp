// BoardLink (port + codec + handshake + acknowledgements + reconnect) against a fake board on the
// master side of a real pseudo-terminal: real bytes through the real port and codec.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <set>
#include <thread>

#include "fake_board.hpp"
#include "rig_drivers/link/serial_port_link.hpp"

using namespace rig_drivers;
using fake::FakeBoard;
using protocol::BoardId;
using protocol::MsgId;

namespace {

std::string tempLink() {
  char tmpl[] = "/tmp/rig_link_testXXXXXX";
  const char* d = ::mkdtemp(tmpl);
  return std::string(d ? d : "/tmp") + "/ttyRIG";
}

/// Collects what the link reports.
struct Probe {
  std::mutex m;
  std::vector<LinkEvent> events;
  std::vector<std::int64_t> state_ms;  // host arrival time of each stream frame
  int outgoing = 0;
  void onFrame(const protocol::Frame& f, const std::vector<std::uint8_t>& wire, bool out) {
    std::lock_guard<std::mutex> l(m);
    EXPECT_EQ(wire, protocol::frameBytes(f));
    if (out) {
      ++outgoing;
    } else if (f.id == MsgId::kTrackState || f.id == MsgId::kCarSensors) {
      state_ms.push_back(steadyMs());
    }
  }
  void onEvent(const LinkEvent& e) {
    std::lock_guard<std::mutex> l(m);
    events.push_back(e);
  }
  int count(LinkEvent::Type t) {
    std::lock_guard<std::mutex> l(m);
    int n = 0;
    for (const auto& e : events) n += e.type == t;
    return n;
  }
  std::string last() {
    std::lock_guard<std::mutex> l(m);
    return events.empty() ? "" : events.back().message;
  }
  int framesBetween(std::int64_t a, std::int64_t b) {
    std::lock_guard<std::mutex> l(m);
    int n = 0;
    for (auto t : state_ms) n += t >= a && t < b;
    return n;
  }
};

std::unique_ptr<BoardLink> makeLink(const std::string& dev, BoardId board, Probe& probe) {
  BoardLinkConfig c;
  c.serial.device = dev;
  c.board = board;
  c.reconnect_period_ms = 100;
  c.handshake_timeout_ms = 1000;
  c.stale_timeout_ms = 500;
  auto link = std::make_unique<BoardLink>(
      c, std::make_unique<PosixSerialPort>(c.serial),
      [&probe](const protocol::Frame& f, const std::vector<std::uint8_t>& w, bool o) {
        probe.onFrame(f, w, o);
      },
      [&probe](const LinkEvent& e) { probe.onEvent(e); });
  return link;
}

bool waitFor(const std::function<bool()>& pred, int ms) {
  const auto end = steadyMs() + ms;
  while (steadyMs() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return pred();
}

}  // namespace

TEST(BoardLink, InvalidConfigIsRejected) {
  BoardLinkConfig c;
  c.serial.device = "";
  c.board = BoardId::kHost;
  c.stale_timeout_ms = 5;
  EXPECT_EQ(c.validate().size(), 3u);
  EXPECT_THROW(BoardLink(c, std::make_unique<PosixSerialPort>(SerialConfig{"/dev/x"}), {}, {}),
               SerialError);
}

TEST(BoardLink, HandshakeCommandsAndThirtyHertzStream) {
  const std::string dev = tempLink();
  FakeBoard board(BoardId::kTrack, dev);
  Probe probe;
  auto link = makeLink(dev, BoardId::kTrack, probe);
  link->start();
  // connected() turns true just before the link thread reports the event: wait for both.
  ASSERT_TRUE(waitFor([&] { return link->connected() && probe.count(LinkEvent::kConnected) >= 1; },
                      3000))
      << probe.last();
  EXPECT_EQ(probe.count(LinkEvent::kConnected), 1);
  EXPECT_NE(probe.last().find("FakeTrackDRV 0.9.1"), std::string::npos) << probe.last();
  EXPECT_EQ(std::string(link->boardVersion().name), "FakeTrackDRV");

  // init: Accepted on receipt, Done when homed; the board saw exactly our seq.
  const auto r = link->command(MsgId::kInit, {}, 2.0, true);
  EXPECT_TRUE(r.success) << r.message;
  EXPECT_EQ(r.status, protocol::AckStatus::kDone);
  const auto seqs = board.seqsReceived();
  EXPECT_NE(std::find(seqs.begin(), seqs.end(), r.seq), seqs.end());
  // Every number the track host sent (vers, init) is in the track board's class, n * 4 + 1.
  for (const std::uint32_t s : seqs) EXPECT_EQ(s % 4, 1u) << "seq " << s;

  protocol::CmdMode mode;
  mode.mode = 2;
  EXPECT_TRUE(link->send(mode, 1.0, true).success);

  // A 20 mm relative move at 100 mm/s completes (Done) with the carriage at +20 mm.
  protocol::CmdTrackMove mv;
  mv.target_um = 20000;
  mv.flags = protocol::CmdTrackMove::kRelative;
  mv.max_speed_mm_s = 100;
  const auto m = link->send(mv, 2.0, true);
  EXPECT_TRUE(m.success) << m.message;
  EXPECT_NEAR(board.positionMm(), 20.0, 1e-3);  // fixed-point um on the wire

  // Out-of-range target is rejected by the board and reported as such.
  mv.target_um = 5'000'000;
  mv.flags = 0;
  const auto bad = link->send(mv, 1.0, true);
  EXPECT_FALSE(bad.success);
  EXPECT_TRUE(bad.acked);
  EXPECT_EQ(bad.status, protocol::AckStatus::kBadArgument);

  const auto para = link->command(MsgId::kPara, {}, 1.0, true);
  EXPECT_TRUE(para.success) << para.message;
  ASSERT_EQ(para.replies.size(), 3u);
  protocol::ParamValue p0;
  ASSERT_EQ(protocol::decodePayload(para.replies[0], p0), protocol::DecodeError::kNone);
  EXPECT_NEAR(p0.value(), 0.0186, 1e-9);

  // Stream rate: the board's frame clock is 30 Hz; a 2 s window holds 60 frames +-1 for the
  // window edges and +-2 for host read jitter (10 ms poll).
  const std::int64_t t0 = steadyMs();
  std::this_thread::sleep_for(std::chrono::milliseconds(2100));
  const int n = probe.framesBetween(t0 + 50, t0 + 2050);
  EXPECT_NEAR(n, 60, 3);
  EXPECT_EQ(link->decoderStats().bad_crc, 0u);
  EXPECT_GT(probe.outgoing, 5);
  link->stop();
}

TEST(BoardLink, UnplugIsReportedOnceAndReplugRecoversWithoutRestart) {
  const std::string dev = tempLink();
  FakeBoard board(BoardId::kCar, dev);
  Probe probe;
  auto link = makeLink(dev, BoardId::kCar, probe);
  link->start();
  ASSERT_TRUE(waitFor([&] { return link->connected(); }, 3000)) << probe.last();

  board.unplug();
  ASSERT_TRUE(waitFor([&] { return !link->connected(); }, 1000));
  // 1.5 s unplugged = ~15 reopen attempts at 100 ms; one disconnect message only.
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  EXPECT_EQ(probe.count(LinkEvent::kDisconnected), 1);
  const auto r = link->command(MsgId::kStart, {}, 0.5, false);
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("not connected"), std::string::npos) << r.message;
  EXPECT_NE(r.message.find(dev), std::string::npos) << r.message;

  board.plug();
  ASSERT_TRUE(waitFor([&] { return link->connected() && probe.count(LinkEvent::kConnected) >= 2; },
                      3000))
      << probe.last();
  EXPECT_EQ(probe.count(LinkEvent::kConnected), 2);
  protocol::CmdServo s;
  s.pitch_cdeg = 500;
  const auto ok = link->send(s, 1.0, true);
  EXPECT_TRUE(ok.success) << ok.message;
  // The stream resumed: frames arrive again within a few periods.
  const std::int64_t t = steadyMs();
  EXPECT_TRUE(waitFor([&] { return probe.framesBetween(t, t + 100000) >= 3; }, 1000));
  link->stop();
}

TEST(BoardLink, SilentBoardIsDetectedAsLost) {
  const std::string dev = tempLink();
  FakeBoard board(BoardId::kTrack, dev);
  Probe probe;
  auto link = makeLink(dev, BoardId::kTrack, probe);
  link->start();
  ASSERT_TRUE(waitFor([&] { return link->connected(); }, 3000));
  board.setSilent(true);
  // The link drops after stale_timeout_ms without frames (the board may answer the next
  // handshake, so it can come back at once; the event log keeps the reason).
  EXPECT_TRUE(waitFor([&] { return probe.count(LinkEvent::kDisconnected) >= 1; }, 2000));
  bool named = false;
  {
    std::lock_guard<std::mutex> l(probe.m);
    for (const auto& e : probe.events)
      named |=
          e.type == LinkEvent::kDisconnected && e.message.find("no frame") != std::string::npos;
  }
  EXPECT_TRUE(named);
  board.setSilent(false);
  EXPECT_TRUE(waitFor([&] { return link->connected(); }, 3000)) << probe.last();
  link->stop();
}

TEST(BoardLink, WrongBoardOnThePortIsRefusedWithANamedReason) {
  const std::string dev = tempLink();
  FakeBoard board(BoardId::kCar, dev);
  Probe probe;
  auto link = makeLink(dev, BoardId::kTrack, probe);
  link->start();
  ASSERT_TRUE(waitFor([&] { return probe.count(LinkEvent::kDisconnected) > 0; }, 3000));
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  EXPECT_FALSE(link->connected());
  EXPECT_EQ(probe.count(LinkEvent::kDisconnected), 1);
  EXPECT_NE(probe.last().find("CarDRV"), std::string::npos) << probe.last();
  EXPECT_NE(probe.last().find("TrackDRV"), std::string::npos) << probe.last();
  link->stop();
}

// docs/rigs.md: command numbers are n * 4 + board id (track 1, car 2, truck 3), n counting up
// from the start value, so the hosts of one rig never collide.
TEST(SequenceCounter, HostsOfOneRigNeverShareANumber) {
  SequenceCounter track(BoardId::kTrack, 1000), car(BoardId::kCar, 1000),
      truck(BoardId::kTruck, 1000);
  std::set<std::uint32_t> seen;
  for (std::uint32_t n = 1000; n < 2000; ++n) {
    const auto t = track.next(), c = car.next(), k = truck.next();
    EXPECT_EQ(t, n * 4 + 1);
    EXPECT_EQ(c, n * 4 + 2);
    EXPECT_EQ(k, n * 4 + 3);
    EXPECT_TRUE(seen.insert(t).second);
    EXPECT_TRUE(seen.insert(c).second);
    EXPECT_TRUE(seen.insert(k).second);
  }
}
