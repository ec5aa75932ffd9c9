#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "board_harness.hpp"
#include "rig_drivers/firmware/track_drv.hpp"

using namespace rig_test;
using rp::AckStatus;
using rp::MsgId;
using rp::TrackStateCode;

namespace {

/// Track electronics with a rigid carriage: true position = start + steps * m_per_step.
/// Far sensor active at true position <= 0, near sensor at >= near_sensor_m.
class FakeTrack : public rp::TrackHardware {
 public:
  explicit FakeTrack(double m_per_step) : m_per_step_(m_per_step) {}
  void step(int dir) override {
    EXPECT_TRUE(dir == 1 || dir == -1);
    EXPECT_TRUE(motor_on);
    steps += dir;
    step_times_us.push_back(now_us);
    step_dirs.push_back(dir);
  }
  bool farSensor() override { return far_connected && truePos() <= 0.0; }
  bool nearSensor() override { return truePos() >= near_sensor_m; }
  bool estopPressed() override { return estop; }
  void enableMotor(bool on) override { motor_on = on; }
  void write(const uint8_t* d, size_t n) override { out.write(d, n); }
  double truePos() const { return start_m + steps * m_per_step_; }

  double start_m = 0.0;
  double near_sensor_m = 1.2;
  bool far_connected = true;
  bool estop = false;
  bool motor_on = true;
  int64_t steps = 0;
  uint64_t now_us = 0;
  std::vector<uint64_t> step_times_us;
  std::vector<int> step_dirs;
  CaptureOut out;

 private:
  double m_per_step_;
};

constexpr double kMps = 0.0186e-3;  // table B3, 20-tooth pulley

struct Rig {
  explicit Rig(rp::TrackDrvConfig c = rp::TrackDrvConfig()) : cfg(c), hw(kMps), drv(cfg, hw) {}
  /// Runs the board for `seconds` calling update every `tick_us`.
  void run(double seconds, uint32_t tick_us = 20) {
    const uint64_t end = hw.now_us + static_cast<uint64_t>(seconds * 1e6);
    while (hw.now_us < end) {
      hw.now_us += tick_us;
      drv.update(static_cast<uint32_t>(hw.now_us));
    }
  }
  /// Runs until seq has a final (non-accepted) ack or the timeout; returns its status.
  int runUntilDone(uint32_t seq, double timeout_s, uint32_t tick_us = 20) {
    const uint64_t end = hw.now_us + static_cast<uint64_t>(timeout_s * 1e6);
    while (hw.now_us < end) {
      const auto acks = hw.out.acksFor(seq);
      if (!acks.empty() && acks.back().status != AckStatus::kAccepted)
        return static_cast<int>(acks.back().status);
      hw.now_us += tick_us;
      drv.update(static_cast<uint32_t>(hw.now_us));
    }
    return -1;
  }
  /// Homes, then starts a 1 m move at 0.2 m/s and 0.4 m/s^2 (seq 2) and lets it reach cruise.
  void cruise() {
    home();
    move(2, 1.0, false, 0.2, 0.4);
    run(1.5, 10);
  }
  void home() {
    sendCmd(drv, 1, MsgId::kInit);
    ASSERT_EQ(runUntilDone(1, 120.0, 200), st(AckStatus::kDone));
  }
  uint32_t move(uint32_t seq, double target_m, bool relative = false, double v_mps = 0,
                double a_mps2 = 0) {
    rp::CmdTrackMove m;
    m.target_um = static_cast<int32_t>(std::lround(target_m * 1e6));
    m.flags = relative ? rp::CmdTrackMove::kRelative : 0;
    m.max_speed_mm_s = static_cast<uint16_t>(std::lround(v_mps * 1e3));
    m.accel_mm_s2 = static_cast<uint16_t>(std::lround(a_mps2 * 1e3));
    sendTo(drv, seq, m);
    return seq;
  }
  rp::TrackDrvConfig cfg;
  FakeTrack hw;
  rp::TrackDrv drv;
};

struct WindowStats {
  double max_speed = 0;  // steps/s
  double max_accel = 0;  // steps/s^2
};

// Speeds over windows of W steps and accelerations between consecutive windows. With step times
// late by at most one tick h, a window of duration T reads at most W / (T - h): the bounds the
// tests use follow from that.
WindowStats windowStats(const std::vector<uint64_t>& t_us, size_t first, size_t last, size_t w) {
  WindowStats s;
  double prev_v = -1, prev_tc = 0;
  for (size_t k = first; k + w <= last; k += w) {
    const double t0 = t_us[k] * 1e-6, t1 = t_us[k + w - 1] * 1e-6;
    const double v = (w - 1) / (t1 - t0);
    const double tc = 0.5 * (t0 + t1);
    s.max_speed = std::max(s.max_speed, v);
    if (prev_v >= 0) s.max_accel = std::max(s.max_accel, std::fabs(v - prev_v) / (tc - prev_tc));
    prev_v = v;
    prev_tc = tc;
  }
  return s;
}

}  // namespace

