// Whole runs through the tracker, scored against ground truth: the rendered thesis test runs
// (xtest1_05_chair, rt3) with the L515 noise model and with D435-class noise, and the real TUM
// fr3/teddy and fr1/xyz Kinect sequences.
// Each rendered run is held to two bounds: the product's accuracy target (README; they beat the
// thesis's tables 5.3 and 5.5), and a guard near what is measured, so that a regression many
// times the measured error fails long before the target does. The guards' margins come from the
// seed-to-seed spread, measured with the noise seeds 1 to 5 (DT_TEST_SEED, test_seed.hpp;
// 2026-12-01): max rotation / position error of each seed, in the comments below. Those seed
// figures were measured with the registration model off; with it on (the default since
// 2026-12-03) seed 1 gives: chair P2L 0.014 deg / 0.63 mm, Cell Search 0.017 deg / 0.97 mm,
// P2P 0.760 deg / 24.0 mm, rt3 0.034 deg / 1.23 mm, all inside the same bounds.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <utility>

#include "../shared_data.hpp"
#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/sim/imu.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/core/tum_io.hpp"
#include "test_seed.hpp"

using namespace depth_track;

namespace {

struct RunResult {
  ThesisErrors errors;
  int tracked = 0, frames = 0;
  int unconfirmed = 0;  ///< frames the basin probe flagged (FrameStatus::unconfirmed_directions)
  int deep_kept = 0;    ///< frames the deep returns confirmed (FrameStatus::basin_deep_kept)
};

// The run's first `frames` frames (0 = all) with noise seed `seed` (0 = the suite's, runSeed(1)).
RunResult trackRendered(const std::string& name, const TrackerConfig& cfg,
                        sim::NoiseModel noise_model = sim::NoiseModel::kL515,
                        std::uint64_t seed = 0, std::size_t frames = 0) {
  const sim::RenderedRun run = sim::makeRun(name);
  const sim::NoiseConfig noise = sim::NoiseConfig::forModel(noise_model);
  Tracker tracker(run.intrinsics, cfg);
  if (seed == 0) seed = dt_test::runSeed(1);
  const std::size_t n = frames > 0 ? std::min(frames, run.size()) : run.size();
  std::vector<Eigen::Isometry3d> est, gt;
  RunResult r;
  for (std::size_t i = 0; i < n; ++i) {
    const FrameStatus st = tracker.track(run.renderFrame(i, noise, seed), run.stamps_s[i]);
    r.tracked += st.tracked;
    r.unconfirmed += st.unconfirmed_directions > 0;
    r.deep_kept += st.basin_deep_kept;
    est.push_back(st.T_W_C);
    gt.push_back(run.T_W_C[i]);
  }
  r.frames = static_cast<int>(n);
  r.errors = computeThesisErrors(est, gt);
  std::printf("%s %s %s: max_err_deg=%.3f,%.3f,%.3f max_err_mm=%.2f,%.2f,%.2f end_drift_mm=%.2f\n",
              name.c_str(), sim::noiseModelName(noise_model).c_str(),
              toString(cfg.registration.method).c_str(), r.errors.max_err_deg.x(),
              r.errors.max_err_deg.y(), r.errors.max_err_deg.z(), r.errors.max_err_mm.x(),
              r.errors.max_err_mm.y(), r.errors.max_err_mm.z(), r.errors.end_drift_mm);
  return r;
}

RunResult trackRendered(const std::string& name, RegistrationMethod method) {
  TrackerConfig cfg;
  cfg.registration.method = method;
  return trackRendered(name, cfg);
}

// Every frame tracked, and the thesis-style maximum errors within the bounds.
void expectTrackedWithin(const RunResult& r, double max_deg, double max_mm) {
  EXPECT_EQ(r.tracked, r.frames);
  EXPECT_LE(r.errors.max_err_deg.maxCoeff(), max_deg);
  EXPECT_LE(r.errors.max_err_mm.maxCoeff(), max_mm);
}

}  // namespace

// Thesis table 5.3 (its rig, best case): 0.43-0.90 deg and 7-17 mm. Target: 0.25 deg, 3 mm.
// Measured, seeds 1-5: 0.022/0.034/0.016/0.027/0.028 deg, 2.10/2.13/0.88/1.38/1.29 mm. Guard
// 0.05 deg (1.5x the largest; the spread is a factor 2); in position the 3 mm target is already
// 1.4x the largest.
TEST(WholeRun, Xtest1ChairPointToPlane) {
  const RunResult r = trackRendered("xtest1_05_chair", RegistrationMethod::kPointToPlane);
  expectTrackedWithin(r, 0.25, 3.0);  // product target
  expectTrackedWithin(r, 0.05, 3.0);  // guard near the measured level
}

