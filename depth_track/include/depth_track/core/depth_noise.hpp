#pragma once
/// A depth sensor's per-pixel noise as a function of depth: what auto_noise measures
/// (noise_model.hpp) and what the registration's weighting and the registration model's gate
/// read. ROS-free core.

#include <cmath>
#include <limits>

namespace depth_track {

/// Depth noise: standard deviation sigma(z) = const_m + linear z + quad_per_m z^2 of one pixel's
/// depth about the surface, metres (z along the optical axis, metres).
struct DepthNoiseModel {
  double const_m = 0.0;
  double linear = 0.0;
  double quad_per_m = 0.0;
  double sigmaAt(double z_m) const { return const_m + linear * z_m + quad_per_m * z_m * z_m; }
  bool known() const { return const_m > 0.0 || linear > 0.0 || quad_per_m > 0.0; }
  /// No coefficient negative (or NaN).
  bool valid() const { return const_m >= 0.0 && linear >= 0.0 && quad_per_m >= 0.0; }
  /// The depth at which sigma(z) reaches sigma_m, metres: 0 when it is reached at z = 0 already,
  /// infinity when never (a valid model's sigma grows with z).
  double depthAtSigma(double sigma_m) const {
    if (!(sigma_m > const_m)) return 0.0;
    const double r = sigma_m - const_m;
    if (quad_per_m > 0.0)
      return 2.0 * r / (linear + std::sqrt(linear * linear + 4.0 * quad_per_m * r));
    return linear > 0.0 ? r / linear : std::numeric_limits<double>::infinity();
  }
};

}  // namespace depth_track
