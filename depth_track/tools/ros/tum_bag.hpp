#pragma once
// The bag layout tum_to_bag writes, shared with the readers of such bags (its test, and the bag
// evaluator to come). It is the scenario bags' layout (rig_drivers make_scenario_bag) with the
// ground truth under its own topic name, plus the depth unit recorded where a reader finds it:
//
//   /camera/image_rect         sensor_msgs/Image 16UC1, frame camera_depth_optical_frame; the
//                              connection header carries depth_scale_m (metres per unit, TUM
//                              0.0002)
//   /camera/camera_info        sensor_msgs/CameraInfo, same stamps, same depth_scale_m header field
//   /ground_truth/camera_pose  geometry_msgs/PoseStamped, frame map: T_map_optical (TUM ground
//                              truth, camera-to-world) at the ground truth's own stamps (100 Hz)
//   /tf_static                 base_link -> camera_link -> camera_depth_optical_frame (latched)
//
// Poses and transforms go through the graph's conversions (depth_track/ros/conversions.hpp);
// the CameraInfo of given intrinsics, which those do not offer, is written here.
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/message_traits.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>

#include <Eigen/Geometry>
#include <boost/make_shared.hpp>
#include <cstdlib>
#include <map>
#include <optional>
#include <string>

#include "depth_track/core/camera.hpp"
#include "depth_track/ros/conversions.hpp"

namespace depth_track {
namespace tum_bag {

inline constexpr const char* kDepthTopic = "/camera/image_rect";
inline constexpr const char* kInfoTopic = "/camera/camera_info";
inline constexpr const char* kGroundTruthTopic = "/ground_truth/camera_pose";
inline constexpr const char* kTfStaticTopic = "/tf_static";
inline constexpr const char* kOpticalFrame = "camera_depth_optical_frame";
inline constexpr const char* kMapFrame = "map";
/// Connection-header field of the depth and camera_info topics: metres per 16-bit depth unit.
inline constexpr const char* kDepthScaleKey = "depth_scale_m";

/// A connection header for topic messages of type M, with extra fields. A custom header replaces
/// the one rosbag would make, so it carries the type fields as well.
template <class M>
boost::shared_ptr<ros::M_string> connectionHeader(const std::string& callerid,
                                                  const std::map<std::string, std::string>& extra) {
  auto h = boost::make_shared<ros::M_string>();
  (*h)["type"] = ros::message_traits::DataType<M>::value();
  (*h)["md5sum"] = ros::message_traits::MD5Sum<M>::value();
  (*h)["message_definition"] = ros::message_traits::Definition<M>::value();
  (*h)["callerid"] = callerid;
  for (const auto& [key, value] : extra) (*h)[key] = value;
  return h;
}

/// The depth unit recorded in a connection header (nullopt when absent or not a positive number).
inline std::optional<double> depthScaleOf(const ros::M_string& header) {
  const auto it = header.find(kDepthScaleKey);
  if (it == header.end()) return std::nullopt;
  char* end = nullptr;
  const double v = std::strtod(it->second.c_str(), &end);
  if (end == it->second.c_str() || *end != '\0' || !(v > 0.0)) return std::nullopt;
  return v;
}

/// CameraInfo of an undistorted pinhole camera (plumb_bob with zero coefficients, P = [K | 0]).
inline sensor_msgs::CameraInfo cameraInfoMsg(const PinholeIntrinsics& K, const ros::Time& stamp,
                                             const std::string& frame_id) {
  sensor_msgs::CameraInfo ci;
  ci.header.stamp = stamp;
  ci.header.frame_id = frame_id;
  ci.width = K.width;
  ci.height = K.height;
  ci.distortion_model = "plumb_bob";
  ci.D.assign(5, 0.0);
  ci.K = {K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1};
  ci.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  ci.P = {K.fx, 0, K.cx, 0, 0, K.fy, K.cy, 0, 0, 0, 1, 0};
  return ci;
}

/// T_parent_child as a stamped tf message.
inline geometry_msgs::TransformStamped transformStamped(const ros::Time& stamp,
                                                        const std::string& parent,
                                                        const std::string& child,
                                                        const Eigen::Isometry3d& T) {
  geometry_msgs::TransformStamped m;
  m.header.stamp = stamp;
  m.header.frame_id = parent;
  m.child_frame_id = child;
  m.transform = conv::toTransformMsg(T);
  return m;
}

}  // namespace tum_bag
}  // namespace depth_track
