#pragma once
// The one ROS adapter for parameters: the core stages' tables (tracker_params, mapper_params) and
// the nodelets' own parameters (their table is nodeParams() below) read from the parameter
// server, each starting from the struct's or the table's default, validated all at once. A bad
// value throws ParamError whose message names every offending parameter with its resolved name,
// the value and what is allowed; onInit lets it stop the nodelet. Every parameter is documented
// in config/tracking.yaml (a test keeps the file equal to these tables).
#include <ros/node_handle.h>

#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "depth_track/core/param_table.hpp"

namespace depth_track {
namespace rosparams {

class ParamError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A nodelet's own parameter (not a core stage's).
struct NodeParamSpec {
  std::string node;  ///< nodelet name as in config/tracking.yaml ("ingest", "registration", ...)
  std::string name;
  char type = 'd';  ///< 'd' double, 'i' int, 'b' bool, 's' string
  std::string unit, help;
  std::string default_text;
  double min = -std::numeric_limits<double>::infinity();  ///< numbers: allowed closed range
  double max = std::numeric_limits<double>::infinity();
  std::vector<std::string> choices;  ///< strings: allowed values (empty = any)
};

/// Every nodelet parameter. Thread-safe.
const std::vector<NodeParamSpec>& nodeParams();

/// A parameter that dynamic_reconfigure may change while the graph runs: a row of a stage table
/// (`table` "tracker" | "mapper": name, unit, meaning and default come from that row) or of
/// nodeParams() (`table` empty: its range too). The range is what the server offers and
/// enforces before the stage's validate() sees the value; dt_test_ros_conversions checks that
/// validate() accepts both ends and the default lies inside.
struct ReconfigurableSpec {
  std::string node;   ///< the nodelet that serves it
  std::string table;  ///< "tracker" | "mapper" | "" (the nodelet's own, nodeParams())
  std::string name;
  char type = 'd';  ///< 'd' double, 'i' int, 'b' bool, 's' one of `choices`
  double min = 0.0, max = 0.0;
  std::vector<std::string> choices;
};

/// Every runtime-reconfigurable parameter (ranges of the node parameters filled from
/// nodeParams()). Thread-safe.
const std::vector<ReconfigurableSpec>& reconfigurableParams();
/// The nodelet names of nodeParams(), in order of first appearance.
std::vector<std::string> nodeNames();

/// A parameter value of any XmlRpc scalar type as the text the tables parse ("" and false for
/// a missing key). Doubles keep all 17 digits.
bool readText(const ros::NodeHandle& nh, const std::string& key, std::string* text);

/// Reads one nodelet's parameters and the stage tables it needs, collecting every problem;
/// finish() throws them as one ParamError.
class ParamReader {
 public:
  /// `node` selects the nodelet's rows of nodeParams(); they are read from `private_nh`.
  ParamReader(const ros::NodeHandle& private_nh, std::string node);

  double getDouble(const std::string& name);
  int getInt(const std::string& name);
  bool getBool(const std::string& name);
  std::string getString(const std::string& name);

  /// Applies the parameters of `table` found under `nh` onto `config` (the struct's values are
  /// the defaults), then runs `validate` and names, for each problem, the parameters whose value
  /// alone causes it (each set parameter tried on its own against the defaults). Keys under
  /// `nh` that the table does not know are problems too (a typo must not pass silently).
  /// With a `prefix` the rows are read as `prefix + name` from `nh` among other keys (a
  /// nodelet's private ones: its nodeParams() rows, which the constructor checks), so keys the
  /// table does not know are left alone.
  template <class Config>
  Config table(const ros::NodeHandle& nh, const std::vector<BasicParamSpec<Config>>& table,
               Config config,
               const std::function<std::vector<std::string>(const Config&)>& validate,
               const std::string& prefix = "");

  /// Adds a problem found elsewhere (e.g. a value combination the node checks itself).
  void problem(const std::string& text) { problems_.push_back(text); }
  /// Throws ParamError listing every problem ("node: invalid parameters: a; b").
  void finish() const;

 private:
  const NodeParamSpec& spec(const std::string& name, char type) const;
  std::string raw(const std::string& name, char type);

  ros::NodeHandle nh_;
  std::string node_;
  std::vector<std::string> problems_;
};

// ---- implementation of the template ----------------------------------------------------------

/// Names of the parameters present under nh (relative to it, one level deep).
std::vector<std::string> keysUnder(const ros::NodeHandle& nh);

template <class Config>
Config ParamReader::table(const ros::NodeHandle& nh,
                          const std::vector<BasicParamSpec<Config>>& table, Config config,
                          const std::function<std::vector<std::string>(const Config&)>& validate,
                          const std::string& prefix) {
  const Config defaults = config;
  std::vector<std::pair<std::string, std::string>> set;  // (name, text)
  if (prefix.empty())
    for (const auto& key : keysUnder(nh)) {
      bool known = false;
      for (const auto& p : table) known = known || p.name == key;
      if (!known) problems_.push_back(nh.resolveName(key) + ": unknown parameter");
    }
  for (const auto& p : table) {
    std::string text;
    if (!readText(nh, prefix + p.name, &text)) continue;
    try {
      p.set(config, text);
      set.emplace_back(p.name, text);
    } catch (const std::invalid_argument& e) {
      problems_.push_back(nh.resolveName(prefix + p.name) + " = '" + text + "': " + e.what());
    }
  }
  for (const std::string& prob : validate(config)) {
    std::string who;
    for (const auto& [name, text] : set) {
      Config alone = defaults;
      for (const auto& p : table)
        if (p.name == name) p.set(alone, text);
      for (const std::string& q : validate(alone))
        if (q == prob)
          who += (who.empty() ? "" : ", ") + nh.resolveName(prefix + name) + " = " + text;
    }
    problems_.push_back((who.empty() ? nh.getNamespace() + ": " : who + ": ") + prob);
  }
  return config;
}

}  // namespace rosparams
}  // namespace depth_track
