#include "depth_track/core/registration.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "depth_track/core/degeneracy.hpp"
#include "depth_track/core/se3.hpp"
#include "simd4.hpp"

namespace depth_track {

RegistrationMethod parseRegistrationMethod(const std::string& name) {
  if (name == "p2p") return RegistrationMethod::kPointToPoint;
  if (name == "p2l") return RegistrationMethod::kPointToPlane;
  if (name == "cell_search") return RegistrationMethod::kCellSearch;
  throw std::invalid_argument("unknown registration method '" + name +
                              "' (expected p2p, p2l or cell_search)");
}

std::string toString(RegistrationMethod method) {
  switch (method) {
    case RegistrationMethod::kPointToPoint:
      return "p2p";
    case RegistrationMethod::kPointToPlane:
      return "p2l";
    case RegistrationMethod::kCellSearch:
      return "cell_search";
  }
  return "?";
}

std::vector<std::string> RegistrationConfig::validate() const {
  std::vector<std::string> p;
  if (!(match.dist_min_m > 0.0)) p.push_back("dist_min_m must be > 0 m");
  if (!(match.cos_min > -1.0 && match.cos_min <= 1.0)) p.push_back("cos_min must lie in (-1, 1]");
  if (!(match.normal_weight_m >= 0.0)) p.push_back("normal_weight_m must be >= 0 m");
  if (!(match.initial_dist_m >= 0.0)) p.push_back("initial_dist_m must be >= 0 m");
  if (patience < 1) p.push_back("patience must be >= 1");
  if (match.search_radius_cells < 0 || match.search_radius_cells > 16)
    p.push_back("search_radius_cells must lie in [0, 16]");
  if (!(fm_thresh > 0.0)) p.push_back("fm_thresh must be > 0");
  if (max_iterations < 1 || max_iterations > 1000)
    p.push_back("max_iterations must lie in [1, 1000]");
  if (!(tolerance_m >= 0.0)) p.push_back("tolerance_m must be >= 0 m");
  if (!(tolerance_rad >= 0.0)) p.push_back("tolerance_rad must be >= 0 rad");
  if (!(huber_delta_m > 0.0)) p.push_back("huber_delta_m must be > 0 m");
  if (!noise.valid()) p.push_back("noise: the depth-noise coefficients must be >= 0");
  if (!(noise_ref_depth_m >= 0.0)) p.push_back("noise_ref_depth_m must be >= 0 m (0 = off)");
  if (!(noise_weighting_min >= 0.0 && noise_weighting_min <= 1.0))
    p.push_back("noise_weighting_min must be in [0, 1] (0 = no floor)");
  if (min_matches < 6) p.push_back("min_matches must be >= 6 (six unknowns)");
  for (const auto& s : degeneracy.validate()) p.push_back(s);
  return p;
}

double forstnerMoonenFromMatrices(const Eigen::Matrix3d& a_inv_sqrt, const Eigen::Matrix3d& b_reg) {
  const Eigen::Matrix3d d = a_inv_sqrt * b_reg * a_inv_sqrt;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
  es.computeDirect(0.5 * (d + d.transpose()), Eigen::EigenvaluesOnly);
  double fm = 0.0;
  for (int i = 0; i < 3; ++i) {
    const double lg = std::log(std::max(es.eigenvalues()(i), 1e-300));
    fm += lg * lg;
  }
  return fm;
}

double forstnerMoonen(const Cell& a, const Cell& b, double eps_m2) {
  const Eigen::Matrix3d b_reg = b.cov.cast<double>() + eps_m2 * Eigen::Matrix3d::Identity();
  return forstnerMoonenFromMatrices(a.cov_inv_sqrt.cast<double>(), b_reg);
}

Eigen::Isometry3d alignPointToPoint(const std::vector<Eigen::Vector3d>& p,
                                    const std::vector<Eigen::Vector3d>& q,
                                    const std::vector<double>& w) {
  if (p.size() != q.size() || (!w.empty() && w.size() != p.size()))
    throw std::invalid_argument("alignPointToPoint: point and weight counts differ");
  if (p.size() < 3) throw std::invalid_argument("alignPointToPoint: needs at least 3 pairs");
  double wsum = 0.0;
  Eigen::Vector3d mp = Eigen::Vector3d::Zero(), mq = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double wi = w.empty() ? 1.0 : w[i];
    wsum += wi;
    mp += wi * p[i];
    mq += wi * q[i];
  }
  if (!(wsum > 0.0)) throw std::invalid_argument("alignPointToPoint: weights sum to zero");
  mp /= wsum;
  mq /= wsum;
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < p.size(); ++i)
    S += (w.empty() ? 1.0 : w[i]) * (p[i] - mp) * (q[i] - mq).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(S, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  // Reflection check: a negative determinant would mirror the cloud instead of rotating it.
  if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0.0) D(2, 2) = -1.0;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = svd.matrixV() * D * svd.matrixU().transpose();
  T.translation() = mq - T.linear() * mp;
  return T;
}

