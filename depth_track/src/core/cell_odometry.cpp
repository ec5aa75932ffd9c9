#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/angles.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <sstream>
#include <stdexcept>

namespace depth_track {

namespace {
// The smallest ratio of a direction's information to its noise floor (0 without floors).
double weakestInformation(const DegeneracyAnalysis& a) {
  double weakest = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 6; ++i) {
    const double f = a.noise_floor(i);
    if (f > 0.0) weakest = std::min(weakest, a.eigenvalues(i) / f);
  }
  return std::isfinite(weakest) ? weakest : 0.0;
}
// The prior is never trusted beyond this per frame (metres): 2 mm in one frame at 30 Hz is an
// acceleration of ~2 m/s^2, which a hand or a rig starting to move can reach unannounced; a
// camera at rest must not earn a prior that its first move then breaks.
constexpr double kMinPriorSigmaM = 0.002;
// ... and a prior that has not yet predicted any frame is worth little (1 cm per frame).
constexpr double kUntestedPriorSigmaM = 0.01;
// A retry from the previous pose replaces the first registration only with this many times its
// pairs (CellOdometryConfig::retry_pairs_below).
constexpr double kRetryPairsGain = 1.5;
}  // namespace

std::vector<std::string> RelocaliseConfig::validate() const {
  std::vector<std::string> p;
  if (search_radius_cells < 0 || search_radius_cells > 16)
    p.push_back("relocalise.search_radius_cells must lie in [0, 16]");
  if (!(initial_dist_m >= 0.0)) p.push_back("relocalise.initial_dist_m must be >= 0 m");
  if (max_iterations < 1 || max_iterations > 1000)
    p.push_back("relocalise.max_iterations must lie in [1, 1000]");
  if (!(search_angle_deg >= 0.0 && search_angle_deg <= 45.0))
    p.push_back("relocalise.search_angle_deg must lie in [0, 45] deg");
  if (!(search_step_deg > 0.0)) p.push_back("relocalise.search_step_deg must be > 0 deg");
  if (screen_iterations < 1 || screen_iterations > 1000)
    p.push_back("relocalise.screen_iterations must lie in [1, 1000]");
  if (screened_kept < 1 || screened_kept > 100)
    p.push_back("relocalise.screened_kept must lie in [1, 100]");
  if (!(min_overlap >= 0.0 && min_overlap <= 1.0))
    p.push_back("relocalise.min_overlap must lie in [0, 1]");
  return p;
}

std::vector<std::string> CellOdometryConfig::validate() const {
  std::vector<std::string> p = registration.validate();
  if (icp_frames < 0) p.push_back("icp_frames must be >= 0 (0 = adaptive keyframes)");
  if (!(keyframe_dist_m > 0.0)) p.push_back("keyframe_dist_m must be > 0 m");
  if (!(keyframe_angle_deg > 0.0)) p.push_back("keyframe_angle_deg must be > 0 deg");
  if (!(keyframe_min_overlap >= 0.0 && keyframe_min_overlap <= 1.0))
    p.push_back("keyframe_min_overlap must lie in [0, 1]");
  if (!(max_error_rms_m > 0.0)) p.push_back("max_error_rms_m must be > 0 m");
  if (!(max_jump_m > 0.0)) p.push_back("max_jump_m must be > 0 m");
  if (!(max_jump_deg > 0.0)) p.push_back("max_jump_deg must be > 0 deg");
  if (!(velocity_span_s >= 0.0 && velocity_span_s <= 10.0))
    p.push_back("velocity_span must lie in [0, 10] s");
  if (!(velocity_firm_information >= 0.0))
    p.push_back("velocity_firm_information must be >= 0 (0 = every frame counts)");
  if (!(retry_pairs_below >= 0.0 && retry_pairs_below <= 1.0))
    p.push_back("retry_pairs_below must lie in [0, 1] (0 = off)");
  if (!(basin_probe_below >= 0.0 && basin_probe_below <= 1000.0))
    p.push_back("basin_probe_below must lie in [0, 1000] (0 = off)");
  if (!(basin_probe_step_m > 0.0 && basin_probe_step_m <= 0.1))
    p.push_back("basin_probe_step must lie in (0, 0.1] m");
  if (!(basin_probe_tolerance_m > 0.0 && basin_probe_tolerance_m < basin_probe_step_m))
    p.push_back("basin_probe_tolerance must lie in (0, basin_probe_step) m");
  if (!(basin_deep_floor >= 0.0 && basin_deep_floor <= 1.0))
    p.push_back("basin_deep_floor must lie in [0, 1] (0 = off)");
  for (const auto& s : relocalise.validate()) p.push_back(s);
  for (const auto& s : model.validate()) p.push_back(s);
  return p;
}

