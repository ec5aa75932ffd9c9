#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/sim/scene.hpp"

using namespace depth_track;
using namespace depth_track::sim;

namespace {

// Rendered depths are stored as float: relative rounding 6e-8, i.e. < 1 um within 4 m.
constexpr double kFloatTol_m = 1e-6;

/// Camera at p_W looking along +x of W (level), then yawed/pitched about its own centre.
Eigen::Isometry3d lookingAlongX(const Eigen::Vector3d& p_W, double yaw = 0.0, double pitch = 0.0) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(-pitch, Eigen::Vector3d::UnitY()))
                   .toRotationMatrix() *
               rotationBodyFromOptical();
  T.translation() = p_W;
  return T;
}

Scene wallScene(double x_m) {
  Scene s;
  s.name = "wall";
  s.addRectangle(Eigen::Vector3d(x_m, 0.0, 1.0), -Eigen::Vector3d::UnitX(), 20.0, 20.0, "wall");
  return s;
}

}  // namespace

TEST(Render, FrontoParallelPlaneHasExactDepth) {
  const PinholeIntrinsics K = l515Intrinsics();
  const DepthImage d = renderDepth(wallScene(2.0), K, lookingAlongX({0, 0, 1}), DepthRange{});
  ASSERT_EQ(d.width, 640);
  ASSERT_EQ(d.height, 480);
  for (float z : d.data) ASSERT_NEAR(z, 2.0, kFloatTol_m);  // z-depth, not ray length
}