TEST(TrackDrvConfig, PulleyTableAndValidation) {
  EXPECT_DOUBLE_EQ(rp::pulleyMetresPerStep(20), 0.0186e-3);
  EXPECT_DOUBLE_EQ(rp::pulleyMetresPerStep(48), 0.04464e-3);
  EXPECT_EQ(rp::pulleyMetresPerStep(25), 0.0);
  rp::TrackDrvConfig c;
  EXPECT_EQ(c.validate(), "");
  c.pulley_teeth = 25;
  c.max_speed_mps = -1;
  c.home_search_m = 0.5;
  const std::string e = c.validate();
  EXPECT_NE(e.find("pulley_teeth"), std::string::npos) << e;
  EXPECT_NE(e.find("max_speed_mps"), std::string::npos) << e;
  EXPECT_NE(e.find("home_search_m"), std::string::npos) << e;
  FakeTrack hw(kMps);
  EXPECT_THROW(rp::TrackDrv(c, hw), std::invalid_argument);
}

TEST(TrackDrvConfig, ProblemsNameEachBadFieldByItsBit) {
  // problems() is what a board checks; validate() words the same bits on the host.
  using C = rp::TrackDrvConfig;
  EXPECT_EQ(C().problems(), 0u);
  const struct {
    void (*spoil)(C&);
    uint32_t bit;
    const char* text;
  } cases[] = {
      {[](C& c) { c.m_per_step = -1; }, C::kBadMPerStep, "m_per_step"},
      {[](C& c) { c.pulley_teeth = 25; }, C::kUnknownPulley, "pulley_teeth"},
      {[](C& c) { c.accel_mps2 = 0; }, C::kAccel, "accel_mps2 must be > 0"},
      {[](C& c) { c.max_speed_mps = 0.35; }, C::kSpeedOverLimit, "exceeds speed_limit_mps"},
      {[](C& c) { c.soft_margin_m = 0.7; }, C::kSoftMargin, "soft_margin_m"},
      {[](C& c) { c.home_search_m = 1.0; }, C::kHomeSearchShort, "home_search_m (1)"},
  };
  for (const auto& k : cases) {
    C c;
    k.spoil(c);
    EXPECT_EQ(c.problems(), k.bit) << k.text;
    EXPECT_NE(c.validate().find(k.text), std::string::npos) << c.validate();
  }
}

TEST(TrackDrv, HomesToFarSensorOnInit) {
  Rig rig;
  rig.hw.start_m = 0.37;  // carriage somewhere on the track at power-up
  rig.run(0.1);
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kUninitialised);
  sendCmd(rig.drv, 1, MsgId::kInit);
  const auto first = rig.hw.out.acksFor(1);
  ASSERT_EQ(first.size(), 1u);
  EXPECT_EQ(first[0].status, AckStatus::kAccepted);
  rig.run(0.5);
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kHoming);
  // 0.37 m at 20 mm/s: ~18.5 s plus the ramp
  EXPECT_EQ(rig.runUntilDone(1, 30.0, 100), st(AckStatus::kDone));
  EXPECT_TRUE(rig.drv.homed());
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kReady);
  EXPECT_EQ(rig.drv.positionSteps(), 0);
  // Stopped on the first step that made the sensor active: within one step of its edge.
  EXPECT_LE(rig.hw.truePos(), 0.0);
  EXPECT_GT(rig.hw.truePos(), -kMps * 1.0001);
  for (int d : rig.hw.step_dirs) EXPECT_EQ(d, -1);
  // Homing speed never above home_speed_mps (window of 100 steps, 100 us ticks).
  const auto s = windowStats(rig.hw.step_times_us, 0, rig.hw.step_times_us.size(), 100);
  const double bound = rig.cfg.home_speed_mps / kMps * (0.093 / (0.093 - 1e-4));  // T=93ms
  EXPECT_LE(s.max_speed, bound);
  EXPECT_GE(s.max_speed, 0.98 * rig.cfg.home_speed_mps / kMps);
}

