// The tracker's stages: the prefilter, reducer and odometry composed by hand give the Tracker's
// results bit for bit (on another pool size, as the graph's nodelets would run them); the
// association grid kept across frames matches a fresh one; the registration's normal matrix;
// tracking loss, reset and relocalisation; the bounded statistics and the worker pool.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <optional>
#include <random>
#include <thread>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/cell_reducer.hpp"
#include "depth_track/core/prefilter_stage.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/worker_pool.hpp"
#include "planes_scene.hpp"

using namespace depth_track;
using depth_track::test::cornerRoom;
using depth_track::test::l515;
using depth_track::test::Plane;
using depth_track::test::renderPlanes;
using depth_track::test::shifted;

namespace {
void expectSameStatus(const FrameStatus& a, const FrameStatus& b, std::size_t frame) {
  EXPECT_EQ(a.T_W_C.matrix(), b.T_W_C.matrix()) << "frame " << frame;
  EXPECT_EQ(a.tracked, b.tracked) << frame;
  EXPECT_EQ(a.state, b.state) << frame;
  EXPECT_EQ(a.cells, b.cells) << frame;
  EXPECT_EQ(a.matches, b.matches) << frame;
  EXPECT_EQ(a.fm_matches, b.fm_matches) << frame;
  EXPECT_EQ(a.iterations, b.iterations) << frame;
  EXPECT_EQ(a.error_rms_m, b.error_rms_m) << frame;
  EXPECT_EQ(a.new_keyframe, b.new_keyframe) << frame;
  EXPECT_EQ(a.normal_matrix, b.normal_matrix) << frame;
}
}  // namespace

// The graph runs the stages apart (ingest's prefilter, pca_reduce, registration) and passes
// the cells on as shared clouds; that must be the Tracker's pipeline exactly, for any pool.
TEST(Stages, ComposeToTheTrackersResults) {
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  for (const RegistrationMethod method :
       {RegistrationMethod::kPointToPlane, RegistrationMethod::kCellSearch}) {
    TrackerConfig cfg;
    cfg.registration.method = method;
    cfg.prefilter.type = PrefilterType::kBilateral;
    cfg.prefilter.bilateral_mode = BilateralMode::kSeparable;
    cfg.icp_frames = 0;  // adaptive keyframes: the grid is kept over several frames
    Tracker tracker(run.intrinsics, cfg, run.T_W_C.front());

    auto pool = std::make_shared<const WorkerPool>(2);
    PrefilterStage prefilter(run.intrinsics, cfg.prefilter, pool);
    // Reducer and odometry take the first frame's noise calibration as the graph's do (from
    // cells/noise): the Tracker measures it on that frame before reducing it.
    std::optional<CellReducer> reducer_opt;
    std::optional<CellOdometry> odometry_opt;
    int keyframes = 0;
    for (std::size_t i = 0; i < 24; ++i) {
      const DepthImage d = run.renderFrame(i, noise, 1);
      const FrameStatus a = tracker.track(d, run.stamps_s[i]);
      if (!odometry_opt) {
        ASSERT_TRUE(tracker.noiseCalibration().has_value());
        ASSERT_TRUE(tracker.noiseCalibration()->measured);
        PcaConfig pca = cfg.reducerConfig();
        CellOdometryConfig oc = cfg.odometryConfig();
        tracker.noiseCalibration()->applyTo(&pca);
        tracker.noiseCalibration()->applyTo(&oc);
        reducer_opt.emplace(run.intrinsics, pca, pool);
        odometry_opt.emplace(run.intrinsics, oc, run.T_W_C.front());
      }
      CellReducer& reducer = *reducer_opt;
      CellOdometry& odometry = *odometry_opt;
      const auto cells = reducer.reduce(prefilter.apply(d), run.stamps_s[i], "camera_optical");
      EXPECT_EQ(cells->stamp_s, run.stamps_s[i]);
      EXPECT_EQ(cells->frame_id, "camera_optical");
      const FrameStatus b = odometry.track(cells);
      expectSameStatus(a, b, i);
      EXPECT_TRUE(b.tracked) << b.failure;
      EXPECT_EQ(b.state, TrackingState::kTracking);
      keyframes += b.new_keyframe;
      EXPECT_EQ(odometry.lastCells(), cells);  // held, not copied
    }
    // Some frames ran against a kept keyframe, some refreshed it.
    EXPECT_GT(keyframes, 1);
    EXPECT_LT(keyframes, 24);
    EXPECT_EQ(tracker.timing().count(), 24u);
    EXPECT_EQ(reducer_opt->timing().count(), 24u);
    EXPECT_EQ(prefilter.timing().count(), 24u);
    EXPECT_EQ(odometry_opt->timing().count(), 23u);  // the first frame has nothing to register to
  }
}

