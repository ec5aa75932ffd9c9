#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_noise.hpp"
#include "simd4.hpp"

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
  if (!(noise_sigma_const_m >= 0.0) || !(noise_sigma_quad_per_m >= 0.0))
    problems.push_back("noise_sigma_const_m and noise_sigma_quad_per_m must be >= 0");
  if (!(edge_jump_sigmas >= 0.0)) problems.push_back("edge_jump_sigmas must be >= 0");
  if (normal_radius_cells < 0 || normal_radius_cells > 4)
    problems.push_back("normal_radius_cells must lie in [0, 4]");
  if (!(normal_merge_dist_m > 0.0)) problems.push_back("normal_merge_dist_m must be > 0 m");
  if (!(crease_sigmas >= 0.0 && std::isfinite(crease_sigmas)))
    problems.push_back("crease_sigmas must be >= 0 (0 = off)");
  if (crease_min_radius_cells < 1 || crease_min_radius_cells > 4)
    problems.push_back("crease_min_radius_cells must lie in [1, 4]");
  if (!(min_valid_fraction > 0.0 && min_valid_fraction <= 1.0))
    problems.push_back("min_valid_fraction must lie in (0, 1]");
  if (!(min_eigenvalue_m2 > 0.0 && std::isfinite(min_eigenvalue_m2)))
    problems.push_back("min_eigenvalue_m2 must be a small positive number of m^2");
  return problems;
}

