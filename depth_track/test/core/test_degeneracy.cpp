// Degenerate views: the eigen-analysis of the registration's normal equations finds the pose
// directions a view cannot fix, the registration keeps the motion prior there and registers the
// rest, and the status and covariance say so. A bare wall leaves three directions free (two
// translations in its plane, the turn about its normal); a room corner none. The rendered
// wall_slide run faces a wall and a parallel cabinet front for three seconds at 0.15 m/s.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <optional>
#include <cstdio>
#include <random>

#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/degeneracy.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/registration.hpp"
#include "depth_track/core/sim/imu.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "planes_scene.hpp"

using namespace depth_track;
using depth_track::test::cornerRoom;
using depth_track::test::l515;
using depth_track::test::Plane;
using depth_track::test::renderPlanes;
using depth_track::test::shifted;

namespace {

// L515-like depth noise (1.5 mm at 2 m): without any the normals are exact and no direction has
// a noise floor to be compared with.
DepthImage noisy(DepthImage img, unsigned seed, double sigma_m = 0.0015) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0.0f, static_cast<float>(sigma_m));
  for (float& z : img.data)
    if (z > 0.0f) z += n(rng);
  return img;
}

RegistrationResult registerViews(const std::vector<Plane>& planes, const Eigen::Isometry3d& truth,
                                 const Eigen::Isometry3d& guess) {
  const auto K = l515();
  const PcaConfig pca;
  const CellCloud ref =
      reduceToCells(noisy(renderPlanes(planes, K, Eigen::Isometry3d::Identity()), 1), K, pca);
  const CellCloud cur = reduceToCells(noisy(renderPlanes(planes, K, truth), 2), K, pca);
  RegistrationConfig cfg;
  cfg.match.search_radius_cells = 3;
  return registerCells(ref, cur, K, guess, cfg);
}

}  // namespace

// Square on to a wall 2 m away, the camera 8 mm closer and the guess 6 mm off in the wall's
// plane: the depth is registered, the in-plane offset of the guess is kept (nothing in the view
// can tell it), and three directions are reported free.
TEST(Degeneracy, WallKeepsTheGuessInItsPlaneAndRegistersTheDepth) {
  const std::vector<Plane> wall = {{Eigen::Vector3d(0, 0, -1), -2.0}};
  const Eigen::Isometry3d truth = shifted(0.0, 0.0, 0.008);
  const Eigen::Isometry3d guess = shifted(0.006, -0.004, 0.0);
  const RegistrationResult r = registerViews(wall, truth, guess);
  ASSERT_TRUE(r.failure.empty()) << r.failure;
  EXPECT_EQ(r.degeneracy.degenerate, 3);
  // Depth: one pair's noise is ~1.5 mm, averaged over thousands of pairs.
  EXPECT_NEAR(r.T_ref_cur.translation().z(), 0.008, 3e-4);
  // In the plane the guess stands: a plain solve would move it by noise alone; held, it moves
  // by the measurement's information-weighted share of the step, which is below the noise floor
  // here (a fraction of a millimetre).
  EXPECT_NEAR(r.T_ref_cur.translation().x(), 0.006, 5e-4);
  EXPECT_NEAR(r.T_ref_cur.translation().y(), -0.004, 5e-4);
  // The roll about the wall's normal stays at the guess's (none).
  const Eigen::AngleAxisd aa(r.T_ref_cur.rotation());
  EXPECT_LT(std::abs(aa.angle() * aa.axis().z()), 0.05 * M_PI / 180.0);
  // The weakest eigenvector is a translation in the wall's plane or the roll: no depth in it.
  EXPECT_LT(std::abs(r.degeneracy.weakest(5)), 0.1);
}

