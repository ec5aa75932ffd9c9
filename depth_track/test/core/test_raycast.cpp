// Depth from the voxel map: the ray cast of a map built from one frame reproduces that frame
// within one voxel; the skipping ray cast equals the reference march; min_age_frames leaves out
// recently born blocks; range and bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>
#include <tuple>
#include <vector>

#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

using namespace depth_track;

namespace {

// True when pixel (u, v) lies within 2 px of a depth jump > 5 cm (or of a missing return): at
// occluding edges a voxel hit by a foreground pixel can shadow a background pixel.
bool nearEdge(const DepthImage& d, int u, int v) {
  for (int dv = -2; dv <= 2; ++dv)
    for (int du = -2; du <= 2; ++du) {
      const int x = u + du, y = v + dv;
      if (x < 0 || y < 0 || x >= d.width || y >= d.height) return true;
      if (d.at(x, y) <= 0.0f || std::abs(d.at(x, y) - d.at(u, v)) > 0.05f) return true;
    }
  return false;
}

}  // namespace

TEST(Raycast, OneFrameMapReproducesItsDepthWithinAVoxel) {
  // A surface point lies in an occupied voxel; the ray through it meets that voxel (or a
  // neighbour holding another point of the same surface) within one voxel diagonal, sqrt(3) s,
  // of the surface measured along its normal, i.e. sqrt(3) s / cos(incidence) along the ray;
  // away from occluding edges and grazing views.
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  const DepthImage d = run.renderFrame(0, sim::NoiseConfig::forModel(sim::NoiseModel::kNone), 1, 2);
  for (const double s : {0.005, 0.01}) {
    MapConfig cfg;
    cfg.voxel_size_m = s;
    cfg.model = UpdateModel::kHitOnly;
    cfg.occupancy_threshold = 0.5;  // one hit: the single frame shows (the default takes two)
    VoxelMap map(cfg);
    map.placeRegion(run.T_W_C[0]);
    map.fuse(d, run.intrinsics, run.T_W_C[0]);
    const DepthImage v = map.raycast(run.intrinsics, run.T_W_C[0], run.range);
    std::size_t compared = 0, within = 0, missing = 0;
    std::vector<double> err;
    for (int y = 0; y < d.height; ++y)
      for (int x = 0; x < d.width; ++x) {
        if (d.at(x, y) <= 0.0f || nearEdge(d, x, y)) continue;
        const Eigen::Vector3d p = run.intrinsics.backProject(x, y, d.at(x, y)).cast<double>();
        if (!map.region().contains(run.T_W_C[0] * p)) continue;  // not fused
        // Along the ray a voxel's extent grows as 1 / cos(incidence): normal from neighbours.
        const Eigen::Vector3d px =
            run.intrinsics.backProject(x + 1, y, d.at(x + 1, y)).cast<double>() - p;
        const Eigen::Vector3d py =
            run.intrinsics.backProject(x, y + 1, d.at(x, y + 1)).cast<double>() - p;
        const double cos_inc = std::abs(px.cross(py).normalized().dot(p.normalized()));
        if (cos_inc < 0.2) continue;  // grazing beyond 78 deg
        ++compared;
        if (v.at(x, y) <= 0.0f) {
          ++missing;
          continue;
        }
        const double e = std::abs(v.at(x, y) - d.at(x, y));
        err.push_back(e);
        within += e * cos_inc <= std::sqrt(3.0) * s;
      }
    ASSERT_GT(compared, 200000u);
    std::sort(err.begin(), err.end());
    // Where a pixel's footprint (z / f: 7 mm at the 3.2 m back wall) exceeds the voxel, one frame
    // leaves a lattice of unhit voxels (thesis fig. 5.5) that a few rays pass through.
    EXPECT_LT(static_cast<double>(missing) / compared, 0.01) << "voxel " << s;
    EXPECT_GT(static_cast<double>(within) / compared, 0.99) << "voxel " << s;
    EXPECT_LE(err[err.size() / 2], 0.5 * s + 1e-4) << "voxel " << s;
  }
}

