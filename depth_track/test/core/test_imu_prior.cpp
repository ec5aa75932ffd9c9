// The IMU motion prior (ImuMotionPrior) and the simulated camera IMU (sim::simulateImu): exact
// readings give back the rendered trajectory's motion between frames; readings that are not a
// still camera's, not m/s^2, out of order or with gaps are refused with the reason.
#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <set>

#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/core/sim/imu.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"

using namespace depth_track;

namespace {

// An IMU mounted off the optical centre and turned against it, as on a real camera.
Eigen::Isometry3d imuMount() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.03, -0.01, 0.02);
  return T;
}

Matrix6d smallCov() { return Matrix6d::Identity() * 1e-8; }

// A rendered run read by an exact IMU at imuMount(), and the prior fed frame by frame.
struct ExactImu {
  sim::RenderedRun run;
  ImuPriorConfig cfg;
  std::vector<ImuSample> samples;
  std::optional<ImuMotionPrior> prior;
  std::size_t fed = 0;
  explicit ExactImu(const std::string& name, double accel_significance) : run(sim::makeRun(name)) {
    cfg.T_C_I = imuMount();
    cfg.accel_significance = accel_significance;
    samples = sim::simulateImu(run, cfg.T_C_I, sim::ImuNoiseConfig::none(), 1);
    prior.emplace(cfg);
  }
  // Gives the prior the readings up to frame i; returns its stamp.
  double feed(std::size_t i) {
    fed = prior->addUpTo(samples, fed, run.stamps_s[i]);
    return run.stamps_s[i];
  }
};

}  // namespace

namespace {
struct GuessErrors {
  std::vector<double> mm, deg;  // per frame from the second on
  Eigen::Vector3d gravity = Eigen::Vector3d::Zero();
};

// The prior over a rendered run, given the true poses as the tracked ones (with exact readings):
// the error of its guess for each next frame against the true motion.
GuessErrors guessErrors(const std::string& name) {
  ExactImu x(name, 0.0);  // the integration itself (the soft threshold: its own test)
  const sim::RenderedRun& run = x.run;
  ImuMotionPrior& prior = *x.prior;
  EXPECT_GE(x.samples.size(), static_cast<std::size_t>((run.stamps_s.back() + 0.5) * 200));
  GuessErrors out;
  for (std::size_t i = 0; i < run.size(); ++i) {
    const double t = x.feed(i);
    const auto guess = prior.predict(t);
    EXPECT_EQ(guess.has_value(), i > 0) << name << " frame " << i;
    if (guess) {
      const Eigen::Isometry3d truth = run.T_W_C[i - 1].inverse() * run.T_W_C[i];
      const Eigen::Isometry3d err = truth.inverse() * *guess;
      out.mm.push_back(1e3 * err.translation().norm());
      out.deg.push_back(rotationAngle(err) * 180.0 / M_PI);
    }
    EXPECT_TRUE(prior.update(t, run.T_W_C[i], smallCov())) << prior.reason();
    if (i == 0) out.gravity = prior.gravity();
  }
  return out;
}

// Largest of v[from, v.size() - but_last).
double maxOf(const std::vector<double>& v, std::size_t from = 0, std::size_t but_last = 0) {
  double m = 0.0;
  for (std::size_t i = from; i + but_last < v.size(); ++i) m = std::max(m, v[i]);
  return m;
}
}  // namespace

