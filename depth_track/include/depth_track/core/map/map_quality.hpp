#pragma once
/// Map quality as numbers (thesis §5.1–5.3 judged the "extrusion" of the chair by eye):
/// precision and completeness against known geometry, and the voxel-set difference between two
/// maps (e.g. fused from tracked vs ground-truth poses). ROS-free core.
#include <Eigen/Core>
#include <cmath>
#include <functional>
#include <vector>

#include "depth_track/core/map/voxel_map.hpp"

namespace depth_track {

struct SurfaceQuality {
  std::size_t occupied = 0;         ///< occupied voxels evaluated
  std::size_t near_surface = 0;     ///< ... with centre within the tolerance of a true surface
  double precision = 0.0;           ///< near_surface / occupied
  std::size_t surface_samples = 0;  ///< visible true-surface points given
  std::size_t covered = 0;          ///< ... with an occupied voxel within the tolerance
  double completeness = 0.0;        ///< covered / surface_samples
};

/// Precision: share of occupied voxels whose centre lies within `tolerance_m` of a true surface
/// (`distance_to_surface_m(p_W)` gives the unsigned distance, metres). Completeness: share of
/// the visible true-surface points `surface_W` (e.g. back-projected noise-free renders) that
/// have an occupied voxel whose centre lies within `tolerance_m`. A natural tolerance is one
/// voxel plus half its diagonal (the centre of a voxel holding a surface point lies within
/// sqrt(3)/2 voxel of it). Thread-safe against other const uses of the map.
/// That tolerance for voxels of edge voxel_m: (1 + sqrt(3) / 2) voxel_m, "within one voxel" (the
/// voxel is, or touches, one the surface passes through).
inline double oneVoxelTolerance(double voxel_m) { return (1.0 + 0.5 * std::sqrt(3.0)) * voxel_m; }

SurfaceQuality surfaceQuality(
    const VoxelMap& map, const std::function<double(const Eigen::Vector3d&)>& distance_to_surface_m,
    const std::vector<Eigen::Vector3d>& surface_W, double tolerance_m);

struct VoxelSetDifference {
  std::size_t a = 0, b = 0;     ///< occupied voxels in each map
  std::size_t both = 0;         ///< occupied in both (same key)
  std::size_t a_far = 0;        ///< voxels of a with no voxel of b within `radius_voxels`
  std::size_t b_far = 0;        ///< voxels of b with no voxel of a within `radius_voxels`
  double jaccard = 0.0;         ///< both / (a + b - both)
  double a_far_fraction = 0.0;  ///< a_far / a: the "extrusion" of a against the reference b
  double b_far_fraction = 0.0;  ///< b_far / b: what a misses of b
};

/// Voxel-set difference of occupied voxels of two keyed sets of the same voxel size (e.g.
/// tracked map `a` against the map fused from ground-truth poses `b`). radius_voxels = 1 counts
/// a voxel as matched when the other set has one in its 3x3x3 neighbourhood. Thread-safe.
VoxelSetDifference voxelSetDifference(const std::vector<VoxelKey>& a,
                                      const std::vector<VoxelKey>& b, int radius_voxels = 1);

}  // namespace depth_track
