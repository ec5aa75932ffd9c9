#pragma once
/// Rigid transforms: exponential map and small helpers (ROS-free core).
/// Naming: T_A_B maps points expressed in frame B into frame A (p_A = T_A_B * p_B).
#include <Eigen/Core>
#include <Eigen/Geometry>

namespace depth_track {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

/// Cross-product matrix: skew(v) * x = v.cross(x).
inline Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

/// Exact SO(3) exponential of a rotation vector (radians). Thread-safe.
inline Eigen::Matrix3d expSO3(const Eigen::Vector3d& omega) {
  const double theta = omega.norm();
  if (theta < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(theta, omega / theta).toRotationMatrix();
}

/// Rotation vector of a rotation matrix (the inverse of expSO3; angle in [0, pi], radians).
inline Eigen::Vector3d logSO3(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

/// Increment xi = [omega (rad); v (m)] applied as an exact rigid transform: rotation exp(omega)
/// and translation v (the "rotation then translate" parameterisation used by the linearised
/// point-to-plane solve, where p' = R p + t with R ~ I + [omega]x).
inline Eigen::Isometry3d expIncrement(const Vector6d& xi) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = expSO3(xi.head<3>());
  T.translation() = xi.tail<3>();
  return T;
}

/// Rotation angle of a transform in radians, in [0, pi].
inline double rotationAngle(const Eigen::Isometry3d& T) {
  return Eigen::AngleAxisd(T.rotation()).angle();
}

/// How far R is from a rotation's orthonormality: |R^T R - I| (Frobenius norm). Thread-safe.
inline double orthonormalityError(const Eigen::Matrix3d& R) {
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).norm();
}

/// True when T is finite and its linear part a proper rotation: orthonormalityError <= tol and
/// det > 0 (a reflection is not a pose). The default suits poses written in a configuration;
/// a pose composed from many tracked increments needs a looser tol. Thread-safe.
inline bool isRigid(const Eigen::Isometry3d& T, double tol = 1e-6) {
  return T.matrix().allFinite() && orthonormalityError(T.linear()) <= tol &&
         T.linear().determinant() > 0.0;
}

/// Re-orthonormalises the rotation part (guards long products of transforms against drift).
inline Eigen::Isometry3d orthonormalized(const Eigen::Isometry3d& T) {
  Eigen::Isometry3d out = T;
  out.linear() = Eigen::Quaterniond(T.rotation()).normalized().toRotationMatrix();
  return out;
}

/// The pose a share f in [0, 1] of the way from a to b: position linear, rotation slerp (as tf2
/// interpolates between two stamped transforms).
inline Eigen::Isometry3d interpolatePose(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b,
                                         double f) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() =
      Eigen::Quaterniond(a.linear()).slerp(f, Eigen::Quaterniond(b.linear())).toRotationMatrix();
  T.translation() = (1.0 - f) * a.translation() + f * b.translation();
  return T;
}

}  // namespace depth_track
