// TrackDRV driving the elastic-belt carriage model: the firmware's trapezoid excites the ~9 Hz
// belt mode (thesis fig. 5.23), visible in the carriage acceleration even when sampled at 30 Hz.
#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <vector>

#include "../firmware/board_harness.hpp"
#include "rig_drivers/firmware/track_drv.hpp"
#include "rig_drivers/sim/physics_models.hpp"

using namespace rig_test;

namespace {
constexpr double kPi = 3.14159265358979323846;

class BeltTrack : public rp::TrackHardware {
 public:
  explicit BeltTrack(double mps) : m_per_step(mps) {}
  void step(int dir) override { steps += dir; }
  // sensors see the carriage, not the motor
  bool farSensor() override { return belt.position() <= 0.0; }
  bool nearSensor() override { return belt.position() >= 1.2; }
  bool estopPressed() override { return false; }
  void write(const uint8_t* d, size_t n) override { out.write(d, n); }
  double m_per_step;
  int64_t steps = 0;
  rp::BeltCarriageModel belt;
  CaptureOut out;
};
}  // namespace

TEST(TrackOnBelt, StopExcitesTheNineHertzModeSeenAt30Hz) {
  const double mps = rp::pulleyMetresPerStep(20);
  BeltTrack hw(mps);
  hw.belt.reset(0.0);
  rp::TrackDrv drv(rp::TrackDrvConfig(), hw);
  const auto cmd = rp::encodeCommand(rp::BoardId::kTrack, rp::MsgId::kInit, 1);
  drv.receive(cmd.data(), cmd.size());  // carriage already at the far sensor: homed at once
  ASSERT_EQ(hw.out.lastStatus(1), st(rp::AckStatus::kDone));
  rp::CmdTrackMove m;
  m.target_um = 300000;
  m.max_speed_mm_s = 200;
  m.accel_mm_s2 = 400;
  sendTo(drv, 2, m);
  // Firmware and physics in lock step at 5 kHz (0.2 ms: the model's substep).
  const uint32_t tick_us = 200;
  uint64_t now = 0;
  std::vector<double> acc_1k, acc_30;
  bool done = false;
  double t_done = 0;
  for (int i = 0; i < 5000 * 6; ++i) {
    now += tick_us;
    drv.update(static_cast<uint32_t>(now));
    hw.belt.advance(tick_us * 1e-6, hw.steps * mps);
    if (!done && hw.out.lastStatus(2) == st(rp::AckStatus::kDone)) {
      done = true;
      t_done = now * 1e-6;
    }
    if (done) {
      if (i % 5 == 0) acc_1k.push_back(hw.belt.acceleration());
      // 30 Hz samples at the frame clock (every 33.3 ms)
      if ((now % 100000) * 3 / 100000 != ((now - tick_us) % 100000) * 3 / 100000)
        acc_30.push_back(hw.belt.acceleration());
    }
  }
  ASSERT_TRUE(done);
  EXPECT_NEAR(t_done, 0.3 / 0.2 + 0.2 / 0.4, 0.01);  // trapezoid duration d/v + v/a
  // The carriage lands on the motor position (the belt relaxes), within a micrometre.
  EXPECT_NEAR(hw.belt.position(), 0.3, 1e-6 + mps);
  // Ringing after the deceleration ends: a 0.4 m/s^2 step in acceleration.
  double peak = 0;
  for (size_t i = 0; i < 200; ++i) peak = std::max(peak, std::fabs(acc_1k[i]));
  EXPECT_GT(peak, 0.2);
  EXPECT_LT(peak, 0.4 * 2.0);  // a step response overshoots by at most 100 %
  // Frequency from 1 kHz zero crossings over the first 1.5 s.
  std::vector<double> tz;
  for (size_t i = 1; i < 1500; ++i)
    if (acc_1k[i - 1] < 0 && acc_1k[i] >= 0)
      tz.push_back((i - 1 + acc_1k[i - 1] / (acc_1k[i - 1] - acc_1k[i])) * 1e-3);
  ASSERT_GE(tz.size(), 8u);
  const double f = (tz.size() - 1) / (tz.back() - tz.front());
  EXPECT_NEAR(f, 9.0 * std::sqrt(1 - 0.06 * 0.06), 0.05);
  // As in fig. 5.23: the 30 Hz accelerometer record shows the mode below Nyquist (15 Hz).
  // Zero-padded DFT of the first 1.5 s (45 samples): peak within one bin (0.67 Hz) of 9 Hz.
  const size_t n = 45;
  double best = 0, f_best = 0;
  for (double fq = 1.0; fq < 15.0; fq += 0.05) {
    std::complex<double> s = 0;
    for (size_t k = 0; k < n; ++k)
      s += acc_30[k] * std::exp(std::complex<double>(0, -2 * kPi * fq * k / 30.0));
    if (std::abs(s) > best) {
      best = std::abs(s);
      f_best = fq;
    }
  }
  EXPECT_NEAR(f_best, 9.0, 30.0 / n);
}
