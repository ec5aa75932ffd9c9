#include "rig_drivers/sim/physics_models.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace rig_drivers {
namespace protocol {

namespace {

std::string trimmed(const std::ostringstream& e) {
  std::string s = e.str();
  if (s.size() >= 2) s.resize(s.size() - 2);
  return s;
}
bool finite(double v) { return std::isfinite(v); }
void requirePositive(std::ostringstream& e, const char* name, double v) {
  if (!(v > 0) || !finite(v)) e << name << " must be > 0, got " << v << "; ";
}
void requireNonNegative(std::ostringstream& e, const char* name, double v) {
  if (!(v >= 0) || !finite(v)) e << name << " must be >= 0, got " << v << "; ";
}
void requireProbability(std::ostringstream& e, const char* name, double v) {
  if (!(v >= 0 && v <= 1)) e << name << " must be in [0, 1], got " << v << "; ";
}
template <class C>
const C& checked(const C& c, const char* what) {
  const std::string err = c.validate();
  if (!err.empty()) throw std::invalid_argument(std::string(what) + ": " + err);
  return c;
}
}  // namespace

double Rng::normal() {
  if (have_spare_) {
    have_spare_ = false;
    return spare_;
  }
  double u1 = uniform();
  while (u1 <= 0.0) u1 = uniform();
  const double u2 = uniform();
  const double r = std::sqrt(-2.0 * std::log(u1));
  spare_ = r * std::sin(2 * M_PI * u2);
  have_spare_ = true;
  return r * std::cos(2 * M_PI * u2);
}

// ---- belt
// ------------------------------------------------------------------------------------------------

std::string BeltCarriageConfig::validate() const {
  std::ostringstream e;
  requirePositive(e, "natural_freq_hz", natural_freq_hz);
  if (!(damping_ratio >= 0 && damping_ratio < 1))
    e << "damping_ratio must be in [0, 1) (an oscillating belt), got " << damping_ratio << "; ";
  requirePositive(e, "max_substep_s", max_substep_s);
  if (natural_freq_hz > 0 && max_substep_s * natural_freq_hz > 0.02)
    e << "max_substep_s must be <= 0.02 / natural_freq_hz for an accurate integration, got "
      << max_substep_s << "; ";
  return trimmed(e);
}

BeltCarriageModel::BeltCarriageModel(const BeltCarriageConfig& config)
    : config_(checked(config, "BeltCarriageConfig")), w_(2 * M_PI * config.natural_freq_hz) {}

void BeltCarriageModel::reset(double x_m) {
  x_ = x_m;
  xm_ = x_m;
  v_ = 0;
  a_ = 0;
}

double BeltCarriageModel::accel(double x, double v, double xm, double vm) const {
  return w_ * w_ * (xm - x) + 2 * config_.damping_ratio * w_ * (vm - v);
}

void BeltCarriageModel::advance(double dt, double motor_x_m) {
  if (!(dt > 0)) return;
  const int n = std::max(1, static_cast<int>(std::ceil(dt / config_.max_substep_s)));
  const double h = dt / n;
  const double x0m = xm_;
  const double vm = (motor_x_m - x0m) / dt;
  for (int i = 0; i < n; ++i) {
    const double t0 = i * h;
    auto xmAt = [&](double t) { return x0m + vm * t; };
    // RK4 on (x, v)
    const double k1x = v_, k1v = accel(x_, v_, xmAt(t0), vm);
    const double k2x = v_ + 0.5 * h * k1v,
                 k2v = accel(x_ + 0.5 * h * k1x, k2x, xmAt(t0 + 0.5 * h), vm);
    const double k3x = v_ + 0.5 * h * k2v,
                 k3v = accel(x_ + 0.5 * h * k2x, k3x, xmAt(t0 + 0.5 * h), vm);
    const double k4x = v_ + h * k3v, k4v = accel(x_ + h * k3x, k4x, xmAt(t0 + h), vm);
    x_ += h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x);
    v_ += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v);
  }
  xm_ = motor_x_m;
  a_ = accel(x_, v_, xm_, vm);
}

