// Loop closure against the map: gates reject what the map cannot support; on a rendered run that
// revisits its start (ServoTruck Room3: two laps of a circle in a furnished room) with a drifting
// odometry, and with our own tracker in the thesis's frame-to-frame mode on Room3 and rt3,
// tracking with loop closure ends with less drift and smaller maximum errors than without.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/cell_reducer.hpp"
#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "test_seed.hpp"

using namespace depth_track;

namespace {

struct RunErrors {
  double end_m = 0.0;  ///< position error at the last frame
  double max_m = 0.0;  ///< largest position error over the run
  int attempts = 0, accepted = 0;
};

}  // namespace

TEST(LoopClosure, SingleWallIsADegenerateView) {
  // A wall alone constrains one translation direction only: the registration could slide along
  // it, so the correction is refused before registering.
  const PinholeIntrinsics k = PinholeIntrinsics::isotropic(640, 480, 458.0);
  MapConfig mc;
  mc.bounded = false;
  mc.occupancy_threshold = 0.5;  // one hit: the single frame shows (the default takes two)
  VoxelMap map(mc);
  const DepthImage wall(640, 480, 2.0025f);
  map.fuse(wall, k, Eigen::Isometry3d::Identity());
  LoopClosureConfig lc;
  lc.reference = LoopReference::kRaycast;  // closeLoop: the ray cast
  lc.min_model_age_frames = 0;
  const LoopClosureResult r =
      closeLoop(map, wall, k, DepthRange{}, Eigen::Isometry3d::Identity(), lc);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("degenerate view"), std::string::npos) << r.reason;
  EXPECT_LT(r.normal_spread, 1e-3);
}

TEST(LoopClosure, GatesRejectASparseModelAndALargeJump) {
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  const auto clean = sim::NoiseConfig::forModel(sim::NoiseModel::kNone);
  MapConfig mc;
  mc.voxel_size_m = 0.01;
  mc.occupancy_threshold = 0.5;  // one hit: the single frame shows (the default takes two)
  VoxelMap map(mc);
  map.placeRegion(run.T_W_C.front());
  const DepthImage d0 = run.renderFrame(0, clean, 1, 2);
  LoopClosureConfig lc;
  lc.reference = LoopReference::kRaycast;  // closeLoop: the ray cast
  lc.enabled = true;
  lc.min_model_age_frames = 0;  // one fused frame is the whole model here
  lc.deadband_m = 0.0;
  lc.deadband_deg = 0.0;
  // Empty map: nothing to register against.
  LoopClosureResult r = closeLoop(map, d0, run.intrinsics, run.range, run.T_W_C[0], lc);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("model too sparse"), std::string::npos) << r.reason;
  EXPECT_TRUE(r.T_W_C.isApprox(run.T_W_C[0]));

  map.fuse(d0, run.intrinsics, run.T_W_C[0]);
  // At the true pose the correction is accepted and small: within the voxel size.
  r = closeLoop(map, d0, run.intrinsics, run.range, run.T_W_C[0], lc);
  EXPECT_TRUE(r.accepted) << r.reason;
  EXPECT_LT(r.correction_m, mc.voxel_size_m);
  // The dead band drops a correction smaller than the map resolves, naming why.
  LoopClosureConfig banded = lc;
  banded.deadband_m = mc.voxel_size_m;
  banded.deadband_deg = 1.0;
  r = closeLoop(map, d0, run.intrinsics, run.range, run.T_W_C[0], banded);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("below the map's resolution"), std::string::npos) << r.reason;
  // Only blocks at least 5 frames old form the model: after one frame there is none.
  LoopClosureConfig aged = lc;
  aged.min_model_age_frames = 5;
  r = closeLoop(map, d0, run.intrinsics, run.range, run.T_W_C[0], aged);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("model too sparse"), std::string::npos) << r.reason;
  // A prediction 3 cm off along the optical axis is pulled back towards the truth (to within a
  // voxel), and accepted: 3 cm is inside the 5 cm bound.
  Eigen::Isometry3d off = run.T_W_C[0];
  off.translation() += run.T_W_C[0].linear() * Eigen::Vector3d(0.01, 0.0, 0.03);
  r = closeLoop(map, d0, run.intrinsics, run.range, off, lc);
  EXPECT_TRUE(r.accepted) << r.reason;
  EXPECT_LT((r.T_W_C.translation() - run.T_W_C[0].translation()).norm(), mc.voxel_size_m);
  // The same with a tighter bound on the correction is rejected, naming the reason.
  LoopClosureConfig tight = lc;
  tight.max_correction_m = 0.01;
  r = closeLoop(map, d0, run.intrinsics, run.range, off, tight);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("correction too large"), std::string::npos) << r.reason;
  EXPECT_TRUE(r.T_W_C.isApprox(off));
  // Too few matches: demand more pairs than there are cells.
  LoopClosureConfig greedy = lc;
  greedy.min_matches = 100000;
  r = closeLoop(map, d0, run.intrinsics, run.range, run.T_W_C[0], greedy);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("too few matches"), std::string::npos) << r.reason;
  // Looking away from everything mapped: sparse model.
  Eigen::Isometry3d away = run.T_W_C[0];
  away.linear() =
      run.T_W_C[0].linear() * Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY()).matrix();
  r = closeLoop(map, d0, run.intrinsics, run.range, away, lc);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("model too sparse"), std::string::npos) << r.reason;
}

