#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <random>

#include "depth_track/core/cells.hpp"
#include "planes_scene.hpp"

using namespace depth_track;
using depth_track::test::Plane;
using depth_track::test::renderPlanes;

namespace {
PinholeIntrinsics l515() { return PinholeIntrinsics::isotropic(640, 480, 458.0); }
}  // namespace

TEST(Pca, TiltedPlaneGivesItsNormalAndZeroSurfaceVariation) {
  const Eigen::Vector3d n_true = Eigen::Vector3d(0.3, -0.2, -1.0).normalized();  // faces camera
  const DepthImage depth = renderPlanes({{n_true, -2.0}}, l515(), Eigen::Isometry3d::Identity());
  PcaConfig cfg;
  cfg.cell_size = 5;
  const CellCloud cloud = reduceToCells(depth, l515(), cfg);
  EXPECT_EQ(cloud.stats.total, 128 * 96);
  EXPECT_EQ(cloud.stats.retained, 128 * 96);
  for (const Cell& c : cloud.cells) {
    ASSERT_GT(c.normal_C.cast<double>().dot(n_true), 1.0 - 1e-6);  // float geometry of ~2 m
    ASSERT_LT(c.surface_variation, 1e-5f);
    ASSERT_NEAR(n_true.dot(c.mean_C.cast<double>()), -2.0, 1e-4);  // mean lies on the plane
    ASSERT_LE(c.eigenvalues(0), c.eigenvalues(1));
    ASSERT_LE(c.eigenvalues(1), c.eigenvalues(2));
  }
}

TEST(Pca, CovarianceAndEigenvectorsMatchADirectComputation) {
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.003f);
  DepthImage depth(40, 40);
  for (float& d : depth.data) d = 1.5f + noise(rng);
  PinholeIntrinsics K = PinholeIntrinsics::isotropic(40, 40, 458.0);
  PcaConfig cfg;
  cfg.cell_size = 8;
  cfg.normal_radius_cells = 0;  // the cell's own normal
  const CellCloud cloud = reduceToCells(depth, K, cfg);
  ASSERT_EQ(cloud.cells.size(), 25u);
  const Cell& c = cloud.cells[7];
  std::vector<Eigen::Vector3d> pts;
  for (int v = c.gy * 8; v < c.gy * 8 + 8; ++v)
    for (int u = c.gx * 8; u < c.gx * 8 + 8; ++u)
      pts.push_back(K.backProject(u, v, depth.at(u, v)).cast<double>());
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : pts) mean += p;
  mean /= pts.size();
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : pts) cov += (p - mean) * (p - mean).transpose();
  cov /= (pts.size() - 1.0);
  EXPECT_LT((c.mean_C.cast<double>() - mean).norm(), 1e-6);
  EXPECT_LT((c.cov.cast<double>() - cov).norm(), 1e-6 * cov.norm() + 1e-12);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
  EXPECT_NEAR(std::abs(es.eigenvectors().col(0).dot(c.normal_C.cast<double>())), 1.0, 1e-4);
  EXPECT_NEAR(c.det, cov.determinant(), 1e-3 * std::abs(cov.determinant()));
  EXPECT_NEAR(c.surface_variation, es.eigenvalues()(0) / es.eigenvalues().sum(), 1e-4);
  // (cov + eps)^(-1/2) squared times (cov + eps) is the identity.
  const Eigen::Matrix3d reg = cov + cfg.min_eigenvalue_m2 * Eigen::Matrix3d::Identity();
  const Eigen::Matrix3d is = c.cov_inv_sqrt.cast<double>();
  EXPECT_LT((is * reg * is - Eigen::Matrix3d::Identity()).norm(), 2e-3);
}

