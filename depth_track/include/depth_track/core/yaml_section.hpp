#pragma once
/// Reading one flat section of a YAML file with errors that name file, line and key (ROS-free
/// core; yaml-cpp stays inside the core library). Used by the loaders of camera_check's output.
#include <string>
#include <utility>
#include <vector>

namespace depth_track {

/// One scalar value of a YAML map: its text and its 1-based line in the file.
struct YamlScalar {
  std::string text;
  int line = 0;
};

/// The key/value pairs, in file order, of the map under the top-level key `section` of YAML file
/// `path`. Throws std::invalid_argument naming the file (and line) when it cannot be read or
/// parsed, has no such section, the section is not a map, or a value is not a single scalar.
/// Thread-safe.
std::vector<std::pair<std::string, YamlScalar>> readYamlSection(const std::string& path,
                                                                const std::string& section);

/// The value as a finite number; throws std::invalid_argument "path:line: section.key: cannot
/// read 'text' as a number". Thread-safe.
double yamlNumber(const std::string& path, const std::string& section, const std::string& key,
                  const YamlScalar& value);

/// "path:line: section.key: what", the form of every loader error.
std::string yamlProblem(const std::string& path, const std::string& section, const std::string& key,
                        int line, const std::string& what);

}  // namespace depth_track