// Odometry that drifts: each frame's ground-truth motion composed with a constant bias (yaw
// about the camera's y axis and a sideways slip), the way a biased tracker accumulates error.
// Returns position errors of the camera with or without loop closure against the map.
RunErrors driftingOdometryRun(const sim::RenderedRun& run, const std::vector<DepthImage>& frames,
                              int step, double voxel_m, bool loop) {
  Eigen::Isometry3d bias = Eigen::Isometry3d::Identity();
  bias.linear() = Eigen::AngleAxisd(0.015 * M_PI / 180.0, Eigen::Vector3d::UnitY()).matrix();
  bias.translation() = Eigen::Vector3d(0.0003, 0.0, 0.0);
  MapperConfig mc;
  mc.map.voxel_size_m = voxel_m;
  mc.map.bounded = false;
  mc.range = run.range;
  mc.loop.enabled = loop;
  mc.loop.reference = LoopReference::kRaycast;  // the thesis's reference (see the Room3 test)
  mc.loop.cl_step = 5;
  mc.loop.min_model_age_frames = 30;
  Mapper mapper(run.intrinsics, mc, run.T_W_C.front());
  Eigen::Isometry3d T_W_C = run.T_W_C.front();
  RunErrors e;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const std::size_t i = k * step;
    if (k > 0) T_W_C = T_W_C * (run.T_W_C[i - step].inverse() * run.T_W_C[i]) * bias;
    const MapperFrame mf = mapper.process(frames[k], T_W_C);
    if (mf.loop_attempted && std::getenv("DT_VERBOSE"))
      std::printf("frame %zu: %s\n", k, mf.loop.reason.c_str());
    T_W_C = mf.T_W_C;
    const double err = (T_W_C.translation() - run.T_W_C[i].translation()).norm();
    e.max_m = std::max(e.max_m, err);
    e.end_m = err;
  }
  e.attempts = mapper.loopAttempts();
  e.accepted = mapper.loopAccepted();
  std::printf("drifting odometry %s, %zu frames: end drift %.1f mm, max error %.1f mm, %s\n",
              loop ? "with loop closure" : "open loop", frames.size(), 1000 * e.end_m,
              1000 * e.max_m, mapper.summary().c_str());
  return e;
}

TEST(LoopClosure, RevisitRunDriftsLessWithLoopClosure) {
  // Room3 at 10 Hz (every 3rd frame: 3 cm and 2.5 deg per frame), 1.3 of its 2 laps and 1 cm
  // voxels keep the test short; the second lap revisits the start. On this clean rendered run
  // our tracker drifts only millimetres, below what a 1 cm map resolves, so the drift that loop
  // closure must remove comes from an odometry bias of 0.015 deg and 0.3 mm per frame
  // (driftingOdometryRun; 191 frames, so about 2.9 deg and 57 mm of accumulated bias).
  const sim::RenderedRun run = sim::makeRun("room3");
  const int step = 3;
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  const std::uint64_t seed = dt_test::runSeed(7);
  std::vector<DepthImage> frames;
  for (std::size_t i = 0; i < run.size() * 13 / 20; i += step)
    frames.push_back(run.renderFrame(i, noise, seed, 2));
  const RunErrors open = driftingOdometryRun(run, frames, step, 0.01, false);
  const RunErrors closed = driftingOdometryRun(run, frames, step, 0.01, true);
  // One attempt every cl_step = 5 frames (the map holds voxels from the first frame on); 6 of the
  // 38 were accepted with each of the noise seeds 7 (committed), 1, 2, 3, 4 (DT_TEST_SEED,
  // 2026-12-02). No seed moved the count, so the band allows one decision either way (5 to 7):
  // a dead band twice as wide (with the hits 2 mm deeper) accepted 4 and failed here while every
  // drift check above still passed.
  EXPECT_EQ(closed.attempts, static_cast<int>(frames.size()) / 5);
  EXPECT_GE(closed.accepted, 5);
  EXPECT_LE(closed.accepted, 7);
  // Measured: end drift 42 -> 12.5 mm, maximum error 42 -> 34 mm; with the returns snapped to
  // their cell's plane (the default since 2026-12-05) 42 -> 10.7 and 34.7 mm, 7 accepted.
  EXPECT_LT(closed.end_m, 0.6 * open.end_m);
  EXPECT_LT(closed.max_m, open.max_m);
}