namespace {

// Adjugate (transposed cofactor matrix) of a symmetric 3x3 matrix: det(S) S^-1 where S is
// invertible, and still defined (a projector onto the null space) where it is not.
Eigen::Matrix3d adjugate(const Eigen::Matrix3d& S) {
  Eigen::Matrix3d a;
  a(0, 0) = S(1, 1) * S(2, 2) - S(1, 2) * S(1, 2);
  a(0, 1) = a(1, 0) = S(0, 2) * S(1, 2) - S(0, 1) * S(2, 2);
  a(0, 2) = a(2, 0) = S(0, 1) * S(1, 2) - S(0, 2) * S(1, 1);
  a(1, 1) = S(0, 0) * S(2, 2) - S(0, 2) * S(0, 2);
  a(1, 2) = a(2, 1) = S(0, 1) * S(0, 2) - S(0, 0) * S(1, 2);
  a(2, 2) = S(0, 0) * S(1, 1) - S(0, 1) * S(0, 1);
  return a;
}

// Smallest eigenvector of a symmetric PSD 3x3 matrix with adjugate `adj`, by inverse iteration
// from `start` (the adjugate has the inverse's eigenvectors, and stays defined when the matrix
// is singular), two steps per normalisation (with adj^2: the normalisation's square root and
// division are the slow, serial part). False when it has not settled to 1e-7 within eight steps
// (a small eigengap): the caller then uses the closed-form solver.
bool smallestEigenvector(const Eigen::Matrix3d& adj, Eigen::Vector3d start, Eigen::Vector3d* out) {
  const Eigen::Matrix3d adj2 = adj * adj;
  for (int step = 0; step < 4; ++step) {
    Eigen::Vector3d next = adj2 * start;
    const double len = next.norm();
    if (!(len > 1e-300) || !std::isfinite(len)) return false;
    next *= 1.0 / len;
    if (next.dot(start) < 0.0) next = -next;
    const bool settled = (next - start).squaredNorm() < 1e-14;
    start = next;
    if (settled && step >= 1) {
      *out = start;
      return true;
    }
  }
  return false;
}

enum class CellOutcome { kKept, kInvalid, kDegenerate, kEdge };

enum class Planarity { kPlanar, kCollinear, kUndecided };

// The planarity test lambda1 > kMinPlanarity * lambda2 (ascending eigenvalues of a PSD matrix)
// decided, where it can be, from the trace T and the sum E2 of the principal 2x2 minors
// (E2 = l0 l1 + l0 l2 + l1 l2) without solving for the eigenvalues. With l2 <= T and
// l1 l2 <= E2 <= 3 l1 l2: E2 > 3 eps T^2 implies the test passes and E2 <= eps T^2 / 9 that it
// fails. Margins of a third and a half keep rounding out of both; between them, and for a zero or
// non-finite trace, the caller solves.
Planarity planarityFromInvariants(const Eigen::Matrix3d& S) {
  const double T = S(0, 0) + S(1, 1) + S(2, 2);
  const double E2 = S(0, 0) * S(1, 1) - S(0, 1) * S(0, 1) + S(0, 0) * S(2, 2) - S(0, 2) * S(0, 2) +
                    S(1, 1) * S(2, 2) - S(1, 2) * S(1, 2);
  if (!(T > 0.0) || !std::isfinite(T) || !std::isfinite(E2)) return Planarity::kUndecided;
  const double T2 = T * T;
  if (E2 > 4.0 * kMinPlanarity * T2) return Planarity::kPlanar;
  if (E2 < kMinPlanarity * T2 / 18.0) return Planarity::kCollinear;
  return Planarity::kUndecided;
}

// One cell's pass over its pixels: sums of vertices taken relative to the first valid vertex in
// float (so the covariance does not cancel metre-sized offsets: patch extents are centimetres,
// so it keeps ~1e-9 m^2 absolute precision), and the depth range that gates the edge test.
struct CellSums {
  int count = 0, missing = 0;
  float ox = 0, oy = 0, oz = 0;
  float sx = 0, sy = 0, sz = 0, sxx = 0, sxy = 0, sxz = 0, syy = 0, syz = 0, szz = 0;
  float z_lo = std::numeric_limits<float>::max(), z_hi = 0.0f;
};

// The pass for one cell. u_ray/v_ray hold (u - cx)/fx per column and (v - cy)/fy per row. False
// as soon as more than max_missing pixels have no return (the cell is invalid).
bool sumCell(const DepthImage& depth, const float* u_ray, const float* v_ray, int gx, int gy,
             int n, int max_missing, CellSums* out) {
  const int u0 = gx * n, v0 = gy * n;
  CellSums& s = *out;
  s = CellSums();
  for (int v = v0; v < v0 + n; ++v) {
    const float* row = depth.data.data() + static_cast<std::size_t>(v) * depth.width;
    const float vr = v_ray[v];
    for (int u = u0; u < u0 + n; ++u) {
      const float z = row[u];
      if (!(z > 0.0f)) {
        if (++s.missing > max_missing) return false;
        continue;
      }
      const float x = u_ray[u] * z, y = vr * z;
      if (s.count == 0) {
        s.ox = x;
        s.oy = y;
        s.oz = z;
      }
      s.z_lo = std::min(s.z_lo, z);
      s.z_hi = std::max(s.z_hi, z);
      const float dx = x - s.ox, dy = y - s.oy, dz = z - s.oz;
      s.sx += dx;
      s.sy += dy;
      s.sz += dz;
      s.sxx += dx * dx;
      s.sxy += dx * dy;
      s.sxz += dx * dz;
      s.syy += dy * dy;
      s.syz += dy * dz;
      s.szz += dz * dz;
      ++s.count;
    }
  }
  return true;
}

// The same pass for the four cells gx..gx+3 of a grid row at once, one cell per lane: every
// lane takes its pixels in sumCell's order and does sumCell's arithmetic on them, so the sums
// are sumCell's to the bit (a pixel without a return adds +0, which changes no sum). That holds
// while the compiler fuses multiply-adds in neither path (x86-64 has no FMA in its baseline); a
// build that fuses them in one path only breaks it, and dt_test_pca says so. It does not stop
// early; a cell with too many missing pixels shows it in `missing`.
void sumFourCells(const DepthImage& depth, const float* u_ray, const float* v_ray, int gx, int gy,
                  int n, CellSums out[4]) {
  using simd4::splat;
  using simd4::V4f;
  using simd4::V4i;
  const int b = gx * n, v0 = gy * n;
  V4f ur[32];  // cell sizes are at most 32 px (PcaConfig::validate)
  for (int du = 0; du < n; ++du)
    ur[du] = V4f{u_ray[b + du], u_ray[b + n + du], u_ray[b + 2 * n + du], u_ray[b + 3 * n + du]};
  const V4f zero = splat(0.0f);
  V4i count = {0, 0, 0, 0}, missing = {0, 0, 0, 0};
  V4f ox = zero, oy = zero, oz = zero;
  V4f sx = zero, sy = zero, sz = zero, sxx = zero, sxy = zero, sxz = zero, syy = zero,
      syz = zero, szz = zero;
  V4f z_lo = splat(std::numeric_limits<float>::max()), z_hi = zero;
  for (int v = v0; v < v0 + n; ++v) {
    const float* row = depth.data.data() + static_cast<std::size_t>(v) * depth.width + b;
    const V4f vr = splat(v_ray[v]);
    for (int du = 0; du < n; ++du) {
      const V4f z = {row[du], row[n + du], row[2 * n + du], row[3 * n + du]};
      const V4i valid = z > 0.0f;  // false for NaN, as in sumCell
      missing -= ~valid;
      const V4f x = ur[du] * z, y = vr * z;
      const V4i first = valid & (count == 0);
      ox = first ? x : ox;
      oy = first ? y : oy;
      oz = first ? z : oz;
      z_lo = (valid & (z < z_lo)) ? z : z_lo;  // std::min(z_lo, z)
      z_hi = (valid & (z_hi < z)) ? z : z_hi;  // std::max(z_hi, z)
      const V4f dx = valid ? x - ox : zero, dy = valid ? y - oy : zero,
                dz = valid ? z - oz : zero;
      sx += dx;
      sy += dy;
      sz += dz;
      sxx += dx * dx;
      sxy += dx * dy;
      sxz += dx * dz;
      syy += dy * dy;
      syz += dy * dz;
      szz += dz * dz;
      count -= valid;
    }
  }
  for (int k = 0; k < 4; ++k) {
    CellSums& s = out[k];
    s.count = count[k];
    s.missing = missing[k];
    s.ox = ox[k], s.oy = oy[k], s.oz = oz[k];
    s.sx = sx[k], s.sy = sy[k], s.sz = sz[k];
    s.sxx = sxx[k], s.sxy = sxy[k], s.sxz = sxz[k];
    s.syy = syy[k], s.syz = syz[k], s.szz = szz[k];
    s.z_lo = z_lo[k], s.z_hi = z_hi[k];
  }
}

// A cell from its sums: the occluding-edge test against the left and upper neighbours (read
// from `depth`), then the mean, covariance and normal.
CellOutcome finishCell(const DepthImage& depth, int gx, int gy, const PcaConfig& config,
                       int min_valid, const CellSums& s, Cell* cell) {
  const int n = config.cell_size;
  const int u0 = gx * n, v0 = gy * n;
  if (s.missing > n * n - min_valid) return CellOutcome::kInvalid;
  const bool edge_test = config.edge_jump_rel > 0.0;
  const float rel = static_cast<float>(config.edge_jump_rel);
  const float floor_m = static_cast<float>(config.edge_jump_min_m);
  const float k0 = static_cast<float>(config.edge_jump_sigmas * config.noise_sigma_const_m);
  const float k2 = static_cast<float>(config.edge_jump_sigmas * config.noise_sigma_quad_per_m);
  // Smallest jump that counts as an edge at depth z (the nearer of the two pixels).
  auto threshold = [&](float z) { return std::max(std::max(floor_m, rel * z), k0 + k2 * z * z); };
  auto jump = [&](float a, float b) {
    return a > 0.0f && b > 0.0f && std::abs(a - b) > threshold(std::min(a, b));
  };
  // Only a cell whose depths spread wider than one edge jump can contain one.
  if (edge_test && s.z_hi - s.z_lo > threshold(s.z_lo)) {
    for (int v = v0; v < v0 + n; ++v) {
      const float* row = depth.data.data() + static_cast<std::size_t>(v) * depth.width;
      for (int u = u0; u < u0 + n; ++u) {
        if ((u > u0 && jump(row[u], row[u - 1])) || (v > v0 && jump(row[u], row[u - depth.width])))
          return CellOutcome::kEdge;
      }
    }
  }
  if (s.count < min_valid || s.count < 3) return CellOutcome::kInvalid;

  const double inv = 1.0 / s.count;
  const double mx = s.sx * inv, my = s.sy * inv, mz = s.sz * inv;
  const double norm = 1.0 / (s.count - 1);
  Eigen::Matrix3d cov;
  cov(0, 0) = (s.sxx - s.sx * mx) * norm;
  cov(0, 1) = cov(1, 0) = (s.sxy - s.sx * my) * norm;
  cov(0, 2) = cov(2, 0) = (s.sxz - s.sx * mz) * norm;
  cov(1, 1) = (s.syy - s.sy * my) * norm;
  cov(1, 2) = cov(2, 1) = (s.syz - s.sy * mz) * norm;
  cov(2, 2) = (s.szz - s.sz * mz) * norm;
  const Eigen::Vector3d mean(double(s.ox) + mx, double(s.oy) + my, double(s.oz) + mz);

  // With pooled normals and no Förstner–Moonen terms only the eigenvalues of the cell itself are
  // read (degeneracy, surface variation): skip its eigenvectors, and let pooling start from the
  // viewing ray.
  const bool values_only = config.normal_radius_cells > 0 && !config.compute_inv_sqrt;
  // Without the spectra (and without eigenvectors) most cells need no eigensolver at all.
  const bool spectra = config.computesSpectra();
  const Planarity planarity = spectra ? Planarity::kUndecided : planarityFromInvariants(cov);
  if (planarity == Planarity::kCollinear) return CellOutcome::kDegenerate;
  Eigen::Vector3d lambda = Eigen::Vector3d::Zero();
  Eigen::Matrix3d vecs = Eigen::Matrix3d::Zero();
  Eigen::Vector3d normal = -mean.normalized();
  if (planarity == Planarity::kUndecided) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(cov, values_only ? Eigen::EigenvaluesOnly : Eigen::ComputeEigenvectors);
    lambda = es.eigenvalues().cwiseMax(0.0);  // ascending
    if (!values_only) {
      vecs = es.eigenvectors();
      normal = vecs.col(0).normalized();
    }
    if (!(lambda(1) > kMinPlanarity * lambda(2)) || !(lambda(2) > 0.0))
      return CellOutcome::kDegenerate;
    if (!spectra) lambda.setZero();  // the same cells either way, and none with spectra
  }
  if (normal.dot(mean) > 0.0) normal = -normal;  // face the camera (which sits at the origin)
  if (!normal.allFinite()) return CellOutcome::kDegenerate;
  vecs.col(0) = normal;