// Measured, seeds 1-5: 0.019/0.023/0.013/0.035/0.018 deg, 1.56/2.06/0.97/1.63/1.10 mm. Guard
// 0.05 deg, 3 mm (1.4x and 1.5x the largest).
TEST(WholeRun, Xtest1ChairCellSearch) {
  const RunResult r = trackRendered("xtest1_05_chair", RegistrationMethod::kCellSearch);
  expectTrackedWithin(r, 0.25, 3.0);  // product target
  expectTrackedWithin(r, 0.05, 3.0);  // guard near the measured level
}

// Point-to-point is the thesis's weakest method and ours too (cell means sample surfaces at
// grid-dependent places). Measured, seeds 1-5: 1.31/1.29/1.26/1.39/1.39 deg,
// 24.0/43.2/24.3/24.3/24.4 mm:
// the 40 mm bound this test had failed on seed 2, so the position bound is 60 mm (1.4x the
// largest, the spread being nearly a factor 2); rotation keeps 2.0 deg (1.4x the largest).
TEST(WholeRun, Xtest1ChairPointToPoint) {
  const RunResult r = trackRendered("xtest1_05_chair", RegistrationMethod::kPointToPoint);
  expectTrackedWithin(r, 2.0, 60.0);
}

// Thesis table 5.5: 3.3 deg, 84 mm. Target: 1.0 deg, 15 mm. Measured, seeds 1-5:
// 0.058/0.071/0.073/0.061/0.076 deg, 1.25/1.99/1.41/1.46/1.41 mm. Guard 0.10 deg, 3 mm (1.3x and
// 1.5x the largest).
TEST(WholeRun, Rt3PitchSinusoid) {
  const RunResult r = trackRendered("rt3", RegistrationMethod::kPointToPlane);
  expectTrackedWithin(r, 1.0, 15.0);  // product target
  expectTrackedWithin(r, 0.10, 3.0);  // guard near the measured level
}

// D435-class stereo depth (sigma 3 cm at 2.5 m): with the defaults (5 px cells) the chair run
// ends 4.9 deg and 0.38 m off (and rt3 loses track); config/d435.yaml tracks it. Measured, seeds
// 1-5: 0.45/0.30/0.42/0.35/0.36 deg, 16.2/14.3/14.6/16.5/13.0 mm (the thesis's L515 figures:
// 0.43-0.90 deg, 7-17 mm); the bounds are 1.3x and 1.5x the largest.
TEST(WholeRun, Xtest1ChairD435Preset) {
  TrackerConfig cfg;
  loadTrackerParamsYaml(std::string(DT_SOURCE_DIR) + "/../config/d435.yaml", cfg);
  const RunResult r = trackRendered("xtest1_05_chair", cfg, sim::NoiseModel::kD435);
  expectTrackedWithin(r, 0.6, 25.0);
}

// The same D435-class noise with the defaults (one configuration for every sensor: the noise
// is measured on the first frame; the registration model on). Issue 12's targets: xtest1 0.25 deg
// / 8 mm, rt3 0.5 deg / 15 mm, Room3 1 deg / 40 mm, all three met. Measured, seeds 1-5
// (2026-12-03, degeneracy margin 3), max rotation / position error: xtest1
// 0.230/0.211/0.224/0.220/0.221 deg, 5.02/5.83/5.81/5.68/5.17 mm; rt3 0.405/0.263/0.303/0.255/
// 0.244 deg, 9.65/9.81/9.42/12.22/10.48 mm; Room3 0.295/0.238/0.304/0.288/0.372 deg,
// 7.45/7.36/7.71/8.85/7.11 mm. xtest1's margin in rotation is thin (0.230 of 0.25 deg).
TEST(WholeRun, Xtest1ChairD435Defaults) {
  const RunResult r = trackRendered("xtest1_05_chair", TrackerConfig{}, sim::NoiseModel::kD435);
  expectTrackedWithin(r, 0.25, 8.0);  // target
}

// Neither run has a view the depth cannot fix: the basin probe (basin_probe_below) probes
// 82 / 288 of their frames (seed 1) and flags none.
TEST(WholeRun, Rt3D435Defaults) {
  const RunResult r = trackRendered("rt3", TrackerConfig{}, sim::NoiseModel::kD435);
  expectTrackedWithin(r, 0.5, 15.0);  // target
  EXPECT_EQ(r.unconfirmed, 0);
}

TEST(WholeRun, Room3D435Defaults) {
  const RunResult r = trackRendered("room3", TrackerConfig{}, sim::NoiseModel::kD435);
  expectTrackedWithin(r, 1.0, 40.0);  // target
  EXPECT_EQ(r.unconfirmed, 0);
}

