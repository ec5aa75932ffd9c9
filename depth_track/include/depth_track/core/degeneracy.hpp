#pragma once
/// Degeneracy of a rigid registration: eigen-analysis of its 6x6 normal equations. A view that
/// holds too little geometry (one wall, a wall with parallel cabinet faces, a bare corridor)
/// leaves directions of the pose that the residuals do not change; a plain solve slides along
/// them on noise. The analysis finds them, the constrained solve keeps the prior (the initial
/// guess: the motion prediction) there and registers the rest, and the covariance says how
/// well each direction is known. ROS-free core; all functions thread-safe.
///
/// Parameterisation: the increment is [omega; u], a rotation omega (rad) about the camera centre
/// of the current estimate and the displacement u (m) of that centre, both in the reference
/// frame; so along a direction the view cannot fix, the camera centre keeps exactly the motion
/// the prior gave it. Eigen-analysis in scaled coordinates [L omega; u], L the RMS distance of
/// the paired points from the camera centre, so rotation and translation are comparable.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "depth_track/core/se3.hpp"

namespace depth_track {

/// How the registration's step along each eigen-direction is weighed against the prior (the
/// initial guess). The normals' noise alone gives every direction some apparent information,
/// however many pairs there are: a direction's noise floor is sigma_n^2 times the mean over the
/// pairs of |w_perp|^2, w = omega x (p - c) / L + u for the unit direction d = [L omega; u] and
/// w_perp its part across the pair's normal (what a random tilt of variance sigma_n^2 per axis
/// adds to (J . d)^2); sigma_n^2 is half the mean of 1 - cos between paired normals (two
/// independently noisy normals). A wall's in-plane translation has floor sigma_n^2, the roll
/// about its normal (r / L)^2 sigma_n^2. Only the information above noise_margin times the floor
/// is measured. Where it outweighs the prior's (1 / prior_sigma^2) the direction is registered;
/// where it does not, the direction is held (degenerate) and the step along it is only the
/// measurement's information-weighted share, so the better the prior, the more of a weak
/// direction it keeps.
struct DegeneracyConfig {
  double noise_margin = 3.0;  ///< 0 switches the analysis off (plain solve)
  /// Hysteresis for a sequence of frames (CellOdometry): after a frame that held directions,
  /// the next one registers a direction only above this many times its floor (>= noise_margin;
  /// equal = no hysteresis). Near the margin the gain switches a direction on and off from frame
  /// to frame, and each single frame that releases it takes a whole biased step.
  double release_margin = 6.0;
  /// Standard deviation of the prior per frame along a direction (metres; at the length L for
  /// rotations) when the caller does not know it better (CellOdometry measures it from how well
  /// the recent motion fits a constant velocity).
  double prior_sigma_m = 0.002;