TEST(TrackDrv, HomingFailsWhenFarSensorNeverSeen) {
  rp::TrackDrvConfig c;
  c.home_search_m = 1.3;
  c.home_speed_mps = 0.1;
  Rig rig(c);
  rig.hw.far_connected = false;
  sendCmd(rig.drv, 1, MsgId::kInit);
  EXPECT_EQ(rig.runUntilDone(1, 30.0, 100), st(AckStatus::kFailed));
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kFault);
  EXPECT_EQ(rig.hw.steps, -std::llround(1.3 / kMps));
  rig.move(2, 0.5);
  EXPECT_EQ(rig.hw.out.lastStatus(2), st(AckStatus::kNotReady));
}

TEST(TrackDrv, TrapezoidReachesButNeverExceedsLimitsAndLandsOnTarget) {
  Rig rig;
  rig.home();
  rig.hw.step_times_us.clear();
  const double v = 0.2, a = 0.4;  // RT1 set speed, 0.5 s ramps
  const uint32_t tick = 10;
  rig.move(10, 0.6, false, v, a);
  ASSERT_EQ(rig.runUntilDone(10, 10.0, tick), st(AckStatus::kDone));
  const int32_t target = static_cast<int32_t>(std::lround(0.6 / kMps));
  EXPECT_EQ(rig.drv.positionSteps(), target);
  EXPECT_EQ(rig.hw.steps, target);
  EXPECT_EQ(static_cast<int32_t>(rig.hw.step_times_us.size()), target);  // no back-and-forth
  rig.run(0.5, tick);
  EXPECT_EQ(rig.hw.steps, target);  // and nothing after arrival

  const size_t w = 400;  // >= 37 ms windows at full speed
  const auto s = windowStats(rig.hw.step_times_us, 0, rig.hw.step_times_us.size(), w);
  const double v_sps = v / kMps, a_sps2 = a / kMps;
  const double t_win = (w - 1) / v_sps;
  const double h = tick * 1e-6;
  const double v_bound = v_sps * t_win / (t_win - h);
  EXPECT_LE(s.max_speed, v_bound);
  EXPECT_GE(s.max_speed, 0.995 * v_sps);  // 0.6 m is long enough to cruise
  // each window speed may be off by v*h/T (both ends), two windows T apart:
  const double a_bound = a_sps2 + 2 * 2 * v_sps * h / t_win / t_win;
  EXPECT_LE(s.max_accel, a_bound);
  EXPECT_GE(s.max_accel, 0.9 * a_sps2);
  // First to last step spans the trapezoid d/v + v/a less the time to the first step,
  // sqrt(2 / a) (one step from rest), to within two ticks.
  const double dur = (rig.hw.step_times_us.back() - rig.hw.step_times_us.front()) * 1e-6;
  EXPECT_NEAR(dur, 0.6 / v + v / a - std::sqrt(2 / a_sps2), 2 * h);
}

TEST(TrackDrv, ShortMoveIsTriangularAndBackwardsWorks) {
  Rig rig;
  rig.home();
  rig.move(2, 0.3);
  ASSERT_EQ(rig.runUntilDone(2, 10.0), st(AckStatus::kDone));
  rig.hw.step_times_us.clear();
  rig.hw.step_dirs.clear();
  rig.move(3, 0.29, false, 0.2, 0.4);  // 10 mm back: peak sqrt(a d) = 0.063 m/s < 0.2
  ASSERT_EQ(rig.runUntilDone(3, 5.0, 10), st(AckStatus::kDone));
  EXPECT_EQ(rig.drv.positionSteps(), std::lround(0.29 / kMps));
  const double dur = (rig.hw.step_times_us.back() - rig.hw.step_times_us.front()) * 1e-6;
  const double d_steps = std::lround(0.3 / kMps) - std::lround(0.29 / kMps);
  const double a_sps2 = 0.4 / kMps;
  EXPECT_NEAR(dur, 2 * std::sqrt(d_steps / a_sps2) - std::sqrt(2 / a_sps2), 2e-5);
  for (int d : rig.hw.step_dirs) EXPECT_EQ(d, -1);
}

