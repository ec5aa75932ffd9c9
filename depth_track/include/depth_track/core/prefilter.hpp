#pragma once
/// Depth-frame prefilters (thesis §3.4 and the PreFilter switch of fig. 5.1): none, an
/// edge-preserving bilateral filter, or a crop to a pixel rectangle. ROS-free core.
#include <string>
#include <vector>

#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/worker_pool.hpp"

namespace depth_track {

/// Thesis codes in brackets (PreFilter in fig. 5.1).
enum class PrefilterType {
  kNone,       ///< (0) frame passes unchanged
  kBilateral,  ///< (1) bilateral filter
  kCrop,       ///< (2) pixels outside a rectangle become "no return"
};

/// "none" | "bilateral" | "crop" (or the thesis codes "0" | "1" | "2"); throws
/// std::invalid_argument naming any other value.
PrefilterType parsePrefilterType(const std::string& name);
/// "none" | "bilateral" | "crop".
std::string toString(PrefilterType type);

/// How the bilateral kernel is evaluated.
enum class BilateralMode {
  kFull,       ///< the thesis's square Ksz x Ksz kernel (Ksz^2 taps per pixel)
  kSeparable,  ///< a horizontal then a vertical 1-D bilateral pass (2 Ksz taps per pixel);
               ///< the usual separable approximation (Pham & van Vliet 2005): same smoothing
               ///< on smooth surfaces, slightly different weights across corners
};

/// "full" | "separable"; throws std::invalid_argument naming any other value.
BilateralMode parseBilateralMode(const std::string& name);
/// "full" | "separable".
std::string toString(BilateralMode mode);

/// Configuration of the prefilter stage. Defaults: the thesis's fig. 5.1 (PreFilter 0, Ksz 31,
/// Spatial_Const 15.0, Depth_Const 200.0).
///
/// Units of the thesis's Depth_Const: its GPU kernel filters the raw 16-bit frame before the
/// conversion to metres, so the constant is a Gaussian sigma in raw camera depth units. The
/// L515 used for the fig. 5.1 runs counts 0.25 mm per unit (table 4.1), so 200 units = 0.05 m,
/// the same size as the +/-0.05 m depth waviness the thesis measures in §3.4. On a 1 mm camera
/// (D435i, ROS drivers) the same constant would mean 0.2 m. This struct stores metres; use
/// depthSigmaFromRawUnits() to carry a thesis-style constant over.
struct PrefilterConfig {
  PrefilterType type = PrefilterType::kNone;
  // ---- bilateral ----
  BilateralMode bilateral_mode = BilateralMode::kFull;
  int kernel_size_px = 31;         ///< Ksz: odd kernel side, pixels (radius = Ksz / 2)
  double spatial_sigma_px = 15.0;  ///< Spatial_Const: Gaussian sigma over pixel distance, px
  double depth_sigma_m = 0.05;     ///< Depth_Const: Gaussian sigma over depth difference, m
  /// Neighbours further than this many depth sigmas from the centre get weight 0 (the Gaussian
  /// is 0.011 at 3 sigma): keeps the other side of a step edge out completely. At most 5.
  double depth_cutoff_sigmas = 3.0;
  // ---- crop: the rectangle that is kept, pixels ----
  int crop_x_px = 0;       ///< left column of the kept rectangle
  int crop_y_px = 0;       ///< top row of the kept rectangle
  int crop_width_px = 0;   ///< kept columns (>= 1 when type is crop)
  int crop_height_px = 0;  ///< kept rows (>= 1 when type is crop)

  /// Every problem of the parameters of the selected type (empty = valid).
  std::vector<std::string> validate() const;
  /// As validate(), plus a crop rectangle that does not fit a width x height frame.
  std::vector<std::string> validate(int width, int height) const;
};

/// Converts a thesis-style depth constant in raw camera units into metres (e.g. 200 units at
/// 0.00025 m per unit -> 0.05 m).
inline double depthSigmaFromRawUnits(double raw_units, double depth_scale_m) {
  return raw_units * depth_scale_m;
}

/// Applies the configured prefilter to a frame in metres. Invalid (0) pixels neither contribute
/// to neighbours nor get filled; valid pixels stay valid. Throws std::invalid_argument listing
/// every problem of the config for this frame size. Thread-safe; `threads` > 1 splits rows over
/// TBB workers (results are identical for any thread count).
DepthImage applyPrefilter(const DepthImage& depth, const PrefilterConfig& config, int threads = 1);
/// As above, rows split over the pool's workers. Thread-safe.
DepthImage applyPrefilter(const DepthImage& depth, const PrefilterConfig& config,
                          const WorkerPool& pool);

}  // namespace depth_track
