// PCL Generalized-ICP and NDT as frame-to-frame odometries, the way PCL's registration tutorials
// use them: VoxelGrid-downsampled clouds, the previous frame as target, the current one as
// source, align() from an initial guess. The only translation unit of the project that includes
// PCL headers.
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#include <pcl/registration/ndt.h>

#include <sstream>

#include "peers.hpp"

namespace depth_track {
namespace peers {
namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;

// Cloud preparation and pose bookkeeping common to both; Registration supplies the algorithm.
template <class Registration>
class PclOdometry : public Odometry {
 public:
  PclOdometry(const PinholeIntrinsics& K, double voxel_m, InitialGuess guess)
      : K_(K), voxel_m_(voxel_m), motion_(guess) {}

  Eigen::Isometry3d track(const DepthImage& depth, bool* registered) override {
    Cloud::Ptr raw(new Cloud);
    const std::vector<Eigen::Vector3f> pts = backProject(depth, K_);
    raw->reserve(pts.size());
    for (const Eigen::Vector3f& p : pts) raw->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
    Cloud::Ptr cloud(new Cloud);
    pcl::VoxelGrid<pcl::PointXYZ> grid;
    grid.setInputCloud(raw);
    grid.setLeafSize(voxel_m_, voxel_m_, voxel_m_);
    grid.filter(*cloud);

    bool ok = false;
    Eigen::Isometry3d T_prev_cur = motion_.guess();
    if (previous_ && cloud->size() >= kMinPoints && previous_->size() >= kMinPoints) {
      reg_.setInputTarget(previous_);
      reg_.setInputSource(cloud);
      Cloud aligned;
      reg_.align(aligned, T_prev_cur.matrix().cast<float>());
      ok = reg_.hasConverged();
      if (ok) T_prev_cur.matrix() = reg_.getFinalTransformation().template cast<double>();
    }
    const bool first = !previous_;
    previous_ = cloud;
    *registered = first || ok;
    return first ? motion_.pose() : motion_.advance(T_prev_cur, ok);
  }

 protected:
  static constexpr std::size_t kMinPoints = 30;
  Registration reg_;

 private:
  PinholeIntrinsics K_;
  double voxel_m_;
  MotionModel motion_;
  Cloud::Ptr previous_;
};

class PclGicp
    : public PclOdometry<pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ>> {
 public:
  PclGicp(const PinholeIntrinsics& K, const GicpParams& p, InitialGuess guess)
      : PclOdometry(K, p.voxel_m, guess), p_(p) {
    reg_.setMaxCorrespondenceDistance(p.max_corr_m);
    reg_.setCorrespondenceRandomness(p.k_correspondences);
    reg_.setMaximumIterations(p.max_iterations);
  }
  std::string name() const override { return "pcl_gicp"; }
  std::string params() const override {
    std::ostringstream s;
    s << "voxel=" << p_.voxel_m << " m max_corr=" << p_.max_corr_m
      << " m k=" << p_.k_correspondences << " max_iter=" << p_.max_iterations
      << " (PCL defaults otherwise: transformation eps 5e-4, rotation eps 2e-3)";
    return s.str();
  }

 private:
  GicpParams p_;
};

class PclNdt : public PclOdometry<pcl::NormalDistributionsTransform<pcl::PointXYZ, pcl::PointXYZ>> {
 public:
  PclNdt(const PinholeIntrinsics& K, const NdtParams& p, InitialGuess guess)
      : PclOdometry(K, p.voxel_m, guess), p_(p) {
    reg_.setResolution(static_cast<float>(p.resolution_m));
    reg_.setStepSize(p.step_size_m);
    reg_.setTransformationEpsilon(p.epsilon);
    reg_.setMaximumIterations(p.max_iterations);
  }
  std::string name() const override { return "pcl_ndt"; }
  std::string params() const override {
    std::ostringstream s;
    s << "voxel=" << p_.voxel_m << " m resolution=" << p_.resolution_m
      << " m step=" << p_.step_size_m << " m eps=" << p_.epsilon
      << " max_iter=" << p_.max_iterations << " (outlier ratio 0.55, PCL default)";
    return s.str();
  }

 private:
  NdtParams p_;
};

}  // namespace

std::unique_ptr<Odometry> makePclGicp(const PinholeIntrinsics& K, const GicpParams& params,
                                      InitialGuess guess) {
  return std::make_unique<PclGicp>(K, params, guess);
}

std::unique_ptr<Odometry> makePclNdt(const PinholeIntrinsics& K, const NdtParams& params,
                                     InitialGuess guess) {
  return std::make_unique<PclNdt>(K, params, guess);
}

}  // namespace peers
}  // namespace depth_track