// ---- servo
// ---------------------------------------------------------------------------------------------

std::string ServoModelConfig::validate() const {
  std::ostringstream e;
  requireNonNegative(e, "lag_s", lag_s);
  requirePositive(e, "max_rate_deg_s", max_rate_deg_s);
  requireNonNegative(e, "breakaway_deg", breakaway_deg);
  if (!(breakaway_spread >= 0 && breakaway_spread < 1))
    e << "breakaway_spread must be in [0, 1), got " << breakaway_spread << "; ";
  requireNonNegative(e, "kinetic_deg", kinetic_deg);
  if (kinetic_deg > breakaway_deg * (1 - breakaway_spread))
    e << "kinetic_deg (" << kinetic_deg
      << ") must not exceed the smallest breakaway, breakaway_deg * (1 - breakaway_spread); ";
  requirePositive(e, "max_substep_s", max_substep_s);
  return trimmed(e);
}

ServoModel::ServoModel(const ServoModelConfig& config, uint64_t seed)
    : config_(checked(config, "ServoModelConfig")), rng_(seed) {
  newBreakaway();
}

void ServoModel::newBreakaway() {
  breakaway_ = config_.breakaway_deg * (1 + config_.breakaway_spread * (2 * rng_.uniform() - 1));
}

void ServoModel::reset(double angle_deg) {
  angle_ = angle_deg;
  set_point_ = angle_deg;
  stuck_ = true;
}

void ServoModel::advance(double dt, double demand_deg) {
  if (!(dt > 0)) return;
  const int n = std::max(1, static_cast<int>(std::ceil(dt / config_.max_substep_s)));
  const double h = dt / n;
  const double alpha = config_.lag_s > 0 ? 1 - std::exp(-h / config_.lag_s) : 1.0;
  for (int i = 0; i < n; ++i) {
    set_point_ += (demand_deg - set_point_) * alpha;
    double err = set_point_ - angle_;
    if (stuck_ && std::fabs(err) > breakaway_) stuck_ = false;
    if (!stuck_) {
      const double max_move = config_.max_rate_deg_s * h;
      angle_ += std::clamp(err, -max_move, max_move);
      err = set_point_ - angle_;
      if (std::fabs(err) <= config_.kinetic_deg) {
        stuck_ = true;
        ++stick_events_;
        newBreakaway();
      }
    }
  }
}

// ---- sensors
// -------------------------------------------------------------------------------------------

std::string SensorNoiseConfig::validate() const {
  std::ostringstream e;
  if (!finite(gain) || gain == 0) e << "gain must be finite and non-zero, got " << gain << "; ";
  if (!finite(bias)) e << "bias must be finite, got " << bias << "; ";
  requireNonNegative(e, "sigma", sigma);
  requireNonNegative(e, "quantum", quantum);
  if (!(min_value < max_value)) e << "min_value must be < max_value; ";
  return trimmed(e);
}

NoisySensor::NoisySensor(const SensorNoiseConfig& config, uint64_t seed)
    : config_(checked(config, "SensorNoiseConfig")), rng_(seed) {}

double NoisySensor::read(double true_value) {
  double v = config_.gain * true_value + config_.bias;
  if (config_.sigma > 0) v += config_.sigma * rng_.normal();
  v = std::clamp(v, config_.min_value, config_.max_value);
  if (config_.quantum > 0) v = std::round(v / config_.quantum) * config_.quantum;
  return v;
}

std::string AdcConfig::validate() const {
  std::ostringstream e;
  requirePositive(e, "vref", vref);
  if (bits < 1 || bits > 16) e << "bits must be in [1, 16], got " << bits << "; ";
  requireNonNegative(e, "noise_sigma_v", noise_sigma_v);
  if (!finite(gain) || !(gain > 0)) e << "gain must be > 0, got " << gain << "; ";
  if (!finite(offset_v)) e << "offset_v must be finite; ";
  return trimmed(e);
}