// Our tracker in the thesis's frame-to-frame mode (ICPFrames = 1: every frame registered onto
// the one before) drifts on the rendered runs by centimetres, the setting in which the thesis
// studied its loop closure. Each frame is rendered once and tracked twice, open loop and with
// loop closure (default configuration; accepted corrections are fed back into the tracker as
// track_sequence does); returns the thesis-style errors of both.
namespace {

struct TrackedPair {
  ThesisErrors open, closed;
  int attempts = 0, accepted = 0;
  std::size_t frames = 0;
  int cl_step = 0;
};

// Attempts come every cl_step frames (the map holds voxels from the first frame on), so their
// number is the run's length over cl_step; how many are accepted depends on the noise. Measured
// with the noise seeds 1 (committed) to 5 (DT_TEST_SEED, 2026-12-02): rt3 14/9/14/15/14 of 75,
// Room3 28/27/28/28/28 of 88. The bands below go half rt3's spread (6) beyond either end there
// (6 to 18), and about a tenth beyond either end on Room3 (25 to 31): a change that makes the
// gates refuse or pass a few more corrections than the noise does fails, not only one that stops
// loop closure altogether.
void expectAttemptsAndAccepted(const TrackedPair& r, int lo, int hi) {
  EXPECT_EQ(r.attempts, static_cast<int>(r.frames) / r.cl_step);
  EXPECT_GE(r.accepted, lo);
  EXPECT_LE(r.accepted, hi);
}

TrackedPair trackWithAndWithoutLoopClosure(const std::string& name, bool bounded_map,
                                           LoopReference reference = LoopReference::kRaycast) {
  const sim::RenderedRun run = sim::makeRun(name);
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  TrackerConfig tc;
  tc.icp_frames = 1;
  // The thesis's odometry: each frame onto the one before's own cells. With the registration
  // model (the default) every new reference takes the model's averaged planes, and the same
  // ICPFrames=1 run drifts about a millimetre (rt3: end drift 0.73 mm, Room3 max error 4 mm,
  // seed 1), below what the 5 mm map resolves: there loop closure adds its own error (rt3 2.6 mm,
  // Room3 7.0 mm; docs/mapping.md). So these tests switch the model off, and the depth-noise
  // weighting (on by default since 2026-12-04; the thesis weighs every pair alike). With the
  // weighting on, Room3 seed 1 (2026-12-04): end drift 76.7 -> 21.9 mm, position 28.7/60.9/37.1
  // -> 10.5/29.0/26.9 mm, but pitch 0.419 -> 0.419 deg (its largest error comes before the first
  // correction) and roll 0.309 -> 0.480 deg, beyond the dead band (docs/mapping.md).
  tc.model.enabled = false;
  tc.registration.noise_weighting = false;
  Tracker open(run.intrinsics, tc), closed(run.intrinsics, tc);
  MapperConfig mc;
  mc.map.bounded = bounded_map;
  mc.range = run.range;
  mc.loop.enabled = true;
  mc.loop.reference = reference;
  // The ray-cast reference is checked on the map its bounds were measured with: returns fused
  // where they were measured (snap_cell 0; the default snaps them to their cell's plane since
  // 2026-12-05). With snapping (seeds 1/2/3) the Room3 run below ends nearer the truth (end drift
  // 14.4/14.8/13.1 mm against 18.9-19 mm) but its largest yaw and roll errors grow (1.05/1.03/1.01
  // and 0.62/0.63/0.48 deg against 0.86/0.86/0.86 and 0.42/0.47/0.42), beyond the roll check's
  // dead band, with 22/22/24 of 88 accepted; rt3 improves (end drift 6.1 mm against 16.6,
  // 13 of 75 accepted). docs/mapping.md, "Snapping returns to their cell's plane". And with one
  // hit per occupied voxel (occupancy_threshold 0.5, the default until 2026-12-06). With the
  // default two hits and snapping (seed 1) Room3 ends nearer still (end drift 13.5 mm, position
  // 10.4/32.6/18.4 mm, 24 of 88 accepted) but its largest pitch and roll errors grow further
  // (0.55 and 1.00 deg against 0.49 and 0.42 open loop); docs/mapping.md, "The occupancy
  // threshold".
  if (reference == LoopReference::kRaycast) {
    mc.map.snap_cell_px = 0;
    mc.map.occupancy_threshold = 0.5;
  }
  Mapper mapper(run.intrinsics, mc, closed.pose());
  const std::uint64_t seed = dt_test::runSeed(1);
  std::vector<Eigen::Isometry3d> est_open, est_closed;
  for (std::size_t i = 0; i < run.size(); ++i) {
    const DepthImage d = run.renderFrame(i, noise, seed);
    est_open.push_back(open.track(d, run.stamps_s[i]).T_W_C);
    const FrameStatus st = closed.track(d, run.stamps_s[i]);
    const MapperFrame mf = mapper.process(d, st.T_W_C);
    if (mf.loop_attempted && mf.loop.accepted) closed.correctPose(mf.T_W_C);
    if (mf.loop_attempted && std::getenv("DT_VERBOSE"))
      std::printf("frame %zu: %s\n", i, mf.loop.reason.c_str());
    est_closed.push_back(mf.T_W_C);
  }
  TrackedPair r;
  r.open = computeThesisErrors(est_open, run.T_W_C);
  r.closed = computeThesisErrors(est_closed, run.T_W_C);
  r.attempts = mapper.loopAttempts();
  r.accepted = mapper.loopAccepted();
  r.frames = run.size();
  r.cl_step = mc.loop.cl_step;
  for (const auto* e : {&r.open, &r.closed})
    std::printf(
        "%s ICPFrames=1 %s: max_err_deg=%.3f,%.3f,%.3f max_err_mm=%.2f,%.2f,%.2f "
        "end_drift_mm=%.2f\n",
        name.c_str(), e == &r.open ? "open loop" : "with loop closure", e->max_err_deg.x(),
        e->max_err_deg.y(), e->max_err_deg.z(), e->max_err_mm.x(), e->max_err_mm.y(),
        e->max_err_mm.z(), e->end_drift_mm);
  std::printf("%s: %s\n", name.c_str(), mapper.summary().c_str());
  return r;
}

}  // namespace