// The Hall1 corridor (8 m straight at 0.3 m/s) with D435 noise. What fixes the motion along it
// lies deep (door frames, and the far end once within 4 m), and D435 noise grows with z^2: the
// inverse-variance weights alone put those pairs at 1/81-1/625 of the near walls', whose
// camera-fixed normal tilts then pull every frame back to the guess. With the weighting
// unbounded (noise_weighting_min 0) the estimate stood still for the first 4.8 m and ended
// 4.9 m short (seeds 1/2: 4914/5063 mm largest position error); with the default floor of 1/32,
// seeds 1-3 69.9/65.7/87.9 mm and 0.414/0.328/0.459 deg, end drift 26.5/30.7/17.1 mm
// (track_sequence, with the degeneracy hysteresis of 2026-12-04; before it 69.9/62.2/87.9 mm,
// 0.350/0.328/0.440 deg, 20.7/24.7/53.5 mm).
// The end drift rests on the last bits of sums: the registration model's per-voxel averages
// taken in another order (2026-12-04: grouped through a table instead of a sort, the same sums)
// move seed 1's from 26.5 to 42.7 mm. Over seeds 1-8, before / after that change: largest
// position error 69.9/65.7/87.9/61.4/57.9/1011/98.0/62.1 and 69.9/67.6/87.9/61.4/63.0/1003/98.0/
// 64.1 mm, end drift 26.5/30.8/17.1/15.7/43.9/990/19.1/22.4 and 42.7/32.0/31.0/13.7/40.3/957/
// 15.3/39.9 mm; after it, seeds 9-20: 85.2/62.0/71.6/147.2/71.2/73.2/129.8/73.1/123.1/109.0/1061/
// 119.7 mm, end drift 43.3/29.0/19.2/141.6/13.6/61.2/120.8/19.5/23.2/46.3/1022/112.8 mm. Seeds 6
// and 19 stand still at the start (docs/tracking.md, "Hall1 with D435 noise, seed 6": not
// solved); over the other 18 the largest error spans 61-147 mm, the end drift 14-142 mm and the
// rotation error reaches 0.450 deg. The guards then were 1.4x the largest of those 18: 210 mm
// largest error and 200 mm end drift, and 0.5 deg (seed 1: 0.434 deg, 69.93 mm, 42.72 mm).
// With crease pooling (PcaConfig::crease_sigmas 2, an option since 2026-12-05, off by default:
// it costs the Hall1 D435 bag of docs/results.md; docs/tracking.md, "Normals across creases") the
// crease cells that held seeds 6 and 19 at zero motion lean no more and all 20 seeds track: largest
// position error 22.7/26.7/56.9/32.1/31.8/41.6/104.1/34.3/74.8/29.9/20.6/34.3/61.1/40.6/126.4/
// 31.3/32.3/30.6/92.1/119.0 mm, end drift 18.8/10.4/54.0/22.7/13.8/30.5/102.2/24.1/62.3/15.9/
// 5.6/24.8/46.8/42.6/121.7/21.0/26.3/27.1/90.1/116.0 mm, rotation up to 0.447 deg (seed 15).
// The defaults kept the guards above (seed 1 here: 0.434 deg, 69.93 mm, end drift 42.72 mm;
// 0.426 deg, 69.93 mm, 43.59 mm since the velocity span is in seconds, 2026-12-05).
// Since 2026-12-06 a frame that holds directions or that the basin probe flags is registered
// again with the deep returns weighted up (basin_deep_floor 0.25; docs/tracking.md, "The deep
// returns' say"), and all 20 seeds track: largest position error 28.1/43.9/26.8/25.7/25.2/27.5/
// 40.7/44.8/48.4/42.4/37.9/68.3/42.7/31.2/32.6/77.0/30.4/44.7/37.8/25.2 mm, end drift 24.1/17.5/
// 11.3/15.3/18.1/16.4/22.4/39.8/11.4/33.0/36.8/15.3/17.2/16.1/33.0/72.2/22.5/29.9/23.2/21.8 mm
// (seed 1: 0.134 deg, 28.06 mm, 24.08 mm). Guards 1.4x the largest: 110 mm and 105 mm; 0.5 deg
// as before.
TEST(WholeRun, Hall1D435Defaults) {
  const RunResult r = trackRendered("hall1", TrackerConfig{}, sim::NoiseModel::kD435);
  expectTrackedWithin(r, 0.5, 110.0);
  EXPECT_LE(r.errors.end_drift_mm, 105.0);
}

