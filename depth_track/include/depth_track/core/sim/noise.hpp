#pragma once
/// Depth-sensor noise models for rendered frames (ROS-free, library depth_track_sim).
/// Deterministic: the same clean frame, config and seed give the same noisy frame on any thread
/// count (every random draw is a hash of (seed, pixel, purpose)).
#include <cstdint>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

namespace depth_track {
namespace sim {

enum class NoiseModel {
  kNone,  ///< exact depth (no quantisation)
  kL515,  ///< Intel RealSense L515 lidar (thesis ch. 4.1.3-4.1.4)
  kD435,  ///< Intel RealSense D435(i) active stereo (thesis ch. 4.1.3-4.1.4)
};

/// Parses "none", "l515" or "d435"; throws std::invalid_argument naming the text and the
/// accepted names.
NoiseModel parseNoiseModel(const std::string& name);
/// "none", "l515" or "d435".
std::string noiseModelName(NoiseModel model);

/// Noise parameters; use forModel() for the calibrated presets. The order of effects is:
/// lateral jitter (resample a neighbouring pixel), edge bleeding (stereo only), edge drop-outs,
/// Gaussian depth noise, speckle and random drop-outs, range clipping, quantisation.
struct NoiseConfig {
  NoiseModel model = NoiseModel::kNone;
  /// Depth standard deviation sigma(z) = sigma_const_m + sigma_linear * z + sigma_quad_per_m * z^2.
  double sigma_const_m = 0.0;
  double sigma_linear = 0.0;      ///< metres per metre of depth
  double sigma_quad_per_m = 0.0;  ///< metres per metre^2 of depth
  /// Lateral blur: each pixel reports the depth of a neighbour offset by a Gaussian with this
  /// full width at half maximum, pixels (0 = off); offsets are clamped to +-max_jitter_px.
  double lateral_fwhm_px = 0.0;
  int max_jitter_px = 3;
  /// A depth discontinuity lies between 4-neighbours whose depths differ by more than
  /// max(edge_jump_min_m, edge_jump_rel * nearer depth), or where only one has a return.
  double edge_jump_min_m = 0.03;
  double edge_jump_rel = 0.04;
  int edge_band_px = 2;            ///< pixels within this chessboard distance of an edge are "near"
  double edge_dropout_prob = 0.0;  ///< drop-out probability at the edge, falling linearly to 0
                                   ///< at edge_band_px + 1
  double edge_bleed_prob = 0.0;    ///< probability that a background pixel near an edge reports
                                   ///< the foreground depth (stereo "fattening")
  double speckle_prob = 0.0;       ///< per-pixel probability of seeding a drop-out blob
  int speckle_radius_px = 0;       ///< blob radius (chessboard), pixels
  double random_dropout_prob = 0.0;  ///< independent per-pixel drop-out probability
  /// Grazing incidence: below this |cos| of the angle between ray and surface normal the return
  /// weakens; the drop-out probability rises linearly from 0 at grazing_cos to
  /// grazing_dropout_prob at cos = 0 (needs the incidence from renderDepthWithIncidence).
  double grazing_cos = 0.0;
  double grazing_dropout_prob = 0.0;
  double quantum_m = 0.0;  ///< output quantisation step (sensor depth unit), 0 = none
  /// Systematic depth scale error: reported depth = (1 + depth_scale_bias) * true depth before
  /// the random noise. 0 in every preset (the ground truth stays exact); the thesis's table 4.2
  /// fits +0.0063 for its L515 (camera vs laser-measured depth), which alone makes a tracker
  /// overestimate travel along the view by 0.63 %.
  double depth_scale_bias = 0.0;
  /// Systematic depth offset added to every return after the scale error, metres (a time-of-flight
  /// camera's zero error; camera_check fits it with the scale). 0 in every preset.
  double depth_offset_m = 0.0;

  /// Preset of the named model: L515 sigma = 1.5 mm + 1.1 mm/m z (crosses 5 mm just above 3 m,
  /// thesis 4.1.3), 2.4 px lateral resolution (thesis 4.1.4), edge drop-outs, drop-outs at
  /// grazing incidence beyond 80 deg (near the ground plane, thesis 4.1.4), 0.25 mm units;
  /// D435 sigma = 4.8 mm/m^2 z^2 (30 mm at 2.5 m, inside the thesis's 24-37 mm), edge bleeding
  /// and drop-outs, speckle, 1 mm units; none = exact.
  static NoiseConfig forModel(NoiseModel model);
  /// Standard deviation of the depth noise at depth z_m, metres.
  double sigmaAt(double z_m) const {
    return sigma_const_m + sigma_linear * z_m + sigma_quad_per_m * z_m * z_m;
  }
  /// Every problem (negative sigma, probability outside [0, 1], ...); empty = valid.
  std::vector<std::string> validate() const;
};

/// Loads the `noise_model:` section of a YAML file (camera_check writes one): `base` names the
/// preset the unmeasured effects come from (l515 | d435 | none; default none), every other key
/// sets the NoiseConfig field of the same name (sigma_const_m, sigma_linear, sigma_quad_per_m,
/// lateral_fwhm_px, depth_scale_bias, depth_offset_m, quantum_m, ...). Throws
/// std::invalid_argument naming the file, line and key of an unknown key, a non-number, or a
/// config that does not validate. Thread-safe.
NoiseConfig loadNoiseModelYaml(const std::string& path);

/// Applies the noise model to a clean rendered frame (metres, 0 = no return). Pixels pushed
/// outside `range` become 0. `cos_incidence` (one value per pixel, from
/// renderDepthWithIncidence) enables grazing-angle drop-outs; without it they are skipped.
/// Throws std::invalid_argument naming every config problem, or DepthInputError for a frame
/// (or incidence) buffer that does not match the frame size. Thread-safe.
DepthImage applyNoise(const DepthImage& clean, const NoiseConfig& config, std::uint64_t seed,
                      const DepthRange& range, const std::vector<float>* cos_incidence = nullptr);

/// Per-pixel chessboard distance (pixels, capped at 255) to the nearest depth discontinuity of
/// `depth` under the config's edge rule; discontinuity pixels themselves have distance 0.
std::vector<std::uint8_t> edgeDistance(const DepthImage& depth, const NoiseConfig& config);

/// A raw 16-bit depth frame ("16UC1") and its scale: depth_m = value * depth_scale_m.
struct RawDepth16 {
  int width = 0;
  int height = 0;
  double depth_scale_m = 0.001;
  std::vector<std::uint16_t> data;  ///< row-major, step = 2 * width bytes
};

/// Encodes metres as 16-bit units of depth_scale_m (rounded; 0 stays 0). Throws
/// std::invalid_argument for a non-positive scale and DepthInputError naming the pixel for a
/// depth that does not fit in 16 bits or is negative / not finite. Thread-safe.
RawDepth16 toRaw16(const DepthImage& depth, double depth_scale_m);

/// Native depth unit of a model's raw stream (L515 0.25 mm, D435 1 mm; "none" uses 1/5000 m,
/// the TUM unit), metres.
double nativeDepthScale(NoiseModel model);

/// Derives an independent per-frame seed from a run seed and a frame index.
std::uint64_t frameSeed(std::uint64_t run_seed, std::uint64_t frame_index);

}  // namespace sim
}  // namespace depth_track
