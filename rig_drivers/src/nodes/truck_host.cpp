// truck_host: ROS driver of the ServoTruck RC board (TruckDRV: CH2 steering, CH3 speed/direction,
// CH5 start/stop, CH7 record). Publishes rig_msgs/TruckRc (30 Hz) and rig_msgs/RawFrame; serves
// ~command, ~mode, ~vers, ~para (the truck is driven by its RC transmitter, so ~step answers
// "unsupported"). Parameters: config/drivers.yaml.
#include <rig_msgs/TruckRc.h>

#include "board_host.hpp"
#include "rig_drivers/ros/conversions.hpp"

using namespace rig_drivers;

int main(int argc, char** argv) {
  ros::init(argc, argv, "truck_host");
  BoardHost host(protocol::BoardId::kTruck, "truck_host");
  if (!host.configure()) return 1;
  ros::Publisher pub = host.nh().advertise<rig_msgs::TruckRc>("truck_rc", 30);

  auto publish_state = [&](const protocol::Frame& f, const ros::Time& stamp) {
    rig_msgs::TruckRc m;
    if (!conv::fromFrame(f, stamp, host.frameId(), m)) return false;
    pub.publish(m);
    return true;
  };
  return host.run(publish_state, StepHandler());
}