TEST(Pca, CellsWithHolesArePrunedUnlessAFractionIsAllowed) {
  DepthImage depth =
      renderPlanes({{Eigen::Vector3d(0, 0, -1), -2.0}}, l515(), Eigen::Isometry3d::Identity());
  depth.at(12, 7) = 0.0f;  // one hole in cell (2, 1)
  for (int v = 100; v < 105; ++v)
    for (int u = 200; u < 205; ++u) depth.at(u, v) = 0.0f;  // an empty cell (40, 20)
  PcaConfig cfg;
  const CellCloud strict = reduceToCells(depth, l515(), cfg);
  EXPECT_EQ(strict.stats.pruned_invalid, 2);
  EXPECT_EQ(strict.stats.retained, 128 * 96 - 2);
  EXPECT_EQ(strict.cellAt(2, 1), -1);
  EXPECT_EQ(strict.cellAt(40, 20), -1);
  EXPECT_GE(strict.cellAt(3, 1), 0);
  cfg.min_valid_fraction = 0.9;
  const CellCloud lenient = reduceToCells(depth, l515(), cfg);
  EXPECT_EQ(lenient.stats.pruned_invalid, 1);
  ASSERT_GE(lenient.cellAt(2, 1), 0);
  EXPECT_EQ(lenient.cells[lenient.cellAt(2, 1)].n_valid, 24);
}

TEST(Pca, CellSizeThatDoesNotTileIsNamed) {
  PcaConfig cfg;
  cfg.cell_size = 7;
  ASSERT_EQ(cfg.validate(640, 480).size(), 1u);
  EXPECT_NE(cfg.validate(640, 480)[0].find("7"), std::string::npos);
  cfg.cell_size = 32;
  EXPECT_TRUE(cfg.validate(640, 480).empty());
  const auto p = cfg.validate(650, 480);
  ASSERT_EQ(p.size(), 1u);
  EXPECT_NE(p[0].find("does not tile"), std::string::npos);
  EXPECT_NE(p[0].find("650"), std::string::npos);
  PinholeIntrinsics K = PinholeIntrinsics::isotropic(650, 480, 458.0);
  EXPECT_THROW(reduceToCells(DepthImage(650, 480, 1.0f), K, cfg), DepthInputError);
  for (int s : {2, 4, 5, 8, 10, 16}) {
    cfg.cell_size = s;
    EXPECT_TRUE(cfg.validate(640, 480).empty()) << s;
  }
}

TEST(Pca, EmptyNanAndWrongSizeFrames) {
  PcaConfig cfg;
  const CellCloud empty = reduceToCells(DepthImage(640, 480, 0.0f), l515(), cfg);
  EXPECT_EQ(empty.stats.retained, 0);
  EXPECT_EQ(empty.stats.pruned_invalid, 128 * 96);
  const CellCloud nan = reduceToCells(DepthImage(640, 480, std::nanf("")), l515(), cfg);
  EXPECT_EQ(nan.stats.retained, 0);
  EXPECT_THROW(reduceToCells(DepthImage(320, 240, 1.0f), l515(), cfg), DepthInputError);
}

TEST(Pca, CollinearCellsArePrunedAsDegenerate) {
  // Only one row of each 4x4 cell is valid: points on a line have no plane.
  DepthImage depth(16, 16, 0.0f);
  for (int u = 0; u < 16; ++u) depth.at(u, 1) = 2.0f;
  PcaConfig cfg;
  cfg.cell_size = 4;
  cfg.min_valid_fraction = 0.25;
  const CellCloud cloud = reduceToCells(depth, PinholeIntrinsics::isotropic(16, 16, 458.0), cfg);
  EXPECT_EQ(cloud.stats.retained, 0);
  EXPECT_EQ(cloud.stats.pruned_degenerate, 4);
}

TEST(Pca, ThreadCountDoesNotChangeTheResult) {
  const auto planes = depth_track::test::cornerRoom();
  const DepthImage depth = renderPlanes(planes, l515(), Eigen::Isometry3d::Identity());
  PcaConfig cfg;
  const CellCloud a = reduceToCells(depth, l515(), cfg, 1);
  const CellCloud b = reduceToCells(depth, l515(), cfg, 2);
  ASSERT_EQ(a.cells.size(), b.cells.size());
  EXPECT_EQ(a.grid_index, b.grid_index);
  for (std::size_t i = 0; i < a.cells.size(); ++i) ASSERT_EQ(a.cells[i].mean_C, b.cells[i].mean_C);
}

