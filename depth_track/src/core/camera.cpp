#include "depth_track/core/camera.hpp"

#include <cmath>
#include <sstream>

namespace depth_track {

PinholeIntrinsics PinholeIntrinsics::isotropic(int width, int height, double k_px) {
  PinholeIntrinsics k;
  k.width = width;
  k.height = height;
  k.fx = k.fy = k_px;
  k.cx = width / 2.0;
  k.cy = height / 2.0;
  return k;
}

std::vector<std::string> PinholeIntrinsics::validate() const {
  std::vector<std::string> problems;
  if (width <= 0 || height <= 0) {
    std::ostringstream s;
    s << "image size " << width << "x" << height << " px must be positive";
    problems.push_back(s.str());
  }
  if (!(std::isfinite(fx) && fx > 0.0)) problems.push_back("fx must be a positive pixel count");
  if (!(std::isfinite(fy) && fy > 0.0)) problems.push_back("fy must be a positive pixel count");
  if (!std::isfinite(cx) || cx < 0.0 || cx > width)
    problems.push_back("cx must lie inside the image width");
  if (!std::isfinite(cy) || cy < 0.0 || cy > height)
    problems.push_back("cy must lie inside the image height");
  return problems;
}

std::vector<std::string> DepthRange::validate() const {
  std::vector<std::string> problems;
  if (!(std::isfinite(min_m) && min_m >= 0.0)) problems.push_back("d_min_m must be >= 0 m");
  if (!(std::isfinite(max_m) && max_m > min_m)) problems.push_back("d_max_m must exceed d_min_m");
  return problems;
}

std::string joinProblems(const std::vector<std::string>& problems) {
  std::string out;
  for (const auto& p : problems) {
    if (!out.empty()) out += "; ";
    out += p;
  }
  return out;
}

}  // namespace depth_track
