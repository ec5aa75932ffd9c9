// rostest: TrackDRV's firmware image running in qemu-system-avr (emulated_track.test) against
// track_host's real serial-port code and the sequencer. Everything is counted by the board's
// frame counter (the seq of every board frame, whatever its type) and by acknowledgements, never
// over wall time: the emulator runs the board at a speed that depends on the machine's load.
//
// The emulated board's inputs come from the adapter's stub (src/firmware/avr/track_board.cpp): the
// carriage starts 18.6 mm (1000 steps) from the far sensor and moves with the board's own step
// pulses, so homing, moves and the reported position are the firmware's.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <std_msgs/Bool.h>
#include <std_srvs/Trigger.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "rig_drivers/protocol/codec.hpp"
#include "rig_msgs/Command.h"
#include "rig_msgs/RawFrame.h"
#include "rig_msgs/SequenceStep.h"
#include "rig_msgs/SetMode.h"
#include "rig_msgs/TrackState.h"
#include "rig_msgs/Version.h"
#include "wait_until.hpp"

namespace rp = rig_drivers::protocol;
using rig_drivers::test::waitUntil;

namespace {

constexpr double kStepM = 0.0186e-3;  // one motor step with the 20-tooth pulley (the board's unit)
constexpr double kWaitS = 240;        // generous: qemu on a loaded 2-core machine

struct Link {
  std::mutex m;
  std::vector<rp::Frame> in;   ///< board -> host frames, in arrival order
  std::vector<rp::Frame> out;  ///< host -> board commands
  rig_msgs::TrackState last_state;
  int states = 0;
  bool connected = false;
  std::vector<double> trigger_pos_m;  ///< carriage position at each camera trigger