TEST(Raycast, SkippingEqualsReferenceMarch) {
  // Map of a few noisy frames; views at reduced resolution (the reference march is slow).
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  MapConfig cfg;
  cfg.voxel_size_m = 0.01;
  VoxelMap map(cfg);
  map.placeRegion(run.T_W_C[0]);
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  for (std::size_t i = 0; i < run.size(); i += 25)
    map.fuse(run.renderFrame(i, noise, 3, 2), run.intrinsics, run.T_W_C[i]);
  PinholeIntrinsics k = run.intrinsics;
  k.width = 160, k.height = 120, k.fx /= 4, k.fy /= 4, k.cx /= 4, k.cy /= 4;
  for (const std::size_t i : {std::size_t{0}, run.size() / 2, run.size() - 1}) {
    Eigen::Isometry3d T = run.T_W_C[i];
    T.linear() =
        T.linear() * Eigen::AngleAxisd(0.2, Eigen::Vector3d(0.3, 1, 0.2).normalized()).matrix();
    const DepthImage fast = map.raycast(k, T, run.range);
    const DepthImage fast2 = map.raycast(k, T, run.range, 2);
    const DepthImage ref = map.raycastReference(k, T, run.range);
    std::size_t differ = 0, valid = 0;
    for (std::size_t p = 0; p < ref.data.size(); ++p) {
      valid += ref.data[p] > 0;
      differ += std::abs(fast.data[p] - ref.data[p]) > 1e-4f;
      EXPECT_EQ(fast.data[p], fast2.data[p]);
    }
    EXPECT_GT(valid, 12000u);
    EXPECT_LE(differ, ref.data.size() / 10000)
        << "pose " << i;  // voxel-corner tie-breaks only  // voxel-corner tie-breaks only
  }
}

TEST(Raycast, SkippingEqualsReferenceMarchOnAFiveMillimetreMap) {
  // The map the ray-cast benchmark uses (5 mm voxels, L515 noise), from fewer frames, at the
  // 320x240 loop closure resolution. The run's own poses are axis-aligned at the start, so many
  // rays pass exactly through voxel edges there: a voxel the ray only grazes must not start a run.
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  VoxelMap map{MapConfig{}};
  map.placeRegion(run.T_W_C[0]);
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  // Every 8th frame: at the default threshold a voxel takes two hits, so a surface must be seen
  // by two of the fused frames (every 16th, as before the default changed, leaves 70 % of pose
  // 0's pixels).
  for (std::size_t i = 0; i < run.size(); i += 8)
    map.fuse(run.renderFrame(i, noise, 42, 2), run.intrinsics, run.T_W_C[i]);
  const PinholeIntrinsics k = downsampledIntrinsics(run.intrinsics, 2);
  for (const std::size_t i : {std::size_t{0}, run.size() / 3}) {
    const DepthImage fast = map.raycast(k, run.T_W_C[i], run.range);
    const DepthImage ref = map.raycastReference(k, run.T_W_C[i], run.range);
    std::size_t differ = 0, valid = 0;
    for (std::size_t p = 0; p < ref.data.size(); ++p) {
      valid += ref.data[p] > 0;
      differ += std::abs(fast.data[p] - ref.data[p]) > 1e-4f;
    }
    // Measured 83.0-83.2 % at pose 0 (its edges are seen by the first fused frame only) and
    // 95.9 % at pose 34 over noise seeds 42, 7 and 1234 (one hit: 94.4 and 99.0 %).
    std::printf("pose %zu: %zu of %zu px valid\n", i, valid, ref.data.size());
    EXPECT_GT(valid, ref.data.size() * 8 / 10) << "pose " << i;
    EXPECT_LE(differ, ref.data.size() / 10000) << "pose " << i;
    // Against the noise-free scene: the run-weighted depth sits on the surface, not on the near
    // side of the noise shell (docs/mapping.md). Measured 1.31-1.32 mm at pose 0 and 0.82-0.85 mm
    // at pose 34 over noise seeds 42, 7 and 1234 (seed 42 with one hit: 0.84 / 0.54 mm; one hit
    // and every 16th frame, before 2026-12-06: 3.49-3.50 / 2.69-2.72 mm); the guard keeps 0.5 mm
    // (ten seed spreads) above that, well under the 7.8 mm that "first occupied voxel" left on the
    // chair map.
    const DepthImage truth = downsampleDepth(
        run.renderFrame(i, sim::NoiseConfig::forModel(sim::NoiseModel::kNone), 1, 2), 2);
    std::vector<double> err;
    for (int y = 0; y < truth.height; ++y)
      for (int x = 0; x < truth.width; ++x)
        if (truth.at(x, y) > 0.0f && fast.at(x, y) > 0.0f && !nearEdge(truth, x, y))
          err.push_back(std::abs(fast.at(x, y) - truth.at(x, y)));
    ASSERT_GT(err.size(), truth.data.size() / 2) << "pose " << i;
    std::nth_element(err.begin(), err.begin() + err.size() / 2, err.end());
    std::printf("pose %zu: median |virtual - true| %.2f mm over %zu px\n", i,
                1000.0 * err[err.size() / 2], err.size());
    EXPECT_LT(err[err.size() / 2], 0.0018) << "pose " << i;
  }
}