// One grid built for a keyframe and kept over the following frames pairs and registers exactly
// as a grid rebuilt on every call (the old path, registerCells without a grid).
TEST(AssociationGrid, KeptAcrossCallsGivesIdenticalRegistrations) {
  const sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  PcaConfig pca;
  const CellCloud key = reduceToCells(run.renderFrame(10, noise, 1), run.intrinsics, pca);
  for (const RegistrationMethod method :
       {RegistrationMethod::kPointToPoint, RegistrationMethod::kPointToPlane,
        RegistrationMethod::kCellSearch}) {
    RegistrationConfig cfg;
    cfg.method = method;
    const AssociationGrid grid(key, cfg.match.search_radius_cells);
    for (std::size_t i = 11; i < 16; ++i) {
      const CellCloud cur = reduceToCells(run.renderFrame(i, noise, 1), run.intrinsics, pca);
      const Eigen::Isometry3d guess = run.T_W_C[10].inverse() * run.T_W_C[i - 1];
      const RegistrationResult kept = registerCells(key, grid, cur, run.intrinsics, guess, cfg);
      const RegistrationResult fresh = registerCells(key, cur, run.intrinsics, guess, cfg);
      ASSERT_TRUE(kept.failure.empty()) << kept.failure;
      EXPECT_EQ(kept.T_ref_cur.matrix(), fresh.T_ref_cur.matrix()) << toString(method) << i;
      EXPECT_EQ(kept.matches, fresh.matches);
      EXPECT_EQ(kept.candidates, fresh.candidates);
      EXPECT_EQ(kept.iterations, fresh.iterations);
      EXPECT_EQ(kept.normal_matrix, fresh.normal_matrix);
      // The matches of one pass too.
      const MatchResult m = matchCells(key, cur, run.intrinsics, kept.T_ref_cur, cfg);
      EXPECT_GT(m.pairs.size(), 3000u);
    }
    RegistrationConfig wider = cfg;
    wider.match.search_radius_cells = 3;
    EXPECT_THROW(
        registerCells(key, grid, key, run.intrinsics, Eigen::Isometry3d::Identity(), wider),
        std::invalid_argument);
    const CellCloud other = key;
    EXPECT_THROW(
        registerCells(other, grid, key, run.intrinsics, Eigen::Isometry3d::Identity(), cfg),
        std::invalid_argument);
  }
}

// The normal matrix is the pairs' J^T W J: its translation block sums w n n^T (P2L) or w I
// (P2P), so with noise-free planes (all Huber weights 1) its trace counts the pairs; a lone wall
// leaves three directions unconstrained (slide in its plane, turn about its normal).
TEST(Registration, NormalMatrixCountsPairsAndShowsDegeneracy) {
  const auto K = l515();
  PcaConfig pca;
  const Eigen::Isometry3d truth = shifted(0.01, -0.005, 0.01, 0.5);
  const CellCloud ref =
      reduceToCells(renderPlanes(cornerRoom(), K, Eigen::Isometry3d::Identity()), K, pca);
  const CellCloud cur = reduceToCells(renderPlanes(cornerRoom(), K, truth), K, pca);
  RegistrationConfig cfg;
  cfg.match.search_radius_cells = 3;
  for (const RegistrationMethod m :
       {RegistrationMethod::kPointToPlane, RegistrationMethod::kPointToPoint}) {
    cfg.method = m;
    // Cell means of two views sit centimetres apart along the surfaces, beyond the Huber
    // threshold, so P2P runs unweighted here for the pair count to show.
    cfg.robust = m != RegistrationMethod::kPointToPoint;
    const RegistrationResult r = registerCells(ref, cur, K, Eigen::Isometry3d::Identity(), cfg);
    ASSERT_TRUE(r.failure.empty()) << r.failure;
    const double per_pair = m == RegistrationMethod::kPointToPoint ? 3.0 : 1.0;
    const double trace = r.normal_matrix.bottomRightCorner<3, 3>().trace();
    EXPECT_NEAR(trace, per_pair * r.matches, 1e-6 * r.matches) << toString(m);
    EXPECT_LT((r.normal_matrix - r.normal_matrix.transpose()).norm(),
              1e-9 * r.normal_matrix.norm());
    const Eigen::VectorXd ev =
        Eigen::SelfAdjointEigenSolver<Matrix6d>(r.normal_matrix).eigenvalues();
    EXPECT_GT(ev(0), 1e-3 * ev(5)) << toString(m) << ": the corner room constrains all six";
  }
  const std::vector<Plane> wall = {{Eigen::Vector3d(0, 0, -1), -2.0}};
  const CellCloud wref =
      reduceToCells(renderPlanes(wall, K, Eigen::Isometry3d::Identity()), K, pca);
  const CellCloud wcur = reduceToCells(renderPlanes(wall, K, shifted(0, 0, 0.01)), K, pca);
  cfg.method = RegistrationMethod::kPointToPlane;
  cfg.robust = true;
  const RegistrationResult w = registerCells(wref, wcur, K, Eigen::Isometry3d::Identity(), cfg);
  const Eigen::VectorXd ev = Eigen::SelfAdjointEigenSolver<Matrix6d>(w.normal_matrix).eigenvalues();
  EXPECT_LT(ev(2), 1e-9 * ev(5)) << "a wall: x, y and the turn about z stay free";
  EXPECT_GT(ev(3), 1e-4 * ev(5));
}

