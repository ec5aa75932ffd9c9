#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numeric>
#include <vector>

#include "rig_drivers/protocol/codec.hpp"
#include "rig_drivers/sim/physics_models.hpp"

namespace rp = rig_drivers::protocol;

namespace {
constexpr double kPi = 3.14159265358979323846;

struct Stats {
  double mean = 0, sd = 0;
};
Stats stats(const std::vector<double>& v) {
  Stats s;
  for (double x : v) s.mean += x;
  s.mean /= v.size();
  for (double x : v) s.sd += (x - s.mean) * (x - s.mean);
  s.sd = std::sqrt(s.sd / (v.size() - 1));
  return s;
}

// Times (s) of upward zero crossings of a sampled signal, linearly interpolated.
std::vector<double> upCrossings(const std::vector<double>& y, double dt, size_t from) {
  std::vector<double> t;
  for (size_t i = from + 1; i < y.size(); ++i)
    if (y[i - 1] < 0 && y[i] >= 0) t.push_back((i - 1 + y[i - 1] / (y[i - 1] - y[i])) * dt);
  return t;
}
}  // namespace

TEST(BeltCarriage, RingsAtTheBeltFrequencyWithItsDamping) {
  rp::BeltCarriageConfig c;  // 9 Hz, zeta 0.06 (thesis fig. 5.23: ~9 Hz longitudinal)
  rp::BeltCarriageModel belt(c);
  belt.reset(0.0);
  const double dt = 1e-3;
  // Motor runs at 0.1 m/s for 1 s, then stops dead (a stepper at the end of a step).
  double xm = 0;
  std::vector<double> rel, acc;
  for (int i = 0; i < 3000; ++i) {
    if (i < 1000) xm += 0.1 * dt;
    belt.advance(dt, xm);
    rel.push_back(belt.position() - belt.motorPosition());
    acc.push_back(belt.acceleration());
  }
  // Frequency from the acceleration signal after the stop (what the MPU6050 would see).
  const auto t = upCrossings(acc, dt, 1000);
  ASSERT_GE(t.size(), 10u);
  const double f = (t.size() - 1) / (t.back() - t.front());
  const double fd = 9.0 * std::sqrt(1 - 0.06 * 0.06);  // damped natural frequency
  // Zero-crossing interpolation at 1 kHz on a 9 Hz signal: error far below 0.02 Hz.
  EXPECT_NEAR(f, fd, 0.02);
  // Log decrement of the relative displacement peaks: delta = 2 pi zeta / sqrt(1 - zeta^2).
  std::vector<double> peaks;
  for (size_t i = 1001; i + 1 < rel.size(); ++i)
    if (rel[i] > rel[i - 1] && rel[i] >= rel[i + 1] && rel[i] > 0) peaks.push_back(rel[i]);
  ASSERT_GE(peaks.size(), 5u);
  const double delta = std::log(peaks[0] / peaks[4]) / 4;
  EXPECT_NEAR(delta, 2 * kPi * 0.06 / std::sqrt(1 - 0.06 * 0.06), 0.01);
  // First overshoot: a carriage at v hitting a stopped motor swings by about v / w.
  EXPECT_NEAR(peaks[0], 0.1 / (2 * kPi * 9.0) * std::exp(-0.06 * kPi / 2), 0.1 * peaks[0]);
  // At rest again after the ringing has decayed (20 time constants 1/(zeta w))
  EXPECT_LT(std::fabs(rel.back()), 1e-6);
}

TEST(BeltCarriage, LagsByAOverOmegaSquaredUnderConstantAcceleration) {
  rp::BeltCarriageModel belt;
  belt.reset(0.2);
  const double a = 0.4, dt = 1e-3, w = 2 * kPi * 9.0;
  double xm = 0.2, vm = 0;
  for (int i = 0; i < 3000; ++i) {  // 3 s of constant acceleration: 10 decay times 1/(zeta w)
    xm += vm * dt + 0.5 * a * dt * dt;
    vm += a * dt;
    belt.advance(dt, xm);
  }
  EXPECT_NEAR(belt.motorPosition() - belt.position(), a / (w * w), 0.03 * a / (w * w));
  EXPECT_NEAR(belt.acceleration(), a, 0.03 * a);
}

TEST(BeltCarriage, RejectsBadConfig) {
  rp::BeltCarriageConfig c;
  c.natural_freq_hz = -1;
  c.damping_ratio = 1.5;
  const auto e = c.validate();
  EXPECT_NE(e.find("natural_freq_hz"), std::string::npos);
  EXPECT_NE(e.find("damping_ratio"), std::string::npos);
  EXPECT_THROW(rp::BeltCarriageModel m(c), std::invalid_argument);
}

