#pragma once
/// Frame-to-keyframe odometry on cell clouds (thesis eq. 2.48–2.52, written as T_W_C): motion
/// prediction, registration against the reference cells, failure gates, keyframe refresh and
/// the tracking state, with a relocalisation hook for a reference from elsewhere (the map's ray
/// cast). Owns the reference, the velocity and the association grid, which it keeps while the
/// keyframe stays. ROS-free core; not thread-safe (one instance per camera stream).
#include <Eigen/Geometry>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/registration.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/core/surface_model.hpp"

namespace depth_track {

/// Search of a relocalisation, wider than frame-to-frame tracking: the pose held while the
/// camera was lost can be off by more than one frame's motion.
struct RelocaliseConfig {
  int search_radius_cells = 4;  ///< image-grid window of the first pass, cells
  double initial_dist_m = 0.3;  ///< first-iteration pair gate, halved per iteration, metres
  int max_iterations = 60;      ///< ICP iterations
  /// Starts of the search besides the guess: the guess turned about the camera's x and y axes
  /// by multiples of search_step_deg up to search_angle_deg (a held pose is off mostly in
  /// rotation after a turn the prediction missed: 10 deg moves the view ~90 px, beyond the
  /// window). Each start is screened with screen_iterations; the best screened_kept (most
  /// pairs) are then registered to convergence. search_angle_deg 0 = the guess alone.
  double search_angle_deg = 10.0;
  double search_step_deg = 5.0;
  int screen_iterations = 12;
  int screened_kept = 2;
  /// Share of the smaller of the two clouds (the frame's cells, the reference's) that must pair
  /// up at the result: a registration that slid off the view onto a sliver of it pairs few.
  double min_overlap = 0.3;

