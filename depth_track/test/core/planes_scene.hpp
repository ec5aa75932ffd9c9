#pragma once
// A minimal closed-form scene for unit tests of the tracking core: a set of planes (n . p = d in
// world coordinates) seen from inside, so each ray's first positive hit is its depth.
#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <vector>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

namespace depth_track::test {

struct Plane {
  Eigen::Vector3d n;  // unit normal in W
  double d;           // n . p_W = d
};

/// The L515's depth camera at 640x480 (the rendered runs' intrinsics).
inline PinholeIntrinsics l515() { return PinholeIntrinsics::isotropic(640, 480, 458.0); }

/// A pose translated by (tx, ty, tz) m and turned by ry_deg about its y axis.
inline Eigen::Isometry3d shifted(double tx, double ty, double tz, double ry_deg = 0.0) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(ry_deg * kDegToRad, Eigen::Vector3d::UnitY()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(tx, ty, tz);
  return T;
}

/// Renders the z-depth of the nearest plane along each pixel ray from camera pose T_W_C.
inline DepthImage renderPlanes(const std::vector<Plane>& planes, const PinholeIntrinsics& K,
                               const Eigen::Isometry3d& T_W_C, double max_range_m = 10.0) {
  DepthImage img(K.width, K.height);
  const Eigen::Matrix3d R = T_W_C.rotation();
  const Eigen::Vector3d o = T_W_C.translation();
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d ray_C((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);  // z = 1
      const Eigen::Vector3d ray_W = R * ray_C;
      double best = std::numeric_limits<double>::infinity();
      for (const Plane& pl : planes) {
        const double den = pl.n.dot(ray_W);
        if (std::abs(den) < 1e-12) continue;
        const double s = (pl.d - pl.n.dot(o)) / den;  // z-depth, since ray_C.z = 1
        if (s > 0.0 && s < best) best = s;
      }
      img.at(u, v) = best < max_range_m ? static_cast<float>(best) : 0.0f;
    }
  return img;
}

/// A room corner seen obliquely: back wall, side wall, floor and a slanted panel, enough to
/// constrain all six degrees of freedom. Camera at the origin looks along +z (optical frame = W).
inline std::vector<Plane> cornerRoom() {
  return {
      {Eigen::Vector3d(0, 0, -1), -3.0},                    // back wall z = 3
      {Eigen::Vector3d(-1, 0, 0), -1.5},                    // right wall x = 1.5
      {Eigen::Vector3d(1, 0, 0), -1.6},                     // left wall x = -1.6
      {Eigen::Vector3d(0, -1, 0), -0.9},                    // floor y = 0.9 (y down)
      {Eigen::Vector3d(0.3, 0.2, -1).normalized(), -2.2},   // slanted panel
      {Eigen::Vector3d(-0.5, 0.1, -1).normalized(), -2.4},  // another one
  };
}

}  // namespace depth_track::test
