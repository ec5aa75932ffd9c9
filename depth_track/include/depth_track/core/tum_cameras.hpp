#pragma once
/// The TUM RGB-D benchmark's published Kinect calibrations (Freiburg 1, 2, 3) and its depth unit,
/// for what reads TUM folders (track_sequence, tum_to_bag, the depth_camera node's tum backend,
/// the peer benchmarks). The benchmark registers its depth images to the colour camera, so these
/// are the colour camera's intrinsics. Header-only, ROS-free, thread-safe.
#include <array>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>

#include "depth_track/core/camera.hpp"

namespace depth_track {

/// Metres per unit of a TUM depth PNG (the benchmark stores 5000 units per metre).
inline constexpr double kTumDepthScaleM = 1.0 / 5000.0;

struct TumCamera {
  const char* name;  ///< "fr1", "fr2", "fr3"
  double fx, fy, cx, cy;
  bool distorted;  ///< the benchmark publishes lens distortion its images still carry (fr1, fr2)
};

/// The three cameras, as published with the benchmark (640x480).
inline const std::array<TumCamera, 3>& tumCameras() {
  static const std::array<TumCamera, 3> cameras{{
      {"fr1", 517.3, 516.5, 318.6, 255.3, true},
      {"fr2", 520.9, 521.0, 325.1, 249.7, true},
      {"fr3", 535.4, 539.2, 320.1, 247.6, false},
  }};
  return cameras;
}

/// Intrinsics (640x480) of camera `name` ("fr1" | "fr2" | "fr3"); nullopt for any other name.
inline std::optional<PinholeIntrinsics> tumIntrinsics(const std::string& name) {
  for (const TumCamera& c : tumCameras()) {
    if (name != c.name) continue;
    PinholeIntrinsics k;
    k.width = 640;
    k.height = 480;
    k.fx = c.fx, k.fy = c.fy, k.cx = c.cx, k.cy = c.cy;
    return k;
  }
  return std::nullopt;
}

/// The camera a TUM sequence name implies ("rgbd_dataset_freiburg3_teddy" -> "fr3"), or "" when
/// the text names none. Only a hint for error messages: the user chooses the camera.
inline std::string tumCameraHint(const std::string& text) {
  const auto at = text.find("freiburg");
  if (at == std::string::npos || at + 8 >= text.size()) return "";
  const char digit = text[at + 8];
  return digit >= '1' && digit <= '3' ? std::string("fr") + digit : "";
}

/// The camera a folder's name or its depth.txt header points at ("fr3"), or "": a hint only.
inline std::string folderCameraHint(const std::string& dir) {
  std::ifstream in(dir + "/depth.txt");
  std::error_code ec;
  std::string line, text = std::filesystem::absolute(dir, ec).string();
  for (int i = 0; i < 5 && std::getline(in, line); ++i) text += " " + line;
  return tumCameraHint(text);
}

}  // namespace depth_track