  void onRaw(const rig_msgs::RawFrame& r) {
    rp::StreamDecoder d;
    const auto events = rp::feed(d, r.bytes);
    std::lock_guard<std::mutex> l(m);
    for (const auto& e : events)
      if (e.error == rp::DecodeError::kNone) (r.outgoing ? out : in).push_back(e.frame);
  }
  void onState(const rig_msgs::TrackState& s) {
    std::lock_guard<std::mutex> l(m);
    last_state = s;
    ++states;
  }
  void onConnected(const std_msgs::Bool& b) {
    std::lock_guard<std::mutex> l(m);
    connected = b.data;
  }
  bool onTrigger(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    std::lock_guard<std::mutex> l(m);
    trigger_pos_m.push_back(last_state.track_pos_m);
    res.success = true;
    return true;
  }
  size_t inCount() {
    std::lock_guard<std::mutex> l(m);
    return in.size();
  }
  std::vector<rp::Frame> inFrom(size_t first) {
    std::lock_guard<std::mutex> l(m);
    return {in.begin() + static_cast<std::ptrdiff_t>(std::min(first, in.size())), in.end()};
  }
  /// Index after the last board frame that is not a TrackState, once 5 frames have followed it.
  size_t afterLastReply() {
    const size_t n = inCount();
    waitUntil([&] { return inCount() >= n + 5; }, kWaitS);
    std::lock_guard<std::mutex> l(m);
    size_t k = in.size();
    while (k > 0 && in[k - 1].id == rp::MsgId::kTrackState) --k;
    return k;
  }
  rig_msgs::TrackState state() {
    std::lock_guard<std::mutex> l(m);
    return last_state;
  }
};

Link* g_link = nullptr;

/// Frames missing between consecutive board frames (seq gaps), and the number of gaps.
struct Gaps {
  int gaps = 0;
  uint32_t lost = 0;
  size_t last_gap_at = 0;  ///< index of the first frame after the last gap
};
Gaps gapsOf(const std::vector<rp::Frame>& frames) {
  Gaps g;
  for (size_t i = 1; i < frames.size(); ++i) {
    if (frames[i].seq != frames[i - 1].seq + 1) {
      ++g.gaps;
      g.lost += frames[i].seq - frames[i - 1].seq - 1;
      g.last_gap_at = i;
    }
  }
  return g;
}

bool call(const std::string& service, const std::string& what) {
  std_srvs::Trigger t;
  if (!ros::service::call(service, t)) return false;
  EXPECT_TRUE(t.response.success) << what << ": " << t.response.message;
  return t.response.success;
}

/// Runs the real sequencer executable (next to this test's binary) to its end; its exit code.
int runSequencer(const std::string& script, std::string* output) {
  char self[4096] = {0};
  if (::readlink("/proc/self/exe", self, sizeof self - 1) <= 0) return -1;
  std::string dir(self);
  dir = dir.substr(0, dir.rfind('/'));
  const std::string cmd = dir + "/sequencer __name:=emu_sequencer _script:=" + script +
                          " _camera_trigger_service:=/emu_camera/trigger _still_timeout_s:=120" +
                          " _step_timeout_s:=120 _service_wait_s:=120 2>&1";
  FILE* f = ::popen(cmd.c_str(), "r");
  if (f == nullptr) return -1;
  char buf[512];
  while (std::fgets(buf, sizeof buf, f)) *output += buf;
  const int status = ::pclose(f);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace

TEST(EmulatedTrack, HandshakeAnd90ConsecutiveFrames) {
  Link& L = *g_link;
  ASSERT_TRUE(waitUntil(
      [&] {
        std::lock_guard<std::mutex> l(L.m);
        return L.connected;
      },
      kWaitS))
      << "track_host never completed its handshake with the emulated board";
  rig_msgs::Version vers;
  ASSERT_TRUE(ros::service::call("track_host/vers", vers));
  EXPECT_TRUE(vers.response.success) << vers.response.message;
  ASSERT_EQ(vers.response.components.size(), 2u);
  EXPECT_EQ(vers.response.components[1], "TrackDRV");
  EXPECT_EQ(vers.response.protocol_version, rp::kProtocolVersion);

  // 90 board frames with nothing sent meanwhile: all TrackState, counters consecutive, board
  // clock increasing by at least the 30 Hz period on average. The window starts after vers's
  // replies (they may reach this node after the service's answer).
  const size_t mark = L.afterLastReply();
  ASSERT_TRUE(waitUntil([&] { return L.inCount() >= mark + 90; }, kWaitS));
  auto frames = L.inFrom(mark);
  frames.resize(90);
  const Gaps g = gapsOf(frames);
  EXPECT_EQ(g.gaps, 0) << g.lost << " frames lost";
  uint32_t first_ms = 0, prev_ms = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    rp::TrackStatePayload s;
    ASSERT_EQ(rp::decodePayload(frames[i], s), rp::DecodeError::kNone) << "frame " << i;
    if (i == 0) first_ms = s.board_time_ms;
    if (i > 0) EXPECT_GT(s.board_time_ms, prev_ms) << "frame " << i;
    prev_ms = s.board_time_ms;
  }
  // Frame k is due at k * 100/3 ms of board time and sent no earlier; the first may be late.
  EXPECT_GE(prev_ms - first_ms, 89 * 100 / 3 - 34u);
  std::printf("[ figures  ] 90 frames, seq %u..%u, board time %u..%u ms\n", frames.front().seq,
              frames.back().seq, first_ms, prev_ms);
}

TEST(EmulatedTrack, ModeOneCommands) {
  Link& L = *g_link;
  rig_msgs::Command cmd;
  cmd.request.command = rig_msgs::Command::Request::INIT;  // homing onto the stub's far sensor
  ASSERT_TRUE(ros::service::call("track_host/command", cmd));
  EXPECT_TRUE(cmd.response.success) << cmd.response.message;
  EXPECT_EQ(cmd.response.status, static_cast<uint8_t>(rp::AckStatus::kDone));
  rig_msgs::SetMode mode;
  mode.request.mode = 1;
  ASSERT_TRUE(ros::service::call("track_host/mode", mode));
  EXPECT_TRUE(mode.response.success) << mode.response.message;

  rig_msgs::SequenceStep step;
  step.request.target = rig_msgs::SequenceStep::Request::TARGET_TRACK;
  step.request.track_pos_m = 0.020;
  step.request.max_speed_mps = 0.05;
  ASSERT_TRUE(ros::service::call("track_host/step", step));
  EXPECT_TRUE(step.response.success) << step.response.message;
  EXPECT_EQ(step.response.status, static_cast<uint8_t>(rp::AckStatus::kDone));
  // The next state frames show the carriage there, homed and ready.
  const int after = [&] {
    std::lock_guard<std::mutex> l(L.m);
    return L.states;
  }();
  ASSERT_TRUE(waitUntil(
      [&] {
        std::lock_guard<std::mutex> l(L.m);
        return L.states >= after + 3;
      },
      kWaitS));
  const auto s = L.state();
  EXPECT_NEAR(s.track_pos_m, 0.020, kStepM);
  EXPECT_EQ(s.state, rig_msgs::TrackState::STATE_READY);
  EXPECT_EQ(s.mode, 1);

  for (uint8_t c : {rig_msgs::Command::Request::START, rig_msgs::Command::Request::STOP}) {
    cmd.request.command = c;
    ASSERT_TRUE(ros::service::call("track_host/command", cmd));
    EXPECT_TRUE(cmd.response.success) << cmd.response.message;
  }
}

TEST(EmulatedTrack, ModeTwoStepScriptRunsToItsEndWithEveryAck) {
  Link& L = *g_link;
  ros::NodeHandle pnh("~");
  std::string script;
  ASSERT_TRUE(pnh.getParam("script", script));
  size_t out_mark = 0;
  {
    std::lock_guard<std::mutex> l(L.m);
    out_mark = L.out.size();
    L.trigger_pos_m.clear();
  }
  const double start_m = L.state().track_pos_m;
  std::string output;
  EXPECT_EQ(runSequencer(script, &output), 0) << output;
  EXPECT_NE(output.find("sequencer: done: 19 steps, 6 frames"), std::string::npos) << output;

  std::lock_guard<std::mutex> l(L.m);
  // Every board step of the script went out once and came back accepted, then done.
  std::map<uint32_t, rp::MsgId> steps;
  for (size_t i = out_mark; i < L.out.size(); ++i)
    if (L.out[i].id == rp::MsgId::kTrackMove || L.out[i].id == rp::MsgId::kWait)
      steps[L.out[i].seq] = L.out[i].id;
  EXPECT_EQ(steps.size(), 12u);
  std::map<uint32_t, std::vector<rp::AckStatus>> acks;
  for (const auto& f : L.in) {
    rp::Ack a;
    if (rp::decodePayload(f, a) == rp::DecodeError::kNone && steps.count(a.acked_seq))
      acks[a.acked_seq].push_back(a.status);
  }
  int done = 0;
  for (const auto& [seq, id] : steps) {
    const std::vector<rp::AckStatus> want{rp::AckStatus::kAccepted, rp::AckStatus::kDone};
    EXPECT_EQ(acks[seq], want) << "step seq " << seq << " (" << rp::msgName(id) << ")";
    done += acks[seq] == want;
  }
  // One frame after each 5 mm move, the carriage still at the commanded position (one step).
  ASSERT_EQ(L.trigger_pos_m.size(), 6u);
  for (size_t k = 0; k < 6; ++k)
    EXPECT_NEAR(L.trigger_pos_m[k], start_m + 0.005 * (k + 1), kStepM) << "frame " << k;
  std::printf("[ figures  ] step script: %zu board steps, %d accepted+done, %zu frames\n",
              steps.size(), done, L.trigger_pos_m.size());
}

TEST(EmulatedTrack, GarbageAndBadChecksumsLoseOnlyTheFrameTheyHit) {
  Link& L = *g_link;
  // 100 garbage bytes inside a board frame: that frame is lost, none after it.
  for (const std::string fault : {"inject_garbage", "corrupt_next_frame"}) {
    const size_t mark = L.inCount() - 1;  // from the last frame before the fault
    ASSERT_TRUE(call("emulated_board/" + fault, fault));
    ASSERT_TRUE(waitUntil([&] { return L.inCount() >= mark + 60; }, kWaitS));
    const auto frames = L.inFrom(mark);
    const Gaps g = gapsOf(frames);
    EXPECT_EQ(g.gaps, 1) << fault;
    EXPECT_EQ(g.lost, 1u) << fault;
    EXPECT_GE(frames.size() - g.last_gap_at, 30u) << fault;
    std::printf("[ figures  ] %s: %u frame lost, %zu consecutive frames after it\n", fault.c_str(),
                g.lost, frames.size() - g.last_gap_at);
  }
  // 100 garbage bytes to the board (false frame starts among them): once the line is quiet the
  // board gives up what they began, the command behind them is answered and the board's stream
  // goes on without a gap.
  const size_t mark = L.inCount();
  ASSERT_TRUE(call("emulated_board/inject_host_garbage", "host garbage"));
  rig_msgs::Version vers;
  ASSERT_TRUE(ros::service::call("track_host/vers", vers));
  EXPECT_TRUE(vers.response.success) << vers.response.message;
  ASSERT_TRUE(waitUntil([&] { return L.inCount() >= mark + 30; }, kWaitS));
  EXPECT_EQ(gapsOf(L.inFrom(mark)).gaps, 0);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_emulated_track");
  ros::NodeHandle nh;
  Link link;
  g_link = &link;
  auto s1 = nh.subscribe("raw_frames", 10000, &Link::onRaw, &link);
  auto s2 = nh.subscribe("track_state", 1000, &Link::onState, &link);
  auto s3 = nh.subscribe("track_host/connected", 10, &Link::onConnected, &link);
  auto srv = nh.advertiseService("emu_camera/trigger", &Link::onTrigger, &link);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}
