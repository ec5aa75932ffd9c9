// Test node: one fake rig board (see fake_board.hpp) on a pty behind the symlink ~link, with
// services ~unplug and ~plug (std_srvs/Trigger) so a rostest can pull the cable.
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include "../link/fake_board.hpp"

int main(int argc, char** argv) {
  ros::init(argc, argv, "fake_board");
  ros::NodeHandle pnh("~");
  std::string link, board_name;
  pnh.param<std::string>("link", link, "/tmp/rig_fake_tty");
  pnh.param<std::string>("board", board_name, "track");
  using rig_drivers::protocol::BoardId;
  BoardId board = board_name == "car"     ? BoardId::kCar
                  : board_name == "truck" ? BoardId::kTruck
                                          : BoardId::kTrack;
  rig_drivers::fake::FakeBoard fake(board, link);
  auto unplug = pnh.advertiseService<std_srvs::Trigger::Request, std_srvs::Trigger::Response>(
      "unplug", [&](std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
        fake.unplug();
        res.success = true;
        return true;
      });
  auto plug = pnh.advertiseService<std_srvs::Trigger::Request, std_srvs::Trigger::Response>(
      "plug", [&](std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
        fake.plug();
        res.success = true;
        return true;
      });
  ROS_INFO("fake %s board on %s", board_name.c_str(), link.c_str());
  ros::spin();
  return 0;
}
