// truck_host: ROS driver of the ServoTruck RC board (TruckDRV: CH2 steering, CH3 speed/direction,
// CH5 start/stop, CH7 record). Publishes rig_msgs/TruckRc (30 Hz) and rig_msgs/RawFrame; serves
// ~command, ~mode, ~vers, ~para (the truck is driven by its RC transmitter, so ~step answers
// "unsupported"). Parameters: config/drivers.yaml.
#include <rig_msgs/TruckRc.h>

#include "board_host.hpp"

using namespace rig_drivers;

int main(int argc, char** argv) {
  ros::init(argc, argv, "truck_host");
  BoardHost host(protocol::BoardId::kTruck, "truck_host");
  if (!host.configure()) return 1;
  ros::Publisher pub = host.nh().advertise<rig_msgs::TruckRc>("truck_rc", 30);

  auto publish_state = [&](const protocol::Frame& f, const ros::Time& stamp) {
    protocol::TruckRcPayload p;
    if (protocol::decodePayload(f, p) != protocol::DecodeError::kNone) return false;
    using P = protocol::TruckRcPayload;
    rig_msgs::TruckRc m;
    m.header.stamp = stamp;
    m.header.frame_id = host.frameId();
    m.ch2_us = p.ch2_us;
    m.ch3_us = p.ch3_us;
    m.ch5_us = p.ch5_us;
    m.ch7_us = p.ch7_us;
    m.steering = p.steering_permille * 1e-3f;
    m.speed_signal = p.speed_permille * 1e-3f;
    m.speed_mps = p.speed_mm_s * 1e-3f;
    m.running = p.flags & P::kRunning;
    m.recording = p.flags & P::kRecording;
    m.signal_ok = p.flags & P::kSignalOk;
    m.board_time_s = p.board_time_ms * 1e-3;
    m.frame_seq = f.seq;
    pub.publish(m);
    return true;
  };
  return host.run(publish_state, StepHandler());
}