TEST(TrackDrv, StepSequenceOf100x10mmLandsOn1m) {
  Rig rig;
  rig.home();
  rp::CmdMode mode;
  mode.mode = 2;
  sendTo(rig.drv, 2, mode);
  EXPECT_EQ(rig.hw.out.lastStatus(2), st(AckStatus::kDone));
  EXPECT_EQ(rig.drv.mode(), 2);
  for (uint32_t i = 0; i < 100; ++i) {
    const uint32_t seq = 100 + i;
    rig.move(seq, 0.010, true);
    ASSERT_EQ(rig.runUntilDone(seq, 2.0, 100), st(AckStatus::kDone)) << "step " << i;
  }
  // 1 m / 0.0186 mm = 53763.4 steps: within half a step of the commanded metre
  EXPECT_NEAR(rig.drv.positionM(), 1.0, 0.5 * kMps + 1e-12);
}

TEST(TrackDrv, EndOfTrackSensorStopsTheMove) {
  Rig rig;
  rig.hw.near_sensor_m = 0.8;  // the near sensor is closer than the configured track length
  rig.home();
  rig.move(2, 1.0);
  EXPECT_EQ(rig.runUntilDone(2, 20.0), st(AckStatus::kEndOfTrack));
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kEndOfTrack);
  // Stopped at the first step that reached the sensor: within one step of 0.8 m
  EXPECT_GE(rig.hw.truePos(), 0.8);
  EXPECT_LT(rig.hw.truePos(), 0.8 + kMps * 1.0001);
  const int64_t at_stop = rig.hw.steps;
  rig.move(3, 0.9);  // further into the end stop: refused
  EXPECT_EQ(rig.hw.out.lastStatus(3), st(AckStatus::kEndOfTrack));
  rig.run(0.5);
  EXPECT_EQ(rig.hw.steps, at_stop);
  rig.move(4, 0.5);  // away from it: allowed
  EXPECT_EQ(rig.runUntilDone(4, 20.0), st(AckStatus::kDone));
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kReady);
  // Targets outside the configured track are rejected before moving.
  rig.move(5, 1.3);
  EXPECT_EQ(rig.hw.out.lastStatus(5), st(AckStatus::kBadArgument));
  rig.move(6, 0.5, false, 0.5);  // above speed_limit_mps
  EXPECT_EQ(rig.hw.out.lastStatus(6), st(AckStatus::kBadArgument));
}

TEST(TrackDrv, EmergencyStopLatchesUntilResetAndInit) {
  Rig rig;
  rig.home();
  rig.move(2, 0.8);
  rig.run(1.0);
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kMoving);
  rig.hw.estop = true;
  rig.run(0.01);
  const int64_t at_stop = rig.hw.steps;
  EXPECT_EQ(rig.hw.out.lastStatus(2), st(AckStatus::kEStop));
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kEStop);
  EXPECT_FALSE(rig.hw.motor_on);
  rig.run(1.0);
  EXPECT_EQ(rig.hw.steps, at_stop);  // not one step after the e-stop
  rig.move(3, 0.1);
  EXPECT_EQ(rig.hw.out.lastStatus(3), st(AckStatus::kEStop));
  sendCmd(rig.drv, 4, MsgId::kReset);  // still pressed
  EXPECT_EQ(rig.hw.out.lastStatus(4), st(AckStatus::kEStop));
  rig.hw.estop = false;
  rig.run(0.1);
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kEStop);  // latched
  sendCmd(rig.drv, 5, MsgId::kReset);
  EXPECT_EQ(rig.hw.out.lastStatus(5), st(AckStatus::kDone));
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kUninitialised);
  rig.move(6, 0.1);
  EXPECT_EQ(rig.hw.out.lastStatus(6), st(AckStatus::kNotReady));
  sendCmd(rig.drv, 7, MsgId::kInit);
  EXPECT_EQ(rig.runUntilDone(7, 60.0, 200), st(AckStatus::kDone));
}