namespace {

// Four floats at a time, for scoring four association candidates at once.
using simd4::load4;
using simd4::splat;
using simd4::V4f;
using simd4::V4i;

// Current cells moved into the reference frame by the running estimate.
struct Moved {
  std::vector<Eigen::Vector3f> p, n;
};

void moveCells(const CellCloud& current, const Eigen::Isometry3d& T_ref_cur, Moved* out) {
  const Eigen::Matrix3f R = T_ref_cur.rotation().cast<float>();
  const Eigen::Vector3f t = T_ref_cur.translation().cast<float>();
  const std::size_t n = current.cells.size();
  out->p.resize(n);
  out->n.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    out->p[i] = R * current.cells[i].mean_C + t;
    out->n[i] = R * current.cells[i].normal_C;
  }
}

// Projective association in the reference grid, then one-to-one resolution: every reference
// cell keeps only its cheapest claimant (ties go to the lower current index), so the result does
// not depend on evaluation order.
// Förstner–Moonen verdicts already reached for (reference, current) pairs: later ICP iterations
// mostly keep their pairs, and the gate barely changes with the small rotation updates.
struct FmCache {
  std::vector<int> ref;    ///< per current cell: the reference cell of the cached verdict, or -1
  std::vector<char> pass;  ///< per current cell: the verdict
};

