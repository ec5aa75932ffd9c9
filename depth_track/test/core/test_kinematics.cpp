#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"

using namespace depth_track;

namespace {
// Pure geometry in double precision: only rounding error remains.
constexpr double kTol = 1e-12;

Eigen::Vector3d opticalAxis(const Eigen::Isometry3d& T_W_C) { return T_W_C.linear().col(2); }
}  // namespace

TEST(Kinematics, ZeroAnglesLookAlongTheTrack) {
  const TrackGeometry g;
  const Eigen::Isometry3d T = cameraPoseOnTrack(0.0, 0.0, 0.0, g);
  EXPECT_NEAR((opticalAxis(T) - Eigen::Vector3d::UnitX()).norm(), 0.0, kTol);
  // Optical x is right (= -y in W), optical y is down (= -z in W).
  EXPECT_NEAR((T.linear().col(0) - (-Eigen::Vector3d::UnitY())).norm(), 0.0, kTol);
  EXPECT_NEAR((T.linear().col(1) - (-Eigen::Vector3d::UnitZ())).norm(), 0.0, kTol);
  // The documented default places the optical centre at (0, 0, 0.80) m.
  EXPECT_NEAR((T.translation() - Eigen::Vector3d(0.0, 0.0, 0.80)).norm(), 0.0, kTol);
  EXPECT_NEAR(std::abs(T.linear().determinant() - 1.0), 0.0, kTol);
}

TEST(Kinematics, TrackPositionTranslatesAlongDirection) {
  TrackGeometry g;
  g.direction_W = Eigen::Vector3d(0.0, 2.0, 0.0);  // not unit on purpose: normalised on use
  const Eigen::Isometry3d T0 = cameraPoseOnTrack(0.0, 0.0, 0.0, g);
  const Eigen::Isometry3d T1 = cameraPoseOnTrack(0.75, 0.0, 0.0, g);
  EXPECT_NEAR((T1.translation() - T0.translation() - Eigen::Vector3d(0, 0.75, 0)).norm(), 0.0,
              kTol);
  EXPECT_NEAR((opticalAxis(T0) - Eigen::Vector3d::UnitY()).norm(), 0.0, kTol);
  EXPECT_NEAR((T0.linear() - T1.linear()).norm(), 0.0, kTol);
}

TEST(Kinematics, PositivePitchIsNoseUpAboutThePitchAxis) {
  const TrackGeometry g;
  const double p = 10.0 * kDegToRad;
  const Eigen::Isometry3d T = cameraPoseOnTrack(0.2, p, 0.0, g);
  EXPECT_NEAR((opticalAxis(T) - Eigen::Vector3d(std::cos(p), 0.0, std::sin(p))).norm(), 0.0, kTol);
  // Image rows stay horizontal (no roll): optical x keeps zero z component.
  EXPECT_NEAR(T.linear().col(0).z(), 0.0, kTol);
  // The optical centre turns rigidly about the pitch axis.
  const Eigen::Vector3d pivot =
      g.origin_W + Eigen::Vector3d(0.2 + g.pitch_axis_forward_m, 0.0, g.pitch_axis_height_m);
  const Eigen::Vector3d off = g.camera_offset_m;
  const Eigen::Vector3d expected(off.x() * std::cos(p) - off.z() * std::sin(p), off.y(),
                                 off.x() * std::sin(p) + off.z() * std::cos(p));
  EXPECT_NEAR((T.translation() - pivot - expected).norm(), 0.0, kTol);
}

TEST(Kinematics, PositiveYawTurnsLeft) {
  const TrackGeometry g;
  const double y = 15.0 * kDegToRad;
  const Eigen::Isometry3d T = cameraPoseOnTrack(0.0, 0.0, y, g);
  EXPECT_NEAR((opticalAxis(T) - Eigen::Vector3d(std::cos(y), std::sin(y), 0.0)).norm(), 0.0, kTol);
  EXPECT_NEAR((T.linear().col(1) - (-Eigen::Vector3d::UnitZ())).norm(), 0.0, kTol);
}

