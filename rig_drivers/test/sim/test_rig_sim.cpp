// Rig simulator: the boards' readings differ from the ground truth by the modelled errors and no
// more; the runs have the thesis's frame counts, speeds and step positions; links delay frames by
// their modelled latency; runs are deterministic; an external host drives the boards.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "rig_drivers/firmware/car_drv.hpp"
#include "rig_drivers/firmware/truck_drv.hpp"
#include "rig_drivers/sim/rig_sim.hpp"

#ifndef RIG_SOURCE_DIR
#error "RIG_SOURCE_DIR must name the rig_drivers folder"
#endif

namespace rig_drivers {
namespace {

using protocol::BoardId;
using protocol::MsgId;

const std::string kScenarios = std::string(RIG_SOURCE_DIR) + "/../config/scenarios/";

/// A scripted run stepped one physics step at a time, keeping the truth after every step.
struct Recorded {
  RigSimConfig cfg;
  std::vector<RigTruth> truth;  ///< truth[k] = state after physics step k (truth[0] = start)
  std::vector<SimLinkFrame> log;
  std::vector<SimCameraFrame> frames;
  bool finished = false, failed = false;

  /// The state a board sampled in the loop of a frame written at time sent_t_s: its firmware
  /// runs before that step's physics, so it saw the state after the previous step.
  const RigTruth& seenAt(double sent_t_s) const {
    const long k = std::lround(sent_t_s * cfg.physics_rate_hz) - 1;
    return truth.at(static_cast<std::size_t>(std::max(0l, k)));
  }
};

Recorded record(const std::string& name, const RigSimConfig& cfg = RigSimConfig{},
                double t_max_s = 120.0) {
  Recorded r;
  r.cfg = cfg;
  RigSimulator sim(loadScenario(kScenarios + name + ".yaml"), cfg);
  r.truth.push_back(sim.truth());
  const double dt = 1.0 / cfg.physics_rate_hz;
  while (!sim.finished() && sim.now() < t_max_s) {
    sim.advanceTo(sim.now() + dt);
    r.truth.push_back(sim.truth());
  }
  r.log = sim.takeLinkLog();
  r.frames = sim.takeCameraFrames();
  r.finished = sim.finished();
  r.failed = sim.failed();
  for (const auto& e : sim.takeEvents()) ADD_FAILURE() << name << ": " << e;
  return r;
}

/// The frames of one message id a board sent, decoded.
template <class P>
std::vector<std::pair<const SimLinkFrame*, P>> payloads(const Recorded& r, BoardId board) {
  std::vector<std::pair<const SimLinkFrame*, P>> out;
  for (const SimLinkFrame& lf : r.log) {
    if (lf.outgoing || lf.board != board) continue;
    protocol::StreamDecoder dec;
    for (const auto& ev : protocol::feed(dec, lf.bytes)) {
      P p;
      if (ev.error == protocol::DecodeError::kNone &&
          protocol::decodePayload(ev.frame, p) == protocol::DecodeError::kNone)
        out.emplace_back(&lf, p);
    }
  }
  return out;
}

/// Largest |dy/dx| of a calibration curve (deg per volt).
double maxSlope(const protocol::PiecewiseLinear& c) {
  double s = 0.0;
  for (int i = 1; i < c.size(); ++i)
    s = std::max(s, std::abs((c.y(i) - c.y(i - 1)) / (c.x(i) - c.x(i - 1))));
  return s;
}

TEST(RigSim, RealTimeRunsHaveTable54FramesAtTheAchievedSpeed) {
  for (const char* name : {"RT1", "RT4"}) {
    SCOPED_TRACE(name);
    const Scenario sc = loadScenario(kScenarios + name + ".yaml");
    const Recorded r = record(name);
    ASSERT_TRUE(r.finished && !r.failed);
    ASSERT_EQ(static_cast<int>(r.frames.size()), sc.frameCount());
    for (std::size_t i = 1; i < r.frames.size(); ++i) {
      // Exposures on the 30 Hz camera clock, quantised to the physics step.
      ASSERT_NEAR(r.frames[i].truth.t_s - r.frames[i - 1].truth.t_s, 1.0 / 30.0,
                  1.0 / r.cfg.physics_rate_hz + 1e-9);
    }
    // Cruise speed over the middle of the run (the belt ring adds < 0.1 mm to each end point).
    const std::size_t a = r.frames.size() / 6, b = r.frames.size() * 5 / 6;
    const double v = (r.frames[b].truth.track_pos_m - r.frames[a].truth.track_pos_m) /
                     (r.frames[b].truth.t_s - r.frames[a].truth.t_s);
    EXPECT_NEAR(v * 1e3, sc.track.achieved_speed_mm_s, 0.5);
    // Over 1 m of track in all cases (thesis 5.4).
    EXPECT_GT(r.frames.back().truth.track_pos_m - r.frames.front().truth.track_pos_m, 1.0);
  }
}

TEST(RigSim, StepModeTakesOneStillFramePerStep) {
  const Recorded r = record("XTest1_05_Chair");
  ASSERT_TRUE(r.finished && !r.failed);
  ASSERT_EQ(r.frames.size(), 103u);
  // Frames 0..2 at the home position, frame 3 + i after step i + 1 of 10 mm. Tolerance: one
  // motor step (0.0186 mm) plus the belt ring left after the 0.4 s settle (< 0.05 mm).
  const double x0 = r.frames[0].truth.track_pos_m;
  for (std::size_t k = 0; k < r.frames.size(); ++k) {
    const double expected = x0 + (k < 3 ? 0.0 : (k - 2) * 0.010);
    ASSERT_NEAR(r.frames[k].truth.track_pos_m, expected, 0.07e-3) << "frame " << k;
  }
  // Nothing on the gimbal.
  for (const auto& f : r.frames) ASSERT_NEAR(f.truth.pitch_deg, 0.0, 1e-9);
}

TEST(RigSim, TripodStandsStillOnTheTargetAxisAtEachDistance) {
  const Recorded r = record("Calibration_L515");
  const Scenario sc = loadScenario(kScenarios + "Calibration_L515.yaml");
  ASSERT_TRUE(r.finished && !r.failed);
  EXPECT_TRUE(r.log.empty());  // no boards, nothing on any link
  ASSERT_EQ(static_cast<int>(r.frames.size()), sc.frameCount());
  const double period = sc.tripod.hold_s + sc.tripod.move_s;
  const double t0 = r.frames[0].truth.t_s;
  std::vector<int> still(sc.tripod.distances_m.size(), 0);
  for (const SimCameraFrame& f : r.frames) {
    const double t_run = f.truth.t_s - t0;
    ASSERT_NEAR(t_run, f.index / 30.0, 1.0 / r.cfg.physics_rate_hz + 1e-9);
    // Looking along +x (the target's axis) at its centre height, whatever the distance.
    const Eigen::Vector3d view = f.truth.T_W_C.rotation().col(2);
    ASSERT_NEAR(view.x(), 1.0, 1e-12);
    ASSERT_NEAR(f.truth.T_W_C.translation().y(), 0.0, 1e-12);
    ASSERT_NEAR(f.truth.T_W_C.translation().z(), 1.0, 1e-12);
    const double d = -f.truth.T_W_C.translation().x();
    const std::size_t i = static_cast<std::size_t>(t_run / period);
    if (t_run - i * period <= sc.tripod.hold_s - 1e-3) {
      ASSERT_EQ(d, sc.tripod.distances_m[i]) << "frame " << f.index;
      ++still[i];
    } else {
      // Carried: between this distance and the next.
      ASSERT_GE(d, std::min(sc.tripod.distances_m[i], sc.tripod.distances_m[i + 1]));
      ASSERT_LE(d, std::max(sc.tripod.distances_m[i], sc.tripod.distances_m[i + 1]));
    }
  }
  // Every hold gives its 2 s of still frames (one frame either way with the camera's phase).
  for (int n : still) EXPECT_NEAR(n, sc.tripod.hold_s * 30.0, 1.0);
}

TEST(RigSim, TrackPositionDiffersFromTruthByBeltStretchOnly) {
  const Recorded r = record("RT1");
  const auto states = payloads<protocol::TrackStatePayload>(r, BoardId::kTrack);
  ASSERT_GT(states.size(), 390u);  // 30 Hz over ~13.6 s
  // TrackPos counts motor steps; the carriage lags on its belt by a/w^2 under acceleration
  // (0.4 m/s^2 / (2 pi 9 Hz)^2 = 0.13 mm, doubled by the ring) plus a step of homing overshoot.
  const double w = 2 * M_PI * r.cfg.belt.natural_freq_hz;
  const double bound = 2.0 * 0.4 / (w * w) + 0.0186e-3 + 1e-6 + 0.05e-3;
  double max_err = 0.0;
  for (const auto& [lf, p] : states) {
    if (!(p.flags & protocol::TrackStatePayload::kHomed)) continue;
    const double err = p.pos_um * 1e-6 - r.seenAt(lf->sent_t_s).track_pos_m;
    max_err = std::max(max_err, std::abs(err));
  }
  EXPECT_LT(max_err, bound);
  EXPECT_GT(max_err, 0.02e-3);  // the belt is there: the reading is not the truth
}

void checkGimbalSensor(const char* scenario, bool pitch) {
  SCOPED_TRACE(scenario);
  const RigSimConfig cfg;
  const Recorded r = record(scenario, cfg);
  ASSERT_TRUE(r.finished && !r.failed);
  const auto sensors = payloads<protocol::CarSensorsPayload>(r, BoardId::kCar);
  ASSERT_GT(sensors.size(), 300u);
  const protocol::CarDrvConfig board = protocol::CarDrvConfig::defaults();
  const protocol::AxisCalibration& cal = pitch ? board.pitch : board.yaw;
  const double g = pitch ? cfg.pitch_sensor_gain_error : cfg.yaw_sensor_gain_error;
  const double o = pitch ? cfg.pitch_sensor_offset_deg : cfg.yaw_sensor_offset_deg;
  // CarDRV averages adc_samples readings: half an ADC step of quantisation plus 5 sigma of the
  // averaged electrical noise, through the steepest part of the calibration curve, plus the
  // 0.01 deg wire resolution.
  const double lsb_v = cfg.adc.vref / (1 << cfg.adc.bits);
  const double noise_v = cfg.adc.noise_sigma_v / std::sqrt(static_cast<double>(board.adc_samples));
  const double quant_deg = maxSlope(cal.deg_of_volts) * (0.5 * lsb_v + 5.0 * noise_v) + 0.006;
  double max_model_err = 0.0, max_total_err = 0.0, max_allowed = 0.0, max_angle = 0.0;
  for (const auto& [lf, p] : sensors) {
    const RigTruth& tr = r.seenAt(lf->sent_t_s);
    const double a = pitch ? tr.pitch_deg : tr.yaw_deg;
    const double reading = (pitch ? p.pitch_cdeg : p.yaw_cdeg) * 0.01;
    // Against the modelled calibration error: only quantisation and noise remain.
    max_model_err = std::max(max_model_err, std::abs(reading - (a * (1 + g) + o)));
    // Against the truth: calibration error + quantisation + noise, and no more.
    const double allowed = std::abs(g * a + o) + quant_deg;
    max_total_err = std::max(max_total_err, std::abs(reading - a));
    max_allowed = std::max(max_allowed, allowed);
    ASSERT_LE(std::abs(reading - a), allowed) << "t = " << lf->sent_t_s << " true " << a;
    max_angle = std::max(max_angle, std::abs(a));
  }
  EXPECT_LE(max_model_err, quant_deg);
  EXPECT_GT(max_angle, 10.0);  // the axis really moved
  // The calibration error is visible: at the largest angles it exceeds the quantisation bound.
  EXPECT_GT(max_total_err, quant_deg);
}

TEST(RigSim, PitchSensorErrorIsCalibrationPlusQuantisationPlusNoise) {
  checkGimbalSensor("RT6", true);
}

TEST(RigSim, YawSensorErrorIsCalibrationPlusQuantisationPlusNoise) {
  checkGimbalSensor("RT5", false);
}

TEST(RigSim, ServoLagsAndSticksBehindDemand) {
  const Recorded r = record("RT3");
  // Lag: the true angle trails the 20 deg, 1/12.6 Hz demand. Stick-slip: while the demand keeps
  // moving the shaft alternates between resting (static friction) and slipping.
  double max_lag = 0.0;
  int stuck = 0, slipping = 0;
  for (std::size_t k = 1; k < r.truth.size(); ++k) {
    const RigTruth& a = r.truth[k - 1];
    const RigTruth& b = r.truth[k];
    max_lag = std::max(max_lag, std::abs(b.pitch_dem_deg - b.pitch_deg));
    if (std::abs(b.pitch_dem_deg) > 1.0) (b.pitch_deg == a.pitch_deg ? stuck : slipping)++;
  }
  // Bound: the demand moves at most 2 pi f A = 10 deg/s; the servo's lag adds ~A w tau and the
  // friction band a breakaway (0.6 deg + 30 % spread).
  const double w = 2 * M_PI / 12.6;
  const double lag_bound =
      20 * w * (r.cfg.pitch_servo.lag_s + 1.0 / 30) +
      r.cfg.pitch_servo.breakaway_deg * (1 + r.cfg.pitch_servo.breakaway_spread) +
      std::abs(r.cfg.servo_offset_deg) + 20 * std::abs(r.cfg.servo_gain_error);
  EXPECT_GT(max_lag, 0.5);
  EXPECT_LT(max_lag, lag_bound);
  EXPECT_GT(stuck, 1000);
  EXPECT_GT(slipping, 100);
  // How much of the time it slips follows from the physics: the shaft only moves while slipping,
  // at the rate limit, so over the run it moves for its travel / rate, plus at most one partial
  // step per slip. Its travel is the demand's (through the pulse calibration's gain error),
  // less up to a breakaway on both legs of each turning point and at either end.
  const double dt = 1.0 / r.cfg.physics_rate_hz;
  const auto& servo = r.cfg.pitch_servo;
  double demand_travel = 0.0, last_step = 0.0;
  int moving = 0, slips = 0, turns = 0;
  for (std::size_t k = 1; k < r.truth.size(); ++k) {
    const double d = r.truth[k].pitch_dem_deg - r.truth[k - 1].pitch_dem_deg;
    demand_travel += std::abs(d);
    if (d != 0.0) {
      turns += last_step * d < 0.0;
      last_step = d;
    }
    const bool moves = r.truth[k].pitch_deg != r.truth[k - 1].pitch_deg;
    moving += moves;
    slips += moves && (k < 2 || r.truth[k - 1].pitch_deg == r.truth[k - 2].pitch_deg);
  }
  const double travel = demand_travel * (1 + std::abs(r.cfg.servo_gain_error));
  const double b_max = servo.breakaway_deg * (1 + servo.breakaway_spread);
  const double step = servo.max_rate_deg_s * dt;
  std::printf(
      "RT3 pitch servo: moving %.1f %% of %zu steps in %d slips, demand travel %.0f deg, %d "
      "turns\n",
      100.0 * moving / (r.truth.size() - 1), r.truth.size() - 1, slips, demand_travel, turns);
  EXPECT_GE(moving,
            (demand_travel * (1 - std::abs(r.cfg.servo_gain_error)) - 2 * b_max * (turns + 1)) /
                step);
  EXPECT_LE(moving, (travel + 2 * b_max) / step + slips);
}

TEST(RigSim, CarriageSensorsSeeTheBeltAndGravity) {
  const RigSimConfig cfg;
  const Recorded r = record("RT1", cfg);
  const auto sensors = payloads<protocol::CarSensorsPayload>(r, BoardId::kCar);
  const double acc_bound = 5 * cfg.accel.sigma + cfg.accel.quantum + 0.5e-3 + 1.0 / 16384;
  const double tof_bound = 5 * cfg.tof.sigma + cfg.tof.quantum + 0.5e-3;
  for (const auto& [lf, p] : sensors) {
    const RigTruth& tr = r.seenAt(lf->sent_t_s);
    ASSERT_NEAR(p.acc_x_mg * 1e-3, tr.accel_C_g.x(), acc_bound);
    ASSERT_NEAR(p.acc_y_mg * 1e-3, tr.accel_C_g.y(), acc_bound);
    ASSERT_NEAR(p.acc_z_mg * 1e-3, tr.accel_C_g.z(), acc_bound);
    if (p.flags & protocol::CarSensorsPayload::kTofValid) {
      ASSERT_NEAR(p.tof_mm * 1e-3, cfg.tof.gain * tr.track_pos_m + cfg.tof.bias, tof_bound);
    }
  }
  // Level camera: gravity along optical -y.
  EXPECT_NEAR(r.truth.back().accel_C_g.y(), -1.0, 1e-6);
}

TEST(RigSim, LinksDelayFramesByTheirModelledLatency) {
  const RigSimConfig cfg;
  const Recorded r = record("RT1", cfg);
  double min_track = 1e9, max_track = 0, min_car = 1e9, max_car = 0;
  for (const SimLinkFrame& lf : r.log) {
    if (lf.outgoing) continue;
    const double d = lf.t_s - lf.sent_t_s;
    if (lf.board == BoardId::kTrack)
      min_track = std::min(min_track, d), max_track = std::max(max_track, d);
    if (lf.board == BoardId::kCar) min_car = std::min(min_car, d), max_car = std::max(max_car, d);
  }
  // Lower bound: the base latency; upper: base + jitter + spike + line time of a queue of frames
  // (at most a few frames of 32 bytes at 11.5 bytes/ms), rounded to the physics step.
  const double step = 1.0 / cfg.physics_rate_hz;
  EXPECT_GE(min_track, cfg.track_link.base_latency_s - 1e-9);
  EXPECT_LE(max_track, cfg.track_link.base_latency_s + cfg.track_link.jitter_s +
                           cfg.track_link.spike_extra_s + 0.010 + step);
  EXPECT_GE(min_car, cfg.car_link.base_latency_s - 1e-9);
  EXPECT_LE(max_car, cfg.car_link.base_latency_s + cfg.car_link.jitter_s +
                         cfg.car_link.spike_extra_s + 0.010 + step);
  EXPECT_GT(min_car, max_track);  // ZigBee is slower than USB serial
}

TEST(RigSim, SameSeedSameRunOtherSeedOtherNoise) {
  Scenario sc = loadScenario(kScenarios + "RT6.yaml");
  auto run = [](const Scenario& s) {
    RigSimulator sim(s);
    sim.advanceTo(3.0);
    std::vector<uint8_t> all;
    for (const auto& lf : sim.takeLinkLog())
      all.insert(all.end(), lf.bytes.begin(), lf.bytes.end());
    return all;
  };
  const auto a = run(sc), b = run(sc);
  EXPECT_EQ(a, b);
  sc.seed += 1;
  EXPECT_NE(run(sc), a);
}

TEST(RigSim, ExternalHostCommandsAreAcknowledgedAfterTheLinkDelay) {
  RigSimConfig cfg;
  cfg.scripted_host = false;
  RigSimulator sim(loadScenario(kScenarios + "RT1.yaml"), cfg);
  sim.advanceTo(0.1);
  (void)sim.takeHostBytes();  // stream frames so far
  const auto cmd = protocol::encodeCommand(BoardId::kTrack, MsgId::kVers, 42);
  const double t_sent = sim.now();
  sim.hostSend(BoardId::kTrack, cmd.data(), cmd.size());
  double t_ack = -1.0;
  while (t_ack < 0 && sim.now() < 1.0) {
    sim.advanceTo(sim.now() + 0.0005);
    for (const auto& lf : sim.takeHostBytes()) {
      protocol::StreamDecoder dec;
      for (const auto& ev : protocol::feed(dec, lf.bytes)) {
        protocol::Ack ack;
        if (protocol::decodePayload(ev.frame, ack) == protocol::DecodeError::kNone &&
            ack.acked_seq == 42 && ack.status == protocol::AckStatus::kDone)
          t_ack = lf.t_s;
      }
    }
  }
  ASSERT_GT(t_ack, 0.0);
  // Two USB hops, each at least the base latency.
  EXPECT_GE(t_ack - t_sent, 2 * cfg.track_link.base_latency_s - 1e-9);
  EXPECT_LT(t_ack - t_sent, 0.05);
}

TEST(RigSim, AutopilotRunsModeOneAfterTheHostsStartAndHidesItsAcks) {
  RigSimConfig cfg;
  cfg.scripted_host = false;
  RigSimulator sim(loadScenario(kScenarios + "RT2.yaml"), cfg);
  uint32_t seq = 1;
  auto send = [&](BoardId b, MsgId id) {
    const auto c = protocol::encodeCommand(b, id, seq++);
    sim.hostSend(b, c.data(), c.size());
  };
  send(BoardId::kTrack, MsgId::kInit);
  sim.advanceTo(2.0);  // homing 20 mm at 20 mm/s
  send(BoardId::kTrack, MsgId::kStart);
  sim.advanceTo(5.0);  // a quarter period (3 s) of the 1/12 Hz yaw sine after the start
  EXPECT_GT(sim.truth().track_pos_m, 0.2);            // ~95 mm/s for ~3 s
  EXPECT_GT(std::abs(sim.truth().yaw_dem_deg), 8.0);  // near the 10 deg crest
  bool own_ack_leaked = false;
  for (const auto& lf : sim.takeHostBytes()) {
    protocol::StreamDecoder dec;
    for (const auto& ev : protocol::feed(dec, lf.bytes)) {
      protocol::Ack ack;
      if (protocol::decodePayload(ev.frame, ack) == protocol::DecodeError::kNone &&
          ack.acked_seq >= seq)
        own_ack_leaked = true;
    }
  }
  EXPECT_FALSE(own_ack_leaked);
  EXPECT_GE(sim.framesTaken(), 149);  // camera at 30 Hz throughout the 5 s
}

TEST(RigSim, TruckCirclesTwiceAtFullLockAndReportsItsCalibratedSpeed) {
  const RigSimConfig cfg;
  const Recorded r = record("Room3", cfg);
  ASSERT_TRUE(r.finished && !r.failed);
  const TruckModel model(cfg.truck);
  // Total heading change: two full anti-clockwise turns and a bit.
  double turned = 0.0;
  for (std::size_t k = 1; k < r.truth.size(); ++k)
    turned +=
        std::remainder(r.truth[k].truck.heading_rad - r.truth[k - 1].truck.heading_rad, 2 * M_PI);
  EXPECT_GT(turned, 2 * 2 * M_PI);
  EXPECT_LT(turned, 2.5 * 2 * M_PI);
  const auto rc = payloads<protocol::TruckRcPayload>(r, BoardId::kTruck);
  ASSERT_NEAR(static_cast<double>(rc.size()), r.truth.back().t_s * 30.0, 2.0);
  // One sample of the RC pulse jitter (+-2 us over the 480 us stick travel past the deadband)
  // through the steepest part of the speed curve; the plant averages it out in its lag.
  const protocol::TruckDrvConfig board = protocol::TruckDrvConfig::defaults();
  const double jitter_mps = (1 + cfg.truck.speed_scale_error) * maxSlope(board.speed_curve) * 2.0 /
                            (board.half_range_us - board.deadband_us);
  int steady = 0;
  for (const auto& [lf, p] : rc) {
    const RigTruth& tr = r.seenAt(lf->sent_t_s);
    if (lf->sent_t_s < 3.0 || lf->sent_t_s > 20.0) continue;  // after the lags settled (tau 0.35 s)
    ++steady;
    // On the circle of the full-lock radius about the room centre (the start was put there).
    EXPECT_NEAR(std::hypot(tr.truck.x_m, tr.truck.y_m), model.minTurnRadius(), 0.01);
    // TruckDRV's speed estimate (curve of fig. 5.42) misses the plant's calibration error only,
    // plus the 1 mm/s wire resolution and the receiver's 2 us pulse jitter through the curve.
    EXPECT_TRUE(p.flags & protocol::TruckRcPayload::kRunning);
    EXPECT_NEAR(tr.truck.speed_mps, p.speed_mm_s * 1e-3 * (1 + cfg.truck.speed_scale_error),
                jitter_mps + 0.002);
  }
  EXPECT_GT(steady, 400);
}

TEST(RigSim, BadConfigIsRejectedNamingTheField) {
  RigSimConfig cfg;
  cfg.physics_rate_hz = 10;
  cfg.pitch_sensor_gain_error = 0.5;
  try {
    RigSimulator sim(loadScenario(kScenarios + "RT1.yaml"), cfg);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("physics_rate_hz"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("pitch_sensor_gain_error"), std::string::npos);
  }
}

}  // namespace
}  // namespace rig_drivers
