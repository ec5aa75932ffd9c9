// The map as storage with stages over it: a MapRayCaster (own scratch, own pool) casts the
// pixels VoxelMap::raycast casts; ray casts on two threads while a fuser writes see the map
// between whole frames, never a half-fused one. The loop closer's map -> odom correction,
// stamped with its frame, holds for later odometry poses, and the mapper keeping it gives the
// poses of corrections fed back into the tracker.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/map/map_fuser.hpp"
#include "depth_track/core/map/map_raycaster.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

using namespace depth_track;

namespace {
struct ChairRun {
  sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  std::vector<DepthImage> depth;  // frames 0, 8, 16, ...
  std::vector<Eigen::Isometry3d> T_W_C;
  ChairRun() {
    const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
    for (std::size_t i = 0; i < run.size(); i += 8) {
      depth.push_back(run.renderFrame(i, noise, 3, 2));
      T_W_C.push_back(run.T_W_C[i]);
    }
  }
};
const ChairRun& chair() {
  static const ChairRun c;
  return c;
}
}  // namespace

TEST(MapRayCaster, CastsTheMapsPixelsWithItsOwnScratchAndPool) {
  const ChairRun& c = chair();
  VoxelMap map{MapConfig{}};
  map.placeRegion(c.T_W_C.front());
  MapFuser fuser(map, c.run.intrinsics);
  for (std::size_t k = 0; k < c.depth.size(); ++k) fuser.fuse(c.depth[k], c.T_W_C[k]);
  EXPECT_EQ(fuser.timing().count(), c.depth.size());
  EXPECT_EQ(map.framesFused(), static_cast<int>(c.depth.size()));
  MapRayCaster one(map, c.run.intrinsics, c.run.range);
  MapRayCaster two(map, c.run.intrinsics, c.run.range, std::make_shared<const WorkerPool>(2));
  // Poses in an order that changes the view a lot between calls: stale scratch would show.
  std::size_t valid = 0;
  for (std::size_t k : {3u, 0u, 11u, 5u, 12u}) {
    for (const int age : {0, 4}) {
      const DepthImage ref = map.raycast(c.run.intrinsics, c.T_W_C[k], c.run.range, 1, age);
      EXPECT_EQ(one.cast(c.T_W_C[k], age).data, ref.data) << "pose " << k << " age " << age;
      EXPECT_EQ(two.cast(c.T_W_C[k], age).data, ref.data) << "pose " << k << " age " << age;
      valid += ref.countValid();
    }
  }
  EXPECT_GT(valid, 10u * 100000u);  // the views see the chair and the room: mostly returns
  EXPECT_THROW(one.cast(c.T_W_C[0], -1), std::invalid_argument);
  EXPECT_THROW(MapRayCaster(map, c.run.intrinsics, DepthRange{2.0, 1.0}), std::invalid_argument);
}

// A fuser adds frames on one thread while two casters cast on two others. Every image a reader
// gets must be the image of one of the map's states between whole frames (each known from a
// second map fused one frame at a time), and each reader must see those states in order.
TEST(MapStorage, ConcurrentReadersSeeWholeFramesOnly) {
  const ChairRun& c = chair();
  const PinholeIntrinsics K = downsampledIntrinsics(c.run.intrinsics, 2);
  const Eigen::Isometry3d view = c.T_W_C[6];
  const std::size_t first = 4, n = c.depth.size();
  std::vector<std::vector<float>> expected;  // state s: frames 0 .. first + s - 1 fused
  std::vector<std::size_t> expected_occupied;
  {
    VoxelMap serial{MapConfig{}};
    serial.placeRegion(c.T_W_C.front());
    MapFuser fuser(serial, c.run.intrinsics);
    for (std::size_t k = 0; k < n; ++k) {
      fuser.fuse(c.depth[k], c.T_W_C[k]);
      if (k + 1 < first) continue;
      expected.push_back(serial.raycast(K, view, c.run.range).data);
      expected_occupied.push_back(serial.occupiedCount());
    }
  }
  for (std::size_t s = 1; s < expected.size(); ++s)
    ASSERT_NE(expected[s], expected[s - 1]) << "each frame must change the view, state " << s;

  VoxelMap map{MapConfig{}};
  map.placeRegion(c.T_W_C.front());
  MapFuser fuser(map, c.run.intrinsics);
  for (std::size_t k = 0; k < first; ++k) fuser.fuse(c.depth[k], c.T_W_C[k]);
  std::atomic<bool> done{false};
  struct Seen {
    std::vector<int> states;  // index into expected, -1 = matches none
    std::vector<int> occupied_states;
  };
  Seen seen[2];
  auto reader = [&](Seen* out) {
    MapRayCaster caster(map, K, c.run.range);
    bool last = false;
    while (!last) {
      last = done.load();  // one more cast after the writer finished
      const std::vector<float> img = caster.cast(view).data;
      const auto it = std::find(expected.begin(), expected.end(), img);
      out->states.push_back(it == expected.end() ? -1 : static_cast<int>(it - expected.begin()));
      const auto occ =
          std::find(expected_occupied.begin(), expected_occupied.end(), map.occupiedCount());
      out->occupied_states.push_back(
          occ == expected_occupied.end() ? -1 : static_cast<int>(occ - expected_occupied.begin()));
    }
  };
  std::thread r0(reader, &seen[0]), r1(reader, &seen[1]);
  double waited_ms = 0.0;
  for (std::size_t k = first; k < n; ++k)
    waited_ms += fuser.fuse(c.depth[k], c.T_W_C[k]).ms_lock_wait;
  done = true;
  r0.join();
  r1.join();
  for (const Seen& s : seen) {
    ASSERT_GE(s.states.size(), 2u);
    for (std::size_t i = 0; i < s.states.size(); ++i) {
      ASSERT_GE(s.states[i], 0) << "cast " << i << " shows no whole-frame state of the map";
      ASSERT_GE(s.occupied_states[i], 0) << "occupied count " << i << " of no whole-frame state";
      if (i > 0) {
        EXPECT_GE(s.states[i], s.states[i - 1]) << "a reader saw the map go back";
      }
    }
    EXPECT_EQ(s.states.back(), static_cast<int>(expected.size()) - 1) << "the last cast is final";
  }
  std::printf("casts during fusion: %zu and %zu; the fuser waited %.1f ms for readers in all\n",
              seen[0].states.size(), seen[1].states.size(), waited_ms);
}