  std::vector<std::string> validate() const;
};

struct CellOdometryConfig {
  RegistrationConfig registration;
  /// Reference refresh: N >= 1 refreshes every N frames (the thesis's ICPFrames); 0 keeps a
  /// keyframe until the camera has moved keyframe_dist_m or turned keyframe_angle_deg from it,
  /// or fewer than keyframe_min_overlap of its cells still find a partner. Registering against
  /// a keyframe instead of the previous frame stops per-registration errors adding up at rest
  /// and at slow speed.
  int icp_frames = 0;
  double keyframe_dist_m = 0.10;
  double keyframe_angle_deg = 5.0;
  double keyframe_min_overlap = 0.5;
  double max_error_rms_m = 0.02;  ///< larger residual = failed frame, metres
  double max_jump_m = 0.15;       ///< larger correction of the prediction = failed frame, metres
  double max_jump_deg = 15.0;     ///< ... degrees
  bool constant_velocity = true;  ///< predict with the last motion (else: no motion)
  /// Along directions the view cannot fix (RegistrationConfig::degeneracy) the pose follows the
  /// camera's velocity fitted over the frames whose view fixed every direction, over the last
  /// velocity_span_s seconds up to the latest of them (a line through their positions, their
  /// mean rotation rate): one frame's motion carries that frame's registration noise (~0.3 mm at
  /// 30 Hz is ~9 mm/s of drift), and the frames of a view turning degenerate follow weak
  /// constraints. A span in seconds, not frames: a camera at 7.5 Hz (or dropping frames) must
  /// not fit its velocity over several seconds of hand-held motion. 0.65 s holds 20 frames at
  /// 30 Hz. 0 = the last frame's motion, as everywhere else.
  double velocity_span_s = 0.65;
  /// The velocity the held directions follow is fitted to the window's firm frames only: those
  /// whose weakest direction carried at least this many times its noise floor
  /// (FrameStatus::weakest_information). A view turning degenerate fixes its weak directions less
  /// and less before they are held, and the frames in between slide along them; fitted to them,
  /// the velocity carries that slide through the whole degenerate stretch. With fewer than three
  /// firm frames in the window, all count. 0 = all frames count.
  double velocity_firm_information = 10.0;
  /// A frame that holds directions with fewer pairs than this fraction of the last fully
  /// constrained frame's is registered once more from the previous pose (no motion), and that
  /// result is kept when it fixes every direction with at least 1.5 times the pairs. Between
  /// distant frames (a slow frame rate, dropped frames) a hand that reverses or stops leaves the
  /// constant-velocity guess centimetres off: the pairs that fix the motion fall outside the
  /// gates, and the planes that remain look like a degenerate view. A view that is degenerate
  /// stays so from any guess and keeps the first result. 0 = off.
  double retry_pairs_below = 0.9;
  /// The basin probe. A frame whose view fixes every direction, but whose weakest direction
  /// carries less than this many times its noise floor (FrameStatus::weakest_information), is
  /// registered twice more, from its own result moved basin_probe_step_m either way along that
  /// direction (when it is mostly a translation). Where either ends more than
  /// basin_probe_tolerance_m from the first result along it, the view does not fix the direction
  /// after all (a flat valley: a corridor's start with stereo noise, whose pooled creases read
  /// as information): the frame is flagged (FrameStatus::unconfirmed_directions) and its
  /// covariance along the direction widened to the probes' spread. The flag by itself changes
  /// nothing else (basin_deep_floor may). 0 = off.
  double basin_probe_below = 20.0;
  double basin_probe_step_m = 0.02;       ///< see basin_probe_below, metres
  double basin_probe_tolerance_m = 0.005;  ///< see basin_probe_below, metres (< the step)
  /// The deep returns' say where the near surfaces leave a direction unfixed. The depth-noise
  /// weighting gives a pair at least RegistrationConfig::noise_weighting_min of the nearest
  /// pair's weight, so that the far, noisy returns cannot bias a view its near surfaces fix. A
  /// frame whose view is read as degenerate (directions held), or that the basin probe flags (a
  /// corridor's start with stereo noise: door frames and the far end lie deep), is registered
  /// once more from the same guess with that floor raised to this value. If that result fixes
  /// every direction and probes from basin_probe_step_m either side of it (along its own weakest
  /// direction for a held frame, along the probe's for a flagged one) end within
  /// basin_probe_tolerance_m, it is the frame's: nothing is held and the frame is not flagged
  /// (FrameStatus::basin_deep_kept). Otherwise the first result, its held directions and the
  /// flag stay. A frame costs up to three registrations more. 0 (or a value not above
  /// noise_weighting_min) = off: held directions follow the motion prior, the probe only flags.
  double basin_deep_floor = 0.25;
  RelocaliseConfig relocalise;
  /// The registration model: tracked frames' cells averaged per voxel, and each new keyframe's
  /// cells replaced by the model's planes where it is confident (SurfaceModel).
  SurfaceModelConfig model;