TEST(LoopClosure, TrackerOnRt3DriftsLessWithLoopClosure) {
  // Measured (default 4x3x4 m region): max errors 1.14/0.32/0.43 deg and 13.0/37.7/10.1 mm, end
  // drift 35.6 mm open loop; 0.40/0.09/0.31 deg, 10.8/22.2/8.7 mm and 15.0 mm with loop closure
  // (12 of 75 attempts accepted; noise seed 1, at 499fb4a).
  const TrackedPair r = trackWithAndWithoutLoopClosure("rt3", true);
  expectAttemptsAndAccepted(r, 6, 18);
  EXPECT_LT(r.closed.end_drift_mm, r.open.end_drift_mm);
  for (int a = 0; a < 3; ++a) {
    EXPECT_LT(r.closed.max_err_deg[a], r.open.max_err_deg[a]) << "rotation axis " << a;
    EXPECT_LT(r.closed.max_err_mm[a], r.open.max_err_mm[a]) << "position axis " << a;
  }
}

TEST(LoopClosure, TrackerOnRoom3DriftsLessWithLoopClosure) {
  // The truck circles a furnished room twice; the map is unbounded (the camera looks all
  // around). Measured (noise seed 1): end drift 77 -> 19 mm, max position errors 29/62/35 ->
  // 9/27/25 mm, max rotation errors 0.48/1.92/0.43 -> 0.38/0.87/0.42 deg (28 of 88 attempts
  // accepted).
  const TrackedPair r = trackWithAndWithoutLoopClosure("room3", false);
  expectAttemptsAndAccepted(r, 25, 31);
  EXPECT_LT(r.closed.end_drift_mm, 0.5 * r.open.end_drift_mm);
  for (int a = 0; a < 3; ++a)
    EXPECT_LT(r.closed.max_err_mm[a], r.open.max_err_mm[a]) << "position axis " << a;
  for (int a = 0; a < 2; ++a)
    EXPECT_LT(r.closed.max_err_deg[a], r.open.max_err_deg[a]) << "rotation axis " << a;
  // Roll (about the first view's optical axis) is where loop closure does not help on this run:
  // the open-loop roll drift (0.43-0.45 deg) is no larger than the precision of the corrections
  // about that axis: on the second lap four corrections in a row moved the roll error -0.23 ->
  // +0.05 -> +0.42 -> +0.06 deg (residuals 5-6 mm; 1.5-3.8 mm in the corrections around them).
  // Whether the closed run's largest roll error ends below the open run's is then up to the noise:
  // closed vs open with the seeds 1 to 4 (DT_TEST_SEED, 2026-12-02) 0.424/0.425, 0.474/0.425,
  // 0.459/0.450, 0.459/0.425 deg, and on main before this step (a2e6f3a) 0.376/0.426,
  // 0.474/0.425, 0.460/0.452 deg: the margin "closed < open" had there with seed 1 was luck
  // (seeds 2 and 3 failed it on main too). Pitch and yaw (0.38-0.40 / 0.87-0.91 against
  // 0.47-0.49 / 1.91-1.94 deg over the seeds) and the position errors keep "closed < open". What is
  // asserted for roll is that closure does not cost roll beyond what the map resolves (the
  // correction dead band, 0.1 deg; the worst excess measured is 0.05 deg): the thesis's accelerated
  // drift would break it.
  EXPECT_LT(r.closed.max_err_deg[2], r.open.max_err_deg[2] + LoopClosureConfig().deadband_deg)
      << "roll";
}

