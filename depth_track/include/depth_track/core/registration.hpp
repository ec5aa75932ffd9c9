#pragma once
/// One-to-one cell pair matching and rigid registration of cell clouds: point-to-point (SVD),
/// point-to-plane (6x6 normal equations) and Cell Search (point-to-plane with pairs gated by the
/// Förstner–Moonen covariance metric). ROS-free core.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/degeneracy.hpp"
#include "depth_track/core/depth_noise.hpp"
#include "depth_track/core/se3.hpp"

namespace depth_track {

enum class RegistrationMethod { kPointToPoint, kPointToPlane, kCellSearch };

/// "p2p" | "p2l" | "cell_search" -> method; throws std::invalid_argument naming the bad value.
RegistrationMethod parseRegistrationMethod(const std::string& name);
std::string toString(RegistrationMethod method);

/// Pair-matching thresholds (thesis §3.8) and the search window.
struct MatchConfig {
  double dist_min_m = 0.05;  ///< max distance between paired mean vertices, metres (DistMin)
  double initial_dist_m =
      0.2;                ///< first-iteration gate, halved per iteration down to dist_min_m, m
  double cos_min = 0.99;  ///< min cosine between paired normals (CosMin); cos(8.1 deg)
  double normal_weight_m = 0.05;  ///< metres per unit of normal difference in the 6-vector distance
  int search_radius_cells = 1;    ///< image-grid window (cells) around the predicted position
};

/// Registration configuration (thesis fig. 5.1 names in brackets).
struct RegistrationConfig {
  RegistrationMethod method = RegistrationMethod::kPointToPlane;  ///< (RegMethod)
  MatchConfig match;
  double fm_thresh = 1.0;       ///< Förstner–Moonen gate for Cell Search (FMThresh)
  double fm_eps_m2 = 1e-6;      ///< covariance regulariser, = PcaConfig::min_eigenvalue_m2
  int max_iterations = 30;      ///< ICP iterations (re-matching after each update)
  int patience = 3;             ///< stop after this many iterations without a lower error
  double tolerance_m = 2e-4;    ///< stop when an update moves points less than this, metres
  double tolerance_rad = 2e-4;  ///< ... and rotates less than this, radians
  bool robust = true;           ///< Huber weighting of residuals
  double huber_delta_m = 0.01;  ///< Huber threshold, metres
  /// Depth-noise weighting of point-to-plane pairs (P2L, Cell Search): with the sensor's sigma(z)
  /// (`noise`; auto_noise measures it on the first frames), a pair whose reference cell lies
  /// deeper than noise_ref_depth_m weighs (sigma(z_ref) / sigma(z))^2, its inverse variance, and
  /// its Huber threshold grows by sigma(z) / sigma(z_ref); nearer pairs weigh 1. The gains of
  /// the degeneracy analysis and the pose covariance read the information against the residual
  /// variance of a pair of weight 1 (DegeneracyAnalysis::residual_var_m2). No noise model or
  /// noise_ref_depth_m = 0: every pair alike.
  /// On by default since 2026-12-04: on real Kinect depth the far floor's errors, which move with
  /// the camera, otherwise pull the estimate back to the keyframe (TUM fr3/teddy 0.064 -> 0.008 m,
  /// docs/tracking.md "Depth-noise weighting").
  bool noise_weighting = true;
  DepthNoiseModel noise;
  /// Metres. Not the scene's depth: nearer pairs are not weighed up, as the near range of a
  /// stereo or structured-light sensor is not as much better as the quadratic model says.
  double noise_ref_depth_m = 1.0;
  /// The smallest weight factor a pair is given (1/32: no pair counts less than one whose noise
  /// is 5.7 times the reference depth's). The inverse variance alone weighs a D435's pairs at
  /// 5 m 1/625 of those at 1 m; what the deep pairs alone fix (the motion along a corridor, seen
  /// on its door frames and far end) then loses to the near pairs' systematic normal tilts,
  /// which pull the estimate to the guess and which the degeneracy floors do not see: the
  /// rendered Hall1 corridor with D435 noise stood still while the camera walked 4.8 m
  /// (docs/tracking.md "The weighting's floor"). 0 = the inverse variance unbounded.
  double noise_weighting_min = 0.03125;
  bool overlap_mask = true;     ///< drop cells predicted to fall outside the other view
  int min_matches = 30;         ///< fewer pairs than this = failure
  /// Directions of the pose the pairs do not constrain keep the initial guess (P2L, Cell Search).
  DegeneracyConfig degeneracy;

