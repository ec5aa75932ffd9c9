#include "depth_track/core/servotrack_kinematics.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <optional>
#include <stdexcept>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/camera.hpp"
#include "depth_track/core/se3.hpp"

namespace depth_track {

namespace {
bool finite3(const Eigen::Vector3d& v) { return v.allFinite(); }

template <class Sample>
void checkStream(const std::vector<Sample>& s, const char* name) {
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (!std::isfinite(s[i].stamp_s))
      throw std::invalid_argument(std::string(name) + " sample " + std::to_string(i) +
                                  ": stamp is not finite");
    if (i > 0 && s[i].stamp_s < s[i - 1].stamp_s)
      throw std::invalid_argument(std::string(name) + " sample " + std::to_string(i) +
                                  ": stamp goes back in time (" + std::to_string(s[i].stamp_s) +
                                  " s after " + std::to_string(s[i - 1].stamp_s) + " s)");
  }
}

/// Linear interpolation of value(sample) at t; nullopt outside the stream's span.
template <class Sample, class Value>
std::optional<double> interpolate(const std::vector<Sample>& s, double t, Value value) {
  if (s.empty() || !(t >= s.front().stamp_s) || !(t <= s.back().stamp_s)) return std::nullopt;
  const auto hi = std::lower_bound(s.begin(), s.end(), t,
                                   [](const Sample& a, double x) { return a.stamp_s < x; });
  if (hi == s.begin() || hi->stamp_s == t) return value(*hi);
  const auto lo = hi - 1;
  const double span = hi->stamp_s - lo->stamp_s;
  if (!(span > 0.0)) return value(*hi);
  const double w = (t - lo->stamp_s) / span;
  return (1.0 - w) * value(*lo) + w * value(*hi);
}

double medianInterval(std::vector<double> d) {
  if (d.empty()) return 0.0;
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return d[d.size() / 2];
}

template <class Sample>
double medianPeriod(const std::vector<Sample>& s) {
  std::vector<double> d;
  for (std::size_t i = 1; i < s.size(); ++i) d.push_back(s[i].stamp_s - s[i - 1].stamp_s);
  return medianInterval(d);
}

// Advances `s` to time t_end with the demands held (zero-order hold, the board's own rule):
// exact first-order lags, the arc integrated in steps of at most 1 ms (midpoint heading).
void advanceTruck(TruckOdometry::State& s, double t_end, double speed_dem, double steer_dem,
                  const TruckGeometry& g) {
  constexpr double kStep = 1e-3;
  while (s.t < t_end) {
    const double h = std::min(kStep, t_end - s.t);
    const auto lag = [h](double x, double demand, double tau) {
      return tau > 0.0 ? demand + (x - demand) * std::exp(-h / tau) : demand;
    };
    const double v1 = lag(s.speed, speed_dem, g.speed_lag_s);
    const double d1 = lag(s.steer, steer_dem, g.steer_lag_s);
    const double v = 0.5 * (s.speed + v1), steer = 0.5 * (s.steer + d1);
    const double dheading = v * std::tan(steer) / g.wheelbase_m * h;
    const double mid = s.heading + 0.5 * dheading;
    s.x += v * std::cos(mid) * h;
    s.y += v * std::sin(mid) * h;
    s.heading += dheading;
    s.speed = v1;
    s.steer = d1;
    s.t += h;
  }
}

Eigen::Isometry3d truckBasePose(const TruckOdometry::State& s) {
  Eigen::Isometry3d T_W_B = Eigen::Isometry3d::Identity();
  T_W_B.linear() = Eigen::AngleAxisd(s.heading, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T_W_B.translation() = Eigen::Vector3d(s.x, s.y, 0.0);
  return T_W_B;
}

// Steering +1 is full right; the bicycle's wheel angle is positive to the left.
double wheelAngle(const TruckRcSample& s, const TruckGeometry& g) {
  return -std::clamp(s.steering, -1.0, 1.0) * g.max_steer_deg * kDegToRad;
}

}  // namespace

std::vector<std::string> TrackGeometry::validate() const {
  std::vector<std::string> problems;
  if (!finite3(origin_W)) problems.push_back("track origin_W must be finite");
  if (!finite3(direction_W) || direction_W.norm() < 1e-9) {
    problems.push_back("track direction_W must be a finite non-zero vector");
  } else if (direction_W.normalized().cross(Eigen::Vector3d::UnitZ()).norm() < 1e-3) {
    problems.push_back("track direction_W must not be vertical");
  }
  if (!std::isfinite(pitch_axis_height_m)) problems.push_back("pitch_axis_height_m must be finite");
  if (!std::isfinite(pitch_axis_forward_m))
    problems.push_back("pitch_axis_forward_m must be finite");
  if (!finite3(camera_offset_m)) problems.push_back("camera_offset_m must be finite");
  return problems;
}

Eigen::Matrix3d rotationBodyFromOptical() {
  Eigen::Matrix3d R_B_C;
  // Columns: optical x (right) = body -y, optical y (down) = body -z, optical z = body x.
  R_B_C << 0, 0, 1,  //
      -1, 0, 0,      //
      0, -1, 0;
  return R_B_C;
}

Eigen::Isometry3d cameraPoseOnTrack(double track_pos_m, double pitch_rad, double yaw_rad,
                                    const TrackGeometry& g) {
  const auto problems = g.validate();
  if (!problems.empty())
    throw std::invalid_argument("invalid TrackGeometry: " + joinProblems(problems));
  if (!std::isfinite(track_pos_m) || !std::isfinite(pitch_rad) || !std::isfinite(yaw_rad))
    throw std::invalid_argument("cameraPoseOnTrack: track position and angles must be finite");

  // Carriage frame K: x along the track (levelled), z up.
  Eigen::Vector3d x = g.direction_W.normalized();
  const Eigen::Vector3d z = Eigen::Vector3d::UnitZ();
  x = (x - x.dot(z) * z).normalized();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Isometry3d T_W_K = Eigen::Isometry3d::Identity();
  T_W_K.linear().col(0) = x;
  T_W_K.linear().col(1) = y;
  T_W_K.linear().col(2) = z;
  T_W_K.translation() = g.origin_W + track_pos_m * g.direction_W.normalized();

  Eigen::Isometry3d T_K_Y = Eigen::Isometry3d::Identity();  // yaw stage
  T_K_Y.linear() = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();

  // Pitch stage P: rotation about the stage's left (y) axis; a positive rotation about +y turns
  // +x downwards, so nose-up pitch is a rotation by -pitch.
  Eigen::Isometry3d T_Y_P = Eigen::Isometry3d::Identity();
  T_Y_P.translation() = Eigen::Vector3d(g.pitch_axis_forward_m, 0.0, g.pitch_axis_height_m);
  T_Y_P.linear() = Eigen::AngleAxisd(-pitch_rad, Eigen::Vector3d::UnitY()).toRotationMatrix();

  Eigen::Isometry3d T_P_C = Eigen::Isometry3d::Identity();
  T_P_C.translation() = g.camera_offset_m;
  T_P_C.linear() = rotationBodyFromOptical();

  return T_W_K * T_K_Y * T_Y_P * T_P_C;
}

std::vector<std::string> TruckGeometry::validate() const {
  std::vector<std::string> problems;
  if (!(wheelbase_m > 0.0 && std::isfinite(wheelbase_m)))
    problems.push_back("truck wheelbase_m must be > 0");
  if (!(max_steer_deg > 0.0 && max_steer_deg < 89.0))
    problems.push_back("truck max_steer_deg must be in (0, 89) deg");
  if (!(steer_lag_s >= 0.0 && std::isfinite(steer_lag_s)))
    problems.push_back("truck steer_lag_s must be >= 0");
  if (!(speed_lag_s >= 0.0 && std::isfinite(speed_lag_s)))
    problems.push_back("truck speed_lag_s must be >= 0");
  if (!isRigid(T_B_C)) problems.push_back("truck T_B_C must be a finite rigid transform");
  return problems;
}

double RigSensorStreams::samplePeriod() const {
  return !track.empty() ? medianPeriod(track) : medianPeriod(truck);
}

std::string RigSensorStreams::describe() const {
  if (hasServoTrack()) return "track_state + carriage_sensors";
  if (hasServoTruck()) return "truck_rc";
  return "";
}

Trajectory sensorTrajectory(const RigSensorStreams& streams, const std::vector<double>& stamps_s,
                            const RigGeometry& geometry, double shift_s) {
  if (!std::isfinite(shift_s)) throw std::invalid_argument("sensorTrajectory: shift not finite");
  Trajectory out;
  if (streams.hasServoTrack()) {
    checkStream(streams.track, "track_state");
    checkStream(streams.gimbal, "carriage_sensors");
    for (const auto& s : streams.track)
      if (!std::isfinite(s.track_pos_m))
        throw std::invalid_argument("track_state: track position not finite");
    for (const auto& s : streams.gimbal)
      if (!std::isfinite(s.pitch_deg) || !std::isfinite(s.yaw_deg))
        throw std::invalid_argument("carriage_sensors: pitch or yaw not finite");
    for (const double t : stamps_s) {
      const double ts = t + shift_s;
      const auto pos = interpolate(streams.track, ts, [](const auto& s) { return s.track_pos_m; });
      const auto pitch = interpolate(streams.gimbal, ts, [](const auto& s) { return s.pitch_deg; });
      const auto yaw = interpolate(streams.gimbal, ts, [](const auto& s) { return s.yaw_deg; });
      if (!pos || !pitch || !yaw) continue;
      out.push_back(
          {t, cameraPoseOnTrack(*pos, *pitch * kDegToRad, *yaw * kDegToRad, geometry.track)});
    }
    return out;
  }
  if (!streams.hasServoTruck())
    throw std::invalid_argument(
        "sensorTrajectory: no sensor stream (need track_state + carriage_sensors, or truck_rc)");
  const TruckGeometry& g = geometry.truck;
  TruckOdometry odometry(g);  // validates the geometry
  const auto& rc = streams.truck;
  checkStream(rc, "truck_rc");
  for (const auto& s : rc)
    if (!std::isfinite(s.speed_mps) || !std::isfinite(s.steering))
      throw std::invalid_argument("truck_rc: speed or steering not finite");
  std::vector<std::size_t> order(stamps_s.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return stamps_s[a] < stamps_s[b]; });
  std::vector<std::optional<Eigen::Isometry3d>> poses(stamps_s.size());
  for (const std::size_t q : order) {
    const double ts = stamps_s[q] + shift_s;
    if (!(ts >= rc.front().stamp_s) || !(ts <= rc.back().stamp_s)) continue;
    while (odometry.readings() < rc.size() && rc[odometry.readings()].stamp_s <= ts)
      odometry.add(rc[odometry.readings()]);
    poses[q] = *odometry.predict(ts) * g.T_B_C;
  }
  for (std::size_t i = 0; i < stamps_s.size(); ++i)
    if (poses[i]) out.push_back({stamps_s[i], *poses[i]});
  return out;
}