TEST(Kinematics, YawIsOuterAxisPitchInner) {
  const double p = 12.0 * kDegToRad, y = -25.0 * kDegToRad;
  const Eigen::Isometry3d T = cameraPoseOnTrack(0.0, p, y, TrackGeometry{});
  const Eigen::Vector3d expected(std::cos(p) * std::cos(y), std::cos(p) * std::sin(y), std::sin(p));
  EXPECT_NEAR((opticalAxis(T) - expected).norm(), 0.0, kTol);
  // Pitch about a yawed horizontal axis never rolls the image.
  EXPECT_NEAR(T.linear().col(0).z(), 0.0, kTol);
}

TEST(Kinematics, BadInputIsNamed) {
  TrackGeometry g;
  g.direction_W = Eigen::Vector3d(0.0, 0.0, 1.0);
  try {
    cameraPoseOnTrack(0.0, 0.0, 0.0, g);
    FAIL() << "vertical track accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("direction_W"), std::string::npos) << e.what();
  }
  EXPECT_THROW(cameraPoseOnTrack(std::numeric_limits<double>::quiet_NaN(), 0.0, 0.0),
               std::invalid_argument);
  g = TrackGeometry{};
  g.pitch_axis_height_m = std::numeric_limits<double>::infinity();
  g.camera_offset_m.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(g.validate().size(), 2u);
}

// ---- sensor references -------------------------------------------------------------------------

namespace {

// A ServoTrack run in closed form: carriage at 42 mm/s, pitch 20 deg at 1/12.6 Hz (RT3), yaw a
// slower 5 deg sine; sensors sampled at 30 Hz from t0, the camera 11 ms out of phase.
constexpr double kSpeed = 0.042, kPitchAmp = 20.0, kPitchW = 2 * M_PI / 12.6, kYawAmp = 5.0,
                 kYawW = 2 * M_PI / 25.0;
double trackPos(double t) { return 0.1 + kSpeed * t; }
double pitchDeg(double t) { return kPitchAmp * std::sin(kPitchW * t); }
double yawDeg(double t) { return kYawAmp * std::sin(kYawW * t); }

RigSensorStreams servoTrackStreams(double t0, double t1, double delay_s = 0.0) {
  RigSensorStreams s;
  for (double t = t0; t <= t1 + 1e-9; t += 1.0 / 30.0) {
    // A reading of instant t reaches the host delay_s later.
    s.track.push_back({t + delay_s, trackPos(t)});
    s.gimbal.push_back({t + delay_s, pitchDeg(t), yawDeg(t)});
  }
  return s;
}

}  // namespace

TEST(SensorReference, ServoTrackInterpolatesBetweenReadings) {
  const RigSensorStreams s = servoTrackStreams(0.0, 10.0);
  std::vector<double> stamps;
  for (int i = 0; i < 320; ++i) stamps.push_back(-0.2 + 0.011 + i / 30.0);  // a few outside
  const RigGeometry g;
  const Trajectory ref = sensorTrajectory(s, stamps, g);
  // Stamps before the first or after the last reading get no pose; the rest keep their stamps.
  std::size_t inside = 0;
  for (const double t : stamps) inside += t >= 0.0 && t <= 10.0;
  ASSERT_EQ(ref.size(), inside);
  // Linear interpolation of a sine errs by at most A w^2 dt^2 / 8 (pitch 6.9e-4 deg, yaw
  // 4.4e-5 deg); the carriage moves linearly (exact). Tolerance: the sum of both bounds on the
  // angle, and what it moves the optical centre (0.054 m from the pitch axis).
  const double dt = 1.0 / 30.0;
  const double bound_deg =
      kPitchAmp * kPitchW * kPitchW * dt * dt / 8.0 + kYawAmp * kYawW * kYawW * dt * dt / 8.0;
  for (const StampedPose& p : ref) {
    const Eigen::Isometry3d T =
        cameraPoseOnTrack(trackPos(p.stamp_s), pitchDeg(p.stamp_s) * kDegToRad,
                          yawDeg(p.stamp_s) * kDegToRad, g.track);
    const double ang = Eigen::AngleAxisd(T.rotation().transpose() * p.T_W_C.rotation()).angle();
    EXPECT_LE(ang, bound_deg * kDegToRad + 1e-12) << p.stamp_s;
    EXPECT_LE((T.translation() - p.T_W_C.translation()).norm(),
              0.06 * bound_deg * kDegToRad + 1e-12);
  }
  // A shift reads the sensors shift_s after each frame.
  const Trajectory shifted = sensorTrajectory(s, {2.0, 3.0}, g, 0.1);
  ASSERT_EQ(shifted.size(), 2u);
  EXPECT_DOUBLE_EQ(shifted[0].stamp_s, 2.0);
  EXPECT_LT((shifted[0].T_W_C.matrix() - sensorTrajectory(s, {2.1}, g)[0].T_W_C.matrix()).norm(),
            1e-12);
  EXPECT_NEAR(s.samplePeriod(), dt, 1e-9);
  EXPECT_EQ(s.describe(), "track_state + carriage_sensors");
}

