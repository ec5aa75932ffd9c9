#include "depth_track/core/tracker.hpp"

#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "depth_track/core/se3.hpp"

namespace depth_track {

namespace {
double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}
constexpr double kRadToDeg = 180.0 / M_PI;
}  // namespace

std::vector<std::string> TrackerConfig::validate(const PinholeIntrinsics& intrinsics) const {
  std::vector<std::string> p = intrinsics.validate();
  for (const auto& s : prefilter.validate(intrinsics.width, intrinsics.height)) p.push_back(s);
  for (const auto& s : pca.validate(intrinsics.width, intrinsics.height)) p.push_back(s);
  for (const auto& s : registration.validate()) p.push_back(s);
  if (icp_frames < 0) p.push_back("icp_frames must be >= 0 (0 = adaptive keyframes)");
  if (!(keyframe_dist_m > 0.0)) p.push_back("keyframe_dist_m must be > 0 m");
  if (!(keyframe_angle_deg > 0.0)) p.push_back("keyframe_angle_deg must be > 0 deg");
  if (!(keyframe_min_overlap >= 0.0 && keyframe_min_overlap <= 1.0))
    p.push_back("keyframe_min_overlap must lie in [0, 1]");
  if (!(max_error_rms_m > 0.0)) p.push_back("max_error_rms_m must be > 0 m");
  if (!(max_jump_m > 0.0)) p.push_back("max_jump_m must be > 0 m");
  if (!(max_jump_deg > 0.0)) p.push_back("max_jump_deg must be > 0 deg");
  if (threads < 1) p.push_back("threads must be >= 1");
  return p;
}

Tracker::Tracker(const PinholeIntrinsics& intrinsics, const TrackerConfig& config,
                 const Eigen::Isometry3d& T_W_C0)
    : intrinsics_(intrinsics),
      config_(config),
      T_W_C_(T_W_C0),
      T_W_Cref_(T_W_C0),
      velocity_T_Cprev_Ccur_(Eigen::Isometry3d::Identity()) {
  const auto problems = config.validate(intrinsics);
  if (!problems.empty()) throw std::invalid_argument("tracker config: " + joinProblems(problems));
  if (!T_W_C0.matrix().allFinite())
    throw std::invalid_argument("tracker: initial pose is not finite");
  config_.registration.fm_eps_m2 = config_.pca.min_eigenvalue_m2;
  // Only Cell Search's Förstner–Moonen gate reads the inverse square roots.
  config_.pca.compute_inv_sqrt = config_.registration.method == RegistrationMethod::kCellSearch;
}

void Tracker::correctPose(const Eigen::Isometry3d& T_W_C) {
  if (!T_W_C.matrix().allFinite()) throw std::invalid_argument("correctPose: pose is not finite");
  // Move the reference with the camera so the next registration stays consistent.
  const Eigen::Isometry3d T_C_Cref = T_W_C_.inverse() * T_W_Cref_;
  T_W_C_ = orthonormalized(T_W_C);
  T_W_Cref_ = orthonormalized(T_W_C_ * T_C_Cref);
}

