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
  p.cell_spectra = false;  // registration reads no cell's eigenvalues
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

void Tracker::applyCalibration(const NoiseCalibration& calibration) {
  calibration_ = calibration;
  if (!calibration.measured) return;
  TrackerConfig c = config_;
  calibration.applyTo(&c.pca);
  calibration.applyTo(static_cast<CellOdometryConfig*>(&c));
  config_ = checked(intrinsics_, c);
  reducer_ = CellReducer(intrinsics_, config_.pca, pool_);
  odometry_ = CellOdometry(intrinsics_, config_, T_W_C0_);
}

const CellCloud& Tracker::lastCells() const {
  static const CellCloud kEmpty;
  return odometry_.lastCells() ? *odometry_.lastCells() : kEmpty;
}

FrameStatus Tracker::track(const DepthImage& depth, double stamp_s,
                           const std::optional<Eigen::Isometry3d>& prior_T_Cprev_Ccur,
                           const std::optional<InertialHold>& hold) {
  const auto t0 = std::chrono::steady_clock::now();
  checkFrameSize(depth, intrinsics_);
  double ms_prefilter = 0.0;
  DepthImage filtered;
  if (!prefilter_.passthrough()) {
    filtered = prefilter_.apply(depth);
    ms_prefilter = prefilter_.timing().last();
  }
  const DepthImage& input = prefilter_.passthrough() ? depth : filtered;
  // Once, on the first frame with any depth (no earlier frame can have set a reference, so
  // every registration runs the calibrated settings), on the depth the reducer sees: the graph's
  // pca_reduce measures the same image (after ingest's prefilter) by the same rule and call.
  if (config_.auto_noise && !calibration_ && input.countValid() > 0)
    applyCalibration(calibrateNoise(input, intrinsics_, config_.pca.cell_size, stamp_s));
  std::shared_ptr<const CellCloud> cells = reducer_.reduce(input, stamp_s);
  const double ms_front = msSince(t0);
  FrameStatus st = odometry_.track(std::move(cells), prior_T_Cprev_Ccur, hold);
  st.ms_prefilter = ms_prefilter;
  st.ms_reduce = ms_front - ms_prefilter;
  st.ms_total = msSince(t0);
  timing_.add(st.ms_total);
  return st;
}

}  // namespace depth_track