std::string toString(TrackingState state) {
  switch (state) {
    case TrackingState::kTracking:
      return "TRACKING";
    case TrackingState::kLost:
      return "LOST";
    case TrackingState::kRelocalising:
      return "RELOCALISING";
  }
  return "?";
}

CellOdometry::CellOdometry(const PinholeIntrinsics& intrinsics, const CellOdometryConfig& config,
                           const Eigen::Isometry3d& T_W_C0)
    : intrinsics_(intrinsics),
      config_(config),
      T_W_C0_(T_W_C0),
      T_W_C_(T_W_C0),
      T_W_Cref_(T_W_C0),
      velocity_T_Cprev_Ccur_(Eigen::Isometry3d::Identity()) {
  std::vector<std::string> problems = intrinsics.validate();
  for (const auto& s : config.validate()) problems.push_back(s);
  if (!problems.empty())
    throw std::invalid_argument("cell odometry config: " + joinProblems(problems));
  model_ = SurfaceModel(config.model);
  if (!T_W_C0.matrix().allFinite())
    throw std::invalid_argument("cell odometry: initial pose is not finite");
}

void CellOdometry::setConfig(const CellOdometryConfig& config) {
  const auto problems = config.validate();
  if (!problems.empty())
    throw std::invalid_argument("cell odometry config: " + joinProblems(problems));
  const bool regrid = config.registration.match.search_radius_cells !=
                      config_.registration.match.search_radius_cells;
  if (config.model.voxel_m != config_.model.voxel_m) model_ = SurfaceModel(config.model);
  else model_.setConfig(config.model);
  config_ = config;
  if (regrid && reference_)
    grid_.build(*reference_, config_.registration.match.search_radius_cells);
  if (regrid && raw_reference_)
    raw_grid_.build(*raw_reference_, config_.registration.match.search_radius_cells);
}

void CellOdometry::setModelReference(const std::shared_ptr<const CellCloud>& cells,
                                     ModelRefineStats* stats) {
  if (!config_.model.enabled || model_.voxelCount() == 0) {
    setReference(cells);
    return;
  }
  setReference(std::make_shared<const CellCloud>(model_.refine(*cells, modelPose(), stats)));
  raw_reference_ = cells;
  raw_grid_.build(*raw_reference_, config_.registration.match.search_radius_cells);
}

void CellOdometry::setReference(std::shared_ptr<const CellCloud> cells) {
  raw_reference_.reset();
  reference_ = std::move(cells);
  T_W_Cref_ = T_W_C_;
  frames_since_refresh_ = 0;
  // Rebuilt on every change, never looked up by address: a later cloud can reuse a freed one's.
  grid_.build(*reference_, config_.registration.match.search_radius_cells);
}

void CellOdometry::reset(const Eigen::Isometry3d& T_W_C) {
  if (!T_W_C.matrix().allFinite()) throw std::invalid_argument("reset: pose is not finite");
  T_W_C_ = orthonormalized(T_W_C);
  T_W_Cref_ = T_W_C_;
  velocity_T_Cprev_Ccur_ = Eigen::Isometry3d::Identity();
  reference_.reset();
  raw_reference_.reset();
  last_cells_.reset();
  grid_ = AssociationGrid();
  state_ = TrackingState::kLost;
  frames_since_refresh_ = 0;
  history_.clear();
  last_inertial_W_.setZero();
  last_held_ = false;
  prior_var_m2_ = kUntestedPriorSigmaM * kUntestedPriorSigmaM;
  clearModel();
}

void CellOdometry::clearModel() {
  model_.clear();
  model_frames_ = 0;
  T_M_W_.setIdentity();
}

void CellOdometry::correctPose(const Eigen::Isometry3d& T_W_C) {
  if (!T_W_C.matrix().allFinite()) throw std::invalid_argument("correctPose: pose is not finite");
  // Move the reference with the camera so the next registration stays consistent.
  const Eigen::Isometry3d T_C_Cref = T_W_C_.inverse() * T_W_Cref_;
  const Eigen::Isometry3d correction = orthonormalized(T_W_C) * T_W_C_.inverse();
  T_W_C_ = orthonormalized(T_W_C);
  T_W_Cref_ = orthonormalized(T_W_C_ * T_C_Cref);
  for (auto& h : history_) h.T_W_C = correction * h.T_W_C;
  T_M_W_ = orthonormalized(T_M_W_ * correction.inverse());
}