// Room3: at rest for three frames, then two laps of a circle at 0.3 m/s (a turn of 0.43 rad/s
// from a standing start), with the IMU off the optical centre and turned against it. Gravity is
// straight down in the run's world (z up, REP 103) and each guess is the true motion to within
// the integration's error. The start's jump in speed and turn rate falls inside one 5 ms reading,
// whose mean a reading holds from its own stamp, and so does the stop after the last frame: the
// guesses of frames 2, 3 and the last are off by up to 0.34 mm / 0.027 deg. The filter takes the
// start's error out over the next two seconds; from
// 2 s on the guesses are within 0.002 mm / 0.0001 deg (measured).
TEST(ImuPrior, ExactReadingsGiveBackTheMotionBetweenFrames) {
  const GuessErrors e = guessErrors("room3");
  EXPECT_NEAR(e.gravity.x(), 0.0, 1e-6);
  EXPECT_NEAR(e.gravity.y(), 0.0, 1e-6);
  EXPECT_NEAR(e.gravity.z(), -9.80665, 1e-6);
  std::printf("room3, exact readings: worst guess error %.4f mm, %.5f deg over %zu frames; "
              "from 2 s to the last but one %.4f mm, %.5f deg\n",
              maxOf(e.mm), maxOf(e.deg), e.mm.size(), maxOf(e.mm, 60, 1), maxOf(e.deg, 60, 1));
  EXPECT_LT(maxOf(e.mm), 0.5);
  EXPECT_LT(maxOf(e.deg), 0.05);
  EXPECT_LT(maxOf(e.mm, 60, 1), 0.02);
  EXPECT_LT(maxOf(e.deg, 60, 1), 0.001);
}

// wall_slide sways in pitch (0.3 deg at 0.9 Hz) from the start, so the "still" window before
// the first frame tilts and gravity is taken 0.035 m/s^2 off, and the gyro's mean over it (1
// deg/s of sway) is taken for its bias. The tracked positions pull the filter's gravity error in:
// the guesses are off by up to 0.22 mm over the first second and 0.08 mm from 3 s on
// (measured), through the turns to the wall and back. The tracked rotations correct the gyro's
// bias: the guesses' rotation is off by the sway's mean rate over a frame at first (0.033 deg)
// and by 0.0023 deg from 3 s on (measured; 0.034 deg throughout while the start's mean stayed
// the bias, before 2026-12-05's evening).
TEST(ImuPrior, ASwayingStartIsCorrectedByTheTrackedPositions) {
  const GuessErrors e = guessErrors("wall_slide");
  EXPECT_GT(std::abs(e.gravity.x()) + std::abs(e.gravity.y()), 0.01);
  EXPECT_NEAR(e.gravity.norm(), 9.80665, 0.01);
  std::printf("wall_slide, exact readings: worst guess error %.4f mm, %.5f deg in the first "
              "second, %.4f mm, %.5f deg from 3 s on\n",
              maxOf(std::vector<double>(e.mm.begin(), e.mm.begin() + 30)),
              maxOf(std::vector<double>(e.deg.begin(), e.deg.begin() + 30)), maxOf(e.mm, 90),
              maxOf(e.deg, 90));
  EXPECT_LT(maxOf(e.mm), 0.5);
  EXPECT_LT(maxOf(e.mm, 90), 0.2);
  EXPECT_LT(maxOf(e.deg), 0.05);
  EXPECT_LT(maxOf(e.deg, 90), 0.005);
}