  cell->gx = gx;
  cell->gy = gy;
  cell->n_valid = s.count;
  cell->mean_C = mean.cast<float>();
  cell->normal_C = normal.cast<float>();
  cell->cov = cov.cast<float>();
  cell->eigenvectors = vecs.cast<float>();
  if (config.compute_inv_sqrt) {
    const Eigen::Vector3d reg = lambda.array() + config.min_eigenvalue_m2;
    cell->cov_inv_sqrt =
        (vecs * reg.array().rsqrt().matrix().asDiagonal() * vecs.transpose()).cast<float>();
  } else {
    cell->cov_inv_sqrt.setZero();
  }
  const CellSpectrum spectrum = spectrumFromEigenvalues(lambda);  // zeros without spectra
  cell->eigenvalues = spectrum.eigenvalues;
  cell->surface_variation = spectrum.surface_variation;
  cell->det = spectrum.det;
  return CellOutcome::kKept;
}

// Re-estimates each cell's normal from the pooled scatter of the cells around it, skipping
// neighbours whose mean is far from the cell's. Per-cell sufficient statistics about the camera
// origin (count k, k*mean, (k-1)*cov + k*mean*mean^T) are summed in double precision, where the
// metre-sized terms cancel to well below the covariance of a millimetre-noise patch. A patch
// thicker than PcaConfig::crease_sigmas sigma(z) is pooled a second time, over the neighbours
// near its plane through the cell's own mean.
void poolNormals(const PcaConfig& config, CellCloud* cloud) {
  // Per cell: k, s1 (3), s2 (xx xy xz yy yz zz) as one vector of ten (summed two at a time), and
  // the float mean the merge test reads, side by side so a neighbour is one contiguous read.
  using Sums = Eigen::Matrix<double, 10, 1>;
  struct Stats {
    Sums v;
    Eigen::Vector3f mean;
  };
  const std::size_t n_cells = cloud->cells.size();
  std::vector<Stats> st(n_cells);
  for (std::size_t i = 0; i < n_cells; ++i) {
    const Cell& c = cloud->cells[i];
    const double k = c.n_valid;
    const Eigen::Vector3d m = c.mean_C.cast<double>();
    const Eigen::Matrix3f& C = c.cov;
    st[i].v << k, k * m.x(), k * m.y(), k * m.z(),  //
        (k - 1) * C(0, 0) + k * m.x() * m.x(), (k - 1) * C(0, 1) + k * m.x() * m.y(),
        (k - 1) * C(0, 2) + k * m.x() * m.z(), (k - 1) * C(1, 1) + k * m.y() * m.y(),
        (k - 1) * C(1, 2) + k * m.y() * m.z(), (k - 1) * C(2, 2) + k * m.z() * m.z();
    st[i].mean = c.mean_C;
  }
  const int r = config.normal_radius_cells;
  const float max_d2 = static_cast<float>(config.normal_merge_dist_m * config.normal_merge_dist_m);
  std::vector<Eigen::Vector3f> normals(n_cells);
  const double t = config.crease_sigmas;
  DepthNoiseModel noise;
  noise.const_m = config.noise_sigma_const_m;
  noise.quad_per_m = config.noise_sigma_quad_per_m;
  const bool repool = t > 0.0 && r >= config.crease_min_radius_cells && noise.known();
  // Pools cell i's neighbours (those within the merge distance; with `plane`, only those whose
  // mean lies within tol of the plane through cell i's mean with normal *plane) and returns the
  // pooled normal, facing the camera, and the pooled patch's variance along it (m^2).
  auto pool = [&](std::size_t i, const Eigen::Vector3f* plane, float tol, double* thickness) {
    const Cell& c = cloud->cells[i];
    const Eigen::Vector3f mean_i = st[i].mean;
    Sums sum = Sums::Zero();
    for (int y = std::max(0, c.gy - r); y <= std::min(cloud->grid_h - 1, c.gy + r); ++y) {
      const int* idx = cloud->grid_index.data() + static_cast<std::size_t>(y) * cloud->grid_w;
      for (int x = std::max(0, c.gx - r); x <= std::min(cloud->grid_w - 1, c.gx + r); ++x) {
        const int j = idx[x];
        if (j < 0) continue;
        const Stats& o = st[j];
        if ((o.mean - mean_i).squaredNorm() > max_d2) continue;
        if (plane && std::abs(plane->dot(o.mean - mean_i)) > tol) continue;
        sum += o.v;
      }
    }
    const double k = sum(0);
    const Eigen::Vector3d s1 = sum.segment<3>(1);
    const double* s2 = sum.data() + 4;
    const Eigen::Vector3d m = s1 / k;
    Eigen::Matrix3d S;
    S(0, 0) = s2[0] - k * m.x() * m.x();
    S(0, 1) = S(1, 0) = s2[1] - k * m.x() * m.y();
    S(0, 2) = S(2, 0) = s2[2] - k * m.x() * m.z();
    S(1, 1) = s2[3] - k * m.y() * m.y();
    S(1, 2) = S(2, 1) = s2[4] - k * m.y() * m.z();
    S(2, 2) = s2[5] - k * m.z() * m.z();
    // Smallest eigenvector by inverse iteration from the cell's own normal (a few steps on a
    // surface patch); the closed-form solver where that does not settle.
    Eigen::Vector3d normal;
    if (!smallestEigenvector(adjugate(S), c.normal_C.cast<double>(), &normal)) {
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
      es.computeDirect(S);
      normal = es.eigenvectors().col(0).normalized();
    }
    if (normal.dot(c.mean_C.cast<double>()) > 0.0) normal = -normal;
    if (thickness) *thickness = normal.dot(S * normal) / k;
    return normal.allFinite() ? normal.cast<float>() : c.normal_C;
  };
  for (std::size_t i = 0; i < n_cells; ++i) {
    double thickness = 0.0;
    normals[i] = pool(i, nullptr, 0.0f, repool ? &thickness : nullptr);
    if (!repool) continue;
    // Across a crease the pooled plane is a compromise of the two surfaces, off both by more than
    // the noise; the neighbours near that plane through the cell's own mean are, for the most
    // part, those on the cell's own surface.
    const double sigma = noise.sigmaAt(cloud->cells[i].mean_C.z());
    if (thickness > t * t * sigma * sigma) {
      const Eigen::Vector3f across = normals[i];
      normals[i] = pool(i, &across, static_cast<float>(t * sigma), nullptr);
    }
  }
  for (std::size_t i = 0; i < n_cells; ++i) cloud->cells[i].normal_C = normals[i];
}

}  // namespace

