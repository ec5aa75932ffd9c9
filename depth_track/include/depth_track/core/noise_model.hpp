#pragma once
/// The depth sensor's noise as the tracker sees it, estimated from the frames themselves, and the
/// tracker settings that follow from it. A 5 px cell normal is good on an L515 (~4 mm at 3 m)
/// and noise on a D435 (~3 cm at 2.5 m) or a Kinect far away; the edge test, the normal pooling
/// and the gates have to scale with the noise, and no preset per camera can know the scene's
/// depths. ROS-free core.
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/depth_noise.hpp"

namespace depth_track {

/// How the noise is measured.
struct NoiseEstimatorConfig {
  /// Probe reduction: cells of this many pixels per side, each giving the RMS of its pixels along
  /// the normal pooled over its 7x7 neighbours, taken along the viewing ray (divided by |cos
  /// incidence|).
  int probe_cell_size = 8;
  double min_incidence_cos = 0.5;  ///< cells seen more obliquely are left out
  double bin_m = 0.25;             ///< depth bins, metres
  int min_cells_per_bin = 20;      ///< bins with fewer cells are left out of the fit
  /// Per bin the lower quartile of the cells' RMS: curved cells and cells across edges only ever
  /// add to a plane-fit residual, so the low end is the sensor.
  double quantile = 0.25;
  /// A cell counts only inside a plane: at least 6 of its 8 neighbours kept, and every kept
  /// neighbour's mean within this many times the cell's pixel RMS of the cell's plane (0 = no
  /// test). Cells at the image border are left out.
  double planar_tolerance = 3.0;

  std::vector<std::string> validate() const;
};

/// Accumulates plane-fit residuals of probe cells over frames and fits sigma(z) to them. Not
/// thread-safe.
class NoiseEstimator {
 public:
  explicit NoiseEstimator(const NoiseEstimatorConfig& config = NoiseEstimatorConfig{});
  /// Adds one frame (metres, 0 = no return). Throws DepthInputError for a frame whose size does
  /// not match the intrinsics or is not a multiple of the probe cell size.
  void addFrame(const DepthImage& depth, const PinholeIntrinsics& intrinsics);
  /// The fitted model: sigma(z) = const + quad z^2 by non-negative least squares on the bins'
  /// quantiles (relative errors weighted equally). Unknown (all zero) with fewer than two bins.
  DepthNoiseModel model() const;
  /// Depth below which `share` of the probe cells lie, metres (0 when none).
  double depthQuantile(double share) const;
  int cells() const { return static_cast<int>(samples_.size()); }
  /// Share of the probe cells (at least 75 % valid) that miss some pixels: high for stereo
  /// speckle, where the thesis's "any hole prunes the cell" rule would prune most cells.
  double holeShare() const { return probed_ > 0 ? static_cast<double>(holed_) / probed_ : 0.0; }
  /// "sigma(z) = a + b z^2 from N cells in M bins: x mm at 1 m, y mm at 2 m, z mm at 3 m".
  std::string summary() const;

 private:
  struct Sample {
    float z_m, sigma_m;
  };
  bool inPlanarNeighbourhood(const CellCloud& cloud, const Cell& c, float rms_m) const;
  NoiseEstimatorConfig config_;
  std::vector<Sample> samples_;
  long probed_ = 0, holed_ = 0;
};

/// Tracker settings that follow from the noise (TrackerConfig::auto_noise), for a scene whose
/// cells lie at depth z_ref_m or nearer (the tracker uses the 75th percentile of the probe
/// cells' depths).
struct NoiseAdaptation {
  double footprint_noise = 0.0;  ///< kappa = sigma(z_ref) f / z_ref: noise in pixel footprints
  int normal_radius_cells = 1;   ///< pooled normals over (2r+1)^2 cells of pca.cell_size
  /// Neighbours pooled while their mean lies within this distance: 1.5 times the pooled
  /// window's half diagonal at z_ref, at least 0.1 m.
  double normal_merge_dist_m = 0.1;
  double cos_min = 0.99;
  double huber_delta_m = 0.01;
  double max_error_rms_m = 0.02;
  double min_valid_fraction = 1.0;
  std::string summary() const;
};

/// The settings for a sensor with noise `noise` seen at focal length fx (pixels), for cells of
/// cell_size px whose scene lies at z_ref_m or nearer, with `hole_share` of its cells missing
/// some pixels (NoiseEstimator::holeShare). The normals are pooled until the plane fit's angular
/// noise, sqrt(12) kappa / m^2 for a patch m pixels wide (i.i.d. pixel noise), is below 0.013
/// rad: what 5 px cells pooled over 3x3 reach on the L515 (kappa ~0.8) and what the D435 needs
/// (kappa ~4-5 at 2-2.5 m, pooled patches of ~40 px). Thread-safe.
NoiseAdaptation adaptToNoise(const DepthNoiseModel& noise, double fx_px, int cell_size,
                             double z_ref_m, double hole_share);

/// What auto_noise measured on one frame and the settings it takes from it: one value the
/// offline Tracker and the graph's pca_reduce compute by the same call (calibrateNoise) and
/// that the registration nodelet receives whole, so both paths run identical configurations.
struct NoiseCalibration {
  bool measured = false;  ///< false: too few planar cells to tell; the configs stay as given
  double stamp_s = 0.0;   ///< the frame it was measured on, seconds
  DepthNoiseModel noise;
  double z_ref_m = 0.0;  ///< 75th percentile of the probe cells' depths, metres
  NoiseAdaptation adaptation;
  std::string summary;  ///< the estimator's and the adaptation's one-line summaries

  /// Sets the reduction's noise-dependent parameters (edge test's noise term, normal pooling,
  /// min_valid_fraction); nothing when !measured.
  void applyTo(PcaConfig* pca) const;
  /// Sets the odometry's (cos_min, huber_delta, max_error) and its noise model
  /// (applyNoiseModelTo); nothing when !measured.
  void applyTo(CellOdometryConfig* odometry) const;
  /// Sets only the measured sigma(z) where the odometry reads it: the registration's depth-noise
  /// weighting (its reference depth stays the configured noise_ref_depth_m, not z_ref_m) and the
  /// registration model's offset gate; nothing when !measured.
  void applyNoiseModelTo(CellOdometryConfig* odometry) const;
  /// For a runtime reconfiguration from `before` to `*after` (both as configured, without the
  /// calibration): the calibrated value of each of those three that the reconfiguration left as
  /// it was, so a change of one parameter does not undo what auto_noise chose for the others;
  /// the noise model always (applyNoiseModelTo).
  void applyToUnchanged(const CellOdometryConfig& before, CellOdometryConfig* after) const;
};

/// Measures the noise on one depth frame (metres; the depth the cell reducer is given, i.e.
/// after the prefilter) and the settings for cells of cell_size px. Throws DepthInputError for
/// a frame that does not match the intrinsics. Thread-safe.
NoiseCalibration calibrateNoise(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                                int cell_size, double stamp_s);

}  // namespace depth_track
