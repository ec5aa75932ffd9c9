#pragma once
/// PCA cell reduction of a depth frame (thesis section 3.6) and the cell cloud it produces.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/worker_pool.hpp"

namespace depth_track {

/// One grid cell of a depth frame reduced by PCA. All geometry in the camera optical frame (C).
struct Cell {
  int gx = 0, gy = 0;             ///< grid column and row of the cell
  int n_valid = 0;                ///< valid pixels that contributed
  Eigen::Vector3f mean_C;         ///< mean vertex, metres
  Eigen::Vector3f normal_C;       ///< unit normal (smallest eigenvector), facing the camera
  Eigen::Matrix3f cov;            ///< covariance of the cell's vertices, m^2
  Eigen::Vector3f eigenvalues;    ///< ascending, m^2
  Eigen::Matrix3f eigenvectors;   ///< column i belongs to eigenvalues(i); left zero, with
                                  ///< normal_C = the pooled normal, when normals are pooled and
                                  ///< compute_inv_sqrt is off (nothing then reads them)
  Eigen::Matrix3f cov_inv_sqrt;   ///< (cov + eps I)^(-1/2), for the Förstner–Moonen metric, 1/m
  float surface_variation = 0.f;  ///< lambda0 / (lambda0 + lambda1 + lambda2), 0 for a plane
  float det = 0.f;                ///< determinant of cov, m^6
};

/// Cell counts as in the thesis's table 5.1.
struct ReductionStats {
  int total = 0;              ///< cells in the grid
  int retained = 0;           ///< cells kept
  int pruned_invalid = 0;     ///< dropped for missing depth
  int pruned_degenerate = 0;  ///< dropped because the points were collinear / degenerate
  int pruned_edge = 0;        ///< dropped because the cell spans a depth discontinuity
};

/// The reduced frame: kept cells plus a grid lookup (grid_w * grid_h entries, -1 = pruned).
struct CellCloud {
  int cell_size = 0;
  int grid_w = 0, grid_h = 0;
  std::vector<Cell> cells;
  std::vector<int> grid_index;
  ReductionStats stats;
  /// False when the cells' eigenvalues, surface_variation and det were not computed (left 0;
  /// PcaConfig::cell_spectra).
  bool has_spectra = true;
  double stamp_s = 0.0;  ///< time of the depth frame the cells come from, seconds
  std::string frame_id;  ///< optical frame of the camera that saw them (cells are in it)

