#pragma once
/// A measured depth-scale correction applied to frames at ingestion (ROS-free core). camera_check
/// fits the camera's response reported = scale * true + offset_m against laser-measured
/// distances and writes it as the `depth_correction:` section of its YAML; the tracker's front
/// ends load that section and invert the response on every frame before tracking.
#include <string>
#include <vector>

#include "depth_track/core/depth_image.hpp"

namespace depth_track {

/// Depth response of a camera: a surface at true depth z (metres, along the optical axis) is
/// reported at scale * z + offset_m. Identity by default.
struct DepthCorrection {
  double scale = 1.0;     ///< reported metres per true metre (1.0063 = reads 0.63 % long)
  double offset_m = 0.0;  ///< reported depth at true depth 0, metres

  /// Every problem (scale outside 0.8..1.2, offset beyond +-0.2 m, not finite); empty = valid.
  std::vector<std::string> validate() const;
  bool isIdentity() const { return scale == 1.0 && offset_m == 0.0; }
  /// True depth of a reported depth z_m, metres (no-return values are not special-cased here).
  double trueDepth(double z_m) const { return (z_m - offset_m) / scale; }
};

/// Replaces every valid depth z (> 0) of `depth` by correction.trueDepth(z); no-return pixels
/// stay 0, and a depth the correction would make non-positive becomes 0 (no return). Throws
/// std::invalid_argument naming every problem of the correction. Thread-safe on distinct frames.
void applyDepthCorrection(DepthImage& depth, const DepthCorrection& correction);

/// Reads the `depth_correction:` section (`scale`, `offset_m`) of a camera_check YAML file. Throws
/// std::invalid_argument naming the file, line and key of a missing section, unknown key,
/// non-number or invalid value.
DepthCorrection loadDepthCorrectionYaml(const std::string& path);

}  // namespace depth_track