  /// Every problem at once (empty = valid).
  std::vector<std::string> validate() const;
};

/// What an inertial prior (ImuMotionPrior::guess) adds for the directions a view does not fix.
/// Held directions follow the firm frames, as without an external prior, with the IMU's
/// significant accelerations on top rather than the IMU's own velocity: the firm frames'
/// positions less the displacement those accelerations made are fitted to a line, and the held
/// position is that line's velocity plus this frame's displacement. An IMU tells a start or a
/// stop well, a constant velocity no better than the depth of the frames before
/// (docs/tracking.md, "Held directions follow the firm frames").
struct InertialHold {
  /// The camera's displacement from the accelerations the IMU read as significant (past its soft
  /// threshold), summed since the prior started, at this frame (world, m).
  Eigen::Vector3d displacement_W = Eigen::Vector3d::Zero();
  /// Register from the last frame's motion instead of the guess when the two put the camera
  /// within this distance of each other (m; 0 = always from the guess). ImuPriorConfig::guess_gate.
  double guess_tolerance_m = 0.0;
};

/// TRACKING: the last frame registered. LOST: it did not (or no usable frame came yet); the pose
/// is the prediction. RELOCALISING: lost, and a relocalisation was tried and rejected.
enum class TrackingState { kTracking, kLost, kRelocalising };
/// "TRACKING" | "LOST" | "RELOCALISING".
std::string toString(TrackingState state);

/// Per-frame outcome.
struct FrameStatus {
  double stamp_s = 0.0;
  bool tracked = false;  ///< false = pose is the prediction (frame flagged)
  TrackingState state = TrackingState::kLost;
  std::string failure;  ///< reason when !tracked
  int cells = 0;
  int candidates = 0, matches = 0, fm_matches = 0, duplicates_broken = 0, iterations = 0;
  double error_rms_m = 0.0;
  /// Directions of the pose the view did not fix (held at the motion prior, see
  /// DegeneracyAnalysis::degenerate); 0 = a fully constrained view.
  int degenerate_directions = 0;
  /// Smallest ratio of an eigenvalue of the registration's normal equations to its normal-noise
  /// floor (below 1: no information beyond the normals' noise; DegeneracyConfig).
  double weakest_information = 0.0;
  /// Covariance of the pose increment [omega (rad); u (m)] in the reference frame (rotation about
  /// the camera centre, the centre's displacement): sigma^2 H^-1 along the fixed directions (sigma
  /// the residual RMS), the motion prior's variance along held ones. Zero when no registration ran.
  Matrix6d covariance = Matrix6d::Zero();
  /// The same, of what the view alone measured (measurementCovariance): a held direction, whose
  /// pose is the motion prior's, and one below velocity_firm_information times its floor carry
  /// no measurement (kUnmeasuredVariance). What a filter that made the prior (ImuMotionPrior)
  /// takes as the frame's measurement. Zero when no registration ran.
  Matrix6d measurement_covariance = Matrix6d::Zero();
  double ms_prefilter = 0.0, ms_reduce = 0.0, ms_register = 0.0, ms_total = 0.0;
  bool new_keyframe = false;  ///< the frame became the reference for the next ones
  /// Registered again from the previous pose (CellOdometryConfig::retry_pairs_below); kept: that
  /// result is the frame's.
  bool retried = false, retry_kept = false;
  /// The basin probe (CellOdometryConfig::basin_probe_below): probed = the frame was registered
  /// from either side of its result along its weakest direction; unconfirmed_directions = 1
  /// when a probe ended more than the tolerance away (the direction is not fixed, although its
  /// information read above the margin; 0 on a frame not tracked), probe_spread_m the farthest a probe ended from the
  /// result along it (m; 0 when not probed).
  bool basin_probed = false;
  int unconfirmed_directions = 0;
  double probe_spread_m = 0.0;
  /// A held or flagged frame registered again with the deep returns weighted up
  /// (CellOdometryConfig::basin_deep_floor); kept: that result is the frame's, confirmed by its
  /// own probes (nothing held, the frame not flagged; for a flagged frame probe_spread_m is then
  /// the spread of those probes).
  bool basin_deep_retried = false, basin_deep_kept = false;
  /// With new_keyframe and the model on: how the model refined the keyframe's cells.
  ModelRefineStats model;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
  /// Pose of the reference the frame was registered against (the frame of normal_matrix).
  Eigen::Isometry3d T_W_Cref = Eigen::Isometry3d::Identity();
  /// RegistrationResult::normal_matrix of this frame's registration (zero when none ran).
  Matrix6d normal_matrix = Matrix6d::Zero();
};

/// Outcome of CellOdometry::relocalise.
struct RelocalisationResult {
  bool accepted = false;
  std::string reason;  ///< why it was rejected, or "accepted: ..."
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();  ///< relocalised (or held) pose
  RegistrationResult registration;
  double ms = 0.0;
};

class CellOdometry {
 public:
  /// Throws std::invalid_argument listing every problem of the config or intrinsics, or for a
  /// non-finite start pose.
  CellOdometry(const PinholeIntrinsics& intrinsics, const CellOdometryConfig& config,
               const Eigen::Isometry3d& T_W_C0 = Eigen::Isometry3d::Identity());