  /// Every problem at once (empty = valid).
  std::vector<std::string> validate() const;
};

/// One matching pass: index pairs (reference cell, current cell) and counters.
struct MatchResult {
  std::vector<std::pair<int, int>>
      pairs;                  ///< (index into reference.cells, index into current.cells)
  int candidates = 0;         ///< reference cells that had at least one candidate within gates
  int duplicates_broken = 0;  ///< candidates lost to a better claim on the same current cell
  int fm_rejected = 0;        ///< pairs removed by the Förstner–Moonen gate (Cell Search)
};

/// Result of registering `current` onto `reference`.
struct RegistrationResult {
  Eigen::Isometry3d T_ref_cur =
      Eigen::Isometry3d::Identity();  ///< maps current-frame points into the reference frame
  bool converged = false;
  int iterations = 0;
  int candidates = 0;
  int matches = 0;     ///< pairs used in the last iteration
  int fm_matches = 0;  ///< pairs that passed the FM gate (Cell Search), else = matches
  int duplicates_broken = 0;
  double error_rms_m = 0.0;  ///< residual RMS of the last iteration, metres
  /// Normal-equation matrix J^T W J of the registration (Huber weights W, no noise scaling) at
  /// the pairs of the iteration whose pose is returned (or of the last step taken before it):
  /// point-to-plane residuals for P2L and Cell Search, point-to-point for P2P. The increment is
  /// [omega (rad); v (m)] applied on the left, T_ref_cur <- exp(omega, v) T_ref_cur, in the
  /// reference camera frame. sigma^2 H^-1 is the pose covariance for residual noise sigma; a
  /// small eigenvalue is a direction the scene does not constrain. Zero when no step was solved.
  Matrix6d normal_matrix = Matrix6d::Zero();
  /// Eigen-analysis of the same normal equations (P2L, Cell Search): the directions the view did
  /// not fix kept the guess (DegeneracyConfig).
  DegeneracyAnalysis degeneracy;
  std::string failure;  ///< empty when the registration is usable
};

/// The reference cells as the association reads them: means and normals packed contiguously and
/// the grid index padded by the search radius, so the search window needs no bounds checks.
/// Depends only on the reference and the radius: a tracker that keeps its keyframe keeps the
/// grid (CellOdometry), instead of rebuilding it on every registration. Holds the address of
/// the reference it was built for, which must outlive it unchanged.
class AssociationGrid {
 public:
  /// Components of the per-slot planes (plane()).
  enum Component { kMeanX, kMeanY, kMeanZ, kNormalX, kNormalY, kNormalZ };
  /// Lanes read past a window row's last slot (the association scores slots four at a time).
  static constexpr int kLanePad = 3;
  AssociationGrid() = default;
  AssociationGrid(const CellCloud& reference, int radius_cells) { build(reference, radius_cells); }
  /// (Re)builds for `reference` with a window of radius_cells (reusing the buffers).
  void build(const CellCloud& reference, int radius_cells);
  /// True when built for this very cloud (same address and cell count) and radius.
  bool isFor(const CellCloud& reference, int radius_cells) const {
    return reference_ == &reference && pad_ == radius_cells && cells_ == reference.cells.size();
  }
  int pad() const { return pad_; }
  int stride() const { return stride_; }
  const std::vector<int>& index() const { return index_; }  ///< -1 = no reference cell
  /// One component of every slot's reference cell (reference frame), in the layout of index()
  /// and followed by kLanePad unused slots: a slot without a cell has a mean so far away (1e15 m)
  /// that no distance gate passes it, and a zero normal.
  const float* plane(Component k) const { return planes_.data() + k * plane_size_; }

 private:
  const CellCloud* reference_ = nullptr;
  int pad_ = 0, stride_ = 0;
  std::size_t cells_ = 0, plane_size_ = 0;
  std::vector<int> index_;
  std::vector<float> planes_;
};

/// Förstner–Moonen distance between two cells' covariances (same frame): sum of log^2 of the
/// eigenvalues of A^{-1/2} B A^{-1/2}, both regularised by eps_m2 * I as in the PCA reduction
/// (PcaConfig::min_eigenvalue_m2). 0 for identical covariances; symmetric. Thread-safe.
double forstnerMoonen(const Cell& a, const Cell& b, double eps_m2 = PcaConfig{}.min_eigenvalue_m2);

/// The same metric from A's regularised inverse square root and B's regularised covariance.
double forstnerMoonenFromMatrices(const Eigen::Matrix3d& a_inv_sqrt, const Eigen::Matrix3d& b_reg);

/// Closed-form weighted point-to-point alignment (SVD with the reflection check): the rigid T
/// minimising sum w_i |T p_i - q_i|^2. `w` may be empty (all ones). Throws std::invalid_argument
/// for fewer than 3 pairs or mismatched sizes. Thread-safe.
Eigen::Isometry3d alignPointToPoint(const std::vector<Eigen::Vector3d>& p,
                                    const std::vector<Eigen::Vector3d>& q,
                                    const std::vector<double>& w = {});

/// The depth-noise weighting's factor (sigma(z_ref) / sigma(z))^2 of a pair whose reference cell
/// lies at depth z, before the floor RegistrationConfig::noise_weighting_min: 1 when the
/// weighting is off or z is not deeper than noise_ref_depth_m. A registration weighs the pair
/// max(noise_weighting_min, this).
double noiseWeightingFactor(const RegistrationConfig& config, double z);

/// Pairs reference cells with current cells one-to-one, given T_ref_cur. Thread-safe.
MatchResult matchCells(const CellCloud& reference, const CellCloud& current,
                       const PinholeIntrinsics& intrinsics, const Eigen::Isometry3d& T_ref_cur,
                       const RegistrationConfig& config);

/// Iterative registration of `current` onto `reference` from an initial guess T_ref_cur_guess.
/// Thread-safe (no shared state).
RegistrationResult registerCells(const CellCloud& reference, const CellCloud& current,
                                 const PinholeIntrinsics& intrinsics,
                                 const Eigen::Isometry3d& T_ref_cur_guess,
                                 const RegistrationConfig& config);
/// The same with a grid built for `reference` and config.match.search_radius_cells, kept by
/// the caller across registrations against one reference (identical results; throws
/// std::invalid_argument when the grid was built for another cloud or radius). Thread-safe for
/// concurrent calls sharing one const grid.
RegistrationResult registerCells(const CellCloud& reference, const AssociationGrid& grid,
                                 const CellCloud& current, const PinholeIntrinsics& intrinsics,
                                 const Eigen::Isometry3d& T_ref_cur_guess,
                                 const RegistrationConfig& config);

}  // namespace depth_track
