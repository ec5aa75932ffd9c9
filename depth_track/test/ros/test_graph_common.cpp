// The graph's frame hand-over without a roscore: replay keeps every frame in order, live keeps
// the freshest and counts what it skipped; stamp pairing; the stamp guard's verdicts; the shared
// map session's replay order (a correction is waited for, the map catches up).
#include <gtest/gtest.h>
#include <ros/time.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "../../src/nodelets/graph_common.hpp"

using namespace depth_track;
using namespace depth_track::graph;

TEST(FrameQueue, ReplayKeepsEveryFrameInOrder) {
  std::vector<int> seen;
  std::mutex m;
  {
    FrameQueue<int> q(Mode::kReplay, 1000, [&](const int& i) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
      std::lock_guard<std::mutex> lock(m);
      seen.push_back(i);
    });
    for (int i = 0; i < 200; ++i) q.push(i);
    while (q.waiting() > 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
    EXPECT_EQ(q.skipped(), 0u);
  }
  ASSERT_EQ(seen.size(), 200u);
  for (int i = 0; i < 200; ++i) EXPECT_EQ(seen[i], i);
}

TEST(FrameQueue, LiveKeepsTheFreshestAndCountsSkips) {
  std::atomic<bool> release{false};
  std::vector<int> seen;
  std::mutex m;
  FrameQueue<int> q(Mode::kLive, 1000, [&](const int& i) {
    while (!release) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    std::lock_guard<std::mutex> lock(m);
    seen.push_back(i);
  });
  q.push(0);  // taken by the worker, which then blocks
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  for (int i = 1; i <= 9; ++i) q.push(i);  // 1..8 replaced before the worker is free
  EXPECT_EQ(q.skipped(), 8u);
  release = true;
  while (q.waiting() > 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  std::this_thread::sleep_for(std::chrono::milliseconds(10));
  q.stop();
  EXPECT_EQ(seen, (std::vector<int>{0, 9}));
}

TEST(StampPairer, PairsEitherOrderAndReleasesOrphans) {
  StampPairer<int, char> p(3);
  EXPECT_FALSE(p.addA(ros::Time(1.0), 1));
  const auto ab = p.addB(ros::Time(1.0), 'a');
  ASSERT_TRUE(ab);
  EXPECT_EQ(ab->first, 1);
  EXPECT_EQ(ab->second, 'a');
  EXPECT_FALSE(p.addB(ros::Time(2.0), 'b'));
  EXPECT_TRUE(p.addA(ros::Time(2.0), 2));
  // An A whose partner never comes is released once a later pair formed.
  EXPECT_FALSE(p.addA(ros::Time(3.0), 3));
  EXPECT_FALSE(p.addA(ros::Time(4.0), 4));
  EXPECT_TRUE(p.addB(ros::Time(4.0), 'd'));
  EXPECT_EQ(p.takeOlderA(ros::Time(4.0)), std::vector<int>{3});
}

TEST(StampGuard, RejectsRepeatsAndResetsOnAClockJump) {
  ros::Time::init();
  StampGuard g;
  EXPECT_EQ(g.check(ros::Time(100.0)), StampGuard::Verdict::kNext);
  EXPECT_EQ(g.check(ros::Time(100.1)), StampGuard::Verdict::kNext);
  EXPECT_EQ(g.check(ros::Time(100.1)), StampGuard::Verdict::kReject);
  EXPECT_EQ(g.check(ros::Time(100.05)), StampGuard::Verdict::kReject);
  EXPECT_EQ(g.lastStamp(), ros::Time(100.1));  // a rejected frame does not move it
  EXPECT_EQ(g.check(ros::Time(100.2)), StampGuard::Verdict::kNext);
}

TEST(MapSession, ReplayOrderBetweenLoopClosureAndFusion) {
  MapSession s;
  s.attachLoopClosure();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation().x() = 0.01;
  // Fusion asks for frame 2's correction before the loop closure decided it: it waits.
  std::optional<Eigen::Isometry3d> got;
  std::thread fusion([&] { got = s.correctionFor(2.0, true, 5.0); });
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  s.decide(1.0, Eigen::Isometry3d::Identity());
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_FALSE(got.has_value()) << "frame 1's decision must not release frame 2";
  s.decide(2.0, X);
  fusion.join();
  ASSERT_TRUE(got);
  EXPECT_DOUBLE_EQ(got->translation().x(), 0.01);
  // The decision that applies to a frame is the last one at or before its stamp.
  EXPECT_DOUBLE_EQ(s.correctionFor(1.5, false, 0.0)->translation().x(), 0.0);
  // The loop closure of frame 3 waits for the map to hold frame 2.
  std::atomic<bool> ok{false};
  std::thread lc([&] { ok = s.waitFused(2.0, 5.0); });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  s.fused(1.0);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_FALSE(ok);
  s.fused(2.0);
  lc.join();
  EXPECT_TRUE(ok);
  EXPECT_FALSE(s.waitFused(3.0, 0.05)) << "times out when the map never gets there";
}
