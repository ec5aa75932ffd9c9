#include "depth_track/core/degeneracy.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

namespace depth_track {

namespace {
// Diagonal of S: rotation rows scaled by 1/L, so [L omega; u] is in metres throughout.
Vector6d scaleDiagonal(double L) {
  Vector6d s;
  s << 1.0 / L, 1.0 / L, 1.0 / L, 1.0, 1.0, 1.0;
  return s;
}
}  // namespace

std::vector<std::string> DegeneracyConfig::validate() const {
  std::vector<std::string> p;
  if (!(noise_margin >= 0.0)) p.push_back("degeneracy noise_margin must be >= 0");
  if (!(release_margin >= noise_margin)) {
    std::ostringstream s;
    s << "degeneracy_release_margin (" << release_margin << ") must be >= degeneracy_margin ("
      << noise_margin << "); set both (equal = no hysteresis)";
    p.push_back(s.str());
  }
  if (!(prior_sigma_m > 0.0)) p.push_back("degeneracy prior_sigma_m must be > 0 m");
  return p;
}

DegeneracyAnalysis analyseNormalEquations(const Matrix6d& H, double weight_sum,
                                          double length_scale_m) {
  DegeneracyAnalysis a;
  a.length_scale_m = length_scale_m > 1e-6 ? length_scale_m : 1.0;
  a.weight_sum = weight_sum;
  const Vector6d s = scaleDiagonal(a.length_scale_m);
  Matrix6d Hs = s.asDiagonal() * H * s.asDiagonal();
  Hs = 0.5 * (Hs + Hs.transpose());
  if (weight_sum > 0.0) Hs /= weight_sum;
  Eigen::SelfAdjointEigenSolver<Matrix6d> es(Hs);
  a.eigenvalues = es.eigenvalues().cwiseMax(0.0);
  a.eigenvectors = es.eigenvectors();
  const Vector6d w = s.asDiagonal() * a.eigenvectors.col(0);  // back to [omega; u]
  a.weakest = w.normalized();
  return a;
}

Vector6d noiseFloors(const DegeneracyAnalysis& a, const Matrix6d& H, const LeverMoments& m,
                     double sigma_n2) {
  if (!(m.wsum > 0.0)) return Vector6d::Zero();
  const double L = a.length_scale_m;
  const Eigen::Matrix3d s1x = skew(m.s1);
  Matrix6d M;
  M.topLeftCorner<3, 3>() = (m.s2.trace() * Eigen::Matrix3d::Identity() - m.s2) / (L * L);
  M.topRightCorner<3, 3>() = s1x / L;
  M.bottomLeftCorner<3, 3>() = -s1x / L;
  M.bottomRightCorner<3, 3>() = m.wsum * Eigen::Matrix3d::Identity();
  const Vector6d s = scaleDiagonal(L);
  M -= s.asDiagonal() * H * s.asDiagonal();
  Vector6d floors;
  for (int i = 0; i < 6; ++i) {
    const auto e = a.eigenvectors.col(i);
    floors(i) = std::max(0.0, e.dot(M * e)) * (sigma_n2 / m.wsum);
  }
  return floors;
}

void applyNoiseFloors(DegeneracyAnalysis* a, const Vector6d& floors, double sigma_e2_m2,
                      const DegeneracyConfig& config) {
  a->noise_floor = floors;
  a->gain.setOnes();
  a->degenerate = 0;
  if (!(config.noise_margin > 0.0) || !(sigma_e2_m2 > 0.0)) return;
  const double prior_info = 1.0 / (config.prior_sigma_m * config.prior_sigma_m);
  for (int i = 0; i < 6; ++i) {
    if (!(floors(i) > 0.0)) continue;
    const double excess = std::max(0.0, a->eigenvalues(i) - config.noise_margin * floors(i));
    const double info = excess * a->weight_sum / sigma_e2_m2;  // 1 / m^2 along the direction
    a->gain(i) = info / (info + prior_info);
    a->degenerate += a->gain(i) < 0.5;
  }
}

Vector6d solveConstrained(const DegeneracyAnalysis& a, const Vector6d& g) {
  // H x = -g with H = S^-1 (wsum Hn) S^-1 gives y = S^-1 x = (wsum Hn)^-1 S (-g).
  const Vector6d s = scaleDiagonal(a.length_scale_m);
  const Vector6d b = -(s.asDiagonal() * g);
  const double wsum = a.weight_sum > 0.0 ? a.weight_sum : 1.0;
  // Relative floor: a direction with no information at all gets no step.
  const double floor = 1e-9 * std::max(a.eigenvalues(5), 1e-300);
  Vector6d y = Vector6d::Zero();
  for (int i = 0; i < 6; ++i) {
    const double lambda = a.eigenvalues(i);
    if (!(lambda > floor) || a.gain(i) <= 0.0) continue;
    const auto v = a.eigenvectors.col(i);
    y += v * (a.gain(i) * v.dot(b) / (lambda * wsum));
  }
  return s.asDiagonal() * y;
}

Eigen::Isometry3d withPriorAlongDegenerate(const DegeneracyAnalysis& a,
                                           const Eigen::Isometry3d& T_reg,
                                           const Eigen::Isometry3d& T_prior) {
  if ((a.gain.array() >= 1.0).all()) return T_reg;
  // The difference as a rotation about T_reg's camera centre and the centre's displacement,
  // scaled like the analysis. Each held mode takes the prior of its dominant kind: a mode that is
  // mostly a rotation (the roll about a wall's normal) the prior's rotation, one that is mostly
  // a translation (sliding along the wall) the prior's translation. The modes of a real view mix
  // in a little of the other kind, so projecting the whole difference would let the prior's
  // error in a direction the view fixes (a smoothed rotation rate lags every turn) leak in.
  const Eigen::AngleAxisd d(T_prior.rotation() * T_reg.rotation().transpose());
  Vector6d y_rot = Vector6d::Zero(), y_trans = Vector6d::Zero();
  y_rot.head<3>() = a.length_scale_m * d.angle() * d.axis();
  y_trans.tail<3>() = T_prior.translation() - T_reg.translation();
  Vector6d yd = Vector6d::Zero();
  for (int i = 0; i < 6; ++i) {
    const double hold = 1.0 - a.gain(i);
    if (hold <= 0.0) continue;
    const auto v = a.eigenvectors.col(i);
    const bool rotational = v.head<3>().squaredNorm() > v.tail<3>().squaredNorm();
    yd += hold * v * v.dot(rotational ? y_rot : y_trans);
  }
  Eigen::Isometry3d T = T_reg;
  T.linear() = expSO3(yd.head<3>() / a.length_scale_m) * T_reg.rotation();
  T.translation() = T_reg.translation() + yd.tail<3>();
  return T;
}

namespace {
// Sum over the eigenvectors of var(i, lambda_i wsum) v_i v_i^T, scaled back to [omega; u].
template <class Variance>
Matrix6d covarianceAlongModes(const DegeneracyAnalysis& a, const Variance& variance) {
  const Vector6d s = scaleDiagonal(a.length_scale_m);
  const double wsum = a.weight_sum > 0.0 ? a.weight_sum : 1.0;
  Matrix6d Cs = Matrix6d::Zero();
  for (int i = 0; i < 6; ++i) {
    const auto v = a.eigenvectors.col(i);
    Cs += variance(i, a.eigenvalues(i) * wsum) * v * v.transpose();
  }
  return s.asDiagonal() * Cs * s.asDiagonal();
}
}  // namespace

Matrix6d registrationCovariance(const DegeneracyAnalysis& a, double sigma2_m2,
                                const DegeneracyConfig& config) {
  const double prior2 = config.prior_sigma_m * config.prior_sigma_m;
  return covarianceAlongModes(a, [&](int i, double lambda) {
    const double measured = lambda > 0.0 ? sigma2_m2 / lambda : prior2;
    return a.gain(i) * measured + (1.0 - a.gain(i)) * prior2;
  });
}

Matrix6d measurementCovariance(const DegeneracyAnalysis& a, double sigma2_m2,
                               double firm_information) {
  return covarianceAlongModes(a, [&](int i, double lambda) {
    const double g = a.gain(i);
    const bool weak =
        a.noise_floor(i) > 0.0 && a.eigenvalues(i) < firm_information * a.noise_floor(i);
    return lambda > 0.0 && g > 0.0 && !weak
               ? std::min(kUnmeasuredVariance, sigma2_m2 / (lambda * g))
               : kUnmeasuredVariance;
  });
}

}  // namespace depth_track