MatchResult associate(const CellCloud& reference, const AssociationGrid& grid,
                      const CellCloud& current, const Moved& moved, const PinholeIntrinsics& K,
                      const Eigen::Matrix3d& R_ref_cur, const RegistrationConfig& config,
                      int radius, FmCache* fm_cache = nullptr) {
  MatchResult result;
  const std::size_t n_cur = current.cells.size();
  std::vector<int> best_ref(n_cur, -1);
  std::vector<float> best_cost(n_cur, std::numeric_limits<float>::max());
  const float dist_max = static_cast<float>(config.match.dist_min_m);
  const float dist_max2 = dist_max * dist_max;
  const float cos_min = static_cast<float>(config.match.cos_min);
  const float w2 = static_cast<float>(config.match.normal_weight_m * config.match.normal_weight_m);
  const float cs = static_cast<float>(reference.cell_size);
  const float fx = static_cast<float>(K.fx), fy = static_cast<float>(K.fy);
  const float cx = static_cast<float>(K.cx), cy = static_cast<float>(K.cy);
  radius = std::min(radius, grid.pad());
  const int* grid_index = grid.index().data();
  const float* gmx = grid.plane(AssociationGrid::kMeanX);
  const float* gmy = grid.plane(AssociationGrid::kMeanY);
  const float* gmz = grid.plane(AssociationGrid::kMeanZ);
  const float* gnx = grid.plane(AssociationGrid::kNormalX);
  const float* gny = grid.plane(AssociationGrid::kNormalY);
  const float* gnz = grid.plane(AssociationGrid::kNormalZ);
  const int grid_pad = grid.pad(), grid_stride = grid.stride();
  // Overlap mask: a cell predicted within one cell of the border of the reference view may have
  // its true partner outside it, so it is not matched at all.
  const float margin = config.overlap_mask ? cs : 0.0f;
  constexpr float kNone = std::numeric_limits<float>::max();
  // Lanes of the window's chunks of four that lie inside the window row (2 radius + 1 slots).
  const int width = 2 * radius + 1;
  std::array<V4i, (2 * 16 + 1 + 3) / 4> lane_mask{};  // radius <= 16 (config validation)
  for (int j = 0; 4 * j < width; ++j)
    for (int k = 0; k < 4; ++k) lane_mask[j][k] = 4 * j + k < width ? -1 : 0;
  const V4i lane = {0, 1, 2, 3};

  for (std::size_t c = 0; c < n_cur; ++c) {
    const Eigen::Vector3f& p = moved.p[c];
    if (!(p.z() > 0.0f)) continue;
    const float u = fx * p.x() / p.z() + cx, v = fy * p.y() / p.z() + cy;
    if (!K.inImage(u, v, margin)) continue;
    const int gx = static_cast<int>((u + 0.5f) / cs);
    const int gy = static_cast<int>((v + 0.5f) / cs);
    const Eigen::Vector3f& n = moved.n[c];
    const V4f px = splat(p.x()), py = splat(p.y()), pz = splat(p.z());
    const V4f nx = splat(n.x()), ny = splat(n.y()), nz = splat(n.z());
    // Four slots of a window row at a time (empty slots fail the distance gate, lanes past the
    // row's end are masked), each lane keeping its cheapest candidate. Slot indices run in
    // row-major order, so of candidates of equal cost the one with the lowest slot is the first
    // in that order, and wins.
    V4f lane_cost = splat(kNone);
    V4i lane_slot = {-1, -1, -1, -1};
    for (int y = gy - radius; y <= gy + radius; ++y) {
      const int row = (y + grid_pad) * grid_stride + grid_pad;
      for (int j = 0, x = gx - radius; x <= gx + radius; ++j, x += 4) {
        const int s = row + x;
        const V4f dx = px - load4(gmx + s), dy = py - load4(gmy + s), dz = pz - load4(gmz + s);
        const V4f rnx = load4(gnx + s), rny = load4(gny + s), rnz = load4(gnz + s);
        const V4f d2 = dx * dx + dy * dy + dz * dz;
        const V4f cosang = nx * rnx + ny * rny + nz * rnz;
        // Rank candidates by their offset along the reference surface, not by the full 3D
        // distance: picking the nearest of several noisy depths selects whichever noise happens
        // to agree with the current estimate, which pins the estimate where it is. The normal
        // term is |n - n_r|^2 = 2 - 2 cos for unit normals.
        const V4f along = dx * rnx + dy * rny + dz * rnz;
        const V4f cost = d2 - along * along + w2 * (2.0f - 2.0f * cosang);
        const V4i better =
            (d2 <= dist_max2) & (cosang >= cos_min) & (cost < lane_cost) & lane_mask[j];
        lane_cost = better ? cost : lane_cost;
        lane_slot = better ? lane + s : lane_slot;
      }
    }
    float best_c = lane_cost[0];
    int best_slot = lane_slot[0];
    for (int k = 1; k < 4; ++k) {
      if (lane_cost[k] < best_c || (lane_cost[k] == best_c && lane_slot[k] < best_slot)) {
        best_c = lane_cost[k];
        best_slot = lane_slot[k];
      }
    }
    const int best = best_slot < 0 ? -1 : grid_index[best_slot];
    if (best >= 0) {
      best_ref[c] = best;
      best_cost[c] = best_c;
      ++result.candidates;
    }
  }

  std::vector<int> claim(reference.cells.size(), -1);
  for (std::size_t c = 0; c < n_cur; ++c) {
    const int r = best_ref[c];
    if (r < 0) continue;
    const int holder = claim[r];
    if (holder < 0) {
      claim[r] = static_cast<int>(c);
    } else {
      ++result.duplicates_broken;
      if (best_cost[c] < best_cost[holder]) claim[r] = static_cast<int>(c);
    }
  }

  const bool gate_fm = config.method == RegistrationMethod::kCellSearch;
  const Eigen::Matrix3d eps = config.fm_eps_m2 * Eigen::Matrix3d::Identity();
  result.pairs.reserve(reference.cells.size());
  for (std::size_t r = 0; r < claim.size(); ++r) {
    const int c = claim[r];
    if (c < 0) continue;
    if (gate_fm) {
      bool pass;
      if (fm_cache && fm_cache->ref[c] == static_cast<int>(r)) {
        pass = fm_cache->pass[c];
      } else {
        const Eigen::Matrix3d b_reg =
            R_ref_cur * current.cells[c].cov.cast<double>() * R_ref_cur.transpose() + eps;
        pass = forstnerMoonenFromMatrices(reference.cells[r].cov_inv_sqrt.cast<double>(), b_reg) <=
               config.fm_thresh;
        if (fm_cache) {
          fm_cache->ref[c] = static_cast<int>(r);
          fm_cache->pass[c] = pass;
        }
      }
      if (!pass) {
        ++result.fm_rejected;
        continue;
      }
    }
    result.pairs.emplace_back(static_cast<int>(r), c);
  }
  return result;
}