FrameStatus Tracker::track(const DepthImage& depth, double stamp_s,
                           const std::optional<Eigen::Isometry3d>& prior_T_Cprev_Ccur) {
  const auto t0 = std::chrono::steady_clock::now();
  FrameStatus st;
  st.stamp_s = stamp_s;
  checkFrameSize(depth, intrinsics_);

  CellCloud cells;
  if (config_.prefilter.type == PrefilterType::kNone) {
    cells = reduceToCells(depth, intrinsics_, config_.pca, config_.threads);
  } else {
    const DepthImage filtered = applyPrefilter(depth, config_.prefilter, config_.threads);
    st.ms_prefilter = msSince(t0);
    cells = reduceToCells(filtered, intrinsics_, config_.pca, config_.threads);
  }
  st.ms_reduce = msSince(t0) - st.ms_prefilter;
  st.cells = static_cast<int>(cells.cells.size());

  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  if (prior_T_Cprev_Ccur) {
    if (!prior_T_Cprev_Ccur->matrix().allFinite())
      throw std::invalid_argument("track: motion prior is not finite");
    motion = *prior_T_Cprev_Ccur;
  } else if (config_.constant_velocity) {
    motion = velocity_T_Cprev_Ccur_;
  }
  const Eigen::Isometry3d T_W_pred = T_W_C_ * motion;

  if (!have_reference_) {
    if (st.cells < config_.registration.min_matches) {
      std::ostringstream s;
      s << "frame has " << st.cells << " usable cells, fewer than min_matches "
        << config_.registration.min_matches << "; waiting for a usable first frame";
      st.failure = s.str();
      st.T_W_C = T_W_C_;
      st.ms_total = msSince(t0);
      return st;
    }
    reference_ = cells;
    T_W_Cref_ = T_W_C_;
    have_reference_ = true;
    frames_since_refresh_ = 0;
    last_cells_ = std::move(cells);
    st.tracked = true;
    st.T_W_C = T_W_C_;
    st.ms_total = msSince(t0);
    return st;
  }

  const auto t1 = std::chrono::steady_clock::now();
  const Eigen::Isometry3d guess = T_W_Cref_.inverse() * T_W_pred;
  RegistrationResult reg;
  if (st.cells < config_.registration.min_matches) {
    std::ostringstream s;
    s << "frame has only " << st.cells << " usable cells (min_matches "
      << config_.registration.min_matches << ")";
    reg.failure = s.str();
  } else {
    reg = registerCells(reference_, cells, intrinsics_, guess, config_.registration);
  }
  st.ms_register = msSince(t1);
  st.candidates = reg.candidates;
  st.matches = reg.matches;
  st.fm_matches = reg.fm_matches;
  st.duplicates_broken = reg.duplicates_broken;
  st.iterations = reg.iterations;
  st.error_rms_m = reg.error_rms_m;

  std::string failure = reg.failure;
  if (failure.empty() && !reg.T_ref_cur.matrix().allFinite())
    failure = "registration diverged (non-finite)";
  if (failure.empty() && reg.error_rms_m > config_.max_error_rms_m) {
    std::ostringstream s;
    s << "residual " << reg.error_rms_m * 1000.0 << " mm exceeds max_error_rms_m "
      << config_.max_error_rms_m * 1000.0 << " mm";
    failure = s.str();
  }
  if (failure.empty()) {
    const Eigen::Isometry3d jump = guess.inverse() * reg.T_ref_cur;
    const double jump_m = jump.translation().norm();
    const double jump_deg = rotationAngle(jump) * kRadToDeg;
    if (jump_m > config_.max_jump_m || jump_deg > config_.max_jump_deg) {
      std::ostringstream s;
      s << "implausible jump from the prediction: " << jump_m * 1000.0 << " mm, " << jump_deg
        << " deg";
      failure = s.str();
    }
  }

  const Eigen::Isometry3d T_W_prev = T_W_C_;
  if (failure.empty()) {
    T_W_C_ = orthonormalized(T_W_Cref_ * reg.T_ref_cur);
    st.tracked = true;
    velocity_T_Cprev_Ccur_ = T_W_prev.inverse() * T_W_C_;
  } else {
    // Keep the predicted pose and flag the frame; the reference stays as it was.
    T_W_C_ = orthonormalized(T_W_pred);
    st.failure = failure;
  }
  ++frames_since_refresh_;
  bool refresh = false;
  if (config_.icp_frames >= 1) {
    refresh = frames_since_refresh_ >= config_.icp_frames;
  } else if (st.tracked) {
    const Eigen::Isometry3d from_key = T_W_Cref_.inverse() * T_W_C_;
    const double overlap =
        reference_.cells.empty() ? 0.0 : static_cast<double>(st.matches) / reference_.cells.size();
    refresh = from_key.translation().norm() > config_.keyframe_dist_m ||
              rotationAngle(from_key) * kRadToDeg > config_.keyframe_angle_deg ||
              overlap < config_.keyframe_min_overlap;
  }
  if (st.tracked && refresh) {
    reference_ = cells;
    T_W_Cref_ = T_W_C_;
    frames_since_refresh_ = 0;
  }
  last_cells_ = std::move(cells);
  st.T_W_C = T_W_C_;
  st.ms_total = msSince(t0);
  return st;
}

}  // namespace depth_track
