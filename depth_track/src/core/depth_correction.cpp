#include "depth_track/core/depth_correction.hpp"

#include <cmath>
#include <stdexcept>

#include "depth_track/core/yaml_section.hpp"

namespace depth_track {

std::vector<std::string> DepthCorrection::validate() const {
  std::vector<std::string> p;
  // A camera that reads more than 20 % off is broken or mis-configured (wrong depth unit), not
  // something to correct silently.
  if (!(std::isfinite(scale) && scale >= 0.8 && scale <= 1.2))
    p.push_back("scale must be in 0.8..1.2 (reported metres per true metre)");
  if (!(std::isfinite(offset_m) && std::abs(offset_m) <= 0.2))
    p.push_back("offset_m must be within +-0.2 m");
  return p;
}

void applyDepthCorrection(DepthImage& depth, const DepthCorrection& c) {
  const auto problems = c.validate();
  if (!problems.empty()) throw std::invalid_argument("DepthCorrection: " + joinProblems(problems));
  if (c.isIdentity()) return;
  const float inv_scale = static_cast<float>(1.0 / c.scale);
  const float offset = static_cast<float>(c.offset_m);
  for (float& z : depth.data) {
    if (!(z > 0.0f)) continue;
    const float t = (z - offset) * inv_scale;
    z = t > 0.0f ? t : 0.0f;
  }
}

DepthCorrection loadDepthCorrectionYaml(const std::string& path) {
  const std::string section = "depth_correction";
  DepthCorrection c;
  for (const auto& [key, value] : readYamlSection(path, section)) {
    if (key == "scale")
      c.scale = yamlNumber(path, section, key, value);
    else if (key == "offset_m")
      c.offset_m = yamlNumber(path, section, key, value);
    else
      throw std::invalid_argument(
          yamlProblem(path, section, key, value.line, "unknown key (known: scale, offset_m)"));
  }
  const auto problems = c.validate();
  if (!problems.empty())
    throw std::invalid_argument(path + ": " + section + ": " + joinProblems(problems));
  return c;
}

}  // namespace depth_track
