#include <gtest/gtest.h>

#include <cmath>

#include "board_harness.hpp"
#include "rig_drivers/firmware/truck_drv.hpp"

using namespace rig_test;
using rp::AckStatus;
using rp::MsgId;
using rp::RcChannel;

namespace {

class FakeTruck : public rp::TruckHardware {
 public:
  uint16_t pulseUs(RcChannel ch) override { return pulse[static_cast<int>(ch)]; }
  void setMotor(double c) override { motor = c; }
  void setSteering(double c) override { steering = c; }
  void write(const uint8_t* d, size_t n) override { out.write(d, n); }
  uint16_t pulse[4] = {1500, 1500, 1000, 1000};
  double motor = 0, steering = 0;
  CaptureOut out;
};

struct Rig {
  Rig() : drv(rp::TruckDrvConfig::defaults(), hw) {}
  void run(double s) {
    const uint64_t end = now + static_cast<uint64_t>(s * 1e6);
    while (now < end) {
      now += 1000;
      drv.update(static_cast<uint32_t>(now));
    }
  }
  rp::TruckRcPayload last() const { return hw.out.all<rp::TruckRcPayload>().back(); }
  uint64_t now = 0;
  FakeTruck hw;
  rp::TruckDrv drv;
};

}  // namespace

TEST(TruckDrv, ChannelsMapToSteeringSpeedStartAndRecord) {
  Rig rig;
  rig.run(0.1);
  EXPECT_TRUE(rig.drv.signalOk());
  EXPECT_FALSE(rig.drv.running());
  EXPECT_EQ(rig.hw.motor, 0.0);
  rig.hw.pulse[0] = 1760;  // CH2 right
  rig.hw.pulse[1] = 1760;  // CH3 forward
  rig.run(0.1);
  EXPECT_NEAR(rig.hw.steering, (260.0 - 20) / 480, 1e-12);
  EXPECT_EQ(rig.hw.motor, 0.0);  // CH5 off: not started
  rig.hw.pulse[2] = 2000;        // CH5 start
  rig.run(0.1);
  EXPECT_TRUE(rig.drv.running());
  EXPECT_NEAR(rig.hw.motor, 0.5, 1e-12);
  rig.hw.pulse[1] = 1240;  // CH3 reverse, same magnitude
  rig.run(0.1);
  EXPECT_NEAR(rig.hw.motor, -0.5, 1e-12);
  rig.hw.pulse[3] = 2000;  // CH7 record
  rig.run(0.1);
  auto s = rig.last();
  EXPECT_EQ(s.ch3_us, 1240);
  EXPECT_EQ(s.speed_permille, -500);
  EXPECT_EQ(s.steering_permille, 500);
  EXPECT_TRUE(s.flags & rp::TruckRcPayload::kRecording);
  EXPECT_TRUE(s.flags & rp::TruckRcPayload::kRunning);
  // curve: signal 0.5 between (0.4, 0.75) and (0.6, 1.15) -> 0.95 m/s, reversing
  EXPECT_EQ(s.speed_mm_s, -950);
  // deadband: within 20 us of centre reads exactly zero
  rig.hw.pulse[1] = 1515;
  rig.run(0.1);
  EXPECT_EQ(rig.hw.motor, 0.0);
}

TEST(TruckDrv, SpeedCurveIsConfigurableAndMonotonic) {
  auto c = rp::TruckDrvConfig::defaults();
  FakeTruck hw;
  rp::TruckDrv d(c, hw);
  EXPECT_EQ(d.speedMps(0.05), 0.0);  // below the first point: stiction, no motion
  double prev = 0;
  for (double s = 0.08; s <= 1.0; s += 0.01) {
    const double v = d.speedMps(s);
    EXPECT_GE(v, prev);
    EXPECT_NEAR(d.speedMps(-s), -v, 1e-12);
    prev = v;
  }
  EXPECT_NEAR(d.speedMps(1.0), 1.8, 1e-12);
  const double x[] = {0.1, 1.0}, y[] = {0.0, 3.0};
  c.speed_curve.set(x, y, 2, true);
  rp::TruckDrv d2(c, hw);
  EXPECT_NEAR(d2.speedMps(0.55), 1.5, 1e-12);
  c.speed_curve = rp::PiecewiseLinear();
  c.deadband_us = 600;
  const auto e = c.validate();
  EXPECT_NE(e.find("speed_curve"), std::string::npos) << e;
  EXPECT_NE(e.find("deadband_us"), std::string::npos) << e;
  EXPECT_THROW(rp::TruckDrv(c, hw), std::invalid_argument);
}

TEST(TruckDrv, LostReceiverStopsTheTruck) {
  Rig rig;
  rig.hw.pulse[1] = 2000;
  rig.hw.pulse[2] = 2000;
  rig.run(0.1);
  EXPECT_NEAR(rig.hw.motor, 1.0, 1e-12);
  rig.hw.pulse[1] = 0;  // receiver lost CH3
  rig.run(0.1);
  EXPECT_EQ(rig.hw.motor, 0.0);
  EXPECT_FALSE(rig.drv.signalOk());
  EXPECT_FALSE(rig.last().flags & rp::TruckRcPayload::kSignalOk);
  rig.hw.pulse[1] = 2000;
  rig.run(0.1);
  EXPECT_NEAR(rig.hw.motor, 1.0, 1e-12);
  // host stop holds the motor off until start
  sendCmd(rig.drv, 5, MsgId::kStop);
  EXPECT_EQ(rig.hw.out.lastStatus(5), st(AckStatus::kDone));
  rig.run(0.1);
  EXPECT_EQ(rig.hw.motor, 0.0);
  sendCmd(rig.drv, 6, MsgId::kStart);
  rig.run(0.1);
  EXPECT_NEAR(rig.hw.motor, 1.0, 1e-12);
}

TEST(TruckDrv, StreamsAt30HzAndReportsCurveInPara) {
  Rig rig;
  rig.run(3.0);
  EXPECT_NEAR(static_cast<double>(rig.hw.out.all<rp::TruckRcPayload>().size()), 90.0, 1.0);
  sendCmd(rig.drv, 1, MsgId::kPara);
  const auto p = rig.hw.out.all<rp::ParamValue>();
  ASSERT_EQ(p.size(), 10u);
  EXPECT_STREQ(p[4].name, "speed_mps_at_008");
  EXPECT_NEAR(p[9].value(), 1.8, 1e-9);
  rp::CmdServo s;
  sendTo(rig.drv, 2, s);
  EXPECT_EQ(rig.hw.out.lastStatus(2), st(AckStatus::kUnsupported));
}
