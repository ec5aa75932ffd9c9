#include "rig_drivers/sim/rig_sim_truck.hpp"
#include "depth_track/core/angles.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace rig_drivers {

namespace {

}  // namespace

std::vector<std::string> TruckModelConfig::validate() const {
  std::vector<std::string> p;
  auto positive = [&p](const char* n, double v) {
    if (!(v > 0.0) || !std::isfinite(v)) p.push_back(std::string(n) + ": must be > 0");
  };
  positive("wheelbase_m", wheelbase_m);
  positive("steer_time_constant_s", steer_time_constant_s);
  positive("speed_time_constant_s", speed_time_constant_s);
  positive("max_speed_mps", max_speed_mps);
  positive("camera_height_m", camera_height_m);
  if (!(max_steer_deg > 0.0 && max_steer_deg < 60.0))
    p.push_back("max_steer_deg: must lie in (0, 60) degrees");
  if (!(std::abs(speed_scale_error) < 0.5))
    p.push_back("speed_scale_error: must lie in (-0.5, 0.5)");
  if (!std::isfinite(camera_forward_m)) p.push_back("camera_forward_m: must be finite");
  if (!(std::abs(camera_pitch_deg) < 45.0)) p.push_back("camera_pitch_deg: must lie in (-45, 45)");
  return p;
}

TruckModel::TruckModel(const TruckModelConfig& config, const TruckState& start)
    : config_(config), state_(start) {
  const auto problems = config.validate();
  if (!problems.empty()) {
    std::string msg = "TruckModelConfig:";
    for (const auto& s : problems) msg += " " + s + ";";
    throw std::invalid_argument(msg);
  }
}

void TruckModel::step(double dt_s, double demanded_speed_mps, double steering) {
  if (!(dt_s > 0.0) || !std::isfinite(demanded_speed_mps) || !std::isfinite(steering)) {
    throw std::invalid_argument("TruckModel::step: dt_s must be > 0 and inputs finite");
  }
  const double v_target = std::clamp(demanded_speed_mps * (1.0 + config_.speed_scale_error),
                                     -config_.max_speed_mps, config_.max_speed_mps);
  // RC convention: +1 = full right; the model's steer angle is positive to the left.
  const double steer_target =
      -std::clamp(steering, -1.0, 1.0) * config_.max_steer_deg * depth_track::kDegToRad;
  // Exact discretisation of the first-order lags.
  const double a_v = 1.0 - std::exp(-dt_s / config_.speed_time_constant_s);
  const double a_s = 1.0 - std::exp(-dt_s / config_.steer_time_constant_s);
  const double v0 = state_.speed_mps;
  state_.speed_mps += a_v * (v_target - state_.speed_mps);
  state_.steer_rad += a_s * (steer_target - state_.steer_rad);
  // Move along the arc with the mean speed of the step and the new steering angle.
  const double v = 0.5 * (v0 + state_.speed_mps);
  const double ds = v * dt_s;
  const double kappa = std::tan(state_.steer_rad) / config_.wheelbase_m;  // 1/m
  const double dpsi = kappa * ds;
  if (std::abs(dpsi) < 1e-9) {
    state_.x_m += ds * std::cos(state_.heading_rad + 0.5 * dpsi);
    state_.y_m += ds * std::sin(state_.heading_rad + 0.5 * dpsi);
  } else {
    const double r = 1.0 / kappa;
    state_.x_m += r * (std::sin(state_.heading_rad + dpsi) - std::sin(state_.heading_rad));
    state_.y_m -= r * (std::cos(state_.heading_rad + dpsi) - std::cos(state_.heading_rad));
  }
  state_.heading_rad = std::remainder(state_.heading_rad + dpsi, 2.0 * M_PI);
  state_.odometer_m += std::abs(ds);
}

Eigen::Isometry3d TruckModel::T_W_B() const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(state_.heading_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(state_.x_m, state_.y_m, 0.0);
  return T;
}

Eigen::Isometry3d TruckModel::T_B_C() const {
  // Body axes (x forward, y left, z up) -> optical axes (x right, y down, z forward), then the
  // nose-up tilt about the body's y axis (a positive rotation about +y pitches the nose down).
  Eigen::Matrix3d R_body_optical;
  R_body_optical << 0, 0, 1,  //
      -1, 0, 0,               //
      0, -1, 0;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(-config_.camera_pitch_deg * depth_track::kDegToRad,
                                 Eigen::Vector3d::UnitY())
                   .toRotationMatrix() *
               R_body_optical;
  T.translation() = Eigen::Vector3d(config_.camera_forward_m, 0.0, config_.camera_height_m);
  return T;
}

double TruckModel::minTurnRadius() const {
  return config_.wheelbase_m / std::tan(config_.max_steer_deg * depth_track::kDegToRad);
}

}  // namespace rig_drivers