// The basin probe on the corridor's start with D435 noise, seed 6: from frame 3 the camera moves
// at 10 mm per frame while the estimate stands still (docs/tracking.md, "Hall1 with D435 noise,
// seed 6"), and until frame 28, when the analysis reads the direction as unfixed and holds it,
// no frame said so. Registered again from its result 2 cm either way along the weakest direction,
// each of those frames ends somewhere else: the valley is flat, and the probe flags every one
// of frames 3-27 (measured 2026-12-05: all 25). The flag by itself changes nothing else: with
// the deep returns' retry off (basin_deep_floor 0; the next test has it on) the poses are those
// of the run without the probe to the last bit. Along the flagged direction the covariance is at
// least the probes' spread.
TEST(WholeRun, Hall1D435Seed6StartIsFlaggedNotSilent) {
  const sim::RenderedRun run = sim::makeRun("hall1");
  const sim::NoiseConfig noise = sim::NoiseConfig::forModel(sim::NoiseModel::kD435);
  TrackerConfig flag_only, off;
  flag_only.basin_deep_floor = 0.0;
  off.basin_probe_below = 0.0;
  Tracker probed(run.intrinsics, flag_only), plain(run.intrinsics, off);
  int silent_before = 0;
  for (std::size_t i = 0; i < 30; ++i) {
    const DepthImage depth = run.renderFrame(i, noise, 6);
    const FrameStatus a = probed.track(depth, run.stamps_s[i]);
    const FrameStatus b = plain.track(depth, run.stamps_s[i]);
    ASSERT_TRUE(a.tracked && b.tracked) << i;
    EXPECT_TRUE(a.T_W_C.isApprox(b.T_W_C, 0.0)) << "frame " << i << ": the probe moved the pose";
    EXPECT_EQ(b.unconfirmed_directions, 0);
    if (i >= 3 && i <= 27) {
      silent_before += b.degenerate_directions == 0;
      EXPECT_TRUE(a.degenerate_directions > 0 || a.unconfirmed_directions > 0)
          << "frame " << i << " unflagged, weakest information " << a.weakest_information;
    }
    EXPECT_FALSE(a.basin_deep_retried);
    if (a.unconfirmed_directions > 0) {
      EXPECT_TRUE(a.basin_probed);
      EXPECT_GT(a.probe_spread_m, TrackerConfig{}.basin_probe_tolerance_m);
      const double sigma_max =
          std::sqrt(a.covariance.bottomRightCorner<3, 3>().eigenvalues().real().maxCoeff());
      EXPECT_GE(sigma_max, a.probe_spread_m) << i;
    }
  }
  // Without the probe frames 3-27 passed as fixed, and they were wrong: the camera is 250 mm
  // down the corridor at frame 27, the estimate within a few millimetres of the start.
  EXPECT_EQ(silent_before, 25);
  EXPECT_GT((run.T_W_C[27].translation() - run.T_W_C[0].translation()).norm(), 0.2);
  TrackerConfig bad;
  bad.basin_probe_tolerance_m = bad.basin_probe_step_m;
  EXPECT_THROW(Tracker(run.intrinsics, bad), std::invalid_argument);
  for (const double floor : {-0.1, 1.5, std::nan("")}) {
    TrackerConfig bad_floor;
    bad_floor.basin_deep_floor = floor;
    EXPECT_THROW(Tracker(run.intrinsics, bad_floor), std::invalid_argument) << floor;
  }
}

// The same start at the defaults: a frame the probe flags is registered once more with the
// depth-noise weighting's floor raised from 1/32 to 1/4 (basin_deep_floor), and that result is
// kept when its own probes confirm it. What fixes the motion along the corridor lies deep (door
// frames, the far end), and at 1/32 the near walls' crease cells outvote it; at 1/4 it decides.
// Measured 2026-12-06, first 150 frames: largest position error 8.1 mm, end drift 4.2 mm (at 1/8:
// 9.9 / 3.8 mm), against 989 / 988 mm with basin_deep_floor 0 (the probe only flags; the test
// above). Over the whole run 27.5 mm largest error (1013 mm before), also with held frames
// retried (their retry does not change these 150 frames). Guards about 2.5x the measured: 20 mm
// largest error, 12 mm end drift (as the IMU test below); and the flag-only run must still stand
// still here (more than 500 mm behind at frame 150), or this test no longer shows what the retry
// does.
TEST(WholeRun, Hall1D435Seed6LeavesTheStartWithTheDeepReturns) {
  const RunResult r = trackRendered("hall1", TrackerConfig{}, sim::NoiseModel::kD435, 6, 150);
  std::printf("hall1 d435 seed 6, 150 frames, defaults: max_err_mm=%.2f end_drift_mm=%.2f, "
              "%d frames flagged, %d confirmed by the deep returns\n",
              r.errors.max_err_mm.maxCoeff(), r.errors.end_drift_mm, r.unconfirmed, r.deep_kept);
  EXPECT_EQ(r.tracked, r.frames);
  EXPECT_GT(r.deep_kept, 0);
  EXPECT_LE(r.errors.max_err_mm.maxCoeff(), 20.0);
  EXPECT_LE(r.errors.end_drift_mm, 12.0);
  TrackerConfig flag_only;
  flag_only.basin_deep_floor = 0.0;
  const RunResult f = trackRendered("hall1", flag_only, sim::NoiseModel::kD435, 6, 150);
  EXPECT_GT(f.errors.end_drift_mm, 500.0);
}