// Cells are summed four to a lane where four remain in a grid row and one by one after that;
// both must give the same cells to the bit, pruned for the same reasons. A strip 11 cells wide
// (8 in lanes, the last 3 one by one) against the same strip with a 12th, empty cell column
// (all 12 in lanes). The frame has noise, and in the last three columns dense holes, a NaN
// patch and a depth step, so cells there are kept, invalid, edges, or both of the last two.
TEST(Pca, FourCellLanesGiveTheSameCellsAsOneByOne) {
  const DepthImage full =
      renderPlanes(depth_track::test::cornerRoom(), l515(), Eigen::Isometry3d::Identity());
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.003f);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  DepthImage strip(88, full.height, 0.0f), padded(96, full.height, 0.0f);
  for (int v = 0; v < strip.height; ++v) {
    for (int u = 0; u < strip.width; ++u) {
      float z = full.at(u, v);
      if (z > 0.0f) z += noise(rng);
      const bool tail = u >= 64;
      if (unit(rng) < (tail && v >= 100 && v < 160 ? 0.3f : 0.03f)) z = 0.0f;  // holes
      if (v >= 200 && v < 212 && u >= 60 && u < 75) z = std::nanf("");         // a NaN patch
      if (v >= 120 && u >= 66 && u < 80) z *= 0.6f;                             // a depth step
      strip.at(u, v) = padded.at(u, v) = z;
    }
  }
  PinholeIntrinsics k_strip = l515(), k_padded = l515();  // the same cx: the same rays
  k_strip.width = 88;
  k_padded.width = 96;
  PcaConfig cfg;
  cfg.cell_size = 8;
  cfg.normal_radius_cells = 0;  // each cell on its own pixels
  cfg.min_valid_fraction = 0.75;
  const CellCloud a = reduceToCells(strip, k_strip, cfg, 1);
  const CellCloud b = reduceToCells(padded, k_padded, cfg, 1);
  ASSERT_EQ(a.grid_w, 11);
  ASSERT_EQ(b.grid_w, 12);
  int kept_tail = 0;
  for (int gy = 0; gy < a.grid_h; ++gy) {
    for (int gx = 0; gx < 11; ++gx) {
      const int ia = a.grid_index[gy * a.grid_w + gx], ib = b.grid_index[gy * b.grid_w + gx];
      ASSERT_EQ(ia < 0, ib < 0) << "cell " << gx << ", " << gy;
      if (ia < 0) continue;
      kept_tail += gx >= 8;
      const Cell &ca = a.cells[ia], &cb = b.cells[ib];
      EXPECT_EQ(ca.n_valid, cb.n_valid);
      EXPECT_EQ(ca.mean_C, cb.mean_C) << "cell " << gx << ", " << gy;
      EXPECT_EQ(ca.cov, cb.cov) << "cell " << gx << ", " << gy;
      EXPECT_EQ(ca.normal_C, cb.normal_C) << "cell " << gx << ", " << gy;
    }
  }
  // The same reasons: the padded strip's extra column is all invalid.
  EXPECT_EQ(b.stats.pruned_invalid, a.stats.pruned_invalid + a.grid_h);
  EXPECT_EQ(b.stats.pruned_edge, a.stats.pruned_edge);
  EXPECT_EQ(b.stats.pruned_degenerate, a.stats.pruned_degenerate);
  EXPECT_GT(kept_tail, 50);
  EXPECT_GT(a.stats.pruned_invalid, 10);
  EXPECT_GT(a.stats.pruned_edge, 10);
}

TEST(Pca, PooledNormalsAreCloserToTheTruthOnANoisyPlane) {
  // 10 mm depth noise at 2 m (a Kinect-class sensor): per-cell normals of 5x5 px cells scatter by
  // tens of degrees; pooling 5x5 cells gives 25x the support and a much smaller error.
  const Eigen::Vector3d n_true = Eigen::Vector3d(0.2, -0.1, -1.0).normalized();
  DepthImage depth = renderPlanes({{n_true, -2.0}}, l515(), Eigen::Isometry3d::Identity());
  std::mt19937 rng(11);
  std::normal_distribution<float> noise(0.0f, 0.01f);
  for (float& d : depth.data) d += noise(rng);
  auto mean_error_deg = [&](int radius) {
    PcaConfig cfg;
    cfg.normal_radius_cells = radius;
    cfg.edge_jump_rel = 0.0;  // noise this strong would read as edges
    const CellCloud cloud = reduceToCells(depth, l515(), cfg);
    double sum = 0.0;
    for (const Cell& c : cloud.cells)
      sum += std::acos(std::min(1.0, c.normal_C.cast<double>().dot(n_true))) * 180.0 / M_PI;
    return sum / cloud.cells.size();
  };
  const double own = mean_error_deg(0), pooled = mean_error_deg(2);
  EXPECT_GT(own, 20.0);
  EXPECT_LT(pooled, own / 3.0);
}

