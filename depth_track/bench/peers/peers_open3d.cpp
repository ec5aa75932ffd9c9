// Open3D point-to-plane ICP as a frame-to-frame odometry, the way its tutorials register two
// scans: voxel downsampling, normals from a radius search, RegistrationICP with
// TransformationEstimationPointToPlane. Each frame's cloud is prepared once and serves as the
// target of the next registration.
#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/pipelines/registration/Registration.h>
#include <open3d/pipelines/registration/TransformationEstimation.h>

#include <sstream>

#include "peers.hpp"

namespace depth_track {
namespace peers {
namespace {

namespace reg = open3d::pipelines::registration;

class Open3dIcp : public Odometry {
 public:
  Open3dIcp(const PinholeIntrinsics& K, const Open3dParams& p, InitialGuess guess)
      : K_(K), p_(p), motion_(guess) {}

  std::string name() const override { return "open3d_p2l"; }
  std::string params() const override {
    std::ostringstream s;
    s << "voxel=" << p_.voxel_m << " m max_corr=" << p_.max_corr_m
      << " m normal_radius=" << p_.normal_radius_m << " m (30 nn) max_iter=" << p_.max_iterations;
    return s.str();
  }

  Eigen::Isometry3d track(const DepthImage& depth, bool* registered) override {
    open3d::geometry::PointCloud raw;
    const std::vector<Eigen::Vector3f> pts = backProject(depth, K_);
    raw.points_.reserve(pts.size());
    for (const Eigen::Vector3f& p : pts) raw.points_.push_back(p.cast<double>());
    std::shared_ptr<open3d::geometry::PointCloud> cloud = raw.VoxelDownSample(p_.voxel_m);
    cloud->EstimateNormals(open3d::geometry::KDTreeSearchParamHybrid(p_.normal_radius_m, 30));

    bool ok = false;
    Eigen::Isometry3d T_prev_cur = motion_.guess();
    if (previous_ && !cloud->points_.empty() && !previous_->points_.empty()) {
      const reg::RegistrationResult r =
          reg::RegistrationICP(*cloud, *previous_, p_.max_corr_m, T_prev_cur.matrix(),
                               reg::TransformationEstimationPointToPlane(),
                               reg::ICPConvergenceCriteria(1e-6, 1e-6, p_.max_iterations));
      // Open3D reports no convergence flag; too few inliers means nothing was registered.
      ok = r.correspondence_set_.size() >= kMinCorrespondences;
      if (ok) T_prev_cur.matrix() = r.transformation_;
    }
    const bool first = !previous_;
    previous_ = std::move(cloud);
    *registered = first || ok;
    return first ? motion_.pose() : motion_.advance(T_prev_cur, ok);
  }

 private:
  static constexpr std::size_t kMinCorrespondences = 10;
  PinholeIntrinsics K_;
  Open3dParams p_;
  MotionModel motion_;
  std::shared_ptr<open3d::geometry::PointCloud> previous_;
};

}  // namespace

std::unique_ptr<Odometry> makeOpen3dIcp(const PinholeIntrinsics& K, const Open3dParams& params,
                                        InitialGuess guess) {
  return std::make_unique<Open3dIcp>(K, params, guess);
}

}  // namespace peers
}  // namespace depth_track
