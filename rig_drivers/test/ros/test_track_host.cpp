// rostest: track_host against a fake TrackDRV on a pseudo-terminal. A command is acknowledged
// with its sequence number, the state stream arrives at 30 Hz, and an unplug/replug recovers
// without restarting the driver, with one warning (not one per frame) while unplugged.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <std_msgs/Bool.h>
#include <std_srvs/Trigger.h>

#include <mutex>
#include <vector>

#include "rig_msgs/Command.h"
#include "rig_msgs/Parameters.h"
#include "rig_msgs/RawFrame.h"
#include "rig_msgs/SequenceStep.h"
#include "rig_msgs/SetMode.h"
#include "rig_msgs/TrackState.h"
#include "rig_msgs/Version.h"
#include "wait_until.hpp"

namespace {

struct Listener {
  std::mutex m;
  std::vector<ros::Time> state_stamps;
  std::vector<std::uint32_t> frame_seqs;
  double last_pos_m = -1;
  int raw_in = 0, raw_out = 0;
  bool connected = false;
  int link_down_warnings = 0;
  void onState(const rig_msgs::TrackState& s) {
    std::lock_guard<std::mutex> l(m);
    state_stamps.push_back(s.header.stamp);
    frame_seqs.push_back(s.frame_seq);
    last_pos_m = s.track_pos_m;
  }
  void onRaw(const rig_msgs::RawFrame& r) {
    std::lock_guard<std::mutex> l(m);
    (r.outgoing ? raw_out : raw_in)++;
  }
  void onConnected(const std_msgs::Bool& b) {
    std::lock_guard<std::mutex> l(m);
    connected = b.data;
  }
  void onLog(const rosgraph_msgs::Log& log) {
    std::lock_guard<std::mutex> l(m);
    if (log.name.find("track_host") != std::string::npos && log.level == rosgraph_msgs::Log::WARN &&
        log.msg.find("link down") != std::string::npos)
      ++link_down_warnings;
  }
  int statesIn(ros::Time a, ros::Time b) {
    std::lock_guard<std::mutex> l(m);
    int n = 0;
    for (const auto& t : state_stamps) n += t >= a && t < b;
    return n;
  }
  bool isConnected() {
    std::lock_guard<std::mutex> l(m);
    return connected;
  }
};

using rig_drivers::test::waitUntil;

}  // namespace