TEST(Render, TiltedCameraMatchesRayPlaneIntersection) {
  const PinholeIntrinsics K = l515Intrinsics();
  const Eigen::Isometry3d T = lookingAlongX({0.1, -0.2, 1.0}, 20 * kDegToRad, -10 * kDegToRad);
  const double wall_x = 2.5;
  const DepthImage d = renderDepth(wallScene(wall_x), K, T, DepthRange{0.1, 10.0});
  for (int v = 0; v < K.height; v += 7)
    for (int u = 0; u < K.width; u += 5) {
      const Eigen::Vector3d ray_C((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      const Eigen::Vector3d ray_W = T.linear() * ray_C;
      const double t = (wall_x - T.translation().x()) / ray_W.x();  // = z-depth (ray_C.z = 1)
      ASSERT_NEAR(d.at(u, v), t, kFloatTol_m * 3) << u << "," << v;
    }
}

TEST(Render, SphereCentreDepth) {
  Scene s;
  s.name = "sphere";
  s.addSphere(Eigen::Vector3d(2.5, 0.0, 1.0), 0.3, "ball");
  const PinholeIntrinsics K = l515Intrinsics();
  const DepthImage d = renderDepth(s, K, lookingAlongX({0, 0, 1}), DepthRange{});
  EXPECT_NEAR(d.at(320, 240), 2.2, kFloatTol_m);  // pixel (cx, cy) lies on the optical axis
  // Silhouette radius in pixels: tangent rays at asin(r / D) from the axis.
  const double alpha = std::asin(0.3 / 2.5);
  const double r_px = K.fx * std::tan(alpha);
  EXPECT_GT(d.at(320 + static_cast<int>(r_px) - 1, 240), 0.0f);
  EXPECT_EQ(d.at(320 + static_cast<int>(r_px) + 2, 240), 0.0f);
}

TEST(Render, BackProjectedPixelsLieOnTheScene) {
  const Scene scene = chairRoomScene();
  const PinholeIntrinsics K = l515Intrinsics();
  const Eigen::Isometry3d T_W_C = cameraPoseOnTrack(0.37, 14 * kDegToRad, -9 * kDegToRad);
  const DepthImage d = renderDepth(scene, K, T_W_C, DepthRange{});
  int valid = 0;
  for (int v = 0; v < K.height; v += 3)
    for (int u = 0; u < K.width; u += 3) {
      const float z = d.at(u, v);
      if (z <= 0.0f) continue;
      ++valid;
      const Eigen::Vector3d p_W = T_W_C * K.backProject(u, v, z).cast<double>();
      // float back-projection: ~1e-7 relative on coordinates up to 4 m.
      ASSERT_LT(scene.distanceTo(p_W), 1e-5) << "pixel " << u << "," << v << " z=" << z;
    }
  EXPECT_GT(valid, 0.9 * (K.width / 3) * (K.height / 3));
}

TEST(Render, CulledRendererEqualsBruteForce) {
  // Smaller image, same field of view, so the brute-force reference stays quick.
  const PinholeIntrinsics K = PinholeIntrinsics::isotropic(160, 120, 458.0 / 4.0);
  for (const Scene& scene : {chairRoomScene(), furnishedRoomScene(), hallwayScene()}) {
    const Eigen::Isometry3d T = lookingAlongX({0.2, 0.1, 0.5}, 35 * kDegToRad, 12 * kDegToRad);
    const DepthImage a = renderDepth(scene, K, T, DepthRange{});
    const DepthImage b = renderDepthReference(scene, K, T, DepthRange{});
    for (std::size_t i = 0; i < a.data.size(); ++i)
      ASSERT_NEAR(a.data[i], b.data[i], kFloatTol_m) << scene.name << " pixel " << i;
  }
}

TEST(Render, ThreadCountDoesNotChangeTheFrame) {
  const Scene scene = chairRoomScene();
  const PinholeIntrinsics K = l515Intrinsics();
  const Eigen::Isometry3d T = cameraPoseOnTrack(0.5, 5 * kDegToRad, 3 * kDegToRad);
  const DepthImage a = renderDepth(scene, K, T, DepthRange{}, 1);
  const DepthImage b = renderDepth(scene, K, T, DepthRange{}, 2);
  EXPECT_EQ(a.data, b.data);
}

TEST(Render, RangeLimitsAndOcclusionByNearSurfaces) {
  const PinholeIntrinsics K = l515Intrinsics();
  // Wall beyond the range: no return.
  EXPECT_EQ(renderDepth(wallScene(4.5), K, lookingAlongX({0, 0, 1}), DepthRange{}).countValid(),
            0u);
  // A box 0.3 m in front of the camera (below d_min) hides the wall behind it.
  Scene s = wallScene(2.0);
  s.addBoxAabb(Eigen::Vector3d(0.25, -0.05, 0.95), Eigen::Vector3d(0.35, 0.05, 1.05), "near box");
  const DepthImage d = renderDepth(s, K, lookingAlongX({0, 0, 1}), DepthRange{});
  EXPECT_EQ(d.at(320, 240), 0.0f);
  EXPECT_NEAR(d.at(10, 10), 2.0, kFloatTol_m);
}

TEST(Render, BadInputIsNamed) {
  Scene s = wallScene(2.0);
  s.addSphere(Eigen::Vector3d(1, 0, 0), -0.2, "broken ball");
  try {
    renderDepth(s, l515Intrinsics(), Eigen::Isometry3d::Identity(), DepthRange{});
    FAIL() << "negative radius accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("broken ball"), std::string::npos) << e.what();
  }
  PinholeIntrinsics bad = l515Intrinsics();
  bad.fx = 0.0;
  EXPECT_THROW(renderDepth(wallScene(2.0), bad, Eigen::Isometry3d::Identity(), DepthRange{}),
               std::invalid_argument);
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().x() = std::nan("");
  EXPECT_THROW(renderDepth(wallScene(2.0), l515Intrinsics(), nan_pose, DepthRange{}),
               std::invalid_argument);
  EXPECT_THROW(renderDepth(Scene{}, l515Intrinsics(), Eigen::Isometry3d::Identity(), DepthRange{}),
               std::invalid_argument);
}

namespace {

/// Weakest / strongest eigenvalue of the point-to-plane information matrix of a frame, with
/// normals estimated from neighbouring pixels (rotation columns use p x n with p in metres).
double constraintRatio(const DepthImage& d, const PinholeIntrinsics& K) {
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
  for (int v = 1; v + 1 < K.height; v += 2)
    for (int u = 1; u + 1 < K.width; u += 2) {
      const float z = d.at(u, v), zr = d.at(u + 1, v), zd = d.at(u, v + 1);
      if (z <= 0 || zr <= 0 || zd <= 0 || std::abs(zr - z) > 0.02 || std::abs(zd - z) > 0.02)
        continue;
      const Eigen::Vector3d p = K.backProject(u, v, z).cast<double>();
      const Eigen::Vector3d n = (K.backProject(u + 1, v, zr).cast<double>() - p)
                                    .cross(K.backProject(u, v + 1, zd).cast<double>() - p)
                                    .normalized();
      Eigen::Matrix<double, 6, 1> J;
      J << p.cross(n), n;
      H += J * J.transpose();
    }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(H);
  return es.eigenvalues()(0) / es.eigenvalues()(5);
}

}  // namespace

// The scenes must be realistic for tracking: nearly every pixel returns, and the visible
// surfaces constrain all six degrees of freedom of a point-to-plane registration. A single wall
// gives ratio 0 (three free directions); floor, walls and furniture faces keep the weakest
// direction within 1/200 of the strongest.
TEST(Render, ScenesConstrainAllSixDof) {
  const PinholeIntrinsics K = l515Intrinsics();
  Scene wall;
  wall.name = "wall";
  wall.addRectangle(Eigen::Vector3d(2, 0, 1), -Eigen::Vector3d::UnitX(), 20, 20, "wall");
  EXPECT_LT(constraintRatio(renderDepth(wall, K, lookingAlongX({0, 0, 1}), DepthRange{}), K), 1e-6);
  const Scene scene = chairRoomScene();
  for (double pos : {0.0, 1.0}) {
    const DepthImage d = renderDepth(scene, K, cameraPoseOnTrack(pos, 0.0, 0.0), DepthRange{});
    EXPECT_GT(static_cast<double>(d.countValid()) / d.data.size(), 0.97) << "pos " << pos;
    const double ratio = constraintRatio(d, K);
    std::printf("chair room at %.1f m: eigenvalue ratio %.4g\n", pos, ratio);
    EXPECT_GT(ratio, 1.0 / 200.0) << "pos " << pos;
  }
  // Room3 circles the furnished room: every heading must see enough structure.
  const RenderedRun room = makeRun("room3");
  double worst = 1.0;
  for (std::size_t i = 0; i < room.size() / 2; i += 30) {
    const DepthImage d = renderDepth(room.scene, K, room.T_W_C[i], room.range);
    EXPECT_GT(static_cast<double>(d.countValid()) / d.data.size(), 0.9) << "room3 frame " << i;
    worst = std::min(worst, constraintRatio(d, K));
  }
  std::printf("room3 first lap: worst eigenvalue ratio %.4g\n", worst);
  EXPECT_GT(worst, 1.0 / 200.0);
  // Hall1: the far end is beyond the 4 m range, so the recessed doors, furniture and lights
  // carry the along-hall direction.
  const RenderedRun hall = makeRun("hall1");
  worst = 1.0;
  for (std::size_t i = 0; i < hall.size(); i += 100) {
    const DepthImage d = renderDepth(hall.scene, K, hall.T_W_C[i], hall.range);
    EXPECT_GT(static_cast<double>(d.countValid()) / d.data.size(), 0.75) << "hall1 frame " << i;
    worst = std::min(worst, constraintRatio(d, K));
  }
  std::printf("hall1: worst eigenvalue ratio %.4g\n", worst);
  EXPECT_GT(worst, 1.0 / 200.0);
}

// Closed-form hits of each shape from rays whose answer is known by construction.
TEST(Render, PrimitiveIntersectionsAndDistances) {
  const double inf = 1e9;
  Scene s;
  s.name = "shapes";
  s.addCylinder(Eigen::Vector3d(0, 0, -0.5), Eigen::Vector3d(0, 0, 0.5), 0.1, "cyl");
  s.addBox(Eigen::Vector3d::Zero(), 0.0, Eigen::Vector3d(0.2, 0.3, 0.4), "box");
  s.addSphere(Eigen::Vector3d::Zero(), 0.25, "sphere");
  s.addRectangle(Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), 0.5, 0.5, "rect",
                 Eigen::Vector3d::UnitX());
  const Primitive &cyl = s.primitives[0], &box = s.primitives[1], &sph = s.primitives[2],
                  &rect = s.primitives[3];
  const Eigen::Vector3d o(-2, 0, 0), dx(1, 0, 0);
  // Mantle: enters at x = -r.
  EXPECT_NEAR(*intersectLocal(cyl, o, dx, 0.0, inf), 1.9, 1e-12);
  // Cap: from above along the axis, enters at z = +0.5.
  EXPECT_NEAR(*intersectLocal(cyl, Eigen::Vector3d(0.05, 0, 3), -Eigen::Vector3d::UnitZ(), 0, inf),
              2.5, 1e-12);
  // Passing above the top cap misses; from inside there is no entry.
  EXPECT_FALSE(intersectLocal(cyl, Eigen::Vector3d(-2, 0, 0.6), dx, 0.0, inf));
  EXPECT_FALSE(intersectLocal(cyl, Eigen::Vector3d::Zero(), dx, 0.0, inf));
  // Slanted ray through the cap rim region: enters through the cap at z = 0.5.
  const Eigen::Vector3d d_slant = Eigen::Vector3d(0.05, 0, -1).normalized();
  const auto t_slant = intersectLocal(cyl, Eigen::Vector3d(-0.05, 0, 1.5), d_slant, 0.0, inf);
  ASSERT_TRUE(t_slant);
  EXPECT_NEAR((Eigen::Vector3d(-0.05, 0, 1.5) + *t_slant * d_slant).z(), 0.5, 1e-12);
  EXPECT_NEAR(*intersectLocal(box, o, dx, 0.0, inf), 1.8, 1e-12);
  EXPECT_FALSE(intersectLocal(box, Eigen::Vector3d(-2, 0.31, 0), dx, 0.0, inf));
  EXPECT_NEAR(*intersectLocal(sph, o, dx, 0.0, inf), 1.75, 1e-12);
  EXPECT_NEAR(
      *intersectLocal(rect, Eigen::Vector3d(0.1, 0.1, 1), -Eigen::Vector3d::UnitZ(), 0, inf), 1.0,
      1e-12);
  // The t_max bound is honoured (occlusion by a nearer hit).
  EXPECT_FALSE(intersectLocal(sph, o, dx, 0.0, 1.7));
  // Distances to the surface.
  EXPECT_NEAR(distanceToSurface(cyl, Eigen::Vector3d(0.3, 0, 0)), 0.2, 1e-12);
  EXPECT_NEAR(distanceToSurface(cyl, Eigen::Vector3d(0.0, 0, 0.45)), 0.05, 1e-12);
  EXPECT_NEAR(distanceToSurface(box, Eigen::Vector3d(0.0, 0, 0.0)), 0.2, 1e-12);
  EXPECT_NEAR(distanceToSurface(box, Eigen::Vector3d(0.5, 0.7, 0.0)), 0.5, 1e-12);
  EXPECT_NEAR(distanceToSurface(sph, Eigen::Vector3d(0.0, 1.0, 0.0)), 0.75, 1e-12);
  EXPECT_NEAR(distanceToSurface(rect, Eigen::Vector3d(0.8, 0.0, 0.4)), 0.5, 1e-12);
}

// The incidence output equals the analytic |cos| between each pixel ray and the surface normal.
TEST(Render, IncidenceOnTheFloorIsAnalytic) {
  Scene s;
  s.name = "floor";
  s.addRectangle(Eigen::Vector3d(10, 0, 0), Eigen::Vector3d::UnitZ(), 20, 20, "floor",
                 Eigen::Vector3d::UnitX());
  const PinholeIntrinsics K = l515Intrinsics();
  const Eigen::Isometry3d T = lookingAlongX({0, 0, 0.3}, 0.3, -0.2);
  const RenderedDepth r = renderDepthWithIncidence(s, K, T, DepthRange{0.1, 30.0});
  EXPECT_EQ(r.depth.data, renderDepth(s, K, T, DepthRange{0.1, 30.0}).data);
  int checked = 0;
  for (int v = 0; v < K.height; v += 11)
    for (int u = 0; u < K.width; u += 13) {
      const std::size_t i = static_cast<std::size_t>(v) * K.width + u;
      if (r.depth.data[i] == 0.0f) {
        EXPECT_EQ(r.cos_incidence[i], 0.0f);
        continue;
      }
      const Eigen::Vector3d d_W =
          T.linear() * Eigen::Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1);
      ASSERT_NEAR(r.cos_incidence[i], std::abs(d_W.z()) / d_W.norm(), 1e-6);  // float storage
      ++checked;
    }
  EXPECT_GT(checked, 500);
}