TEST(SensorReference, TruckDeadReckoningFollowsTheBicycle) {
  RigGeometry g;
  g.truck.T_B_C.translation() = Eigen::Vector3d(0.12, 0.0, 0.35);
  g.truck.T_B_C.linear() = rotationBodyFromOptical();
  // Full left lock at a steady 0.35 m/s, demands settled from the start: the rear axle runs on a
  // circle of radius L / tan(30 deg) = 0.554 m counter-clockwise from (0, 0) heading +x.
  RigSensorStreams s;
  for (int i = 0; i <= 300; ++i) s.truck.push_back({5.0 + i / 30.0, 0.35, -1.0});
  const double R = g.truck.wheelbase_m / std::tan(g.truck.max_steer_deg * kDegToRad);
  const Trajectory ref = sensorTrajectory(s, {5.0, 7.5, 10.0, 15.0, 15.5}, g);
  ASSERT_EQ(ref.size(), 4u);  // 15.5 s is after the last reading
  for (const StampedPose& p : ref) {
    const double heading = 0.35 * (p.stamp_s - 5.0) / R;
    const Eigen::Vector3d axle(R * std::sin(heading), R * (1.0 - std::cos(heading)), 0.0);
    const Eigen::Isometry3d T_W_B =
        Eigen::Translation3d(axle) * Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ());
    const Eigen::Isometry3d expected = T_W_B * g.truck.T_B_C;
    // Midpoint steps of 1 ms on a circle of 0.55 m: errors far below a micrometre.
    EXPECT_LT((expected.translation() - p.T_W_C.translation()).norm(), 1e-6) << p.stamp_s;
    EXPECT_LT(Eigen::AngleAxisd(expected.rotation().transpose() * p.T_W_C.rotation()).angle(),
              1e-6);
  }
  // A speed step from rest through the drive's first-order lag: straight ahead, distance
  // v (T - tau (1 - exp(-T / tau))).
  RigSensorStreams step;
  step.truck.push_back({0.0, 0.0, 0.0});
  for (int i = 1; i <= 90; ++i) step.truck.push_back({i / 30.0, 0.5, 0.0});
  const double T = 3.0 - 1.0 / 30.0, tau = g.truck.speed_lag_s;
  const Trajectory st = sensorTrajectory(step, {1.0 / 30.0, 3.0}, g);
  ASSERT_EQ(st.size(), 2u);
  const double travelled = (st[1].T_W_C.translation() - st[0].T_W_C.translation()).x();
  EXPECT_NEAR(travelled, 0.5 * (T - tau * (1.0 - std::exp(-T / tau))), 1e-6);
  EXPECT_NEAR((st[1].T_W_C.translation() - st[0].T_W_C.translation()).y(), 0.0, 1e-12);
  EXPECT_EQ(step.describe(), "truck_rc");
}