double huberWeight(double residual, double delta_m, bool robust) {
  if (!robust) return 1.0;
  const double a = std::abs(residual);
  return a <= delta_m ? 1.0 : delta_m / a;
}

double huberWeight(double residual, const RegistrationConfig& config) {
  return huberWeight(residual, config.huber_delta_m, config.robust);
}

// The depth-noise weighting of RegistrationConfig: for a reference depth z, the pair's weight
// factor and its Huber threshold.
struct NoiseWeighting {
  bool on = false;
  DepthNoiseModel noise;
  double z_ref = 0.0, sigma_ref = 0.0, min_factor = 0.0;
  explicit NoiseWeighting(const RegistrationConfig& config)
      : noise(config.noise),
        z_ref(config.noise_ref_depth_m),
        sigma_ref(noise.sigmaAt(z_ref)),
        min_factor(config.noise_weighting_min) {
    on = config.noise_weighting && z_ref > 0.0 && sigma_ref > 0.0;
  }
  // The noise factor (sigma(z_ref) / sigma(z))^2 of a pair at reference depth z: 1 when off or
  // not deeper than z_ref (noiseWeightingFactor).
  double unfloored(double z) const {
    if (!on || !(z > z_ref)) return 1.0;
    const double ratio = noise.sigmaAt(z) / sigma_ref;  // >= 1: sigma grows with depth
    return 1.0 / (ratio * ratio);
  }
  // The same, at least min_factor. Its Huber threshold grows by factor^-1/2 (sigma(z) /
  // sigma(z_ref) above the floor).
  double factor(double z) const { return std::max(min_factor, unfloored(z)); }
  // Huber weight of residual e whose pair has noise factor f (above), times f.
  double weight(double e, double f, const RegistrationConfig& config) const {
    if (f == 1.0) return huberWeight(e, config);
    return huberWeight(e, config.huber_delta_m / std::sqrt(f), config.robust) * f;
  }
};

}  // namespace

double noiseWeightingFactor(const RegistrationConfig& config, double z) {
  return NoiseWeighting(config).unfloored(z);
}

