#include "depth_track/core/reconstruction.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace depth_track {

std::vector<std::string> ReconstructionConfig::validate() const {
  std::vector<std::string> problems;
  if (!(std::isfinite(min_ray_cos) && min_ray_cos > 0.0 && min_ray_cos < 1.0))
    problems.push_back("min_ray_cos must lie in (0, 1)");
  if (!(std::isfinite(max_depth_sigmas) && max_depth_sigmas > 0.0))
    problems.push_back("max_depth_sigmas must be positive");
  if (!(std::isfinite(depth_margin_m) && depth_margin_m >= 0.0))
    problems.push_back("depth_margin_m must be >= 0 m");
  return problems;
}

DepthImage reconstructDepth(const CellCloud& cloud, const PinholeIntrinsics& k,
                            const ReconstructionConfig& config) {
  const auto bad_config = config.validate();
  if (!bad_config.empty())
    throw std::invalid_argument("invalid reconstruction config: " + joinProblems(bad_config));
  const auto bad_k = k.validate();
  if (!bad_k.empty()) throw DepthInputError("invalid intrinsics: " + joinProblems(bad_k));
  const int n = cloud.cell_size;
  if (n <= 0 || cloud.grid_w < 0 || cloud.grid_h < 0 ||
      static_cast<long>(n) * cloud.grid_w > k.width ||
      static_cast<long>(n) * cloud.grid_h > k.height ||
      cloud.grid_index.size() != static_cast<std::size_t>(cloud.grid_w) * cloud.grid_h) {
    std::ostringstream s;
    s << "cell grid " << cloud.grid_w << "x" << cloud.grid_h << " of " << n << " px cells ("
      << cloud.grid_index.size() << " index entries) does not fit a " << k.width << "x" << k.height
      << " image";
    throw DepthInputError(s.str());
  }

  DepthImage out(k.width, k.height);
  for (const Cell& c : cloud.cells) {
    if (c.gx < 0 || c.gy < 0 || c.gx >= cloud.grid_w || c.gy >= cloud.grid_h) {
      std::ostringstream s;
      s << "cell at grid (" << c.gx << ", " << c.gy << ") lies outside the " << cloud.grid_w << "x"
        << cloud.grid_h << " grid";
      throw DepthInputError(s.str());
    }
    const Eigen::Vector3d mean = c.mean_C.cast<double>();
    Eigen::Vector3d normal = c.normal_C.cast<double>();
    const double sigma_z = std::sqrt(std::max(0.0, static_cast<double>(c.cov(2, 2))));
    if (!mean.allFinite() || !normal.allFinite() || !(normal.norm() > 1e-9) ||
        !std::isfinite(sigma_z) || !(mean.z() > 0.0))
      continue;
    normal.normalize();
    // Every point p of the plane satisfies normal . p = normal . mean (eq. 3.5); a pixel's ray is
    // p = z r with r = ((u - cx) / fx, (v - cy) / fy, 1), so z = (normal . mean) / (normal . r).
    const double offset = normal.dot(mean);
    const double max_dev = config.max_depth_sigmas * sigma_z + config.depth_margin_m;
    for (int v = c.gy * n; v < (c.gy + 1) * n; ++v) {
      const double ry = (v - k.cy) / k.fy;
      for (int u = c.gx * n; u < (c.gx + 1) * n; ++u) {
        const Eigen::Vector3d r((u - k.cx) / k.fx, ry, 1.0);
        const double denom = normal.dot(r);
        if (std::abs(denom) < config.min_ray_cos * r.norm()) continue;  // grazing ray
        const double z = offset / denom;
        if (!(z > 0.0) || std::abs(z - mean.z()) > max_dev) continue;
        out.at(u, v) = static_cast<float>(z);
      }
    }
  }
  return out;
}

DepthDifference compareDepth(const DepthImage& a, const DepthImage& b) {
  if (a.width != b.width || a.height != b.height || a.data.size() != b.data.size()) {
    std::ostringstream s;
    s << "cannot compare a " << a.width << "x" << a.height << " depth frame with a " << b.width
      << "x" << b.height << " one";
    throw DepthInputError(s.str());
  }
  DepthDifference d;
  double sum = 0.0, sum2 = 0.0;
  std::vector<float> abs_err;
  abs_err.reserve(a.data.size());
  for (std::size_t i = 0; i < a.data.size(); ++i) {
    const bool va = a.data[i] > 0.0f, vb = b.data[i] > 0.0f;
    if (va && !vb) ++d.only_in_a;
    if (vb && !va) ++d.only_in_b;
    if (!(va && vb)) continue;
    const double e = static_cast<double>(b.data[i]) - a.data[i];
    sum += e;
    sum2 += e * e;
    d.max_abs_m = std::max(d.max_abs_m, std::abs(e));
    abs_err.push_back(static_cast<float>(std::abs(e)));
    ++d.compared;
  }
  if (d.compared > 0) {
    d.mean_m = sum / d.compared;
    d.rms_m = std::sqrt(sum2 / d.compared);
    const auto mid = abs_err.begin() + static_cast<std::ptrdiff_t>(abs_err.size() / 2);
    std::nth_element(abs_err.begin(), mid, abs_err.end());
    d.median_abs_m = *mid;
  }
  return d;
}

}  // namespace depth_track
