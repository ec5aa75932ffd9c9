// The registration model (SurfaceModel): cells averaged per voxel over frames, and a keyframe's
// cells given the averaged plane where it is confident and agrees with them.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include "depth_track/core/surface_model.hpp"

namespace depth_track {
namespace {

// A grid of cells on the plane z = depth (camera frame), means jittered along z by sigma,
// normals facing the camera tilted by noise of sigma_n rad.
CellCloud noisyWall(double depth, double sigma, double sigma_n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g(0.f, 1.f);
  CellCloud cloud;
  cloud.cell_size = 5;
  cloud.grid_w = 40;
  cloud.grid_h = 30;
  cloud.grid_index.assign(cloud.grid_w * cloud.grid_h, -1);
  for (int gy = 0; gy < cloud.grid_h; ++gy)
    for (int gx = 0; gx < cloud.grid_w; ++gx) {
      Cell c;
      c.gx = gx;
      c.gy = gy;
      c.n_valid = 25;
      const float x = -0.4f + 0.02f * gx + 0.003f, y = -0.3f + 0.02f * gy + 0.003f;
      c.mean_C = Eigen::Vector3f(x, y, static_cast<float>(depth) + static_cast<float>(sigma) * g(rng));
      c.normal_C = Eigen::Vector3f(static_cast<float>(sigma_n) * g(rng),
                                   static_cast<float>(sigma_n) * g(rng), -1.f)
                       .normalized();
      c.cov.setZero();
      c.eigenvalues.setZero();
      c.eigenvectors.setZero();
      c.cov_inv_sqrt.setZero();
      cloud.grid_index[gy * cloud.grid_w + gx] = static_cast<int>(cloud.cells.size());
      cloud.cells.push_back(c);
    }
  return cloud;
}

double rmsDepthError(const CellCloud& cloud, double depth) {
  double s = 0.0;
  for (const Cell& c : cloud.cells) s += std::pow(c.mean_C.z() - depth, 2);
  return std::sqrt(s / cloud.cells.size());
}

double rmsNormalTilt(const CellCloud& cloud) {
  double s = 0.0;
  for (const Cell& c : cloud.cells) s += 1.0 - std::abs(c.normal_C.z());
  return std::sqrt(2.0 * s / cloud.cells.size());
}

TEST(SurfaceModel, AveragedPlaneReplacesTheNoiseOfOneFrame) {
  SurfaceModelConfig config;
  config.noise.const_m = 0.003;  // 3 sigma gate: 9 mm, above the 3 mm jitter's spread
  SurfaceModel model(config);
  const Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  for (unsigned f = 0; f < 30; ++f) model.integrate(noisyWall(1.0, 0.003, 0.05, f), T);
  EXPECT_GT(model.voxelCount(), 500u);

  const CellCloud frame = noisyWall(1.0, 0.003, 0.05, 1000);
  ModelRefineStats stats;
  const CellCloud refined = model.refine(frame, T, &stats);
  ASSERT_EQ(refined.cells.size(), frame.cells.size());
  EXPECT_EQ(stats.cells, static_cast<int>(frame.cells.size()));
  EXPECT_GT(stats.refined, 0.95 * stats.cells);
  // 30 frames averaged: the depth noise falls by about sqrt(30) (the voxel holds one 2x2 block
  // of cells per frame, so more), the normals' too.
  EXPECT_NEAR(rmsDepthError(frame, 1.0), 0.003, 0.0005);
  EXPECT_LT(rmsDepthError(refined, 1.0), 0.0008);
  EXPECT_LT(rmsNormalTilt(refined), 0.4 * rmsNormalTilt(frame));
  EXPECT_NEAR(stats.rms_offset_m, 0.003, 0.001);
  // Cells stay where the grid has them: the mean moves along its own ray only.
  for (std::size_t i = 0; i < frame.cells.size(); ++i) {
    const Eigen::Vector3f a = frame.cells[i].mean_C, b = refined.cells[i].mean_C;
    EXPECT_NEAR(a.x() / a.z(), b.x() / b.z(), 1e-6);
    EXPECT_NEAR(a.y() / a.z(), b.y() / b.z(), 1e-6);
    EXPECT_EQ(frame.cells[i].gx, refined.cells[i].gx);
  }
}

TEST(SurfaceModel, ModelPosedInTheWorldIsReadFromAnotherCameraPose) {
  SurfaceModel model;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
  T_W_C.translation() = Eigen::Vector3d(0.3, -0.2, 0.5);
  T_W_C.linear() = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  for (unsigned f = 0; f < 10; ++f) model.integrate(noisyWall(1.2, 0.0, 0.0, f), T_W_C);
  // The same wall seen 1 cm farther in a frame whose pose says it is at T_W_C: the model
  // puts it back on the averaged plane.
  ModelRefineStats stats;
  const CellCloud refined = model.refine(noisyWall(1.21, 0.0, 0.0, 99), T_W_C, &stats);
  EXPECT_GT(stats.refined, 0.9 * stats.cells);
  EXPECT_LT(rmsDepthError(refined, 1.2), 1e-4);
  EXPECT_NEAR(stats.rms_offset_m, 0.01, 1e-4);
}

TEST(SurfaceModel, GatesKeepTheCellsOwnPlane) {
  SurfaceModelConfig config;
  SurfaceModel model(config);
  const Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  // Fewer frames than min_weight: nothing is confident yet.
  for (unsigned f = 0; f + 1 < static_cast<unsigned>(config.min_weight); ++f)
    model.integrate(noisyWall(1.0, 0.0, 0.0, f), T);
  ModelRefineStats stats;
  model.refine(noisyWall(1.0, 0.0, 0.0, 7), T, &stats);
  EXPECT_EQ(stats.refined, 0);
  EXPECT_EQ(stats.no_model, stats.cells);
  model.integrate(noisyWall(1.0, 0.0, 0.0, 8), T);
  model.refine(noisyWall(1.0, 0.0, 0.0, 9), T, &stats);
  EXPECT_EQ(stats.refined, stats.cells);

  // A face 5 cm in front of the modelled one lies in voxels the model has never seen.
  model.refine(noisyWall(0.95, 0.0, 0.0, 10), T, &stats);
  EXPECT_EQ(stats.refined, 0);

  // Within a voxel but farther from its plane than the noise gate: kept as seen.
  SurfaceModelConfig noisy = config;
  noisy.noise.const_m = 0.001;  // gate 3 mm
  model.setConfig(noisy);
  const CellCloud off = noisyWall(1.004, 0.0, 0.0, 11);
  const CellCloud kept = model.refine(off, T, &stats);
  EXPECT_EQ(stats.refined, 0);
  EXPECT_GT(stats.rejected, 0);
  EXPECT_FLOAT_EQ(kept.cells[0].mean_C.z(), off.cells[0].mean_C.z());
  // ... and within it once the gate is wider.
  noisy.noise.const_m = 0.002;  // gate 6 mm
  model.setConfig(noisy);
  model.refine(off, T, &stats);
  EXPECT_GT(stats.refined, 0);

  // A normal across the cos_min gate keeps the cell as it is.
  model.setConfig(config);
  CellCloud tilted = noisyWall(1.0, 0.0, 0.0, 12);
  for (Cell& c : tilted.cells) c.normal_C = Eigen::Vector3f(0.6f, 0.f, -0.8f);
  model.refine(tilted, T, &stats);
  EXPECT_EQ(stats.refined, 0);
  EXPECT_EQ(stats.rejected, stats.cells);
}

TEST(SurfaceModel, OtherSideOfAThinSurfaceDoesNotMixIn) {
  SurfaceModel model;
  const Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  for (unsigned f = 0; f < 5; ++f) model.integrate(noisyWall(1.0, 0.0, 0.0, f), T);
  // The same voxels seen with normals facing away (the back of a sheet): ignored.
  CellCloud back = noisyWall(1.0, 0.0, 0.0, 6);
  for (Cell& c : back.cells) {
    c.normal_C = -c.normal_C;
    c.mean_C.z() += 0.004f;
  }
  for (int f = 0; f < 5; ++f) model.integrate(back, T);
  ModelRefineStats stats;
  const CellCloud refined = model.refine(noisyWall(1.0, 0.0, 0.0, 20), T, &stats);
  EXPECT_EQ(stats.refined, stats.cells);
  EXPECT_LT(rmsDepthError(refined, 1.0), 1e-5);
}

TEST(SurfaceModel, TableGrowsAndKeepsEveryVoxel) {
  SurfaceModel model;
  const Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  // 150 walls 2 cm apart, each seen 3 times: over 100 000 voxels, several doublings.
  for (int layer = 0; layer < 150; ++layer)
    for (unsigned f = 0; f < 3; ++f)
      model.integrate(noisyWall(1.0 + 0.02 * layer + 0.005, 0.0, 0.0, f), T);
  EXPECT_GT(model.voxelCount(), 100000u);
  // Past the first table: 1.4 to 2.9 slots per voxel, each a key and a record.
  const double slot = sizeof(std::uint64_t) + sizeof(SurfaceModel::Voxel);
  EXPECT_GE(model.bytesPerVoxel(), 1.4 * slot);
  EXPECT_LE(model.bytesPerVoxel(), 2.9 * slot);
  for (const int layer : {0, 37, 90, 149}) {
    ModelRefineStats stats;
    const double depth = 1.0 + 0.02 * layer + 0.005;
    const CellCloud refined = model.refine(noisyWall(depth + 0.001, 0.0, 0.0, 9), T, &stats);
    EXPECT_EQ(stats.refined, stats.cells) << layer;
    EXPECT_LT(rmsDepthError(refined, depth), 1e-5) << layer;
  }
  model.clear();
  EXPECT_EQ(model.voxelCount(), 0u);
  ModelRefineStats stats;
  model.refine(noisyWall(1.0, 0.0, 0.0, 1), T, &stats);
  EXPECT_EQ(stats.no_model, stats.cells);
}

TEST(SurfaceModel, PruneKeepsTheSurroundingsAndShrinksTheTable) {
  SurfaceModel model;
  const Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  // Walls at 1 m and, 40 cm apart from 3 m on, 150 further ones out to about 63 m.
  for (unsigned f = 0; f < 3; ++f) model.integrate(noisyWall(1.005, 0.0, 0.0, f), T);
  const std::size_t near_voxels = model.voxelCount();
  for (int layer = 0; layer < 150; ++layer)
    for (unsigned f = 0; f < 3; ++f)
      model.integrate(noisyWall(3.005 + 0.4 * layer, 0.0, 0.0, f), T);
  const std::size_t all = model.voxelCount();
  const std::size_t bytes = model.memoryBytes();
  ASSERT_GT(all, 100000u);
  // Around the camera with a 2 m radius only the near wall (its corners lie within 1.12 m).
  EXPECT_EQ(model.prune(Eigen::Vector3d::Zero(), 2.0), all - near_voxels);
  EXPECT_EQ(model.voxelCount(), near_voxels);
  EXPECT_LE(model.memoryBytes(), bytes / 4);  // back to the first table
  ModelRefineStats stats;
  model.refine(noisyWall(1.006, 0.0, 0.0, 9), T, &stats);
  EXPECT_EQ(stats.refined, stats.cells);
  model.refine(noisyWall(3.006, 0.0, 0.0, 9), T, &stats);
  EXPECT_EQ(stats.no_model, stats.cells);
  EXPECT_EQ(model.prune(Eigen::Vector3d::Zero(), 2.0), 0u);
  // Still a working table: new voxels go in and are found.
  for (unsigned f = 0; f < 3; ++f) model.integrate(noisyWall(3.005, 0.0, 0.0, f), T);
  model.refine(noisyWall(3.006, 0.0, 0.0, 9), T, &stats);
  EXPECT_EQ(stats.refined, stats.cells);
}

TEST(SurfaceModel, ConfigProblemsAreNamed) {
  SurfaceModelConfig c;
  c.voxel_m = 0.0;
  c.min_weight = 0;
  c.max_offset_sigmas = -1.0;
  try {
    SurfaceModel model(c);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("model.voxel_m"), std::string::npos) << what;
    EXPECT_NE(what.find("model.min_weight"), std::string::npos) << what;
    EXPECT_NE(what.find("model.max_offset_sigmas"), std::string::npos) << what;
  }
  SurfaceModel model;
  SurfaceModelConfig other;
  other.voxel_m = 0.02;
  EXPECT_THROW(model.setConfig(other), std::invalid_argument);
  EXPECT_EQ(model.bytesPerVoxel(), 0.0);
}

}  // namespace
}  // namespace depth_track
