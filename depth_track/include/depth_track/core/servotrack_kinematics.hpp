#pragma once
/// ServoTrack rig kinematics: camera pose from carriage position and gimbal angles (ROS-free core).
///
/// Chain (thesis ch. 4.2: a carriage on a straight track carrying a yaw-over-pitch servo table):
///   W -> K (carriage at track position s, x along the track, z up)
///     -> yaw stage (rotation about K's vertical z axis; yaw positive = camera turns LEFT)
///     -> pitch axis (offset forward/up from the yaw axis; rotation about the stage's y axis;
///        pitch positive = NOSE UP)
///     -> camera body B (x forward, y left, z up; optical centre offset from the pitch axis)
///     -> optical frame C (x right, y down, z forward).
/// At zero angles the optical z axis points along the track direction and the image rows are
/// horizontal.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace depth_track {

/// Geometry of the ServoTrack rig in the world frame W (REP 103: x forward, y left, z up, floor
/// z = 0). The thesis gives no drawing dimensions; the defaults are plausible for its bench rig
/// and put the optical centre at (0, 0, 0.80) m at track position 0 with zero angles.
struct TrackGeometry {
  /// Point where the yaw axis meets the carriage deck at track position 0, metres in W.
  Eigen::Vector3d origin_W{-0.045, 0.0, 0.62};
  /// Direction of travel for increasing track position (normalised on use; must be horizontal
  /// enough to define a level carriage, i.e. not parallel to z).
  Eigen::Vector3d direction_W{1.0, 0.0, 0.0};
  /// Height of the pitch axis above the deck, along the yaw axis, metres.
  double pitch_axis_height_m = 0.15;
  /// Forward offset of the pitch axis from the yaw axis (in the yawed stage), metres.
  double pitch_axis_forward_m = 0.0;
  /// Optical centre relative to the pitch axis in the camera body frame (x forward, y left,
  /// z up) at zero pitch, metres.
  Eigen::Vector3d camera_offset_m{0.045, 0.0, 0.03};

  /// Every problem with this geometry (empty = valid).
  std::vector<std::string> validate() const;
};

/// Camera pose T_W_C (optical frame: x right, y down, z forward) for carriage position
/// track_pos_m (metres along direction_W from origin_W), pitch_rad (positive = nose up) and
/// yaw_rad (positive = turn left, counter-clockwise seen from above). Throws
/// std::invalid_argument for an invalid geometry or a non-finite input. Thread-safe.
Eigen::Isometry3d cameraPoseOnTrack(double track_pos_m, double pitch_rad, double yaw_rad,
                                    const TrackGeometry& geometry = TrackGeometry{});

/// Rotation taking camera-body axes (x forward, y left, z up) to optical axes: R_B_C maps
/// optical-frame vectors into the body frame. Thread-safe.
Eigen::Matrix3d rotationBodyFromOptical();

}  // namespace depth_track