// With the registration model on, a view that leaves directions unfixed is registered against
// the keyframe's own cells: approaching a bare wall with a keyframe every frame (so from the
// fourth frame on each keyframe takes the model's planes), every pose equals the one without
// the model, while the model does refine the keyframes.
TEST(Degeneracy, ModelStandsAsideInADegenerateView) {
  const std::vector<Plane> wall = {{Eigen::Vector3d(0, 0, -1), -2.0}};
  const auto K = l515();
  CellOdometryConfig off;
  off.icp_frames = 1;
  off.model.enabled = false;
  CellOdometryConfig on = off;
  on.model.enabled = true;
  CellOdometry odo_off(K, off), odo_on(K, on);
  int refined = 0;
  for (int i = 0; i < 10; ++i) {
    const auto cells = std::make_shared<const CellCloud>(reduceToCells(
        noisy(renderPlanes(wall, K, shifted(0.0, 0.0, 0.002 * i)), 10 + i), K, PcaConfig{}));
    const FrameStatus a = odo_off.track(cells);
    const FrameStatus b = odo_on.track(cells);
    ASSERT_TRUE(a.tracked && b.tracked) << a.failure << b.failure;
    if (i > 0) {
      EXPECT_GT(b.degenerate_directions, 0) << i;
    }
    EXPECT_EQ(a.T_W_C.matrix(), b.T_W_C.matrix()) << "frame " << i;
    refined += b.model.refined;
  }
  EXPECT_GT(refined, 1000);
  EXPECT_GT(odo_on.model().voxelCount(), 0u);
}

// A correction (correctPose, as loop closure applies it) moves the odometry's world, not the
// registration model: the model stays in the frame it was built in, so after a correction by D
// every pose is D times the uncorrected run's and the keyframes take the model's planes as
// before. Without the model frame's offset the keyframes would look the model up D away.
TEST(Degeneracy, CorrectionMovesTheWorldNotTheModel) {
  const auto K = l515();
  CellOdometryConfig cfg;
  cfg.icp_frames = 1;  // a keyframe every frame: every frame after the correction is refined
  cfg.model.enabled = true;
  CellOdometry plain(K, cfg), corrected(K, cfg);
  Eigen::Isometry3d D = shifted(0.05, -0.03, 0.02);
  D.linear() =
      Eigen::AngleAxisd(0.02, Eigen::Vector3d(0.3, 1.0, 0.2).normalized()).toRotationMatrix();
  long refined_plain = 0, refined_corrected = 0;
  for (int i = 0; i < 12; ++i) {
    const auto cells = std::make_shared<const CellCloud>(reduceToCells(
        noisy(renderPlanes(cornerRoom(), K, shifted(0.003 * i, 0.0, 0.002 * i)), 30 + i), K,
        PcaConfig{}));
    const FrameStatus a = plain.track(cells);
    const FrameStatus b = corrected.track(cells);
    ASSERT_TRUE(a.tracked && b.tracked) << i << ": " << a.failure << b.failure;
    if (i == 5) corrected.correctPose(D * b.T_W_C);
    if (i > 5) {
      const Eigen::Isometry3d expect = D * a.T_W_C;
      EXPECT_LT((expect.translation() - b.T_W_C.translation()).norm(), 1e-9) << i;
      EXPECT_LT(rotationAngle(expect.inverse() * b.T_W_C), 1e-9) << i;
      refined_plain += a.model.refined;
      refined_corrected += b.model.refined;
    }
  }
  EXPECT_GT(refined_plain, 1000);
  EXPECT_EQ(refined_corrected, refined_plain);
}

// The corner room fixes every direction: nothing is held, and the registration recovers an
// in-plane shift a wall alone could not.
TEST(Degeneracy, CornerRoomHoldsNothing) {
  const Eigen::Isometry3d truth = shifted(0.006, -0.004, 0.008);
  const RegistrationResult r = registerViews(cornerRoom(), truth, Eigen::Isometry3d::Identity());
  ASSERT_TRUE(r.failure.empty()) << r.failure;
  EXPECT_EQ(r.degeneracy.degenerate, 0);
  EXPECT_TRUE((r.degeneracy.gain.array() > 0.9).all()) << r.degeneracy.gain.transpose();
  EXPECT_LT((r.T_ref_cur.translation() - truth.translation()).norm(), 1e-3);
}