  /// Index into `cells` of grid cell (gx, gy), or -1 when pruned or outside the grid.
  int cellAt(int gx, int gy) const {
    if (gx < 0 || gy < 0 || gx >= grid_w || gy >= grid_h) return -1;
    return grid_index[static_cast<std::size_t>(gy) * grid_w + gx];
  }
};

/// Configuration of the PCA reduction.
struct PcaConfig {
  int cell_size = 5;                ///< pixels per cell side; one of 2, 4, 5, 8, 10, 16, 32
  double min_valid_fraction = 1.0;  ///< 1.0 = the thesis's rule: any missing pixel prunes the cell
  /// A cell whose neighbouring pixels differ in depth by more than
  /// max(edge_jump_min_m, edge_jump_rel * depth) spans an occluding edge: its "plane" would join
  /// foreground and background, and it moves unlike either, so it is pruned. edge_jump_rel = 0
  /// switches the test off.
  double edge_jump_rel = 0.04;
  double edge_jump_min_m = 0.03;
  /// ... and by more than edge_jump_sigmas times the sensor's depth noise there, sigma(z) =
  /// noise_sigma_const_m + noise_sigma_quad_per_m z^2 (both 0 = not known): on a stereo camera
  /// (3 cm at 2.5 m) neighbouring pixels of one surface differ by more than 10 cm often enough
  /// that the rule above prunes most 8 px cells far away. 7 sigmas of one pixel are 5 of the
  /// difference of two.
  double noise_sigma_const_m = 0.0;
  double noise_sigma_quad_per_m = 0.0;
  double edge_jump_sigmas = 7.0;
  /// Normals from (2r+1)^2 neighbouring cells: r = 0 is the thesis's per-cell normal; r = 1 pools
  /// the 3x3 cells around each cell (those within normal_merge_dist_m of its mean), which makes
  /// normals of noisy sensors (Kinect, D435) good enough that pair offsets along a surface do
  /// not leak into the point-to-plane residual. Mean and covariance stay the cell's own.
  int normal_radius_cells = 1;
  double normal_merge_dist_m = 0.1;
  /// A cell whose pooled patch is thicker along its normal than crease_sigmas times the depth
  /// noise sigma(z) (noise_sigma_*; a patch across a crease between two surfaces, or across a
  /// step) is pooled again over only the neighbours whose means lie within crease_sigmas sigma(z)
  /// of that plane through its own mean: its normal then follows its own surface instead of
  /// leaning across the crease. Pooled across a wall-floor crease, a D435's 45 px patches lean
  /// 20-30 deg along a corridor, and as the crease keeps its place in the image while the camera
  /// moves along it, those cells pulled the rendered Hall1 corridor's estimate back to zero
  /// motion (docs/tracking.md, "Normals across creases"). 0 = off (the default), or no noise
  /// model known. Off by default: at 2 it mends the rendered corridor's seeds 6 and 19 but takes
  /// the Hall1 D435 bag of docs/results.md from 0.0090 to 0.1697 m ATE.
  double crease_sigmas = 0.0;
  /// ... only where normals are pooled over at least this radius (cells): the lean across a
  /// crease grows with the pooled window, and auto_noise pools over 7x7 cells or more only for
  /// stereo-class noise (a D435: 9x9). Pooled again at 3x3 (L515) the normals of a cabinet's
  /// outline on a wall, which pin the slide along the wall, followed the wall: rendered
  /// wall_slide with L515 noise drifted 5.07 / 5.48 mm/s on seeds 7 / 13 (target 5; 2.21 / 2.56
  /// without).
  int crease_min_radius_cells = 3;
  /// Regulariser added to covariances for cov_inv_sqrt, m^2: (1 mm)^2, about the depth noise of a
  /// good sensor, so the Förstner–Moonen metric does not weigh sub-noise thicknesses.
  double min_eigenvalue_m2 = 1e-6;
  /// Fill Cell::cov_inv_sqrt (needed by the Förstner–Moonen gate of Cell Search only).
  bool compute_inv_sqrt = true;
  /// Fill each cell's eigenvalues, surface_variation and det. Registration reads none of them:
  /// the tracker turns this off (TrackerConfig::reducerConfig), and with pooled normals and no
  /// cov_inv_sqrt the planarity test then comes from the covariance's invariants, the 3x3
  /// eigensolver running only for the few cells those leave undecided (the same cells are kept
  /// either way). The fields are then 0 and CellCloud::has_spectra is false; a published cells
  /// cloud computes them from the covariance when it is written.
  bool cell_spectra = true;
  /// Whether reduceToCells fills those fields under this config: cell_spectra on, or the
  /// eigensolver runs for every cell anyway (no pooling, or cov_inv_sqrt asked for).
  bool computesSpectra() const {
    return cell_spectra || normal_radius_cells == 0 || compute_inv_sqrt;
  }

  /// Every problem for frames of width x height pixels (a size that does not tile is named).
  std::vector<std::string> validate(int width, int height) const;
};

/// A cell's spectrum fields: eigenvalues (ascending, m^2), surface_variation and det.
struct CellSpectrum {
  Eigen::Vector3f eigenvalues = Eigen::Vector3f::Zero();
  float surface_variation = 0.f;
  float det = 0.f;
};
/// The fields from the ascending eigenvalues of a cell's covariance (negatives already clamped).
CellSpectrum spectrumFromEigenvalues(const Eigen::Vector3d& lambda);
/// The fields solved from a covariance: for the cells of a cloud reduced without them
/// (CellCloud::has_spectra false). Thread-safe.
CellSpectrum spectrumOf(const Eigen::Matrix3f& cov);

/// Reduces a depth frame to PCA cells. Throws DepthInputError for a frame whose size does not
/// match the intrinsics or a config that does not validate. Thread-safe (no shared state);
/// `threads` > 1 splits rows of cells over TBB workers.
CellCloud reduceToCells(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                        const PcaConfig& config, int threads = 1);
/// As above, rows of cells split over the pool's workers (the same cells for any pool).
/// Thread-safe.
CellCloud reduceToCells(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                        const PcaConfig& config, const WorkerPool& pool);

}  // namespace depth_track