// The surface layer (cl_reference surface, the default) on the same thesis-mode rt3 run. Measured
// (noise seeds 1/2/3, 2026-12-04): end drift 3.70/3.38/2.31 mm against 34.9/36.5/37.7 open loop
// (ray cast: 16.6/14.8/12.5); largest rotation errors 0.31-0.32 / 0.08-0.09 / 0.14-0.17 deg
// against 1.11-1.16 / 0.32-0.34 / 0.40-0.43; position 6.7-7.9 / 13.6-15.7 / 3.4-4.1 mm against
// 11.1-13.4 / 37.1-39.6 / 9.8-10.5; 20 of 75 accepted on each seed (asserted 14 to 26).
TEST(LoopClosure, TrackerOnRt3DriftsLessWithTheSurfaceLayer) {
  const TrackedPair r = trackWithAndWithoutLoopClosure("rt3", true, LoopReference::kSurface);
  expectAttemptsAndAccepted(r, 14, 26);
  EXPECT_LT(r.closed.end_drift_mm, 0.25 * r.open.end_drift_mm);
  for (int a = 0; a < 3; ++a) {
    EXPECT_LT(r.closed.max_err_deg[a], r.open.max_err_deg[a]) << "rotation axis " << a;
    EXPECT_LT(r.closed.max_err_mm[a], r.open.max_err_mm[a]) << "position axis " << a;
  }
}

// The layer takes a frame only once it is min_model_age_frames old (here 3; frames 0-58 of the
// 62 observed on rt3), and corrects a later frame's pose, off by 5.4 mm and 0.2 deg, to within
// a millimetre and 0.05 deg of the truth (measured 0.21 mm, 0.004 deg). Its reach is short: off
// by 10.8 mm and 0.4 deg, the first round finds planes for the near wall only and the attempt
// stops as a degenerate view.
TEST(LoopClosure, SurfaceLayerCorrectsAgainstFramesOnceOld) {
  const sim::RenderedRun run = sim::makeRun("rt3");
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  VoxelMap map{MapConfig{}};
  map.placeRegion(run.T_W_C.front());
  LoopClosureConfig lc;
  lc.enabled = true;
  lc.min_model_age_frames = 3;
  LoopCloser closer(map, run.intrinsics, run.range, lc);
  ASSERT_NE(closer.layer(), nullptr);
  Eigen::Isometry3d off = Eigen::Isometry3d::Identity();
  off.linear() = Eigen::AngleAxisd(0.2 * M_PI / 180.0, Eigen::Vector3d::UnitY()).matrix();
  off.translation() = Eigen::Vector3d(0.004, -0.002, 0.003);
  const std::size_t i = 64;
  const DepthImage cur = run.renderFrame(i, noise, 3, 2);
  for (std::size_t k = 0; k < 3; ++k) closer.observe(run.renderFrame(k, noise, 1, 2), run.T_W_C[k]);
  // Three frames observed, none old enough: the layer is empty.
  LoopClosureResult r = closer.attempt(cur, run.stamps_s[i], run.T_W_C[i] * off);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("model too sparse: 0 cells in the surface layer"), std::string::npos)
      << r.reason;
  EXPECT_EQ(closer.layer()->voxelCount(), 0u);
  EXPECT_GT(closer.pendingBytes(), 0u);
  for (std::size_t k = 3; k < 62; ++k)
    closer.observe(run.renderFrame(k, noise, 1, 2), run.T_W_C[k]);
  EXPECT_GT(closer.layer()->voxelCount(), 0u);
  r = closer.attempt(cur, run.stamps_s[i], run.T_W_C[i] * off);
  ASSERT_TRUE(r.accepted) << r.reason;
  const Eigen::Isometry3d e = run.T_W_C[i].inverse() * r.T_W_C;
  std::printf("surface layer: %s; %.2f mm, %.3f deg from the truth (started 5.4 mm, 0.200 deg)\n",
              r.reason.c_str(), 1000 * e.translation().norm(), rotationAngle(e) * kRadToDeg);
  EXPECT_LT(e.translation().norm(), 0.001);
  EXPECT_LT(rotationAngle(e) * kRadToDeg, 0.05);
  // closeLoop builds a closer for one call: it has no layer and refuses the surface reference.
  EXPECT_THROW(closeLoop(map, cur, run.intrinsics, run.range, run.T_W_C[i], lc),
               std::invalid_argument);
}