// wall_slide's three seconds square on to the wall, as a tracker that holds every position
// direction there would take them: each frame's position is the last one moved by the guess
// (its rotation the true one, which the view fixes), given with a covariance that says nothing
// was measured. The camera moves at a constant 0.15 m/s through the turn before and the held
// stretch; the IMU, 3.7 cm off the optical centre, does not: the lever arm turning with the rig
// adds w x r to its velocity (up to 0.06 m/s in the turn), which the end of the turn takes off
// again. That change is known from the gyro, so the soft threshold judges the camera's
// acceleration and the lever arm's part is kept whole: the held stretch ends 4.3 mm off the
// true motion over its 0.45 m (exact readings, measured; the gravity taken at the swaying start
// is 0.035 m/s^2 off, see above). Thresholding the IMU point's acceleration instead (the
// version before 2026-12-05's evening) cut the lever arm's part and ended 148 mm off.
TEST(ImuPrior, ALeverArmTurningWithTheRigIsNoAcceleration) {
  ExactImu x("wall_slide", ImuPriorConfig{}.accel_significance);
  const sim::RenderedRun& run = x.run;
  ImuMotionPrior& prior = *x.prior;
  const auto frameAt = [](double t) { return static_cast<std::size_t>(std::lround(t * 30.0)); };
  const std::size_t a = frameAt(2.4), b = frameAt(5.4);
  Eigen::Isometry3d held = Eigen::Isometry3d::Identity();
  for (std::size_t i = 0; i <= b; ++i) {
    const double t = x.feed(i);
    if (i <= a) {
      ASSERT_TRUE(prior.update(t, run.T_W_C[i], smallCov())) << prior.reason();
      held = run.T_W_C[i];
      continue;
    }
    const auto guess = prior.predict(t);
    ASSERT_TRUE(guess.has_value()) << "frame " << i;
    held = held * *guess;
    held.linear() = run.T_W_C[i].linear();
    Matrix6d cov = smallCov();  // the rotation fixed, the position not at all
    cov.bottomRightCorner<3, 3>() = Eigen::Matrix3d::Identity();
    ASSERT_TRUE(prior.update(t, held, cov));
  }
  const Eigen::Vector3d moved = held.translation() - run.T_W_C[a].translation();
  const Eigen::Vector3d truth = run.T_W_C[b].translation() - run.T_W_C[a].translation();
  std::printf("wall_slide held from 2.4 to 5.4 s on the IMU alone: %.2f mm off over %.0f mm\n",
              1e3 * (moved - truth).norm(), 1e3 * truth.norm());
  EXPECT_NEAR(truth.norm(), 0.45, 1e-3);
  EXPECT_LT((moved - truth).norm(), 0.01);
}

// The gyro's bias follows the tracked rotations, but a jump of the tracked pose (a
// relocalisation or a loop closure moving the tracker) is not taken for one: room3 with exact
// readings and the true poses, one frame given 1 deg off about the vertical. Without the
// 5-sigma gate the bias takes a share of the 0.017 rad residual and this test fails (checked).
TEST(ImuPrior, ATrackedPoseJumpIsNotAGyroBias) {
  ExactImu x("room3", ImuPriorConfig{}.accel_significance);
  const sim::RenderedRun& run = x.run;
  ImuMotionPrior& prior = *x.prior;
  Eigen::Vector3d before = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i <= 150; ++i) {
    const double t = x.feed(i);
    Eigen::Isometry3d pose = run.T_W_C[i];
    if (i == 150) {
      before = prior.gyroBias();
      pose.linear() =
          Eigen::AngleAxisd(M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
          pose.linear();
    }
    ASSERT_TRUE(prior.update(t, pose, smallCov())) << prior.reason();
  }
  EXPECT_LT(before.norm(), 1e-4);  // exact readings of a still start: no bias
  EXPECT_LT((prior.gyroBias() - before).norm(), 1e-6);
}

