#pragma once
/// Synthetic depth rendering of an analytic scene (ROS-free, library depth_track_sim).
#include <Eigen/Geometry>
#include <functional>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/sim/scene.hpp"

namespace depth_track {
namespace sim {

/// Renders the exact z-depth (along the optical axis, not the ray length), metres, of the
/// nearest surface through every pixel centre, for a camera at T_W_C (optical frame: x right,
/// y down, z forward). 0 = no surface, or the nearest surface lies outside `range` (a surface
/// closer than range.min_m still hides what is behind it, as on a real sensor).
/// Rows are split over TBB workers; threads <= 0 uses TBB's default, 1 runs serially; the
/// result does not depend on the thread count. Throws std::invalid_argument naming every
/// problem of the scene, intrinsics, range or pose. Thread-safe (reads the scene only).
DepthImage renderDepth(const Scene& scene, const PinholeIntrinsics& intrinsics,
                       const Eigen::Isometry3d& T_W_C, const DepthRange& range, int threads = 0);

/// A rendered frame with the incidence of each ray on the surface it hit.
struct RenderedDepth {
  DepthImage depth;                  ///< as renderDepth
  std::vector<float> cos_incidence;  ///< |cos| of the angle between ray and surface normal, in
                                     ///< [0, 1] (1 = head-on); 0 where depth is 0
};

/// renderDepth plus the per-pixel incidence (for grazing-angle drop-outs in the noise models).
/// Same contract, threads and exceptions as renderDepth. Thread-safe.
RenderedDepth renderDepthWithIncidence(const Scene& scene, const PinholeIntrinsics& intrinsics,
                                       const Eigen::Isometry3d& T_W_C, const DepthRange& range,
                                       int threads = 0);

/// A frame scanned row by row (the L515's MEMS raster, or a rolling shutter): row v is seen from
/// T_W_C_at_row(v) (v = row index, may be fractional). Rows are rendered in bands of band_rows
/// rows sharing the pose at the band's centre row (band_rows = 1 is exact per row). Same depth
/// and incidence contract, threads and exceptions as renderDepthWithIncidence. Thread-safe if
/// the pose function is.
RenderedDepth renderDepthScanned(const Scene& scene, const PinholeIntrinsics& intrinsics,
                                 const std::function<Eigen::Isometry3d(double row)>& T_W_C_at_row,
                                 const DepthRange& range, int threads = 0, int band_rows = 8);

/// Reference renderer for equivalence tests: same contract as renderDepth, but tests every
/// primitive for every pixel without screen-space culling, serially. Slow; not for runs.
DepthImage renderDepthReference(const Scene& scene, const PinholeIntrinsics& intrinsics,
                                const Eigen::Isometry3d& T_W_C, const DepthRange& range);

}  // namespace sim
}  // namespace depth_track
