#include "depth_track/core/noise_model.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

namespace depth_track {

namespace {
// Angular noise of a pooled plane fit the settings aim for, radians (see adaptToNoise).
constexpr double kTargetNormalNoiseRad = 0.013;
// Above this share of holed cells, cells may miss a quarter of their pixels.
constexpr double kSpeckleHoleShare = 0.2;

double quantileOf(std::vector<float> v, double q) {
  if (v.empty()) return 0.0;
  const std::size_t k = std::min(v.size() - 1, static_cast<std::size_t>(q * (v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}
}  // namespace

std::vector<std::string> NoiseEstimatorConfig::validate() const {
  std::vector<std::string> p;
  if (probe_cell_size < 4 || probe_cell_size > 32) p.push_back("probe_cell_size must lie in 4..32");
  if (!(min_incidence_cos > 0.0 && min_incidence_cos < 1.0))
    p.push_back("min_incidence_cos must lie in (0, 1)");
  if (!(bin_m > 0.0)) p.push_back("bin_m must be > 0 m");
  if (min_cells_per_bin < 3) p.push_back("min_cells_per_bin must be >= 3");
  if (!(quantile > 0.0 && quantile < 1.0)) p.push_back("quantile must lie in (0, 1)");
  if (!(planar_tolerance >= 0.0)) p.push_back("planar_tolerance must be >= 0 (0 = off)");
  return p;
}

NoiseEstimator::NoiseEstimator(const NoiseEstimatorConfig& config) : config_(config) {
  const auto problems = config.validate();
  if (!problems.empty())
    throw std::invalid_argument("noise estimator config: " + joinProblems(problems));
}

bool NoiseEstimator::inPlanarNeighbourhood(const CellCloud& cloud, const Cell& c,
                                           float rms_m) const {
  // A cell across a crease or a step has a residual of geometry, not of noise, and on some
  // views (a corridor's far corners) such cells outnumber the plain ones at their depth. Its
  // neighbours' means (each averaging a cell of pixels, so far less noisy than one pixel) then
  // lie off its plane by centimetres; on a plane they lie within a fraction of the pixel RMS.
  const float tol = static_cast<float>(config_.planar_tolerance) * rms_m;
  int present = 0;
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      if (dx == 0 && dy == 0) continue;
      const int k = cloud.cellAt(c.gx + dx, c.gy + dy);  // -1 beyond the border too
      if (k < 0) continue;
      ++present;
      if (std::abs(c.normal_C.dot(cloud.cells[k].mean_C - c.mean_C)) > tol) return false;
    }
  }
  return present >= 6;  // a border cell has at most 5
}

void NoiseEstimator::addFrame(const DepthImage& depth, const PinholeIntrinsics& intrinsics) {
  PcaConfig probe;
  probe.cell_size = config_.probe_cell_size;
  // The cell's pixels are measured about the plane pooled over its 7x7 neighbours, not about
  // their own best plane: with stereo noise at a few metres a small patch's own "plane" is
  // noise (its smallest spread can even lie in the image plane).
  probe.normal_radius_cells = 3;
  probe.normal_merge_dist_m = 0.3;
  probe.compute_inv_sqrt = false;
  probe.min_valid_fraction = 0.75;
  probe.edge_jump_rel = 0.0;  // cells across edges have large residuals: the quantile drops them
  const CellCloud cloud = reduceToCells(depth, intrinsics, probe);
  const int per_cell = probe.cell_size * probe.cell_size;
  for (const Cell& c : cloud.cells) {
    ++probed_;
    holed_ += c.n_valid < per_cell;
    const float r = c.mean_C.norm();
    const float cos_inc = r > 0.0f ? std::abs(c.normal_C.dot(c.mean_C)) / r : 0.0f;
    if (cos_inc < config_.min_incidence_cos || c.n_valid < 4) continue;
    const float var = std::max(0.0f, c.normal_C.dot(c.cov * c.normal_C));
    const float rms = std::sqrt(var);
    if (config_.planar_tolerance > 0.0 && !inPlanarNeighbourhood(cloud, c, rms)) continue;
    samples_.push_back({c.mean_C.z(), rms / cos_inc});
  }
}

DepthNoiseModel NoiseEstimator::model() const {
  std::map<int, std::vector<float>> bins;
  for (const Sample& s : samples_)
    bins[static_cast<int>(s.z_m / config_.bin_m)].push_back(s.sigma_m);
  // Weighted least squares of q_i = a + c z_i^2 with weights 1 / q_i^2 (relative errors).
  double s11 = 0, s12 = 0, s22 = 0, b1 = 0, b2 = 0;
  int used = 0;
  for (const auto& [bin, v] : bins) {
    if (static_cast<int>(v.size()) < config_.min_cells_per_bin) continue;
    const double q = quantileOf(v, config_.quantile);
    if (!(q > 0.0)) continue;
    const double z = (bin + 0.5) * config_.bin_m, z2 = z * z, w = 1.0 / (q * q);
    s11 += w;
    s12 += w * z2;
    s22 += w * z2 * z2;
    b1 += w * q;
    b2 += w * z2 * q;
    ++used;
  }
  DepthNoiseModel m;
  if (used < 2) return m;
  const double det = s11 * s22 - s12 * s12;
  double a = det > 0.0 ? (b1 * s22 - b2 * s12) / det : -1.0;
  double c = det > 0.0 ? (s11 * b2 - s12 * b1) / det : -1.0;
  if (a < 0.0 || c < 0.0) {  // one coefficient at its bound: the best of the two one-term fits
    const double c_only = b2 / s22, a_only = b1 / s11;
    auto cost = [&](double aa, double cc) {
      return aa * aa * s11 + 2 * aa * cc * s12 + cc * cc * s22 - 2 * (aa * b1 + cc * b2);
    };
    if (cost(0.0, c_only) < cost(a_only, 0.0)) {
      a = 0.0;
      c = c_only;
    } else {
      a = a_only;
      c = 0.0;
    }
  }
  m.const_m = a;
  m.quad_per_m = c;
  return m;
}

double NoiseEstimator::depthQuantile(double share) const {
  std::vector<float> z;
  z.reserve(samples_.size());
  for (const Sample& s : samples_) z.push_back(s.z_m);
  return quantileOf(std::move(z), share);
}

std::string NoiseEstimator::summary() const {
  const DepthNoiseModel m = model();
  char buf[256];
  std::snprintf(buf, sizeof(buf),
                "sigma(z) = %.2f mm + %.2f mm/m^2 z^2 from %d cells: %.1f mm at 1 m, %.1f mm at "
                "2 m, %.1f mm at 3 m; %.0f %% of cells with holes",
                1e3 * m.const_m, 1e3 * m.quad_per_m, cells(), 1e3 * m.sigmaAt(1.0),
                1e3 * m.sigmaAt(2.0), 1e3 * m.sigmaAt(3.0), 100.0 * holeShare());
  return buf;
}

std::string NoiseAdaptation::summary() const {
  char buf[200];
  std::snprintf(buf, sizeof(buf),
                "kappa=%.2f normal_radius=%d normal_merge_dist=%.3f cos_min=%.3f huber_delta=%.3f "
                "max_error=%.3f "
                "min_valid_fraction=%.2f",
                footprint_noise, normal_radius_cells, normal_merge_dist_m, cos_min, huber_delta_m,
                max_error_rms_m, min_valid_fraction);
  return buf;
}

NoiseAdaptation adaptToNoise(const DepthNoiseModel& noise, double fx_px, int cell_size,
                             double z_ref_m, double hole_share) {
  NoiseAdaptation a;
  if (!noise.known() || !(z_ref_m > 0.0) || !(fx_px > 0.0) || cell_size < 1) return a;
  const double sigma = noise.sigmaAt(z_ref_m);
  a.footprint_noise = sigma * fx_px / z_ref_m;
  // sqrt(12) kappa / m^2 <= target  ->  m >= sqrt(sqrt(12) kappa / target).
  const double m_req = std::sqrt(std::sqrt(12.0) * a.footprint_noise / kTargetNormalNoiseRad);
  const int r = static_cast<int>(std::ceil((m_req / cell_size - 1.0) / 2.0 - 1e-9));
  a.normal_radius_cells = std::clamp(r, 1, 4);
  a.normal_merge_dist_m =
      std::max(0.1, 1.5 * std::sqrt(2.0) * a.normal_radius_cells * cell_size * z_ref_m / fx_px);
  // Pair gate on normals: 8 deg for low-noise sensors, widened to 26 deg as kappa reaches 3
  // (stereo noise is correlated over several pixels, so its normals are worse than the i.i.d.
  // model says).
  const double t = std::clamp((a.footprint_noise - 1.0) / 2.0, 0.0, 1.0);
  a.cos_min = 0.99 + t * (0.9 - 0.99);
  a.huber_delta_m = std::max(0.01, sigma);
  a.max_error_rms_m = std::max(0.02, 1.5 * sigma);
  a.min_valid_fraction = hole_share > kSpeckleHoleShare ? 0.75 : 1.0;
  return a;
}

void NoiseCalibration::applyTo(PcaConfig* pca) const {
  if (!measured) return;
  pca->noise_sigma_const_m = noise.const_m;
  pca->noise_sigma_quad_per_m = noise.quad_per_m;
  pca->normal_radius_cells = adaptation.normal_radius_cells;
  pca->normal_merge_dist_m = adaptation.normal_merge_dist_m;
  pca->min_valid_fraction = adaptation.min_valid_fraction;
}

void NoiseCalibration::applyTo(CellOdometryConfig* odometry) const {
  if (!measured) return;
  odometry->registration.match.cos_min = adaptation.cos_min;
  odometry->registration.huber_delta_m = adaptation.huber_delta_m;
  odometry->max_error_rms_m = adaptation.max_error_rms_m;
  applyNoiseModelTo(odometry);
}

void NoiseCalibration::applyNoiseModelTo(CellOdometryConfig* odometry) const {
  if (!measured) return;
  odometry->registration.noise = noise;
  odometry->model.noise = noise;
}

void NoiseCalibration::applyToUnchanged(const CellOdometryConfig& before,
                                        CellOdometryConfig* after) const {
  if (!measured) return;
  CellOdometryConfig calibrated = *after;
  applyTo(&calibrated);
  if (after->registration.match.cos_min == before.registration.match.cos_min)
    after->registration.match.cos_min = calibrated.registration.match.cos_min;
  if (after->registration.huber_delta_m == before.registration.huber_delta_m)
    after->registration.huber_delta_m = calibrated.registration.huber_delta_m;
  if (after->max_error_rms_m == before.max_error_rms_m)
    after->max_error_rms_m = calibrated.max_error_rms_m;
  // The noise model itself is a measurement, not a parameter: it stays through any request.
  applyNoiseModelTo(after);
}

NoiseCalibration calibrateNoise(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                                int cell_size, double stamp_s) {
  NoiseEstimator estimator;
  estimator.addFrame(depth, intrinsics);
  NoiseCalibration c;
  c.stamp_s = stamp_s;
  c.noise = estimator.model();
  c.measured = c.noise.known();
  if (!c.measured) {
    c.noise = DepthNoiseModel{};
    c.summary = "noise not measured (" + std::to_string(estimator.cells()) +
                " probe cells, too few planar depth bins): parameters as given";
    return c;
  }
  c.z_ref_m = estimator.depthQuantile(0.75);
  c.adaptation = adaptToNoise(c.noise, intrinsics.fx, cell_size, c.z_ref_m, estimator.holeShare());
  char z[48];
  std::snprintf(z, sizeof(z), " at z75=%.2f m: ", c.z_ref_m);
  c.summary = estimator.summary() + z + c.adaptation.summary();
  return c;
}

}  // namespace depth_track