  std::vector<std::string> validate() const;
};

/// Eigen-structure of one registration's normal equations.
struct DegeneracyAnalysis {
  double length_scale_m = 1.0;  ///< L, metres
  double weight_sum = 0.0;      ///< sum of the residual weights
  /// Residual variance of a pair of weight 1, m^2: the mean squared residual, each scaled by
  /// its depth-noise factor (RegistrationConfig::noise_weighting; without it the plain mean).
  /// The gains and the pose covariance read the information against it. 0 = not computed.
  double residual_var_m2 = 0.0;
  /// Eigenvalues of S H S / weight_sum (S = diag(1/L, 1/L, 1/L, 1, 1, 1)), ascending, and their
  /// eigenvectors in scaled coordinates [L omega; u] (columns). A translation direction's value
  /// is the mean squared normal component along it: about 1/3 for normals spread evenly.
  Vector6d eigenvalues = Vector6d::Zero();
  Matrix6d eigenvectors = Matrix6d::Identity();
  Vector6d noise_floor = Vector6d::Zero();  ///< per eigenvector (see DegeneracyConfig); 0 = unknown
  /// Share of the registration's step taken along each eigenvector: 1 = registered, below 1/2 =
  /// held (mostly the prior).
  Vector6d gain = Vector6d::Ones();
  int degenerate = 0;  ///< held directions (gain < 1/2): the view does not fix them
  /// Unit direction [omega (rad); u (m)] of the weakest eigenvector (rotation part divided by L,
  /// then normalised), for reporting.
  Vector6d weakest = Vector6d::Zero();
};

/// Eigen-analysis of H = J^T W J in [omega; u] (see the file comment) of a registration with
/// weight sum `weight_sum` and points at RMS distance `length_scale_m` from the camera centre.
/// Every gain is 1 until applyNoiseFloors().
DegeneracyAnalysis analyseNormalEquations(const Matrix6d& H, double weight_sum,
                                          double length_scale_m);

/// Weighted moments of a registration's levers (pair point minus camera centre, metres), summed
/// with the same weights as its normal matrix: with that matrix they give the noise floors in
/// closed form (noiseFloors), without a second pass over the pairs.
struct LeverMoments {
  double wsum = 0.0;                                   ///< sum w
  Eigen::Vector3d s1 = Eigen::Vector3d::Zero();        ///< sum w l
  Eigen::Matrix3d s2 = Eigen::Matrix3d::Zero();        ///< sum w l l^T
  void add(const Eigen::Vector3d& lever, double w) {
    wsum += w;
    s1 += w * lever;
    s2 += w * lever * lever.transpose();
  }
};

/// Per eigenvector e of `a`: sigma_n2 (variance of a normal's in-plane component) times the
/// weighted mean over the pairs of |v_perp|^2, v = omega x l + u the displacement the mode gives
/// a pair's point and v_perp its part in the pair's plane. With A = [-[l]x / L, I] (v = A e in
/// the analysis's scaled coordinates) that sum is e^T (sum w A^T A - S H S) e, since A^T n is
/// the pair's scaled Jacobian row: `H` is the unscaled normal matrix in [omega; u] the analysis
/// was made from and `m` the levers' moments under the same weights. Zero when no weight.
Vector6d noiseFloors(const DegeneracyAnalysis& a, const Matrix6d& H, const LeverMoments& m,
                     double sigma_n2);

/// Sets the analysis's noise floors and the gains and degenerate count that follow from them,
/// for residual variance sigma_e2_m2 per pair and the config's prior.
void applyNoiseFloors(DegeneracyAnalysis* a, const Vector6d& floors, double sigma_e2_m2,
                      const DegeneracyConfig& config);

/// Solves H x = -g along each eigenvector scaled by its gain (the plain solve when every gain is
/// 1; directions without any information get no step).
Vector6d solveConstrained(const DegeneracyAnalysis& analysis, const Vector6d& g);

/// The pose T_reg moved towards T_prior along the held directions (by 1 - gain along each): both
/// T_ref_cur of one reference frame, `analysis` the registration's at T_reg. Each held mode
/// takes the prior of its dominant kind, rotation or translation (see the definition). Returns
/// T_reg when nothing is held.
Eigen::Isometry3d withPriorAlongDegenerate(const DegeneracyAnalysis& analysis,
                                           const Eigen::Isometry3d& T_reg,
                                           const Eigen::Isometry3d& T_prior);

/// Covariance of [omega; u] for residual variance sigma2_m2: sigma2 / (lambda wsum) along each
/// registered eigenvector, config.prior_sigma_m^2 along held ones (mixed by the gain).
Matrix6d registrationCovariance(const DegeneracyAnalysis& analysis, double sigma2_m2,
                                const DegeneracyConfig& config);

/// Variance (m^2 in the scaled coordinates [L omega; u]) standing for "not measured" in
/// measurementCovariance: a metre, against the millimetres of a measured direction. Not larger,
/// since an eigenvector's last digits would carry it into the measured directions.
constexpr double kUnmeasuredVariance = 1.0;

/// Covariance of what the view alone measured of [omega; u]: sigma2 / (lambda wsum) / gain along
/// each eigenvector, kUnmeasuredVariance along one whose gain is zero or whose eigenvalue is
/// below firm_information times its noise floor. A held direction's pose is the motion prior's,
/// so a filter that made that prior must not take it back as a measurement
/// (registrationCovariance puts the prior's variance there instead); a weak one, in a view
/// turning degenerate, slides further than sigma2 says (CellOdometryConfig::
/// velocity_firm_information, whose threshold this is).
Matrix6d measurementCovariance(const DegeneracyAnalysis& analysis, double sigma2_m2,
                               double firm_information);

}  // namespace depth_track