std::optional<Eigen::Isometry3d> CellOdometry::smoothedPrediction(
    double stamp_s, bool firm_only, const Eigen::Vector3d* inertial_W) const {
  if (!(config_.velocity_span_s > 0.0) || history_.size() < 2) return std::nullopt;
  const double threshold = config_.velocity_firm_information;
  const auto is_firm = [&](const HistoryEntry& h) { return h.weakest_information >= threshold; };
  const bool three_firm = std::count_if(history_.begin(), history_.end(), is_firm) >= 3;
  // With the IMU's displacement a line through fewer than three firm frames (after a long hold,
  // the frame or two registered since: a velocity from a step or two) is no better than the
  // IMU filter's own velocity, which the caller then keeps.
  if (inertial_W && !three_firm) return std::nullopt;
  const bool only_firm = firm_only && threshold > 0.0 && three_firm;
  // The position the line is fitted to: with the IMU's displacement taken out.
  const auto position = [&](const HistoryEntry& h) -> Eigen::Vector3d {
    return inertial_W ? Eigen::Vector3d(h.T_W_C.translation() - h.inertial_W)
                      : Eigen::Vector3d(h.T_W_C.translation());
  };
  const auto counts = [&](const HistoryEntry& h) { return !only_firm || is_firm(h); };
  // Translation: least-squares line through the positions (its slope is the world velocity);
  // rotation: the mean body rate from the first to the last pose of the window.
  double tm = 0.0, n = 0.0;
  Eigen::Vector3d pm = Eigen::Vector3d::Zero();
  const HistoryEntry* first = nullptr;
  const HistoryEntry* last = nullptr;
  for (const HistoryEntry& h : history_) {
    if (!counts(h)) continue;
    if (!first) first = &h;
    last = &h;
    tm += h.stamp_s;
    pm += position(h);
    n += 1.0;
  }
  tm /= n;
  pm /= n;
  double stt = 0.0;
  Eigen::Vector3d stp = Eigen::Vector3d::Zero();
  for (const HistoryEntry& h : history_) {
    if (!counts(h)) continue;
    stt += (h.stamp_s - tm) * (h.stamp_s - tm);
    stp += (h.stamp_s - tm) * (position(h) - pm);
  }
  const double span = last->stamp_s - first->stamp_s;
  if (!(stt > 0.0) || !(span > 0.0)) return std::nullopt;
  const double dt = stamp_s - last_stamp_s_;
  const Eigen::AngleAxisd rate(first->T_W_C.rotation().transpose() * last->T_W_C.rotation());
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = T_W_C_.rotation() *
               Eigen::AngleAxisd(rate.angle() * dt / span, rate.axis()).toRotationMatrix();
  T.translation() = T_W_C_.translation() + stp / stt * dt;
  if (inertial_W) T.translation() += *inertial_W - last_inertial_W_;
  return T;
}

