#include "depth_track/core/evaluation.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace depth_track {

namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

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

Eigen::Vector3d rotationVector(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
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
    f.rot_err_deg = rotationVector(g.rotation().transpose() * e.rotation()) * kRadToDeg;
    f.pos_err_mm = 1000.0 * (e.translation() - g.translation());
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

}  // namespace depth_track