// A covered lens: LOST with the pose held at the prediction, never NaN; when the view returns
// far from the extrapolated pose, relocalisation against a view of the model at the held pose
// brings the camera back, and tracking goes on.
TEST(CellOdometry, LostThenRelocalisedAgainstAModelView) {
  const auto K = l515();
  TrackerConfig cfg;
  cfg.max_jump_m = 0.05;
  Tracker tracker(K, cfg);
  const auto truth = [](int i) { return shifted(0.01 * std::min(i, 5), 0.0, 0.0); };
  int i = 0;
  for (; i <= 5; ++i) {
    const FrameStatus s = tracker.track(renderPlanes(cornerRoom(), K, truth(i)), i / 30.0);
    ASSERT_TRUE(s.tracked) << i << ": " << s.failure;
    EXPECT_EQ(s.state, TrackingState::kTracking);
  }
  // The camera stops while the lens is covered; the prediction goes on at 1 cm per frame.
  const Eigen::Isometry3d v = tracker.odometry().velocity();
  EXPECT_NEAR(v.translation().x(), 0.01, 1e-4);
  for (; i <= 15; ++i) {
    const Eigen::Isometry3d expected = tracker.pose() * v;
    const FrameStatus s = tracker.track(DepthImage(640, 480, 0.0f), i / 30.0);
    EXPECT_FALSE(s.tracked);
    EXPECT_EQ(s.state, TrackingState::kLost);
    EXPECT_FALSE(s.failure.empty());
    EXPECT_LT((s.T_W_C.matrix() - expected.matrix()).norm(), 1e-9);
  }
  const Eigen::Isometry3d held = tracker.pose();
  EXPECT_NEAR(held.translation().x(), 0.15, 1e-3);  // 10 cm ahead of the camera
  // The view returns 11 cm from the prediction: more than the jump gate lets tracking correct.
  FrameStatus back = tracker.track(renderPlanes(cornerRoom(), K, truth(i)), i / 30.0);
  ++i;
  EXPECT_FALSE(back.tracked);
  EXPECT_EQ(back.state, TrackingState::kLost);
  const Eigen::Isometry3d model_pose = tracker.pose();
  EXPECT_LT((model_pose.matrix() - (held * v).matrix()).norm(), 1e-9);
  // A relocalisation against an unrelated model (a lone wall) is refused and changes nothing.
  CellReducer reducer(K, tracker.config().reducerConfig());
  const std::vector<Plane> wall = {{Eigen::Vector3d(0, 0, -1), -2.0}};
  const auto wall_cells = reducer.reduce(renderPlanes(wall, K, model_pose), 0.0);
  const RelocalisationResult bad =
      tracker.odometry().relocalise(*wall_cells, model_pose, model_pose);
  EXPECT_FALSE(bad.accepted);
  std::printf("lone wall: %s\n", bad.reason.c_str());
  // Some start pairs one of the room's walls onto it: the check that the view fixes every
  // direction where the pose landed refuses it.
  EXPECT_NE(bad.reason.find("does not fix"), std::string::npos) << bad.reason;
  EXPECT_EQ(tracker.odometry().state(), TrackingState::kRelocalising);
  EXPECT_EQ(tracker.pose().matrix(), model_pose.matrix());
  back = tracker.track(DepthImage(640, 480, 0.0f), i / 30.0);  // still lost: still relocalising
  EXPECT_EQ(back.state, TrackingState::kRelocalising);
  back = tracker.track(renderPlanes(cornerRoom(), K, truth(i)), i / 30.0);
  ++i;
  EXPECT_EQ(back.state, TrackingState::kRelocalising);
  // The model seen from the held pose (what the map's ray cast gives) relocalises the camera.
  const auto model = reducer.reduce(renderPlanes(cornerRoom(), K, model_pose), 0.0);
  const RelocalisationResult r = tracker.odometry().relocalise(*model, model_pose, model_pose);
  EXPECT_GT(r.registration.matches, 1000);
  ASSERT_TRUE(r.accepted) << r.reason;
  EXPECT_EQ(tracker.odometry().state(), TrackingState::kTracking);
  const Eigen::Isometry3d err = truth(i - 1).inverse() * tracker.pose();
  EXPECT_LT(err.translation().norm(), 1e-3);  // noise-free planes: within a millimetre
  EXPECT_LT(rotationAngle(err) / kDegToRad, 0.05);
  // Tracking goes on from there.
  const FrameStatus s =
      tracker.track(renderPlanes(cornerRoom(), K, shifted(0.06, 0.0, 0.01)), i / 30.0);
  ASSERT_TRUE(s.tracked) << s.failure;
  EXPECT_LT((s.T_W_C.translation() - Eigen::Vector3d(0.06, 0.0, 0.01)).norm(), 1e-3);
  // Cells of another grid than the frame's are refused with a clear error.
  CellReducer coarse(K, [] {
    PcaConfig p;
    p.cell_size = 10;
    return p;
  }());
  EXPECT_THROW(tracker.odometry().relocalise(
                   *coarse.reduce(renderPlanes(cornerRoom(), K, held), 0.0), held, held),
               std::invalid_argument);
}

