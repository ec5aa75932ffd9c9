#pragma once
/// The tracker's parameters as one table: name, unit, meaning, and typed get/set on a
/// TrackerConfig. Every front end reads it — the offline tools' command-line options, YAML
/// config files and (in the ROS adapter) private parameters — so a parameter is declared once.
#include <functional>
#include <string>
#include <vector>

#include "depth_track/core/tracker.hpp"

namespace depth_track {

struct ParamSpec {
  std::string name;  ///< snake_case key ("dist_min"); command-line option "--dist-min"
  std::string unit;  ///< "m", "deg", "px", "" for dimensionless / choices
  std::string help;  ///< one line of meaning
  std::function<std::string(const TrackerConfig&)> get;         ///< value as text
  std::function<void(TrackerConfig&, const std::string&)> set;  ///< throws std::invalid_argument
};

/// All tracker parameters (prefilter, PCA, matching, registration, tracker). Thread-safe.
const std::vector<ParamSpec>& trackerParams();

/// Sets parameter `name` from text; throws std::invalid_argument naming the parameter and value
/// (unknown name, not a number, not one of the choices).
void setTrackerParam(TrackerConfig& config, const std::string& name, const std::string& value);

/// Applies a flat YAML map of parameter names to values (a `tracker:` top-level key is also
/// accepted). Throws std::invalid_argument naming the file, line and key of any problem.
void loadTrackerParamsYaml(const std::string& path, TrackerConfig& config);

}  // namespace depth_track