AdcModel::AdcModel(const AdcConfig& config, uint64_t seed)
    : config_(checked(config, "AdcConfig")), rng_(seed) {}

int AdcModel::read(double volts) {
  double v = config_.gain * volts + config_.offset_v;
  if (config_.noise_sigma_v > 0) v += config_.noise_sigma_v * rng_.normal();
  const int full = (1 << config_.bits) - 1;
  // Successive approximation truncates: count c covers [c, c+1) LSB.
  const double c = std::floor(v / lsbVolts());
  if (!(c > 0)) return 0;
  return c >= full ? full : static_cast<int>(c);
}

double AdcModel::countsToVolts(int counts) const { return (counts + 0.5) * lsbVolts(); }

// ---- links
// ---------------------------------------------------------------------------------------------

std::string LinkConfig::validate() const {
  std::ostringstream e;
  requireNonNegative(e, "base_latency_s", base_latency_s);
  requireNonNegative(e, "jitter_s", jitter_s);
  requireProbability(e, "spike_prob", spike_prob);
  requireNonNegative(e, "spike_extra_s", spike_extra_s);
  requirePositive(e, "baud", baud);
  requireProbability(e, "drop_prob", drop_prob);
  if (!(bit_error_rate >= 0 && bit_error_rate < 0.5))
    e << "bit_error_rate must be in [0, 0.5), got " << bit_error_rate << "; ";
  return trimmed(e);
}

LinkConfig LinkConfig::usbSerial() {
  LinkConfig c;
  c.base_latency_s = 0.002;
  c.jitter_s = 0.002;
  c.spike_prob = 0.01;
  c.spike_extra_s = 0.004;
  c.baud = 115200;
  return c;
}

LinkConfig LinkConfig::zigbee() {
  LinkConfig c;
  c.base_latency_s = 0.015;
  c.jitter_s = 0.010;
  c.spike_prob = 0.0;
  c.spike_extra_s = 0.0;
  c.baud = 115200;
  return c;
}

LinkModel::LinkModel(const LinkConfig& config, uint64_t seed)
    : config_(checked(config, "LinkConfig")), rng_(seed) {}

double LinkModel::send(double t, const uint8_t* data, size_t n) {
  // Draw every random number whether or not the chunk is dropped, so one setting does not shift
  // the random sequence of the others.
  const bool drop = rng_.uniform() < config_.drop_prob;
  double delay = config_.base_latency_s + config_.jitter_s * rng_.uniform();
  const bool spike = rng_.uniform() < config_.spike_prob;
  const double extra = config_.spike_extra_s * rng_.uniform();
  if (spike) delay += extra;
  if (drop || n == 0) return -1.0;
  const double wire = static_cast<double>(n) * 10.0 / config_.baud;
  const double arrival = std::max(t + delay + wire, last_arrival_ + wire);
  last_arrival_ = arrival;
  std::vector<uint8_t> bytes(data, data + n);
  if (config_.bit_error_rate > 0) {
    // Draws only when enabled, so a clean link keeps the random sequence it always had.
    const double p_byte = 1.0 - std::pow(1.0 - config_.bit_error_rate, 8);
    for (auto& b : bytes) {
      if (rng_.uniform() < p_byte)
        b ^= static_cast<uint8_t>(1u << static_cast<int>(rng_.uniform() * 8));
    }
  }
  queue_.push_back(Chunk{arrival, std::move(bytes)});
  return arrival;
}

std::vector<uint8_t> LinkModel::receive(double t) {
  std::vector<uint8_t> out;
  while (!queue_.empty() && queue_.front().arrival <= t) {
    out.insert(out.end(), queue_.front().bytes.begin(), queue_.front().bytes.end());
    queue_.pop_front();
  }
  return out;
}

double LinkModel::nextArrival() const { return queue_.empty() ? -1.0 : queue_.front().arrival; }

size_t LinkModel::pendingBytes() const {
  size_t n = 0;
  for (const auto& c : queue_) n += c.bytes.size();
  return n;
}

}  // namespace protocol
}  // namespace rig_drivers
