#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <stdexcept>
#include <string>

#include "depth_track/core/cells.hpp"
#include "depth_track/core/reconstruction.hpp"
#include "depth_track/core/tum_io.hpp"
#include "../shared_data.hpp"

using namespace depth_track;

namespace {

const PinholeIntrinsics kFr3{640, 480, 535.4, 539.2, 320.1, 247.6};

// Cell's Eigen members start uninitialised; hand-built cells set every one.
Cell blankCell() {
  Cell c;
  c.mean_C.setZero();
  c.normal_C.setZero();
  c.cov.setZero();
  c.eigenvalues.setZero();
  c.eigenvectors.setIdentity();
  c.cov_inv_sqrt.setZero();
  return c;
}

// Plane z = a + b x + c y in the camera frame; its depth along pixel (u, v)'s ray, written
// independently of the normal form the reconstruction uses: z = a / (1 - b rx - c ry).
struct Plane {
  double a, b, c;
  double depthAt(const PinholeIntrinsics& k, int u, int v) const {
    const double rx = (u - k.cx) / k.fx, ry = (v - k.cy) / k.fy;
    return a / (1.0 - b * rx - c * ry);
  }
};

DepthImage renderPlane(const PinholeIntrinsics& k, const Plane& p, double noise_m = 0.0,
                       unsigned seed = 1) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_m > 0 ? noise_m : 1.0);
  DepthImage d(k.width, k.height);
  for (int v = 0; v < k.height; ++v)
    for (int u = 0; u < k.width; ++u)
      d.at(u, v) = static_cast<float>(p.depthAt(k, u, v) + (noise_m > 0 ? noise(rng) : 0.0));
  return d;
}

// A cell cloud built by hand from the exact plane: per cell, the mean and covariance of its
// pixels' plane points and the plane's normal turned towards the camera.
CellCloud handCells(const PinholeIntrinsics& k, const Plane& p, int n) {
  CellCloud cloud;
  cloud.cell_size = n;
  cloud.grid_w = k.width / n;
  cloud.grid_h = k.height / n;
  cloud.grid_index.assign(static_cast<std::size_t>(cloud.grid_w) * cloud.grid_h, -1);
  const Eigen::Vector3d normal = Eigen::Vector3d(p.b, p.c, -1.0).normalized();
  for (int gy = 0; gy < cloud.grid_h; ++gy)
    for (int gx = 0; gx < cloud.grid_w; ++gx) {
      std::vector<Eigen::Vector3d> pts;
      for (int v = gy * n; v < (gy + 1) * n; ++v)
        for (int u = gx * n; u < (gx + 1) * n; ++u)
          pts.push_back(k.backProject(u, v, 1.0f).cast<double>() * p.depthAt(k, u, v));
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (const auto& q : pts) mean += q / pts.size();
      Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
      for (const auto& q : pts) cov += (q - mean) * (q - mean).transpose() / (pts.size() - 1.0);
      Cell c = blankCell();
      c.gx = gx;
      c.gy = gy;
      c.n_valid = n * n;
      c.mean_C = mean.cast<float>();
      c.normal_C = normal.cast<float>();
      c.cov = cov.cast<float>();
      cloud.grid_index[static_cast<std::size_t>(gy) * cloud.grid_w + gx] =
          static_cast<int>(cloud.cells.size());
      cloud.cells.push_back(c);
    }
  return cloud;
}

}  // namespace

TEST(Reconstruction, HandBuiltTiltedPlaneIsExactAtEveryPixel) {
  const Plane plane{2.0, 0.5, -0.3};  // about 27 and 17 degrees of tilt
  const CellCloud cloud = handCells(kFr3, plane, 8);
  const DepthImage r = reconstructDepth(cloud, kFr3);
  ASSERT_EQ(r.width, 640);
  ASSERT_EQ(r.height, 480);
  EXPECT_EQ(r.countValid(), 640u * 480u);
  double max_err = 0.0;
  for (int v = 0; v < 480; ++v)
    for (int u = 0; u < 640; ++u)
      max_err = std::max(max_err, std::abs(r.at(u, v) - plane.depthAt(kFr3, u, v)));
  // Float storage of means and normals (~1e-7 relative) at ~2-3 m.
  EXPECT_LT(max_err, 5e-6);
}

