#pragma once
/// Depth frames in metres and the single place where raw encodings are converted (ROS-free core).
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"

namespace depth_track {

/// Thrown for input that cannot be turned into a depth frame; the message names what was wrong.
class DepthInputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Raw depth encodings the pipeline accepts.
enum class DepthEncoding {
  kU16,  ///< "16UC1" / "mono16": unsigned integer units times a depth scale (m per unit)
  kF32,  ///< "32FC1": metres as float
};

/// Parses a ROS/OpenCV encoding name; throws DepthInputError naming any other encoding.
DepthEncoding parseDepthEncoding(const std::string& encoding);

/// A dense depth frame in metres, row-major. 0 means "no return" (also used for NaN, Inf and
/// readings outside the valid range after conversion).
struct DepthImage {
  int width = 0;
  int height = 0;
  std::vector<float> data;  ///< width * height depths in metres

  DepthImage() = default;
  DepthImage(int w, int h, float fill = 0.0f)
      : width(w), height(h), data(static_cast<std::size_t>(w) * h, fill) {}
  float at(int u, int v) const { return data[static_cast<std::size_t>(v) * width + u]; }
  float& at(int u, int v) { return data[static_cast<std::size_t>(v) * width + u]; }
  bool empty() const { return data.empty(); }
  /// Number of pixels with a valid (non-zero) depth.
  std::size_t countValid() const;
};

/// Converts a raw frame (row stride in bytes) into metres. 16-bit values are multiplied by
/// depth_scale_m (e.g. 0.001 for RealSense D4xx / ROS drivers, 0.00025 for L515 raw, 0.0002 for
/// TUM); 32-bit values are metres. 0, NaN, Inf and values outside `range` become 0.
/// Throws DepthInputError for a null buffer, a stride too small for the width, or a bad scale.
DepthImage depthFromRaw(const void* data, int width, int height, std::size_t step_bytes,
                        DepthEncoding encoding, double depth_scale_m, const DepthRange& range);

/// Throws DepthInputError when the frame's size differs from the intrinsics' image size.
void checkFrameSize(const DepthImage& depth, const PinholeIntrinsics& intrinsics);

}  // namespace depth_track