// What the crease pooling option mends: with noise seed 6 the corridor's start reads as standing
// still at the defaults (the estimate 988 mm behind at frame 150), held there by cells whose
// normals are pooled across the wall-floor crease. With crease_sigmas 2: 12.3 mm end drift over
// the first 150 frames (largest position error 15.8 mm).
TEST(WholeRun, Hall1D435Seed6LeavesTheStartWithCreasePooling) {
  TrackerConfig creases;
  creases.pca.crease_sigmas = 2.0;
  creases.basin_deep_floor = 0.0;  // the pooling alone (2026-12-06: 15.2 mm, end 12.1 mm)
  const RunResult r = trackRendered("hall1", creases, sim::NoiseModel::kD435, 6, 150);
  EXPECT_EQ(r.tracked, r.frames);
  EXPECT_LE(r.errors.end_drift_mm, 100.0);
}

// The corridor's start with a camera IMU as motion prior (ImuMotionPrior; a D435i's or D455's
// BMI055, simulated along the run with its noise and a bias, seed 6 for both): the frames the
// view cannot fix keep the IMU's motion, and seed 6 no longer stands still. Measured 2026-12-06,
// first 150 frames: largest position error 12.4 mm (end 3.1 mm; guard 20 mm; 7.2 / 4.1 mm since
// held frames get the deep returns' retry, basin_deep_floor) against 988 mm
// without the IMU (docs/tracking.md); over the whole run (track_sequence --render hall1 --noise
// d435 --seed 6 --imu-sim bmi055) 38.3 mm against 1013 mm (22.4 mm with the held directions on
// the IMU filter's velocity, 38.8 mm before the filter left them out of its measurements, 51.6 mm
// before the lever-arm and gyro-bias fixes; docs/tracking.md).
TEST(WholeRun, Hall1D435Seed6TracksWithAnImu) {
  const sim::RenderedRun run = sim::makeRun("hall1");
  const sim::NoiseConfig noise = sim::NoiseConfig::forModel(sim::NoiseModel::kD435);
  ImuPriorConfig imu_cfg;
  imu_cfg.T_C_I.translation() = Eigen::Vector3d(-0.006, 0.005, 0.012);
  const auto samples = sim::simulateImu(run, imu_cfg.T_C_I, sim::ImuNoiseConfig::bmi055(), 6);
  ImuMotionPrior imu(imu_cfg);
  Tracker tracker(run.intrinsics, TrackerConfig{});
  std::vector<Eigen::Isometry3d> est, gt;
  std::size_t fed = 0;
  int tracked = 0, guessed = 0;
  const std::size_t n = 150;
  for (std::size_t i = 0; i < n; ++i) {
    const double t = run.stamps_s[i];
    fed = imu.addUpTo(samples, fed, t);
    std::optional<Eigen::Isometry3d> guess;
    std::optional<InertialHold> hold;
    if (const auto g = imu.guess(t)) guess = g->T_Cprev_Ccur, hold = g->hold;
    guessed += guess.has_value();
    const FrameStatus st = tracker.track(run.renderFrame(i, noise, 6), t, guess, hold);
    tracked += st.tracked;
    ASSERT_TRUE(imu.update(t, tracker.pose(), trackedPoseCovariance(st))) << imu.reason();
    est.push_back(st.T_W_C);
    gt.push_back(run.T_W_C[i]);
  }
  const ThesisErrors e = computeThesisErrors(est, gt);
  std::printf("hall1 d435 seed 6 with a simulated BMI055, %zu frames: max_err_mm=%.2f,%.2f,%.2f "
              "end_drift_mm=%.2f\n",
              n, e.max_err_mm.x(), e.max_err_mm.y(), e.max_err_mm.z(), e.end_drift_mm);
  EXPECT_EQ(tracked, static_cast<int>(n));
  EXPECT_EQ(guessed, static_cast<int>(n) - 1);
  EXPECT_LE(e.max_err_mm.maxCoeff(), 20.0);
  EXPECT_LE(e.end_drift_mm, 20.0);
}