// Half-resolution loop closure (virtual image cast at 320x240, 5-px cells on both images) against
// full resolution (640x480, 10-px cells): on a noisy chair map at 5 mm, from predictions off by
// up to 3 cm / 1 deg, both pull the pose to the same place. The cells cover the same view, so the
// corrected poses may differ only by the registration's noise: asserted within half a voxel in
// translation and 0.1 deg in rotation, and both within a voxel of the truth.
TEST(LoopClosure, HalfResolutionRaycastAgreesWithFullResolution) {
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  MapConfig mc;  // 5 mm voxels
  VoxelMap map(mc);
  map.placeRegion(run.T_W_C.front());
  for (std::size_t i = 0; i < 40 && i < run.size(); i += 4)
    map.fuse(run.renderFrame(i, noise, 7, 2), run.intrinsics, run.T_W_C[i]);
  LoopClosureConfig full;
  full.reference = LoopReference::kRaycast;  // closeLoop: the ray cast
  full.raycast_downsample = 1;               // (the default is 2: without this line both were half)
  full.enabled = true;
  full.min_model_age_frames = 0;
  full.deadband_m = 0.0;
  full.deadband_deg = 0.0;
  LoopClosureConfig half = full;
  half.raycast_downsample = 2;
  const std::size_t i = 20;
  const DepthImage cur = run.renderFrame(i, noise, 99, 2);
  const Eigen::Isometry3d& T_true = run.T_W_C[i];
  const Eigen::Vector3d offsets[] = {
      {0.0, 0.0, 0.0}, {0.01, 0.0, 0.03}, {-0.02, 0.01, 0.0}, {0.0, -0.015, -0.02}};
  const double yaw_deg[] = {0.0, 0.5, -1.0, 0.0};
  double worst_dt = 0.0, worst_dr = 0.0;
  for (int k = 0; k < 4; ++k) {
    Eigen::Isometry3d pred = T_true;
    pred.translation() += T_true.linear() * offsets[k];
    pred.linear() = pred.linear() *
                    Eigen::AngleAxisd(yaw_deg[k] * M_PI / 180.0, Eigen::Vector3d::UnitY()).matrix();
    const LoopClosureResult a = closeLoop(map, cur, run.intrinsics, run.range, pred, full);
    const LoopClosureResult b = closeLoop(map, cur, run.intrinsics, run.range, pred, half);
    ASSERT_TRUE(a.accepted) << a.reason;
    ASSERT_TRUE(b.accepted) << b.reason;
    const double dt = (a.T_W_C.translation() - b.T_W_C.translation()).norm();
    const double dr = rotationAngle(a.T_W_C.inverse() * b.T_W_C) * 180.0 / M_PI;
    worst_dt = std::max(worst_dt, dt);
    worst_dr = std::max(worst_dr, dr);
    std::printf(
        "offset %d: full %.2f mm / %.3f deg off truth (%d cells, cast %.1f ms), half %.2f mm / "
        "%.3f deg (%d cells, cast %.1f ms); full vs half %.2f mm, %.3f deg\n",
        k, 1000 * (a.T_W_C.translation() - T_true.translation()).norm(),
        rotationAngle(a.T_W_C.inverse() * T_true) * 180.0 / M_PI, a.model_cells, a.ms_raycast,
        1000 * (b.T_W_C.translation() - T_true.translation()).norm(),
        rotationAngle(b.T_W_C.inverse() * T_true) * 180.0 / M_PI, b.model_cells, b.ms_raycast,
        1000 * dt, dr);
    EXPECT_LT((a.T_W_C.translation() - T_true.translation()).norm(), mc.voxel_size_m);
    EXPECT_LT((b.T_W_C.translation() - T_true.translation()).norm(), mc.voxel_size_m);
    EXPECT_LT(dt, 0.5 * mc.voxel_size_m);
    EXPECT_LT(dr, 0.1);
  }
  std::printf("half vs full resolution: worst %.2f mm, %.3f deg\n", 1000 * worst_dt, worst_dr);
}