TEST(TrackDrv, StopDeceleratesWithinAccelLimit) {
  Rig rig;
  rig.cruise();
  const int64_t before = rig.hw.steps;
  rig.hw.step_times_us.clear();
  sendCmd(rig.drv, 3, MsgId::kStop);
  EXPECT_EQ(rig.hw.out.lastStatus(2), st(AckStatus::kAborted));
  EXPECT_EQ(rig.runUntilDone(3, 5.0, 10), st(AckStatus::kDone));
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kReady);
  // braking distance v^2 / 2a = 50 mm
  EXPECT_NEAR((rig.hw.steps - before) * kMps, 0.05, 2 * kMps);
  const auto s = windowStats(rig.hw.step_times_us, 0, rig.hw.step_times_us.size(), 400);
  EXPECT_LE(s.max_accel, 0.4 / kMps * 1.05);
  // a relative move after the stop starts from where it actually stopped
  const double stopped = rig.drv.positionM();
  rig.move(4, 0.01, true);
  EXPECT_EQ(rig.runUntilDone(4, 5.0), st(AckStatus::kDone));
  EXPECT_NEAR(rig.drv.positionM(), stopped + 0.01, kMps);
}

// Found by fuzz_firmware: a stop arriving while an earlier stop was still braking took its place,
// and the earlier stop never got a final ack (a host waiting for it would wait forever).
TEST(TrackDrv, SecondStopSupersedesTheFirstWithOneFinalAckEach) {
  Rig rig;
  rig.cruise();
  const int64_t before = rig.hw.steps;
  sendCmd(rig.drv, 3, MsgId::kStop);
  rig.run(0.1, 10);  // braking takes 0.5 s at 0.4 m/s^2
  sendCmd(rig.drv, 4, MsgId::kStop);
  EXPECT_EQ(rig.runUntilDone(4, 5.0, 10), st(AckStatus::kDone));
  const auto first = rig.hw.out.acksFor(3);
  ASSERT_EQ(first.size(), 2u);
  EXPECT_EQ(first[0].status, AckStatus::kAccepted);
  EXPECT_EQ(first[1].status, AckStatus::kAborted);
  const auto second = rig.hw.out.acksFor(4);
  ASSERT_EQ(second.size(), 2u);
  EXPECT_EQ(second[0].status, AckStatus::kAccepted);
  EXPECT_EQ(rig.drv.state(), TrackStateCode::kReady);
  // the second stop keeps the first one's braking: v^2 / 2a = 50 mm
  EXPECT_NEAR((rig.hw.steps - before) * kMps, 0.05, 2 * kMps);
}

// Found by fuzz_firmware: a ping with a payload of the wrong size got no answer at all, which the
// host cannot tell from a lost link.
TEST(TrackDrv, MalformedPingIsRejectedNotIgnored) {
  Rig rig;
  const uint8_t two_bytes[2] = {1, 2};
  uint8_t buf[rp::kMaxFrameSize];
  const size_t n =
      rp::encodeFrame(rp::BoardId::kTrack, MsgId::kPing, 9, two_bytes, 2, buf, sizeof buf);
  rig.drv.receive(buf, n);
  const auto acks = rig.hw.out.acksFor(9);
  ASSERT_EQ(acks.size(), 1u);
  EXPECT_EQ(acks[0].acked_id, MsgId::kPing);
  EXPECT_EQ(acks[0].status, AckStatus::kBadArgument);
  EXPECT_TRUE(rig.hw.out.all<rp::Pong>().empty());
  rp::CmdPing ping;
  ping.host_time_ms = 777;
  sendTo(rig.drv, 10, ping);  // a well-formed ping still gets its pong and no ack
  const auto pongs = rig.hw.out.all<rp::Pong>();
  ASSERT_EQ(pongs.size(), 1u);
  EXPECT_EQ(pongs[0].host_time_ms, 777u);
  EXPECT_TRUE(rig.hw.out.acksFor(10).empty());
}