  /// Tracks one frame's cells (from a CellReducer with these intrinsics). The first frame with
  /// at least min_matches cells becomes the reference at the current pose. A frame that fails
  /// (too few cells or matches, residual, implausible jump) keeps the predicted pose and is
  /// flagged LOST, never a NaN pose. `prior_T_Cprev_Ccur` optionally replaces the
  /// constant-velocity guess with an external motion prior (the camera's motion since the last
  /// frame); the registration keeps it along the directions the view does not fix, unless
  /// `hold` (an IMU's, with the prior) gives them the firm frames' velocity and its significant
  /// acceleration. Throws std::invalid_argument for a null cloud, a non-finite prior or hold, or
  /// cells of another grid than the reference's (reset() after changing the cell size).
  FrameStatus track(std::shared_ptr<const CellCloud> cells,
                    const std::optional<Eigen::Isometry3d>& prior_T_Cprev_Ccur = std::nullopt,
                    const std::optional<InertialHold>& hold = std::nullopt);

  /// Registers the last frame's cells (lastCells()) onto `reference`, cells of the same grid
  /// seen from T_W_Cref (e.g. the map ray-cast at the held pose and reduced like the frame),
  /// from the guess T_W_C_guess, with the wider search of config.relocalise and the tracking
  /// gates on matches and residual. Accepted: the pose becomes the result, the last frame the
  /// keyframe, the velocity zero, the state TRACKING. Rejected: nothing changes but the state,
  /// RELOCALISING while lost. Throws std::invalid_argument for a grid mismatch or a non-finite
  /// pose.
  RelocalisationResult relocalise(const CellCloud& reference, const Eigen::Isometry3d& T_W_Cref,
                                  const Eigen::Isometry3d& T_W_C_guess);

  /// Forgets reference, velocity and last cells and restarts at T_W_C (the next usable frame
  /// becomes the reference). Throws std::invalid_argument for a non-finite pose.
  void reset(const Eigen::Isometry3d& T_W_C);
  /// reset() to the start pose given at construction.
  void reset() { reset(T_W_C0_); }
  /// Replaces the thresholds and the method between two frames (a runtime reconfiguration),
  /// keeping pose, velocity and keyframe; the association grid is rebuilt for a new search
  /// window. Throws std::invalid_argument listing every problem; the old config then stays.
  void setConfig(const CellOdometryConfig& config);
  /// Replaces the current pose (e.g. after a loop-closure correction); keeps the velocity and
  /// moves the reference frame's pose with it. The registration model stays where it was built
  /// relative to the camera: its voxels are not moved, the correction is kept as the model
  /// frame's offset from the corrected world (so the model lives in the uncorrected odometry
  /// frame, as it does in the graph, where corrections are a map -> odom transform).
  void correctPose(const Eigen::Isometry3d& T_W_C);

  /// Current camera pose in the world.
  const Eigen::Isometry3d& pose() const { return T_W_C_; }
  TrackingState state() const { return state_; }
  /// The keyframe (null before the first usable frame) and its pose.
  const std::shared_ptr<const CellCloud>& reference() const { return reference_; }
  const Eigen::Isometry3d& referencePose() const { return T_W_Cref_; }
  /// Cells of the last frame given to track() (null before the first).
  const std::shared_ptr<const CellCloud>& lastCells() const { return last_cells_; }
  /// Last frame-to-frame motion T_Cprev_Ccur (the constant-velocity prediction).
  const Eigen::Isometry3d& velocity() const { return velocity_T_Cprev_Ccur_; }
  const CellOdometryConfig& config() const { return config_; }
  const PinholeIntrinsics& intrinsics() const { return intrinsics_; }
  /// ms of registration per frame after the first (those with a reference).
  const RunningStats& timing() const { return timing_; }
  /// The registration model (empty with config.model.enabled off).
  const SurfaceModel& model() const { return model_; }