namespace {

// One point-to-plane Gauss-Newton step: minimises sum w (n_r . (p - q_r))^2 over the increment
// [omega; v] with p' = p + omega x p + v, in the directions the pairs constrain (the analysis of
// the normal equations decides which; in the others the increment is zero, so the estimate keeps
// the initial guess there). The analysis and the constrained solve use the rotation about the
// current camera centre c and the centre's displacement u = v + omega x c: a rotation
// correction then leaves the centre where it was, so along a direction the view cannot fix the
// camera centre keeps exactly the motion the guess gave it (about the reference origin, a
// rotation correction would move it there by omega x c). H_out is in [omega; v].
// Returns false when the system is singular.
bool solvePointToPlane(const CellCloud& reference, const Moved& moved, const MatchResult& m,
                       const RegistrationConfig& config, const Eigen::Vector3d& c_ref, Vector6d* xi,
                       double* rms, Matrix6d* normal_matrix, DegeneracyAnalysis* analysis) {
  // Upper triangle of J^T W J (21 terms) and J^T W e, accumulated by hand.
  double h[21] = {0};
  Vector6d g = Vector6d::Zero();
  // sq_unit: squared residuals scaled by their noise factors, whose mean is the residual
  // variance of a pair of weight 1 (at or nearer than the weighting's reference depth). The
  // information along a direction is its weighted eigenvalue over that variance: over the plain
  // mean, which the deep, noisy pairs dominate, a view the near pairs fix well would read as
  // barely fixed and be held at the motion prior.
  double sq = 0.0, sq_unit = 0.0, range2 = 0.0, misalign = 0.0;
  LeverMoments levers;
  const NoiseWeighting noise(config);
  for (const auto& [r, c] : m.pairs) {
    const Eigen::Vector3d q = reference.cells[r].mean_C.cast<double>();
    const Eigen::Vector3d n = reference.cells[r].normal_C.cast<double>();
    const Eigen::Vector3d p = moved.p[c].cast<double>();
    const double e = n.dot(p - q);
    const double f = noise.factor(q.z());
    sq += e * e;
    sq_unit += f * e * e;
    const Eigen::Vector3d lever = p - c_ref;
    range2 += lever.squaredNorm();
    misalign += 1.0 - std::min(1.0, n.dot(moved.n[c].cast<double>()));
    const Eigen::Vector3d pxn = lever.cross(n);
    const double J[6] = {pxn.x(), pxn.y(), pxn.z(), n.x(), n.y(), n.z()};
    const double w = noise.weight(e, f, config);
    levers.add(lever, w);
    int k = 0;
    for (int i = 0; i < 6; ++i) {
      const double wJi = w * J[i];
      g(i) += wJi * e;
      for (int j = i; j < 6; ++j) h[k++] += wJi * J[j];
    }
  }
  Matrix6d H;
  {
    int k = 0;
    for (int i = 0; i < 6; ++i)
      for (int j = i; j < 6; ++j) H(i, j) = H(j, i) = h[k++];
  }
  const std::size_t n_pairs = std::max<std::size_t>(1, m.pairs.size());
  *rms = std::sqrt(sq / n_pairs);
  *analysis = analyseNormalEquations(H, levers.wsum, std::sqrt(range2 / n_pairs));
  analysis->residual_var_m2 = sq_unit / n_pairs;
  if (config.degeneracy.noise_margin > 0.0) {
    // What the normals' noise alone puts into each eigen-direction (DegeneracyConfig): 1 - cos
    // of two independently noisy normals averages twice one normal's in-plane variance.
    applyNoiseFloors(analysis, noiseFloors(*analysis, H, levers, 0.5 * misalign / n_pairs),
                     analysis->residual_var_m2, config.degeneracy);
  }
  const Vector6d y = solveConstrained(*analysis, g);  // [omega; u]
  xi->head<3>() = y.head<3>();
  xi->tail<3>() = y.tail<3>() - y.head<3>().cross(c_ref);
  // [omega; u] = A [omega; v] with u = v + omega x c = v - [c]x omega, so H_v = A^T H_u A.
  Matrix6d A = Matrix6d::Identity();
  A.block<3, 3>(3, 0) = -skew(c_ref);
  *normal_matrix = A.transpose() * H * A;
  return xi->allFinite();
}

// Point-to-point step on the current pairs through alignPointToPoint.
bool solvePointToPoint(const CellCloud& reference, const Moved& moved, const MatchResult& m,
                       const RegistrationConfig& config, Eigen::Isometry3d* delta, double* rms,
                       Matrix6d* normal_matrix) {
  std::vector<Eigen::Vector3d> p(m.pairs.size()), q(m.pairs.size());
  std::vector<double> w(m.pairs.size());
  double sq = 0.0;
  for (std::size_t i = 0; i < m.pairs.size(); ++i) {
    const auto [r, c] = m.pairs[i];
    p[i] = moved.p[c].cast<double>();
    q[i] = reference.cells[r].mean_C.cast<double>();
    const double e = (p[i] - q[i]).norm();
    sq += e * e;
    w[i] = huberWeight(e, config);
  }
  *rms = std::sqrt(sq / std::max<std::size_t>(1, m.pairs.size()));
  // J^T W J of the residual p' - q with p' = p + omega x p + v, J = [-[p]x, I]:
  // [w (|p|^2 I - p p^T), w [p]x; -w [p]x, w I] summed over the pairs.
  Eigen::Matrix3d rr = Eigen::Matrix3d::Zero(), rt = Eigen::Matrix3d::Zero();
  double wsum = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    rr += w[i] * (p[i].squaredNorm() * Eigen::Matrix3d::Identity() - p[i] * p[i].transpose());
    rt += w[i] * skew(p[i]);
    wsum += w[i];
  }
  normal_matrix->topLeftCorner<3, 3>() = rr;
  normal_matrix->topRightCorner<3, 3>() = rt;
  normal_matrix->bottomLeftCorner<3, 3>() = rt.transpose();
  normal_matrix->bottomRightCorner<3, 3>() = wsum * Eigen::Matrix3d::Identity();
  *delta = alignPointToPoint(p, q, w);
  return delta->matrix().allFinite();
}

}  // namespace