// Covariance: along a held direction it is the prior's variance, along a registered one the
// residual variance over the information, so the wall's depth is known to far better than a
// millimetre and its in-plane position only as well as the prior.
TEST(Degeneracy, CovarianceSaysWhatTheViewFixed) {
  const std::vector<Plane> wall = {{Eigen::Vector3d(0, 0, -1), -2.0}};
  const RegistrationResult r =
      registerViews(wall, shifted(0.0, 0.0, 0.008), Eigen::Isometry3d::Identity());
  ASSERT_TRUE(r.failure.empty()) << r.failure;
  DegeneracyConfig dc;
  dc.prior_sigma_m = 0.003;
  const Matrix6d C = registrationCovariance(r.degeneracy, r.error_rms_m * r.error_rms_m, dc);
  EXPECT_LT((C - C.transpose()).norm(), 1e-12);
  // [omega; u]: u_z is the depth, u_x and u_y lie in the wall.
  EXPECT_LT(std::sqrt(C(5, 5)), 1e-4);
  for (int i : {3, 4}) {
    EXPECT_GT(std::sqrt(C(i, i)), 0.5 * dc.prior_sigma_m) << i;
    EXPECT_LT(std::sqrt(C(i, i)), 1.01 * dc.prior_sigma_m) << i;
  }
  // What the view alone measured: the depth to well under a millimetre, the held in-plane
  // position not at all (it is the prior's); and nothing once every direction counts as weak.
  const double sigma2 = r.error_rms_m * r.error_rms_m;
  const Matrix6d M = measurementCovariance(r.degeneracy, sigma2, 10.0);
  EXPECT_LT((M - M.transpose()).norm(), 1e-9);
  EXPECT_LT(std::sqrt(M(5, 5)), 3e-4);  // the held directions' variance leaks in at ~1e-4 m
  for (int i : {3, 4}) EXPECT_GT(M(i, i), 0.5 * kUnmeasuredVariance) << i;
  const Matrix6d none = measurementCovariance(r.degeneracy, sigma2, 1e30);
  const double L2 = r.degeneracy.length_scale_m * r.degeneracy.length_scale_m;
  for (int i = 0; i < 6; ++i)
    EXPECT_GT(none(i, i), 0.5 * kUnmeasuredVariance / (i < 3 ? L2 : 1.0)) << i;
  // The plain solve's analysis (noise_margin 0) holds nothing.
  DegeneracyAnalysis plain = r.degeneracy;
  applyNoiseFloors(&plain, plain.noise_floor, r.error_rms_m * r.error_rms_m,
                   DegeneracyConfig{0.0, 0.002});
  EXPECT_EQ(plain.degenerate, 0);
  EXPECT_TRUE((plain.gain.array() == 1.0).all());
}

// The closed-form noise floors equal their definition summed pair by pair: for each eigenvector
// e = [L omega; u], the weighted mean of |v|^2 - (v.n)^2 with v = omega x l + u, times sigma_n2.
TEST(Degeneracy, NoiseFloorsClosedFormEqualsThePairSum) {
  std::mt19937 rng(7);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> uw(0.2, 1.0);
  const Eigen::Vector3d c(0.3, -0.1, 0.2);
  std::vector<Eigen::Vector3d> lever, normal;
  std::vector<double> weight;
  Matrix6d H = Matrix6d::Zero();
  LeverMoments m;
  double range2 = 0.0;
  for (int i = 0; i < 200; ++i) {
    // Points 1-3 m ahead, normals mostly facing the camera, as a view gives them.
    const Eigen::Vector3d p(g(rng), 0.5 * g(rng), 2.0 + 0.5 * g(rng));
    const Eigen::Vector3d n = Eigen::Vector3d(0.3 * g(rng), 0.3 * g(rng), -1.0).normalized();
    const double w = uw(rng);
    const Eigen::Vector3d l = p - c;
    Vector6d J;
    J << l.cross(n), n;
    H += w * J * J.transpose();
    m.add(l, w);
    range2 += l.squaredNorm();
    lever.push_back(l);
    normal.push_back(n);
    weight.push_back(w);
  }
  const DegeneracyAnalysis a = analyseNormalEquations(H, m.wsum, std::sqrt(range2 / 200));
  const double sigma_n2 = 0.004;
  const Vector6d closed = noiseFloors(a, H, m, sigma_n2);
  for (int k = 0; k < 6; ++k) {
    const Eigen::Vector3d omega = a.eigenvectors.col(k).head<3>() / a.length_scale_m;
    const Eigen::Vector3d u = a.eigenvectors.col(k).tail<3>();
    double sum = 0.0, wsum = 0.0;
    for (std::size_t i = 0; i < lever.size(); ++i) {
      const Eigen::Vector3d v = omega.cross(lever[i]) + u;
      sum += weight[i] * (v.squaredNorm() - v.dot(normal[i]) * v.dot(normal[i]));
      wsum += weight[i];
    }
    const double pairwise = sum * sigma_n2 / wsum;
    EXPECT_GT(pairwise, 0.0) << k;
    EXPECT_NEAR(closed(k), pairwise, 1e-9 * std::max(1.0, pairwise)) << k;
  }
  EXPECT_TRUE(noiseFloors(a, H, LeverMoments{}, sigma_n2).isZero());
}

