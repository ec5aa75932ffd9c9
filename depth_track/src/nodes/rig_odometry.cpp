// rig_odometry: the ServoTruck's dead reckoning from its RC readings (rig_msgs/TruckRc on
// ~truck_topic), published as tf ~frame -> ~child_frame (default rig_odom -> rig_base_link) at
// each reading's stamp and as nav_msgs/Odometry on `rig_odometry/odom`. It is the wheel odometry
// the registration nodelet's ~guess_frame / ~guess_child_frame take their motion prior from
// (launch/replay.launch motion_prior:=sensors, launch/tracking.launch guess_frame:=rig_odom): the
// core's TruckOdometry, the same model evaluate_bag --motion-prior sensors uses. Its tf is a tree
// of its own, so base_link keeps the odometry's odom as its one parent (REP 105).
//
// Bad input: a reading with a non-finite value is skipped with a throttled warning; a stamp that
// goes back in time (a looped bag, a restarted board) starts the odometry again at the identity,
// with a warning.
#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <rig_msgs/TruckRc.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>

#include <cmath>
#include <memory>
#include <stdexcept>

#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/ros/conversions.hpp"

using namespace depth_track;

namespace {

class RigOdometry {
 public:
  RigOdometry() : pnh_("~") {
    std::string topic;
    pnh_.param<std::string>("truck_topic", topic, "/truck_rc");
    pnh_.param<std::string>("frame", frame_, "rig_odom");
    pnh_.param<std::string>("child_frame", child_frame_, "rig_base_link");
    pnh_.param("wheelbase", geometry_.wheelbase_m, geometry_.wheelbase_m);
    pnh_.param("max_steer", geometry_.max_steer_deg, geometry_.max_steer_deg);
    pnh_.param("speed_lag", geometry_.speed_lag_s, geometry_.speed_lag_s);
    pnh_.param("steer_lag", geometry_.steer_lag_s, geometry_.steer_lag_s);
    if (frame_.empty() || child_frame_.empty() || frame_ == child_frame_)
      throw std::invalid_argument("~frame and ~child_frame must be two different, non-empty names");
    odometry_ = std::make_unique<TruckOdometry>(geometry_);  // throws on a bad geometry
    odom_pub_ = pnh_.advertise<nav_msgs::Odometry>("odom", 50);
    sub_ = nh_.subscribe(topic, 200, &RigOdometry::onReading, this);
    ROS_INFO("rig_odometry: %s -> tf %s -> %s (wheelbase %.3f m, full lock %.1f deg, lags %.2f / "
             "%.2f s)",
             topic.c_str(), frame_.c_str(), child_frame_.c_str(), geometry_.wheelbase_m,
             geometry_.max_steer_deg, geometry_.speed_lag_s, geometry_.steer_lag_s);
  }

 private:
  void onReading(const rig_msgs::TruckRcConstPtr& m) {
    const ros::Time stamp = m->header.stamp.isZero() ? ros::Time::now() : m->header.stamp;
    const TruckRcSample reading{stamp.toSec(), m->speed_mps, m->steering};
    if (odometry_->readings() > 0 && stamp < last_stamp_) {
      ROS_WARN("rig_odometry: reading at %.3f s is before the last (%.3f s): the odometry starts "
               "again at the identity",
               stamp.toSec(), last_stamp_.toSec());
      odometry_ = std::make_unique<TruckOdometry>(geometry_);
    }
    Eigen::Isometry3d T;
    try {
      T = odometry_->add(reading);
    } catch (const std::invalid_argument& e) {
      ROS_WARN_THROTTLE(5.0, "rig_odometry: reading at %.3f s skipped (%s)", stamp.toSec(),
                        e.what());
      return;
    }
    if (!last_stamp_.isZero() && stamp == last_stamp_) return;  // tf keeps one per stamp
    last_stamp_ = stamp;
    geometry_msgs::TransformStamped t;
    t.header.stamp = stamp;
    t.header.frame_id = frame_;
    t.child_frame_id = child_frame_;
    t.transform = conv::toTransformMsg(T);
    tf_pub_.sendTransform(t);
    nav_msgs::Odometry o;
    o.header = t.header;
    o.child_frame_id = child_frame_;
    o.pose.pose = conv::toPoseMsg(T);
    // Body-frame twist of the model: the lagged speed and the yaw rate its wheel angle gives.
    const TruckOdometry::State& st = odometry_->state();
    o.twist.twist.linear.x = st.speed;
    o.twist.twist.angular.z = st.speed * std::tan(st.steer) / geometry_.wheelbase_m;
    odom_pub_.publish(o);
  }

  ros::NodeHandle nh_, pnh_;
  std::string frame_, child_frame_;
  TruckGeometry geometry_;
  std::unique_ptr<TruckOdometry> odometry_;
  ros::Time last_stamp_;
  tf2_ros::TransformBroadcaster tf_pub_;
  ros::Publisher odom_pub_;
  ros::Subscriber sub_;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "rig_odometry");
  try {
    RigOdometry node;
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL("rig_odometry: %s", e.what());
    return 1;
  }
  return 0;
}
