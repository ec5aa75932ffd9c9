#pragma once
/// The tracker's parameters as one table: name, unit, meaning, and typed get/set on a
/// TrackerConfig. Every front end reads it — the offline tools' command-line options, YAML
/// config files and (in the ROS adapter) private parameters — so a parameter is declared once.
#include <string>
#include <vector>

#include "depth_track/core/param_table.hpp"
#include "depth_track/core/tracker.hpp"

namespace depth_track {

using ParamSpec = BasicParamSpec<TrackerConfig>;

/// All tracker parameters (prefilter, PCA, matching, registration, tracker). Thread-safe.
const std::vector<ParamSpec>& trackerParams();

/// Sets parameter `name` from text; throws std::invalid_argument naming the parameter and value
/// (unknown name, not a number, not one of the choices).
void setTrackerParam(TrackerConfig& config, const std::string& name, const std::string& value);

/// Applies a flat YAML map of parameter names to values (a `tracker:` top-level key is also
/// accepted). Throws std::invalid_argument naming the file, line and key of any problem.
void loadTrackerParamsYaml(const std::string& path, TrackerConfig& config);

}  // namespace depth_track