TEST(CellOdometry, ResetStartsAgainAtAGivenPose) {
  const auto K = l515();
  TrackerConfig cfg;
  CellReducer reducer(K, cfg.reducerConfig());
  CellOdometry odo(K, cfg.odometryConfig());
  EXPECT_EQ(odo.state(), TrackingState::kLost);
  EXPECT_THROW(odo.track(nullptr), std::invalid_argument);
  odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, Eigen::Isometry3d::Identity()), 0.0));
  FrameStatus s =
      odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, shifted(0.02, 0, 0)), 0.033));
  ASSERT_TRUE(s.tracked);
  EXPECT_NEAR(odo.pose().translation().x(), 0.02, 1e-3);

  const Eigen::Isometry3d T_W_new = shifted(1.0, 2.0, 3.0, 30.0);
  odo.reset(T_W_new);
  EXPECT_EQ(odo.state(), TrackingState::kLost);
  EXPECT_FALSE(odo.reference());
  EXPECT_FALSE(odo.lastCells());
  EXPECT_TRUE(odo.velocity().matrix().isIdentity(0.0));
  // The next usable frame is the new reference, at exactly the given pose.
  s = odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, shifted(0.02, 0, 0)), 0.066));
  EXPECT_TRUE(s.tracked);
  EXPECT_TRUE(s.new_keyframe);
  EXPECT_EQ(s.state, TrackingState::kTracking);
  EXPECT_LT((s.T_W_C.matrix() - T_W_new.matrix()).norm(), 1e-12);
  // Camera motion is measured from there (1 cm along its own x).
  s = odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, shifted(0.03, 0, 0)), 0.1));
  ASSERT_TRUE(s.tracked);
  EXPECT_LT((s.T_W_C.translation() - T_W_new * Eigen::Vector3d(0.01, 0, 0)).norm(), 1e-3);
  odo.reset();  // to the start pose
  EXPECT_TRUE(odo.pose().matrix().isIdentity(0.0));
  EXPECT_THROW(odo.reset(Eigen::Isometry3d(Eigen::Matrix4d::Constant(NAN))), std::invalid_argument);
  CellOdometryConfig bad;
  bad.relocalise.search_radius_cells = -1;
  bad.max_jump_m = 0;
  try {
    CellOdometry o(K, bad);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("relocalise.search_radius_cells"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("max_jump_m"), std::string::npos);
  }
}

