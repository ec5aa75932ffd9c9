#include "depth_track/core/tracker.hpp"

#include <chrono>
#include <cstdio>
#include <stdexcept>

namespace depth_track {

std::vector<std::string> TrackerConfig::validate(const PinholeIntrinsics& intrinsics) const {
  std::vector<std::string> p = intrinsics.validate();
  for (const auto& s : prefilter.validate(intrinsics.width, intrinsics.height)) p.push_back(s);
  for (const auto& s : pca.validate(intrinsics.width, intrinsics.height)) p.push_back(s);
  for (const auto& s : CellOdometryConfig::validate()) p.push_back(s);
  if (threads < 1) p.push_back("threads must be >= 1");
  return p;
}

PcaConfig TrackerConfig::reducerConfig() const {
  PcaConfig p = pca;
  p.compute_inv_sqrt = registration.method == RegistrationMethod::kCellSearch;
  return p;
}

CellOdometryConfig TrackerConfig::odometryConfig() const {
  CellOdometryConfig c = *this;
  c.registration.fm_eps_m2 = pca.min_eigenvalue_m2;
  return c;
}

namespace {
TrackerConfig checked(const PinholeIntrinsics& intrinsics, const TrackerConfig& config) {
  const auto problems = config.validate(intrinsics);
  if (!problems.empty()) throw std::invalid_argument("tracker config: " + joinProblems(problems));
  TrackerConfig c = config;
  c.pca = config.reducerConfig();
  static_cast<CellOdometryConfig&>(c) = config.odometryConfig();
  return c;
}
}  // namespace

Tracker::Tracker(const PinholeIntrinsics& intrinsics, const TrackerConfig& config,
                 const Eigen::Isometry3d& T_W_C0)
    : intrinsics_(intrinsics),
      config_(checked(intrinsics, config)),
      pool_(std::make_shared<const WorkerPool>(config_.threads)),
      prefilter_(intrinsics, config_.prefilter, pool_),
      reducer_(intrinsics, config_.pca, pool_),
      odometry_(intrinsics, config_, T_W_C0),
      T_W_C0_(T_W_C0) {}

bool Tracker::adaptToFrame(const DepthImage& depth) {
  NoiseEstimator estimator;
  estimator.addFrame(depth, intrinsics_);
  const DepthNoiseModel noise = estimator.model();
  if (!noise.known()) return false;
  const double z_ref = estimator.depthQuantile(0.75);
  const NoiseAdaptation a =
      adaptToNoise(noise, intrinsics_.fx, config_.pca.cell_size, z_ref, estimator.holeShare());
  TrackerConfig c = config_;
  c.pca.noise_sigma_const_m = noise.const_m;
  c.pca.noise_sigma_quad_per_m = noise.quad_per_m;
  c.pca.normal_radius_cells = a.normal_radius_cells;
  c.pca.normal_merge_dist_m = a.normal_merge_dist_m;
  c.pca.min_valid_fraction = a.min_valid_fraction;
  c.registration.match.cos_min = a.cos_min;
  c.registration.huber_delta_m = a.huber_delta_m;
  c.max_error_rms_m = a.max_error_rms_m;
  config_ = checked(intrinsics_, c);
  reducer_ = CellReducer(intrinsics_, config_.pca, pool_);
  odometry_ = CellOdometry(intrinsics_, config_, T_W_C0_);
  char z[48];
  std::snprintf(z, sizeof(z), " at z75=%.2f m: ", z_ref);
  noise_summary_ = estimator.summary() + z + a.summary();
  return true;
}

const CellCloud& Tracker::lastCells() const {
  static const CellCloud kEmpty;
  return odometry_.lastCells() ? *odometry_.lastCells() : kEmpty;
}

FrameStatus Tracker::track(const DepthImage& depth, double stamp_s,
                           const std::optional<Eigen::Isometry3d>& prior_T_Cprev_Ccur) {
  const auto t0 = std::chrono::steady_clock::now();
  checkFrameSize(depth, intrinsics_);
  // Before the first reference only: the grids of all later frames must match it.
  if (config_.auto_noise && !adapted_ && !odometry_.reference()) adapted_ = adaptToFrame(depth);
  double ms_prefilter = 0.0;
  std::shared_ptr<const CellCloud> cells;
  if (prefilter_.passthrough()) {
    cells = reducer_.reduce(depth, stamp_s);
  } else {
    const DepthImage filtered = prefilter_.apply(depth);
    ms_prefilter = prefilter_.timing().last();
    cells = reducer_.reduce(filtered, stamp_s);
  }
  const double ms_front = msSince(t0);
  FrameStatus st = odometry_.track(std::move(cells), prior_T_Cprev_Ccur);
  st.ms_prefilter = ms_prefilter;
  st.ms_reduce = ms_front - ms_prefilter;
  st.ms_total = msSince(t0);
  timing_.add(st.ms_total);
  return st;
}

}  // namespace depth_track
