#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "depth_track/core/cells.hpp"

namespace depth_track {

namespace {
constexpr int kAllowedCellSizes[] = {2, 4, 5, 8, 10, 16, 32};
// A cell whose middle eigenvalue is this small relative to the largest has (nearly) collinear
// vertices: its plane, and so its normal, is undefined.
constexpr double kMinPlanarity = 1e-3;
}  // namespace

std::vector<std::string> PcaConfig::validate(int width, int height) const {
  std::vector<std::string> problems;
  const bool allowed = std::find(std::begin(kAllowedCellSizes), std::end(kAllowedCellSizes),
                                 cell_size) != std::end(kAllowedCellSizes);
  if (!allowed) {
    std::ostringstream s;
    s << "cell_size " << cell_size << " px is not one of 2, 4, 5, 8, 10, 16, 32";
    problems.push_back(s.str());
  } else if (width % cell_size != 0 || height % cell_size != 0) {
    std::ostringstream s;
    s << "cell_size " << cell_size << " px does not tile a " << width << "x" << height << " frame ("
      << width << " % " << cell_size << " = " << width % cell_size << ", " << height << " % "
      << cell_size << " = " << height % cell_size << ")";
    problems.push_back(s.str());
  }
  if (!(edge_jump_rel >= 0.0 && edge_jump_rel < 1.0))
    problems.push_back("edge_jump_rel must lie in [0, 1)");
  if (!(edge_jump_min_m >= 0.0)) problems.push_back("edge_jump_min_m must be >= 0 m");
  if (normal_radius_cells < 0 || normal_radius_cells > 4)
    problems.push_back("normal_radius_cells must lie in [0, 4]");
  if (!(normal_merge_dist_m > 0.0)) problems.push_back("normal_merge_dist_m must be > 0 m");
  if (!(min_valid_fraction > 0.0 && min_valid_fraction <= 1.0))
    problems.push_back("min_valid_fraction must lie in (0, 1]");
  if (!(min_eigenvalue_m2 > 0.0 && std::isfinite(min_eigenvalue_m2)))
    problems.push_back("min_eigenvalue_m2 must be a small positive number of m^2");
  return problems;
}

namespace {

enum class CellOutcome { kKept, kInvalid, kDegenerate, kEdge };

// True when two 4-neighbouring valid pixels of the cell differ by more than the edge threshold.
bool spansEdge(const DepthImage& depth, int u0, int v0, int n, const PcaConfig& config) {
  const float rel = static_cast<float>(config.edge_jump_rel);
  const float floor_m = static_cast<float>(config.edge_jump_min_m);
  auto jump = [&](float a, float b) {
    return a > 0.0f && b > 0.0f && std::abs(a - b) > std::max(floor_m, rel * std::min(a, b));
  };
  for (int v = v0; v < v0 + n; ++v) {
    const float* row = depth.data.data() + static_cast<std::size_t>(v) * depth.width;
    const float* below = row + depth.width;
    for (int u = u0; u < u0 + n; ++u) {
      if (u + 1 < u0 + n && jump(row[u], row[u + 1])) return true;
      if (v + 1 < v0 + n && jump(row[u], below[u])) return true;
    }
  }
  return false;
}

// Reduces one grid cell; u_ray/v_ray hold (u - cx)/fx per column and (v - cy)/fy per row.
CellOutcome reduceCell(const DepthImage& depth, const std::vector<float>& u_ray,
                       const std::vector<float>& v_ray, int gx, int gy, const PcaConfig& config,
                       int min_valid, Cell* cell) {
  const int n = config.cell_size;
  const int u0 = gx * n, v0 = gy * n;
  // Up to 32x32 vertices on the stack.
  float xs[32 * 32], ys[32 * 32], zs[32 * 32];
  int count = 0;
  double sx = 0, sy = 0, sz = 0;
  for (int v = v0; v < v0 + n; ++v) {
    const float* row = depth.data.data() + static_cast<std::size_t>(v) * depth.width;
    const float vr = v_ray[v];
    for (int u = u0; u < u0 + n; ++u) {
      const float z = row[u];
      if (!(z > 0.0f)) continue;
      xs[count] = u_ray[u] * z;
      ys[count] = vr * z;
      zs[count] = z;
      sx += xs[count];
      sy += ys[count];
      sz += z;
      ++count;
    }
    // Early out for the default drop-out rule once too many pixels are missing.
    if ((v - v0 + 1) * n - count > n * n - min_valid) return CellOutcome::kInvalid;
  }
  if (count < min_valid || count < 3) return CellOutcome::kInvalid;
  if (config.edge_jump_rel > 0.0 && spansEdge(depth, u0, v0, n, config)) return CellOutcome::kEdge;

  const double inv = 1.0 / count;
  const Eigen::Vector3d mean(sx * inv, sy * inv, sz * inv);
  // Second pass about the mean: accurate covariance even for metre-scale offsets in float input.
  double cxx = 0, cxy = 0, cxz = 0, cyy = 0, cyz = 0, czz = 0;
  for (int i = 0; i < count; ++i) {
    const double dx = xs[i] - mean.x(), dy = ys[i] - mean.y(), dz = zs[i] - mean.z();
    cxx += dx * dx;
    cxy += dx * dy;
    cxz += dx * dz;
    cyy += dy * dy;
    cyz += dy * dz;
    czz += dz * dz;
  }
  const double norm = 1.0 / (count - 1);
  Eigen::Matrix3d cov;
  cov << cxx, cxy, cxz, cxy, cyy, cyz, cxz, cyz, czz;
  cov *= norm;

  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
  es.computeDirect(cov);
  Eigen::Vector3d lambda = es.eigenvalues().cwiseMax(0.0);  // ascending
  if (!(lambda(1) > kMinPlanarity * lambda(2)) || !(lambda(2) > 0.0))
    return CellOutcome::kDegenerate;
  Eigen::Matrix3d vecs = es.eigenvectors();
  Eigen::Vector3d normal = vecs.col(0).normalized();
  if (normal.dot(mean) > 0.0) normal = -normal;  // face the camera (which sits at the origin)
  vecs.col(0) = normal;
  if (!normal.allFinite()) return CellOutcome::kDegenerate;

  const Eigen::Vector3d reg = lambda.array() + config.min_eigenvalue_m2;
  const Eigen::Matrix3d inv_sqrt =
      vecs * reg.array().rsqrt().matrix().asDiagonal() * vecs.transpose();

  cell->gx = gx;
  cell->gy = gy;
  cell->n_valid = count;
  cell->mean_C = mean.cast<float>();
  cell->normal_C = normal.cast<float>();
  cell->cov = cov.cast<float>();
  cell->eigenvalues = lambda.cast<float>();
  cell->eigenvectors = vecs.cast<float>();
  cell->cov_inv_sqrt = inv_sqrt.cast<float>();
  const double sum = lambda.sum();
  cell->surface_variation = static_cast<float>(sum > 0.0 ? lambda(0) / sum : 0.0);
  cell->det = static_cast<float>(lambda.prod());
  return CellOutcome::kKept;
}

// Re-estimates each cell's normal from the pooled scatter of the cells around it (sufficient
// statistics: count, mean, covariance), skipping neighbours whose mean is far from the cell's.
void poolNormals(const PcaConfig& config, CellCloud* cloud) {
  const int r = config.normal_radius_cells;
  const double max_d2 = config.normal_merge_dist_m * config.normal_merge_dist_m;
  std::vector<Eigen::Vector3f> normals(cloud->cells.size());
  for (std::size_t i = 0; i < cloud->cells.size(); ++i) {
    const Cell& c = cloud->cells[i];
    const Eigen::Vector3d m0 = c.mean_C.cast<double>();
    double n = 0.0;
    Eigen::Vector3d s1 = Eigen::Vector3d::Zero();
    Eigen::Matrix3d s2 = Eigen::Matrix3d::Zero();  // sum of outer products about m0
    for (int y = c.gy - r; y <= c.gy + r; ++y)
      for (int x = c.gx - r; x <= c.gx + r; ++x) {
        const int j = cloud->cellAt(x, y);
        if (j < 0) continue;
        const Cell& o = cloud->cells[j];
        const Eigen::Vector3d d = o.mean_C.cast<double>() - m0;
        if (d.squaredNorm() > max_d2) continue;
        const double k = o.n_valid;
        n += k;
        s1 += k * d;
        s2 += (k - 1.0) * o.cov.cast<double>() + k * d * d.transpose();
      }
    const Eigen::Vector3d mean = s1 / n;
    const Eigen::Matrix3d scatter = s2 - n * mean * mean.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(scatter);
    Eigen::Vector3d normal = es.eigenvectors().col(0).normalized();
    if (normal.dot(m0) > 0.0) normal = -normal;
    normals[i] = normal.allFinite() ? normal.cast<float>() : c.normal_C;
  }
  for (std::size_t i = 0; i < normals.size(); ++i) cloud->cells[i].normal_C = normals[i];
}

}  // namespace

CellCloud reduceToCells(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                        const PcaConfig& config, int threads) {
  checkFrameSize(depth, intrinsics);
  const auto problems = config.validate(depth.width, depth.height);
  if (!problems.empty()) throw DepthInputError("PCA reduction: " + joinProblems(problems));

  CellCloud cloud;
  cloud.cell_size = config.cell_size;
  cloud.grid_w = depth.width / config.cell_size;
  cloud.grid_h = depth.height / config.cell_size;
  const int n_cells = cloud.grid_w * cloud.grid_h;
  cloud.grid_index.assign(n_cells, -1);

  std::vector<float> u_ray(depth.width), v_ray(depth.height);
  for (int u = 0; u < depth.width; ++u)
    u_ray[u] = static_cast<float>((u - intrinsics.cx) / intrinsics.fx);
  for (int v = 0; v < depth.height; ++v)
    v_ray[v] = static_cast<float>((v - intrinsics.cy) / intrinsics.fy);
  const int per_cell = config.cell_size * config.cell_size;
  const int min_valid =
      std::max(3, static_cast<int>(std::ceil(config.min_valid_fraction * per_cell - 1e-9)));

  // Reduce into a dense grid-ordered buffer, then compact: deterministic for any thread count.
  std::vector<Cell> dense(n_cells);
  std::vector<unsigned char> outcome(n_cells);
  auto rows = [&](const tbb::blocked_range<int>& r) {
    for (int gy = r.begin(); gy < r.end(); ++gy)
      for (int gx = 0; gx < cloud.grid_w; ++gx) {
        const int i = gy * cloud.grid_w + gx;
        outcome[i] = static_cast<unsigned char>(
            reduceCell(depth, u_ray, v_ray, gx, gy, config, min_valid, &dense[i]));
      }
  };
  if (threads > 1) {
    tbb::task_arena arena(threads);
    arena.execute([&] { tbb::parallel_for(tbb::blocked_range<int>(0, cloud.grid_h, 4), rows); });
  } else {
    rows(tbb::blocked_range<int>(0, cloud.grid_h));
  }

  cloud.cells.reserve(n_cells);
  for (int i = 0; i < n_cells; ++i) {
    switch (static_cast<CellOutcome>(outcome[i])) {
      case CellOutcome::kKept:
        cloud.grid_index[i] = static_cast<int>(cloud.cells.size());
        cloud.cells.push_back(dense[i]);
        break;
      case CellOutcome::kInvalid:
        ++cloud.stats.pruned_invalid;
        break;
      case CellOutcome::kDegenerate:
        ++cloud.stats.pruned_degenerate;
        break;
      case CellOutcome::kEdge:
        ++cloud.stats.pruned_edge;
        break;
    }
  }
  if (config.normal_radius_cells > 0) poolNormals(config, &cloud);
  cloud.stats.total = n_cells;
  cloud.stats.retained = static_cast<int>(cloud.cells.size());
  return cloud;
}

}  // namespace depth_track