FrameStatus CellOdometry::track(std::shared_ptr<const CellCloud> cells,
                                const std::optional<Eigen::Isometry3d>& prior_T_Cprev_Ccur,
                                const std::optional<InertialHold>& hold) {
  const auto t0 = std::chrono::steady_clock::now();
  if (!cells) throw std::invalid_argument("track: no cell cloud (null)");
  FrameStatus st;
  st.stamp_s = cells->stamp_s;
  st.cells = static_cast<int>(cells->cells.size());
  st.T_W_Cref = T_W_Cref_;

  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  if (prior_T_Cprev_Ccur) {
    if (!prior_T_Cprev_Ccur->matrix().allFinite())
      throw std::invalid_argument("track: motion prior is not finite");
    if (hold && (!hold->displacement_W.allFinite() || !std::isfinite(hold->guess_tolerance_m) ||
                 hold->guess_tolerance_m < 0.0))
      throw std::invalid_argument(
          "track: inertial hold is not finite (or its guess tolerance is negative)");
    motion = *prior_T_Cprev_Ccur;
  } else if (config_.constant_velocity) {
    motion = velocity_T_Cprev_Ccur_;
  }
  const Eigen::Isometry3d T_W_pred = T_W_C_ * motion;

  if (!reference_) {
    if (st.cells < config_.registration.min_matches) {
      std::ostringstream s;
      s << "frame has " << st.cells << " usable cells, fewer than min_matches "
        << config_.registration.min_matches << "; waiting for a usable first frame";
      st.failure = s.str();
      st.state = state_ = TrackingState::kLost;
      st.T_W_C = T_W_C_;
      st.ms_total = msSince(t0);
      return st;
    }
    last_cells_ = cells;
    last_stamp_s_ = st.stamp_s;
    if (config_.model.enabled) model_.integrate(*cells, modelPose());
    setReference(std::move(cells));
    st.tracked = true;
    st.new_keyframe = true;
    st.state = state_ = TrackingState::kTracking;
    st.T_W_C = T_W_C_;
    st.T_W_Cref = T_W_Cref_;
    st.ms_total = msSince(t0);
    return st;
  }

  const auto t1 = std::chrono::steady_clock::now();
  // Where the registration starts. An IMU's guess gives way to the last frame's motion where the
  // two agree within the guess's own uncertainty (InertialHold::guess_tolerance_m): along
  // directions the view fixes only weakly the fit ends near its start, and there the filter's
  // velocity wanders more than the motion the view last fixed (docs/tracking.md, "What the IMU
  // still costs on wall_slide"). The held directions' prior stays the IMU's (below).
  Eigen::Isometry3d T_W_start = T_W_pred;
  if (hold && hold->guess_tolerance_m > 0.0) {
    const Eigen::Isometry3d last_motion = T_W_C_ * velocity_T_Cprev_Ccur_;
    if ((last_motion.translation() - T_W_pred.translation()).norm() <= hold->guess_tolerance_m)
      T_W_start = last_motion;
  }
  Eigen::Isometry3d guess = T_W_Cref_.inverse() * T_W_start;
  // The smoothed prediction the held directions would follow, and how good it has been.
  const std::optional<Eigen::Isometry3d> smoothed = prior_T_Cprev_Ccur || !config_.constant_velocity
                                                        ? std::nullopt
                                                        : smoothedPrediction(st.stamp_s);
  RegistrationConfig reg_config = config_.registration;
  reg_config.degeneracy.prior_sigma_m = std::sqrt(prior_var_m2_);
  // A motion prior exists only while tracking: after lost frames the guess is a pose held through
  // them, and holding it along directions the first, badly aligned pairs seem not to fix would
  // also keep the jump gate from seeing how far off it is. Every direction is solved then.
  if (state_ != TrackingState::kTracking) reg_config.degeneracy.noise_margin = 0.0;
  // Hysteresis: a view that held directions keeps holding those that only just clear the
  // margin (docs/tracking.md, "Hysteresis").
  else if (last_held_ && reg_config.degeneracy.noise_margin > 0.0)
    reg_config.degeneracy.noise_margin = reg_config.degeneracy.release_margin;
  RegistrationResult reg;
  Eigen::Vector3d probe_dir = Eigen::Vector3d::Zero();  // the basin probe's direction
  if (st.cells < config_.registration.min_matches) {
    std::ostringstream s;
    s << "frame has only " << st.cells << " usable cells (min_matches "
      << config_.registration.min_matches << ")";
    reg.failure = s.str();
  } else {
    // After lost frames the guess is a pose held through them, and the model's smoother planes
    // let a registration from far off settle in a wrong minimum inside the jump gate (the
    // graph's covered-lens run: 22 mm off, lost again 12 frames later). The keyframe's own
    // cells are the reference until tracking resumes, as without the model.
    const bool raw = raw_reference_ && state_ != TrackingState::kTracking;
    const auto registerWith = [&](const Eigen::Isometry3d& g, const RegistrationConfig& rc) {
      RegistrationResult r = registerCells(raw ? *raw_reference_ : *reference_,
                                           raw ? raw_grid_ : grid_, *cells, intrinsics_, g, rc);
      // A view that leaves directions unfixed is registered against the keyframe's own cells:
      // along the directions it does fix, the model's voxel-sized planes blur the few edges
      // that fix them.
      if (!raw && raw_reference_ && r.degeneracy.degenerate > 0)
        r = registerCells(*raw_reference_, raw_grid_, *cells, intrinsics_, g, rc);
      return r;
    };
    const auto registerFrom = [&](const Eigen::Isometry3d& g) {
      return registerWith(g, reg_config);
    };
    reg = registerFrom(guess);
    // Held directions with the pairs collapsed: the guess, not the view, may be what is wrong
    // (CellOdometryConfig::retry_pairs_below). Once more from the previous pose.
    if (state_ == TrackingState::kTracking && reg.failure.empty() &&
        reg.degeneracy.degenerate > 0 && last_firm_matches_ > 0 &&
        reg.matches < config_.retry_pairs_below * last_firm_matches_) {
      const Eigen::Isometry3d at_rest = T_W_Cref_.inverse() * T_W_C_;
      RegistrationResult again = registerFrom(at_rest);
      st.retried = true;
      if (again.failure.empty() && again.degeneracy.degenerate == 0 &&
          again.matches >= kRetryPairsGain * reg.matches) {
        reg = std::move(again);
        guess = at_rest;
        st.retry_kept = true;
      }
    }
    // The deep returns' say (CellOdometryConfig::basin_deep_floor): where the near surfaces
    // leave the weakest direction unfixed (held by the degeneracy analysis, or flagged by the
    // basin probe below), the frame is registered again with the depth-noise weighting's floor
    // raised, and that result is kept when probes from either side of it confirm it.
    const double tolerance = config_.basin_probe_tolerance_m;
    // How far registrations from `r` moved basin_probe_step_m either way along `dir` end from it
    // (stops at the first beyond the tolerance).
    const auto spreadAround = [&](const RegistrationResult& r, const RegistrationConfig& rc,
                                  const Eigen::Vector3d& dir) {
      double spread = 0.0;
      for (const double side : {1.0, -1.0}) {
        if (spread > tolerance) break;  // one side says it
        Eigen::Isometry3d from = r.T_ref_cur;
        from.translation() += side * config_.basin_probe_step_m * dir;
        const RegistrationResult probe = registerWith(from, rc);
        // A probe that fails outright (too few pairs from there) says nothing either way.
        if (!probe.failure.empty() || !probe.T_ref_cur.matrix().allFinite()) continue;
        spread = std::max(
            spread, std::abs((probe.T_ref_cur.translation() - r.T_ref_cur.translation()).dot(dir)));
      }
      return spread;
    };
    // The raised floor changes a pair's weight only where its reference cell's own factor lies
    // below it; with no such cell (nothing deep in view, or the weighting off) the registration
    // would be the first one again, so it is not run.
    const auto floorReachesAPair = [&] {
      float z_max = 0.0f;
      for (const CellCloud* ref : {reference_.get(), raw_reference_.get()})
        if (ref)
          for (const Cell& c : ref->cells) z_max = std::max(z_max, c.mean_C.z());
      return noiseWeightingFactor(reg_config, z_max) < config_.basin_deep_floor;
    };
    const bool deep_on = state_ == TrackingState::kTracking &&
                         config_.basin_deep_floor > reg_config.noise_weighting_min;
    // Registers the frame again from the guess with the raised floor and keeps that result
    // (returning its probes' spread) when it fixes every direction and the probes along `along`
    // confirm it; with no `along`, along its own weakest direction when that is mostly a
    // translation.
    const auto keepDeep = [&](const Eigen::Vector3d* along) -> std::optional<double> {
      if (!floorReachesAPair()) return std::nullopt;
      RegistrationConfig deep_config = reg_config;
      deep_config.noise_weighting_min = config_.basin_deep_floor;
      RegistrationResult deep = registerWith(guess, deep_config);
      st.basin_deep_retried = true;
      if (!deep.failure.empty() || !deep.T_ref_cur.matrix().allFinite() ||
          deep.degeneracy.degenerate > 0 || deep.matches == 0)
        return std::nullopt;
      Eigen::Vector3d dir = along ? *along : Eigen::Vector3d(deep.degeneracy.weakest.tail<3>());
      if (!along) {
        if (dir.norm() <= 0.5) return std::nullopt;
        dir.normalize();
      }
      const double spread = spreadAround(deep, deep_config, dir);
      if (spread > tolerance) return std::nullopt;
      reg = std::move(deep);
      st.basin_deep_kept = true;
      return spread;
    };
    // A view read as degenerate: its held directions follow the motion prior unless the deep
    // returns fix every direction.
    if (deep_on && reg.failure.empty() && reg.degeneracy.degenerate > 0) keepDeep(nullptr);
    // The basin probe (CellOdometryConfig::basin_probe_below): a flag; on a flagged frame, the
    // deep returns may confirm another result (probed along the same direction). A frame the
    // deep returns fixed above was confirmed by its own probes.
    if (config_.basin_probe_below > 0.0 && state_ == TrackingState::kTracking &&
        !st.basin_deep_kept && reg.failure.empty() && reg.degeneracy.degenerate == 0 &&
        reg.matches > 0 && weakestInformation(reg.degeneracy) < config_.basin_probe_below) {
      probe_dir = reg.degeneracy.weakest.tail<3>();
      if (probe_dir.norm() > 0.5) {  // mostly a translation
        probe_dir.normalize();
        st.basin_probed = true;
        st.probe_spread_m = spreadAround(reg, reg_config, probe_dir);
        if (st.probe_spread_m > tolerance) {
          st.unconfirmed_directions = 1;
          if (deep_on) {
            if (const auto spread = keepDeep(&probe_dir)) {
              st.probe_spread_m = *spread;
              st.unconfirmed_directions = 0;
            }
          }
        }
      }
    }
  }
  st.ms_register = msSince(t1);
  timing_.add(st.ms_register);
  st.candidates = reg.candidates;
  st.matches = reg.matches;
  st.fm_matches = reg.fm_matches;
  st.duplicates_broken = reg.duplicates_broken;
  st.iterations = reg.iterations;
  st.error_rms_m = reg.error_rms_m;
  st.normal_matrix = reg.normal_matrix;
  st.degenerate_directions = reg.degeneracy.degenerate;
  st.weakest_information = weakestInformation(reg.degeneracy);
  if (reg.matches > 0) {
    const double sigma2 = reg.degeneracy.residual_var_m2 > 0.0
                              ? reg.degeneracy.residual_var_m2
                              : reg.error_rms_m * reg.error_rms_m;
    st.covariance = registrationCovariance(reg.degeneracy, sigma2, reg_config.degeneracy);
    st.measurement_covariance =
        measurementCovariance(reg.degeneracy, sigma2, config_.velocity_firm_information);
  }
  // A direction the probe found unfixed is known no better than the probes' spread along it.
  if (st.unconfirmed_directions > 0) {
    const Eigen::Matrix3d widen =
        st.probe_spread_m * st.probe_spread_m * probe_dir * probe_dir.transpose();
    st.covariance.bottomRightCorner<3, 3>() += widen;
    st.measurement_covariance.bottomRightCorner<3, 3>() += widen;
  }

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
  const bool held = reg.degeneracy.degenerate > 0;
  if (failure.empty()) {
    Eigen::Isometry3d T_ref_cur = reg.T_ref_cur;
    // The registration kept the prediction (the last frame's motion) along the held
    // directions; there the smoothed velocity of the firm frames before is the better prior
    // (T_W_C_ and the window are still those `smoothed` was made from).
    if (held && smoothed) {
      const Eigen::Isometry3d prior = smoothedPrediction(st.stamp_s, true).value_or(*smoothed);
      T_ref_cur =
          withPriorAlongDegenerate(reg.degeneracy, reg.T_ref_cur, T_W_Cref_.inverse() * prior);
    } else if (held && prior_T_Cprev_Ccur && hold) {
      // An IMU's guess: its rotation (the gyro's), and for the position the firm frames' line
      // with the IMU's significant accelerations taken out, and this frame's put back (none with
      // fewer than three firm frames: the guess, the IMU filter's velocity, then stands).
      if (const auto firm = smoothedPrediction(st.stamp_s, true, &hold->displacement_W)) {
        Eigen::Isometry3d prior = T_W_pred;
        prior.translation() = firm->translation();
        T_ref_cur =
            withPriorAlongDegenerate(reg.degeneracy, reg.T_ref_cur, T_W_Cref_.inverse() * prior);
      }
    }
    T_W_C_ = orthonormalized(T_W_Cref_ * T_ref_cur);
    last_held_ = held;
    if (!held) last_firm_matches_ = reg.matches;
    if (hold) last_inertial_W_ = hold->displacement_W;
    st.tracked = true;
    state_ = TrackingState::kTracking;
    velocity_T_Cprev_Ccur_ = T_W_prev.inverse() * T_W_C_;
    // A frame that left directions unfixed repeats the prediction there (or, turning
    // degenerate, follows weak constraints): the velocity stays the one measured before.
    if (!held) {
      if (smoothed) {
        // Running mean square of the smoothed prediction's error, per axis: the prior's sigma.
        // Held modes that are mostly a rotation take the prior's rotation
        // (withPriorAlongDegenerate), so its rotation error at the pairs' lever L counts as
        // well; the larger of the two is the one sigma the weighing uses.
        const double L = reg.degeneracy.length_scale_m;
        const double e_rot_m = L * rotationAngle(smoothed->inverse() * T_W_C_);
        const double e_trans2 = (T_W_C_.translation() - smoothed->translation()).squaredNorm();
        const double e2 = std::max(e_trans2, e_rot_m * e_rot_m) / 3.0;
        prior_var_m2_ = std::max(0.9 * prior_var_m2_ + 0.1 * e2, kMinPriorSigmaM * kMinPriorSigmaM);
      }
      history_.push_back({st.stamp_s, T_W_C_, st.weakest_information,
                          hold ? hold->displacement_W : last_inertial_W_});
      while (history_.size() > 2 &&
             history_.back().stamp_s - history_.front().stamp_s > config_.velocity_span_s)
        history_.pop_front();
    }
  } else {
    // Keep the predicted pose and flag the frame; the reference stays as it was. The velocity
    // window starts again with the next tracked frames.
    T_W_C_ = orthonormalized(T_W_pred);
    history_.clear();
    st.failure = failure;
    st.unconfirmed_directions = 0;  // a frame not tracked is flagged as such, not as unconfirmed
    if (state_ != TrackingState::kRelocalising) state_ = TrackingState::kLost;
  }
  st.state = state_;
  ++frames_since_refresh_;
  bool refresh = false;
  if (config_.icp_frames >= 1) {
    refresh = frames_since_refresh_ >= config_.icp_frames;
  } else if (st.tracked) {
    const Eigen::Isometry3d from_key = T_W_Cref_.inverse() * T_W_C_;
    const double overlap = reference_->cells.empty()
                               ? 0.0
                               : static_cast<double>(st.matches) / reference_->cells.size();
    refresh = from_key.translation().norm() > config_.keyframe_dist_m ||
              rotationAngle(from_key) * kRadToDeg > config_.keyframe_angle_deg ||
              overlap < config_.keyframe_min_overlap;
  }
  last_cells_ = cells;
  if (st.tracked && config_.model.enabled) {
    const Eigen::Isometry3d T_M_C = modelPose();
    model_.integrate(*cells, T_M_C);
    if (config_.model.keep_radius_m > 0.0 && ++model_frames_ % config_.model.prune_every == 0)
      model_.prune(T_M_C.translation(), config_.model.keep_radius_m);
  }
  if (st.tracked && refresh) {
    setModelReference(cells, &st.model);
    st.new_keyframe = true;
  }
  last_stamp_s_ = st.stamp_s;
  st.T_W_C = T_W_C_;
  st.ms_total = msSince(t0);
  return st;
}