// The rendered wall_slide run with L515 noise, noise seeds 1-3: every frame of the three seconds
// square on to the wall (2.4-5.4 s, at 0.15 m/s) is flagged degenerate, the error gathered over
// that stretch stays within 5 mm per second of it, and the frames at rest looking at the
// furnished side (0-0.6 s) and after the turn back (7.2-8 s) are not flagged. Seeds 1-3 with
// the defaults of 2026-12-04 (registration model and depth-noise weighting on): 2.72 / 3.65 /
// 2.96 mm/s; with the model before the weighting: 2.59 / 3.68 / 3.08 mm/s; without either
// 1.91 / 2.38 / 1.90 mm/s. Without the model, over seeds 1-20 (2026-12-03, track_sequence
// --status-out) 0.81-3.43 mm/s, every degenerate frame flagged and no furnished one on each. At the
// earlier margin of 1.5 seeds 1-3 gave 4.25 / 18.98 / 9.65 mm/s (the code before), 28.8 / 59.0
// / 6.4 mm/s with the rotation-aware prior (docs/tracking.md, "Degenerate views"); this test fails
// on both.
namespace {
struct WallSlideRun {
  int frames = 0, tracked = 0;
  int degenerate_frames = 0, flagged_degenerate = 0, furnished_frames = 0, flagged_furnished = 0;
  int deep_retried = 0;  ///< frames registered again with the deep returns weighted up
  double drift_mm_per_s = 0.0;
};

// with_imu: a camera IMU as motion prior (a simulated BMI055 mounted as track_sequence's
// --imu-sim puts it, noise seed = seed), its ImuPriorConfig::guess_gate `guess_gate`.
WallSlideRun trackWallSlide(sim::NoiseModel model, int seed,
                            const TrackerConfig& config = TrackerConfig{}, bool with_imu = false,
                            double guess_gate = ImuPriorConfig{}.guess_gate) {
  const sim::RenderedRun run = sim::makeRun("wall_slide");
  const sim::NoiseConfig noise = sim::NoiseConfig::forModel(model);
  Tracker tracker(run.intrinsics, config);
  ImuPriorConfig imu_cfg;
  imu_cfg.T_C_I.translation() = Eigen::Vector3d(-0.006, 0.005, 0.012);
  imu_cfg.guess_gate = guess_gate;
  std::optional<ImuMotionPrior> imu;
  std::vector<ImuSample> samples;
  std::size_t fed = 0;
  if (with_imu) {
    imu.emplace(imu_cfg);
    samples = sim::simulateImu(run, imu_cfg.T_C_I, sim::ImuNoiseConfig::bmi055(), seed);
  }
  WallSlideRun r;
  r.frames = static_cast<int>(run.size());
  std::vector<Eigen::Isometry3d> est;
  for (std::size_t i = 0; i < run.size(); ++i) {
    const double t = run.stamps_s[i];
    std::optional<Eigen::Isometry3d> guess;
    std::optional<InertialHold> hold;
    if (imu) {
      fed = imu->addUpTo(samples, fed, t);
      if (const auto g = imu->guess(t)) guess = g->T_Cprev_Ccur, hold = g->hold;
    }
    const FrameStatus st = tracker.track(run.renderFrame(i, noise, seed), t, guess, hold);
    if (imu) imu->update(t, tracker.pose(), trackedPoseCovariance(st));
    r.tracked += st.tracked;
    r.deep_retried += st.basin_deep_retried;
    est.push_back(st.T_W_C);
    if (t > 2.4 + 1e-6 && t < 5.4 - 1e-6) {
      ++r.degenerate_frames;
      r.flagged_degenerate += st.degenerate_directions > 0;
    } else if ((t > 0.0 && t < 0.6) || t > 7.2) {
      ++r.furnished_frames;
      r.flagged_furnished += st.degenerate_directions > 0;
    }
  }
  // Error gathered over the degenerate stretch: the estimate's motion from its first to its last
  // frame against the truth's, both relative to the first pose of the run (est[0] = truth[0]).
  const auto at = [&](double t) { return static_cast<std::size_t>(std::lround(t * 30.0)); };
  const std::size_t a = at(2.4), b = at(5.4);
  const Eigen::Isometry3d align = run.T_W_C[0] * est[0].inverse();
  const Eigen::Vector3d err_a = (align * est[a]).translation() - run.T_W_C[a].translation();
  const Eigen::Vector3d err_b = (align * est[b]).translation() - run.T_W_C[b].translation();
  r.drift_mm_per_s = 1e3 * (err_b - err_a).norm() / (run.stamps_s[b] - run.stamps_s[a]);
  std::printf(
      "wall_slide %s seed %d: %d of %d degenerate frames flagged, %d of %d furnished; error "
      "%.2f mm at 2.4 s, %.2f mm at 5.4 s: %.2f mm/s over the degenerate view\n",
      sim::noiseModelName(model).c_str(), seed, r.flagged_degenerate, r.degenerate_frames,
      r.flagged_furnished, r.furnished_frames, 1e3 * err_a.norm(), 1e3 * err_b.norm(),
      r.drift_mm_per_s);
  return r;
}
}  // namespace

