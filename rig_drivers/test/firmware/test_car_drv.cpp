#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "board_harness.hpp"
#include "rig_drivers/firmware/car_drv.hpp"
#include "rig_drivers/sim/physics_models.hpp"

using namespace rig_test;
using rp::AckStatus;
using rp::GimbalAxis;
using rp::MsgId;

namespace {

/// Carriage whose servos go exactly where the true calibration says and whose sensors produce the
/// true volts, read by a 10-bit ADC model. `truth` may differ from the firmware's calibration.
class FakeCar : public rp::CarHardware {
 public:
  FakeCar(const rp::CarDrvConfig& truth, const rp::AdcConfig& adc) : truth_(truth), adc_(adc, 17) {}
  void setServoPulse(GimbalAxis axis, double us) override {
    const auto& cal = axis == GimbalAxis::kPitch ? truth_.pitch : truth_.yaw;
    angle[static_cast<int>(axis)] = cal.pulse_us_of_deg.inverse(us);
    pulse[static_cast<int>(axis)] = us;
  }
  int readAdc(GimbalAxis axis) override {
    const auto& cal = axis == GimbalAxis::kPitch ? truth_.pitch : truth_.yaw;
    return adc_.read(cal.deg_of_volts.inverse(angle[static_cast<int>(axis)]));
  }
  bool readImu(int16_t raw[3]) override {
    for (int i = 0; i < 3; ++i) raw[i] = imu[i];
    return imu_ok;
  }
  bool readTof(uint16_t& mm) override {
    mm = tof_mm;
    return tof_ok;
  }
  void write(const uint8_t* d, size_t n) override { out.write(d, n); }

  double angle[2] = {0, 0};
  double pulse[2] = {0, 0};
  int16_t imu[3] = {0, 0, 0};
  bool imu_ok = true;
  uint16_t tof_mm = 0;
  bool tof_ok = true;
  CaptureOut out;

 private:
  rp::CarDrvConfig truth_;
  rp::AdcModel adc_;
};

struct Rig {
  explicit Rig(const rp::CarDrvConfig& fw = rp::CarDrvConfig::defaults(),
               const rp::CarDrvConfig& truth = rp::CarDrvConfig::defaults(),
               rp::AdcConfig adc = quietAdc())
      : hw(truth, adc), drv(fw, hw) {}
  static rp::AdcConfig quietAdc() {
    rp::AdcConfig a;
    a.noise_sigma_v = 0;
    return a;
  }
  void run(double s, uint32_t tick_us = 1000) {
    const uint64_t end = now + static_cast<uint64_t>(s * 1e6);
    while (now < end) {
      now += tick_us;
      drv.update(static_cast<uint32_t>(now));
    }
  }
  rp::CarSensorsPayload last() const {
    const auto all = hw.out.all<rp::CarSensorsPayload>();
    EXPECT_FALSE(all.empty());
    return all.empty() ? rp::CarSensorsPayload() : all.back();
  }
  uint64_t now = 0;
  FakeCar hw;
  rp::CarDrv drv;
};

rp::CmdServo servo(double pitch, double yaw, bool rel = false) {
  rp::CmdServo s;
  s.pitch_cdeg = static_cast<int16_t>(std::lround(pitch * 100));
  s.yaw_cdeg = static_cast<int16_t>(std::lround(yaw * 100));
  s.flags = rel ? rp::CmdServo::kRelative : 0;
  return s;
}

// Largest |d deg / d volt| of a sensor curve: turns half an ADC LSB into degrees.
double maxSlope(const rp::PiecewiseLinear& c) {
  double m = 0;
  for (int i = 1; i < c.size(); ++i)
    m = std::max(m, std::fabs((c.y(i) - c.y(i - 1)) / (c.x(i) - c.x(i - 1))));
  return m;
}

}  // namespace