TEST(Pca, CreaseCellsArePooledOnTheirOwnPlane) {
  // Walls, a floor and two slanted panels meeting at creases, 3 mm depth noise, pooled over 9x9
  // cells within 0.25 m (what auto_noise chooses for a D435). Pooled across a crease, a cell's
  // normal leans towards the other surface; pooled again on its own plane (crease_sigmas), it
  // follows its own more closely. Each cell's truth is the plane its mean lies on.
  const std::vector<Plane> planes = depth_track::test::cornerRoom();
  DepthImage depth = renderPlanes(planes, l515(), Eigen::Isometry3d::Identity());
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.003f);
  for (float& d : depth.data)
    if (d > 0.0f) d += noise(rng);
  auto errors_deg = [&](double crease_sigmas) {
    PcaConfig cfg;
    cfg.normal_radius_cells = 4;
    cfg.normal_merge_dist_m = 0.25;
    cfg.noise_sigma_const_m = 0.003;  // the noise model auto_noise would measure
    cfg.crease_sigmas = crease_sigmas;
    const CellCloud cloud = reduceToCells(depth, l515(), cfg);
    std::vector<double> e;
    for (const Cell& c : cloud.cells) {
      const Eigen::Vector3d m = c.mean_C.cast<double>();
      const Plane* own = &planes.front();
      for (const Plane& p : planes)
        if (std::abs(p.n.dot(m) - p.d) < std::abs(own->n.dot(m) - own->d)) own = &p;
      // Planes are given facing away from the camera; cell normals face it.
      e.push_back(std::acos(std::min(1.0, std::abs(c.normal_C.cast<double>().dot(own->n)))) *
                  180.0 / M_PI);
    }
    return e;
  };
  const std::vector<double> across = errors_deg(0.0), own = errors_deg(2.0);
  ASSERT_EQ(across.size(), own.size());  // the same cells: only normals change
  int leaning_across = 0, leaning_own = 0, changed = 0;
  double sum_across = 0.0, sum_own = 0.0;  // over the cells pooled again
  for (std::size_t i = 0; i < across.size(); ++i) {
    leaning_across += across[i] > 5.0;
    leaning_own += own[i] > 5.0;
    if (across[i] == own[i]) continue;
    ++changed;
    sum_across += across[i];
    sum_own += own[i];
  }
  std::printf("cells leaning > 5 deg: %d pooled across creases, %d pooled again; the %d of %zu "
              "cells pooled again lean %.2f deg on average before, %.2f after\n",
              leaning_across, leaning_own, changed, across.size(), sum_across / changed,
              sum_own / changed);
  // One pass straightens part of them (measured: 1095 -> 828 cells leaning more than 5 deg, the
  // 1431 pooled again 19.0 -> 16.6 deg on average): a cell whose own pixels straddle the crease,
  // or whose patch spans an occluding step, keeps its lean.
  EXPECT_GT(leaning_across, 300);
  EXPECT_LT(leaning_own, 0.85 * leaning_across);
  EXPECT_LT(sum_own, 0.93 * sum_across);
  // Cells whose patch is flat are pooled once, as before.
  EXPECT_LT(changed, static_cast<int>(across.size()) / 4);
  // Pooled over 3x3 cells only (an L515's), the cells are pooled once whatever their thickness.
  PcaConfig narrow;
  narrow.crease_sigmas = 2.0;
  narrow.normal_radius_cells = 1;
  narrow.noise_sigma_const_m = 0.003;
  const CellCloud once = reduceToCells(depth, l515(), narrow);
  narrow.crease_sigmas = 0.0;
  const CellCloud off = reduceToCells(depth, l515(), narrow);
  ASSERT_EQ(once.cells.size(), off.cells.size());
  for (std::size_t i = 0; i < once.cells.size(); ++i)
    ASSERT_EQ(once.cells[i].normal_C, off.cells[i].normal_C) << i;
  PcaConfig bad;
  bad.crease_sigmas = -1.0;
  EXPECT_FALSE(bad.validate(640, 480).empty());
  bad = PcaConfig{};
  bad.crease_min_radius_cells = 0;
  EXPECT_FALSE(bad.validate(640, 480).empty());
}

