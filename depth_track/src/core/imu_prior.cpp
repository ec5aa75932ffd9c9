#include "depth_track/core/imu_prior.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/se3.hpp"

namespace depth_track {

namespace {
constexpr double kStandardGravity = 9.80665;  // m/s^2

std::string fmt(double x) {
  std::ostringstream s;
  s << x;
  return s.str();
}

// The filter's settings table (imuPriorParams).
template <typename Member>
ImuParamSpec num(const char* name, const char* unit, const char* help, Member member) {
  return numParam<ImuPriorConfig>(name, unit, help, member);
}
using C = ImuPriorConfig;
std::vector<ImuParamSpec> makeImuParams() {
  return {
      num("init_window", "s",
          "gravity from the mean accelerometer reading over this window before the first frame "
          "(the camera still)",
          [](C& c) -> double& { return c.init_window_s; }),
      num("accel_noise_density", "m/s^2/sqrt(Hz)", "accelerometer white noise (BMI055: 0.0015)",
          [](C& c) -> double& { return c.accel_noise_density; }),
      num("accel_bias", "m/s^2",
          "accelerometer bias expected per axis (standard deviation; taken in with gravity at the "
          "start, told apart as the camera turns)",
          [](C& c) -> double& { return c.accel_bias_m_s2; }),
      num("accel_bias_walk", "m/s^2/sqrt(s)", "random walk of the bias and of the gravity error",
          [](C& c) -> double& { return c.accel_bias_walk; }),
      num("accel_significance", "sigmas",
          "an interval's acceleration is taken as smaller by this many sigmas of the "
          "accelerometer error the filter still has (0 = off)",
          [](C& c) -> double& { return c.accel_significance; }),
      num("guess_gate", "sigmas",
          "the registration starts from the last frame's motion while the IMU's guess lies "
          "within this many of its sigmas of it (0 = always the IMU's guess)",
          [](C& c) -> double& { return c.guess_gate; }),
      num("unmodelled_accel", "m/s^2",
          "acceleration the IMU filter does not model (the tracked orientation's tilt turning "
          "gravity, timing)",
          [](C& c) -> double& { return c.unmodelled_accel_m_s2; }),
      num("position_floor", "m",
          "added to a tracked position's standard deviation in the IMU filter",
          [](C& c) -> double& { return c.position_floor_m; }),
      num("rotation_floor", "rad",
          "added to a tracked rotation's standard deviation per frame when it corrects the "
          "gyro's bias",
          [](C& c) -> double& { return c.rotation_floor_rad; }),
      num("gyro_bias_walk", "rad/s/sqrt(s)", "random walk of the gyro's bias",
          [](C& c) -> double& { return c.gyro_bias_walk; }),
  };
}
}  // namespace

const std::vector<ImuParamSpec>& imuPriorParams() {
  static const std::vector<ImuParamSpec> table = makeImuParams();
  return table;
}

std::vector<std::string> ImuPriorConfig::validate() const {
  std::vector<std::string> p;
  if (!isRigid(T_C_I, 1e-6)) p.push_back("T_C_I is not a rigid transform");
  if (!(init_window_s > 0.0 && init_window_s <= 10.0))
    p.push_back("init_window_s must be in (0, 10] s, got " + fmt(init_window_s));
  if (!(still_spread_m_s2 > 0.0))
    p.push_back("still_spread_m_s2 must be > 0, got " + fmt(still_spread_m_s2));
  if (!(gravity_tolerance > 0.0 && gravity_tolerance < 1.0))
    p.push_back("gravity_tolerance must be in (0, 1), got " + fmt(gravity_tolerance));
  if (!(accel_noise_density > 0.0 && accel_noise_density < 1.0))
    p.push_back("accel_noise_density must be in (0, 1) m/s^2/sqrt(Hz), got " +
                fmt(accel_noise_density));
  if (!(accel_bias_m_s2 >= 0.0 && accel_bias_m_s2 < 5.0))
    p.push_back("accel_bias_m_s2 must be in [0, 5), got " + fmt(accel_bias_m_s2));
  if (!(accel_bias_walk > 0.0 && accel_bias_walk < 1.0))
    p.push_back("accel_bias_walk must be in (0, 1) m/s^2/sqrt(s), got " + fmt(accel_bias_walk));
  if (!(accel_significance >= 0.0 && accel_significance <= 10.0))
    p.push_back("accel_significance must be in [0, 10] sigmas, got " + fmt(accel_significance));
  if (!(guess_gate >= 0.0 && guess_gate <= 10.0))
    p.push_back("guess_gate must be in [0, 10] sigmas, got " + fmt(guess_gate));
  if (!(unmodelled_accel_m_s2 >= 0.0 && unmodelled_accel_m_s2 < 10.0))
    p.push_back("unmodelled_accel_m_s2 must be in [0, 10) m/s^2, got " +
                fmt(unmodelled_accel_m_s2));
  if (!(position_floor_m > 0.0 && position_floor_m < 1.0))
    p.push_back("position_floor_m must be in (0, 1) m, got " + fmt(position_floor_m));
  if (!(rotation_floor_rad > 0.0 && rotation_floor_rad < 0.1))
    p.push_back("rotation_floor_rad must be in (0, 0.1) rad, got " + fmt(rotation_floor_rad));
  if (!(gyro_bias_walk > 0.0 && gyro_bias_walk < 0.1))
    p.push_back("gyro_bias_walk must be in (0, 0.1) rad/s/sqrt(s), got " + fmt(gyro_bias_walk));
  if (!(max_gap_s > 0.0 && max_gap_s <= 1.0))
    p.push_back("max_gap_s must be in (0, 1] s, got " + fmt(max_gap_s));
  return p;
}

ImuMotionPrior::ImuMotionPrior(const ImuPriorConfig& config) : config_(config) {
  const auto problems = config_.validate();
  if (!problems.empty()) {
    std::string all;
    for (const auto& p : problems) all += (all.empty() ? "" : "; ") + p;
    throw std::invalid_argument("IMU prior: " + all);
  }
}

void ImuMotionPrior::add(const ImuSample& s) {
  if (!std::isfinite(s.stamp_s) || !s.gyro_rad_s.allFinite() || !s.accel_m_s2.allFinite())
    throw std::invalid_argument("IMU reading at " + fmt(s.stamp_s) + " s is not finite");
  if (!samples_.empty() && !(s.stamp_s > samples_.back().stamp_s))
    throw std::invalid_argument("IMU reading at " + fmt(s.stamp_s) +
                                " s is not after the last (" + fmt(samples_.back().stamp_s) +
                                " s)");
  samples_.push_back(s);
  // Before the start only the gravity window is needed; after it, from the last frame on.
  const double keep_from = started_ ? last_stamp_s_ : s.stamp_s - config_.init_window_s - 1.0;
  while (samples_.size() >= 2 && samples_[1].stamp_s <= keep_from) samples_.pop_front();
}

std::size_t ImuMotionPrior::addUpTo(const std::vector<ImuSample>& readings, std::size_t next,
                                    double stamp_s) {
  for (; next < readings.size() && readings[next].stamp_s <= stamp_s; ++next) add(readings[next]);
  return next;
}

std::optional<ImuMotionPrior::Delta> ImuMotionPrior::integrate(double t0, double t1,
                                                               const Eigen::Vector3d& bias) const {
  if (samples_.empty() || samples_.front().stamp_s > t0 || !(t1 > t0)) return std::nullopt;
  std::size_t k = 0;
  while (k + 1 < samples_.size() && samples_[k + 1].stamp_s <= t0) ++k;
  Delta d;
  double a = t0;
  while (a < t1) {
    const ImuSample& s = samples_[k];
    const bool has_next = k + 1 < samples_.size();
    const double next = has_next ? samples_[k + 1].stamp_s : t1;
    // The reading holds until the next one: a gap that long inside [t0, t1] is too long.
    if (next - s.stamp_s > config_.max_gap_s) return std::nullopt;
    const double b = std::min(next, t1);
    const double h = b - a;
    // Rotation at the piece's middle for the specific force; the piece's rotation exact.
    const Eigen::Vector3d w = s.gyro_rad_s - gyro_bias_;
    if (a == t0) d.w0 = w;
    d.w1 = w;
    const Eigen::Matrix3d R_mid = d.R * expSO3(0.5 * h * w);
    const Eigen::Vector3d f = R_mid * (s.accel_m_s2 - bias);
    d.p += d.v * h + 0.5 * f * h * h;
    d.v += f * h;
    d.Jp += d.Jv * h - 0.5 * h * h * R_mid;
    d.Jv -= h * R_mid;
    d.R = d.R * expSO3(h * w);
    a = b;
    if (has_next) ++k;
  }
  return d;
}

std::optional<ImuMotionPrior::Propagated> ImuMotionPrior::propagate(double stamp_s) const {
  if (!started_ || !(stamp_s > last_stamp_s_)) return std::nullopt;
  const Eigen::Vector3d p0 = x_.head<3>(), v0 = x_.segment<3>(3), e = x_.segment<3>(6),
                        bias = x_.tail<3>();
  const std::optional<Delta> d = integrate(last_stamp_s_, stamp_s, bias);
  if (!d) return std::nullopt;
  const double T = stamp_s - last_stamp_s_;
  const Eigen::Matrix3d R0 = last_T_W_C_.linear() * config_.T_C_I.linear();
  // The guess moves the camera from where the tracker left it; the filter's own position (its
  // estimate of that) only weighs the next measurement.
  const Eigen::Vector3d p_tracked = (last_T_W_C_ * config_.T_C_I).translation();
  const Eigen::Vector3d g = g_W_ + e;
  const Eigen::Matrix3d I = Eigen::Matrix3d::Identity();
  // The interval's mean acceleration as the IMU reads it, and how well the filter knows the
  // accelerometer's error in it (the gravity error less the bias turned into the world, at the
  // interval's rotation): an acceleration within accel_significance of those sigmas cannot be
  // told from moving at a constant velocity and is taken as that much smaller (a soft
  // threshold), so that over seconds of a view that cannot correct it the error does not run.
  const Eigen::Vector3d dv = g * T + R0 * d->v;
  // The IMU point's motion has a part the camera's lacks: the lever arm r (the camera's origin
  // in the IMU frame) turning with the rig, v_C = v_I + R (w x r). It is known exactly from the
  // gyro, so the threshold below judges the camera's acceleration, with that part taken out
  // (L_v, L_p) and added back whole.
  const Eigen::Vector3d r = config_.T_C_I.inverse().translation();
  const Eigen::Matrix3d R1 = R0 * d->R;
  const Eigen::Vector3d L_v = R1 * d->w1.cross(r) - R0 * d->w0.cross(r);
  const Eigen::Vector3d L_p = R1 * r - R0 * r - R0 * d->w0.cross(r) * T;
  const Eigen::Vector3d A_v = dv + L_v;
  const Eigen::Vector3d A_p = 0.5 * g * T * T + R0 * d->p + L_p;
  double keep = 1.0;
  if (config_.accel_significance > 0.0) {
    Eigen::Matrix<double, 3, 6> J;
    J << I, R0 * d->Jv / T;  // the gravity error's and the bias's mean effect
    const Eigen::Matrix3d S = J * P_.bottomRightCorner<6, 6>() * J.transpose();
    const double tau = config_.accel_significance * std::sqrt(std::max(0.0, S.trace() / 3.0));
    const double a = A_v.norm() / T;
    keep = a > tau ? (a - tau) / a : 0.0;
  }
  Propagated out;
  out.significant_dv = keep * A_v;
  out.significant_dp = keep * A_p;
  out.x = x_;
  out.x.head<3>() = p0 + v0 * T + keep * A_p - L_p;
  out.x.segment<3>(3) = v0 + keep * A_v - L_v;
  Matrix12d F = Matrix12d::Identity();
  F.block<3, 3>(0, 3) = T * I;
  F.block<3, 3>(0, 6) = keep * 0.5 * T * T * I;
  F.block<3, 3>(0, 9) = keep * R0 * d->Jp;
  F.block<3, 3>(3, 6) = keep * T * I;
  F.block<3, 3>(3, 9) = keep * R0 * d->Jv;
  // White acceleration noise: the readings' own and what the filter does not model (the
  // tracked orientation's tilt turning gravity into the horizontal, timing); the gravity error
  // and the bias walk.
  const double q = config_.accel_noise_density * config_.accel_noise_density +
                   config_.unmodelled_accel_m_s2 * config_.unmodelled_accel_m_s2 * T;
  Matrix12d Q = Matrix12d::Zero();
  Q.block<3, 3>(0, 0) = q * T * T * T / 3.0 * I;
  Q.block<3, 3>(0, 3) = Q.block<3, 3>(3, 0) = q * T * T / 2.0 * I;
  Q.block<3, 3>(3, 3) = q * T * I;
  const double walk = config_.accel_bias_walk * config_.accel_bias_walk * T;
  Q.block<3, 3>(6, 6) = walk * I;
  Q.block<3, 3>(9, 9) = walk * I;
  out.P = F * P_ * F.transpose() + Q;
  Eigen::Isometry3d T_W_I1 = Eigen::Isometry3d::Identity();
  T_W_I1.linear() = R0 * d->R;
  T_W_I1.translation() = p_tracked + (out.x.head<3>() - p0);
  out.T_W_C = orthonormalized(T_W_I1 * config_.T_C_I.inverse());
  return out;
}

std::optional<Eigen::Isometry3d> ImuMotionPrior::predict(double stamp_s) const {
  const auto g = guess(stamp_s);
  if (!g) return std::nullopt;
  return g->T_Cprev_Ccur;
}

std::optional<ImuMotionPrior::Guess> ImuMotionPrior::guess(double stamp_s) const {
  const auto next = propagate(stamp_s);
  if (!next) return std::nullopt;
  Guess g;
  g.T_Cprev_Ccur = last_T_W_C_.inverse() * next->T_W_C;
  g.hold.guess_tolerance_m = config_.guess_gate *
                             std::sqrt(next->P.block<3, 3>(3, 3).trace() / 3.0) *
                             (stamp_s - last_stamp_s_);
  g.hold.displacement_W =
      significant_d_ + significant_v_ * (stamp_s - last_stamp_s_) + next->significant_dp;
  return g;
}

bool ImuMotionPrior::start(double stamp_s, const Eigen::Isometry3d& T_W_C) {
  // Mean and spread of the window's readings in one pass (the spread is ~1e-2 of gravity: the
  // squares lose nothing that matters in double).
  Eigen::Vector3d sum = Eigen::Vector3d::Zero(), gyro_sum = Eigen::Vector3d::Zero();
  double sum_sq = 0.0, gyro_sum_sq = 0.0;
  int n = 0;
  for (const ImuSample& s : samples_)
    if (s.stamp_s <= stamp_s && s.stamp_s >= stamp_s - config_.init_window_s) {
      sum += s.accel_m_s2;
      sum_sq += s.accel_m_s2.squaredNorm();
      gyro_sum += s.gyro_rad_s;
      gyro_sum_sq += s.gyro_rad_s.squaredNorm();
      ++n;
    }
  if (n < 2) {
    reason_ = "fewer than 2 IMU readings in the " + fmt(config_.init_window_s) +
              " s before the frame at " + fmt(stamp_s) + " s";
    return false;
  }
  const Eigen::Vector3d mean = sum / n;
  const double spread = std::sqrt(std::max(0.0, sum_sq / n - mean.squaredNorm()));
  if (std::abs(mean.norm() - kStandardGravity) > config_.gravity_tolerance * kStandardGravity) {
    reason_ = "the accelerometer reads " + fmt(mean.norm()) +
              " m/s^2 on average before the frame at " + fmt(stamp_s) +
              " s, not gravity (9.81): are the readings specific force in m/s^2?";
    return false;
  }
  if (spread > config_.still_spread_m_s2) {
    reason_ = "the camera was not still before the frame at " + fmt(stamp_s) +
              " s (accelerometer spread " + fmt(spread) + " m/s^2 > still_spread_m_s2 " +
              fmt(config_.still_spread_m_s2) + ")";
    return false;
  }
  // At rest the accelerometer reads -gravity: gravity in W from the frame's orientation.
  // At rest the accelerometer reads bias - gravity: gravity in W from the frame's orientation,
  // with the bias in it. A bias b (IMU frame) leaves gravity off by R0 b: the filter's gravity
  // error starts fully correlated with its bias, and as the camera turns the two part.
  const Eigen::Matrix3d R0 = (T_W_C * config_.T_C_I).linear();
  g_W_ = -(R0 * mean);
  // Still, the gyro reads its bias; a sway's mean rate reads as bias too, so the estimate is
  // uncertain by the readings' spread (per axis), which the tracked rotations then correct.
  gyro_bias_ = gyro_sum / n;
  const double gyro_spread2 = std::max(0.0, gyro_sum_sq / n - gyro_bias_.squaredNorm()) / 3.0;
  gyro_bias_P_ = std::max(gyro_spread2, 1e-8) * Eigen::Matrix3d::Identity();
  x_.setZero();
  x_.head<3>() = (T_W_C * config_.T_C_I).translation();
  significant_v_.setZero();
  significant_d_.setZero();
  P_.setZero();
  // Still: velocity zero to within what the readings' spread allows over the window; the mean
  // is off by the window's mean acceleration (a hand's tremor, a sway): at most about the spread.
  const double sv = std::max(1e-3, spread * config_.init_window_s);
  const double se = std::max(1e-2, spread);
  const double sb = std::max(1e-3, config_.accel_bias_m_s2);
  const Eigen::Matrix3d I = Eigen::Matrix3d::Identity();
  P_.block<3, 3>(0, 0) = 1e-6 * I;
  P_.block<3, 3>(3, 3) = sv * sv * I;
  P_.block<3, 3>(6, 6) = (sb * sb + se * se) * I;
  P_.block<3, 3>(9, 9) = sb * sb * I;
  P_.block<3, 3>(6, 9) = sb * sb * R0;
  P_.block<3, 3>(9, 6) = sb * sb * R0.transpose();
  started_ = true;
  reason_.clear();
  return true;
}

bool ImuMotionPrior::update(double stamp_s, const Eigen::Isometry3d& T_W_C,
                            const std::optional<Matrix6d>& pose_cov_W) {
  if (!std::isfinite(stamp_s) || !isRigid(T_W_C, 1e-3))
    throw std::invalid_argument("IMU prior: frame pose at " + fmt(stamp_s) +
                                " s is not finite or not rigid");
  if (pose_cov_W && !pose_cov_W->allFinite())
    throw std::invalid_argument("IMU prior: pose covariance at " + fmt(stamp_s) +
                                " s is not finite");
  if (!started_) {
    if (!start(stamp_s, T_W_C)) return false;
  } else {
    if (!(stamp_s > last_stamp_s_))
      throw std::invalid_argument("IMU prior: frame at " + fmt(stamp_s) +
                                  " s is not after the last (" + fmt(last_stamp_s_) + " s)");
    const Eigen::Vector3d p_tracked = (T_W_C * config_.T_C_I).translation();
    const double T = stamp_s - last_stamp_s_;
    // The significant velocity carries on over the interval (also one without readings).
    significant_d_ += significant_v_ * T;
    if (const auto next = propagate(stamp_s)) {
      x_ = next->x;
      P_ = next->P;
      significant_d_ += next->significant_dp;
      significant_v_ += next->significant_dv;
      gyro_bias_P_ += config_.gyro_bias_walk * config_.gyro_bias_walk * T *
                      Eigen::Matrix3d::Identity();
      if (pose_cov_W) {
        // The gyro's bias from the tracked rotation: the readings less a bias off by db turn
        // the IMU by about -db T more than the tracker saw (residual in the IMU frame).
        const Eigen::Matrix3d R_C_I = config_.T_C_I.linear();
        const Eigen::Matrix3d R_W_I1 = T_W_C.linear() * R_C_I;
        const Eigen::Vector3d r =
            logSO3((next->T_W_C.linear() * R_C_I).transpose() * R_W_I1);
        const Eigen::Matrix3d Rm =
            R_W_I1.transpose() * pose_cov_W->topLeftCorner<3, 3>() * R_W_I1 +
            config_.rotation_floor_rad * config_.rotation_floor_rad * Eigen::Matrix3d::Identity();
        const Eigen::Matrix3d Sg = T * T * gyro_bias_P_ + Rm;
        const Eigen::Matrix3d Sg_inv = Sg.inverse();
        // A jump of the tracked pose (a relocalisation, a loop closure's correction) is no
        // measure of the gyro: a residual beyond 5 sigmas leaves the bias alone.
        if (r.dot(Sg_inv * r) <= 25.0) {
          const Eigen::Matrix3d Kg = -T * gyro_bias_P_ * Sg_inv;
          gyro_bias_ += Kg * r;  // r measures -(bias - estimate) T
          gyro_bias_P_ += T * Kg * gyro_bias_P_;
          gyro_bias_P_ = 0.5 * (gyro_bias_P_ + gyro_bias_P_.transpose());
        }
        const Eigen::Matrix3d S = P_.block<3, 3>(0, 0) + pose_cov_W->bottomRightCorner<3, 3>() +
                                  config_.position_floor_m * config_.position_floor_m *
                                      Eigen::Matrix3d::Identity();
        const Eigen::Matrix<double, 12, 3> K = P_.leftCols<3>() * S.inverse();
        x_ += K * (p_tracked - x_.head<3>());
        P_ -= K * P_.topRows<3>();
        P_ = 0.5 * (P_ + P_.transpose());
      }
    } else if (pose_cov_W) {
      // Readings missing over the interval: the velocity from the depth alone; the filter
      // starts again from the tracked position with its velocity uncertain.
      const Eigen::Vector3d p_last = x_.head<3>();
      x_.head<3>() = p_tracked;
      x_.segment<3>(3) = (p_tracked - p_last) / T;
      P_.block<3, 3>(3, 3) += 0.01 * Eigen::Matrix3d::Identity();
    }
  }
  last_T_W_C_ = T_W_C;
  last_stamp_s_ = stamp_s;
  while (samples_.size() >= 2 && samples_[1].stamp_s <= last_stamp_s_) samples_.pop_front();
  return true;
}

std::optional<Matrix6d> trackedPoseCovariance(const FrameStatus& status) {
  if (!status.tracked) return std::nullopt;
  Matrix6d R = Matrix6d::Zero();
  R.topLeftCorner<3, 3>() = R.bottomRightCorner<3, 3>() = status.T_W_Cref.linear();
  return R * status.measurement_covariance * R.transpose();
}

}  // namespace depth_track