 private:
  void setReference(std::shared_ptr<const CellCloud> cells);
  /// setReference with the model's planes in place of the cells' own (model on and not empty);
  /// what it did goes to *stats.
  void setModelReference(const std::shared_ptr<const CellCloud>& cells, ModelRefineStats* stats);
  /// The constant-velocity pose for stamp_s from history_ (nullopt with too little of it).
  /// firm_only: fitted to the firm frames (CellOdometryConfig::velocity_firm_information) when
  /// the window holds at least three. inertial_W: stamp_s's InertialHold::displacement_W; the
  /// line is then fitted to the positions less theirs, and the pose moved by the difference
  /// (nullopt with fewer than three firm frames).
  std::optional<Eigen::Isometry3d> smoothedPrediction(
      double stamp_s, bool firm_only = false, const Eigen::Vector3d* inertial_W = nullptr) const;
  /// relocalise(): the starts worth registering to convergence (T_ref_cur), screened from the
  /// guess and its turns (RelocaliseConfig::search_angle_deg) with `reg`'s search.
  std::vector<Eigen::Isometry3d> screenRelocalisationStarts(const CellCloud& reference,
                                                            const CellCloud& cur,
                                                            const Eigen::Isometry3d& guess,
                                                            const RegistrationConfig& reg) const;
  /// relocalise(): why a registration of `cur` onto `reference` is refused (residual, overlap,
  /// a view that does not fix every direction where it landed), empty if accepted.
  std::string judgeRelocalisation(const CellCloud& reference, const CellCloud& cur,
                                  const RegistrationResult& res) const;

  PinholeIntrinsics intrinsics_;
  CellOdometryConfig config_;
  Eigen::Isometry3d T_W_C0_;
  Eigen::Isometry3d T_W_C_;
  Eigen::Isometry3d T_W_Cref_;               ///< pose of the reference frame
  Eigen::Isometry3d velocity_T_Cprev_Ccur_;  ///< last frame-to-frame motion
  std::shared_ptr<const CellCloud> reference_;
  std::shared_ptr<const CellCloud> last_cells_;
  AssociationGrid grid_;  ///< built for *reference_ whenever it changes
  /// With the model: the keyframe's own cells (reference_ holds them refined by the model) and
  /// their grid; null when the reference is not refined.
  std::shared_ptr<const CellCloud> raw_reference_;
  AssociationGrid raw_grid_;
  TrackingState state_ = TrackingState::kLost;
  int frames_since_refresh_ = 0;
  double last_stamp_s_ = 0.0;
  /// The tracked frames whose view fixed every direction, over velocity_span_s up to the latest.
  struct HistoryEntry {
    double stamp_s;
    Eigen::Isometry3d T_W_C;
    double weakest_information;  ///< FrameStatus's: firm at velocity_firm_information or more
    Eigen::Vector3d inertial_W;  ///< InertialHold::displacement_W of the frame (the last one given)
  };
  Eigen::Vector3d last_inertial_W_ = Eigen::Vector3d::Zero();  ///< of the last tracked frame
  std::deque<HistoryEntry> history_;
  /// Running mean square per axis of the smoothed prediction's position error on frames whose
  /// view fixed every direction, m^2, starting at (1 cm)^2: the prior's variance for the
  /// degeneracy weighing.
  double prior_var_m2_ = 1e-4;
  bool last_held_ = false;  ///< the last tracked frame held directions (release_margin applies)
  int last_firm_matches_ = 0;  ///< pairs of the last tracked frame that held no direction
  RunningStats timing_;
  /// Empties the registration model and its frame offset (reset).
  void clearModel();
  /// The current camera in the model's frame: where integrate, refine and prune read it.
  Eigen::Isometry3d modelPose() const { return T_M_W_ * T_W_C_; }
  SurfaceModel model_;
  long model_frames_ = 0;  ///< frames fused into the model since the start or reset (pruning)
  /// The model's frame from the odometry's world: identity until a correctPose moves the world.
  Eigen::Isometry3d T_M_W_ = Eigen::Isometry3d::Identity();
};

}  // namespace depth_track