TruckOdometry::TruckOdometry(const TruckGeometry& geometry) : g_(geometry) {
  const auto problems = g_.validate();
  if (!problems.empty())
    throw std::invalid_argument("invalid TruckGeometry: " + joinProblems(problems));
}

Eigen::Isometry3d TruckOdometry::add(const TruckRcSample& r) {
  if (!std::isfinite(r.stamp_s) || !std::isfinite(r.speed_mps) || !std::isfinite(r.steering))
    throw std::invalid_argument("truck_rc: stamp, speed or steering not finite");
  if (readings_ == 0) {
    state_.t = r.stamp_s;
    state_.speed = r.speed_mps;  // the lags start settled on the first demands
    state_.steer = wheelAngle(r, g_);
  } else if (r.stamp_s < state_.t) {
    throw std::invalid_argument("truck_rc: stamp " + std::to_string(r.stamp_s) +
                                " s goes back in time (last " + std::to_string(state_.t) + " s)");
  } else {
    advanceTruck(state_, r.stamp_s, last_.speed_mps, wheelAngle(last_, g_), g_);
  }
  last_ = r;
  ++readings_;
  return truckBasePose(state_);
}

std::optional<Eigen::Isometry3d> TruckOdometry::predict(double stamp_s) const {
  if (readings_ == 0 || !(stamp_s >= state_.t)) return std::nullopt;
  State s = state_;
  advanceTruck(s, stamp_s, last_.speed_mps, wheelAngle(last_, g_), g_);
  return truckBasePose(s);
}