TEST(TrackDrv, RejectsWhileBusyAndUnsupported) {
  Rig rig;
  rig.hw.start_m = 0.5;
  rig.move(1, 0.5);
  EXPECT_EQ(rig.hw.out.lastStatus(1), st(AckStatus::kNotReady));
  sendCmd(rig.drv, 2, MsgId::kInit);
  rig.run(0.1);
  sendCmd(rig.drv, 3, MsgId::kInit);
  EXPECT_EQ(rig.hw.out.lastStatus(3), st(AckStatus::kBusy));
  rp::CmdMode m;
  m.mode = 2;
  sendTo(rig.drv, 4, m);
  EXPECT_EQ(rig.hw.out.lastStatus(4), st(AckStatus::kBusy));
  rp::CmdServo servo;
  sendTo(rig.drv, 5, servo);
  EXPECT_EQ(rig.hw.out.lastStatus(5), st(AckStatus::kUnsupported));
  // frames for another board are ignored entirely
  const auto other = rp::encodeCommand(rp::BoardId::kCar, MsgId::kStop, 6);
  rig.drv.receive(other.data(), other.size());
  EXPECT_TRUE(rig.hw.out.acksFor(6).empty());
}

TEST(TrackDrv, CommandBehindAFalseFrameStartIsHandledWhenTheLineGoesIdle) {
  Rig rig;
  const auto vers = rp::encodeCommand(rp::BoardId::kTrack, MsgId::kVers, 9);
  std::vector<uint8_t> bytes = {rp::kSync0, rp::kSync1, 50, rp::kProtocolVersion, 1};
  bytes.insert(bytes.end(), vers.begin(), vers.end());
  rig.drv.receive(bytes.data(), bytes.size());
  EXPECT_TRUE(rig.hw.out.acksFor(9).empty());  // held by the false start's 50-byte payload
  EXPECT_GT(rig.drv.rxPending(), 0u);
  rig.drv.lineIdle();
  EXPECT_EQ(rig.hw.out.lastStatus(9), st(AckStatus::kDone));
  EXPECT_EQ(rig.hw.out.all<rp::VersionInfo>().size(), 1u);
  EXPECT_EQ(rig.drv.rxPending(), 0u);
}

TEST(TrackDrv, StreamsAt30HzWithVersAndPara) {
  Rig rig;
  rig.run(10.0, 100);
  const auto states = rig.hw.out.all<rp::TrackStatePayload>();
  // frame n due at n * 33.333 ms: t = 0 .. 10 s gives 301 frames
  EXPECT_NEAR(static_cast<double>(states.size()), 300.0, 1.0);
  for (size_t i = 1; i < states.size(); ++i) {
    const uint32_t dt = states[i].board_time_ms - states[i - 1].board_time_ms;
    EXPECT_TRUE(dt == 33 || dt == 34) << dt;
  }
  for (size_t i = 1; i < rig.hw.out.frames.size(); ++i)
    EXPECT_EQ(rig.hw.out.frames[i].seq, rig.hw.out.frames[i - 1].seq + 1);
  sendCmd(rig.drv, 1, MsgId::kVers);
  const auto v = rig.hw.out.all<rp::VersionInfo>();
  ASSERT_EQ(v.size(), 1u);
  EXPECT_STREQ(v[0].name, "TrackDRV");
  EXPECT_EQ(rig.hw.out.lastStatus(1), st(AckStatus::kDone));
  sendCmd(rig.drv, 2, MsgId::kPara);
  const auto p = rig.hw.out.all<rp::ParamValue>();
  ASSERT_EQ(p.size(), 8u);
  EXPECT_STREQ(p[1].name, "mm_per_step");
  EXPECT_NEAR(p[1].value(), 0.0186, 1e-9);
  // ping answered with the echoed host time
  rp::CmdPing ping;
  ping.host_time_ms = 4711;
  sendTo(rig.drv, 3, ping);
  const auto pong = rig.hw.out.all<rp::Pong>();
  ASSERT_EQ(pong.size(), 1u);
  EXPECT_EQ(pong[0].host_time_ms, 4711u);
  EXPECT_NEAR(pong[0].board_time_ms, 10000.0, 1.0);
}