// The same with the registration model off (model: false, frame-to-keyframe on the frames' own
// cells, the default until 2026-12-03). Measured, seeds 1-5 (2026-12-03, degeneracy margin 3):
// xtest1 0.401/0.365/0.401/0.346/0.402 deg, 8.29/7.34/8.28/6.87/7.92 mm (the 0.25 deg / 8 mm
// target is NOT met: pitch); rt3 0.399/0.438/0.312/0.481/0.311 deg, 8.29/14.38/10.27/9.74/8.75
// mm; Room3 0.454/0.284/0.406/0.319/0.306 deg, 26.16/13.75/22.41/20.24/19.28 mm. xtest1 is held
// to a guard 1.3x the largest; rt3 and Room3 to their targets (rt3's margin is thin: 0.481 of
// 0.5 deg on seed 4, 14.38 of 15 mm on seed 2).
namespace {
TrackerConfig withoutModel() {
  TrackerConfig cfg;
  cfg.model.enabled = false;
  return cfg;
}
}  // namespace

TEST(WholeRun, Xtest1ChairD435WithoutModel) {
  const RunResult r = trackRendered("xtest1_05_chair", withoutModel(), sim::NoiseModel::kD435);
  expectTrackedWithin(r, 0.55, 11.0);  // guard; the 0.25 deg / 8 mm target is not met
}

TEST(WholeRun, Rt3D435WithoutModel) {
  const RunResult r = trackRendered("rt3", withoutModel(), sim::NoiseModel::kD435);
  expectTrackedWithin(r, 0.5, 15.0);  // target
}

TEST(WholeRun, Room3D435WithoutModel) {
  const RunResult r = trackRendered("room3", withoutModel(), sim::NoiseModel::kD435);
  expectTrackedWithin(r, 1.0, 40.0);  // target
}

// Real Kinect data with motion-capture ground truth (TUM RGB-D), tracked with one configuration
// for every sensor: the defaults, which measure the depth noise on the first frame (auto_noise).
// Issue 12's target is ATE RMSE <= 0.03 m on each sequence.
namespace {

// With `mapping`, every frame also goes through a Mapper, accepted loop-closure corrections fed
// back into the tracker as track_sequence does. `stride` > 1 takes every stride-th frame (a
// camera at 30 / stride Hz).
TrajectoryEvaluation trackTum(const std::string& dir, const PinholeIntrinsics& K,
                              const TrackerConfig& cfg, const char* label,
                              const MapperConfig* mapping = nullptr, int* accepted = nullptr,
                              std::size_t stride = 1, int* unconfirmed = nullptr) {
  const std::vector<TumFrame> all = readTumFrameList(dir + "/depth.txt");
  std::vector<TumFrame> frames;
  for (std::size_t i = 0; i < all.size(); i += stride) frames.push_back(all[i]);
  Tracker tracker(K, cfg);
  std::unique_ptr<Mapper> mapper;
  if (mapping) mapper = std::make_unique<Mapper>(K, *mapping, tracker.pose());
  Trajectory est;
  for (const TumFrame& f : frames) {
    const DepthImage depth = loadTumDepth(f.path, 1.0 / 5000.0, DepthRange{});
    FrameStatus st = tracker.track(depth, f.stamp_s);
    if (unconfirmed) *unconfirmed += st.unconfirmed_directions > 0;
    if (mapper) {
      const MapperFrame mf = mapper->process(depth, st.T_W_C);
      if (mf.loop_attempted && mf.loop.accepted) {
        tracker.correctPose(mf.T_W_C);
        st.T_W_C = mf.T_W_C;
      }
    }
    est.push_back({f.stamp_s, st.T_W_C});
  }
  if (mapper) std::printf("%s: %s\n", label, mapper->summary().c_str());
  if (mapper && accepted) *accepted = mapper->loopAccepted();
  const TrajectoryEvaluation ev =
      evaluateTrajectory(est, readTumTrajectory(dir + "/groundtruth.txt"));
  std::printf("%s: %s\n", label, formatEvaluation(ev).c_str());
  return ev;
}

const PinholeIntrinsics kFr3{640, 480, 535.4, 539.2, 320.1, 247.6};
const PinholeIntrinsics kFr1{640, 480, 517.3, 516.5, 318.6, 255.3};

}  // namespace