SensorMotionPrior::SensorMotionPrior(RigSensorStreams streams, const RigGeometry& geometry)
    : streams_(std::move(streams)), geometry_(geometry) {
  // Every check sensorTrajectory makes, once, before the first frame.
  if (!streams_.hasServoTrack() && !streams_.hasServoTruck())
    throw std::invalid_argument(
        "sensor motion prior: no sensor stream (need track_state + carriage_sensors, or "
        "truck_rc)");
  const double first = streams_.hasServoTrack() ? streams_.track.front().stamp_s
                                                : streams_.truck.front().stamp_s;
  sensorTrajectory(streams_, {first}, geometry_);
  if (!streams_.hasServoTrack()) truck_.emplace(geometry_.truck);
}

std::optional<Eigen::Isometry3d> SensorMotionPrior::cameraPose(double stamp_s) {
  if (!truck_) {
    const Trajectory at = sensorTrajectory(streams_, {stamp_s}, geometry_);
    if (at.empty()) return std::nullopt;
    return at.front().T_W_C;
  }
  // The base poses at the readings on either side, interpolated as tf2 interpolates the graph's
  // odometry tf (rig_odometry publishes one per reading), so that the graph's prior is this one.
  const auto& rc = streams_.truck;
  if (!(stamp_s >= rc.front().stamp_s) || !(stamp_s <= rc.back().stamp_s)) return std::nullopt;
  while (fed_ == 0 || (fed_ < rc.size() && rc[fed_ - 1].stamp_s < stamp_s)) {
    before_ = after_;
    after_ = truck_->add(rc[fed_++]);
  }
  const double t1 = rc[fed_ - 1].stamp_s;
  const double t0 = fed_ >= 2 ? rc[fed_ - 2].stamp_s : t1;
  const double f = t1 > t0 ? (stamp_s - t0) / (t1 - t0) : 1.0;
  return interpolatePose(before_, after_, f) * geometry_.truck.T_B_C;
}

std::optional<Eigen::Isometry3d> SensorMotionPrior::next(double stamp_s) {
  if (!(stamp_s > last_stamp_s_))
    throw std::invalid_argument("sensor motion prior: frame stamp " + std::to_string(stamp_s) +
                                " s is not after the last (" + std::to_string(last_stamp_s_) +
                                " s)");
  last_stamp_s_ = stamp_s;
  const std::optional<Eigen::Isometry3d> T_W_C = cameraPose(stamp_s);
  std::optional<Eigen::Isometry3d> motion;
  if (T_W_C && last_T_W_C_) motion = last_T_W_C_->inverse() * *T_W_C;
  last_T_W_C_ = T_W_C;
  return motion;
}

}  // namespace depth_track