TEST(LoopClosure, DownsampleHelpersRejectOddSizesAndKeepPixelCentres) {
  const PinholeIntrinsics k = PinholeIntrinsics::isotropic(640, 480, 600.0);
  const PinholeIntrinsics h = downsampledIntrinsics(k, 2);
  EXPECT_EQ(h.width, 320);
  EXPECT_EQ(h.height, 240);
  // A point seen at full-resolution pixel (u, v) lands at ((u + 0.5) / 2 - 0.5, ...).
  const Eigen::Vector3f p(0.3f, -0.2f, 1.7f);
  float u = 0, v = 0, uh = 0, vh = 0;
  ASSERT_TRUE(k.project(p, &u, &v));
  ASSERT_TRUE(h.project(p, &uh, &vh));
  EXPECT_NEAR(uh, (u + 0.5f) / 2 - 0.5f, 1e-4);
  EXPECT_NEAR(vh, (v + 0.5f) / 2 - 0.5f, 1e-4);
  DepthImage d(4, 2, 1.0f);
  d.at(0, 0) = 2.0f;  // block (0, 0): mean of 2, 1, 1, 1
  d.at(3, 1) = 0.0f;  // block (1, 0) has a hole: no return
  const DepthImage dd = downsampleDepth(d, 2);
  ASSERT_EQ(dd.width, 2);
  EXPECT_FLOAT_EQ(dd.at(0, 0), 1.25f);
  EXPECT_FLOAT_EQ(dd.at(1, 0), 0.0f);
  EXPECT_THROW(downsampleDepth(DepthImage(5, 4, 1.0f), 2), std::invalid_argument);
  EXPECT_THROW(downsampledIntrinsics(PinholeIntrinsics::isotropic(641, 480, 600.0), 2),
               std::invalid_argument);
  LoopClosureConfig bad;
  bad.raycast_downsample = 3;
  EXPECT_FALSE(bad.validate(k).empty());
}

// The tracking graph's covered lens (test_graph's CoveredLensEndsRelocalisingThenTracking)
// without ROS: rt3 tracked and fused for 45 frames, 2 s of frames with no return while the
// prediction runs on, then the view returns far from the held pose; every third lost frame is
// relocalised against the map ray-cast at the held pose and reduced like the frames (the
// calibrated pooling), as the registration nodelet does. The first relocalised pose and the run's
// last must lie within 20 mm / 1 deg of the truth.
TEST(LoopClosure, CoveredLensRelocalisesAgainstTheMap) {
  const sim::RenderedRun run = sim::makeRun("rt3");
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  const std::uint64_t seed = dt_test::runSeed(1);
  Tracker tracker(run.intrinsics, TrackerConfig{}, run.T_W_C.front());
  MapperConfig mc;
  mc.range = run.range;
  Mapper mapper(run.intrinsics, mc, run.T_W_C.front());
  const int gap0 = 45, gap1 = 105, frames = 150, every = 3;
  std::unique_ptr<CellReducer> reducer;
  int lost = 0, back = -1;
  std::vector<Eigen::Isometry3d> est;
  for (int i = 0; i < frames; ++i) {
    DepthImage d = run.renderFrame(i, noise, seed);
    if (i >= gap0 && i < gap1) d = DepthImage(d.width, d.height, 0.0f);
    FrameStatus st = tracker.track(d, run.stamps_s[i]);
    if (!reducer && tracker.noiseCalibration()) {
      PcaConfig pca = tracker.config().reducerConfig();
      tracker.noiseCalibration()->applyTo(&pca);
      reducer = std::make_unique<CellReducer>(run.intrinsics, pca);
    }
    if (st.tracked) {
      lost = 0;
      mapper.fuse(d, st.T_W_C);
    } else if (++lost % every == 0 && i >= gap1) {
      const Eigen::Isometry3d held = tracker.pose();
      const auto ref = reducer->reduce(mapper.raycast(held), run.stamps_s[i]);
      const RelocalisationResult r = tracker.odometry().relocalise(*ref, held, held);
      const Eigen::Isometry3d e = run.T_W_C[i].inverse() * tracker.pose();
      const Eigen::Isometry3d e_held = run.T_W_C[i].inverse() * held;
      std::printf("frame %d: %s (%.1f ms); held %.1f mm / %.2f deg off, now %.1f mm / %.3f deg\n",
                  i, r.reason.c_str(), r.ms, 1000 * e_held.translation().norm(),
                  rotationAngle(e_held) / kDegToRad, 1000 * e.translation().norm(),
                  rotationAngle(e) / kDegToRad);
      if (r.accepted) st.tracked = true;
    }
    if (i >= gap1 && back < 0 && st.tracked) back = i;
    est.push_back(tracker.pose());
  }
  ASSERT_GE(back, 0) << "never tracked again after the gap";
  EXPECT_LE(back, gap1 + 6);
  for (int i : {back, frames - 1}) {
    const Eigen::Isometry3d e = run.T_W_C[i].inverse() * est[i];
    std::printf("frame %d: %.2f mm, %.3f deg from the truth\n", i, 1000 * e.translation().norm(),
                rotationAngle(e) / kDegToRad);
    EXPECT_LT(e.translation().norm(), 0.020) << "frame " << i;
    EXPECT_LT(rotationAngle(e) / kDegToRad, 1.0) << "frame " << i;
  }
}

