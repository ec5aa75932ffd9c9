#pragma once
// Peer odometries for the side-by-side benchmark (dt_peers): frame-to-frame registration of
// depth frames with Open3D and PCL, behind one small interface so the benchmark feeds every
// method, ours included, the same frames. Each library lives in its own translation unit
// (peers_open3d.cpp, peers_pcl.cpp): PCL's headers cost tens of seconds per file.
#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

namespace depth_track {
namespace peers {

/// A frame-to-frame odometry: the first frame is the world frame, every later frame is
/// registered against the one before it. Not thread-safe.
class Odometry {
 public:
  virtual ~Odometry() = default;
  /// Short name for tables and file names ("open3d_p2l").
  virtual std::string name() const = 0;
  /// The parameters in use, one line ("voxel=0.02 m max_corr=0.05 m ...").
  virtual std::string params() const = 0;
  /// Camera pose T_W_C after this frame (metres, 0 = no return). `registered` is false when the
  /// library reported no convergence or had too few points; the pose is then the prediction.
  virtual Eigen::Isometry3d track(const DepthImage& depth, bool* registered) = 0;
};

/// How a peer guesses the next frame's motion before registering.
enum class InitialGuess {
  kVelocity,  ///< the last frame-to-frame motion (the prior our tracker uses)
  kIdentity,  ///< no motion
};

/// Pose bookkeeping shared by the peers: compounding T_W_C, the initial guess, and keeping the
/// prediction when a registration fails.
class MotionModel {
 public:
  explicit MotionModel(InitialGuess guess) : guess_(guess) {}
  /// The guess of T_Cprev_Ccur for the next registration.
  Eigen::Isometry3d guess() const {
    return guess_ == InitialGuess::kVelocity ? velocity_ : Eigen::Isometry3d::Identity();
  }
  /// Applies a registration result T_Cprev_Ccur (or, when !ok, the guess) and returns T_W_C.
  const Eigen::Isometry3d& advance(const Eigen::Isometry3d& T_prev_cur, bool ok) {
    const Eigen::Isometry3d step = ok ? T_prev_cur : guess();
    T_W_C_ = T_W_C_ * step;
    velocity_ = step;
    return T_W_C_;
  }
  const Eigen::Isometry3d& pose() const { return T_W_C_; }

 private:
  InitialGuess guess_;
  Eigen::Isometry3d T_W_C_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d velocity_ = Eigen::Isometry3d::Identity();
};

/// Valid pixels of a frame as camera-frame points p_C, metres (every pixel, row-major order).
std::vector<Eigen::Vector3f> backProject(const DepthImage& depth, const PinholeIntrinsics& K);

// Defaults: the best of a sweep on rendered rt2 with D435 noise, a run none of the reported
// inputs is (bench/peers/tune_peers.sh; results in bench/peers/README.md).

/// Open3D point-to-plane ICP, frame to frame, on voxel-downsampled clouds with normals
/// estimated in a radius of `normal_radius_m` (at most 30 neighbours).
struct Open3dParams {
  double voxel_m = 0.02;
  double max_corr_m = 0.1;
  double normal_radius_m = 0.04;
  int max_iterations = 30;  ///< Open3D's default convergence criteria otherwise (1e-6 relative)
};
/// PCL Generalized-ICP (plane-to-plane), frame to frame, on VoxelGrid-downsampled clouds.
struct GicpParams {
  double voxel_m = 0.04;
  double max_corr_m = 0.05;
  int k_correspondences = 20;  ///< PCL default: neighbours per covariance
  int max_iterations = 50;
};
/// PCL Normal Distributions Transform, frame to frame, on VoxelGrid-downsampled clouds.
struct NdtParams {
  double voxel_m = 0.05;
  double resolution_m = 0.2;  ///< NDT cell size
  double step_size_m = 0.1;   ///< More-Thuente line search maximum step (PCL default 0.1)
  double epsilon = 0.01;      ///< stop when the transformation changes less than this
  int max_iterations = 35;
};

/// Factories, defined only when the library was found (DT_HAVE_OPEN3D, DT_HAVE_PCL).
std::unique_ptr<Odometry> makeOpen3dIcp(const PinholeIntrinsics& K, const Open3dParams& params,
                                        InitialGuess guess);
std::unique_ptr<Odometry> makePclGicp(const PinholeIntrinsics& K, const GicpParams& params,
                                      InitialGuess guess);
std::unique_ptr<Odometry> makePclNdt(const PinholeIntrinsics& K, const NdtParams& params,
                                     InitialGuess guess);

}  // namespace peers
}  // namespace depth_track
