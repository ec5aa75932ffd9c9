// rostest: car_host and truck_host against fake CarDRV / TruckDRV boards on ptys, driven through
// the real rig_console executable (one-shot mode). Streams arrive at 30 Hz; typed commands are
// acknowledged by both boards; a gimbal step reports the new pitch; bad input is refused.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <mutex>
#include <vector>

#include "rig_msgs/CarriageSensors.h"
#include "rig_msgs/SequenceStep.h"
#include "rig_msgs/TruckRc.h"

namespace {

struct Listener {
  std::mutex m;
  std::vector<ros::Time> car, truck;
  float pitch_deg = -99;
  void onCar(const rig_msgs::CarriageSensors& s) {
    std::lock_guard<std::mutex> l(m);
    car.push_back(s.header.stamp);
    pitch_deg = s.pitch_deg;
  }
  void onTruck(const rig_msgs::TruckRc& s) {
    std::lock_guard<std::mutex> l(m);
    truck.push_back(s.header.stamp);
  }
  static int in(const std::vector<ros::Time>& v, ros::Time a, ros::Time b) {
    int n = 0;
    for (const auto& t : v) n += t >= a && t < b;
    return n;
  }
};

/// Runs rig_console (next to this binary) with the given arguments; returns exit code and output.
int console(const std::string& args, std::string* out) {
  char self[4096] = {0};
  if (::readlink("/proc/self/exe", self, sizeof self - 1) <= 0) return -1;
  std::string dir(self);
  dir = dir.substr(0, dir.rfind('/'));
  FILE* f =
      ::popen((dir + "/rig_console _hosts:=[car_host,truck_host] " + args + " 2>&1").c_str(), "r");
  if (!f) return -1;
  char buf[512];
  while (std::fgets(buf, sizeof buf, f)) *out += buf;
  const int st = ::pclose(f);
  return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

int countOf(const std::string& s, const std::string& what) {
  int n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + 1)) ++n;
  return n;
}

}  // namespace

TEST(Console, CarAndTruckHostsThroughTheConsole) {
  ros::NodeHandle nh;
  Listener L;
  auto s1 = nh.subscribe("carriage_sensors", 100, &Listener::onCar, &L);
  auto s2 = nh.subscribe("truck_rc", 100, &Listener::onTruck, &L);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  ASSERT_TRUE(ros::service::waitForService("car_host/command", ros::Duration(20)));
  ASSERT_TRUE(ros::service::waitForService("truck_host/command", ros::Duration(20)));
  ros::WallDuration(1.0).sleep();  // handshakes

  // Both 30 Hz streams: 2 s windows hold 60 +-3 frames (edges and host poll jitter).
  const ros::Time t0 = ros::Time::now();
  ros::WallDuration(2.2).sleep();
  {
    std::lock_guard<std::mutex> l(L.m);
    EXPECT_NEAR(Listener::in(L.car, t0, t0 + ros::Duration(2.0)), 60, 3);
    EXPECT_NEAR(Listener::in(L.truck, t0, t0 + ros::Duration(2.0)), 60, 3);
  }

  std::string out;
  EXPECT_EQ(console("vers \"mode 2\" init start stop reset para", &out), 0) << out;
  EXPECT_NE(out.find("FakeCarDRV 0.9.1"), std::string::npos) << out;
  EXPECT_NE(out.find("FakeTruckDRV 0.9.1"), std::string::npos) << out;
  EXPECT_NE(out.find("mm_per_step = 0.0186"), std::string::npos) << out;
  // 7 commands x 2 boards, every one acknowledged; none failed.
  EXPECT_EQ(countOf(out, ": ok - "), 14) << out;
  EXPECT_EQ(countOf(out, "FAILED"), 0) << out;

  out.clear();
  EXPECT_EQ(console("\"mode 3\"", &out), 1) << out;
  EXPECT_NE(out.find("usage: mode 1|2"), std::string::npos) << out;
  out.clear();
  EXPECT_EQ(console("jump", &out), 1) << out;
  EXPECT_NE(out.find("unknown command 'jump'"), std::string::npos) << out;

  // A gimbal step on the carriage: acknowledged done, and the sensors then read 5 deg pitch
  // (the fake reports the demand exactly; 0.01 deg is the wire resolution).
  rig_msgs::SequenceStep st;
  st.request.target = rig_msgs::SequenceStep::Request::TARGET_GIMBAL;
  st.request.pitch_deg = 5.0;
  ASSERT_TRUE(ros::service::call("car_host/step", st));
  EXPECT_TRUE(st.response.success) << st.response.message;
  ros::WallDuration(0.2).sleep();
  {
    std::lock_guard<std::mutex> l(L.m);
    EXPECT_NEAR(L.pitch_deg, 5.0, 0.01);
  }
  // The truck takes no sequence steps and says so.
  ASSERT_TRUE(ros::service::call("truck_host/step", st));
  EXPECT_FALSE(st.response.success);
  EXPECT_NE(st.response.message.find("does not execute"), std::string::npos);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_console");
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}
