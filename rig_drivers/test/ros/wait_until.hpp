#pragma once
// Shared by the rig_drivers rostests: poll a condition in wall time while callbacks run.
#include <ros/ros.h>

#include <functional>

namespace rig_drivers::test {

/// True as soon as pred() holds; false once `seconds` of wall time pass (or ROS shuts down).
inline bool waitUntil(const std::function<bool()>& pred, double seconds) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
  while (ros::WallTime::now() < end && ros::ok()) {
    if (pred()) return true;
    ros::WallDuration(0.01).sleep();
  }
  return pred();
}

}  // namespace rig_drivers::test
