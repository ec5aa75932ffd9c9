// Whole runs through the tracker, scored against ground truth: the rendered thesis test runs
// (xtest1_05_chair, rt3) with the L515 noise model, and the real TUM fr3/teddy Kinect sequence.
// Bounds are the product's accuracy targets (they beat the thesis's tables 5.3 and 5.5).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>

#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/core/tum_io.hpp"
#include "../shared_data.hpp"
#include "test_seed.hpp"

using namespace depth_track;

namespace {

struct RunResult {
  ThesisErrors errors;
  int tracked = 0, frames = 0;
};

RunResult trackRendered(const std::string& name, const TrackerConfig& cfg,
                        sim::NoiseModel noise_model = sim::NoiseModel::kL515) {
  const sim::RenderedRun run = sim::makeRun(name);
  const sim::NoiseConfig noise = sim::NoiseConfig::forModel(noise_model);
  Tracker tracker(run.intrinsics, cfg);
  const std::uint64_t seed = dt_test::runSeed(1);
  const std::size_t n = run.size();
  std::vector<Eigen::Isometry3d> est, gt;
  RunResult r;
  for (std::size_t i = 0; i < n; ++i) {
    const FrameStatus st =
        tracker.track(run.renderFrame(i, noise, seed), run.stamps_s[i]);
    r.tracked += st.tracked;
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
TEST(WholeRun, Xtest1ChairPointToPlane) {
  const RunResult r = trackRendered("xtest1_05_chair", RegistrationMethod::kPointToPlane);
  expectTrackedWithin(r, 0.25, 3.0);
}

TEST(WholeRun, Xtest1ChairCellSearch) {
  const RunResult r = trackRendered("xtest1_05_chair", RegistrationMethod::kCellSearch);
  expectTrackedWithin(r, 0.25, 3.0);
}

// Point-to-point is the thesis's weakest method and ours too (cell means sample surfaces at
// grid-dependent places); it is held to the thesis's own P2P-class figures on the chair run.
TEST(WholeRun, Xtest1ChairPointToPoint) {
  const RunResult r = trackRendered("xtest1_05_chair", RegistrationMethod::kPointToPoint);
  expectTrackedWithin(r, 2.0, 40.0);
}

// Thesis table 5.5: 3.3 deg, 84 mm. Target: 1.0 deg, 15 mm.
TEST(WholeRun, Rt3PitchSinusoid) {
  const RunResult r = trackRendered("rt3", RegistrationMethod::kPointToPlane);
  expectTrackedWithin(r, 1.0, 15.0);
}

// D435-class stereo depth (sigma 3 cm at 2.5 m): with the defaults (5 px cells) the chair run
// ends 4.9 deg and 0.38 m off (and rt3 loses track); config/d435.yaml tracks it. Measured 0.45
// deg, 16.2 mm (the thesis's L515 figures on this run: 0.43-0.90 deg, 7-17 mm).
TEST(WholeRun, Xtest1ChairD435Preset) {
  TrackerConfig cfg;
  loadTrackerParamsYaml(std::string(DT_SOURCE_DIR) + "/../config/d435.yaml", cfg);
  const RunResult r = trackRendered("xtest1_05_chair", cfg, sim::NoiseModel::kD435);
  expectTrackedWithin(r, 0.6, 25.0);
}

// Real Kinect data with motion-capture ground truth. Open3D frame-to-frame point-to-plane ICP
// scores 0.38 m here, a still camera 0.57 m. Target: ATE RMSE <= 0.10 m.
TEST(WholeRun, TumTeddyRealKinect) {
  DT_TEDDY_OR_SKIP(dir);
  const std::vector<TumFrame> frames = readTumFrameList(dir + "/depth.txt");
  TrackerConfig cfg;
  loadTrackerParamsYaml(std::string(DT_SOURCE_DIR) + "/../config/tum_kinect.yaml", cfg);
  const PinholeIntrinsics K{640, 480, 535.4, 539.2, 320.1, 247.6};
  Tracker tracker(K, cfg);
  Trajectory est;
  for (const TumFrame& f : frames) {
    const FrameStatus st =
        tracker.track(loadTumDepth(f.path, 1.0 / 5000.0, DepthRange{}), f.stamp_s);
    est.push_back({f.stamp_s, st.T_W_C});
  }
  const TrajectoryEvaluation ev =
      evaluateTrajectory(est, readTumTrajectory(dir + "/groundtruth.txt"));
  std::printf("teddy: %s\n", formatEvaluation(ev).c_str());
  EXPECT_GE(ev.standard.frames, 190u);
  EXPECT_LE(ev.standard.ate_rmse_m, 0.10);
}
