// The map as storage with stages over it: a MapRayCaster (own scratch, own pool) casts the
// pixels VoxelMap::raycast casts; ray casts on two threads while a fuser writes see the map
// between whole frames, never a half-fused one.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <thread>
#include <vector>

#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/map/map_fuser.hpp"
#include "depth_track/core/map/map_raycaster.hpp"
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