TEST(SensorReference, BadStreamsAreNamed) {
  RigSensorStreams s = servoTrackStreams(0.0, 1.0);
  std::swap(s.gimbal[3], s.gimbal[4]);
  try {
    sensorTrajectory(s, {0.5}, RigGeometry{});
    FAIL() << "unordered stream accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("carriage_sensors sample 4"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(sensorTrajectory(RigSensorStreams{}, {0.5}, RigGeometry{}), std::invalid_argument);
  RigSensorStreams truck;
  truck.truck.push_back({0.0, std::numeric_limits<double>::quiet_NaN(), 0.0});
  EXPECT_THROW(sensorTrajectory(truck, {0.0}, RigGeometry{}), std::invalid_argument);
  TruckGeometry tg;
  tg.wheelbase_m = 0.0;
  tg.max_steer_deg = 95.0;
  EXPECT_EQ(tg.validate().size(), 2u);
}

// TruckOdometry is sensorTrajectory's dead reckoning one reading at a time (rig_odometry's
// source): the same base poses at the readings, on a drive that accelerates, steers and stops.
TEST(SensorReference, TruckOdometryIsTheBatchReferenceOneReadingAtATime) {
  RigGeometry g;
  g.truck.T_B_C.translation() = Eigen::Vector3d(0.12, 0.0, 0.35);
  g.truck.T_B_C.linear() = rotationBodyFromOptical();
  RigSensorStreams s;
  for (int i = 0; i <= 240; ++i) {
    const double t = 2.0 + i / 30.0 + (i % 3) * 1e-3;  // uneven intervals
    s.truck.push_back({t, i < 30 ? 0.0 : 0.45, i < 100 ? 0.0 : (i < 160 ? 0.6 : -0.3)});
  }
  std::vector<double> stamps;
  for (const auto& r : s.truck) stamps.push_back(r.stamp_s);
  const Trajectory batch = sensorTrajectory(s, stamps, g);
  ASSERT_EQ(batch.size(), s.truck.size());
  TruckOdometry odo(g.truck);
  for (std::size_t i = 0; i < s.truck.size(); ++i) {
    const Eigen::Isometry3d T_W_C = odo.add(s.truck[i]) * g.truck.T_B_C;
    EXPECT_LT((T_W_C.matrix() - batch[i].T_W_C.matrix()).norm(), 1e-12) << i;
  }
  EXPECT_EQ(odo.readings(), s.truck.size());
  EXPECT_GT(odo.state().x, 2.0);  // it drove: 0.45 m/s for 7 s, less the lag and the turns
  // Bad readings are refused by name and leave the odometry as it was.
  const TruckOdometry::State before = odo.state();
  const double last = s.truck.back().stamp_s;
  EXPECT_THROW(odo.add({last - 0.1, 0.3, 0.0}), std::invalid_argument);
  EXPECT_THROW(odo.add({last + 0.1, std::numeric_limits<double>::quiet_NaN(), 0.0}),
               std::invalid_argument);
  EXPECT_THROW(odo.add({std::numeric_limits<double>::infinity(), 0.3, 0.0}),
               std::invalid_argument);
  EXPECT_EQ(odo.readings(), s.truck.size());
  EXPECT_EQ(odo.state().x, before.x);
  EXPECT_EQ(odo.state().t, before.t);
  TruckGeometry bad;
  bad.wheelbase_m = -1.0;
  EXPECT_THROW(TruckOdometry{bad}, std::invalid_argument);
}

// The sensors' motion between frames, as Tracker::track takes a prior: composed, it is the
// sensor reference's pose (truck: interpolated between the readings either side, as tf2 does;
// ServoTrack: sensorTrajectory itself).
TEST(SensorReference, SensorMotionPriorComposesToTheSensorReference) {
  RigGeometry g;
  g.truck.T_B_C.translation() = Eigen::Vector3d(0.12, 0.0, 0.35);
  g.truck.T_B_C.linear() = rotationBodyFromOptical();
  RigSensorStreams truck;
  for (int i = 0; i <= 150; ++i) truck.truck.push_back({i / 30.0, i < 20 ? 0.0 : 0.4, 0.5});
  std::vector<double> frames;
  for (int i = 0; i < 160; ++i) frames.push_back(0.011 + i / 30.0);  // last ones after the readings
  const Trajectory ref = sensorTrajectory(truck, frames, g);
  SensorMotionPrior prior(truck, g);
  EXPECT_FALSE(prior.next(frames[0]).has_value());  // no motion before a second frame
  Eigen::Isometry3d T = ref[0].T_W_C;
  std::size_t with = 0;
  for (std::size_t i = 1; i < frames.size(); ++i) {
    const auto m = prior.next(frames[i]);
    if (i >= ref.size()) {
      EXPECT_FALSE(m.has_value()) << "frame " << i << " is after the last reading";
      continue;
    }
    ASSERT_TRUE(m.has_value()) << i;
    ++with;
    T = T * *m;
    // Interpolating linearly between the readings (dt = 1/30 s) errs by the motion's second
    // derivative times dt^2 / 8: while the drive takes up speed (0.4 m/s through a 0.35 s lag,
    // 1.14 m/s^2) 0.16 mm and, on half lock (yaw rate v tan(15 deg) / 0.32 m), 1.3e-4 rad; on
    // the circle at speed the chord's sagitta, ~20 micrometres.
    EXPECT_LT((T.translation() - ref[i].T_W_C.translation()).norm(), 2e-4) << i;
    EXPECT_LT(Eigen::AngleAxisd(T.rotation().transpose() * ref[i].T_W_C.rotation()).angle(),
              2e-4)
        << i;
  }
  EXPECT_EQ(with, ref.size() - 1);
  // Frames must come in time order; a prior needs a stream.
  EXPECT_THROW(prior.next(frames[5]), std::invalid_argument);
  EXPECT_THROW(SensorMotionPrior(RigSensorStreams{}, g), std::invalid_argument);
  RigSensorStreams nan = truck;
  nan.truck[7].speed_mps = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(SensorMotionPrior(nan, g), std::invalid_argument);

  // ServoTrack: the motion between the interpolated sensor poses.
  const RigSensorStreams track = servoTrackStreams(0.0, 4.0);
  SensorMotionPrior track_prior(track, RigGeometry{});
  const Trajectory tref = sensorTrajectory(track, {1.0, 1.5}, RigGeometry{});
  ASSERT_EQ(tref.size(), 2u);
  EXPECT_FALSE(track_prior.next(1.0).has_value());
  const auto tm = track_prior.next(1.5);
  ASSERT_TRUE(tm.has_value());
  EXPECT_LT(((tref[0].T_W_C * *tm).matrix() - tref[1].T_W_C.matrix()).norm(), 1e-12);
}

// isRigid is the one rigid-pose check (kinematics, scene, voxel map): a reflection is orthonormal
// but not a pose, a scaled rotation is refused at the configuration tolerance.
TEST(Se3, IsRigidRefusesReflectionsScalingAndNonFinitePoses) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).matrix();
  T.translation() = Eigen::Vector3d(1.0, 2.0, 3.0);
  EXPECT_TRUE(isRigid(T));
  Eigen::Isometry3d mirrored = T;
  mirrored.linear().col(0) *= -1.0;
  EXPECT_LT(orthonormalityError(mirrored.linear()), 1e-12);
  EXPECT_FALSE(isRigid(mirrored, 1.0));
  Eigen::Isometry3d scaled = T;
  scaled.linear() *= 1.001;  // |R^T R - I| = sqrt(3) (1.001^2 - 1) = 3.5e-3
  EXPECT_NEAR(orthonormalityError(scaled.linear()), std::sqrt(3.0) * (1.001 * 1.001 - 1.0), 1e-9);
  EXPECT_FALSE(isRigid(scaled));
  EXPECT_FALSE(isRigid(scaled, 1e-3));
  EXPECT_TRUE(isRigid(scaled, 1e-2));
  Eigen::Isometry3d nan = T;
  nan.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(isRigid(nan, 1.0));
  TruckGeometry tg;
  EXPECT_TRUE(tg.validate().empty());
  tg.T_B_C = mirrored;
  ASSERT_EQ(tg.validate().size(), 1u);
  EXPECT_NE(tg.validate()[0].find("T_B_C"), std::string::npos);
}