// fr3/teddy, 196 frames with ground truth. Open3D frame-to-frame point-to-plane ICP scores
// 0.38 m here, a still camera 0.57 m, the L515 defaults without the noise adaptation 0.22 m.
// Measured with the defaults (registration model and depth-noise weighting on): 0.0094 m
// (2026-12-04 with the weighting's floor noise_weighting_min 1/32; 0.0083 m without the floor,
// 0.0643 m before the weighting was on). The run is deterministic (one thread, no random
// state): the guard is 1.3x the measured figure, below the 0.03 m target.
// The basin probe probes 35 of its frames and flags none.
TEST(WholeRun, TumTeddyDefaults) {
  DT_TEDDY_OR_SKIP(dir);
  int unconfirmed = 0;
  const TrajectoryEvaluation ev = trackTum(dir, kFr3, TrackerConfig{}, "teddy defaults", nullptr,
                                           nullptr, 1, &unconfirmed);
  EXPECT_EQ(unconfirmed, 0);
  EXPECT_GE(ev.standard.frames, 190u);
  EXPECT_LE(ev.standard.ate_rmse_m, 0.03);    // target
  EXPECT_LE(ev.standard.ate_rmse_m, 0.0125);  // guard
}

// fr1/xyz, 798 frames: the sequence the noise adaptation was validated on, not developed on.
// Measured with the defaults: 0.0153 m (2026-12-04; 0.0160 m before the weighting); bound 0.02 m.
// The basin probe probes 2 of its frames and flags none.
TEST(WholeRun, TumFr1XyzDefaults) {
  DT_FR1_XYZ_OR_SKIP(dir);
  int unconfirmed = 0;
  const TrajectoryEvaluation ev = trackTum(dir, kFr1, TrackerConfig{}, "fr1/xyz defaults",
                                           nullptr, nullptr, 1, &unconfirmed);
  EXPECT_EQ(unconfirmed, 0);
  EXPECT_GE(ev.standard.frames, 780u);
  EXPECT_LE(ev.standard.ate_rmse_m, 0.02);
}

// A slower camera, or one that drops frames: fr1/xyz at 7.5 Hz (every 4th frame, up to 8 cm
// and 4.7 deg between frames). Measured 2026-12-05: 0.0161 m. While the velocity the held
// directions follow was fitted over a count of frames (20, 2.7 s at this rate, across the
// hand's changes of direction) it scored 0.236 m: frames 101-105 held two directions at that
// velocity, every frame flagged tracked. The span is now in seconds (velocity_span, 0.65 s).
// (6 Hz: 0.037 m, docs/tracking.md; 5 Hz: the next test.)
TEST(WholeRun, TumFr1XyzAtQuarterRate) {
  DT_FR1_XYZ_OR_SKIP(dir);
  const TrajectoryEvaluation ev =
      trackTum(dir, kFr1, TrackerConfig{}, "fr1/xyz every 4th frame", nullptr, nullptr, 4);
  EXPECT_GE(ev.standard.frames, 195u);
  EXPECT_LE(ev.standard.ate_rmse_m, 0.02);
}

// 5 Hz (every 6th frame, up to 12 cm between frames): where the hand reverses, the
// constant-velocity guess lands centimetres off, the pairs that fix the motion fall outside the
// gates (frame 76: 2 116 pairs against 4 868 on the last fully constrained frame) and the planes
// left look like a degenerate view, held at a velocity the hand has already reversed. Such a frame is registered
// once more from the previous pose (retry_pairs_below, 0.9) and keeps that result when it fixes
// every direction with 1.5x the pairs (frame 76: 5 953 pairs, none held). Measured 2026-12-05:
// 0.0176 m; 0.2257 m with the retry off, every frame "tracked" (the run without it is asserted
// to fail, so the bound is the retry's doing). At 30 Hz the retry never fires on fr1/xyz or
// teddy.
TEST(WholeRun, TumFr1XyzAtFiveHertzRetriesFromRest) {
  DT_FR1_XYZ_OR_SKIP(dir);
  const TrajectoryEvaluation ev =
      trackTum(dir, kFr1, TrackerConfig{}, "fr1/xyz every 6th frame", nullptr, nullptr, 6);
  EXPECT_GE(ev.standard.frames, 130u);
  EXPECT_LE(ev.standard.ate_rmse_m, 0.025);
  TrackerConfig off;
  off.retry_pairs_below = 0.0;
  const TrajectoryEvaluation without =
      trackTum(dir, kFr1, off, "fr1/xyz every 6th frame, no retry", nullptr, nullptr, 6);
  EXPECT_GT(without.standard.ate_rmse_m, 0.1);
  TrackerConfig bad;
  bad.retry_pairs_below = 1.5;
  EXPECT_THROW(Tracker(kFr1, bad), std::invalid_argument);
}

