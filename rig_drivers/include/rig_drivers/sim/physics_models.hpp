#pragma once
// Physical and sensor models the rig simulator runs around the portable firmware: the carriage on
// its elastic drive belt (the ~9 Hz longitudinal vibration of thesis fig. 5.23), friction-bound
// gimbal servos with stick-slip and lag behind demand (figs. B4/B5), sensor noise with 10-bit ADC
// quantisation and calibration error, and serial/ZigBee link latency with jitter (appendix A3.1).
// Everything is deterministic for a given seed (own normal generator on top of std::mt19937_64,
// whose output sequence the C++ standard fixes). Host-only (uses <random>, <string>, <deque>).
// Not thread-safe: one owner per model instance.

#include <cstddef>
#include <cstdint>
#include <deque>
#include <random>
#include <string>
#include <vector>

namespace rig_drivers {
namespace protocol {

/// Deterministic random source: same seed -> same sequence on every platform.
class Rng {
 public:
  explicit Rng(uint64_t seed = 1) : gen_(seed) {}
  /// Uniform in [0, 1).
  double uniform() { return static_cast<double>(gen_() >> 11) * (1.0 / 9007199254740992.0); }
  /// Uniform in [a, b).
  double uniform(double a, double b) { return a + (b - a) * uniform(); }
  /// Standard normal (Box-Muller, both values used).
  double normal();
  /// Normal with mean and standard deviation.
  double normal(double mean, double sigma) { return mean + sigma * normal(); }

 private:
  std::mt19937_64 gen_;
  bool have_spare_ = false;
  double spare_ = 0.0;
};

// ---- carriage on an elastic belt ----------------------------------------------------------------

struct BeltCarriageConfig {
  double natural_freq_hz = 9.0;  ///< undamped longitudinal mode of carriage mass on belt (Hz)
  double damping_ratio = 0.06;   ///< viscous damping ratio of the belt mode (1)
  double max_substep_s = 2e-4;   ///< integration substep (s); << 1/(2 pi f)
  std::string validate() const;  ///< every problem at once, "" when valid
};

/// Carriage position x_c driven through a spring-damper belt by the motor pulley position x_m:
///   x_c'' = w^2 (x_m - x_c) + 2 zeta w (v_m - v_c),  w = 2 pi f_n.
/// The motor side follows the stepper exactly (steps are stiff), the carriage lags and rings.
class BeltCarriageModel {
 public:
  /// Throws std::invalid_argument naming every bad field.
  explicit BeltCarriageModel(const BeltCarriageConfig& config = BeltCarriageConfig());
  /// Puts carriage and motor at rest at x (m).
  void reset(double x_m);
  /// Advances by dt (s) while the motor position moves linearly to motor_x_m (m) over dt.
  void advance(double dt, double motor_x_m);
  double position() const { return x_; }      ///< carriage position (m)
  double velocity() const { return v_; }      ///< carriage velocity (m/s)
  double acceleration() const { return a_; }  ///< carriage acceleration (m/s^2), for AccZ
  double motorPosition() const { return xm_; }
  const BeltCarriageConfig& config() const { return config_; }

 private:
  double accel(double x, double v, double xm, double vm) const;
  BeltCarriageConfig config_;
  double w_ = 0, x_ = 0, v_ = 0, a_ = 0, xm_ = 0;
};

// ---- friction-bound RC servo
// -------------------------------------------------------------------------

struct ServoModelConfig {
  double lag_s = 0.08;            ///< first-order lag of the servo's internal loop (s)
  double max_rate_deg_s = 120.0;  ///< slew rate limit of the output (deg/s)
  double breakaway_deg = 0.6;     ///< static friction: drive error needed to unstick (deg)
  double breakaway_spread = 0.3;  ///< relative random spread of the breakaway per stick (1)
  double kinetic_deg = 0.15;      ///< once slipping, it moves until the error falls below (deg)
  double max_substep_s = 1e-3;    ///< integration substep (s)
  std::string validate() const;
};

/// Gimbal axis: demand -> servo internal set point with first-order lag -> output shaft that sticks
/// (static friction) until the set point is breakaway_deg away, then slips towards it at the rate
/// limit until within kinetic_deg. This gives the stop-start (stick-slip) response and the lag of
/// figs. B4/B5 at slow sine demands.
class ServoModel {
 public:
  ServoModel(const ServoModelConfig& config, uint64_t seed);
  void reset(double angle_deg);
  /// Advances by dt (s) with demand_deg held.
  void advance(double dt, double demand_deg);
  double angle() const { return angle_; }         ///< true shaft angle (deg)
  double setPoint() const { return set_point_; }  ///< internal lagged set point (deg)
  bool stuck() const { return stuck_; }
  uint32_t stickEvents() const { return stick_events_; }

