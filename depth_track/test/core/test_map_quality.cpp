// Map quality as numbers on the rendered XTest1_05_Chair run (known geometry): precision and
// completeness of the map fused at tracked poses, and its voxel-set difference against the map
// fused at ground-truth poses (ImageTest=2).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include "depth_track/core/map/map_quality.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "test_seed.hpp"

using namespace depth_track;

TEST(MapQuality, VoxelSetDifferenceCountsWhatIsOff) {
  std::vector<VoxelKey> a, b;
  for (int x = 0; x < 10; ++x) {
    a.emplace_back(x, 0, 0);
    b.emplace_back(x, 0, 0);
  }
  b.emplace_back(0, 1, 0);  // next to a: matched within one voxel
  a.emplace_back(5, 5, 5);  // far from b: "extrusion"
  const VoxelSetDifference d = voxelSetDifference(a, b, 1);
  EXPECT_EQ(d.both, 10u);
  EXPECT_EQ(d.a_far, 1u);
  EXPECT_EQ(d.b_far, 0u);
  EXPECT_NEAR(d.jaccard, 10.0 / 12.0, 1e-12);
  EXPECT_EQ(voxelSetDifference(a, b, 0).b_far, 1u);
}

TEST(MapQuality, ChairRunTrackedMapIsPreciseAndCloseToTheGroundTruthMap) {
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  MapperConfig mc;
  mc.range = run.range;
  // For comparison: one hit makes a voxel occupied (OctoMap's 0.5, the default until
  // 2026-12-06), and the same with every return fused where it was measured (snap_cell 0).
  mc.map.occupancy_threshold = 0.5;
  Mapper one_hit(run.intrinsics, mc, run.T_W_C.front());
  mc.map.snap_cell_px = 0;
  Mapper unsnapped(run.intrinsics, mc, run.T_W_C.front());
  // The default: a voxel counts as occupied after two hits (logit(0.8) = 1.39 > 0.85 per hit):
  // sensor outliers that hit a voxel once do not make a surface.
  mc.map = MapConfig();
  ASSERT_DOUBLE_EQ(mc.map.occupancy_threshold, 0.8);
  Mapper tracked(run.intrinsics, mc, run.T_W_C.front());
  Mapper truth(run.intrinsics, mc, run.T_W_C.front());
  Tracker tracker(run.intrinsics, TrackerConfig{}, run.T_W_C.front());
  std::vector<Eigen::Vector3d> surface;
  const std::uint64_t seed = dt_test::runSeed(11);
  // Every 4th frame (40 mm steps) keeps the test short.
  for (std::size_t i = 0; i < run.size(); i += 4) {
    const DepthImage d = run.renderFrame(i, noise, seed, 2);
    const FrameStatus st = tracker.track(d, run.stamps_s[i]);
    tracked.process(d, st.T_W_C);
    one_hit.process(d, st.T_W_C);
    unsnapped.process(d, st.T_W_C);
    truth.fuse(d, run.T_W_C[i]);
    if (i % 20 == 0)  // visible true surface: noise-free render, every 4th pixel
      for (const Eigen::Vector3d& p : run.visibleSurface(i, 4, 2))
        if (tracked.map().region().contains(p)) surface.push_back(p);
  }
  const double s = mc.map.voxel_size_m;
  auto dist = [&](const Eigen::Vector3d& p) { return run.scene.distanceTo(p); };
  // "Within one voxel of a true surface": the voxel is, or touches, a voxel the surface passes
  // through, i.e. its centre lies within one edge plus half a diagonal, (1 + sqrt(3)/2) s.
  const double tol = oneVoxelTolerance(s);
  const SurfaceQuality q = surfaceQuality(tracked.map(), dist, surface, tol);
  const SurfaceQuality q_gt = surfaceQuality(truth.map(), dist, surface, tol);
  const SurfaceQuality q_strict = surfaceQuality(tracked.map(), dist, surface, s);
  const SurfaceQuality q_one_hit = surfaceQuality(one_hit.map(), dist, surface, tol);
  const SurfaceQuality q_unsnapped = surfaceQuality(unsnapped.map(), dist, surface, tol);
  std::printf("one-hit threshold: precision %.2f %% completeness %.2f %%\n",
              100 * q_one_hit.precision, 100 * q_one_hit.completeness);
  std::printf("one-hit, returns fused as measured (snap_cell 0): precision %.2f %% completeness "
              "%.2f %%\n",
              100 * q_unsnapped.precision, 100 * q_unsnapped.completeness);
  std::printf("precision with the centre within one edge (5 mm): %.2f %%\n",
              100 * q_strict.precision);
  const VoxelSetDifference diff =
      voxelSetDifference(tracked.map().occupiedKeys(), truth.map().occupiedKeys(), 1);
  std::printf(
      "tracked poses: precision %.2f %% completeness %.2f %% (%zu occupied); ground-truth poses: "
      "precision %.2f %% completeness %.2f %%; tracked vs truth map: jaccard %.3f, %.2f %% of "
      "tracked voxels > 1 voxel from the truth map, %.2f %% of truth voxels missed; %s\n",
      100 * q.precision, 100 * q.completeness, q.occupied, 100 * q_gt.precision,
      100 * q_gt.completeness, diff.jaccard, 100 * diff.a_far_fraction, 100 * diff.b_far_fraction,
      tracked.summary().c_str());
  // Product target: 95 % precision (README). The guards sit near what is measured with the noise
  // seeds 11 (committed), 1, 2, 3, 4, 5 (DT_TEST_SEED, test_seed.hpp; 2026-12-05, returns snapped
  // to their cell's plane, snap_cell 16, the default since then):
  //   precision           99.96 on every seed                    -> guard 99.9 %
  //   completeness        99.00 98.99 99.00 99.00 99.00 99.04 %  -> guard 98.8 %
  //   strict (5 mm)       98.33 98.34 98.32 98.33 98.34 98.36 %  -> guard 98.0 %
  //   true poses: prec.   99.96 on every seed                    -> guard 99.9 %
  //               compl.  99.01 99.01 99.02 99.02 99.01 99.02 %  -> guard 98.8 %
  //   Jaccard             0.960 0.956 0.962 0.954 0.960 0.962    -> guard 0.94
  //   extruded / missed   0.02 / 0.02 % on every seed            -> guard 0.1 %
  // Since the near side of depth edges and cells too small to place their plane are left out of
  // the hits (edge_margin 2, drop_unplaced; 2026-12-06), seeds 11, 1-5:
  //   precision           99.96-99.97 %                          -> guard 99.9 %
  //   completeness        98.73 98.74 98.77 98.74 98.76 98.78 %  -> guard 98.5 %
  //   strict (5 mm)       98.60 98.59 98.58 98.58 98.58 98.61 %  -> guard 98.0 %
  //   true poses: prec.   99.96-99.97 %                          -> guard 99.9 %
  //               compl.  98.76 98.76 98.79 98.76 98.76 98.78 %  -> guard 98.5 %
  //   Jaccard             0.961 0.957 0.962 0.955 0.961 0.963    -> guard 0.94
  // The rims those rules leave out cost 0.25 points of completeness here; on the D435 chair run
  // they buy 7 points of precision (docs/mapping.md, "Depth edges").
  // (Before snapping, 2026-12-02: precision 99.31, strict 75.1 %, Jaccard 0.92.) The seeds spread
  // by up to 0.05 points; each guard is 0.06-0.3 points below the lowest seed, so a change in
  // fusion or tracking that costs the map a few tenths of a point fails here. The Jaccard index is
  // the noisiest (0.008: it counts single voxels at the surfaces' edges) and its guard is 1.7
  // spreads below the lowest; the extrusion guard is 5x its measured share. Run time stays that
  // of one seed: the spread is measured with the test itself, not inside it.
  EXPECT_GE(q.precision, 0.95);  // product target
  EXPECT_GE(q.precision, 0.999);
  EXPECT_GE(q.completeness, 0.985);
  EXPECT_GE(q_strict.precision, 0.98);
  EXPECT_GE(q_gt.precision, 0.999);
  EXPECT_GE(q_gt.completeness, 0.985);
  EXPECT_GE(diff.jaccard, 0.94);
  EXPECT_LT(diff.a_far_fraction, 0.001);
  EXPECT_LT(diff.b_far_fraction, 0.001);
  // With one hit (the default until 2026-12-06) a voxel hit once by a stray return counts:
  // precision 98.95-98.99 %,
  // completeness 99.77-99.80 % over the same seeds (guards 0.25-0.3 points below the lowest).
  // Fused as measured (snap_cell 0) the one-hit map is 93.83-93.87 % precise (completeness the
  // same): snapping is what meets the 95 % target with one hit, and costs no completeness.
  EXPECT_GE(q_one_hit.precision, 0.987);
  EXPECT_GE(q_one_hit.completeness, 0.995);
  EXPECT_LT(q_one_hit.precision, q.precision);
  EXPECT_GT(q_one_hit.precision, q_unsnapped.precision + 0.04);
  EXPECT_LT(q_unsnapped.precision, 0.95);
  EXPECT_GT(q_one_hit.completeness, q_unsnapped.completeness - 0.002);
}