TEST(Raycast, RangeEmptyMapAndBadInput) {
  // 64x48 px at f = 200 px: 5 mm pixel footprint at 1 m, under the 1 cm voxel (no lattice gaps).
  const PinholeIntrinsics k = PinholeIntrinsics::isotropic(64, 48, 200.0);
  MapConfig cfg;
  cfg.bounded = false;
  cfg.voxel_size_m = 0.01;
  cfg.occupancy_threshold = 0.5;  // one hit: the single frame shows (the default takes two)
  VoxelMap map(cfg);
  EXPECT_EQ(map.raycast(k, Eigen::Isometry3d::Identity(), DepthRange{}).countValid(), 0u);
  map.fuse(DepthImage(64, 48, 1.005f), k, Eigen::Isometry3d::Identity());  // wall at 1 m
  EXPECT_EQ(map.raycast(k, Eigen::Isometry3d::Identity(), DepthRange{0.5, 4.0}).countValid(),
            64u * 48u);
  // The wall is closer than the minimum range: no return, as on the real camera.
  EXPECT_EQ(map.raycast(k, Eigen::Isometry3d::Identity(), DepthRange{1.2, 4.0}).countValid(), 0u);
  // ... and beyond the maximum range.
  EXPECT_EQ(map.raycast(k, Eigen::Isometry3d::Identity(), DepthRange{0.1, 0.9}).countValid(), 0u);
  Eigen::Isometry3d bad = Eigen::Isometry3d::Identity();
  bad.translation().y() = INFINITY;
  EXPECT_THROW(map.raycast(k, bad, DepthRange{}), std::invalid_argument);
  EXPECT_THROW(map.raycast(k, Eigen::Isometry3d::Identity(), DepthRange{2.0, 1.0}),
               std::invalid_argument);
}

TEST(Raycast, MinAgeFramesLeavesOutRecentlyBornBlocks) {
  // Two views of the chair room, the second turned 35 deg to the side: its returns reach blocks
  // the first did not. With min_age_frames = 1 only blocks born in the first
  // frame form the model, so every virtual return must lie in a block the first frame's map
  // alone has, and returns in the second frame's new blocks drop out.
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  const auto clean = sim::NoiseConfig::forModel(sim::NoiseModel::kNone);
  Eigen::Isometry3d T = run.T_W_C[0];
  T.linear() =
      T.linear() * Eigen::AngleAxisd(35.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()).matrix();
  MapConfig cfg;
  cfg.model = UpdateModel::kHitOnly;
  cfg.bounded = false;
  cfg.occupancy_threshold = 0.5;  // one hit: each single frame shows (the default takes two)
  VoxelMap first_only(cfg), both(cfg);
  const DepthImage d0 = run.renderFrame(0, clean, 1, 2);
  const DepthImage d1 = sim::renderDepth(run.scene, run.intrinsics, T, run.range);
  first_only.fuse(d0, run.intrinsics, run.T_W_C[0]);
  both.fuse(d0, run.intrinsics, run.T_W_C[0]);
  both.fuse(d1, run.intrinsics, T);
  // Blocks (8^3 voxels) holding a voxel of the first frame.
  std::set<std::tuple<int, int, int>> first_blocks;
  for (const VoxelKey& k : first_only.occupiedKeys())
    first_blocks.emplace(k.x() >> 3, k.y() >> 3, k.z() >> 3);
  const DepthImage all = both.raycast(run.intrinsics, T, run.range);
  const DepthImage aged = both.raycast(run.intrinsics, T, run.range, 1, 1);
  std::size_t n_all = 0, n_aged = 0, aged_in_first = 0;
  for (int v = 0; v < all.height; ++v)
    for (int u = 0; u < all.width; ++u) {
      n_all += all.at(u, v) > 0.0f;
      if (!(aged.at(u, v) > 0.0f)) continue;
      ++n_aged;
      const VoxelKey k =
          both.keyOf(T * run.intrinsics.backProject(u, v, aged.at(u, v)).cast<double>());
      aged_in_first += first_blocks.count({k.x() >> 3, k.y() >> 3, k.z() >> 3});
    }
  EXPECT_GT(n_aged, 10000u);
  EXPECT_LT(n_aged, n_all - 10000u) << "the second frame's new blocks should drop out";
  EXPECT_GT(static_cast<double>(aged_in_first), 0.999 * static_cast<double>(n_aged));
  // Asking for more age than the map has gives an empty image; a negative age is an error.
  EXPECT_EQ(both.raycast(run.intrinsics, T, run.range, 1, 2).countValid(), 0u);
  EXPECT_THROW(both.raycast(run.intrinsics, T, run.range, 1, -1), std::invalid_argument);
}