TEST(ServoModel, SlowSineShowsStickSlipAndLag) {
  // Figs. B4/B5: 20 deg sine at 0.5 rad/s.
  rp::ServoModelConfig c;
  rp::ServoModel servo(c, 42);
  servo.reset(0);
  const double dt = 1e-3, w = 0.5, amp = 20;
  const int n = static_cast<int>(2 * 2 * kPi / w / dt);  // two periods
  std::vector<double> dem(n), ang(n);
  int stuck_samples = 0;
  double max_err_sp = 0;
  for (int i = 0; i < n; ++i) {
    const double t = (i + 1) * dt;
    dem[i] = amp * std::sin(w * t);
    const double before = servo.angle();
    servo.advance(dt, dem[i]);
    ang[i] = servo.angle();
    stuck_samples += ang[i] == before;
    max_err_sp = std::max(max_err_sp, std::fabs(servo.setPoint() - servo.angle()));
  }
  // Stick-slip: the shaft only moves while slipping, at the 120 deg/s rate limit, so it moves
  // for its travel / rate, plus at most one partial substep per slip; the rest of the time it
  // is still. Its travel is the demand's 4 x 40 deg (two periods) less what friction and lag
  // leave out: each of the 4 turning points is reached short by up to a breakaway (two legs
  // each), and at the end the shaft trails by the lag bound asserted below times the demand
  // rate, plus a breakaway. Docs/rigs.md: "stuck 95 % of the time (~300 stick-slip events)".
  const double travel = 4 * 2 * amp, b_max = c.breakaway_deg * (1 + c.breakaway_spread);
  const double lag_max = c.lag_s + b_max / (2 / kPi * amp * w);
  const double shortfall = 8 * b_max + amp * w * lag_max + b_max;
  const double moving_min = (travel - shortfall) / (c.max_rate_deg_s * dt);
  const double moving_max = (travel + b_max) / (c.max_rate_deg_s * dt) + servo.stickEvents();
  std::printf("servo on the B4/B5 sine: stuck %.1f %% of the time, %u stick-slip events\n",
              100.0 * stuck_samples / n, servo.stickEvents());
  EXPECT_LE(stuck_samples, n - moving_min);
  EXPECT_GE(stuck_samples, n - moving_max);
  // Travel 4 x 40 deg in steps between kinetic and breakaway (0.15 .. 0.6 deg, +-30 %).
  EXPECT_GT(servo.stickEvents(), 160.0 / (c.breakaway_deg * (1 + c.breakaway_spread)));
  EXPECT_LT(servo.stickEvents(),
            160.0 / (c.breakaway_deg * (1 - c.breakaway_spread) - c.kinetic_deg) + 10);
  // Never further from the internal set point than the largest breakaway plus one substep.
  EXPECT_LE(max_err_sp, c.breakaway_deg * (1 + c.breakaway_spread) + c.max_rate_deg_s * dt);
  // Lag behind demand: best cross-correlation shift is at least the servo lag and at most the lag
  // plus the time the largest breakaway takes at the mean demand rate (2/pi * amp * w).
  double best = -1e300;
  int best_k = 0;
  for (int k = 0; k < 600; ++k) {
    double s = 0;
    for (int i = k; i < n; ++i) s += dem[i - k] * ang[i];
    if (s > best) {
      best = s;
      best_k = k;
    }
  }
  const double lag = best_k * dt;
  std::printf("servo lag behind the demand (best cross-correlation shift): %.3f s\n", lag);
  EXPECT_GE(lag, c.lag_s * 0.9);
  EXPECT_LE(lag, lag_max);
}

TEST(ServoModel, StepStopsWithinTheFrictionBand) {
  rp::ServoModelConfig c;
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    rp::ServoModel servo(c, seed);
    servo.reset(0);
    for (int i = 0; i < 2000; ++i) servo.advance(1e-3, 10.0);
    EXPECT_TRUE(servo.stuck());
    // friction-bound steady-state error, never more than the breakaway (no position feedback)
    EXPECT_LE(std::fabs(servo.angle() - 10.0), c.breakaway_deg * (1 + c.breakaway_spread));
  }
  // Deterministic for a seed
  rp::ServoModel a(c, 7), b(c, 7);
  a.reset(0);
  b.reset(0);
  for (int i = 0; i < 3000; ++i) {
    const double d = 15 * std::sin(i * 1e-3);
    a.advance(1e-3, d);
    b.advance(1e-3, d);
  }
  EXPECT_EQ(a.angle(), b.angle());
}