TEST(TrackHost, CommandsStreamAndUnplugReplug) {
  ros::NodeHandle nh;
  Listener L;
  auto s1 = nh.subscribe("track_state", 100, &Listener::onState, &L);
  auto s2 = nh.subscribe("raw_frames", 1000, &Listener::onRaw, &L);
  auto s3 = nh.subscribe("track_host/connected", 10, &Listener::onConnected, &L);
  auto s4 = nh.subscribe("/rosout", 1000, &Listener::onLog, &L);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  ASSERT_TRUE(ros::service::waitForService("track_host/command", ros::Duration(20)));
  ASSERT_TRUE(waitUntil([&] { return L.isConnected(); }, 15)) << "driver never connected";

  // A command is acknowledged (Done once homed) with a sequence number.
  rig_msgs::Command cmd;
  cmd.request.command = rig_msgs::Command::Request::INIT;
  ASSERT_TRUE(ros::service::call("track_host/command", cmd));
  EXPECT_TRUE(cmd.response.success) << cmd.response.message;
  EXPECT_GT(cmd.response.seq, 0u);
  EXPECT_EQ(cmd.response.status, 1u);  // AckStatus::kDone

  rig_msgs::SetMode mode;
  mode.request.mode = 2;
  ASSERT_TRUE(ros::service::call("track_host/mode", mode));
  EXPECT_TRUE(mode.response.success) << mode.response.message;
  EXPECT_GT(mode.response.seq, cmd.response.seq);  // one increasing counter
  mode.request.mode = 3;
  ASSERT_TRUE(ros::service::call("track_host/mode", mode));
  EXPECT_FALSE(mode.response.success);

  rig_msgs::Version vers;
  ASSERT_TRUE(ros::service::call("track_host/vers", vers));
  EXPECT_TRUE(vers.response.success) << vers.response.message;
  ASSERT_EQ(vers.response.components.size(), 2u);
  EXPECT_EQ(vers.response.components[1], "FakeTrackDRV");
  rig_msgs::Parameters para;
  ASSERT_TRUE(ros::service::call("track_host/para", para));
  ASSERT_EQ(para.response.names.size(), 3u);
  EXPECT_NEAR(para.response.values[0], 0.0186, 1e-9);  // mm per step

  // A 10 mm step completes and the state stream reports the new position (1 um on the wire).
  rig_msgs::SequenceStep step;
  step.request.target = rig_msgs::SequenceStep::Request::TARGET_TRACK;
  step.request.relative = true;
  step.request.track_pos_m = 0.010;
  step.request.max_speed_mps = 0.1;
  ASSERT_TRUE(ros::service::call("track_host/step", step));
  EXPECT_TRUE(step.response.success) << step.response.message;
  EXPECT_GT(step.response.seq, mode.response.seq);
  ros::WallDuration(0.15).sleep();
  {
    std::lock_guard<std::mutex> l(L.m);
    EXPECT_NEAR(L.last_pos_m, 0.010, 1e-6);
  }

  // Stream rate: 30 Hz board clock. Stamps are the host's frame-completion times, so a 3 s window
  // holds 90 frames +-1 (window edges) +-2 (host read/poll jitter of a few ms at the edges).
  const ros::Time t0 = ros::Time::now();
  ros::WallDuration(3.2).sleep();
  EXPECT_NEAR(L.statesIn(t0, t0 + ros::Duration(3.0)), 90, 3);
  {
    std::lock_guard<std::mutex> l(L.m);
    EXPECT_GT(L.raw_out, 4);  // every command went out and was recorded
    EXPECT_GT(L.raw_in, 90);
    // Board frame counter without gaps: nothing lost on the link.
    for (std::size_t i = 1; i < L.frame_seqs.size(); ++i)
      EXPECT_EQ(L.frame_seqs[i], L.frame_seqs[i - 1] + 1) << "frame lost at " << i;
  }

  // Unplug: the driver notices, logs once, and commands fail with a clear message.
  int warnings_before = 0;
  {
    std::lock_guard<std::mutex> l(L.m);
    warnings_before = L.link_down_warnings;
  }
  std_srvs::Trigger t;
  ASSERT_TRUE(ros::service::call("fake_board/unplug", t));
  ASSERT_TRUE(waitUntil([&] { return !L.isConnected(); }, 3));
  ros::WallDuration(1.5).sleep();  // ~15 reconnect attempts at 0.1 s
  const ros::Time t1 = ros::Time::now();
  ros::WallDuration(0.5).sleep();
  EXPECT_EQ(L.statesIn(t1, t1 + ros::Duration(0.5)), 0);
  cmd.request.command = rig_msgs::Command::Request::START;
  ASSERT_TRUE(ros::service::call("track_host/command", cmd));
  EXPECT_FALSE(cmd.response.success);
  EXPECT_NE(cmd.response.message.find("not connected"), std::string::npos) << cmd.response.message;

  // Replug: same driver process reconnects and works again.
  ASSERT_TRUE(ros::service::call("fake_board/plug", t));
  ASSERT_TRUE(waitUntil([&] { return L.isConnected(); }, 5)) << "no reconnect after replug";
  ASSERT_TRUE(ros::service::call("track_host/command", cmd));
  EXPECT_TRUE(cmd.response.success) << cmd.response.message;
  const ros::Time t2 = ros::Time::now();
  ros::WallDuration(1.1).sleep();
  EXPECT_NEAR(L.statesIn(t2, t2 + ros::Duration(1.0)), 30, 3);
  {
    std::lock_guard<std::mutex> l(L.m);
    EXPECT_EQ(L.link_down_warnings - warnings_before, 1);
  }
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_track_host");
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}
