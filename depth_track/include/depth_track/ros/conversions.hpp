#pragma once
// The one place where the tracking graph converts between ROS messages and the core's types:
// depth images (16UC1 with a depth scale, 32FC1 in metres), camera_info -> PinholeIntrinsics,
// cell clouds <-> sensor_msgs/PointCloud2, poses and transforms, the registration's normal
// equations -> a pose covariance, and core outcomes -> status messages. ROS side only (the core
// under include/depth_track/core never sees these headers). Every function is thread-safe.
#include <geometry_msgs/Pose.h>
#include <geometry_msgs/Transform.h>
#include <rig_msgs/NoiseCalibration.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Header.h>

#include <Eigen/Geometry>
#include <array>
#include <memory>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/noise_model.hpp"

namespace depth_track {
namespace conv {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

// ---- depth
// ---------------------------------------------------------------------------------------

/// A depth image message in metres through the core's one conversion (depthFromRaw): "16UC1" /
/// "mono16" times depth_scale_m, "32FC1" as metres; 0, NaN, Inf and depths outside `range` become
/// "no return". Throws DepthInputError naming the encoding, a big-endian image, a step too small
/// for the width or a data size that does not match height * step.
DepthImage depthFromMsg(const sensor_msgs::Image& image, double depth_scale_m,
                        const DepthRange& range);

/// A depth frame in metres as a 32FC1 image; "no return" (0 in the core) becomes NaN (REP 118).
sensor_msgs::ImagePtr depthToMsg(const DepthImage& depth, const std_msgs::Header& header);

/// False-colour rendering of a depth frame: cyclic bands of `band_m` (the thesis's 50 mm, §5.1)
/// through a hue wheel, black where there is no return ("rgb8").
sensor_msgs::ImagePtr falseColourDepth(const DepthImage& depth, const std_msgs::Header& header,
                                       double band_m = 0.05);

/// An IMU message's reading (header stamp, angular velocity, linear acceleration; the
/// orientation is not read). Values are copied as they are: ImuMotionPrior::add checks them.
ImuSample imuSampleFromMsg(const sensor_msgs::Imu& m);

/// Intrinsics of a rectified image from camera_info (the projection matrix P, or K when P is
/// zero). Throws DepthInputError for an uncalibrated camera (zero focal lengths), a zero image
/// size, binning or a region of interest (not handled), or intrinsics that do not validate.
PinholeIntrinsics intrinsicsFromCameraInfo(const sensor_msgs::CameraInfo& info);

/// Throws DepthInputError when the image's size differs from the intrinsics' (camera_info's).
void checkImageMatchesInfo(const sensor_msgs::Image& image, const PinholeIntrinsics& intrinsics);

// ---- cells
// ---------------------------------------------------------------------------------------

/// A cell cloud as an organised PointCloud2 (width = grid columns, height = grid rows) in the
/// optical frame. Fields (float32 unless noted): x y z (mean vertex, m), normal_x/y/z,
/// curvature (surface variation), cov_xx cov_xy cov_xz cov_yy cov_yz cov_zz (m^2), eig0..2
/// (ascending eigenvalues, m^2), isq_xx .. isq_zz ((cov + eps I)^-1/2, 1/m), col row n_valid
/// (int32). Pruned grid cells have NaN geometry and n_valid 0. Everything registration and loop
/// closure read is carried bit for bit (cellsFromCloud gives the same cells, the same order).
sensor_msgs::PointCloud2Ptr cellsToCloud(const CellCloud& cells, const std_msgs::Header& header);

/// The cell cloud of a message from cellsToCloud, for frames of image_width x image_height
/// pixels (the cell size is image_width / grid columns). Stamp and frame come from the header.
/// Throws DepthInputError for a missing or mistyped field, an inconsistent size, or a grid that
/// does not tile the image.
std::shared_ptr<CellCloud> cellsFromCloud(const sensor_msgs::PointCloud2& cloud, int image_width,
                                          int image_height);

/// The first frame's noise calibration (auto_noise) as pca_reduce sends it to registration;
/// every value travels as float64, so the receiver applies the sender's settings bit for bit.
rig_msgs::NoiseCalibration toMsg(const NoiseCalibration& calibration,
                                 const std_msgs::Header& header);
/// Throws DepthInputError for a measured calibration with a non-finite or out-of-range value.
NoiseCalibration fromMsg(const rig_msgs::NoiseCalibration& msg);

// ---- poses
// ---------------------------------------------------------------------------------------

geometry_msgs::Pose toPoseMsg(const Eigen::Isometry3d& T);
geometry_msgs::Transform toTransformMsg(const Eigen::Isometry3d& T);
/// Throws std::invalid_argument for a non-finite entry or a quaternion far from unit length
/// (|q| outside [0.9, 1.1]: a corrupt pose, not rounding); the quaternion is normalised.
Eigen::Isometry3d fromPoseMsg(const geometry_msgs::Pose& pose);
Eigen::Isometry3d fromTransformMsg(const geometry_msgs::Transform& transform);

/// Covariance of a registered pose as ROS wants it (row-major 6x6 over x y z and rotations about
/// x y z of the parent frame, at the body's origin `p_P_body`): from the registration's normal
/// matrix H (increment [omega; v] applied on the left in the reference frame, see
/// RegistrationResult::normal_matrix) scaled by the residual variance sigma_m^2, carried from the
/// reference frame into the parent frame by R_P_ref and t_P_ref. Directions H does not
/// constrain (eigenvalue below 1e-9 of the largest) get `unconstrained_var`.
std::array<double, 36> poseCovariance(const Matrix6d& H, double sigma_m,
                                      const Eigen::Isometry3d& T_P_ref,
                                      const Eigen::Vector3d& p_P_body,
                                      double unconstrained_var = 1e3);

/// The same ROS covariance from a covariance already taken over the increment [omega; u] of
/// FrameStatus::covariance (rotation about the camera centre, the centre's displacement, both in
/// the reference frame of orientation R_P_ref), with the camera centre at c_P in the parent frame.
std::array<double, 36> poseCovarianceOfIncrement(const Matrix6d& cov_ref,
                                                 const Eigen::Matrix3d& R_P_ref,
                                                 const Eigen::Vector3d& c_P,
                                                 const Eigen::Vector3d& p_P_body);

/// Diagonal covariance with the given position (m^2) and rotation (rad^2) variances.
std::array<double, 36> diagonalCovariance(double var_pos_m2, double var_rot_rad2);

}  // namespace conv
}  // namespace depth_track
