#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "depth_track/core/servotrack_kinematics.hpp"

using namespace depth_track;

namespace {
constexpr double kDeg = M_PI / 180.0;
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
  const double p = 10.0 * kDeg;
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
  const double y = 15.0 * kDeg;
  const Eigen::Isometry3d T = cameraPoseOnTrack(0.0, 0.0, y, g);
  EXPECT_NEAR((opticalAxis(T) - Eigen::Vector3d(std::cos(y), std::sin(y), 0.0)).norm(), 0.0, kTol);
  EXPECT_NEAR((T.linear().col(1) - (-Eigen::Vector3d::UnitZ())).norm(), 0.0, kTol);
}

TEST(Kinematics, YawIsOuterAxisPitchInner) {
  const double p = 12.0 * kDeg, y = -25.0 * kDeg;
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