void AssociationGrid::build(const CellCloud& reference, int radius_cells) {
  reference_ = &reference;
  pad_ = radius_cells;
  stride_ = reference.grid_w + 2 * radius_cells;
  cells_ = reference.cells.size();
  const std::size_t n_slots =
      static_cast<std::size_t>(stride_) * (reference.grid_h + 2 * radius_cells);
  index_.assign(n_slots, -1);
  plane_size_ = n_slots + kLanePad;
  // 1e15 m: its squared distance to any real point (~1e30) stays finite in float and fails
  // every gate.
  planes_.assign(6 * plane_size_, 0.0f);
  std::fill(planes_.begin(), planes_.begin() + 3 * plane_size_, 1e15f);
  for (std::size_t i = 0; i < reference.cells.size(); ++i) {
    const Cell& c = reference.cells[i];
    const std::size_t s = static_cast<std::size_t>(c.gy + pad_) * stride_ + c.gx + pad_;
    index_[s] = static_cast<int>(i);
    for (int k = 0; k < 3; ++k) {
      planes_[k * plane_size_ + s] = c.mean_C(k);
      planes_[(3 + k) * plane_size_ + s] = c.normal_C(k);
    }
  }
}

MatchResult matchCells(const CellCloud& reference, const CellCloud& current,
                       const PinholeIntrinsics& intrinsics, const Eigen::Isometry3d& T_ref_cur,
                       const RegistrationConfig& config) {
  Moved moved;
  moveCells(current, T_ref_cur, &moved);
  const AssociationGrid grid(reference, config.match.search_radius_cells);
  return associate(reference, grid, current, moved, intrinsics, T_ref_cur.rotation(), config,
                   config.match.search_radius_cells);
}

RegistrationResult registerCells(const CellCloud& reference, const CellCloud& current,
                                 const PinholeIntrinsics& intrinsics,
                                 const Eigen::Isometry3d& T_ref_cur_guess,
                                 const RegistrationConfig& config) {
  const AssociationGrid grid(reference, config.match.search_radius_cells);
  return registerCells(reference, grid, current, intrinsics, T_ref_cur_guess, config);
}