namespace {

// Why a registration's result is unusable at all (failed, non-finite, residual above the
// tracking gate), empty if it is usable: the screens and the final check of a relocalisation.
std::string unusableRegistration(const RegistrationResult& res, double max_error_rms_m) {
  std::ostringstream why;
  if (!res.failure.empty()) {
    why << "registration failed: " << res.failure;
  } else if (!res.T_ref_cur.matrix().allFinite()) {
    why << "registration diverged (non-finite)";
  } else if (res.error_rms_m > max_error_rms_m) {
    why << "residual " << res.error_rms_m * 1000.0 << " mm exceeds max_error_rms_m "
        << max_error_rms_m * 1000.0 << " mm";
  }
  return why.str();
}

// The starts of a relocalisation: the guess, then the guess turned about the camera's x and y
// axes by multiples of search_step_deg up to search_angle_deg (the camera centre stays).
std::vector<Eigen::Isometry3d> relocalisationStarts(const Eigen::Isometry3d& guess,
                                                    const RelocaliseConfig& rc) {
  std::vector<Eigen::Isometry3d> starts = {guess};
  if (!(rc.search_angle_deg > 0.0)) return starts;
  const int steps = static_cast<int>(std::floor(rc.search_angle_deg / rc.search_step_deg));
  for (int ix = -steps; ix <= steps; ++ix)
    for (int iy = -steps; iy <= steps; ++iy) {
      if (ix == 0 && iy == 0) continue;
      Eigen::Isometry3d turn = Eigen::Isometry3d::Identity();
      turn.linear() =
          (Eigen::AngleAxisd(ix * rc.search_step_deg * kDegToRad, Eigen::Vector3d::UnitX()) *
           Eigen::AngleAxisd(iy * rc.search_step_deg * kDegToRad, Eigen::Vector3d::UnitY()))
              .toRotationMatrix();
      starts.push_back(guess * turn);
    }
  return starts;
}

}  // namespace

