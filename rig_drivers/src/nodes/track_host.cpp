// track_host: ROS driver of the ServoTrack track board (TrackDRV) over USB serial.
// Publishes rig_msgs/TrackState (30 Hz, the rig's frame clock), rig_msgs/LinkTiming (Time1 board
// clock, Time2 this host's clock) and rig_msgs/RawFrame; serves ~command, ~mode, ~vers, ~para,
// ~step (track moves and waits of a mode 2 sequence). Parameters: config/drivers.yaml.
#include <rig_msgs/LinkTiming.h>
#include <rig_msgs/TrackState.h>

#include <atomic>
#include <cmath>

#include "board_host.hpp"
#include "rig_drivers/ros/conversions.hpp"

using namespace rig_drivers;

int main(int argc, char** argv) {
  ros::init(argc, argv, "track_host");
  BoardHost host(protocol::BoardId::kTrack, "track_host");
  if (!host.configure()) return 1;
  ros::Publisher state_pub = host.nh().advertise<rig_msgs::TrackState>("track_state", 30);
  ros::Publisher timing_pub = host.nh().advertise<rig_msgs::LinkTiming>("link_timing", 30);
  const ros::WallTime host_start = ros::WallTime::now();
  std::atomic<double> pos_m{0.0};

  auto publish_state = [&](const protocol::Frame& f, const ros::Time& stamp) {
    rig_msgs::TrackState m;
    if (!conv::fromFrame(f, stamp, host.frameId(), m)) return false;
    pos_m = m.track_pos_m;
    state_pub.publish(m);
    timing_pub.publish(conv::trackLinkTiming(m, (ros::WallTime::now() - host_start).toSec()));
    return true;
  };

  auto step = [&](BoardLink& link, const rig_msgs::SequenceStep::Request& req,
                  rig_msgs::SequenceStep::Response& res, double timeout_s) {
    using Req = rig_msgs::SequenceStep::Request;
    if (req.target == Req::TARGET_TRACK) {
      if (!std::isfinite(req.track_pos_m) || std::fabs(req.track_pos_m) > 100.0 ||
          req.max_speed_mps < 0 || req.max_speed_mps > 60 || req.accel_mps2 < 0 ||
          req.accel_mps2 > 60) {
        res.success = false;
        res.message = "track step rejected: track_pos_m, max_speed_mps or accel_mps2 out of range";
        return;
      }
      protocol::CmdTrackMove mv;
      mv.target_um = static_cast<std::int32_t>(std::lround(req.track_pos_m * 1e6));
      mv.flags = req.relative ? protocol::CmdTrackMove::kRelative : 0;
      mv.max_speed_mm_s = static_cast<std::uint16_t>(std::lround(req.max_speed_mps * 1e3));
      mv.accel_mm_s2 = static_cast<std::uint16_t>(std::lround(req.accel_mps2 * 1e3));
      fillStepResult(link.send(mv, timeout_s, true, req.seq), res);
    } else if (req.target == Req::TARGET_WAIT) {
      if (!runWaitStep(link, req, res, timeout_s)) return;
    } else {
      rejectStepTarget("track_host", "TARGET_TRACK and TARGET_WAIT", req.target, res);
      return;
    }
    res.track_pos_m = pos_m;
  };
  return host.run(publish_state, step);
}
