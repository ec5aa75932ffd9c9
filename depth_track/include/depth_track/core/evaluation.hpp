#pragma once
/// Trajectory evaluation against ground truth (ROS-free core): the standard metrics (ATE RMSE
/// after rigid alignment, RPE over one frame) and the thesis's style of result (ch. 5 tables
/// 5.3/5.5/5.6: maximum absolute per-axis errors relative to the start pose, end-of-run drift).
/// Trajectories are camera-to-world poses T_W_C. All functions are thread-safe.
/// The numbers agree with the independent checkers shared/tools/eval_traj.py and pose_errors.py.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/tum_io.hpp"

namespace depth_track {

// ---- thesis Euler convention (§2.5, eq. 2.59)
// ----------------------------------------------------- Eq. 2.59 writes the global-to-camera matrix
// T_CG = Rz(-θz) Rx(-θx) Ry(-θy) (frame rotations, positive right-handed); its transpose is the
// camera-to-world rotation used here:
//   R_W_C = Ry(θy) Rx(θx) Rz(θz),   pitch θx about camera x, yaw θy about y, roll θz about z.
// For small angles R_W_C ~ I + [θ]x (eq. 2.60), so the angles are the rotation vector to first
// order. (The printed eq. 2.59 has a typo in element (2,1): it reads sinθy sinθx cosθz -
// cosθx cosθz where the product above gives sinθy sinθx cosθz - sinθz cosθy.)

/// Thesis angles (θx pitch, θy yaw, θz roll), radians, of a rotation R_W_C. θx in [-pi/2, pi/2],
/// θy and θz in (-pi, pi]. At θx = +-pi/2 (gimbal lock) θz is set to 0.
Eigen::Vector3d thesisEulerFromRotation(const Eigen::Matrix3d& R_W_C);

/// R_W_C = Ry(θy) Rx(θx) Rz(θz) from thesis angles (θx pitch, θy yaw, θz roll) in radians.
Eigen::Matrix3d rotationFromThesisEuler(const Eigen::Vector3d& theta_xyz_rad);

// ---- metrics
// ----------------------------------------------------------------------------------------

/// Rigid transform T_gt_est (rotation + translation, no scale) minimising
/// sum |T_gt_est p_est - p_gt|^2 (Horn / Umeyama closed form by SVD). Throws
/// std::invalid_argument for lists of different length or fewer than 2 points.
Eigen::Isometry3d alignRigid(const std::vector<Eigen::Vector3d>& p_est,
                             const std::vector<Eigen::Vector3d>& p_gt);

/// Standard metrics of associated pose pairs (equal-length lists, same order).
struct AteRpe {
  std::size_t frames = 0;
  double ate_rmse_m = 0.0;  ///< RMS position error after alignRigid, metres
  double ate_max_m = 0.0;   ///< largest aligned position error, metres
  double rpe_1f_m = 0.0;    ///< RMS translation of the 1-frame relative pose error, metres
  double rpe_1f_deg = 0.0;  ///< RMS rotation angle of the 1-frame relative pose error, degrees
  Eigen::Isometry3d T_gt_est = Eigen::Isometry3d::Identity();  ///< the alignment used
};

/// ATE RMSE and RPE (1 frame). Throws std::invalid_argument for lists of different length or
/// fewer than 2 poses.
AteRpe computeAteRpe(const std::vector<Eigen::Isometry3d>& est_T_W_C,
                     const std::vector<Eigen::Isometry3d>& gt_T_W_C);

/// Relative pose error over chosen index pairs (i, j): E = (gt_i^-1 gt_j)^-1 (est_i^-1 est_j).
struct RelativeError {
  std::size_t pairs = 0;
  double rms_m = 0.0;    ///< RMS of |translation of E|, metres
  double rms_deg = 0.0;  ///< RMS of the rotation angle of E, degrees
};

/// RPE over the given pairs of indices into the associated lists. Throws std::invalid_argument
/// for lists of different length or an index out of range; no pairs gives zeros.
RelativeError relativePoseError(const std::vector<Eigen::Isometry3d>& est_T_W_C,
                                const std::vector<Eigen::Isometry3d>& gt_T_W_C,
                                const std::vector<std::pair<std::size_t, std::size_t>>& pairs);

/// Index pairs (i, j) with j the first pose at least delta_s after pose i (stamps in time
/// order; 1 us slack for stamps stored with 6 decimals). Poses less than delta_s before the end
/// get no pair.
std::vector<std::pair<std::size_t, std::size_t>> pairsOverTime(const std::vector<double>& stamps_s,
                                                               double delta_s);

/// One frame's error, both trajectories taken relative to their first pose (the start camera
/// frame S): T_S_C = T_W_C0^-1 T_W_C.
struct FrameError {
  Eigen::Vector3d rot_err_deg;    ///< rotation vector of R_gt^T R_est (about camera x, y, z), deg
  Eigen::Vector3d pos_err_mm;     ///< t_est - t_gt in the start camera frame, mm
  Eigen::Vector3d pos_est_mm;     ///< t_est in the start camera frame (x right, y down, z ahead)
  Eigen::Vector3d pos_gt_mm;      ///< t_gt in the start camera frame, mm
  Eigen::Vector3d euler_est_deg;  ///< thesis angles (pitch, yaw, roll) of the estimate, deg
  Eigen::Vector3d euler_gt_deg;   ///< thesis angles of the ground truth, deg
  Eigen::Vector3d euler_err_deg;  ///< euler_est - euler_gt, wrapped to (-180, 180], deg
};

/// Per-frame errors of associated pose pairs, relative to the first pair. Throws
/// std::invalid_argument for lists of different length or no poses.
std::vector<FrameError> frameErrors(const std::vector<Eigen::Isometry3d>& est_T_W_C,
                                    const std::vector<Eigen::Isometry3d>& gt_T_W_C);

/// The thesis's table style: maximum absolute error per axis over the run.
struct ThesisErrors {
  std::size_t frames = 0;
  Eigen::Vector3d max_err_deg = Eigen::Vector3d::Zero();  ///< max |rot_err_deg| per axis (x, y, z)
  Eigen::Vector3d max_err_mm = Eigen::Vector3d::Zero();   ///< max |pos_err_mm| per axis
  Eigen::Vector3d max_euler_err_deg = Eigen::Vector3d::Zero();  ///< max |euler_err_deg| per axis
  double end_drift_mm = 0.0;                                    ///< |pos_err_mm| of the last frame
};

/// Thesis-style errors (pitch/yaw/roll and x/y/z maxima, end drift). Throws std::invalid_argument
/// for lists of different length or fewer than 2 poses.
ThesisErrors computeThesisErrors(const std::vector<Eigen::Isometry3d>& est_T_W_C,
                                 const std::vector<Eigen::Isometry3d>& gt_T_W_C);

/// Everything for an estimated trajectory against ground truth.
struct TrajectoryEvaluation {
  AteRpe standard;
  RelativeError rpe_1s;  ///< RPE over 1 s (TUM's second standard RPE)
  ThesisErrors thesis;
  std::size_t est_poses = 0;  ///< poses in the estimate before association
};

/// Associates est with gt by nearest stamp (max_gap_s, TUM: 0.02 s), then computes both metric
/// sets. Throws std::invalid_argument when fewer than 2 poses associate.
TrajectoryEvaluation evaluateTrajectory(const Trajectory& est, const Trajectory& gt,
                                        double max_gap_s = 0.02);

/// The two result lines in the checkers' format:
/// "frames=N ate_rmse_m=X rpe_1f_m=Y" and
/// "frames=N max_err_deg=a,b,c max_err_mm=x,y,z end_drift_mm=d".
std::string formatEvaluation(const TrajectoryEvaluation& evaluation);

// ---- a run against its references (evaluate_bag and the graph's evaluator share this) ---------

/// A trajectory a run is scored against.
struct Reference {
  std::string name;    ///< what and where from, e.g. "ground truth /rig_sim/camera_pose"
  bool exact = false;  ///< ground truth (true), or a measurement with errors of its own (sensors)
  Trajectory poses;    ///< T_W_C of the optical frame, any world frame
};

/// A run scored against one reference.
struct ReferenceScore {
  std::string name;
  bool exact = false;
  std::size_t reference_poses = 0;
  std::vector<std::size_t> est_index;  ///< index into the estimate of each associated frame
  std::vector<double> stamps_s;        ///< stamps of the associated frames
  std::vector<FrameError> frames;      ///< per associated frame, relative to the first one
  std::optional<TrajectoryEvaluation> evaluation;  ///< empty when fewer than 2 frames associate
  std::string problem;                             ///< why there is no evaluation
};

/// Scores `est` against one reference (nearest stamp within max_gap_s; non-finite poses left
/// out). Never throws for too few associated frames: the score then says why. Thread-safe.
ReferenceScore scoreAgainst(const Trajectory& est, const Reference& reference,
                            double max_gap_s = 0.02);

/// Latency scan (thesis 5.4.1): the sensor stream shifted by -N..+N of its sample intervals
/// against a trajectory, and the shift that fits best.
struct LatencyScan {
  double period_s = 0.0;            ///< one step of shift: the sensor stream's median interval
  std::vector<int> shifts;          ///< -N..N; positive = the sensors lag the camera
  std::vector<double> rms_rot_deg;  ///< RMS angle of the rotation error, per shift
  std::vector<double> rms_pos_mm;   ///< RMS position error, per shift
  std::size_t frames = 0;           ///< frames scored at every shift
  int best_rot_shift = 0, best_pos_shift = 0;
  int best_shift = 0;     ///< the minimiser of `criterion`
  std::string criterion;  ///< "rotation" (the sensors turned > 1 deg) or "position"
  /// Whether a minimum means a latency: how much the curve rises from it two steps to either
  /// side (the smaller of the two) against the curve's jitter (robust sigma from its third
  /// differences). Resolved when the rise exceeds 3x the jitter and the minimum lies at least two
  /// steps inside the scan; never for scans of fewer than +-4 steps.
  double rise_rot_deg = 0.0, rise_pos_mm = 0.0;
  double jitter_rot_deg = 0.0, jitter_pos_mm = 0.0;
  bool rot_resolved = false, pos_resolved = false;
  bool resolved = false;  ///< that of `criterion`
  std::string verdict;    ///< why `best_shift` is, or is not, a latency: one line
};

/// Shifts the sensor stream by k = -max_shift..max_shift intervals against `trajectory` (the
/// tracked one, or ground truth to see the sensors' own latency), scoring the frames all shifts
/// cover. Throws std::invalid_argument without a sensor stream, for max_shift < 0, or when fewer
/// than 2 frames are covered. Thread-safe.
LatencyScan scanSensorLatency(const Trajectory& trajectory, const RigSensorStreams& streams,
                              const RigGeometry& geometry, int max_shift);

/// What a run can be scored against; any part may be empty.
struct RunReferences {
  Trajectory ground_truth;        ///< T_W_C of the optical frame
  std::string ground_truth_name;  ///< e.g. the topic it came from
  RigSensorStreams sensors;       ///< the rig's own sensors
  RigGeometry geometry;           ///< to turn the sensors into camera poses
};

struct RunEvaluationOptions {
  double max_gap_s = 0.02;  ///< association of estimate and ground truth stamps, s
  int latency_scan = 0;     ///< latency scan over +-N sensor intervals (0 = none)
};

/// A run against every reference it has.
struct RunEvaluation {
  /// Ground truth first (when given), then the rig sensors (when given).
  std::vector<ReferenceScore> scores;
  /// Index into `scores` of the thesis-style table and the summary line: ground truth when it
  /// scores, else the sensors; -1 when nothing scores.
  int table = -1;
  std::optional<ReferenceScore> sensors_vs_truth;  ///< the sensor reference against ground truth
  std::optional<LatencyScan> latency;              ///< sensors shifted against the estimate
  std::optional<LatencyScan> sensor_latency;       ///< sensors shifted against ground truth
  std::vector<std::string> notes;                  ///< what could not be evaluated, and why
};

/// Scores a tracked trajectory against the ground truth and the rig's sensors (camera poses
/// through the rig's kinematics at the tracked frames' stamps), with the sensors' own error
/// against ground truth and the latency scans when asked. The one function behind every
/// thesis-style table (offline evaluate_bag and the graph's evaluator). Never throws for
/// missing references (see notes); throws std::invalid_argument for malformed sensor streams
/// or geometry. Thread-safe.
RunEvaluation evaluateRun(const Trajectory& est, const RunReferences& references,
                          const RunEvaluationOptions& options = RunEvaluationOptions{});

/// The thesis-style table (max |error| per axis: angles in degrees, positions in mm; one row per
/// reference, the row the summary uses marked), ATE/RPE/end drift per reference, the sensors
/// against ground truth, the latency scans and the notes, as printable lines.
std::string formatRunEvaluation(const RunEvaluation& evaluation);

/// "ate_rmse_m=X max_err_deg=a,b,c max_err_mm=x,y,z" of the table's reference ("nan" fields when
/// nothing scores): the tail of the tools' final line.
std::string formatSummaryFields(const RunEvaluation& evaluation);

// ---- link timing (thesis 4.2.3: the clocks Time1..Time6 along the rig's links) -----------------

/// One frame on a link: the sender's clock when it was sent and the receiver's when it arrived
/// (unsynchronised clocks, each counting from its own start).
struct LinkClockSample {
  double sender_s = 0.0;
  double receiver_s = 0.0;
};

/// Latency and jitter of one link. The clocks are not synchronised, so the fixed part of the
/// delay cannot be observed: latency is measured above the fastest frame, after the clocks'
/// relative drift (a straight-line fit of receiver - sender) is taken out.
struct LinkTiming {
  std::string name;  ///< e.g. "TrackDRV -> TrackHost (Time1 -> Time2)"
  std::size_t frames = 0;
  double sender_period_ms = 0.0;       ///< median sender interval
  double receiver_period_ms = 0.0;     ///< median receiver interval
  double receiver_period_sd_ms = 0.0;  ///< standard deviation of the receiver interval
  double drift_ms_per_s = 0.0;         ///< slope of receiver - sender against the sender clock
  double latency_mean_ms = 0.0, latency_p95_ms = 0.0, latency_max_ms = 0.0;  ///< above fastest
  double jitter_ms = 0.0;  ///< standard deviation of the delay
  std::size_t gaps = 0;    ///< sender intervals over 1.5 periods (frames not received)
};

/// Summary of a link's clock samples (in arrival order). Fewer than 3 samples give frames only.
/// Thread-safe.
LinkTiming summariseLinkTiming(const std::string& name,
                               const std::vector<LinkClockSample>& samples);

/// A table of links, one line each.
std::string formatLinkTiming(const std::vector<LinkTiming>& links);

}  // namespace depth_track