TEST(PiecewiseLinear, InverseAndValidation) {
  const auto c = rp::CarDrvConfig::defaults();
  for (double d = -40; d <= 40; d += 0.37) {
    EXPECT_NEAR(c.pitch.pulse_us_of_deg.inverse(c.pitch.pulse_us_of_deg(d)), d, 1e-9);
    EXPECT_NEAR(c.yaw.pulse_us_of_deg.inverse(c.yaw.pulse_us_of_deg(d)), d, 1e-9);  // decreasing
  }
  rp::PiecewiseLinear p;
  const double x[] = {0, 1, 1}, y[] = {0, 1, 2};
  EXPECT_FALSE(p.set(x, y, 3));  // x not strictly increasing
  const double x2[] = {0, 1, 2}, y2[] = {0, 1, 0.5};
  EXPECT_FALSE(p.set(x2, y2, 3));  // not monotonic: not invertible
  EXPECT_FALSE(p.valid());
  EXPECT_TRUE(p.set(x2, x2, 3, true));
  EXPECT_EQ(p(5.0), 2.0);  // clamped
  const auto s = p.scaled(2.0, 1.0);
  EXPECT_EQ(s(1.0), 3.0);
}

TEST(CarDrvConfig, ValidationNamesEveryProblem) {
  auto c = rp::CarDrvConfig::defaults();
  EXPECT_EQ(c.validate(), "");
  c.yaw.max_deg = 80;  // beyond the servo pulse range
  c.adc_samples = 0;
  c.tof_sign = 0;
  const auto e = c.validate();
  EXPECT_NE(e.find("yaw: demand limits [-40, 80] deg exceed the calibrated range"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("adc_samples"), std::string::npos) << e;
  EXPECT_NE(e.find("tof_sign"), std::string::npos) << e;
  rp::CarDrvConfig empty;  // no calibration tables at all
  EXPECT_NE(empty.validate().find("pitch.pulse_us_of_deg"), std::string::npos);
}

TEST(CarDrv, ServoCalibrationRoundTrip) {
  Rig rig;
  const auto c = rp::CarDrvConfig::defaults();
  const double lsb = 5.0 / 1024;
  // Reading error: half an ADC LSB through the steepest sensor segment, plus 0.005 deg wire
  // rounding (centidegrees).
  const double tol_p = 0.5 * lsb * maxSlope(c.pitch.deg_of_volts) + 0.005;
  const double tol_y = 0.5 * lsb * maxSlope(c.yaw.deg_of_volts) + 0.005;
  uint32_t seq = 1;
  for (double d = -40; d <= 40; d += 2.5) {
    sendTo(rig.drv, seq, servo(d, -d));
    rig.run(2.0);
    EXPECT_EQ(rig.hw.out.lastStatus(seq), st(AckStatus::kDone)) << d;
    ++seq;
    EXPECT_NEAR(rig.hw.angle[0], d, 1e-9);  // open-loop demand hits the ideal servo exactly
    EXPECT_NEAR(rig.hw.angle[1], -d, 1e-9);
    const auto s = rig.last();
    EXPECT_NEAR(s.pitch_dem_cdeg * 0.01, d, 0.005);
    EXPECT_NEAR(s.yaw_dem_cdeg * 0.01, -d, 0.005);
    EXPECT_NEAR(s.pitch_cdeg * 0.01, d, tol_p) << d;
    EXPECT_NEAR(s.yaw_cdeg * 0.01, -d, tol_y) << d;
  }
  EXPECT_LT(tol_p, 0.07);  // a 10-bit ADC resolves the gimbal to better than 0.1 deg
}

TEST(CarDrv, CalibrationErrorShowsAsTheModelledError) {
  // The rig's true sensor reads 3 % more than the firmware's table believes (and +0.2 deg).
  const auto fw = rp::CarDrvConfig::defaults();
  auto truth = fw;
  truth.pitch.deg_of_volts = fw.pitch.deg_of_volts.scaled(1.0 / 1.03, -0.2 / 1.03);
  Rig rig(fw, truth);
  sendTo(rig.drv, 1, servo(20.0, 0.0));
  rig.run(2.0);
  const double lsb = 5.0 / 1024;
  const double tol = 0.5 * lsb * maxSlope(fw.pitch.deg_of_volts) + 0.005;
  // firmware angle = 1.03 * true + 0.2
  EXPECT_NEAR(rig.last().pitch_cdeg * 0.01, 1.03 * 20.0 + 0.2, tol);
}

TEST(CarDrv, NoisyAdcAveragingReducesTheSpread) {
  rp::AdcConfig adc;
  adc.noise_sigma_v = 0.01;  // 2 LSB
  auto fw = rp::CarDrvConfig::defaults();
  fw.adc_samples = 16;
  Rig rig(fw, rp::CarDrvConfig::defaults(), adc);
  sendTo(rig.drv, 1, servo(10.0, 0.0));
  rig.run(60.0);
  std::vector<double> p;
  for (const auto& s : rig.hw.out.all<rp::CarSensorsPayload>())
    if (s.board_time_ms > 2000) p.push_back(s.pitch_cdeg * 0.01);
  ASSERT_GT(p.size(), 1000u);
  double mean = 0, var = 0;
  for (double v : p) mean += v;
  mean /= p.size();
  for (double v : p) var += (v - mean) * (v - mean);
  const double sd = std::sqrt(var / (p.size() - 1));
  // The mean of 16 independent samples, each with 10 mV noise and the ADC's rounding (uniform,
  // lsb^2/12; 2 LSB of noise dithers it), through the calibration's slope where the gimbal
  // rests: sd = slope(10 deg) * sqrt(0.01^2 + lsb^2/12) / sqrt(16). With ~1700 independent
  // readings the sd is estimated within 1/sqrt(2n) ~ 1.7 %; 8 % is over four of those.
  const double lsb = 5.0 / 1024;
  const double v10 = fw.pitch.deg_of_volts.inverse(10.0), h = 1e-4;
  const double slope =
      (fw.pitch.deg_of_volts(v10 + h) - fw.pitch.deg_of_volts(v10 - h)) / (2 * h);
  const double expected = slope * std::sqrt(1e-4 + lsb * lsb / 12) / 4;
  std::printf("averaged pitch reading: sd %.4f deg, expected %.4f deg (%.1f deg/V), n %zu\n", sd,
              expected, slope, p.size());
  EXPECT_NEAR(sd, expected, 0.08 * expected);
  EXPECT_NEAR(mean, 10.0, 5 * expected / std::sqrt(p.size()) + 0.5 * lsb * slope / 4 + 0.005);
}

TEST(CarDrv, ImuAndTimeOfFlight) {
  Rig rig;
  rig.hw.imu[0] = 164;     // 0.01 g
  rig.hw.imu[1] = -16384;  // -1 g (gravity, camera y down)
  rig.hw.imu[2] = 8192;    // 0.5 g
  rig.hw.tof_mm = 1234;
  rig.run(0.1);
  auto s = rig.last();
  EXPECT_EQ(s.acc_x_mg, 10);
  EXPECT_EQ(s.acc_y_mg, -1000);
  EXPECT_EQ(s.acc_z_mg, 500);
  EXPECT_EQ(s.tof_mm, 1234);
  EXPECT_TRUE(s.flags & rp::CarSensorsPayload::kTofValid);
  rig.hw.tof_ok = false;
  rig.run(0.1);
  s = rig.last();
  EXPECT_FALSE(s.flags & rp::CarSensorsPayload::kTofValid);
}

TEST(CarDrv, StepAcknowledgedAfterSlewAndSettle) {
  Rig rig;
  const auto c = rp::CarDrvConfig::defaults();
  rp::CmdMode mode2;
  mode2.mode = 2;  // step sequence: one move at a time
  sendTo(rig.drv, 100, mode2);
  ASSERT_EQ(rig.hw.out.lastStatus(100), st(AckStatus::kDone));
  ASSERT_EQ(rig.drv.mode(), 2);
  sendTo(rig.drv, 1, servo(15.0, -6.0));
  EXPECT_EQ(rig.hw.out.lastStatus(1), st(AckStatus::kAccepted));
  const double t_done = 15.0 / c.servo_rate_deg_s + c.settle_s;  // the larger axis sets it
  rig.run(t_done - 0.01);
  EXPECT_EQ(rig.hw.out.lastStatus(1), st(AckStatus::kAccepted));
  sendTo(rig.drv, 2, servo(1.0, 1.0));
  EXPECT_EQ(rig.hw.out.lastStatus(2), st(AckStatus::kBusy));
  rig.run(0.02);
  EXPECT_EQ(rig.hw.out.lastStatus(1), st(AckStatus::kDone));
  sendTo(rig.drv, 3, servo(1.0, 1.0, true));  // relative
  rig.run(1.0);
  EXPECT_EQ(rig.hw.out.lastStatus(3), st(AckStatus::kDone));
  EXPECT_NEAR(rig.drv.pitchDemandDeg(), 16.0, 1e-9);
  EXPECT_NEAR(rig.drv.yawDemandDeg(), -5.0, 1e-9);
  sendTo(rig.drv, 4, servo(45.0, 0.0));  // beyond max_deg
  EXPECT_EQ(rig.hw.out.lastStatus(4), st(AckStatus::kBadArgument));
  rp::CmdTrackMove m;
  sendTo(rig.drv, 5, m);
  EXPECT_EQ(rig.hw.out.lastStatus(5), st(AckStatus::kUnsupported));
  sendCmd(rig.drv, 6, MsgId::kInit);  // centres the gimbal
  rig.run(1.0);
  EXPECT_EQ(rig.hw.out.lastStatus(6), st(AckStatus::kDone));
  EXPECT_NEAR(rig.hw.angle[0], 0.0, 1e-9);
}

TEST(CarDrv, StreamsAt30Hz) {
  Rig rig;
  rig.run(5.0, 500);
  const auto all = rig.hw.out.all<rp::CarSensorsPayload>();
  EXPECT_NEAR(static_cast<double>(all.size()), 150.0, 1.0);
}

TEST(CarDrv, Mode1StreamedDemandsAreAllAcceptedAndFollowed) {
  // 30 Hz demand stream of a 20 deg, 1/12.6 Hz pitch sine with a 10 deg yaw cosine (the RT3 kind
  // of run): every demand arrives while the previous one is still settling (settle_s = 0.3 s).
  Rig rig;
  const auto c = rp::CarDrvConfig::defaults();
  ASSERT_EQ(rig.drv.mode(), 1);
  ASSERT_GT(c.settle_s, 1.0 / 30.0);
  const double lsb = 5.0 / 1024;
  const double tol_p = 0.5 * lsb * maxSlope(c.pitch.deg_of_volts) + 0.005;
  const double tol_y = 0.5 * lsb * maxSlope(c.yaw.deg_of_volts) + 0.005;
  const double w = 2 * M_PI / 12.6;
  const int n = 90;
  double p = 0, y = 0;
  for (int k = 0; k < n; ++k) {
    const uint32_t seq = 1 + k;
    p = std::round(2000 * std::sin(w * k / 30.0)) * 0.01;  // centidegrees on the wire
    y = std::round(1000 * std::cos(w * k / 30.0)) * 0.01;
    sendTo(rig.drv, seq, servo(p, y));
    ASSERT_EQ(rig.hw.out.lastStatus(seq), st(AckStatus::kAccepted)) << k;
    if (k > 0) {  // the previous demand was still settling: superseded, never "busy"
      ASSERT_EQ(rig.hw.out.lastStatus(seq - 1), st(AckStatus::kAborted)) << k;
    }
    // Followed at once: the servo pulse is the new demand through the calibration (ideal servo).
    EXPECT_NEAR(rig.hw.angle[0], p, 1e-9) << k;
    EXPECT_NEAR(rig.hw.angle[1], y, 1e-9) << k;
    EXPECT_DOUBLE_EQ(rig.drv.pitchDemandDeg(), p);
    EXPECT_DOUBLE_EQ(rig.drv.yawDemandDeg(), y);
    rig.run(1.0 / 30.0);
    // The stream frame after the demand reports it and the sensor reading of the new angle.
    const auto s = rig.last();
    EXPECT_NEAR(s.pitch_dem_cdeg * 0.01, p, 0.005) << k;
    EXPECT_NEAR(s.yaw_dem_cdeg * 0.01, y, 0.005) << k;
    EXPECT_NEAR(s.pitch_cdeg * 0.01, p, tol_p) << k;
    EXPECT_NEAR(s.yaw_cdeg * 0.01, y, tol_y) << k;
  }
  for (int k = 0; k < n; ++k) {
    for (const auto& a : rig.hw.out.acksFor(1 + k))
      EXPECT_NE(static_cast<int>(a.status), st(AckStatus::kBusy)) << k;
  }
  // The last demand completes after its slew and settle like a single move.
  rig.run(c.settle_s + 0.1);
  EXPECT_EQ(rig.hw.out.lastStatus(n), st(AckStatus::kDone));
  EXPECT_NEAR(rig.hw.angle[0], p, 1e-9);
  EXPECT_NEAR(rig.hw.angle[1], y, 1e-9);
}
