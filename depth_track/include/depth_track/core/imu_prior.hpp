#pragma once
/// An inertial motion prior for the tracker (ROS-free core): the camera's motion between two
/// frames as a camera-mounted IMU (a D435i's or D455's BMI055 / BMI085, an external one) sees it,
/// for Tracker::track's `prior_T_Cprev_Ccur`. The gyro turns the last frame's orientation, the
/// accelerometer (gravity taken out) moves its velocity and position; the registration then fixes
/// what the view fixes, and a direction the view does not fix keeps the IMU's motion. Each tracked
/// frame pulls the velocity towards the motion the depth measured, so the accelerometer's bias
/// and the gravity estimate only act over the stretches the view cannot fix.
#include <Eigen/Geometry>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/param_table.hpp"

namespace depth_track {

/// The covariance of what a tracked frame's registration measured of its camera pose, in the
/// world frame, [rotation (rad); position (m)]: FrameStatus::measurement_covariance turned from
/// the reference frame into the world. A held or weak direction reads kUnmeasuredVariance;
/// nullopt for a frame not tracked.
std::optional<Eigen::Matrix<double, 6, 6>> trackedPoseCovariance(const FrameStatus& status);

/// One IMU reading in the IMU's own frame. The accelerometer reads specific force: acceleration
/// minus gravity, so +9.81 m/s^2 upwards when at rest. A reading holds from its stamp to the
/// next one's (zero-order hold).
struct ImuSample {
  double stamp_s = 0.0;
  Eigen::Vector3d gyro_rad_s = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_m_s2 = Eigen::Vector3d::Zero();
};

struct ImuPriorConfig {
  /// Pose of the IMU in the camera's optical frame (p_C = T_C_I * p_I): a RealSense's
  /// camera_depth_optical_frame <- camera_imu_optical_frame from tf.
  Eigen::Isometry3d T_C_I = Eigen::Isometry3d::Identity();
  /// Gravity is the mean specific force over this window ending at the first frame, and the
  /// gyro's bias its mean rate, during which the camera must be still (seconds).
  double init_window_s = 0.3;
  /// Largest spread (RMS about the mean, m/s^2) of the readings in that window: more, and the
  /// camera was not still, and the prior waits for a later frame to start from.
  double still_spread_m_s2 = 0.3;
  /// The mean's magnitude must lie within this fraction of standard gravity (9.80665 m/s^2),
  /// else the readings are not m/s^2 specific force (units, a g-scaled driver) and are refused.
  double gravity_tolerance = 0.1;
  /// The velocity is a Kalman filter over the IMU point's position and velocity, the error of the
  /// gravity taken at the start (world frame) and the accelerometer's bias (IMU frame), with the
  /// tracked positions as measurements. Accelerometer white noise, m/s^2/sqrt(Hz) (BMI055: 150 ug/sqrt(Hz)).
  double accel_noise_density = 0.0015;
  /// Accelerometer bias expected, m/s^2 per axis (standard deviation): at the start it is taken
  /// in with gravity, and as the camera turns the two part, and the tracked positions tell them
  /// apart.
  double accel_bias_m_s2 = 0.1;
  /// Random walk of the bias and of the gravity error, m/s^2 per sqrt(s).
  double accel_bias_walk = 0.002;
  /// Acceleration the filter does not model, m/s^2 over each frame interval: the tracked
  /// orientation's tilt turning gravity into the horizontal (0.1 deg: 0.017 m/s^2), the readings'
  /// timing. It keeps the filter from trusting its velocity beyond what the tracked positions say.
  double unmodelled_accel_m_s2 = 0.1;
  /// An interval's mean acceleration is taken as smaller by this many standard deviations of the
  /// filter's own uncertainty about the accelerometer's error (bias and gravity; 0 = off):
  /// what it cannot tell from a constant velocity does not build up over a view that cannot
  /// correct it. A start from rest, a braking robot read far above it.
  double accel_significance = 3.0;
  /// The registration starts from the last frame's motion, not from the IMU's guess, while the
  /// two put the camera within this many standard deviations of the guess's displacement (the
  /// filter's velocity uncertainty over the interval) of each other (0 = always the IMU's
  /// guess): a constant motion is then what the IMU reads too, and the last frame's motion,
  /// which follows what the view fixed, is the better start where it fixes little. A start or
  /// a stop reads far above it.
  double guess_gate = 3.0;
  /// Standard deviation added to a tracked position's own (the registration's covariance, which
  /// the basin probe widens along a direction it could not confirm), m.
  double position_floor_m = 0.002;
  /// The gyro's bias starts as its mean over the still window, uncertain by the readings' spread
  /// there (a swaying start: the sway's mean rate is no bias); each tracked frame's rotation
  /// then corrects it, the registration's rotation covariance plus this floor (rad per frame)
  /// as the measurement's noise.
  double rotation_floor_rad = 0.0005;
  /// Random walk of the gyro's bias, rad/s per sqrt(s).
  double gyro_bias_walk = 0.0001;
  /// Longest interval without a reading that is integrated across (seconds); a frame whose span
  /// has a longer gap gets no prior.
  double max_gap_s = 0.05;

  std::vector<std::string> validate() const;
};

/// The filter's settings a user tunes, as one table (param_table.hpp): the ROS parameters
/// `imu_<name>` of the registration nodelet and the tools' `--imu-<name>` options are made from
/// it. T_C_I (from tf or the bag), the start's still test and max_gap_s are not in it.
using ImuParamSpec = BasicParamSpec<ImuPriorConfig>;
const std::vector<ImuParamSpec>& imuPriorParams();

class ImuMotionPrior {
 public:
  /// Throws std::invalid_argument listing the config's problems.
  explicit ImuMotionPrior(const ImuPriorConfig& config);