namespace {
// An odometry whose frame is off the map's by E (T_O_C = E T_M_C): 12 mm and 0.6 deg.
Eigen::Isometry3d odomError() {
  Eigen::Isometry3d E = Eigen::Isometry3d::Identity();
  E.linear() = Eigen::AngleAxisd(0.6 * M_PI / 180.0, Eigen::Vector3d::UnitY()).matrix();
  E.translation() = Eigen::Vector3d(0.012, -0.008, 0.01);
  return E;
}
double degBetween(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd((a.inverse() * b).rotation()).angle() * 180.0 / M_PI;
}
}  // namespace

// Loop closure corrects map -> odom, stamped with its frame: the tracker's odometry poses of
// later frames, mapped through that correction, are in the map frame too (what a mapper running
// frames behind the tracker needs). On a 5 mm map of the chair run fused at the true poses,
// every map-frame pose is asserted within a voxel and 0.2 deg of the truth (the loop-closure
// tests' bound for one correction).
TEST(LoopCloser, StampedCorrectionHoldsForLaterFrames) {
  const ChairRun& c = chair();
  VoxelMap map{MapConfig{}};
  map.placeRegion(c.T_W_C.front());
  MapFuser fuser(map, c.run.intrinsics);
  for (std::size_t k = 0; k < 6; ++k) fuser.fuse(c.depth[k], c.T_W_C[k]);  // frames 0..40
  LoopClosureConfig lc;
  lc.enabled = true;
  lc.reference = LoopReference::kRaycast;  // a map fused here, no frames observed
  lc.min_model_age_frames = 0;
  LoopCloser closer(map, c.run.intrinsics, c.run.range, lc);
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  const Eigen::Isometry3d E = odomError();
  const double voxel = map.config().voxel_size_m;
  const std::size_t i = 20;
  const Eigen::Isometry3d T_O_C = E * c.run.T_W_C[i];
  const LoopClosureResult r =
      closer.attempt(c.run.renderFrame(i, noise, 99, 2), c.run.stamps_s[i], T_O_C);
  ASSERT_TRUE(r.accepted) << r.reason;
  EXPECT_EQ(r.correction.stamp_s, c.run.stamps_s[i]);
  EXPECT_LT((r.T_W_C.translation() - c.run.T_W_C[i].translation()).norm(), voxel);
  EXPECT_LT(degBetween(r.T_W_C, c.run.T_W_C[i]), 0.2);
  EXPECT_LT(((r.correction.T_M_O * T_O_C).matrix() - r.T_W_C.matrix()).norm(), 1e-12);
  // Ten frames later (10 cm closer to the chair), the same correction still maps odom to map.
  for (const std::size_t later : {25u, 30u}) {
    const Eigen::Isometry3d T_M_C = r.correction.T_M_O * (E * c.run.T_W_C[later]);
    EXPECT_LT((T_M_C.translation() - c.run.T_W_C[later].translation()).norm(), voxel) << later;
    EXPECT_LT(degBetween(T_M_C, c.run.T_W_C[later]), 0.2) << later;
  }
  // An attempt from the corrected prediction has (almost) nothing left to correct: accepted or
  // in the dead band, its correction keeps the map-frame pose within the same bound.
  const std::size_t j = 24;
  const LoopClosureResult again =
      closer.attempt(c.run.renderFrame(j, noise, 98, 2), c.run.stamps_s[j], E * c.run.T_W_C[j],
                     r.correction.T_M_O);
  EXPECT_LT(again.correction_m, voxel) << again.reason;
  EXPECT_EQ(again.correction.stamp_s, c.run.stamps_s[j]);
  const Eigen::Isometry3d T_M_Cj = again.correction.T_M_O * (E * c.run.T_W_C[j]);
  EXPECT_LT((T_M_Cj.translation() - c.run.T_W_C[j].translation()).norm(), voxel);
  if (!again.accepted) {
    EXPECT_EQ(again.correction.T_M_O.matrix(), r.correction.T_M_O.matrix());
  }
  EXPECT_EQ(closer.timing().count(), 2u);
  // A corrupt correction is named, not cast from.
  Eigen::Isometry3d corrupt = r.correction.T_M_O;
  corrupt.translation().x() = std::numeric_limits<double>::quiet_NaN();
  try {
    closer.attempt(c.depth[5], c.run.stamps_s[j], E * c.run.T_W_C[j], corrupt);
    ADD_FAILURE() << "a NaN correction was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("T_M_O"), std::string::npos) << e.what();
  }
  EXPECT_EQ(closer.timing().count(), 2u);
}

