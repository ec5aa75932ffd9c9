// rostest: CarDRV's and TruckDRV's firmware images running in qemu-system-avr
// (emulated_boards.test) against car_host and truck_host. TruckDRV's image is its Leonardo logic
// built for the emulated Mega 2560, USART0 standing in for the Leonardo's link. Counted by the
// boards' frame counters and acknowledgements, never over wall time.
//
// Inputs come from the adapters' stubs (src/firmware/avr/): CarDRV's pots read 512 counts, its
// accelerometer 1 g along camera y, its ranger 500 mm; TruckDRV's receiver has the sticks centred
// (1500 us) and both switches off (1000 us). What the boards report is those inputs through the
// firmware's own calibration and RC logic.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <std_msgs/Bool.h>

#include <mutex>
#include <string>
#include <vector>

#include "rig_drivers/firmware/car_drv.hpp"
#include "rig_msgs/CarriageSensors.h"
#include "rig_msgs/Command.h"
#include "rig_msgs/SequenceStep.h"
#include "rig_msgs/SetMode.h"
#include "rig_msgs/TruckRc.h"
#include "rig_msgs/Version.h"
#include "wait_until.hpp"

namespace rp = rig_drivers::protocol;
using rig_drivers::test::waitUntil;

namespace {

constexpr double kWaitS = 240;  // generous: qemu on a loaded 2-core machine

template <class Msg>
struct Stream {
  std::mutex m;
  std::vector<Msg> msgs;
  bool connected = false;
  void onMsg(const Msg& s) {
    std::lock_guard<std::mutex> l(m);
    msgs.push_back(s);
  }
  void onConnected(const std_msgs::Bool& b) {
    std::lock_guard<std::mutex> l(m);
    connected = b.data;
  }
  bool isConnected() {
    std::lock_guard<std::mutex> l(m);
    return connected;
  }
  size_t count() {
    std::lock_guard<std::mutex> l(m);
    return msgs.size();
  }
  /// `n` messages from index `first` once they are there (empty on timeout).
  std::vector<Msg> take(size_t first, size_t n) {
    if (!waitUntil([&] { return count() >= first + n; }, kWaitS)) return {};
    std::lock_guard<std::mutex> l(m);
    return {msgs.begin() + static_cast<std::ptrdiff_t>(first),
            msgs.begin() + static_cast<std::ptrdiff_t>(first + n)};
  }
};

template <class Msg>
int seqGaps(const std::vector<Msg>& v) {
  int gaps = 0;
  for (size_t i = 1; i < v.size(); ++i) gaps += v[i].frame_seq != v[i - 1].frame_seq + 1;
  return gaps;
}

std::string boardName(const std::string& host) {
  rig_msgs::Version vers;
  if (!ros::service::call(host + "/vers", vers) || !vers.response.success ||
      vers.response.components.size() != 2)
    return "";
  return vers.response.components[1];
}

}  // namespace

TEST(EmulatedBoards, CarDrvStreamsItsStubInputsThroughItsCalibration) {
  ros::NodeHandle nh;
  Stream<rig_msgs::CarriageSensors> car;
  auto s1 = nh.subscribe("carriage_sensors", 1000, &decltype(car)::onMsg, &car);
  auto s2 = nh.subscribe("car_host/connected", 10, &decltype(car)::onConnected, &car);
  ASSERT_TRUE(waitUntil([&] { return car.isConnected(); }, kWaitS)) << "no handshake";
  EXPECT_EQ(boardName("car_host"), "CarDRV");

  const auto frames = car.take(car.count(), 30);
  ASSERT_EQ(frames.size(), 30u);
  EXPECT_EQ(seqGaps(frames), 0);
  const auto cfg = rp::CarDrvConfig::defaults();
  const double volts = (512 + 0.5) * cfg.adc_vref / 1024;  // mid-count voltage, as the board
  for (const auto& f : frames) {
    EXPECT_NEAR(f.pitch_deg, cfg.pitch.deg_of_volts(volts), 0.005 + 1e-4);  // 0.01 deg on the wire
    EXPECT_NEAR(f.yaw_deg, cfg.yaw.deg_of_volts(volts), 0.005 + 1e-4);
    EXPECT_NEAR(f.acc_y_g, 1.0, 0.0005 + 1e-6);  // 1 mg on the wire
    EXPECT_NEAR(f.acc_x_g, 0.0, 1e-6);
    EXPECT_TRUE(f.tf_valid);
    EXPECT_NEAR(f.tf_pos_m, 0.500, 1e-6);
  }

  // A mode 2 gimbal step: accepted, done once slewed and settled (board time), then reported.
  rig_msgs::SetMode mode;
  mode.request.mode = 2;
  ASSERT_TRUE(ros::service::call("car_host/mode", mode));
  EXPECT_TRUE(mode.response.success) << mode.response.message;
  rig_msgs::SequenceStep step;
  step.request.target = rig_msgs::SequenceStep::Request::TARGET_GIMBAL;
  step.request.pitch_deg = 10.0;
  step.request.yaw_deg = -5.0;
  ASSERT_TRUE(ros::service::call("car_host/step", step));
  EXPECT_TRUE(step.response.success) << step.response.message;
  EXPECT_EQ(step.response.status, static_cast<uint8_t>(rp::AckStatus::kDone));
  const auto after = car.take(car.count(), 3);
  ASSERT_EQ(after.size(), 3u);
  EXPECT_NEAR(after.back().pitch_dem_deg, 10.0, 1e-4);
  EXPECT_NEAR(after.back().yaw_dem_deg, -5.0, 1e-4);
}

TEST(EmulatedBoards, TruckDrvStreamsItsStubReceiver) {
  ros::NodeHandle nh;
  Stream<rig_msgs::TruckRc> truck;
  auto s1 = nh.subscribe("truck_rc", 1000, &decltype(truck)::onMsg, &truck);
  auto s2 = nh.subscribe("truck_host/connected", 10, &decltype(truck)::onConnected, &truck);
  ASSERT_TRUE(waitUntil([&] { return truck.isConnected(); }, kWaitS)) << "no handshake";
  EXPECT_EQ(boardName("truck_host"), "TruckDRV");

  const auto frames = truck.take(truck.count(), 30);
  ASSERT_EQ(frames.size(), 30u);
  EXPECT_EQ(seqGaps(frames), 0);
  for (const auto& f : frames) {
    EXPECT_EQ(f.ch2_us, 1500);
    EXPECT_EQ(f.ch3_us, 1500);
    EXPECT_EQ(f.ch5_us, 1000);
    EXPECT_EQ(f.ch7_us, 1000);
    EXPECT_TRUE(f.signal_ok);
    EXPECT_FALSE(f.running);  // CH5 off: the motor stays off
    EXPECT_FALSE(f.recording);
    EXPECT_EQ(f.steering, 0.0f);
    EXPECT_EQ(f.speed_mps, 0.0f);
  }
  rig_msgs::Command cmd;
  cmd.request.command = rig_msgs::Command::Request::START;
  ASSERT_TRUE(ros::service::call("truck_host/command", cmd));
  EXPECT_TRUE(cmd.response.success) << cmd.response.message;
  EXPECT_EQ(cmd.response.status, static_cast<uint8_t>(rp::AckStatus::kDone));
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_emulated_boards");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}