// A still camera read by a BMI055 (noise and bias): the readings' spread is the datasheet's
// noise density at 200 Hz, their mean gravity plus a bias of at most 0.1 m/s^2 per axis.
TEST(ImuPrior, SimulatedBmi055AtRest) {
  const sim::RenderedRun run = sim::makeRun("chair_still");
  ASSERT_TRUE(static_cast<bool>(run.pose_at));
  const auto noise = sim::ImuNoiseConfig::bmi055();
  struct Stats {
    Eigen::Vector3d accel_mean, gyro_mean;
    double accel_sigma, gyro_sigma;
    std::size_t n;
  };
  const auto stats = [&](std::uint64_t seed) {
    const auto samples = sim::simulateImu(run, Eigen::Isometry3d::Identity(), noise, seed);
    Stats st{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 0.0, 0.0, samples.size()};
    for (const auto& s : samples) st.accel_mean += s.accel_m_s2, st.gyro_mean += s.gyro_rad_s;
    st.accel_mean /= st.n;
    st.gyro_mean /= st.n;
    for (const auto& s : samples) {
      st.accel_sigma += (s.accel_m_s2 - st.accel_mean).squaredNorm();
      st.gyro_sigma += (s.gyro_rad_s - st.gyro_mean).squaredNorm();
    }
    st.accel_sigma = std::sqrt(st.accel_sigma / st.n / 3.0);
    st.gyro_sigma = std::sqrt(st.gyro_sigma / st.n / 3.0);
    return st;
  };
  const Stats a = stats(7), b = stats(8);
  EXPECT_NEAR(a.accel_sigma, noise.accel_noise_m_s2, 0.1 * noise.accel_noise_m_s2);
  EXPECT_NEAR(a.gyro_sigma, noise.gyro_noise_rad_s, 0.1 * noise.gyro_noise_rad_s);
  // The means' own noise: sigma / sqrt(n), 0.0008 m/s^2 and 0.00013 rad/s over the 700
  // readings; the biases stand out of it, within the preset's bounds, and another seed draws
  // others.
  const Eigen::Vector3d up_C = run.T_W_C[0].linear().transpose() * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d bias_a = a.accel_mean - 9.80665 * up_C;
  const Eigen::Vector3d bias_b = b.accel_mean - 9.80665 * up_C;
  const double accel_mean_sigma = noise.accel_noise_m_s2 / std::sqrt(static_cast<double>(a.n));
  const double gyro_mean_sigma = noise.gyro_noise_rad_s / std::sqrt(static_cast<double>(a.n));
  std::printf("seed 7: accelerometer bias %.4f m/s^2, gyro bias %.5f rad/s; seed 8: %.4f, %.5f\n",
              bias_a.norm(), a.gyro_mean.norm(), bias_b.norm(), b.gyro_mean.norm());
  EXPECT_LE(bias_a.cwiseAbs().maxCoeff(), noise.accel_bias_m_s2 + 4 * accel_mean_sigma);
  EXPECT_LE(a.gyro_mean.cwiseAbs().maxCoeff(), noise.gyro_bias_rad_s + 4 * gyro_mean_sigma);
  EXPECT_GT(bias_a.norm(), 10 * accel_mean_sigma);
  EXPECT_GT(a.gyro_mean.norm(), 10 * gyro_mean_sigma);
  EXPECT_GT((bias_a - bias_b).norm(), 10 * accel_mean_sigma);
  EXPECT_GT((a.gyro_mean - b.gyro_mean).norm(), 10 * gyro_mean_sigma);
}

TEST(ImuPrior, StartsOnlyFromAStillCameraReadInMetresPerSecondSquared) {
  ImuPriorConfig cfg;
  const Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  {  // a driver that publishes g instead of m/s^2
    ImuMotionPrior prior(cfg);
    for (int j = 0; j < 60; ++j) prior.add({j * 0.005, Eigen::Vector3d::Zero(), {0, -1.0, 0}});
    EXPECT_FALSE(prior.update(0.3, pose, smallCov()));
    EXPECT_NE(prior.reason().find("m/s^2"), std::string::npos) << prior.reason();
    EXPECT_FALSE(prior.predict(0.33).has_value());
  }
  {  // shaken before the first frame
    ImuMotionPrior prior(cfg);
    for (int j = 0; j < 60; ++j)
      prior.add({j * 0.005, Eigen::Vector3d::Zero(), {(j % 2 ? 3.0 : -3.0), -9.8, 0}});
    EXPECT_FALSE(prior.update(0.3, pose, smallCov()));
    EXPECT_NE(prior.reason().find("not still"), std::string::npos) << prior.reason();
    // Still from then on: it starts at a later frame.
    for (int j = 60; j < 200; ++j) prior.add({j * 0.005, Eigen::Vector3d::Zero(), {0, -9.8, 0}});
    EXPECT_TRUE(prior.update(0.99, pose, smallCov())) << prior.reason();
    EXPECT_TRUE(prior.reason().empty());
  }
  {  // no readings at all
    ImuMotionPrior prior(cfg);
    EXPECT_FALSE(prior.update(0.3, pose, smallCov()));
    EXPECT_NE(prior.reason().find("fewer than 2"), std::string::npos) << prior.reason();
  }
}