TEST(Pca, EdgeCellsArePruned) {
  // A box face 1 m in front of a wall 3 m away: cells straddling the silhouette are pruned.
  DepthImage depth(640, 480, 3.0f);
  for (int v = 100; v < 300; ++v)
    for (int u = 102; u < 402; ++u) depth.at(u, v) = 1.0f;
  PcaConfig cfg;
  const CellCloud cloud = reduceToCells(depth, l515(), cfg);
  // Silhouette columns 102 and 402 and rows 100 (cell boundary) and 300 (cell boundary): the
  // vertical edges cut 40 cell rows each; the horizontal ones lie on cell boundaries.
  EXPECT_EQ(cloud.stats.pruned_edge, 2 * 40);
  EXPECT_EQ(cloud.cellAt(102 / 5, 150 / 5), -1);
  cfg.edge_jump_rel = 0.0;
  EXPECT_EQ(reduceToCells(depth, l515(), cfg).stats.pruned_edge, 0);
}

TEST(Pca, PooledNormalIsTheClosedFormEigenvectorOfThePooledScatter) {
  // Pooled normals come from inverse iteration; they must equal the smallest eigenvector of the
  // pooled scatter matrix computed directly from the pixels of the 3x3 cells.
  DepthImage depth =
      renderPlanes(depth_track::test::cornerRoom(), l515(), Eigen::Isometry3d::Identity());
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0.0f, 0.002f);
  for (float& d : depth.data) d += noise(rng);
  PcaConfig cfg;                   // 5 px cells, 3x3 pooling
  cfg.normal_merge_dist_m = 10.0;  // pool every neighbour, so the pixels are easy to gather
  cfg.edge_jump_rel = 0.0;
  const CellCloud cloud = reduceToCells(depth, l515(), cfg);
  int checked = 0;
  double worst = 0.0;
  for (std::size_t i = 0; i < cloud.cells.size(); i += 97) {
    const Cell& c = cloud.cells[i];
    if (c.gx < 1 || c.gy < 1 || c.gx > cloud.grid_w - 2 || c.gy > cloud.grid_h - 2) continue;
    std::vector<Eigen::Vector3d> pts;
    bool complete = true;
    for (int gy = c.gy - 1; gy <= c.gy + 1; ++gy)
      for (int gx = c.gx - 1; gx <= c.gx + 1; ++gx) {
        if (cloud.cellAt(gx, gy) < 0) complete = false;
        for (int v = gy * 5; v < gy * 5 + 5; ++v)
          for (int u = gx * 5; u < gx * 5 + 5; ++u)
            if (depth.at(u, v) > 0)
              pts.push_back(l515().backProject(u, v, depth.at(u, v)).cast<double>());
      }
    if (!complete) continue;
    Eigen::Vector3d m = Eigen::Vector3d::Zero();
    for (const auto& p : pts) m += p;
    m /= pts.size();
    Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
    for (const auto& p : pts) S += (p - m) * (p - m).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S);
    worst =
        std::max(worst, 1.0 - std::abs(es.eigenvectors().col(0).dot(c.normal_C.cast<double>())));
    ++checked;
  }
  EXPECT_GT(checked, 80);
  EXPECT_LT(worst, 1e-6);  // 1 - |cos|: within 0.08 deg (float storage of the cell statistics)
}

TEST(Pca, ValuesOnlyPathGivesTheSameCells) {
  // Without inverse square roots (P2L, P2P) the cell's own eigenvectors are skipped and pooling
  // starts from the viewing ray: means, eigenvalues and pooled normals must not change.
  DepthImage depth =
      renderPlanes(depth_track::test::cornerRoom(), l515(), Eigen::Isometry3d::Identity());
  std::mt19937 rng(9);
  std::normal_distribution<float> noise(0.0f, 0.002f);
  for (float& d : depth.data) d += noise(rng);
  PcaConfig full;
  PcaConfig lean = full;
  lean.compute_inv_sqrt = false;
  const CellCloud a = reduceToCells(depth, l515(), full), b = reduceToCells(depth, l515(), lean);
  ASSERT_EQ(a.cells.size(), b.cells.size());
  double worst = 0.0;
  for (std::size_t i = 0; i < a.cells.size(); ++i) {
    ASSERT_EQ(a.cells[i].mean_C, b.cells[i].mean_C);
    ASSERT_LT((a.cells[i].eigenvalues - b.cells[i].eigenvalues).norm(),
              1e-6f * a.cells[i].eigenvalues(2));
    worst = std::max(
        worst, 1.0 - a.cells[i].normal_C.cast<double>().dot(b.cells[i].normal_C.cast<double>()));
  }
  EXPECT_LT(worst, 1e-7);  // 1 - cos: the same pooled normals to ~0.03 deg
}

