// ServoTruck bicycle model: straight runs, full-lock circles and the camera mount.
#include <gtest/gtest.h>

#include <cmath>

#include "rig_drivers/sim/rig_sim_truck.hpp"

namespace rig_drivers {
namespace {

constexpr double kPi = 3.14159265358979323846;

TEST(RigSimTruck, StraightRunCoversSpeedTimesTimeMinusLag) {
  TruckModelConfig cfg;
  cfg.speed_scale_error = 0.0;
  TruckModel truck(cfg);
  const double dt = 0.001, v = 0.4, T = 5.0;
  for (int i = 0; i < static_cast<int>(T / dt); ++i) truck.step(dt, v, 0.0);
  // A first-order lag from rest loses v * tau of distance once settled (exp(-T/tau) ~ 6e-7).
  const double expected = v * (T - cfg.speed_time_constant_s);
  EXPECT_NEAR(truck.state().x_m, expected, 1e-4);
  EXPECT_NEAR(truck.state().y_m, 0.0, 1e-12);
  EXPECT_NEAR(truck.state().heading_rad, 0.0, 1e-12);
}

TEST(RigSimTruck, SpeedCalibrationErrorScalesDistance) {
  TruckModelConfig cfg;
  cfg.speed_scale_error = 0.05;
  TruckModel truck(cfg);
  for (int i = 0; i < 5000; ++i) truck.step(0.001, 0.4, 0.0);
  EXPECT_NEAR(truck.state().x_m, 1.05 * 0.4 * (5.0 - cfg.speed_time_constant_s), 1e-4);
}

TEST(RigSimTruck, FullLeftLockDrivesACircleOfTheMinimumRadius) {
  TruckModelConfig cfg;
  cfg.speed_scale_error = 0.0;
  TruckModel truck(cfg);
  const double R = truck.minTurnRadius();
  EXPECT_NEAR(R, cfg.wheelbase_m / std::tan(cfg.max_steer_deg * kPi / 180.0), 1e-12);
  // Settle speed and steering first, then drive one lap and compare positions on the circle.
  const double dt = 0.001, v = 0.3;
  for (int i = 0; i < 3000; ++i) truck.step(dt, v, -1.0);
  const TruckState a = truck.state();
  const double lap_s = 2.0 * kPi * R / v;
  for (int i = 0; i < static_cast<int>(std::round(lap_s / dt)); ++i) truck.step(dt, v, -1.0);
  const TruckState b = truck.state();
  // Back to the same point after one lap (within one step of travel, v * dt = 0.3 mm).
  EXPECT_NEAR(b.x_m, a.x_m, 1e-3);
  EXPECT_NEAR(b.y_m, a.y_m, 1e-3);
  EXPECT_NEAR(std::remainder(b.heading_rad - a.heading_rad, 2 * kPi), 0.0, 2e-3);
  // The centre lies R to the left of the rear axle (left turn = counter-clockwise).
  const Eigen::Vector2d centre(a.x_m - R * std::sin(a.heading_rad),
                               a.y_m + R * std::cos(a.heading_rad));
  for (int i = 0; i < 1000; ++i) {
    truck.step(dt, v, -1.0);
    const Eigen::Vector2d p(truck.state().x_m, truck.state().y_m);
    ASSERT_NEAR((p - centre).norm(), R, 1e-6);
  }
}

TEST(RigSimTruck, CameraLooksForwardAtMountHeight) {
  TruckModelConfig cfg;
  TruckModel truck(cfg, TruckState{1.0, 2.0, kPi / 2, 0, 0, 0});
  const Eigen::Isometry3d T_W_C = truck.T_W_C();
  // Optical z (forward) = heading (+y in W); optical y (down) = -z in W.
  EXPECT_NEAR((T_W_C.rotation().col(2) - Eigen::Vector3d(0, 1, 0)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((T_W_C.rotation().col(1) - Eigen::Vector3d(0, 0, -1)).norm(), 0.0, 1e-12);
  EXPECT_NEAR(
      (T_W_C.translation() - Eigen::Vector3d(1.0, 2.0 + cfg.camera_forward_m, cfg.camera_height_m))
          .norm(),
      0.0, 1e-12);
}

TEST(RigSimTruck, BadConfigAndInputsAreRejected) {
  TruckModelConfig cfg;
  cfg.wheelbase_m = -1;
  cfg.max_steer_deg = 90;
  try {
    TruckModel t(cfg);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("wheelbase_m"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("max_steer_deg"), std::string::npos);
  }
  TruckModel ok{TruckModelConfig{}};
  EXPECT_THROW(ok.step(0.0, 0.1, 0.0), std::invalid_argument);
  EXPECT_THROW(ok.step(0.01, std::nan(""), 0.0), std::invalid_argument);
}

}  // namespace
}  // namespace rig_drivers
