// The graph's frame hand-over without a roscore: replay keeps every frame in order, live keeps
// the freshest and counts what it skipped; stamp pairing; the stamp guard's verdicts; the shared
// map session's replay order (a correction is waited for, the map catches up), and its map's
// lifetime across a reset (a reader finishes on the map it took; stages follow the new one).
#include <gtest/gtest.h>
#include <ros/time.h>

#include <sys/resource.h>

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

// A stage slowed on purpose (held until released) while frames keep coming: with two waiting
// slots one overrun costs nothing, and beyond them the oldest waiting frame goes, so the worker
// always resumes on the freshest two and never on a backlog.
TEST(FrameQueue, LiveDepthTwoAbsorbsOneOverrunAndSkipsTheOldest) {
  std::atomic<bool> release{false};
  std::vector<int> seen;
  std::mutex m;
  FrameQueueOptions o;
  o.live_depth = 2;
  FrameQueue<int> q(
      Mode::kLive, 1000,
      [&](const int& i) {
        while (!release) std::this_thread::sleep_for(std::chrono::milliseconds(1));
        std::lock_guard<std::mutex> lock(m);
        seen.push_back(i);
      },
      o);
  q.push(0);
  while (q.waiting() > 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  q.push(1);  // the stage overran one period: 1 waits, nothing lost
  EXPECT_EQ(q.skipped(), 0u);
  EXPECT_EQ(q.waiting(), 1u);
  q.push(2);
  EXPECT_EQ(q.skipped(), 0u);
  EXPECT_EQ(q.waiting(), 2u);
  for (int i = 3; i <= 6; ++i) q.push(i);  // still held: 1, 2, 3, 4 pushed out in turn
  EXPECT_EQ(q.skipped(), 4u);
  EXPECT_EQ(q.waiting(), 2u);
  release = true;
  while (q.waiting() > 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  q.stop();
  EXPECT_EQ(seen, (std::vector<int>{0, 5, 6}));
  EXPECT_EQ(q.overflowed(), 0u);
}

namespace {

// The nice value a queue's worker ran one item at (getpriority(PRIO_PROCESS, 0) names the
// calling thread on Linux), and the one the queue reports, for a worker asked to run at
// `worker_nice`.
std::pair<int, int> workerNiceSeen(Mode mode, int worker_nice) {
  std::atomic<int> in_worker{-100};
  FrameQueueOptions o;
  o.worker_nice = worker_nice;
  int reported = -100;
  {
    FrameQueue<int> q(
        mode, 4, [&](const int&) { in_worker = getpriority(PRIO_PROCESS, 0); }, o);
    q.push(0);
    while (in_worker == -100) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    reported = q.workerNice();
  }
  return {in_worker.load(), reported};
}

}  // namespace

// Linux nice is per thread: the worker runs at the value asked for, the caller stays as it was.
TEST(FrameQueue, WorkerRunsAtItsNiceValue) {
  errno = 0;
  const int caller = getpriority(PRIO_PROCESS, 0);
  const int asked = std::min(caller + 7, 19);
  const auto [in_worker, reported] = workerNiceSeen(Mode::kLive, asked);
  EXPECT_EQ(in_worker, asked);
  EXPECT_EQ(reported, asked);
  EXPECT_EQ(getpriority(PRIO_PROCESS, 0), caller);
}

// Replay takes every frame in order: the queue leaves its worker at the caller's priority.
TEST(FrameQueue, ReplayIgnoresTheNiceValue) {
  errno = 0;
  const int caller = getpriority(PRIO_PROCESS, 0);
  const auto [in_worker, reported] = workerNiceSeen(Mode::kReplay, std::min(caller + 7, 19));
  EXPECT_EQ(in_worker, caller);
  EXPECT_EQ(reported, caller);
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

TEST(MapSession, ReadersKeepTheirMapAcrossAResetAndStagesFollowTheNewOne) {
  // 64x48 px at f = 200 px: a 5 mm pixel footprint at 1 m, under the 1 cm voxel, so a wall at
  // 1 m fills every pixel of the cast.
  const PinholeIntrinsics K = PinholeIntrinsics::isotropic(64, 48, 200.0);
  MapperConfig c;
  c.map.bounded = false;
  c.map.voxel_size_m = 0.01;
  c.map.occupancy_threshold = 0.5;  // one hit: each single frame shows (the default takes two)
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  auto makeFuser = [&](VoxelMap& m) { return std::make_unique<MapFuser>(m, K); };
  auto makeCaster = [&](const VoxelMap& m) {
    return std::make_unique<MapRayCaster>(m, K, DepthRange{0.5, 4.0});
  };
  MapSession s;
  EXPECT_FALSE(s.map());
  const std::shared_ptr<VoxelMap> m0 = s.ensureMap(K, c, I);
  EXPECT_EQ(s.ensureMap(K, c, I), m0) << "the first frame builds the map, later ones share it";
  MapStage<MapFuser> fuser;
  MapStage<MapRayCaster> caster;
  fuser.over(m0, K, makeFuser).fuse(DepthImage(64, 48, 1.005f), I);  // a wall at 1 m
  const DepthImage v0 = caster.over(s.map(), K, makeCaster).cast(I);
  ASSERT_EQ(v0.countValid(), 64u * 48u);
  // The first occupied voxel along the axis spans [1.00, 1.01) m: its centre, within a voxel.
  EXPECT_NEAR(v0.at(32, 24), 1.005, 0.01);

  const std::shared_ptr<VoxelMap> held = s.map();  // a reader mid-cast
  s.clear(1);
  EXPECT_FALSE(s.map());
  EXPECT_EQ(held->occupiedCount(), m0->occupiedCount());
  EXPECT_EQ(caster.over(held, K, makeCaster).cast(I).countValid(), 64u * 48u)
      << "a reader finishes on the map it took";
  const std::shared_ptr<VoxelMap> m1 = s.ensureMap(K, c, I);
  EXPECT_NE(m1, m0);
  EXPECT_EQ(caster.over(m1, K, makeCaster).cast(I).countValid(), 0u)
      << "the stage follows the session's new, empty map";
  fuser.over(m1, K, makeFuser).fuse(DepthImage(64, 48, 2.005f), I);  // the writer too
  EXPECT_NEAR(caster.over(s.map(), K, makeCaster).cast(I).at(32, 24), 2.005, 0.01);

  // Epochs: frames of the map's epoch belong to it; an older one is dropped; a newer one (a
  // registration that reset in another process) clears the map and is adopted.
  EXPECT_TRUE(s.adopt(1));
  EXPECT_FALSE(s.adopt(0));
  EXPECT_TRUE(s.map());
  EXPECT_TRUE(s.adopt(3));
  EXPECT_EQ(s.epoch(), 3u);
  EXPECT_FALSE(s.map()) << "a newer epoch starts a new map";
  EXPECT_FALSE(s.adopt(2));
}