TEST(Pca, WithoutSpectraTheSameCellsAreKeptAndTheFieldsAreZero) {
  // The tracker's reduction (cell_spectra off) decides the planarity test from the covariance's
  // invariants where it can: it must keep and prune exactly the cells the eigensolver does. The
  // frame mixes noisy planes, cells with holes, and cells whose valid pixels are one row: exact
  // depths make that row collinear (pruned), depths with noise from 0.01 to 1 mm along the rays
  // make it nearly collinear, across the band the invariants leave to the solver.
  const DepthImage clean =
      renderPlanes(depth_track::test::cornerRoom(), l515(), Eigen::Isometry3d::Identity());
  DepthImage depth = clean;
  std::mt19937 rng(11);
  std::normal_distribution<float> unit(0.0f, 1.0f);
  std::uniform_int_distribution<int> kind(0, 5);
  std::uniform_real_distribution<double> log_sigma(std::log(1e-5), std::log(1e-3));
  const int n = 5;
  for (int gy = 0; gy < depth.height / n; ++gy)
    for (int gx = 0; gx < depth.width / n; ++gx) {
      const int k = kind(rng);
      const float sigma = k == 3 ? 0.0f : k == 4 ? static_cast<float>(std::exp(log_sigma(rng))) : 0.002f;
      for (int v = 0; v < n; ++v)
        for (int u = 0; u < n; ++u) {
          float& d = depth.at(gx * n + u, gy * n + v);
          const bool keep = k < 3 || ((k == 3 || k == 4) && v == 2) || (k == 5 && (u + v) % 3 == 0);
          d = keep && d > 0.0f ? d + sigma * unit(rng) : 0.0f;
        }
    }
  PcaConfig with;
  with.cell_size = n;
  with.normal_radius_cells = 2;
  with.compute_inv_sqrt = false;
  with.min_valid_fraction = 0.2;
  PcaConfig without = with;
  without.cell_spectra = false;
  const CellCloud a = reduceToCells(depth, l515(), with), b = reduceToCells(depth, l515(), without);
  EXPECT_TRUE(a.has_spectra);
  EXPECT_FALSE(b.has_spectra);
  EXPECT_GT(a.stats.pruned_degenerate, 300);  // the exact rows and the flattest noisy ones
  // Kept cells inside the undecided band (lambda1 / lambda2 below 4e-3): the solver's cases.
  int near_collinear = 0;
  for (const Cell& c : a.cells) near_collinear += c.eigenvalues(1) < 4e-3f * c.eigenvalues(2);
  EXPECT_GT(near_collinear, 50);
  EXPECT_EQ(a.stats.pruned_degenerate, b.stats.pruned_degenerate);
  EXPECT_EQ(a.stats.pruned_invalid, b.stats.pruned_invalid);
  EXPECT_EQ(a.grid_index, b.grid_index);
  ASSERT_EQ(a.cells.size(), b.cells.size());
  for (std::size_t i = 0; i < a.cells.size(); ++i) {
    ASSERT_TRUE(a.cells[i].mean_C == b.cells[i].mean_C) << i;
    ASSERT_TRUE(a.cells[i].cov == b.cells[i].cov) << i;
    ASSERT_TRUE(a.cells[i].normal_C == b.cells[i].normal_C) << i;
    ASSERT_GT(a.cells[i].eigenvalues(2), 0.0f);
    ASSERT_TRUE(b.cells[i].eigenvalues.isZero()) << i;
    ASSERT_EQ(b.cells[i].surface_variation, 0.0f);
    ASSERT_EQ(b.cells[i].det, 0.0f);
  }
  // With eigenvectors asked for (Cell Search) the spectra are always filled.
  PcaConfig fm = without;
  fm.compute_inv_sqrt = true;
  EXPECT_TRUE(reduceToCells(depth, l515(), fm).has_spectra);
}
