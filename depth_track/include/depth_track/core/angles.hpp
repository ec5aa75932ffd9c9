#pragma once
/// Degree / radian conversion factors: the one definition of both (ROS-free core).
#include <cmath>

namespace depth_track {

/// Radians per degree.
inline constexpr double kDegToRad = M_PI / 180.0;
/// Degrees per radian.
inline constexpr double kRadToDeg = 180.0 / M_PI;

}  // namespace depth_track