TEST(Reconstruction, PrunedCellsStayEmpty) {
  const Plane plane{1.5, 0.0, 0.0};
  CellCloud cloud = handCells(kFr3, plane, 16);
  // Prune every third cell (index entry -1, cell removed from the list).
  CellCloud pruned = cloud;
  pruned.cells.clear();
  for (auto& idx : pruned.grid_index) {
    const int i = &idx - pruned.grid_index.data();
    if (i % 3 == 0) {
      idx = -1;
    } else {
      idx = static_cast<int>(pruned.cells.size());
      pruned.cells.push_back(cloud.cells[i]);
    }
  }
  const DepthImage r = reconstructDepth(pruned, kFr3);
  EXPECT_EQ(r.countValid(), pruned.cells.size() * 256u);
  for (int gy = 0; gy < pruned.grid_h; ++gy)
    for (int gx = 0; gx < pruned.grid_w; ++gx) {
      const float z = r.at(gx * 16 + 7, gy * 16 + 9);
      if (pruned.cellAt(gx, gy) < 0) {
        EXPECT_EQ(z, 0.0f);
      } else {
        EXPECT_NEAR(z, 1.5f, 1e-6f);
      }
    }
}

TEST(Reconstruction, GrazingRaysGiveNoHugeDepths) {
  CellCloud cloud;
  cloud.cell_size = 8;
  cloud.grid_w = 80;
  cloud.grid_h = 60;
  cloud.grid_index.assign(80 * 60, -1);
  // Cell 0: normal almost perpendicular to the central rays (cos ~ 0.01).
  // Cell 1: 80 degrees to the ray (passes the ray guard) but with a fronto-parallel cell's depth
  // spread (sigma 1 mm): the plane leaves the cell's depth span within a pixel or two.
  // Cell 2: non-finite normal.
  const Eigen::Vector3f mean(0.0f, 0.0f, 2.0f);
  const float rad80 = static_cast<float>(80.0 * M_PI / 180.0);
  const Eigen::Vector3f normals[3] = {Eigen::Vector3f(1.0f, 0.0f, -0.01f).normalized(),
                                      Eigen::Vector3f(std::sin(rad80), 0.0f, -std::cos(rad80)),
                                      Eigen::Vector3f(NAN, 0.0f, -1.0f)};
  for (int i = 0; i < 3; ++i) {
    Cell c = blankCell();
    c.gx = 39 + i;
    c.gy = 30;
    c.mean_C = Eigen::Vector3f(static_cast<float>((c.gx * 8 + 3.5 - kFr3.cx) / kFr3.fx * 2.0),
                               static_cast<float>((30 * 8 + 3.5 - kFr3.cy) / kFr3.fy * 2.0), 2.0f);
    c.normal_C = normals[i];
    c.cov = Eigen::Matrix3f::Identity() * 1e-6f;
    cloud.grid_index[30 * 80 + c.gx] = i;
    cloud.cells.push_back(c);
  }
  const DepthImage r = reconstructDepth(cloud, kFr3);
  int valid1 = 0;
  for (int v = 240; v < 248; ++v)
    for (int u = 312; u < 336; ++u) {
      const float z = r.at(u, v);
      EXPECT_TRUE(std::isfinite(z));
      if (u < 320 || u >= 328) {
        EXPECT_EQ(z, 0.0f) << u << "," << v;  // cells 0 and 2
      }
      if (z > 0.0f) {
        ++valid1;
        // max deviation: 4 sigma + 1 cm margin
        EXPECT_LE(std::abs(z - mean.z()), 4 * 1e-3 + 0.01 + 1e-6);
      }
    }
  // At 80 degrees a pixel (3.7 mm at 2 m) moves depth by ~2.1 cm: only the pixel columns
  // nearest the mean survive the 1.4 cm span guard.
  EXPECT_GT(valid1, 0);
  EXPECT_LT(valid1, 64);
}

TEST(Reconstruction, BadInputIsNamed) {
  const CellCloud cloud = handCells(kFr3, Plane{2.0, 0.0, 0.0}, 8);
  PinholeIntrinsics small = kFr3;
  small.width = 320;
  small.cx = 160.0;
  try {
    reconstructDepth(cloud, small);
    ADD_FAILURE() << "no throw";
  } catch (const DepthInputError& e) {
    EXPECT_NE(std::string(e.what()).find("80x60"), std::string::npos) << e.what();
  }
  ReconstructionConfig bad;
  bad.min_ray_cos = 0.0;
  bad.max_depth_sigmas = -1.0;
  EXPECT_EQ(bad.validate().size(), 2u);
  EXPECT_THROW(reconstructDepth(cloud, kFr3, bad), std::invalid_argument);
}

TEST(Reconstruction, CompareDepthCountsAndErrors) {
  DepthImage a(3, 1), b(3, 1);
  a.data = {1.0f, 2.0f, 0.0f};
  b.data = {1.1f, 0.0f, 3.0f};
  const DepthDifference d = compareDepth(a, b);
  EXPECT_EQ(d.compared, 1u);
  EXPECT_EQ(d.only_in_a, 1u);
  EXPECT_EQ(d.only_in_b, 1u);
  EXPECT_NEAR(d.rms_m, 0.1, 1e-6);
  EXPECT_NEAR(d.mean_m, 0.1, 1e-6);
  EXPECT_NEAR(d.median_abs_m, 0.1, 1e-6);
  EXPECT_THROW(compareDepth(a, DepthImage(2, 2)), DepthInputError);
}

