#include "depth_track/core/se3.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/sim/render.hpp"

namespace depth_track {
namespace sim {

PinholeIntrinsics l515Intrinsics() { return PinholeIntrinsics::isotropic(640, 480, 458.0); }

DepthImage RenderedRun::renderFrame(std::size_t i, const NoiseConfig& noise, std::uint64_t run_seed,
                                    int threads) const {
  if (i >= T_W_C.size()) {
    std::ostringstream s;
    s << "run '" << name << "' has " << T_W_C.size() << " frames; frame " << i << " requested";
    throw std::out_of_range(s.str());
  }
  RenderedDepth clean;
  if (scan_time_s > 0.0 && pose_at) {
    const double t0 = stamps_s[i], h = intrinsics.height;
    const double scan = scan_time_s;
    const auto& pose = pose_at;
    clean = renderDepthScanned(
        scene, intrinsics, [&](double row) { return pose(t0 + scan * ((row + 0.5) / h - 0.5)); },
        range, threads);
  } else {
    clean = renderDepthWithIncidence(scene, intrinsics, T_W_C[i], range, threads);
  }
  return applyNoise(clean.depth, noise, frameSeed(run_seed, i), range, &clean.cos_incidence);
}

std::vector<Eigen::Vector3d> RenderedRun::visibleSurface(std::size_t i, int step_px,
                                                         int threads) const {
  if (step_px < 1) throw std::invalid_argument("visibleSurface: step_px must be >= 1");
  const DepthImage clean = renderFrame(i, NoiseConfig::forModel(NoiseModel::kNone), 0, threads);
  std::vector<Eigen::Vector3d> out;
  for (int v = 0; v < clean.height; v += step_px)
    for (int u = 0; u < clean.width; u += step_px)
      if (clean.at(u, v) > 0.0f)
        out.push_back(T_W_C[i] * intrinsics.backProject(u, v, clean.at(u, v)).cast<double>());
  return out;
}

RawDepth16 RenderedRun::renderFrameRaw(std::size_t i, const NoiseConfig& noise,
                                       std::uint64_t run_seed, int threads) const {
  return toRaw16(renderFrame(i, noise, run_seed, threads), nativeDepthScale(noise.model));
}

std::vector<std::string> TrackRunSpec::validate() const {
  std::vector<std::string> p;
  if (name.empty()) p.push_back("run name is empty");
  if (!(std::isfinite(rate_hz) && rate_hz > 0.0)) p.push_back("rate_hz must be > 0");
  if (still_frames < 0) p.push_back("still_frames must be >= 0");
  if (!std::isfinite(start_pos_m)) p.push_back("start_pos_m must be finite");
  const bool stepped = step_m > 0.0;
  if (stepped && steps <= 0) p.push_back("stepped mode needs steps > 0");
  if (!stepped && !(std::isfinite(speed_mps) && std::isfinite(duration_s) && duration_s > 0.0))
    p.push_back("continuous mode needs a finite speed_mps and duration_s > 0");
  if (axis != Axis::kNone && !(std::isfinite(amplitude_deg) && std::abs(amplitude_deg) <= 45.0 &&
                               std::isfinite(frequency_hz) && frequency_hz >= 0.0))
    p.push_back("gimbal input needs |amplitude_deg| <= 45 and frequency_hz >= 0");
  if (!std::isfinite(step_m)) p.push_back("step_m must be finite");
  return p;
}

RenderedRun makeTrackRun(const TrackRunSpec& spec, const Scene& scene, const TrackGeometry& track) {
  auto problems = spec.validate();
  for (const auto& q : track.validate()) problems.push_back(q);
  if (!problems.empty())
    throw std::invalid_argument("track run '" + spec.name + "': " + joinProblems(problems));
  RenderedRun run;
  run.name = spec.name;
  run.description = spec.description;
  run.scene = scene;
  run.on_track = true;
  run.track = track;
  auto add = [&](double t, double pos, double angle_t) {
    RigSample s;
    s.track_pos_m = pos;
    const double a =
        spec.amplitude_deg * kDegToRad * std::sin(2.0 * M_PI * spec.frequency_hz * angle_t);
    if (spec.axis == TrackRunSpec::Axis::kPitch) s.pitch_rad = a;
    if (spec.axis == TrackRunSpec::Axis::kYaw) s.yaw_rad = a;
    run.stamps_s.push_back(t);
    run.rig.push_back(s);
    run.T_W_C.push_back(cameraPoseOnTrack(s.track_pos_m, s.pitch_rad, s.yaw_rad, track));
  };
  const double dt = 1.0 / spec.rate_hz;
  if (spec.step_m <= 0.0) {
    // Continuous motion from the last still frame on; at rest before it.
    const double t_move = spec.still_frames * dt;
    run.pose_at = [spec, track, t_move](double t) {
      const double tm = std::max(0.0, t - t_move);
      const double pos = spec.start_pos_m + spec.speed_mps * tm;
      const double a = t < t_move ? 0.0
                                  : spec.amplitude_deg * kDegToRad *
                                        std::sin(2.0 * M_PI * spec.frequency_hz * tm);
      return cameraPoseOnTrack(pos, spec.axis == TrackRunSpec::Axis::kPitch ? a : 0.0,
                               spec.axis == TrackRunSpec::Axis::kYaw ? a : 0.0, track);
    };
  }
  int k = 0;
  for (; k < spec.still_frames; ++k) add(k * dt, spec.start_pos_m, 0.0);
  if (spec.step_m > 0.0) {
    for (int i = 1; i <= spec.steps; ++i, ++k)
      add(k * dt, spec.start_pos_m + i * spec.step_m, (i - 1) * dt);
  } else {
    const int n = static_cast<int>(std::lround(spec.duration_s * spec.rate_hz));
    for (int i = 0; i < n; ++i, ++k)
      add(k * dt, spec.start_pos_m + spec.speed_mps * i * dt, i * dt);
  }
  return run;
}

std::vector<std::string> TruckRunSpec::validate() const {
  std::vector<std::string> p;
  if (name.empty()) p.push_back("run name is empty");
  if (!(std::isfinite(rate_hz) && rate_hz > 0.0)) p.push_back("rate_hz must be > 0");
  if (!start_xy_m.allFinite() || !std::isfinite(start_heading_rad))
    p.push_back("start pose must be finite");
  if (!(std::isfinite(camera_height_m) && camera_height_m > 0.0))
    p.push_back("camera_height_m must be > 0");
  if (!std::isfinite(camera_forward_m) || !std::isfinite(camera_pitch_rad))
    p.push_back("camera offsets must be finite");
  if (still_frames < 0) p.push_back("still_frames must be >= 0");
  if (segments.empty()) p.push_back("a truck run needs at least one segment");
  for (std::size_t i = 0; i < segments.size(); ++i) {
    const auto& s = segments[i];
    if (!(std::isfinite(s.duration_s) && s.duration_s > 0.0 && std::isfinite(s.speed_mps) &&
          std::isfinite(s.yaw_rate_radps)))
      p.push_back("segment " + std::to_string(i) + " needs duration_s > 0 and finite rates");
  }
  return p;
}

RenderedRun makeTruckRun(const TruckRunSpec& spec, const Scene& scene) {
  const auto problems = spec.validate();
  if (!problems.empty())
    throw std::invalid_argument("truck run '" + spec.name + "': " + joinProblems(problems));
  RenderedRun run;
  run.name = spec.name;
  run.description = spec.description;
  run.scene = scene;

  Eigen::Isometry3d T_B_C = Eigen::Isometry3d::Identity();  // truck body -> optical
  T_B_C.translation() = Eigen::Vector3d(spec.camera_forward_m, 0.0, spec.camera_height_m);
  T_B_C.linear() = Eigen::AngleAxisd(-spec.camera_pitch_rad, Eigen::Vector3d::UnitY()) *
                   rotationBodyFromOptical();
  Eigen::Vector2d p = spec.start_xy_m;
  double heading = spec.start_heading_rad;
  auto add = [&](double t) {
    Eigen::Isometry3d T_W_B = Eigen::Isometry3d::Identity();
    T_W_B.translation() = Eigen::Vector3d(p.x(), p.y(), 0.0);
    T_W_B.linear() = Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    run.stamps_s.push_back(t);
    run.T_W_C.push_back(T_W_B * T_B_C);
  };
  const double dt = 1.0 / spec.rate_hz;
  int k = 0;
  for (; k < spec.still_frames; ++k) add(k * dt);
  // Time within the current segment; the first moving frame is one period after the last
  // still frame.
  std::size_t seg = 0;
  double seg_left = spec.segments[0].duration_s;
  const double eps = 1e-9;
  while (seg < spec.segments.size()) {
    double step = dt;
    // Advance exactly one frame period across segment boundaries (exact arcs per piece).
    while (step > eps && seg < spec.segments.size()) {
      const double h = std::min(step, seg_left);
      const TruckSegment& s = spec.segments[seg];
      const double dth = s.yaw_rate_radps * h;
      Eigen::Vector2d d;
      if (std::abs(dth) < 1e-12) {
        d = Eigen::Vector2d(s.speed_mps * h, 0.0);
      } else {
        const double r = s.speed_mps / s.yaw_rate_radps;
        d = Eigen::Vector2d(r * std::sin(dth), r * (1.0 - std::cos(dth)));
      }
      p += Eigen::Rotation2Dd(heading) * d;
      heading += dth;
      step -= h;
      seg_left -= h;
      if (seg_left <= eps) {
        ++seg;
        if (seg < spec.segments.size()) seg_left = spec.segments[seg].duration_s;
      }
    }
    if (step > eps) break;  // the drive ended between frames
    add(k * dt);
    ++k;
  }
  // Between frames the motion is a short arc; interpolating the frame poses (linear position,
  // slerp rotation) cuts its chord: 0.02 mm off for a 10 mm step on a 0.7 m circle (sagitta
  // s^2 / 8r), far below the sensor noise.
  const std::vector<Eigen::Isometry3d> poses = run.T_W_C;
  run.pose_at = [poses, dt](double t) {
    const double x = std::clamp(t / dt, 0.0, static_cast<double>(poses.size() - 1));
    const std::size_t a = static_cast<std::size_t>(std::floor(x));
    const std::size_t b = std::min(a + 1, poses.size() - 1);
    return interpolatePose(poses[a], poses[b], x - static_cast<double>(a));
  };
  return run;
}

namespace {

TrackRunSpec rtSpec(const std::string& name, double speed_mmps, double duration_s,
                    TrackRunSpec::Axis axis, double amplitude_deg, double frequency_hz) {
  TrackRunSpec s;
  s.name = name;
  std::ostringstream d;
  d << "ServoTrack real-time run " << name << " (thesis table 5.4): " << speed_mmps
    << " mm/s achieved for " << duration_s << " s";
  if (axis != TrackRunSpec::Axis::kNone)
    d << ", " << (axis == TrackRunSpec::Axis::kPitch ? "pitch" : "yaw") << " +-" << amplitude_deg
      << " deg at " << frequency_hz << " Hz";
  s.description = d.str();
  s.speed_mps = speed_mmps / 1000.0;
  s.duration_s = duration_s;
  s.axis = axis;
  s.amplitude_deg = amplitude_deg;
  s.frequency_hz = frequency_hz;
  return s;
}

}  // namespace

namespace {
// Smoothstep 3u^2 - 2u^3 on [0, 1] and its integral u^3 - u^4 / 2 (clamped outside).
double smooth(double u) {
  u = std::clamp(u, 0.0, 1.0);
  return u * u * (3.0 - 2.0 * u);
}
double smoothIntegral(double u) {
  if (u <= 0.0) return 0.0;
  if (u >= 1.0) return 0.5 + (u - 1.0);
  return u * u * u - 0.5 * u * u * u * u;
}

// wall_slide: a camera carried along a wall in wallCabinetScene(). 0-0.6 s at rest looking at
// the furnished +x side; 0.6-1.4 s speeding up to 0.15 m/s along -x (still looking at the
// furnished side); 1.4-2.4 s turning left to face the +y wall at that speed; 2.4-5.4 s square on
// to the wall and cabinet, sliding along them (the degenerate stretch); 5.4-6.4 s turning back;
// 6.4-7.2 s slowing down; 7.2-8 s at rest looking at the furnished side again. The speed is
// constant while the view is degenerate: no depth sensor sees motion along a bare wall, so the
// motion prior is all a tracker has there. A small pitch sway throughout (pitch stays
// observable square on to a wall).
RenderedRun makeWallSlideRun() {
  RenderedRun run;
  run.name = "wall_slide";
  run.description =
      "camera carried along a wall at 0.15 m/s: furnished side, then 3 s square on to the wall "
      "with a parallel cabinet front and picture, then back to the furnished side";
  run.scene = wallCabinetScene();
  const double speed = 0.15, x0 = 0.45, ramp = 0.8;
  auto pose = [=](double t) {
    const double x =
        x0 - speed * ramp * (smoothIntegral((t - 0.6) / ramp) - smoothIntegral((t - 6.4) / ramp));
    const double yaw = 0.5 * M_PI * (smooth(t - 1.4) - smooth(t - 5.4));
    const double pitch = 0.3 * M_PI / 180.0 * std::sin(2.0 * M_PI * 0.9 * t);
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = Eigen::Vector3d(x, 0.4, 1.3);
    T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(-pitch, Eigen::Vector3d::UnitY()))
                     .toRotationMatrix() *
                 rotationBodyFromOptical();
    return T;
  };
  const double dt = 1.0 / 30.0;
  for (int k = 0; k <= 240; ++k) {
    run.stamps_s.push_back(k * dt);
    run.T_W_C.push_back(pose(k * dt));
  }
  run.pose_at = pose;
  return run;
}
}  // namespace

std::vector<std::string> knownRuns() {
  return {"xtest1_05_chair", "chair_still", "rt1",   "rt2",       "rt3", "rt4", "rt5", "rt6",
          "chair3",          "room3",       "hall1", "wall_slide"};
}

RenderedRun makeRun(const std::string& name) {
  using Axis = TrackRunSpec::Axis;
  if (name == "xtest1_05_chair") {
    TrackRunSpec s;
    s.name = name;
    s.description =
        "ServoTrack Mode 2 (thesis 5.3): 3 still frames, then 100 steps of 10 mm towards the "
        "chair, no rotation; chair back 2.16 m and back wall 3.2 m ahead at the start";
    s.still_frames = 3;
    s.step_m = 0.010;
    s.steps = 100;
    return makeTrackRun(s, chairRoomScene());
  }
  if (name == "chair_still") {
    // The thesis's stationary check (5.3.1): the same scene seen repeatedly must not drift.
    TrackRunSpec s;
    s.name = name;
    s.description = "ServoTrack at rest at the XTest1_05_Chair start pose for 3 s (90 frames)";
    s.speed_mps = 0.0;
    s.duration_s = 3.0;
    return makeTrackRun(s, chairRoomScene());
  }
  if (name == "rt1") return makeTrackRun(rtSpec(name, 95, 12, Axis::kNone, 0, 0), chairRoomScene());
  if (name == "rt2")
    return makeTrackRun(rtSpec(name, 95, 12, Axis::kYaw, 10, 1.0 / 12), chairRoomScene());
  if (name == "rt3")
    return makeTrackRun(rtSpec(name, 42, 25, Axis::kPitch, 20, 1.0 / 12.6), chairRoomScene());
  if (name == "rt4") return makeTrackRun(rtSpec(name, 42, 25, Axis::kNone, 0, 0), chairRoomScene());
  if (name == "rt5")
    return makeTrackRun(rtSpec(name, 95, 12, Axis::kYaw, 15, 1.0 / 24), chairRoomScene());
  if (name == "rt6")
    return makeTrackRun(rtSpec(name, 95, 12, Axis::kPitch, 15, 1.0 / 24), chairRoomScene());
  if (name == "chair3") {
    TruckRunSpec s;
    s.name = name;
    s.description =
        "ServoTruck Chair3 (thesis 5.5.1): straight at the chair from 2.5 m, 1.5 m at 0.3 m/s";
    s.start_xy_m = Eigen::Vector2d(2.16 - 2.5 - 0.12, 0.0);
    s.segments = {{5.0, 0.30, 0.0}};
    return makeTruckRun(s, chairRoomScene());
  }
  if (name == "room3") {
    TruckRunSpec s;
    s.name = name;
    s.description =
        "ServoTruck Room3 (thesis 5.5.2): two anti-clockwise laps of a 0.7 m radius circle at "
        "0.3 m/s in a furnished room";
    const double radius = 0.7, speed = 0.30;
    s.start_xy_m = Eigen::Vector2d(0.0, -radius);
    s.start_heading_rad = 0.0;
    const double omega = speed / radius;
    s.segments = {{2.0 * 2.0 * M_PI / omega, speed, omega}};
    return makeTruckRun(s, furnishedRoomScene());
  }
  if (name == "hall1") {
    TruckRunSpec s;
    s.name = name;
    s.description = "ServoTruck Hall1 (thesis 5.5.5): 8 m along a hallway at 0.3 m/s";
    s.start_xy_m = Eigen::Vector2d(0.0, 0.0);
    s.segments = {{8.0 / 0.30, 0.30, 0.0}};
    return makeTruckRun(s, hallwayScene());
  }
  if (name == "wall_slide") return makeWallSlideRun();
  std::string known;
  for (const auto& k : knownRuns()) known += (known.empty() ? "" : ", ") + k;
  throw std::invalid_argument("unknown run '" + name + "' (known: " + known + ")");
}

}  // namespace sim
}  // namespace depth_track