TEST(NoisySensor, ErrorStatisticsMatchTheConfiguration) {
  rp::SensorNoiseConfig c;
  c.gain = 1.02;
  c.bias = 0.1;
  c.sigma = 0.5;
  rp::NoisySensor s(c, 3);
  const int n = 20000;
  std::vector<double> err;
  for (int i = 0; i < n; ++i) err.push_back(s.read(10.0) - 10.0);
  const auto st = stats(err);
  // mean: 5 standard errors sigma/sqrt(n); sd: 5 standard errors sigma/sqrt(2n)
  EXPECT_NEAR(st.mean, 0.02 * 10.0 + 0.1, 5 * c.sigma / std::sqrt(n));
  EXPECT_NEAR(st.sd, c.sigma, 5 * c.sigma / std::sqrt(2.0 * n));

  // Quantised to q with sigma = q: variance sigma^2 + q^2/12 (Sheppard), values on the grid.
  c.gain = 1;
  c.bias = 0;
  c.sigma = 1.0;
  c.quantum = 1.0;
  rp::NoisySensor q(c, 4);
  err.clear();
  for (int i = 0; i < n; ++i) {
    const double r = q.read(0.3);
    EXPECT_EQ(r, std::round(r));
    err.push_back(r - 0.3);
  }
  const auto sq = stats(err);
  const double sd = std::sqrt(1.0 + 1.0 / 12);
  EXPECT_NEAR(sq.mean, 0.0, 5 * sd / std::sqrt(n));
  EXPECT_NEAR(sq.sd, sd, 5 * sd / std::sqrt(2.0 * n));
}

TEST(AdcModel, TenBitQuantisationAndNoise) {
  rp::AdcConfig c;
  c.noise_sigma_v = 0;
  rp::AdcModel adc(c, 1);
  const double lsb = 5.0 / 1024;
  EXPECT_DOUBLE_EQ(adc.lsbVolts(), lsb);
  double max_err = 0;
  for (double v = 0.0; v < 5.0 - lsb; v += 0.000731) {
    const int counts = adc.read(v);
    ASSERT_GE(counts, 0);
    ASSERT_LE(counts, 1023);
    max_err = std::max(max_err, std::fabs(adc.countsToVolts(counts) - v));
  }
  EXPECT_LE(max_err, lsb / 2 + 1e-12);  // uniform quantisation error of a noise-free ADC
  EXPECT_GT(max_err, 0.45 * lsb);
  EXPECT_EQ(adc.read(-1.0), 0);
  EXPECT_EQ(adc.read(7.0), 1023);

  c.noise_sigma_v = 0.005;  // ~1 LSB of analogue noise
  rp::AdcModel noisy(c, 9);
  const int n = 20000;
  std::vector<double> err;
  for (int i = 0; i < n; ++i) err.push_back(noisy.countsToVolts(noisy.read(2.5013)) - 2.5013);
  const auto st = stats(err);
  const double sd = std::sqrt(c.noise_sigma_v * c.noise_sigma_v + lsb * lsb / 12);
  EXPECT_NEAR(st.mean, 0.0, 5 * sd / std::sqrt(n));
  EXPECT_NEAR(st.sd, sd, 5 * sd / std::sqrt(2.0 * n) + 0.01 * sd);
}

TEST(LinkModel, UsbSerialLatencyWithinTwoToFourMsPlusSpikes) {
  const auto c = rp::LinkConfig::usbSerial();
  rp::LinkModel link(c, 5);
  const std::vector<uint8_t> pkt(19, 0x55);  // the thesis's 19-byte timer packet
  const double wire = 19 * 10 / 115200.0;    // 1.65 ms on the line
  std::vector<double> lat;
  double prev = -1;
  for (int i = 0; i < 5000; ++i) {
    const double t = i / 30.0;
    const double arr = link.send(t, pkt);
    ASSERT_GE(arr, prev);
    prev = arr;
    lat.push_back(arr - t);
    const auto got = link.receive(arr);
    ASSERT_EQ(got.size(), 19u);
  }
  const auto st = stats(lat);
  double lo = 1e9, hi = 0;
  for (double l : lat) lo = std::min(lo, l), hi = std::max(hi, l);
  EXPECT_GE(lo, c.base_latency_s + wire - 1e-12);
  EXPECT_LE(hi, c.base_latency_s + c.jitter_s + c.spike_extra_s + wire + 1e-12);
  // mean = base + jitter/2 + p * spike/2 + wire; sd of the sum < 1 ms -> 5 sigma/sqrt(n) bound
  const double mean = c.base_latency_s + c.jitter_s / 2 + c.spike_prob * c.spike_extra_s / 2 + wire;
  EXPECT_NEAR(st.mean, mean, 5 * 1e-3 / std::sqrt(5000.0));
  EXPECT_GT(hi, c.base_latency_s + c.jitter_s + wire);  // some spikes occurred
}