RegistrationResult registerCells(const CellCloud& reference, const AssociationGrid& grid,
                                 const CellCloud& current, const PinholeIntrinsics& intrinsics,
                                 const Eigen::Isometry3d& T_ref_cur_guess,
                                 const RegistrationConfig& config) {
  RegistrationResult result;
  result.T_ref_cur = T_ref_cur_guess;
  const auto problems = config.validate();
  if (!problems.empty()) throw std::invalid_argument("registration: " + joinProblems(problems));
  if (reference.cell_size != current.cell_size || reference.grid_w != current.grid_w ||
      reference.grid_h != current.grid_h)
    throw std::invalid_argument("registration: reference and current cell grids differ");
  if (!grid.isFor(reference, config.match.search_radius_cells))
    throw std::invalid_argument(
        "registration: the association grid was built for another reference or search radius");

  Eigen::Isometry3d T = T_ref_cur_guess;
  Eigen::Isometry3d T_best = T;
  double best_rms = std::numeric_limits<double>::infinity();
  bool error_rose = false;
  int since_best = 0;
  Moved moved;
  Matrix6d H = Matrix6d::Zero(), H_best = Matrix6d::Zero();
  DegeneracyAnalysis analysis, analysis_best;
  FmCache fm_cache{std::vector<int>(current.cells.size(), -1),
                   std::vector<char>(current.cells.size(), 0)};
  for (int it = 0; it < config.max_iterations; ++it) {
    moveCells(current, T, &moved);
    // The first pass covers the prediction's error; later passes follow a re-projected estimate.
    const int radius =
        it == 0 ? config.match.search_radius_cells : std::min(1, config.match.search_radius_cells);
    RegistrationConfig gated = config;
    gated.match.dist_min_m =
        std::max(config.match.dist_min_m,
                 config.match.initial_dist_m / static_cast<double>(1 << std::min(it, 20)));
    const MatchResult m = associate(reference, grid, current, moved, intrinsics, T.rotation(),
                                    gated, radius, &fm_cache);
    result.iterations = it + 1;
    result.candidates = m.candidates;
    result.duplicates_broken = m.duplicates_broken;
    result.matches = static_cast<int>(m.pairs.size()) + m.fm_rejected;
    result.fm_matches = static_cast<int>(m.pairs.size());
    if (static_cast<int>(m.pairs.size()) < config.min_matches) {
      std::ostringstream s;
      s << "too few matches: " << m.pairs.size() << " < " << config.min_matches;
      result.failure = s.str();
      result.T_ref_cur = std::isfinite(best_rms) ? T_best : T_ref_cur_guess;
      return result;
    }
    double rms = 0.0;
    Eigen::Isometry3d delta = Eigen::Isometry3d::Identity();
    bool ok;
    if (config.method == RegistrationMethod::kPointToPoint) {
      ok = solvePointToPoint(reference, moved, m, config, &delta, &rms, &H);
    } else {
      Vector6d xi;
      ok =
          solvePointToPlane(reference, moved, m, config, T.translation(), &xi, &rms, &H, &analysis);
      if (ok) delta = expIncrement(xi);
    }
    result.normal_matrix = H;
    result.degeneracy = analysis;
    if (!ok) {
      result.failure = "singular registration system";
      result.T_ref_cur = std::isfinite(best_rms) ? T_best : T_ref_cur_guess;
      return result;
    }
    // rms is the error at T, before this update: stop once it has stopped decreasing for
    // `patience` iterations (pair sets change between iterations, so one rise is no verdict),
    // and return the best pose seen.
    if (rms < best_rms) {
      best_rms = rms;
      T_best = T;
      H_best = H;
      analysis_best = analysis;
      since_best = 0;
    } else if (++since_best >= config.patience) {
      error_rose = true;
      break;
    }
    result.error_rms_m = rms;
    T = orthonormalized(delta * T);
    if (rotationAngle(delta) < config.tolerance_rad &&
        delta.translation().norm() < config.tolerance_m) {
      result.converged = true;
      break;
    }
  }
  if (error_rose) {
    result.converged = true;
    result.T_ref_cur = T_best;
    result.error_rms_m = best_rms;
    result.normal_matrix = H_best;
    result.degeneracy = analysis_best;
  } else {
    result.T_ref_cur = T;
  }
  return result;
}

}  // namespace depth_track
