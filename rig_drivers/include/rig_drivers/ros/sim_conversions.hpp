#pragma once
// ROS adapters of the rig simulator's ground truth (Eigen poses -> geometry_msgs) and the rig's
// static camera frames, shared by the live simulator node (rig_sim) and the offline bag writer
// (make_scenario_bag). Kept apart from conversions.hpp so the board hosts need no Eigen.
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/Transform.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/time.h>

#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "depth_track/core/servotrack_kinematics.hpp"
#include "rig_drivers/sim/rig_sim.hpp"
#include "rig_drivers/sim/rig_sim_truck.hpp"

namespace rig_drivers {
namespace conv {

/// Rigid transform as geometry_msgs/Transform (translation, unit quaternion).
inline geometry_msgs::Transform toTransformMsg(const Eigen::Isometry3d& T) {
  geometry_msgs::Transform m;
  m.translation.x = T.translation().x();
  m.translation.y = T.translation().y();
  m.translation.z = T.translation().z();
  const Eigen::Quaterniond q(T.rotation());
  m.rotation.x = q.x();
  m.rotation.y = q.y();
  m.rotation.z = q.z();
  m.rotation.w = q.w();
  return m;
}

/// T_parent_child as a stamped tf message.
inline geometry_msgs::TransformStamped toTransformStamped(const ros::Time& stamp,
                                                          const std::string& parent,
                                                          const std::string& child,
                                                          const Eigen::Isometry3d& T) {
  geometry_msgs::TransformStamped m;
  m.header.stamp = stamp;
  m.header.frame_id = parent;
  m.child_frame_id = child;
  m.transform = toTransformMsg(T);
  return m;
}

/// Pose T_frame_body as geometry_msgs/PoseStamped in `frame_id`.
inline geometry_msgs::PoseStamped toPoseStamped(const ros::Time& stamp, const std::string& frame_id,
                                                const Eigen::Isometry3d& T) {
  const geometry_msgs::Transform tr = toTransformMsg(T);
  geometry_msgs::PoseStamped pose;
  pose.header.stamp = stamp;
  pose.header.frame_id = frame_id;
  pose.pose.position.x = tr.translation.x;
  pose.pose.position.y = tr.translation.y;
  pose.pose.position.z = tr.translation.z;
  pose.pose.orientation = tr.rotation;
  return pose;
}

/// base_link -> camera_link (camera body: x forward, y left, z up) of the simulated rig. On
/// ServoTrack and a tripod base_link is the camera body itself (the gimbal moves it), on ServoTruck
/// the rear axle.
inline Eigen::Isometry3d baseToCameraLink(const RigSimulator& sim) {
  if (sim.scenario().rig != RigKind::kServoTruck) return Eigen::Isometry3d::Identity();
  TruckModel m(sim.config().truck);
  Eigen::Isometry3d T = m.T_B_C();
  T.linear() = T.linear() * depth_track::rotationBodyFromOptical().transpose();
  return T;
}

/// The rig's static frames: base_link -> camera_link -> `optical_frame` (z forward, x right).
inline std::vector<geometry_msgs::TransformStamped> rigStaticTransforms(
    const RigSimulator& sim, const ros::Time& stamp, const std::string& optical_frame) {
  Eigen::Isometry3d T_L_O = Eigen::Isometry3d::Identity();
  T_L_O.linear() = depth_track::rotationBodyFromOptical();
  return {toTransformStamped(stamp, "base_link", "camera_link", baseToCameraLink(sim)),
          toTransformStamped(stamp, "camera_link", optical_frame, T_L_O)};
}

}  // namespace conv
}  // namespace rig_drivers