class WallSlide : public ::testing::TestWithParam<int> {};

// With L515 noise nothing in this room is deep enough for basin_deep_floor (1/4) to change a
// pair's weight (sigma 4.9 mm at 3 m against 3.1 mm at 1 m: a factor of 0.40), so the held frames
// are not registered again at all (measured 2026-12-06: 0 of 114 held frames on seed 1; before
// that check every held frame was, and none kept).
TEST_P(WallSlide, FlaggedAndHeldAtTheMotionPrior) {
  const WallSlideRun r = trackWallSlide(sim::NoiseModel::kL515, GetParam());
  EXPECT_EQ(r.tracked, r.frames);
  EXPECT_EQ(r.flagged_degenerate, r.degenerate_frames);
  EXPECT_EQ(r.flagged_furnished, 0) << "of " << r.furnished_frames;
  EXPECT_LE(r.drift_mm_per_s, 5.0);
  EXPECT_EQ(r.deep_retried, 0);
}

INSTANTIATE_TEST_SUITE_P(Seeds, WallSlide, ::testing::Values(1, 2, 3));

// The same run with D435 noise (seeds 1-3, 5 and 11). With the release margin's hysteresis
// (degeneracy_release_margin 6, 2026-12-04) seeds 1-10 drift 2.28 / 1.84 / 1.30 / 0.83 / 2.73 /
// 1.29 / 1.56 / 1.37 / 4.81 / 3.97 mm/s and seeds 11-20 (not looked at while choosing it) 1.39 /
// 1.63 / 1.30 / 3.43 / 2.22 / 2.12 / 1.54 / 2.78 / 2.00 / 1.75, every degenerate frame flagged.
// Without it (release margin 3 = the margin) seeds 1-10 drifted 3.34 / 2.11 / 4.14 / 3.77 / 6.63 /
// 1.25 / 1.32 / 4.03 / 4.24 / 4.22 and seeds 11-20 7.38 / 3.41 / 7.56 / 3.51 / 5.25 / 3.29 / 5.66
// / 4.47 / 4.92 / 6.67 (seeds 5, 11, 13, 15, 17 and 20 fail this test), seeds 3, 10 and 12
// flagging 88 of 89. Before the weighting's floor (noise_weighting_min 1/32) seeds 1-10 drifted
// 4.01 / 2.09 / 4.09 / 2.19 / 6.91 / 1.38 / 1.38 / 4.03 / 4.09 / 4.19; before the held
// directions followed the firm frames' velocity only (velocity_firm_information) 2.2-10.6 mm/s
// (median 7.1), before the depth-noise weighting 5.8-60.4 (median 10.4). With the deep returns'
// retry of held frames (basin_deep_floor, 2026-12-06) seeds 1-20 drift 0.80-4.67 mm/s, every
// degenerate frame still held; D435 noise puts the room's far side below the raised floor, so
// here the retry runs (seed 1: 118 frames registered again, 4 kept, those turning to and from
// the wall).
class WallSlideD435 : public ::testing::TestWithParam<int> {};