TEST(ImuPrior, RefusesBadReadingsAndGaps) {
  ImuPriorConfig cfg;
  ImuMotionPrior prior(cfg);
  for (int j = 0; j < 60; ++j) prior.add({j * 0.005, Eigen::Vector3d::Zero(), {0, -9.8, 0}});
  EXPECT_THROW(prior.add({0.1, Eigen::Vector3d::Zero(), {0, -9.8, 0}}), std::invalid_argument);
  EXPECT_THROW(prior.add({0.4, Eigen::Vector3d(NAN, 0, 0), {0, -9.8, 0}}), std::invalid_argument);
  EXPECT_EQ(prior.samples(), 60u);  // unchanged by the refused readings
  ASSERT_TRUE(prior.update(0.29, Eigen::Isometry3d::Identity(), smallCov()));
  EXPECT_TRUE(prior.predict(0.30).has_value());
  // The last reading (0.295 s) is more than max_gap_s (50 ms) before 0.36 s.
  EXPECT_FALSE(prior.predict(0.36).has_value());
  // A gap inside the interval.
  prior.add({0.5, Eigen::Vector3d::Zero(), {0, -9.8, 0}});
  EXPECT_FALSE(prior.predict(0.45).has_value());
  EXPECT_FALSE(prior.predict(0.29).has_value());  // not after the last frame
  EXPECT_THROW(prior.update(0.2, Eigen::Isometry3d::Identity(), smallCov()),
               std::invalid_argument);
  Matrix6d nan_cov = smallCov();
  nan_cov(0, 0) = NAN;
  EXPECT_THROW(prior.update(0.5, Eigen::Isometry3d::Identity(), nan_cov), std::invalid_argument);
}

TEST(ImuPrior, ConfigAndSimulatorCheckTheirInput) {
  ImuPriorConfig bad;
  bad.position_floor_m = 0.0;
  bad.accel_noise_density = -1.0;
  try {
    ImuMotionPrior prior(bad);
    FAIL() << "accepted a bad config";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("position_floor_m"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("accel_noise_density"), std::string::npos);
  }
  // A stepped run has no trajectory between its frames.
  const sim::RenderedRun stepped = sim::makeRun("xtest1_05_chair");
  EXPECT_THROW(sim::simulateImu(stepped, Eigen::Isometry3d::Identity(),
                                sim::ImuNoiseConfig::none(), 1),
               std::invalid_argument);
  EXPECT_THROW(sim::ImuNoiseConfig::parse("bmi088"), std::invalid_argument);
}

// The settings table behind ~imu_<name> and --imu-<name>: every row reads back what it sets,
// moves its own field of the config and no other, and a value that is not a number is refused
// naming the row; a value out of range is left to validate(), which names the field.
TEST(ImuPrior, EverySettingOfTheTableSetsItsOwnField) {
  const ImuPriorConfig d;
  ASSERT_EQ(imuPriorParams().size(), 10u);
  std::set<std::string> names;
  for (const ImuParamSpec& p : imuPriorParams()) {
    SCOPED_TRACE(p.name);
    EXPECT_TRUE(names.insert(p.name).second) << "declared twice";
    EXPECT_FALSE(p.unit.empty());
    ImuPriorConfig c;
    const double v = 1.5 * std::stod(p.get(d));  // within every range from the default
    p.set(c, param_text::format(v));
    EXPECT_DOUBLE_EQ(std::stod(p.get(c)), v);
    EXPECT_TRUE(c.validate().empty());
    int changed = 0;
    for (const ImuParamSpec& q : imuPriorParams()) changed += q.get(c) != q.get(d);
    EXPECT_EQ(changed, 1);
    try {
      p.set(c, "fast");
      FAIL() << "accepted 'fast'";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(p.name), std::string::npos) << e.what();
    }
  }
  ImuPriorConfig c;
  setParam(imuPriorParams(), c, "guess_gate", "-1", "IMU prior");
  ASSERT_EQ(c.validate().size(), 1u);
  EXPECT_NE(c.validate().front().find("guess_gate"), std::string::npos);
  EXPECT_THROW(setParam(imuPriorParams(), c, "guess_gates", "1", "IMU prior"),
               std::invalid_argument);
}