 private:
  void newBreakaway();
  ServoModelConfig config_;
  Rng rng_;
  double angle_ = 0, set_point_ = 0, breakaway_ = 0;
  bool stuck_ = true;
  uint32_t stick_events_ = 0;
};

// ---- sensors
// --------------------------------------------------------------------------------------------

struct SensorNoiseConfig {
  double gain = 1.0;          ///< calibration (scale) error: reading = gain * true + bias (1)
  double bias = 0.0;          ///< calibration offset error (sensor unit)
  double sigma = 0.0;         ///< white noise standard deviation (sensor unit)
  double quantum = 0.0;       ///< output resolution (sensor unit, 0 = continuous)
  double min_value = -1e300;  ///< saturation (sensor unit)
  double max_value = 1e300;
  std::string validate() const;
};

/// Scalar sensor: reading = quantise(clamp(gain * true + bias + N(0, sigma))).
class NoisySensor {
 public:
  NoisySensor(const SensorNoiseConfig& config, uint64_t seed);
  double read(double true_value);
  const SensorNoiseConfig& config() const { return config_; }

 private:
  SensorNoiseConfig config_;
  Rng rng_;
};

struct AdcConfig {
  double vref = 5.0;             ///< ADC reference (V)
  int bits = 10;                 ///< Arduino Mega ADC resolution
  double noise_sigma_v = 0.003;  ///< analogue noise before conversion (V)
  double gain = 1.0;             ///< front-end gain error (1)
  double offset_v = 0.0;         ///< front-end offset error (V)
  std::string validate() const;
};

/// Analogue input: volts -> noisy, clamped, quantised ADC counts (0 .. 2^bits - 1).
class AdcModel {
 public:
  AdcModel(const AdcConfig& config, uint64_t seed);
  /// Counts read for the input voltage v (V).
  int read(double volts);
  /// Volts at the middle of a count's interval, (count + 0.5) * vref / 2^bits (unbiased).
  double countsToVolts(int counts) const;
  double lsbVolts() const { return config_.vref / (1 << config_.bits); }
  const AdcConfig& config() const { return config_; }

 private:
  AdcConfig config_;
  Rng rng_;
};

// ---- serial links
// -------------------------------------------------------------------------------------

struct LinkConfig {
  double base_latency_s = 0.002;  ///< minimum one-way delay (s)
  double jitter_s = 0.002;        ///< extra delay uniform in [0, jitter] (s)
  double spike_prob = 0.01;       ///< probability of a delay spike per chunk (1)
  double spike_extra_s = 0.004;   ///< spike adds uniform [0, spike_extra] (s)
  double baud = 115200;           ///< line rate (bit/s), 10 bits per byte (8N1)
  double drop_prob = 0.0;         ///< probability a chunk is lost (1)
  double bit_error_rate = 0.0;    ///< probability each bit arrives flipped (1); 0 = clean line
  std::string validate() const;
  /// USB serial to an Arduino: one-way 2-4 ms with rare spikes to ~8 ms (thesis fig. A4).
  static LinkConfig usbSerial();
  /// XBee ZigBee pair: one-way 15-25 ms (thesis fig. A8).
  static LinkConfig zigbee();
};

/// One-directional byte link with latency, jitter and line rate. Order is preserved (a serial link
/// is FIFO): a chunk never arrives before the one sent ahead of it, nor faster than the baud rate.
class LinkModel {
 public:
  LinkModel(const LinkConfig& config, uint64_t seed);
  /// Queues bytes sent at time t (s); returns their arrival time (s), or -1 if dropped.
  double send(double t, const uint8_t* data, size_t n);
  double send(double t, const std::vector<uint8_t>& bytes) {
    return send(t, bytes.data(), bytes.size());
  }
  /// Bytes that have arrived by time t (s), in order, removed from the queue.
  std::vector<uint8_t> receive(double t);
  /// Arrival time of the next pending chunk (s), or -1 when empty.
  double nextArrival() const;
  size_t pendingBytes() const;

 private:
  struct Chunk {
    double arrival;
    std::vector<uint8_t> bytes;
  };
  LinkConfig config_;
  Rng rng_;
  std::deque<Chunk> queue_;
  double last_arrival_ = -1e300;
};

}  // namespace protocol
}  // namespace rig_drivers
