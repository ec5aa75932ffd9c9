#include "depth_track/core/servotrack_kinematics.hpp"

#include <cmath>
#include <stdexcept>

#include "depth_track/core/camera.hpp"

namespace depth_track {

namespace {
bool finite3(const Eigen::Vector3d& v) { return v.allFinite(); }
}  // namespace

std::vector<std::string> TrackGeometry::validate() const {
  std::vector<std::string> problems;
  if (!finite3(origin_W)) problems.push_back("track origin_W must be finite");
  if (!finite3(direction_W) || direction_W.norm() < 1e-9) {
    problems.push_back("track direction_W must be a finite non-zero vector");
  } else if (direction_W.normalized().cross(Eigen::Vector3d::UnitZ()).norm() < 1e-3) {
    problems.push_back("track direction_W must not be vertical");
  }
  if (!std::isfinite(pitch_axis_height_m)) problems.push_back("pitch_axis_height_m must be finite");
  if (!std::isfinite(pitch_axis_forward_m))
    problems.push_back("pitch_axis_forward_m must be finite");
  if (!finite3(camera_offset_m)) problems.push_back("camera_offset_m must be finite");
  return problems;
}

Eigen::Matrix3d rotationBodyFromOptical() {
  Eigen::Matrix3d R_B_C;
  // Columns: optical x (right) = body -y, optical y (down) = body -z, optical z = body x.
  R_B_C << 0, 0, 1,  //
      -1, 0, 0,      //
      0, -1, 0;
  return R_B_C;
}

Eigen::Isometry3d cameraPoseOnTrack(double track_pos_m, double pitch_rad, double yaw_rad,
                                    const TrackGeometry& g) {
  const auto problems = g.validate();
  if (!problems.empty())
    throw std::invalid_argument("invalid TrackGeometry: " + joinProblems(problems));
  if (!std::isfinite(track_pos_m) || !std::isfinite(pitch_rad) || !std::isfinite(yaw_rad))
    throw std::invalid_argument("cameraPoseOnTrack: track position and angles must be finite");

  // Carriage frame K: x along the track (levelled), z up.
  Eigen::Vector3d x = g.direction_W.normalized();
  const Eigen::Vector3d z = Eigen::Vector3d::UnitZ();
  x = (x - x.dot(z) * z).normalized();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Isometry3d T_W_K = Eigen::Isometry3d::Identity();
  T_W_K.linear().col(0) = x;
  T_W_K.linear().col(1) = y;
  T_W_K.linear().col(2) = z;
  T_W_K.translation() = g.origin_W + track_pos_m * g.direction_W.normalized();

  Eigen::Isometry3d T_K_Y = Eigen::Isometry3d::Identity();  // yaw stage
  T_K_Y.linear() = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();

  // Pitch stage P: rotation about the stage's left (y) axis; a positive rotation about +y turns
  // +x downwards, so nose-up pitch is a rotation by -pitch.
  Eigen::Isometry3d T_Y_P = Eigen::Isometry3d::Identity();
  T_Y_P.translation() = Eigen::Vector3d(g.pitch_axis_forward_m, 0.0, g.pitch_axis_height_m);
  T_Y_P.linear() = Eigen::AngleAxisd(-pitch_rad, Eigen::Vector3d::UnitY()).toRotationMatrix();

  Eigen::Isometry3d T_P_C = Eigen::Isometry3d::Identity();
  T_P_C.translation() = g.camera_offset_m;
  T_P_C.linear() = rotationBodyFromOptical();

  return T_W_K * T_K_Y * T_Y_P * T_P_C;
}

}  // namespace depth_track
