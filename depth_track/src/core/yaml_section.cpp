#include "depth_track/core/yaml_section.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <stdexcept>

namespace depth_track {

std::vector<std::pair<std::string, YamlScalar>> readYamlSection(const std::string& path,
                                                                const std::string& section) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::invalid_argument(path + ": cannot open the file");
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(path + ":" + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
  if (!root.IsMap() || !root[section])
    throw std::invalid_argument(path + ": no '" + section + ":' section");
  const YAML::Node node = root[section];
  if (!node.IsMap())
    throw std::invalid_argument(
        yamlProblem(path, section, "", node.Mark().line + 1, "must be a map of key: value lines"));
  std::vector<std::pair<std::string, YamlScalar>> out;
  for (const auto& kv : node) {
    const std::string key = kv.first.as<std::string>();
    const int line = kv.first.Mark().line + 1;
    if (!kv.second.IsScalar())
      throw std::invalid_argument(yamlProblem(path, section, key, line, "must be a single value"));
    out.push_back({key, YamlScalar{kv.second.as<std::string>(), line}});
  }
  return out;
}

double yamlNumber(const std::string& path, const std::string& section, const std::string& key,
                  const YamlScalar& value) {
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(value.text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != value.text.size() || !std::isfinite(v))
    throw std::invalid_argument(yamlProblem(path, section, key, value.line,
                                            "cannot read '" + value.text + "' as a number"));
  return v;
}

std::string yamlProblem(const std::string& path, const std::string& section, const std::string& key,
                        int line, const std::string& what) {
  std::string s = path;
  if (line > 0) s += ":" + std::to_string(line);
  s += ": " + section;
  if (!key.empty()) s += "." + key;
  return s + ": " + what;
}

}  // namespace depth_track