std::vector<Eigen::Isometry3d> CellOdometry::screenRelocalisationStarts(
    const CellCloud& reference, const CellCloud& cur, const Eigen::Isometry3d& guess,
    const RegistrationConfig& reg) const {
  const RelocaliseConfig& rc = config_.relocalise;
  std::vector<Eigen::Isometry3d> starts = relocalisationStarts(guess, rc);
  if (starts.size() == 1) return starts;
  // A few iterations from each start, every direction solved; the starts whose screens paired
  // the most cells within the residual gate go on.
  RegistrationConfig screen = reg;
  screen.max_iterations = rc.screen_iterations;
  screen.degeneracy.noise_margin = 0.0;
  std::vector<std::pair<int, Eigen::Isometry3d>> screened;  // (pairs or -1, pose)
  for (const Eigen::Isometry3d& s0 : starts) {
    const RegistrationResult sr = registerCells(reference, cur, intrinsics_, s0, screen);
    const bool usable = unusableRegistration(sr, config_.max_error_rms_m).empty();
    screened.emplace_back(usable ? sr.matches : -1, usable ? sr.T_ref_cur : s0);
  }
  std::stable_sort(screened.begin(), screened.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  starts.clear();
  for (int k = 0; k < rc.screened_kept && k < static_cast<int>(screened.size()); ++k)
    if (screened[k].first > 0 || k == 0) starts.push_back(screened[k].second);
  return starts;
}

std::string CellOdometry::judgeRelocalisation(const CellCloud& reference, const CellCloud& cur,
                                              const RegistrationResult& res) const {
  const std::string unusable = unusableRegistration(res, config_.max_error_rms_m);
  if (!unusable.empty()) return unusable;
  std::ostringstream why;
  const double denom = static_cast<double>(
      std::max<std::size_t>(1, std::min(reference.cells.size(), cur.cells.size())));
  if (res.matches < config_.relocalise.min_overlap * denom) {
    why << res.matches << " pairs, " << 100.0 * res.matches / denom
        << " % of the cells (relocalise.min_overlap " << 100.0 * config_.relocalise.min_overlap
        << " %)";
  } else if (config_.registration.degeneracy.noise_margin > 0.0) {
    // Where the pose landed, the view must fix every direction: against a reference that does
    // not (a lone wall), some start pairs up somewhere along it. One step at the result with the
    // tracking window and the degeneracy analysis, the prior as wide as the first pass's gate,
    // so only what the view cannot fix is held.
    RegistrationConfig verify = config_.registration;
    verify.max_iterations = 1;
    verify.degeneracy.prior_sigma_m = config_.relocalise.initial_dist_m;
    const int held =
        registerCells(reference, cur, intrinsics_, res.T_ref_cur, verify).degeneracy.degenerate;
    if (held > 0)
      why << "the view does not fix " << held << " direction" << (held > 1 ? "s" : "")
          << " of the pose there";
  }
  return why.str();
}

RelocalisationResult CellOdometry::relocalise(const CellCloud& reference,
                                              const Eigen::Isometry3d& T_W_Cref,
                                              const Eigen::Isometry3d& T_W_C_guess) {
  const auto t0 = std::chrono::steady_clock::now();
  if (!T_W_Cref.matrix().allFinite() || !T_W_C_guess.matrix().allFinite())
    throw std::invalid_argument("relocalise: reference or guess pose is not finite");
  RelocalisationResult r;
  r.T_W_C = T_W_C_;
  if (!last_cells_) {
    r.reason = "no frame to relocalise yet";
    r.ms = msSince(t0);
    return r;
  }
  const CellCloud& cur = *last_cells_;
  if (reference.cell_size != cur.cell_size || reference.grid_w != cur.grid_w ||
      reference.grid_h != cur.grid_h)
    throw std::invalid_argument("relocalise: the reference's cell grid differs from the frame's");
  RegistrationConfig reg = config_.registration;
  reg.match.search_radius_cells = config_.relocalise.search_radius_cells;
  reg.match.initial_dist_m = config_.relocalise.initial_dist_m;
  reg.max_iterations = config_.relocalise.max_iterations;
  reg.degeneracy.prior_sigma_m = config_.relocalise.initial_dist_m;
  const std::vector<Eigen::Isometry3d> starts =
      screenRelocalisationStarts(reference, cur, T_W_Cref.inverse() * T_W_C_guess, reg);
  // From each start two registrations, the one pairing the most cells kept among those the
  // checks accept: every direction solved (the guess is a pose held through lost frames, not a
  // motion prior worth keeping along directions the first, badly aligned pairs seem not to fix),
  // and directions the view does not fix held at the start, since in a view close to degenerate
  // (a wall and little else) the plain solve slides along the wall on noise, off the view.
  std::string rejected, kept;
  RegistrationResult last;
  bool have = false;
  for (const Eigen::Isometry3d& start : starts)
    for (const bool hold : {false, true}) {
      reg.degeneracy.noise_margin = hold ? config_.registration.degeneracy.noise_margin : 0.0;
      if (hold && !(reg.degeneracy.noise_margin > 0.0)) break;
      RegistrationResult res = registerCells(reference, cur, intrinsics_, start, reg);
      const char* how = hold ? "holding unfixed directions" : "solving every direction";
      const std::string why = judgeRelocalisation(reference, cur, res);
      if (!why.empty()) {
        rejected += (rejected.empty() ? "" : "; ") + std::string(how) + ": " + why;
        if (!have) last = std::move(res);
      } else if (!have || res.matches > r.registration.matches) {
        r.registration = std::move(res);
        kept = how;
        have = true;
      }
    }
  if (!have) {
    r.registration = std::move(last);
    r.reason = rejected;
    if (state_ != TrackingState::kTracking) state_ = TrackingState::kRelocalising;
    r.ms = msSince(t0);
    return r;
  }
  const RegistrationResult& res = r.registration;
  std::ostringstream why;
  T_W_C_ = orthonormalized(T_W_Cref * res.T_ref_cur);
  velocity_T_Cprev_Ccur_ = Eigen::Isometry3d::Identity();
  history_.clear();
  setReference(last_cells_);
  state_ = TrackingState::kTracking;
  r.accepted = true;
  r.T_W_C = T_W_C_;
  why << "accepted (" << kept << "): " << res.matches << " pairs, residual "
      << res.error_rms_m * 1000.0 << " mm, " << res.iterations << " iterations";
  r.reason = why.str();
  r.ms = msSince(t0);
  return r;
}

}  // namespace depth_track
