#include "depth_track/core/sim/imu.hpp"

#include <cmath>
#include <random>
#include <stdexcept>

#include "depth_track/core/se3.hpp"

namespace depth_track {
namespace sim {

ImuNoiseConfig ImuNoiseConfig::none() { return ImuNoiseConfig{}; }

ImuNoiseConfig ImuNoiseConfig::bmi055() {
  ImuNoiseConfig c;
  c.rate_hz = 200.0;
  const double deg = M_PI / 180.0;
  c.gyro_noise_rad_s = 0.014 * deg * std::sqrt(c.rate_hz);          // 0.0035 rad/s
  c.accel_noise_m_s2 = 150e-6 * 9.80665 * std::sqrt(c.rate_hz);     // 0.021 m/s^2
  c.gyro_bias_rad_s = 0.5 * deg;
  c.accel_bias_m_s2 = 0.1;
  return c;
}

ImuNoiseConfig ImuNoiseConfig::parse(const std::string& name) {
  if (name == "none") return none();
  if (name == "bmi055") return bmi055();
  throw std::invalid_argument("unknown IMU noise '" + name + "' (known: none, bmi055)");
}

std::vector<std::string> ImuNoiseConfig::validate() const {
  std::vector<std::string> p;
  if (!(rate_hz >= 30.0 && rate_hz <= 2000.0)) p.push_back("IMU rate_hz must be in [30, 2000]");
  for (double x : {gyro_noise_rad_s, accel_noise_m_s2, gyro_bias_rad_s, accel_bias_m_s2})
    if (!(x >= 0.0 && std::isfinite(x))) {
      p.push_back("IMU noise and bias figures must be finite and >= 0");
      break;
    }
  return p;
}

std::vector<ImuSample> simulateImu(const RenderedRun& run, const Eigen::Isometry3d& T_C_I,
                                   const ImuNoiseConfig& noise, std::uint64_t seed,
                                   double lead_s) {
  if (!run.pose_at)
    throw std::invalid_argument("simulated IMU: run '" + run.name +
                                "' has no continuous trajectory (stepped run)");
  if (!(lead_s >= 0.0)) throw std::invalid_argument("simulated IMU: lead_s must be >= 0");
  if (run.stamps_s.empty()) return {};
  // pose_at takes the frames' stamps (and holds the first pose before the first stamp).
  return simulateImu(run.pose_at, run.stamps_s.front() - lead_s, run.stamps_s.back(), T_C_I,
                     noise, seed);
}

std::vector<ImuSample> simulateImu(const std::function<Eigen::Isometry3d(double)>& T_W_C,
                                   double t_first, double t_last, const Eigen::Isometry3d& T_C_I,
                                   const ImuNoiseConfig& noise, std::uint64_t seed) {
  auto problems = noise.validate();
  if (!T_W_C) problems.push_back("no trajectory");
  if (!isRigid(T_C_I)) problems.push_back("T_C_I is not rigid");
  if (!(t_last >= t_first)) problems.push_back("t_last must be >= t_first");
  if (!problems.empty()) {
    std::string all;
    for (const auto& p : problems) all += (all.empty() ? "" : "; ") + p;
    throw std::invalid_argument("simulated IMU: " + all);
  }
  const Eigen::Vector3d g_W(0.0, 0.0, -9.80665);
  const double dt = 1.0 / noise.rate_hz;
  auto T_W_I = [&](double t) { return T_W_C(t) * T_C_I; };
  const double h = 1e-4;  // central differences for the velocity
  auto velocity = [&](double t) {
    return Eigen::Vector3d((T_W_I(t + h).translation() - T_W_I(t - h).translation()) / (2 * h));
  };
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 0x1D8E4E27C47D124Full);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  Eigen::Vector3d b_g, b_a;
  for (int k = 0; k < 3; ++k) b_g[k] = noise.gyro_bias_rad_s * uni(rng);
  for (int k = 0; k < 3; ++k) b_a[k] = noise.accel_bias_m_s2 * uni(rng);
  std::vector<ImuSample> out;
  const long n = static_cast<long>(std::floor((t_last - t_first) / dt)) + 1;
  out.reserve(static_cast<std::size_t>(n));
  for (long j = 0; j < n; ++j) {
    const double t = t_first + j * dt;
    const Eigen::Isometry3d A = T_W_I(t), B = T_W_I(t + dt), M = T_W_I(t + 0.5 * dt);
    ImuSample s;
    s.stamp_s = t;
    s.gyro_rad_s = logSO3(A.linear().transpose() * B.linear()) / dt;
    const Eigen::Vector3d a_W = (velocity(t + dt) - velocity(t)) / dt;
    s.accel_m_s2 = M.linear().transpose() * (a_W - g_W);
    for (int k = 0; k < 3; ++k) {
      s.gyro_rad_s[k] += b_g[k] + noise.gyro_noise_rad_s * gauss(rng);
      s.accel_m_s2[k] += b_a[k] + noise.accel_noise_m_s2 * gauss(rng);
    }
    out.push_back(s);
  }
  return out;
}

}  // namespace sim
}  // namespace depth_track