TEST_P(WallSlideD435, FlaggedAndHeldAtTheFirmVelocity) {
  const WallSlideRun r = trackWallSlide(sim::NoiseModel::kD435, GetParam());
  EXPECT_EQ(r.tracked, r.frames);
  EXPECT_EQ(r.flagged_degenerate, r.degenerate_frames);
  EXPECT_EQ(r.flagged_furnished, 0) << "of " << r.furnished_frames;
  EXPECT_LE(r.drift_mm_per_s, 5.0);
  EXPECT_GT(r.deep_retried, 0);
}

// What the firm-frame velocity is for: while the view turns degenerate (1.7-2.0 s) its weakest
// direction reads 4-9 times its floor, is still registered and slides on D435 noise; a velocity
// fitted to those frames carries the slide through the 3 s held (seed 3: 7.42 mm/s).
TEST(WallSlideD435Firm, AllFramesVelocityCarriesTheSlide) {
  TrackerConfig all_frames;
  all_frames.velocity_firm_information = 0.0;
  const WallSlideRun firm = trackWallSlide(sim::NoiseModel::kD435, 3);
  const WallSlideRun all = trackWallSlide(sim::NoiseModel::kD435, 3, all_frames);
  EXPECT_GT(all.drift_mm_per_s, 1.5 * firm.drift_mm_per_s);
}

TEST(WallSlideD435Firm, RejectsANegativeThreshold) {
  CellOdometryConfig c;
  c.velocity_firm_information = -1.0;
  EXPECT_FALSE(c.validate().empty());
}

INSTANTIATE_TEST_SUITE_P(Seeds, WallSlideD435, ::testing::Values(1, 2, 3, 5, 11));

// With a camera IMU as motion prior (ImuMotionPrior, a simulated BMI055). Two things make its
// held directions hold (docs/tracking.md, "A camera IMU as motion prior"):
// - A held direction's pose is the guess itself: the IMU filter must not take it back as a
//   measurement of the position, nor the weak directions of the frames turning onto the wall
//   (FrameStatus::measurement_covariance). D435 seed 1 drifted 7.77 mm/s with the pose's
//   covariance as the measurement (the version of 2026-12-05 evening), 0.66 without.
// - Held directions follow the firm frames' line with the IMU's significant accelerations on top
//   (InertialHold), not the filter's velocity: L515 seed 1 drifted 5.42 mm/s on the filter's
//   velocity, which this test fails.
// Measured 2026-12-06 with both: D435 seed 1 1.21 mm/s, L515 seed 1 2.75 mm/s; with the guess
// gate below 2.26 / 2.99 mm/s.
class WallSlideImu : public ::testing::TestWithParam<sim::NoiseModel> {};

TEST_P(WallSlideImu, HeldDirectionsFollowTheFirmFramesAndTheImusAccelerations) {
  const WallSlideRun r = trackWallSlide(GetParam(), 1, TrackerConfig{}, true);
  EXPECT_EQ(r.tracked, r.frames);
  EXPECT_EQ(r.flagged_degenerate, r.degenerate_frames);
  EXPECT_LE(r.drift_mm_per_s, 5.0);
}