// The soft threshold (accel_significance): after a still start the filter knows the
// accelerometer's error to about the readings' spread (0.01 m/s^2 here), so a 2 m/s^2 start reads
// as one, less three of those sigmas (measured 0.789 of 0.803 mm over the frame), and 0.02 m/s^2
// as none (a constant velocity).
TEST(ImuPrior, AnAccelerationWithinTheErrorIsTakenAsNone) {
  for (const double accel : {0.02, 2.0}) {
    ImuPriorConfig cfg;
    ImuMotionPrior prior(cfg);
    int j = 0;
    for (; j <= 60; ++j) prior.add({j * 0.005, Eigen::Vector3d::Zero(), {0, 0, 9.80665}});
    ASSERT_TRUE(prior.update(0.3, Eigen::Isometry3d::Identity(), smallCov()));
    for (; j <= 67; ++j) prior.add({j * 0.005, Eigen::Vector3d::Zero(), {accel, 0, 9.80665}});
    const auto guess = prior.predict(0.3 + 1.0 / 30);
    ASSERT_TRUE(guess.has_value());
    const double moving = 1.0 / 30 - 0.005;  // the reading at 0.3 s still reads rest
    const double x = guess->translation().x(), exact = 0.5 * accel * moving * moving;
    std::printf("accel %.2f m/s^2: guess %.4f mm, exact %.4f mm\n", accel, 1e3 * x, 1e3 * exact);
    if (accel < 0.1)
      EXPECT_NEAR(x, 0.0, 1e-7);
    else
      EXPECT_NEAR(x, exact, 0.05 * exact);
    // From rest the whole displacement is the significant acceleration's: what the tracker's
    // held directions add to the firm frames' line (InertialHold).
    const auto g = prior.guess(0.3 + 1.0 / 30);
    ASSERT_TRUE(g.has_value());
    EXPECT_NEAR(g->hold.displacement_W.x(), x, 1e-9);
  }
}

// The hold's displacement sums what the significant accelerations made since the start: a start
// at 2 m/s^2 for 65 ms and then a constant 0.13 m/s (the readings exact), frame by frame, within
// 5 % of the truth (the soft threshold takes three sigmas off each interval's acceleration);
// 0.02 m/s^2 makes none.
TEST(ImuPrior, TheHoldsDisplacementSumsTheSignificantAccelerations) {
  for (const double accel : {0.02, 2.0}) {
    ImuMotionPrior prior{ImuPriorConfig{}};
    int j = 0;
    for (; j <= 60; ++j) prior.add({j * 0.005, Eigen::Vector3d::Zero(), {0, 0, 9.80665}});
    ASSERT_TRUE(prior.update(0.3, Eigen::Isometry3d::Identity(), smallCov()));
    for (; j <= 100; ++j)
      prior.add({j * 0.005, Eigen::Vector3d::Zero(), {j <= 73 ? accel : 0.0, 0, 9.80665}});
    // The truth: accelerating over [0.305, 0.370) s, then coasting.
    const auto truth = [&](double t) {
      const double t0 = 0.305, t1 = 0.370;
      if (t <= t0) return 0.0;
      if (t <= t1) return 0.5 * accel * (t - t0) * (t - t0);
      return 0.5 * accel * (t1 - t0) * (t1 - t0) + accel * (t1 - t0) * (t - t1);
    };
    for (int k = 1; k <= 4; ++k) {
      const double t = 0.3 + k / 30.0;
      const auto g = prior.guess(t);
      ASSERT_TRUE(g.has_value()) << k;
      const double d = g->hold.displacement_W.x();
      std::printf("accel %.2f m/s^2, frame %d: hold displacement %.4f mm, truth %.4f mm\n", accel,
                  k, 1e3 * d, 1e3 * truth(t));
      if (accel < 0.1)
        EXPECT_NEAR(d, 0.0, 1e-9) << k;
      else
        EXPECT_NEAR(d, truth(t), 0.05 * truth(t)) << k;
      EXPECT_NEAR(g->hold.displacement_W.tail<2>().norm(), 0.0, 1e-9) << k;
      Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
      pose.translation().x() = truth(t);
      ASSERT_TRUE(prior.update(t, pose, smallCov()));
    }
  }
}

