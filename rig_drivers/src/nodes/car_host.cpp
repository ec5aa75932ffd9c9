// car_host: ROS driver of the ServoTrack carriage board (CarDRV: pitch/yaw servos and sensors,
// MPU6050, time-of-flight position). Publishes rig_msgs/CarriageSensors (30 Hz),
// rig_msgs/LinkTiming (Time3 board clock, Time5 host clock) and rig_msgs/RawFrame; serves ~command,
// ~mode, ~vers, ~para, ~step (gimbal moves and waits of a mode 2 sequence). Parameters:
// config/drivers.yaml.
#include <rig_msgs/CarriageSensors.h>
#include <rig_msgs/LinkTiming.h>

#include <atomic>
#include <cmath>

#include "board_host.hpp"
#include "rig_drivers/ros/conversions.hpp"

using namespace rig_drivers;

int main(int argc, char** argv) {
  ros::init(argc, argv, "car_host");
  BoardHost host(protocol::BoardId::kCar, "car_host");
  if (!host.configure()) return 1;
  ros::Publisher pub = host.nh().advertise<rig_msgs::CarriageSensors>("carriage_sensors", 30);
  ros::Publisher timing_pub = host.nh().advertise<rig_msgs::LinkTiming>("link_timing", 30);
  const ros::WallTime host_start = ros::WallTime::now();
  std::atomic<double> pitch_deg{0.0}, yaw_deg{0.0}, tof_m{0.0};

  auto publish_state = [&](const protocol::Frame& f, const ros::Time& stamp) {
    rig_msgs::CarriageSensors m;
    if (!conv::fromFrame(f, stamp, host.frameId(), m)) return false;
    pitch_deg = m.pitch_deg;
    yaw_deg = m.yaw_deg;
    tof_m = m.tf_pos_m;
    pub.publish(m);
    timing_pub.publish(conv::carLinkTiming(m, (ros::WallTime::now() - host_start).toSec()));
    return true;
  };

  auto step = [&](BoardLink& link, const rig_msgs::SequenceStep::Request& req,
                  rig_msgs::SequenceStep::Response& res, double timeout_s) {
    using Req = rig_msgs::SequenceStep::Request;
    if (req.target == Req::TARGET_GIMBAL) {
      // int16 centi-degrees on the wire: +-327 deg; the gimbal's own limits are the board's.
      if (!std::isfinite(req.pitch_deg) || !std::isfinite(req.yaw_deg) ||
          std::fabs(req.pitch_deg) > 180 || std::fabs(req.yaw_deg) > 180) {
        res.success = false;
        res.message = "gimbal step rejected: pitch_deg / yaw_deg must be finite and within +-180";
        return;
      }
      protocol::CmdServo s;
      s.pitch_cdeg = static_cast<std::int16_t>(std::lround(req.pitch_deg * 100));
      s.yaw_cdeg = static_cast<std::int16_t>(std::lround(req.yaw_deg * 100));
      s.flags = req.relative ? protocol::CmdServo::kRelative : 0;
      fillStepResult(link.send(s, timeout_s, true, req.seq), res);
    } else if (req.target == Req::TARGET_WAIT) {
      if (!runWaitStep(link, req, res, timeout_s)) return;
    } else {
      rejectStepTarget("car_host", "TARGET_GIMBAL and TARGET_WAIT", req.target, res);
      return;
    }
    res.pitch_deg = pitch_deg;
    res.yaw_deg = yaw_deg;
    res.track_pos_m = tof_m;
  };
  return host.run(publish_state, step);
}