// The first round's search along the normal (surface_reach_m, 5 cm): from a prediction 2-3 cm and
// 0.2-0.5 deg off, the cells find the layer's planes and one attempt brings the pose within
// 0.3 mm / 0.005 deg of the truth (measured 0.18-0.27 mm). With the layer's own reach (0: the
// voxel and its two neighbours) three of the four stop as degenerate views: the few cells that
// still find a plane lie on one surface (normal spread 0.005-0.014); the second (29 mm, 0.3 deg)
// closes. The reach counts per cell, along its normal: a rotation adds its angle times the
// cell's range to the offset (1 deg at 2.5 m: 44 mm).
TEST(LoopClosure, SurfaceLayerReachesCentimetresOfDrift) {
  const sim::RenderedRun run = sim::makeRun("rt3");
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  VoxelMap map{MapConfig{}};
  map.placeRegion(run.T_W_C.front());
  LoopClosureConfig wide;
  wide.enabled = true;
  wide.min_model_age_frames = 3;
  ASSERT_DOUBLE_EQ(wide.surface_reach_m, wide.max_correction_m);  // the default
  LoopClosureConfig narrow = wide;
  narrow.surface_reach_m = 0.0;
  LoopCloser a(map, run.intrinsics, run.range, wide), b(map, run.intrinsics, run.range, narrow);
  for (std::size_t k = 0; k < 62; ++k) {
    const DepthImage d = run.renderFrame(k, noise, 1, 2);
    a.observe(d, run.T_W_C[k]);
    b.observe(d, run.T_W_C[k]);
  }
  const std::size_t i = 64;
  const DepthImage cur = run.renderFrame(i, noise, 3, 2);
  struct Offset {
    Eigen::Vector3d t;
    double deg;
  };
  const Offset offsets[] = {{{0.015, -0.010, 0.010}, 0.5}, {{-0.020, 0.015, -0.015}, 0.3},
                            {{0.025, 0.0, 0.020}, 0.2}, {{0.0, -0.030, -0.010}, 0.4}};
  int narrow_closed = 0;
  for (const Offset& o : offsets) {
    Eigen::Isometry3d off = Eigen::Isometry3d::Identity();
    off.linear() = Eigen::AngleAxisd(o.deg * M_PI / 180.0, Eigen::Vector3d::UnitY()).matrix();
    off.translation() = o.t;
    const LoopClosureResult ra = a.attempt(cur, run.stamps_s[i], run.T_W_C[i] * off);
    const LoopClosureResult rb = b.attempt(cur, run.stamps_s[i], run.T_W_C[i] * off);
    const Eigen::Isometry3d ea = run.T_W_C[i].inverse() * ra.T_W_C;
    const Eigen::Isometry3d eb = run.T_W_C[i].inverse() * rb.T_W_C;
    std::printf(
        "start %.1f mm, %.2f deg: reach %.0f mm -> %.2f mm, %.3f deg (%s); layer's own reach -> "
        "%.2f mm, %.3f deg (%s)\n",
        1000 * o.t.norm(), o.deg, 1000 * wide.surface_reach_m, 1000 * ea.translation().norm(),
        rotationAngle(ea) * kRadToDeg, ra.reason.c_str(), 1000 * eb.translation().norm(),
        rotationAngle(eb) * kRadToDeg, rb.reason.c_str());
    ASSERT_TRUE(ra.accepted) << ra.reason;
    // As tight as the layer's own-reach test above (measured 0.18-0.27 mm, 0.003-0.005 deg).
    EXPECT_LT(ea.translation().norm(), 0.001);
    EXPECT_LT(rotationAngle(ea) * kRadToDeg, 0.05);
    narrow_closed += rb.accepted && eb.translation().norm() < 0.002;
  }
  EXPECT_LE(narrow_closed, 1);
}