// The guess gate (ImuPriorConfig::guess_gate): the tracker registers from the last frame's motion
// while the IMU's guess lies within guess_gate standard deviations of the guess's displacement
// (the filter's velocity sigma times the interval) of it. After a perfectly still start the
// velocity is known to the start's floor of 1 mm/s, and over one interval T at rest it spreads by
// the white acceleration noise, accel_noise_density^2 + unmodelled_accel^2 T per second: sigma_v
// = sqrt(1e-6 + (0.0015^2 + 0.1^2 T) T) m/s, 3.48 mm/s at 30 Hz, so gate 3 allows 0.348 mm. The
// tolerance scales with the gate (0: none, the guess always), and the config and the tracker
// refuse what cannot be a tolerance.
TEST(ImuPrior, TheGuessToleranceIsTheGateTimesTheGuessSigma) {
  double tol[3];
  const double gates[3] = {0.0, 3.0, 6.0};
  for (int k = 0; k < 3; ++k) {
    ImuPriorConfig cfg;
    cfg.guess_gate = gates[k];
    ImuMotionPrior prior(cfg);
    int j = 0;
    for (; j <= 67; ++j) prior.add({j * 0.005, Eigen::Vector3d::Zero(), {0, 0, 9.80665}});
    ASSERT_TRUE(prior.update(0.3, Eigen::Isometry3d::Identity(), smallCov()));
    const auto g = prior.guess(0.3 + 1.0 / 30);
    ASSERT_TRUE(g.has_value());
    tol[k] = g->hold.guess_tolerance_m;
  }
  std::printf("guess tolerance at gate 3 after a still start: %.4f mm\n", 1e3 * tol[1]);
  const ImuPriorConfig d;
  const double T = 1.0 / 30;
  const double sigma_v = std::sqrt(
      1e-6 + (d.accel_noise_density * d.accel_noise_density +
              d.unmodelled_accel_m_s2 * d.unmodelled_accel_m_s2 * T) * T);
  EXPECT_EQ(tol[0], 0.0);
  EXPECT_NEAR(tol[1], 3.0 * sigma_v * T, 1e-3 * tol[1]);
  EXPECT_NEAR(tol[2], 2.0 * tol[1], 1e-12);

  for (const double bad : {-1.0, 10.5, std::nan("")}) {
    ImuPriorConfig cfg;
    cfg.guess_gate = bad;
    EXPECT_FALSE(cfg.validate().empty()) << bad;
  }
  const sim::RenderedRun run = sim::makeRun("wall_slide");
  Tracker tracker(run.intrinsics, TrackerConfig{});
  const DepthImage frame = run.renderFrame(0, sim::NoiseConfig::forModel(sim::NoiseModel::kNone), 1);
  InertialHold bad_hold;
  bad_hold.guess_tolerance_m = -1e-3;
  EXPECT_THROW(tracker.track(frame, 0.0, Eigen::Isometry3d::Identity(), bad_hold),
               std::invalid_argument);
}

// The untracked frame: the filter carries on with the IMU alone, and a frame's pose covariance
// comes from its status (what the registration measured, not the pose's covariance with the
// prior in it), turned into the world frame.
TEST(ImuPrior, PoseCovarianceOfAStatus) {
  FrameStatus st;
  st.tracked = false;
  EXPECT_FALSE(trackedPoseCovariance(st).has_value());
  st.tracked = true;
  st.covariance = Matrix6d::Identity();  // not what the filter takes
  st.measurement_covariance.setZero();
  st.measurement_covariance(3, 3) = 4e-4;  // along the reference camera's x
  st.measurement_covariance(2, 2) = 1e-6;  // rotation about its z
  st.T_W_Cref.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Matrix6d c = *trackedPoseCovariance(st);
  EXPECT_NEAR(c(3, 3), 4e-4, 1e-12);  // the camera's x is the world's x
  EXPECT_NEAR(c(4, 4), 0.0, 1e-12);
  EXPECT_NEAR(c(1, 1), 1e-6, 1e-12);  // its z is the world's -y
  EXPECT_NEAR(c(2, 2), 0.0, 1e-12);
}
