#include "depth_track/core/evaluation.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/se3.hpp"

namespace depth_track {

namespace {

void checkPairs(std::size_t est, std::size_t gt, std::size_t min_count, const char* what) {
  if (est != gt) {
    throw std::invalid_argument(std::string(what) + ": " + std::to_string(est) +
                                " estimated poses but " + std::to_string(gt) +
                                " ground-truth poses");
  }
  if (est < min_count) {
    throw std::invalid_argument(std::string(what) + ": needs at least " +
                                std::to_string(min_count) + " associated poses, got " +
                                std::to_string(est));
  }
}

double wrapDeg(double a) {
  a = std::fmod(a, 360.0);
  if (a > 180.0) a -= 360.0;
  if (a <= -180.0) a += 360.0;
  return a;
}

}  // namespace

Eigen::Vector3d thesisEulerFromRotation(const Eigen::Matrix3d& R) {
  // R = Ry(θy) Rx(θx) Rz(θz):
  //   R(1,2) = -sin θx,  R(0,2) = cos θx sin θy,  R(2,2) = cos θx cos θy,
  //   R(1,0) = cos θx sin θz,  R(1,1) = cos θx cos θz.
  const double sx = std::clamp(-R(1, 2), -1.0, 1.0);
  const double theta_x = std::asin(sx);
  const double cx = std::sqrt(R(1, 0) * R(1, 0) + R(1, 1) * R(1, 1));
  double theta_y, theta_z;
  if (cx > 1e-9) {
    theta_y = std::atan2(R(0, 2), R(2, 2));
    theta_z = std::atan2(R(1, 0), R(1, 1));
  } else {
    // Gimbal lock: only θy +- θz is defined; take θz = 0, then R = Ry Rx and
    // R(0,0) = cos θy, R(2,0) = -sin θy.
    theta_z = 0.0;
    theta_y = std::atan2(-R(2, 0), R(0, 0));
  }
  return {theta_x, theta_y, theta_z};
}

Eigen::Matrix3d rotationFromThesisEuler(const Eigen::Vector3d& t) {
  return (Eigen::AngleAxisd(t.y(), Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(t.x(), Eigen::Vector3d::UnitX()) *
          Eigen::AngleAxisd(t.z(), Eigen::Vector3d::UnitZ()))
      .toRotationMatrix();
}

Eigen::Isometry3d alignRigid(const std::vector<Eigen::Vector3d>& p_est,
                             const std::vector<Eigen::Vector3d>& p_gt) {
  checkPairs(p_est.size(), p_gt.size(), 2, "rigid alignment");
  const double n = static_cast<double>(p_est.size());
  Eigen::Vector3d mu_e = Eigen::Vector3d::Zero(), mu_g = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < p_est.size(); ++i) {
    mu_e += p_est[i] / n;
    mu_g += p_gt[i] / n;
  }
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();  // cross-covariance est -> gt
  for (std::size_t i = 0; i < p_est.size(); ++i)
    H += (p_est[i] - mu_e) * (p_gt[i] - mu_g).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d& U = svd.matrixU();
  const Eigen::Matrix3d& V = svd.matrixV();
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (V * U.transpose()).determinant() < 0.0 ? -1.0 : 1.0;  // a rotation, never a mirror
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = V * D * U.transpose();
  T.translation() = mu_g - T.linear() * mu_e;
  return T;
}

AteRpe computeAteRpe(const std::vector<Eigen::Isometry3d>& est,
                     const std::vector<Eigen::Isometry3d>& gt) {
  checkPairs(est.size(), gt.size(), 2, "ATE/RPE");
  AteRpe r;
  r.frames = est.size();
  std::vector<Eigen::Vector3d> pe(est.size()), pg(gt.size());
  for (std::size_t i = 0; i < est.size(); ++i) {
    pe[i] = est[i].translation();
    pg[i] = gt[i].translation();
  }
  r.T_gt_est = alignRigid(pe, pg);
  double sum2 = 0.0;
  for (std::size_t i = 0; i < pe.size(); ++i) {
    const double e = (r.T_gt_est * pe[i] - pg[i]).norm();
    sum2 += e * e;
    r.ate_max_m = std::max(r.ate_max_m, e);
  }
  r.ate_rmse_m = std::sqrt(sum2 / pe.size());

  std::vector<std::pair<std::size_t, std::size_t>> steps;
  for (std::size_t i = 0; i + 1 < est.size(); ++i) steps.emplace_back(i, i + 1);
  const RelativeError rpe = relativePoseError(est, gt, steps);
  r.rpe_1f_m = rpe.rms_m;
  r.rpe_1f_deg = rpe.rms_deg;
  return r;
}

RelativeError relativePoseError(const std::vector<Eigen::Isometry3d>& est,
                                const std::vector<Eigen::Isometry3d>& gt,
                                const std::vector<std::pair<std::size_t, std::size_t>>& pairs) {
  checkPairs(est.size(), gt.size(), 0, "relative pose error");
  RelativeError r;
  double t2 = 0.0, a2 = 0.0;
  for (const auto& [i, j] : pairs) {
    if (i >= est.size() || j >= est.size()) {
      throw std::invalid_argument("relative pose error: pair (" + std::to_string(i) + ", " +
                                  std::to_string(j) + ") outside " + std::to_string(est.size()) +
                                  " poses");
    }
    const Eigen::Isometry3d E = (gt[i].inverse() * gt[j]).inverse() * (est[i].inverse() * est[j]);
    t2 += E.translation().squaredNorm();
    const double a = Eigen::AngleAxisd(E.rotation()).angle() * kRadToDeg;
    a2 += a * a;
    ++r.pairs;
  }
  if (r.pairs > 0) {
    r.rms_m = std::sqrt(t2 / r.pairs);
    r.rms_deg = std::sqrt(a2 / r.pairs);
  }
  return r;
}

std::vector<std::pair<std::size_t, std::size_t>> pairsOverTime(const std::vector<double>& stamps,
                                                               double delta_s) {
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  std::size_t j = 0;
  for (std::size_t i = 0; i < stamps.size(); ++i) {
    j = std::max(j, i + 1);
    while (j < stamps.size() && stamps[j] < stamps[i] + delta_s - 1e-6) ++j;
    if (j >= stamps.size()) break;
    pairs.emplace_back(i, j);
  }
  return pairs;
}

std::vector<FrameError> frameErrors(const std::vector<Eigen::Isometry3d>& est,
                                    const std::vector<Eigen::Isometry3d>& gt) {
  checkPairs(est.size(), gt.size(), 1, "frame errors");
  const Eigen::Isometry3d T_C0_W_est = est.front().inverse();
  const Eigen::Isometry3d T_C0_W_gt = gt.front().inverse();
  std::vector<FrameError> out(est.size());
  for (std::size_t i = 0; i < est.size(); ++i) {
    const Eigen::Isometry3d e = T_C0_W_est * est[i];  // T_S_C of the estimate
    const Eigen::Isometry3d g = T_C0_W_gt * gt[i];
    FrameError& f = out[i];
    f.rot_err_deg = logSO3(g.rotation().transpose() * e.rotation()) * kRadToDeg;
    f.pos_est_mm = 1000.0 * e.translation();
    f.pos_gt_mm = 1000.0 * g.translation();
    f.pos_err_mm = f.pos_est_mm - f.pos_gt_mm;
    f.euler_est_deg = thesisEulerFromRotation(e.rotation()) * kRadToDeg;
    f.euler_gt_deg = thesisEulerFromRotation(g.rotation()) * kRadToDeg;
    for (int k = 0; k < 3; ++k)
      f.euler_err_deg(k) = wrapDeg(f.euler_est_deg(k) - f.euler_gt_deg(k));
  }
  return out;
}

ThesisErrors computeThesisErrors(const std::vector<Eigen::Isometry3d>& est,
                                 const std::vector<Eigen::Isometry3d>& gt) {
  checkPairs(est.size(), gt.size(), 2, "thesis errors");
  const std::vector<FrameError> errs = frameErrors(est, gt);
  ThesisErrors t;
  t.frames = errs.size();
  for (const FrameError& f : errs) {
    t.max_err_deg = t.max_err_deg.cwiseMax(f.rot_err_deg.cwiseAbs());
    t.max_err_mm = t.max_err_mm.cwiseMax(f.pos_err_mm.cwiseAbs());
    t.max_euler_err_deg = t.max_euler_err_deg.cwiseMax(f.euler_err_deg.cwiseAbs());
  }
  t.end_drift_mm = errs.back().pos_err_mm.norm();
  return t;
}

TrajectoryEvaluation evaluateTrajectory(const Trajectory& est, const Trajectory& gt,
                                        double max_gap_s) {
  const AssociatedTrajectories a = associateTrajectories(est, gt, max_gap_s);
  if (a.est_T_W_C.size() < 2) {
    throw std::invalid_argument(
        "trajectory evaluation: only " + std::to_string(a.est_T_W_C.size()) + " of " +
        std::to_string(est.size()) + " estimated poses have ground truth within " +
        std::to_string(max_gap_s) + " s (need 2)");
  }
  TrajectoryEvaluation e;
  e.est_poses = est.size();
  e.standard = computeAteRpe(a.est_T_W_C, a.gt_T_W_C);
  e.rpe_1s = relativePoseError(a.est_T_W_C, a.gt_T_W_C, pairsOverTime(a.stamps_s, 1.0));
  e.thesis = computeThesisErrors(a.est_T_W_C, a.gt_T_W_C);
  return e;
}

std::string formatEvaluation(const TrajectoryEvaluation& e) {
  char buf[512];
  const ThesisErrors& t = e.thesis;
  std::snprintf(buf, sizeof(buf),
                "frames=%zu ate_rmse_m=%.4f rpe_1f_m=%.4f\n"
                "frames=%zu max_err_deg=%.3f,%.3f,%.3f max_err_mm=%.2f,%.2f,%.2f "
                "end_drift_mm=%.2f",
                e.standard.frames, e.standard.ate_rmse_m, e.standard.rpe_1f_m, t.frames,
                t.max_err_deg.x(), t.max_err_deg.y(), t.max_err_deg.z(), t.max_err_mm.x(),
                t.max_err_mm.y(), t.max_err_mm.z(), t.end_drift_mm);
  return buf;
}

// ---- a run against its references --------------------------------------------------------------

namespace {

std::string fmt(const char* format, ...) __attribute__((format(printf, 1, 2)));
std::string fmt(const char* format, ...) {
  char buf[1024];
  va_list args;
  va_start(args, format);
  std::vsnprintf(buf, sizeof(buf), format, args);
  va_end(args);
  return buf;
}

double rms(const std::vector<double>& v) {
  if (v.empty()) return 0.0;
  double s = 0.0;
  for (const double x : v) s += x * x;
  return std::sqrt(s / v.size());
}

}  // namespace

ReferenceScore scoreAgainst(const Trajectory& est, const Reference& reference, double max_gap_s) {
  ReferenceScore r;
  r.name = reference.name;
  r.exact = reference.exact;
  r.reference_poses = reference.poses.size();
  std::vector<double> est_s(est.size()), ref_s(reference.poses.size());
  for (std::size_t i = 0; i < est.size(); ++i) est_s[i] = est[i].stamp_s;
  for (std::size_t i = 0; i < ref_s.size(); ++i) ref_s[i] = reference.poses[i].stamp_s;
  std::vector<Eigen::Isometry3d> e, g;
  for (const auto& [ie, ir] : associateStamps(est_s, ref_s, max_gap_s)) {
    if (!est[ie].T_W_C.matrix().allFinite() || !reference.poses[ir].T_W_C.matrix().allFinite())
      continue;
    r.est_index.push_back(ie);
    r.stamps_s.push_back(est[ie].stamp_s);
    e.push_back(est[ie].T_W_C);
    g.push_back(reference.poses[ir].T_W_C);
  }
  if (e.size() < 2) {
    r.problem = fmt("only %zu of %zu frames have a %s pose within %.3f s (need 2)", e.size(),
                    est.size(), reference.name.c_str(), max_gap_s);
    if (!e.empty()) r.frames = frameErrors(e, g);
    return r;
  }
  r.frames = frameErrors(e, g);
  TrajectoryEvaluation ev;
  ev.est_poses = est.size();
  ev.standard = computeAteRpe(e, g);
  ev.rpe_1s = relativePoseError(e, g, pairsOverTime(r.stamps_s, 1.0));
  ev.thesis = computeThesisErrors(e, g);
  r.evaluation = ev;
  return r;
}

LatencyScan scanSensorLatency(const Trajectory& trajectory, const RigSensorStreams& streams,
                              const RigGeometry& geometry, int max_shift) {
  if (max_shift < 0) throw std::invalid_argument("latency scan: max shift must be >= 0");
  if (!streams.hasServoTrack() && !streams.hasServoTruck())
    throw std::invalid_argument("latency scan: no sensor stream");
  LatencyScan scan;
  scan.period_s = streams.samplePeriod();
  if (!(scan.period_s > 0.0))
    throw std::invalid_argument("latency scan: the sensor stream has fewer than 2 samples");
  std::vector<double> stamps;
  std::map<double, Eigen::Isometry3d> poses;
  for (const StampedPose& p : trajectory)
    if (p.T_W_C.matrix().allFinite() && poses.emplace(p.stamp_s, p.T_W_C).second)
      stamps.push_back(p.stamp_s);
  // Every shift's reference, then the frames all of them cover (the same frames at every shift).
  std::vector<std::map<double, Eigen::Isometry3d>> refs;
  std::map<double, int> covered;
  for (int k = -max_shift; k <= max_shift; ++k) {
    std::map<double, Eigen::Isometry3d> m;
    for (const StampedPose& p : sensorTrajectory(streams, stamps, geometry, k * scan.period_s)) {
      m.emplace(p.stamp_s, p.T_W_C);
      ++covered[p.stamp_s];
    }
    refs.push_back(std::move(m));
  }
  std::vector<double> common;
  for (const auto& [t, n] : covered)
    if (n == static_cast<int>(refs.size())) common.push_back(t);
  if (common.size() < 2)
    throw std::invalid_argument(
        fmt("latency scan: only %zu frames lie within the sensor stream "
            "at every shift of +-%d intervals (need 2)",
            common.size(), max_shift));
  scan.frames = common.size();
  std::vector<Eigen::Isometry3d> est;
  for (const double t : common) est.push_back(poses.at(t));
  double best_rot = std::numeric_limits<double>::infinity(), best_pos = best_rot;
  double turned_deg = 0.0;
  for (int k = -max_shift; k <= max_shift; ++k) {
    const auto& m = refs[k + max_shift];
    std::vector<Eigen::Isometry3d> ref;
    for (const double t : common) ref.push_back(m.at(t));
    std::vector<double> rot, pos;
    for (const FrameError& f : frameErrors(est, ref)) {
      rot.push_back(f.rot_err_deg.norm());
      pos.push_back(f.pos_err_mm.norm());
      if (k == 0) turned_deg = std::max(turned_deg, f.euler_gt_deg.cwiseAbs().maxCoeff());
    }
    scan.shifts.push_back(k);
    scan.rms_rot_deg.push_back(rms(rot));
    scan.rms_pos_mm.push_back(rms(pos));
    // Ties go to the smaller shift: a flat curve does not claim a latency.
    const auto better = [k](double v, double best, int best_k) {
      return v < best - 1e-12 || (std::abs(v - best) <= 1e-12 && std::abs(k) < std::abs(best_k));
    };
    if (better(scan.rms_rot_deg.back(), best_rot, scan.best_rot_shift)) {
      best_rot = scan.rms_rot_deg.back();
      scan.best_rot_shift = k;
    }
    if (better(scan.rms_pos_mm.back(), best_pos, scan.best_pos_shift)) {
      best_pos = scan.rms_pos_mm.back();
      scan.best_pos_shift = k;
    }
  }
  // Latency shows on the moving axis: the gimbal when it turns, else the carriage or truck.
  const bool by_rot = turned_deg > 1.0;
  scan.criterion = by_rot ? "rotation" : "position";
  scan.best_shift = by_rot ? scan.best_rot_shift : scan.best_pos_shift;
  // A minimum means a latency when the curve rises from it, two steps to either side, by more
  // than three times the curve's own jitter. The jitter is estimated from third differences
  // (zero on any smooth parabola- or V-shaped curve; 20 sigma^2 in variance for independent
  // noise), robustly through their median: sensor noise that picks other readings at each shift
  // makes dips anywhere, motion makes one clear valley.
  // Besides, a rise must exceed a floor far below any rig sensor's resolution (pot and encoder
  // steps are tenths of a degree / millimetres) but above rounding: an almost exact curve (a
  // truck's heading integrated from the same steering at every shift) has no jitter at all.
  constexpr double kMinRiseDeg = 1e-3, kMinRiseMm = 1e-2;
  const auto judge = [max_shift](const std::vector<double>& c, int best, double min_rise,
                                 double* rise, double* jitter) {
    const int i = best + max_shift;
    if (max_shift < 4 || std::abs(best) > max_shift - 2) return false;
    std::vector<double> d3;
    for (std::size_t j = 0; j + 3 < c.size(); ++j)
      d3.push_back(std::abs(c[j + 3] - 3.0 * c[j + 2] + 3.0 * c[j + 1] - c[j]));
    std::nth_element(d3.begin(), d3.begin() + d3.size() / 2, d3.end());
    *jitter = d3[d3.size() / 2] / 0.6745 / std::sqrt(20.0);
    *rise = std::min(c[i - 2], c[i + 2]) - c[i];
    return *rise > 3.0 * *jitter && *rise > min_rise;
  };
  scan.rot_resolved = judge(scan.rms_rot_deg, scan.best_rot_shift, kMinRiseDeg, &scan.rise_rot_deg,
                            &scan.jitter_rot_deg);
  scan.pos_resolved = judge(scan.rms_pos_mm, scan.best_pos_shift, kMinRiseMm, &scan.rise_pos_mm,
                            &scan.jitter_pos_mm);
  scan.resolved = by_rot ? scan.rot_resolved : scan.pos_resolved;
  const double rise = by_rot ? scan.rise_rot_deg : scan.rise_pos_mm;
  const double jitter = by_rot ? scan.jitter_rot_deg : scan.jitter_pos_mm;
  const char* unit = by_rot ? "deg" : "mm";
  if (max_shift < 4)
    scan.verdict = "not resolved: a scan of fewer than +-4 steps cannot tell a valley from noise";
  else if (std::abs(scan.best_shift) > max_shift - 2)
    scan.verdict =
        fmt("not resolved: the minimum (%+d) lies within two steps of the scan's edge; "
            "the latency may be larger, scan further",
            scan.best_shift);
  else if (!scan.resolved)
    scan.verdict =
        fmt("not resolved: two steps either side the error rises by only %.3g %s (needs "
            "more than 3x the curve's jitter of %.3g %s and %g %s: the rig moved too little on "
            "this axis; the dips are the readings' noise)",
            rise, unit, jitter, unit, by_rot ? kMinRiseDeg : kMinRiseMm, unit);
  else
    scan.verdict =
        fmt("resolved: two steps either side the error rises by %.3g %s, above 3x the "
            "curve's jitter of %.3g %s",
            rise, unit, jitter, unit);
  return scan;
}

RunEvaluation evaluateRun(const Trajectory& est, const RunReferences& refs,
                          const RunEvaluationOptions& options) {
  RunEvaluation run;
  const std::string gt_name =
      "ground truth" + (refs.ground_truth_name.empty() ? "" : " " + refs.ground_truth_name);
  const std::string sensor_name = "rig sensors (" + refs.sensors.describe() + ")";
  const bool have_sensors = refs.sensors.hasServoTrack() || refs.sensors.hasServoTruck();
  if (est.size() < 2)
    run.notes.push_back(fmt("only %zu tracked poses: nothing to score", est.size()));
  if (!refs.ground_truth.empty()) {
    run.scores.push_back(scoreAgainst(est, {gt_name, true, refs.ground_truth}, options.max_gap_s));
  } else {
    run.notes.push_back("no ground truth (/rig_sim/camera_pose or /ground_truth/camera_pose)");
  }
  Trajectory sensor_traj;
  if (have_sensors) {
    std::vector<double> stamps;
    for (const StampedPose& p : est) stamps.push_back(p.stamp_s);
    sensor_traj = sensorTrajectory(refs.sensors, stamps, refs.geometry);
    // The sensor poses are made at the frames' own stamps: association is exact.
    run.scores.push_back(scoreAgainst(est, {sensor_name, false, sensor_traj}, 1e-9));
  } else if (!refs.sensors.track.empty() || !refs.sensors.gimbal.empty()) {
    run.notes.push_back(refs.sensors.track.empty()
                            ? "carriage_sensors without track_state: no sensor reference"
                            : "track_state without carriage_sensors: no sensor reference");
  } else {
    run.notes.push_back(
        "no rig sensor topics (track_state + carriage_sensors, or truck_rc): no sensor reference");
  }
  for (std::size_t i = 0; i < run.scores.size(); ++i) {
    if (run.scores[i].evaluation) {
      if (run.table < 0) run.table = static_cast<int>(i);
    } else {
      run.notes.push_back(run.scores[i].name + ": " + run.scores[i].problem);
    }
  }
  if (have_sensors && !refs.ground_truth.empty() && sensor_traj.size() >= 2) {
    run.sensors_vs_truth =
        scoreAgainst(sensor_traj, {gt_name, true, refs.ground_truth}, options.max_gap_s);
  }
  if (options.latency_scan > 0 && have_sensors) {
    try {
      run.latency = scanSensorLatency(est, refs.sensors, refs.geometry, options.latency_scan);
    } catch (const std::invalid_argument& e) {
      run.notes.push_back(std::string("no latency scan against the track: ") + e.what());
    }
    if (!refs.ground_truth.empty()) {
      // Ground truth at the tracked frames' stamps, so both scans score the same frames.
      const AssociatedTrajectories a =
          associateTrajectories(est, refs.ground_truth, options.max_gap_s);
      Trajectory gt;
      for (std::size_t i = 0; i < a.stamps_s.size(); ++i)
        gt.push_back({a.stamps_s[i], a.gt_T_W_C[i]});
      try {
        run.sensor_latency =
            scanSensorLatency(gt, refs.sensors, refs.geometry, options.latency_scan);
      } catch (const std::invalid_argument& e) {
        run.notes.push_back(std::string("no latency scan against ground truth: ") + e.what());
      }
    }
  } else if (options.latency_scan > 0) {
    run.notes.push_back("no latency scan: it needs the rig's sensor topics");
  }
  return run;
}

namespace {

std::string tableRow(const ReferenceScore& s, bool marked) {
  if (!s.evaluation)
    return fmt("%s %-46s  no score: %s", marked ? "*" : " ", s.name.c_str(), s.problem.c_str());
  const ThesisErrors& t = s.evaluation->thesis;
  return fmt("%s %-46s %6zu %7.3f %7.3f %7.3f | %7.2f %7.2f %7.2f | %8.2f", marked ? "*" : " ",
             s.name.c_str(), t.frames, t.max_err_deg.x(), t.max_err_deg.y(), t.max_err_deg.z(),
             t.max_err_mm.x(), t.max_err_mm.y(), t.max_err_mm.z(), t.end_drift_mm);
}

std::string standardLine(const ReferenceScore& s) {
  if (!s.evaluation) return "";
  const TrajectoryEvaluation& e = *s.evaluation;
  return fmt(
      "  %-46s ATE RMSE %.4f m (max %.4f m), RPE 1 frame %.4f m / %.3f deg, RPE 1 s %.4f m "
      "/ %.3f deg (%zu pairs), end drift %.2f mm",
      s.name.c_str(), e.standard.ate_rmse_m, e.standard.ate_max_m, e.standard.rpe_1f_m,
      e.standard.rpe_1f_deg, e.rpe_1s.rms_m, e.rpe_1s.rms_deg, e.rpe_1s.pairs,
      e.thesis.end_drift_mm);
}

std::string scanLines(const LatencyScan& l, const std::string& against) {
  std::string out = fmt(
      "latency scan, the sensor stream shifted against %s (%zu frames; one step = %.1f ms; +k = "
      "the sensors lag the camera by k steps):\n",
      against.c_str(), l.frames, 1000.0 * l.period_s);
  out += "  shift      ";
  for (const int k : l.shifts) out += fmt(" %+6d", k);
  out += "\n  rms_deg    ";
  for (const double v : l.rms_rot_deg) out += fmt(" %6.3f", v);
  out += "\n  rms_mm     ";
  for (const double v : l.rms_pos_mm) out += fmt(" %6.2f", v);
  out +=
      fmt("\n  best shift %+d steps (%+.0f ms) by %s error; by rotation %+d%s, by position %+d%s\n",
          l.best_shift, 1000.0 * l.best_shift * l.period_s, l.criterion.c_str(), l.best_rot_shift,
          l.rot_resolved ? "" : " (not resolved)", l.best_pos_shift,
          l.pos_resolved ? "" : " (not resolved)");
  out += "  " + l.verdict + "\n";
  return out;
}

}  // namespace

std::string formatRunEvaluation(const RunEvaluation& run) {
  std::string out;
  out +=
      "thesis-style table: max |error| per axis over the run, both trajectories relative to their "
      "first pose\n"
      "  (errTx/Ty/Tz: rotation error about camera x = pitch, y = yaw, z = roll, deg; errDx/Dy/Dz: "
      "position error along camera x = sway, y = heave, z = surge, mm)\n";
  out += fmt("  %-46s %6s %7s %7s %7s | %7s %7s %7s | %8s\n", "reference", "frames", "errTx",
             "errTy", "errTz", "errDx", "errDy", "errDz", "drift_mm");
  for (std::size_t i = 0; i < run.scores.size(); ++i)
    out += tableRow(run.scores[i], static_cast<int>(i) == run.table) + "\n";
  if (run.table >= 0) {
    out += "  * the reference of the summary line: " + run.scores[run.table].name +
           (run.scores[run.table].exact
                ? " (exact; the sensor row includes the sensors' own errors)\n"
                : " (the bag has no ground truth: sensor errors count as tracking errors)\n");
  }
  out += "thesis Euler angles (pitch θx, yaw θy, roll θz, eq. 2.59), max |error|, deg:\n";
  for (const ReferenceScore& s : run.scores)
    if (s.evaluation) {
      const Eigen::Vector3d& e = s.evaluation->thesis.max_euler_err_deg;
      out += fmt("  %-46s %7.3f %7.3f %7.3f\n", s.name.c_str(), e.x(), e.y(), e.z());
    }
  out += "standard metrics (ATE after rigid alignment, no scale):\n";
  for (const ReferenceScore& s : run.scores)
    if (s.evaluation) out += standardLine(s) + "\n";
  if (run.sensors_vs_truth) {
    out += "the rig sensors against ground truth (the sensor reference's own error):\n";
    ReferenceScore s = *run.sensors_vs_truth;
    s.name = "sensors vs " + s.name;
    out += tableRow(s, false) + "\n" + standardLine(s) + "\n";
  }
  if (run.latency) out += scanLines(*run.latency, "the tracked trajectory");
  if (run.sensor_latency) out += scanLines(*run.sensor_latency, "ground truth");
  for (const std::string& n : run.notes) out += "note: " + n + "\n";
  return out;
}

std::string formatSummaryFields(const RunEvaluation& run) {
  if (run.table < 0) return "ate_rmse_m=nan max_err_deg=nan,nan,nan max_err_mm=nan,nan,nan";
  const TrajectoryEvaluation& e = *run.scores[run.table].evaluation;
  const ThesisErrors& t = e.thesis;
  return fmt("ate_rmse_m=%.4f max_err_deg=%.3f,%.3f,%.3f max_err_mm=%.2f,%.2f,%.2f",
             e.standard.ate_rmse_m, t.max_err_deg.x(), t.max_err_deg.y(), t.max_err_deg.z(),
             t.max_err_mm.x(), t.max_err_mm.y(), t.max_err_mm.z());
}

// ---- link timing -------------------------------------------------------------------------------

LinkTiming summariseLinkTiming(const std::string& name,
                               const std::vector<LinkClockSample>& samples) {
  LinkTiming l;
  l.name = name;
  l.frames = samples.size();
  if (samples.size() < 3) return l;
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  std::vector<double> ds, dr;
  for (std::size_t i = 1; i < samples.size(); ++i) {
    ds.push_back(samples[i].sender_s - samples[i - 1].sender_s);
    dr.push_back(samples[i].receiver_s - samples[i - 1].receiver_s);
  }
  l.sender_period_ms = 1000.0 * median(ds);
  l.receiver_period_ms = 1000.0 * median(dr);
  double mean_dr = 0.0;
  for (const double d : dr) mean_dr += d / dr.size();
  double var_dr = 0.0;
  for (const double d : dr) var_dr += (d - mean_dr) * (d - mean_dr) / dr.size();
  l.receiver_period_sd_ms = 1000.0 * std::sqrt(var_dr);
  for (const double d : ds) l.gaps += d > 1.5 * median(ds) ? 1 : 0;
  // Delay = receiver - sender up to the clocks' offset and drift: a least-squares line against
  // the sender clock takes both out; the fastest frame is the zero of the latency.
  const double n = static_cast<double>(samples.size());
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  // Both relative to the first frame: an epoch-based receiver clock against a board clock from
  // zero differs by ~1e9 s, which would eat the microseconds.
  const double x0 = samples.front().sender_s, y0 = samples.front().receiver_s - x0;
  const auto delay = [&](const LinkClockSample& s) {
    return (s.receiver_s - y0 - x0) - (s.sender_s - x0);
  };
  for (const LinkClockSample& s : samples) {
    const double x = s.sender_s - x0, y = delay(s);
    sx += x, sy += y, sxx += x * x, sxy += x * y;
  }
  const double den = n * sxx - sx * sx;
  const double slope = std::abs(den) > 1e-18 ? (n * sxy - sx * sy) / den : 0.0;
  const double icpt = (sy - slope * sx) / n;
  l.drift_ms_per_s = 1000.0 * slope;
  std::vector<double> res;
  for (const LinkClockSample& s : samples)
    res.push_back(delay(s) - (icpt + slope * (s.sender_s - x0)));
  const double lo = *std::min_element(res.begin(), res.end());
  double mean = 0.0;
  for (double& r : res) {
    r = 1000.0 * (r - lo);
    mean += r / n;
  }
  double var = 0.0;
  for (const double r : res) var += (r - mean) * (r - mean) / n;
  std::vector<double> sorted = res;
  std::sort(sorted.begin(), sorted.end());
  l.latency_mean_ms = mean;
  l.latency_p95_ms = sorted[static_cast<std::size_t>(0.95 * (sorted.size() - 1))];
  l.latency_max_ms = sorted.back();
  l.jitter_ms = std::sqrt(var);
  return l;
}

std::string formatLinkTiming(const std::vector<LinkTiming>& links) {
  std::string out =
      fmt("  %-44s %6s %8s %8s %8s %8s | %8s %8s %8s %8s %5s\n", "link", "frames", "send_ms",
          "recv_ms", "recv_sd", "drift", "lat_mean", "lat_p95", "lat_max", "jitter", "gaps");
  out += fmt("  %-44s %6s %8s %8s %8s %8s | %8s %8s %8s %8s %5s\n", "", "", "period", "period",
             "ms", "ms/s", "ms", "ms", "ms", "ms", "");
  for (const LinkTiming& l : links) {
    if (l.frames < 3) {
      out += fmt("  %-44s %6zu  (too few frames to summarise)\n", l.name.c_str(), l.frames);
      continue;
    }
    out += fmt("  %-44s %6zu %8.2f %8.2f %8.2f %8.3f | %8.2f %8.2f %8.2f %8.2f %5zu\n",
               l.name.c_str(), l.frames, l.sender_period_ms, l.receiver_period_ms,
               l.receiver_period_sd_ms, l.drift_ms_per_s, l.latency_mean_ms, l.latency_p95_ms,
               l.latency_max_ms, l.jitter_ms, l.gaps);
  }
  out +=
      "  (latency above the link's fastest frame, after the clocks' relative drift is fitted "
      "out: unsynchronised clocks hide the fixed part)\n";
  return out;
}

}  // namespace depth_track