TEST(TrackDrv, BoardClockSurvivesMicrosWrap) {
  Rig rig;
  rig.hw.now_us = 0xFFFFFFFFull - 50000;  // 50 ms before the 32-bit micros() wrap
  rig.run(0.2, 100);
  const auto states = rig.hw.out.all<rp::TrackStatePayload>();
  ASSERT_GE(states.size(), 6u);
  for (size_t i = 1; i < states.size(); ++i)
    EXPECT_LE(states[i].board_time_ms - states[i - 1].board_time_ms, 34u);
}

TEST(TrackDrv, WaitStepAcknowledgedAfterItsTime) {
  Rig rig;
  rp::CmdWait w;
  w.wait_ms = 500;
  sendTo(rig.drv, 9, w);
  EXPECT_EQ(rig.hw.out.lastStatus(9), st(AckStatus::kAccepted));
  rig.run(0.45);
  EXPECT_EQ(rig.hw.out.lastStatus(9), st(AckStatus::kAccepted));
  rig.run(0.1);
  EXPECT_EQ(rig.hw.out.lastStatus(9), st(AckStatus::kDone));
}

TEST(TrackDrv, CoarseLoopStillLandsExactlyAndKeepsTheFrameClock) {
  // A host simulator may call update() only every 1 ms (~11 steps per call at 0.2 m/s): steps
  // bunch up but the count follows the same analytic profile and ends on the target.
  Rig rig;
  rig.home();
  const size_t frames_before = rig.hw.out.all<rp::TrackStatePayload>().size();
  rig.move(2, 0.777, false, 0.2, 0.4);
  ASSERT_EQ(rig.runUntilDone(2, 10.0, 1000), st(AckStatus::kDone));
  EXPECT_EQ(rig.drv.positionSteps(), std::lround(0.777 / kMps));
  EXPECT_EQ(rig.hw.steps, std::lround(0.777 / kMps));
  for (int d : rig.hw.step_dirs) EXPECT_EQ(d, 1);
  // The last TrackState streamed while moving never reports more than the speed limit.
  for (const auto& s : rig.hw.out.all<rp::TrackStatePayload>())
    EXPECT_LE(std::abs(s.vel_um_s), 200000);
  const auto frames = rig.hw.out.all<rp::TrackStatePayload>();
  const double t = (frames.back().board_time_ms - frames[frames_before].board_time_ms) * 1e-3;
  EXPECT_NEAR(static_cast<double>(frames.size() - frames_before - 1), t * 30.0, 1.0);
}

TEST(TrackDrv, RetransmittedCommandRunsOnce) {
  Rig rig;
  rig.home();
  rp::CmdTrackMove m;
  m.target_um = 10000;
  m.flags = rp::CmdTrackMove::kRelative;
  const auto frame = rp::encodeMessage(rp::BoardId::kTrack, 42, m);
  rig.drv.receive(frame.data(), frame.size());
  rig.run(0.05);
  rig.drv.receive(frame.data(), frame.size());  // host retries: ack lost on the way back
  auto acks = rig.hw.out.acksFor(42);
  ASSERT_EQ(acks.size(), 2u);
  EXPECT_EQ(acks[1].status, AckStatus::kAccepted);  // still running: same answer again
  ASSERT_EQ(rig.runUntilDone(42, 2.0), st(AckStatus::kDone));
  rig.drv.receive(frame.data(), frame.size());  // and once more after completion
  rig.run(1.0);
  acks = rig.hw.out.acksFor(42);
  EXPECT_EQ(acks.back().status, AckStatus::kDone);
  EXPECT_NEAR(rig.drv.positionM(), 0.010, kMps);  // moved 10 mm once, not 20 or 30
  // a new seq with the same payload is a new command
  const auto again = rp::encodeMessage(rp::BoardId::kTrack, 43, m);
  rig.drv.receive(again.data(), again.size());
  ASSERT_EQ(rig.runUntilDone(43, 2.0), st(AckStatus::kDone));
  EXPECT_NEAR(rig.drv.positionM(), 0.020, kMps);
}