  /// Adds a reading. Throws std::invalid_argument for a non-finite value or a stamp not after
  /// the last reading's; the prior is then unchanged.
  void add(const ImuSample& sample);

  /// Adds readings[next], readings[next + 1], ... up to those stamped stamp_s and returns the
  /// index of the first left (a recorded stream fed frame by frame). Throws as add().
  std::size_t addUpTo(const std::vector<ImuSample>& readings, std::size_t next, double stamp_s);

  /// The camera's motion T_Cprev_Ccur from the last frame given to update() to stamp_s; nullopt
  /// before the prior has started (see reason()), for a stamp not after that frame's, or when the
  /// readings do not cover the interval (none at or before its start, none within max_gap_s of
  /// its end, or a gap longer than max_gap_s inside it). Const: the state moves in update().
  std::optional<Eigen::Isometry3d> predict(double stamp_s) const;

  /// predict() and, for the tracker's held directions (Tracker::track's `hold`), the camera's
  /// displacement from the accelerations the soft threshold let through, summed since the start.
  struct Guess {
    Eigen::Isometry3d T_Cprev_Ccur;
    InertialHold hold;
  };
  std::optional<Guess> guess(double stamp_s) const;

  /// A frame's pose as the tracker left it (T_W_C) and, when it was tracked, the covariance of
  /// its pose in the world frame ([rotation; position], trackedPoseCovariance of its FrameStatus);
  /// nullopt: not tracked. The first call starts the prior when the readings before it show a still camera
  /// (gravity from their mean, velocity zero); until then it returns false and reason() says
  /// why. Later calls carry the filter across the interval and, for a tracked frame, correct
  /// it by the tracked position. Returns whether the prior has started.
  bool update(double stamp_s, const Eigen::Isometry3d& T_W_C,
              const std::optional<Eigen::Matrix<double, 6, 6>>& pose_cov_W);

  bool started() const { return started_; }
  /// Why the prior has not started, or "" once it has.
  const std::string& reason() const { return reason_; }
  /// Gravity in the tracker's world frame (m/s^2), known once started.
  const Eigen::Vector3d& gravity() const { return g_W_; }
  /// Velocity of the IMU in the world frame at the last frame (m/s).
  Eigen::Vector3d velocity() const { return x_.segment<3>(3); }
  /// The gravity error as estimated, world frame (m/s^2).
  Eigen::Vector3d gravityError() const { return x_.segment<3>(6); }
  /// The gyro's bias as estimated: its mean over the still start, then corrected by the tracked
  /// rotations (rad/s, IMU frame).
  const Eigen::Vector3d& gyroBias() const { return gyro_bias_; }
  /// The accelerometer's bias as estimated, IMU frame (m/s^2).
  Eigen::Vector3d accelBias() const { return x_.tail<3>(); }
  std::size_t samples() const { return samples_.size(); }
  const ImuPriorConfig& config() const { return config_; }

 private:
  using Vector12d = Eigen::Matrix<double, 12, 1>;
  using Matrix12d = Eigen::Matrix<double, 12, 12>;
  struct Delta {
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  // R_I0_I1
    Eigen::Vector3d v = Eigen::Vector3d::Zero();      // velocity change in I0, gravity not in
    Eigen::Vector3d p = Eigen::Vector3d::Zero();      // position change in I0, nor v0 * dt
    Eigen::Matrix3d Jv = Eigen::Matrix3d::Zero();     // d v / d bias
    Eigen::Matrix3d Jp = Eigen::Matrix3d::Zero();     // d p / d bias
    Eigen::Vector3d w0 = Eigen::Vector3d::Zero();     // rate at t0, I0 (gyro bias taken off)
    Eigen::Vector3d w1 = Eigen::Vector3d::Zero();     // rate at t1, I1
  };
  /// The readings over [t0, t1], less the accelerometer bias `bias`.
  std::optional<Delta> integrate(double t0, double t1, const Eigen::Vector3d& bias) const;
  struct Propagated {
    Eigen::Isometry3d T_W_C;  // position from the filter's
    Vector12d x;
    Matrix12d P;
    // The camera's significant (past the soft threshold) velocity change and displacement over
    // the interval, world frame.
    Eigen::Vector3d significant_dv, significant_dp;
  };
  /// The filter and the camera pose carried from the last frame to stamp_s.
  std::optional<Propagated> propagate(double stamp_s) const;
  bool start(double stamp_s, const Eigen::Isometry3d& T_W_C);

  ImuPriorConfig config_;
  std::deque<ImuSample> samples_;
  bool started_ = false;
  std::string reason_ = "no frame yet";
  Eigen::Vector3d g_W_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_bias_ = Eigen::Vector3d::Zero();
  Eigen::Matrix3d gyro_bias_P_ = Eigen::Matrix3d::Zero();  // its covariance
  // The IMU point's position and velocity (world), gravity error (world), accelerometer bias (IMU).
  Vector12d x_ = Vector12d::Zero();
  Matrix12d P_ = Matrix12d::Zero();
  Eigen::Isometry3d last_T_W_C_ = Eigen::Isometry3d::Identity();
  double last_stamp_s_ = 0.0;
  // The significant velocity changes and the displacement they made, summed since the start up
  // to the last frame (world, m/s and m).
  Eigen::Vector3d significant_v_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d significant_d_ = Eigen::Vector3d::Zero();
};

}  // namespace depth_track
