#include "depth_track/core/map/map_quality.hpp"

#include <cmath>
#include <stdexcept>
#include <unordered_set>

namespace depth_track {

namespace {

struct KeyHash {
  std::size_t operator()(const VoxelKey& k) const {
    return static_cast<std::size_t>((static_cast<std::int64_t>(k.x()) * 73856093) ^
                                    (static_cast<std::int64_t>(k.y()) * 19349663) ^
                                    (static_cast<std::int64_t>(k.z()) * 83492791));
  }
};
using KeySet = std::unordered_set<VoxelKey, KeyHash>;

// True when a key of `set` within r voxels of k (per axis) passes accept(key).
template <class Accept>
bool anyWithin(const KeySet& set, const VoxelKey& k, int r, Accept&& accept) {
  for (int dz = -r; dz <= r; ++dz)
    for (int dy = -r; dy <= r; ++dy)
      for (int dx = -r; dx <= r; ++dx) {
        const VoxelKey n = k + VoxelKey(dx, dy, dz);
        if (set.count(n) && accept(n)) return true;
      }
  return false;
}

bool anyWithin(const KeySet& set, const VoxelKey& k, int r) {
  return anyWithin(set, k, r, [](const VoxelKey&) { return true; });
}

}  // namespace

SurfaceQuality surfaceQuality(
    const VoxelMap& map, const std::function<double(const Eigen::Vector3d&)>& distance_to_surface_m,
    const std::vector<Eigen::Vector3d>& surface_W, double tolerance_m) {
  if (!(std::isfinite(tolerance_m) && tolerance_m > 0.0))
    throw std::invalid_argument("surfaceQuality: tolerance_m must be > 0 m");
  SurfaceQuality q;
  KeySet occupied;
  map.forEachOccupied([&](const VoxelKey& k) {
    occupied.insert(k);
    ++q.occupied;
    if (distance_to_surface_m(map.centerOf(k)) <= tolerance_m) ++q.near_surface;
  });
  q.precision = q.occupied ? static_cast<double>(q.near_surface) / q.occupied : 0.0;
  const double s = map.config().voxel_size_m;
  const int r = static_cast<int>(std::ceil(tolerance_m / s));
  for (const auto& p : surface_W) {
    ++q.surface_samples;
    q.covered += anyWithin(occupied, map.keyOf(p), r, [&](const VoxelKey& k) {
      return (map.centerOf(k) - p).norm() <= tolerance_m;
    });
  }
  q.completeness = q.surface_samples ? static_cast<double>(q.covered) / q.surface_samples : 0.0;
  return q;
}

VoxelSetDifference voxelSetDifference(const std::vector<VoxelKey>& a,
                                      const std::vector<VoxelKey>& b, int radius_voxels) {
  if (radius_voxels < 0)
    throw std::invalid_argument("voxelSetDifference: radius_voxels must be >= 0");
  const KeySet sa(a.begin(), a.end()), sb(b.begin(), b.end());
  VoxelSetDifference d;
  d.a = sa.size();
  d.b = sb.size();
  for (const auto& k : sa) {
    d.both += sb.count(k);
    d.a_far += !anyWithin(sb, k, radius_voxels);
  }
  for (const auto& k : sb) d.b_far += !anyWithin(sa, k, radius_voxels);
  const std::size_t uni = d.a + d.b - d.both;
  d.jaccard = uni ? static_cast<double>(d.both) / uni : 1.0;
  d.a_far_fraction = d.a ? static_cast<double>(d.a_far) / d.a : 0.0;
  d.b_far_fraction = d.b ? static_cast<double>(d.b_far) / d.b : 0.0;
  return d;
}

}  // namespace depth_track
