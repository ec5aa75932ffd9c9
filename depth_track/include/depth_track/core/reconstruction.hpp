#pragma once
/// PCA surface reconstruction (thesis §3.7, eq. 3.4-3.13): a depth frame re-rendered from a cell
/// cloud, each cell as the patch of its plane (mean vertex, normal) seen through its pixels.
/// Used to check how faithfully the reduction represents the scene (thesis §5.2). ROS-free core.
#include <cstddef>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_image.hpp"

namespace depth_track {

/// Guards of the reconstruction.
struct ReconstructionConfig {
  /// Smallest |cos| between a pixel's viewing ray and the cell normal. Near-grazing rays meet
  /// the plane far from the cell (depth error grows as 1/cos), so such pixels are left at 0.
  /// 0.05 = rays within 87 degrees of the normal are used.
  double min_ray_cos = 0.05;
  /// A plane fitted to a cell cannot leave the depth span of the cell's own vertices: pixels
  /// whose plane depth differs from mean_C.z by more than max_depth_sigmas * sqrt(cov(2,2)) +
  /// depth_margin_m are left at 0 (uniform data spans about 2.5 sigma corner to mean).
  double max_depth_sigmas = 4.0;
  double depth_margin_m = 0.01;  ///< metres, absolute slack of the span guard

  /// Every problem at once (empty = valid).
  std::vector<std::string> validate() const;
};

/// Renders the depth (metres, camera optical frame) of every pixel of every kept cell as the
/// intersection of the pixel's viewing ray with the cell's plane {p : normal_C . (p - mean_C) =
/// 0}. Uses each cell's gx, gy, mean_C, normal_C and cov(2,2) (the span guard); cells from
/// reduceToCells have all of them. Pixels of pruned cells, of cells with a non-finite mean,
/// normal or cov(2,2), and guarded pixels (see ReconstructionConfig) are 0. The thesis interpolates
/// linearly between the depths at the cell corners (eq. 3.11-3.13); intersecting each ray is exact
/// for a tilted plane, where depth is not linear in pixel coordinates. Throws DepthInputError when
/// the cell grid does not fit the intrinsics' image or the intrinsics are invalid,
/// std::invalid_argument for a bad config. Thread-safe.
DepthImage reconstructDepth(const CellCloud& cells, const PinholeIntrinsics& intrinsics,
                            const ReconstructionConfig& config = ReconstructionConfig());

/// Pixel-wise comparison of two depth frames of the same size, over pixels valid in both.
struct DepthDifference {
  std::size_t compared = 0;   ///< pixels valid in both frames
  std::size_t only_in_a = 0;  ///< valid in a, 0 in b
  std::size_t only_in_b = 0;  ///< valid in b, 0 in a
  double rms_m = 0.0;         ///< root mean square of (b - a), metres
  double mean_m = 0.0;        ///< mean of (b - a), metres
  double max_abs_m = 0.0;     ///< largest |b - a|, metres
  double median_abs_m = 0.0;  ///< median |b - a|, metres (robust to edge cells)
};

/// Compares b against a (e.g. a reconstruction against the frame it came from). Throws
/// DepthInputError when the sizes differ. Thread-safe.
DepthDifference compareDepth(const DepthImage& a, const DepthImage& b);

}  // namespace depth_track