TEST(Reconstruction, NoisyPlaneThroughReduceToCellsIsRecoveredWithinTheFitError) {
  const Plane plane{2.0, 0.4, 0.2};
  const double sigma = 0.002;  // 2 mm depth noise
  const DepthImage truth = renderPlane(kFr3, plane);
  const DepthImage noisy = renderPlane(kFr3, plane, sigma, 7);
  const double n = 64.0;  // pixels per 8x8 cell
  for (const int radius : {0, 1}) {
    PcaConfig pca;
    pca.cell_size = 8;
    pca.normal_radius_cells = radius;  // 0: each cell's own PCA normal, as in the thesis
    const CellCloud cloud = reduceToCells(noisy, kFr3, pca, 2);
    ASSERT_EQ(cloud.cells.size(), 80u * 60u);
    const DepthImage r = reconstructDepth(cloud, kFr3);
    EXPECT_EQ(r.countValid(), 640u * 480u);
    const DepthDifference vs_truth = compareDepth(truth, r);
    if (radius == 0) {
      // A plane fitted to n noisy samples is off at a pixel by sigma * sqrt(1/n + x^2/Sxx +
      // y^2/Syy); averaged over the cell that is sigma * sqrt(3 / n) = 0.22 sigma.
      EXPECT_NEAR(vs_truth.rms_m, sigma * std::sqrt(3.0 / n), 0.25 * sigma * std::sqrt(3.0 / n));
    } else {
      // Normals pooled over neighbouring cells: the tilt error shrinks, the cell mean's own
      // error (sigma / sqrt(n)) cannot, so the residual lies between the two.
      EXPECT_GT(vs_truth.rms_m, 0.9 * sigma / std::sqrt(n));
      EXPECT_LT(vs_truth.rms_m, sigma * std::sqrt(3.0 / n));
    }
    EXPECT_NEAR(vs_truth.mean_m, 0.0, 0.05 * sigma);
    // Against the noisy input the residual is the noise the fit removed: between
    // sigma * sqrt(1 - 3/n) and sigma * sqrt(1 - 1/n), i.e. ~0.98 sigma.
    const DepthDifference vs_noisy = compareDepth(noisy, r);
    EXPECT_NEAR(vs_noisy.rms_m, sigma * std::sqrt(1.0 - 2.0 / n), 0.05 * sigma);
    std::printf(
        "noisy plane, normal radius %d cells: rms vs truth %.3f mm (per-cell fit "
        "%.3f mm, mean only %.3f mm)\n",
        radius, 1e3 * vs_truth.rms_m, 1e3 * sigma * std::sqrt(3.0 / n), 1e3 * sigma / std::sqrt(n));
  }
}

TEST(Reconstruction, TeddyFrameIsReproducedWithinKinectNoise) {
  DT_TEDDY_OR_SKIP(teddy);
  const std::string list = teddy + "/depth.txt";
  const auto frames = readTumFrameList(list);
  const DepthImage d = loadTumDepth(frames.front().path, 1.0 / 5000.0, DepthRange{0.1, 10.0});
  PcaConfig pca;
  pca.cell_size = 4;
  const CellCloud cloud = reduceToCells(d, kFr3, pca, 2);
  const DepthImage r = reconstructDepth(cloud, kFr3);
  const DepthDifference diff = compareDepth(d, r);
  std::printf(
      "teddy frame 0, 4 px cells: %zu cells, %zu px compared, rms %.2f mm, mean %.2f mm, "
      "median |err| %.2f mm, max %.1f mm, %zu px of pruned cells\n",
      cloud.cells.size(), diff.compared, 1e3 * diff.rms_m, 1e3 * diff.mean_m,
      1e3 * diff.median_abs_m, 1e3 * diff.max_abs_m, diff.only_in_a);
  EXPECT_EQ(diff.only_in_b, 0u);  // nothing is invented where the camera saw nothing
  EXPECT_GT(diff.compared, d.countValid() / 2);
  // Kinect depth noise grows as ~1.42e-3 z^2 m (Khoshelham & Elberink 2012): 6.3 mm at the
  // 2.1 m median depth. A typical pixel sits on a smooth surface, so its residual is at most
  // that noise; the RMS is dominated by cells straddling depth edges (a plane fitted across
  // two surfaces) and is not asserted. A plane fit is unbiased: the mean stays far below 1 mm.
  EXPECT_LT(diff.median_abs_m, 1.42e-3 * 2.1 * 2.1);
  EXPECT_LT(std::abs(diff.mean_m), 1e-3);
}
