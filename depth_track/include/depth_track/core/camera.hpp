#pragma once
/// Pinhole camera model and the valid depth range (ROS-free core).
#include <Eigen/Core>
#include <string>
#include <vector>

namespace depth_track {

/// Pinhole intrinsics in pixels. Pixel (u, v) = (column, row), origin at the centre of the top-left
/// pixel; the optical frame is x right, y down, z forward (REP 103 optical convention).
struct PinholeIntrinsics {
  int width = 640;                                ///< image width in pixels
  int height = 480;                               ///< image height in pixels
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;  ///< focal lengths and principal point, pixels

  /// The thesis's isotropic camera: one projection constant k for both axes, centre at (W/2, H/2).
  static PinholeIntrinsics isotropic(int width, int height, double k_px);
  /// Every problem with these intrinsics (empty = valid).
  std::vector<std::string> validate() const;
  /// Camera-frame point p_C (metres) of pixel (u, v) at depth z_m. Thread-safe.
  Eigen::Vector3f backProject(float u, float v, float z_m) const {
    return {static_cast<float>((u - cx) / fx) * z_m, static_cast<float>((v - cy) / fy) * z_m, z_m};
  }
  /// Projects p_C into pixel coordinates; false when behind the camera (z <= 0). Thread-safe.
  bool project(const Eigen::Vector3f& p_C, float* u, float* v) const {
    if (!(p_C.z() > 0.0f)) return false;
    *u = static_cast<float>(fx * p_C.x() / p_C.z() + cx);
    *v = static_cast<float>(fy * p_C.y() / p_C.z() + cy);
    return true;
  }
  /// True when (u, v) lies inside the image (pixel centres, with a margin in pixels).
  bool inImage(float u, float v, float margin_px = 0.0f) const {
    return u >= -0.5f + margin_px && v >= -0.5f + margin_px && u < width - 0.5f - margin_px &&
           v < height - 0.5f - margin_px;
  }
};

/// Valid depth interval of the sensor in metres; readings outside count as "no return".
/// Defaults are the Intel RealSense L515's (0.53 m to 4.0 m in the thesis's configuration).
struct DepthRange {
  double min_m = 0.53;
  double max_m = 4.0;
  std::vector<std::string> validate() const;
};

/// Joins a list of problems into one message ("a; b; c").
std::string joinProblems(const std::vector<std::string>& problems);

}  // namespace depth_track