CellSpectrum spectrumFromEigenvalues(const Eigen::Vector3d& lambda) {
  CellSpectrum s;
  s.eigenvalues = lambda.cast<float>();
  const double sum = lambda.sum();
  s.surface_variation = static_cast<float>(sum > 0.0 ? lambda(0) / sum : 0.0);
  s.det = static_cast<float>(lambda.prod());
  return s;
}

CellSpectrum spectrumOf(const Eigen::Matrix3f& cov) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
  es.computeDirect(cov.cast<double>(), Eigen::EigenvaluesOnly);
  return spectrumFromEigenvalues(es.eigenvalues().cwiseMax(0.0));
}

CellCloud reduceToCells(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                        const PcaConfig& config, int threads) {
  return reduceToCells(depth, intrinsics, config, WorkerPool(std::max(1, threads)));
}

CellCloud reduceToCells(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                        const PcaConfig& config, const WorkerPool& pool) {
  checkFrameSize(depth, intrinsics);
  const auto problems = config.validate(depth.width, depth.height);
  if (!problems.empty()) throw DepthInputError("PCA reduction: " + joinProblems(problems));

  CellCloud cloud;
  cloud.cell_size = config.cell_size;
  cloud.has_spectra = config.computesSpectra();
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

  // Cells are produced row by row in grid order, so the result is the same for any thread count.
  const int n = config.cell_size, max_missing = per_cell - min_valid;
  auto reduceRow = [&](int gy, std::vector<Cell>* out, ReductionStats* stats) {
    Cell cell;
    auto emit = [&](CellOutcome outcome) {
      switch (outcome) {
        case CellOutcome::kKept:
          out->push_back(cell);
          break;
        case CellOutcome::kInvalid:
          ++stats->pruned_invalid;
          break;
        case CellOutcome::kDegenerate:
          ++stats->pruned_degenerate;
          break;
        case CellOutcome::kEdge:
          ++stats->pruned_edge;
          break;
      }
    };
    // Four cells' sums at a time while four remain in the row; the last few one by one.
    CellSums sums[4];
    int gx = 0;
    for (; gx + 4 <= cloud.grid_w; gx += 4) {
      sumFourCells(depth, u_ray.data(), v_ray.data(), gx, gy, n, sums);
      for (int k = 0; k < 4; ++k)
        emit(finishCell(depth, gx + k, gy, config, min_valid, sums[k], &cell));
    }
    for (; gx < cloud.grid_w; ++gx)
      emit(sumCell(depth, u_ray.data(), v_ray.data(), gx, gy, n, max_missing, &sums[0])
               ? finishCell(depth, gx, gy, config, min_valid, sums[0], &cell)
               : CellOutcome::kInvalid);
  };
  if (pool.threads() > 1) {
    std::vector<std::vector<Cell>> rows(cloud.grid_h);
    std::vector<ReductionStats> row_stats(cloud.grid_h);
    pool.parallelFor(0, cloud.grid_h, 4, [&](int b, int e) {
      for (int gy = b; gy < e; ++gy) reduceRow(gy, &rows[gy], &row_stats[gy]);
    });
    std::size_t total = 0;
    for (const auto& r : rows) total += r.size();
    cloud.cells.reserve(total);
    for (int gy = 0; gy < cloud.grid_h; ++gy) {
      cloud.cells.insert(cloud.cells.end(), rows[gy].begin(), rows[gy].end());
      cloud.stats.pruned_invalid += row_stats[gy].pruned_invalid;
      cloud.stats.pruned_degenerate += row_stats[gy].pruned_degenerate;
      cloud.stats.pruned_edge += row_stats[gy].pruned_edge;
    }
  } else {
    cloud.cells.reserve(n_cells);
    for (int gy = 0; gy < cloud.grid_h; ++gy) reduceRow(gy, &cloud.cells, &cloud.stats);
  }
  for (std::size_t i = 0; i < cloud.cells.size(); ++i) {
    const Cell& c = cloud.cells[i];
    cloud.grid_index[static_cast<std::size_t>(c.gy) * cloud.grid_w + c.gx] = static_cast<int>(i);
  }
  if (config.normal_radius_cells > 0) poolNormals(config, &cloud);
  cloud.stats.total = n_cells;
  cloud.stats.retained = static_cast<int>(cloud.cells.size());
  return cloud;
}

}  // namespace depth_track