INSTANTIATE_TEST_SUITE_P(Noise, WallSlideImu,
                         ::testing::Values(sim::NoiseModel::kD435, sim::NoiseModel::kL515),
                         [](const ::testing::TestParamInfo<sim::NoiseModel>& info) {
                           return sim::noiseModelName(info.param);
                         });

// The registration starts from the last frame's motion, not the IMU's guess, while the two agree
// within the guess's uncertainty (ImuPriorConfig::guess_gate, 3 sigmas): along the directions
// the wall fixes only weakly the fit ends near its start, and the filter's velocity wanders more
// there. L515 seed 7, the seed of 20 where the IMU cost most before the gate: 4.66 mm/s with
// every frame started from the IMU's guess (gate 0), 1.08 with the gate; without the IMU 2.21.
// Over seeds 1-20 the gate takes L515 from 0.84-5.20 to 0.92-4.99 mm/s and D435 from 0.62-5.86
// to 0.67-5.23 (docs/tracking.md).
TEST(WallSlideImuGuessGate, ConstantMotionStartsFromTheLastFramesMotion) {
  const WallSlideRun gated = trackWallSlide(sim::NoiseModel::kL515, 7, TrackerConfig{}, true);
  const WallSlideRun always = trackWallSlide(sim::NoiseModel::kL515, 7, TrackerConfig{}, true, 0.0);
  EXPECT_EQ(gated.flagged_degenerate, gated.degenerate_frames);
  EXPECT_LE(gated.drift_mm_per_s, 2.5);
  EXPECT_GT(always.drift_mm_per_s, 2.0 * gated.drift_mm_per_s);
}

// What the release margin is for: near the margin a direction's gain switches it on and off from
// frame to frame, and each frame that releases it (seed 5: the first frame against a new keyframe,
// reading 4.1 times its floor) takes a whole step, 8-14 mm along the wall there. Seed 11 without
// the hysteresis: 7.38 mm/s, with it 1.39. With normals pooled again at creases (the option
// PcaConfig::crease_sigmas 2) seed 11 does not show it: 2.24 mm/s without, 1.49 with; the test
// pins the default pooling (crease_sigmas 0) it was written for. It also pins held frames to the
// motion prior (basin_deep_floor 0): the deep returns' retry of held frames (the default since
// 2026-12-06) fixes some of the frames that flicker here, and without the hysteresis seed 11 then
// drifts 3.27 mm/s instead of 7.38 (1.38 with it), which no longer shows the release margin.
TEST(WallSlideD435Hysteresis, SingleFramesReleasingADirectionSlide) {
  TrackerConfig base;
  base.pca.crease_sigmas = 0.0;
  base.basin_deep_floor = 0.0;
  TrackerConfig none = base;
  none.registration.degeneracy.release_margin = none.registration.degeneracy.noise_margin;
  const WallSlideRun with = trackWallSlide(sim::NoiseModel::kD435, 11, base);
  const WallSlideRun without = trackWallSlide(sim::NoiseModel::kD435, 11, none);
  EXPECT_GT(without.drift_mm_per_s, 5.0);
  EXPECT_GT(without.drift_mm_per_s, 2.0 * with.drift_mm_per_s);
}

TEST(WallSlideD435Hysteresis, ReleaseMarginBelowTheMarginIsRejected) {
  DegeneracyConfig c;
  EXPECT_TRUE(c.validate().empty());
  c.release_margin = c.noise_margin;  // no hysteresis: allowed
  EXPECT_TRUE(c.validate().empty());
  c.release_margin = 0.5 * c.noise_margin;
  EXPECT_FALSE(c.validate().empty());
  c.release_margin = std::nan("");
  EXPECT_FALSE(c.validate().empty());
}

TEST(NoiseWeightingFloor, IsValidated) {
  RegistrationConfig c;
  EXPECT_TRUE(c.validate().empty());
  for (const double bad : {-0.1, 1.5, std::nan("")}) {
    c.noise_weighting_min = bad;
    EXPECT_FALSE(c.validate().empty()) << bad;
  }
  c.noise_weighting_min = 0.0;  // unbounded: allowed
  EXPECT_TRUE(c.validate().empty());
}