// The graph's way (the odometry never corrected, the mapper keeping map -> odom) against the
// offline tool's (accepted corrections fed back into the odometry): the same poses up to
// rounding. An odometry biased by 0.03 deg and 0.6 mm per step drifts past the dead band, so
// corrections are accepted along the way. Both references: the ray cast on the chair run (6 of
// 13 accepted), the surface layer on rt3 (16 of 93; on the chair run its coverage stays below
// half the view while the camera closes in, and none is accepted).
TEST(Mapper, ProcessOdomEqualsFeedingCorrectionsBack) {
  for (const LoopReference reference : {LoopReference::kRaycast, LoopReference::kSurface}) {
    SCOPED_TRACE("reference " + toString(reference));
    const bool surface = reference == LoopReference::kSurface;
    const sim::RenderedRun run = sim::makeRun(surface ? "rt3" : "xtest1_05_chair");
    const std::size_t frames = run.size();
    const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
    Eigen::Isometry3d bias = Eigen::Isometry3d::Identity();
    bias.linear() = Eigen::AngleAxisd(0.03 * M_PI / 180.0, Eigen::Vector3d::UnitY()).matrix();
    bias.translation() = Eigen::Vector3d(0.0006, 0.0, 0.0);
    MapperConfig mc;
    mc.range = run.range;
    mc.loop.enabled = true;
    mc.loop.reference = reference;
    mc.loop.cl_step = 4;
    mc.loop.min_model_age_frames = 8;
    Mapper fed_back(run.intrinsics, mc, run.T_W_C.front());
    Mapper graph(run.intrinsics, mc, run.T_W_C.front());
    Eigen::Isometry3d T_W_C = run.T_W_C.front(), T_O_C = run.T_W_C.front();
    double worst_m = 0.0, worst_deg = 0.0, stamp = -1.0;
    for (std::size_t i = 0; i < frames; i += 2) {
      if (i > 0) {
        const Eigen::Isometry3d motion = run.T_W_C[i - 2].inverse() * run.T_W_C[i] * bias;
        T_W_C = T_W_C * motion;
        T_O_C = T_O_C * motion;
      }
      const DepthImage d = run.renderFrame(i, noise, 5, 2);
      const MapperFrame a = fed_back.process(d, T_W_C);
      T_W_C = a.T_W_C;  // the correction moves the odometry itself
      const MapperFrame b = graph.processOdom(d, run.stamps_s[i], T_O_C);
      if (b.loop_attempted && std::getenv("DT_VERBOSE"))
        std::printf("frame %zu: %s\n", i, b.loop.reason.c_str());
      EXPECT_EQ(a.loop_attempted, b.loop_attempted);
      EXPECT_EQ(a.loop.accepted, b.loop.accepted) << "frame " << i;
      if (b.loop.accepted) stamp = run.stamps_s[i];
      EXPECT_EQ(b.correction.stamp_s, std::max(0.0, stamp));
      EXPECT_EQ(b.correction.T_M_O.matrix(), graph.correction().T_M_O.matrix());
      worst_m = std::max(worst_m, (a.T_W_C.translation() - b.T_W_C.translation()).norm());
      worst_deg = std::max(worst_deg, degBetween(a.T_W_C, b.T_W_C));
    }
    EXPECT_GE(graph.loopAccepted(), 2);
    EXPECT_EQ(graph.loopAccepted(), fed_back.loopAccepted());
    EXPECT_LT(worst_m, 1e-9);
    EXPECT_LT(worst_deg, 1e-7);
    std::printf("%d of %d corrections accepted; the two ways differ by %.2e m, %.2e deg at most\n",
                graph.loopAccepted(), graph.loopAttempts(), worst_m, worst_deg);
  }
}