TEST(LinkModel, ZigbeeLatencyAndFifoAtLineRate) {
  const auto c = rp::LinkConfig::zigbee();
  rp::LinkModel link(c, 6);
  std::vector<uint8_t> frame(33);
  for (size_t i = 0; i < frame.size(); ++i) frame[i] = static_cast<uint8_t>(i);
  // 100 frames sent in one instant: they leave one after another at 115200 baud.
  double last = 0;
  for (int i = 0; i < 100; ++i) last = link.send(1.0, frame);
  EXPECT_GE(last - 1.0, c.base_latency_s + 100 * 33 * 10 / 115200.0 - 1e-9);
  const auto all = link.receive(last);
  ASSERT_EQ(all.size(), 3300u);
  for (size_t i = 0; i < all.size(); ++i) ASSERT_EQ(all[i], i % 33);
  EXPECT_EQ(link.pendingBytes(), 0u);
  // single frames: one-way delay 15 .. 25 ms plus the line time
  rp::LinkModel z(c, 7);
  for (int i = 0; i < 1000; ++i) {
    const double t = 10.0 + i * 0.1;
    const double d = z.send(t, frame) - t;
    EXPECT_GE(d, 0.015);
    EXPECT_LE(d, 0.025 + 33 * 10 / 115200.0 + 1e-12);
  }
  // same seed -> same arrivals
  rp::LinkModel a(c, 11), b(c, 11);
  for (int i = 0; i < 50; ++i) EXPECT_EQ(a.send(i * 0.03, frame), b.send(i * 0.03, frame));
}

TEST(LinkModel, RejectsBadConfig) {
  rp::LinkConfig c;
  c.baud = 0;
  c.drop_prob = 2;
  const auto e = c.validate();
  EXPECT_NE(e.find("baud"), std::string::npos);
  EXPECT_NE(e.find("drop_prob"), std::string::npos);
  EXPECT_THROW(rp::LinkModel(c, 1), std::invalid_argument);
}

TEST(LinkModel, BitErrorsCostTheExpectedFramesAndNeverForgeOne) {
  // 33-byte CarSensors frames over a line with bit error rate 1e-4: a frame survives with
  // probability (1 - 1e-4)^264 = 0.974 (a byte with two flipped bits is counted once, the model
  // flips one bit per corrupted byte: survival (1 - p_byte)^33 with p_byte = 1 - (1 - ber)^8).
  auto c = rp::LinkConfig::usbSerial();
  c.bit_error_rate = 1e-4;
  rp::LinkModel link(c, 21);
  const int n = 5000;
  std::vector<std::vector<uint8_t>> sent;
  double t = 0;
  for (int i = 0; i < n; ++i) {
    rp::CarSensorsPayload s;
    s.board_time_ms = static_cast<uint32_t>(i * 33);
    s.pitch_cdeg = static_cast<int16_t>(i);
    s.tof_mm = static_cast<uint16_t>(i * 3);
    sent.push_back(rp::encodeMessage(rp::BoardId::kCar, static_cast<uint32_t>(i), s));
    t = i / 30.0;
    link.send(t, sent.back());
  }
  const auto bytes = link.receive(t + 1.0);
  ASSERT_EQ(bytes.size(), static_cast<size_t>(n) * 33);
  rp::StreamDecoder dec;
  int good = 0;
  for (const auto& e : rp::feed(dec, bytes)) {
    if (e.error != rp::DecodeError::kNone) continue;
    ++good;
    ASSERT_LT(e.frame.seq, static_cast<uint32_t>(n));
    EXPECT_EQ(rp::frameBytes(e.frame), sent[e.frame.seq]);  // never a corrupted frame passed
  }
  const double p = std::pow(1.0 - (1.0 - std::pow(1.0 - 1e-4, 8)), 33);
  const double sd = std::sqrt(n * p * (1 - p));
  EXPECT_NEAR(good, n * p, 5 * sd);
  EXPECT_LT(good, n);  // the line did corrupt some
}