// A runtime reconfiguration (dynamic_reconfigure in the graph) between two frames: a new search
// window rebuilds the kept keyframe's association grid (registering through the old one would
// refuse: a grid serves one window), pose, velocity and keyframe stay; a bad config changes
// nothing.
TEST(CellOdometry, SetConfigBetweenFramesKeepsTheKeyframeAndRegridsForANewWindow) {
  const auto K = l515();
  TrackerConfig cfg;
  CellReducer reducer(K, cfg.reducerConfig());
  CellOdometryConfig oc = cfg.odometryConfig();
  oc.registration.match.search_radius_cells = 1;
  CellOdometry odo(K, oc);
  odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, Eigen::Isometry3d::Identity()), 0.0));
  FrameStatus s =
      odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, shifted(0.01, 0, 0)), 0.033));
  ASSERT_TRUE(s.tracked) << s.failure;
  const auto key = odo.reference();
  const Eigen::Isometry3d pose = odo.pose(), velocity = odo.velocity();

  CellOdometryConfig wider = oc;
  wider.registration.match.search_radius_cells = 2;
  odo.setConfig(wider);
  EXPECT_EQ(odo.config().registration.match.search_radius_cells, 2);
  EXPECT_EQ(odo.reference(), key);
  EXPECT_EQ(odo.pose().matrix(), pose.matrix());
  EXPECT_EQ(odo.velocity().matrix(), velocity.matrix());
  s = odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, shifted(0.02, 0, 0)), 0.066));
  ASSERT_TRUE(s.tracked) << s.failure;
  EXPECT_TRUE(s.failure.empty()) << s.failure;
  EXPECT_EQ(odo.reference(), key);  // 2 cm from the keyframe: still the keyframe
  EXPECT_NEAR(odo.pose().translation().x(), 0.02, 1e-3);

  CellOdometryConfig bad = wider;
  bad.registration.match.search_radius_cells = -1;
  EXPECT_THROW(odo.setConfig(bad), std::invalid_argument);
  EXPECT_EQ(odo.config().registration.match.search_radius_cells, 2);
  s = odo.track(reducer.reduce(renderPlanes(cornerRoom(), K, shifted(0.03, 0, 0)), 0.1));
  ASSERT_TRUE(s.tracked) << s.failure;
  EXPECT_NEAR(odo.pose().translation().x(), 0.03, 1e-3);
}

TEST(RunningStats, MeanOverAllQuantilesOverTheWindow) {
  RunningStats s(100);
  EXPECT_EQ(s.median(), 0.0);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 10.0);
  std::vector<double> all;
  for (int i = 0; i < 1000; ++i) {
    all.push_back(u(rng));
    s.add(all.back());
    EXPECT_LE(s.windowCount(), 100u);  // memory stays bounded
  }
  double sum = 0.0;
  for (double x : all) sum += x;
  EXPECT_EQ(s.count(), 1000u);
  EXPECT_NEAR(s.mean(), sum / 1000.0, 1e-12);
  EXPECT_EQ(s.min(), *std::min_element(all.begin(), all.end()));
  EXPECT_EQ(s.max(), *std::max_element(all.begin(), all.end()));
  EXPECT_EQ(s.last(), all.back());
  std::vector<double> recent(all.end() - 100, all.end());
  std::sort(recent.begin(), recent.end());
  EXPECT_EQ(s.median(), recent[50]);  // nearest rank: round(0.5 * 99) = 50
  EXPECT_EQ(s.p95(), recent[94]);     // round(0.95 * 99) = 94
  EXPECT_EQ(s.quantile(0.0), recent.front());
  EXPECT_EQ(s.quantile(1.0), recent.back());
  EXPECT_THROW(s.quantile(1.5), std::invalid_argument);
  s.clear();
  EXPECT_EQ(s.count(), 0u);
  EXPECT_EQ(s.windowCount(), 0u);
  EXPECT_THROW(RunningStats(0), std::invalid_argument);
  // Below the window the quantiles cover every sample: odd and even counts.
  RunningStats t;
  for (double x : {5.0, 1.0, 4.0}) t.add(x);
  EXPECT_EQ(t.median(), 4.0);
  t.add(2.0);
  EXPECT_EQ(t.median(), 4.0);  // sorted 1 2 4 5, index round(1.5) = 2
}

TEST(WorkerPool, CoversEveryIndexOnceFromConcurrentCallers) {
  EXPECT_THROW(WorkerPool(0), std::invalid_argument);
  for (int threads : {1, 2}) {
    const WorkerPool pool(threads);
    std::vector<std::atomic<int>> hits(1000);
    auto run = [&] {
      pool.parallelFor(0, 1000, 7, [&](int b, int e) {
        for (int k = b; k < e; ++k) hits[k].fetch_add(1);
      });
    };
    std::thread other(run);
    run();
    other.join();
    for (const auto& h : hits) ASSERT_EQ(h.load(), 2) << threads << " threads";
  }
}
