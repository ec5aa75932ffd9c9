#include "depth_track/core/depth_image.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>

namespace depth_track {

DepthEncoding parseDepthEncoding(const std::string& encoding) {
  if (encoding == "16UC1" || encoding == "mono16") return DepthEncoding::kU16;
  if (encoding == "32FC1") return DepthEncoding::kF32;
  throw DepthInputError("unsupported depth encoding '" + encoding +
                        "' (expected 16UC1, mono16 or 32FC1)");
}

std::size_t DepthImage::countValid() const {
  return static_cast<std::size_t>(
      std::count_if(data.begin(), data.end(), [](float d) { return d > 0.0f; }));
}

DepthImage depthFromRaw(const void* data, int width, int height, std::size_t step_bytes,
                        DepthEncoding encoding, double depth_scale_m, const DepthRange& range) {
  if (data == nullptr) throw DepthInputError("depth frame has no data");
  if (width <= 0 || height <= 0) {
    std::ostringstream s;
    s << "depth frame size " << width << "x" << height << " is empty";
    throw DepthInputError(s.str());
  }
  const std::size_t bpp = encoding == DepthEncoding::kU16 ? 2 : 4;
  if (step_bytes < bpp * static_cast<std::size_t>(width)) {
    std::ostringstream s;
    s << "depth row step " << step_bytes << " bytes is smaller than width " << width << " x " << bpp
      << " bytes";
    throw DepthInputError(s.str());
  }
  if (encoding == DepthEncoding::kU16 && !(std::isfinite(depth_scale_m) && depth_scale_m > 0.0))
    throw DepthInputError("depth scale must be a positive number of metres per unit");

  DepthImage out(width, height);
  const float lo = static_cast<float>(range.min_m);
  const float hi = static_cast<float>(range.max_m);
  const auto* bytes = static_cast<const unsigned char*>(data);
  const float scale = static_cast<float>(depth_scale_m);
  for (int v = 0; v < height; ++v) {
    const unsigned char* row = bytes + step_bytes * static_cast<std::size_t>(v);
    float* dst = out.data.data() + static_cast<std::size_t>(v) * width;
    for (int u = 0; u < width; ++u) {
      float d;
      if (encoding == DepthEncoding::kU16) {
        std::uint16_t raw;
        std::memcpy(&raw, row + 2 * u, 2);  // rows of an image message need not be aligned
        d = raw * scale;
      } else {
        std::memcpy(&d, row + 4 * u, 4);
      }
      // NaN fails both comparisons, +Inf fails the upper one: both end as "no return".
      dst[u] = (d >= lo && d <= hi && d > 0.0f) ? d : 0.0f;
    }
  }
  return out;
}

void checkFrameSize(const DepthImage& depth, const PinholeIntrinsics& intrinsics) {
  if (depth.width != intrinsics.width || depth.height != intrinsics.height) {
    std::ostringstream s;
    s << "depth frame is " << depth.width << "x" << depth.height
      << " px but the camera intrinsics are for " << intrinsics.width << "x" << intrinsics.height
      << " px";
    throw DepthInputError(s.str());
  }
  if (depth.data.size() != static_cast<std::size_t>(depth.width) * depth.height)
    throw DepthInputError("depth frame buffer size does not match its width x height");
}

}  // namespace depth_track