// The defaults (registration model on) against the model off (issue 12: the map's help must
// lower the error, and where it cannot help cost at most 5 %). Measured (2026-12-04, weighting
// on in both, floor 1/32): fr1/xyz 0.0153 m against 0.0320 m without the model; teddy 0.0094 m
// against 0.0108 m. Both are held below the model-off figure. Without the model fr1/xyz misses the
// 0.03 m target (the defaults meet it): that bound is a guard 1.1x the measured figure.
namespace {
struct ModelAndWithout {
  TrajectoryEvaluation model, without;
};
ModelAndWithout trackTumWithAndWithoutModel(const std::string& dir, const PinholeIntrinsics& K,
                                            const std::string& name) {
  return {trackTum(dir, K, TrackerConfig{}, (name + " defaults (model)").c_str()),
          trackTum(dir, K, withoutModel(), (name + " without model").c_str())};
}
}  // namespace

TEST(WholeRun, TumFr1XyzModelAgainstWithout) {
  DT_FR1_XYZ_OR_SKIP(dir);
  const ModelAndWithout r = trackTumWithAndWithoutModel(dir, kFr1, "fr1/xyz");
  EXPECT_GE(r.without.standard.frames, 780u);
  EXPECT_LE(r.without.standard.ate_rmse_m, 0.036);  // guard
  EXPECT_LT(r.model.standard.ate_rmse_m, r.without.standard.ate_rmse_m);
}

TEST(WholeRun, TumTeddyModelAgainstWithout) {
  DT_TEDDY_OR_SKIP(dir);
  const ModelAndWithout r = trackTumWithAndWithoutModel(dir, kFr3, "teddy");
  EXPECT_GE(r.without.standard.frames, 190u);
  EXPECT_LE(r.without.standard.ate_rmse_m, 0.03);  // the target holds without the model too
  EXPECT_LT(r.model.standard.ate_rmse_m, r.without.standard.ate_rmse_m);
}

// Loop closure (off by default) against its mean-surface layer (cl_reference surface, its
// default) on the real sequences, with the defaults otherwise: where it cannot help it may cost at
// most 5 % (issue 12). Measured (2026-12-04): fr1/xyz 0.0146 m against 0.0153 m without (58 of 79
// corrections accepted); teddy 0.0094 m against 0.0094 m (none of 20: the layer holds under half
// of each view). Against the occupancy map's ray cast (cl_reference raycast) fr1/xyz rose to
// 0.0249 m (docs/mapping.md).
namespace {
// min_accepted: corrections that must pass, so that a loop closure accepting none (and changing
// nothing) does not pass for one that costs nothing.
// Returns the ATE with and without loop closure.
std::pair<double, double> expectLoopClosureCostsAtMost5Percent(const std::string& dir,
                                                               const PinholeIntrinsics& K,
                                                               const std::string& name,
                                                               int min_accepted) {
  MapperConfig mc;
  mc.loop.enabled = true;
  const TrajectoryEvaluation open = trackTum(dir, K, TrackerConfig{}, (name + " defaults").c_str());
  int accepted = 0;
  const TrajectoryEvaluation closed =
      trackTum(dir, K, TrackerConfig{}, (name + " with loop closure").c_str(), &mc, &accepted);
  EXPECT_GE(accepted, min_accepted);
  EXPECT_EQ(closed.standard.frames, open.standard.frames);
  EXPECT_LE(closed.standard.ate_rmse_m, 1.05 * open.standard.ate_rmse_m);
  return {closed.standard.ate_rmse_m, open.standard.ate_rmse_m};
}
}  // namespace

TEST(WholeRun, TumFr1XyzLoopClosure) {
  DT_FR1_XYZ_OR_SKIP(dir);
  // 58 of 79 accepted (measured); it lowers the error there, asserted too.
  const auto [closed, open] = expectLoopClosureCostsAtMost5Percent(dir, kFr1, "fr1/xyz", 40);
  EXPECT_LT(closed, open);  // 0.0146 against 0.0153 m
}

TEST(WholeRun, TumTeddyLoopClosure) {
  DT_TEDDY_OR_SKIP(dir);
  expectLoopClosureCostsAtMost5Percent(dir, kFr3, "teddy", 0);  // none pass here (measured)
}

// The Kinect preset (an explicit override, tuned on teddy, so it proves nothing about other
// sequences): measured 0.061 m; guarded at 0.10 m so the preset keeps working.
TEST(WholeRun, TumTeddyKinectPreset) {
  DT_TEDDY_OR_SKIP(dir);
  TrackerConfig cfg;
  loadTrackerParamsYaml(std::string(DT_SOURCE_DIR) + "/../config/tum_kinect.yaml", cfg);
  const TrajectoryEvaluation ev = trackTum(dir, kFr3, cfg, "teddy tum_kinect.yaml");
  EXPECT_GE(ev.standard.frames, 190u);
  EXPECT_LE(ev.standard.ate_rmse_m, 0.10);
}
