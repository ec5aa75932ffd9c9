#pragma once
// Runtime reconfiguration of a nodelet through the dynamic_reconfigure protocol
// (~parameter_descriptions, ~parameter_updates, ~set_parameters), served straight from the
// parameter tables (rosparams::reconfigurableParams() over the core's tracker / mapper tables
// and nodeParams()), so names, units, meanings, defaults and ranges exist once; rqt_reconfigure
// and dynamic_reconfigure's clients see it like a generated server. A request is checked against
// the ranges, then the stage's validate() on the whole changed config; a refused request changes
// nothing and each refused value is logged with its name and range. An accepted one waits until
// the nodelet's worker takes it between two frames (takePending), never mid-frame.
#include <dynamic_reconfigure/ConfigDescription.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <ros/ros.h>

#include <functional>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "depth_track/core/param_table.hpp"
#include "depth_track/ros/params.hpp"

namespace depth_track {
namespace graph {

/// The reconfigurable parameters of one nodelet over its state (a config struct or a few).
template <class State>
class RuntimeParams {
 public:
  struct Entry {
    rosparams::ReconfigurableSpec spec;
    std::string description;  ///< "[unit] meaning"
    std::function<std::string(const State&)> get;
    std::function<void(State&, const std::string&)> set;  ///< throws std::invalid_argument
  };
  using Validate = std::function<std::vector<std::string>(const State&)>;

  /// Binds the rows of reconfigurableParams() for `node` that live in stage table `table_name`
  /// to `part(state)`.
  template <class Config, class Part>
  void bindTable(const std::string& node, const std::string& table_name,
                 const std::vector<BasicParamSpec<Config>>& table, Part part) {
    for (const auto& r : rosparams::reconfigurableParams()) {
      if (r.node != node || r.table != table_name) continue;
      const BasicParamSpec<Config>* row = nullptr;
      for (const auto& p : table)
        if (p.name == r.name) row = &p;
      if (!row) throw std::logic_error("reconfigurable " + r.name + " is not in " + table_name);
      entries_.push_back(
          {r, describe(row->unit, row->help),
           [row, part](const State& s) { return row->get(part(const_cast<State&>(s))); },
           [row, part](State& s, const std::string& v) { row->set(part(s), v); }});
    }
  }
  /// Binds a nodelet's own reconfigurable parameter (a double of nodeParams()) to `member`.
  void bindNodeParam(const std::string& node, const std::string& name,
                     std::function<double&(State&)> member) {
    for (const auto& r : rosparams::reconfigurableParams())
      if (r.node == node && r.table.empty() && r.name == name)
        for (const auto& p : rosparams::nodeParams())
          if (p.node == node && p.name == name)
            entries_.push_back({r, describe(p.unit, p.help),
                                [member](const State& s) {
                                  return param_text::format(member(const_cast<State&>(s)));
                                },
                                [member, name](State& s, const std::string& v) {
                                  member(s) = param_text::toDouble(name, v);
                                }});
  }

  /// Advertises the server under `pnh` with `state` as the current values (their defaults are
  /// `defaults`: the tables' values before the launch file's).
  void start(ros::NodeHandle& pnh, const std::string& who, const State& state,
             const State& defaults, Validate validate) {
    who_ = who;
    current_ = state;
    validate_ = std::move(validate);
    descr_pub_ =
        pnh.advertise<dynamic_reconfigure::ConfigDescription>("parameter_descriptions", 1, true);
    update_pub_ = pnh.advertise<dynamic_reconfigure::Config>("parameter_updates", 1, true);
    descr_pub_.publish(description(defaults));
    update_pub_.publish(toConfig(current_));
    srv_ = pnh.advertiseService("set_parameters", &RuntimeParams::onSet, this);
  }

  /// The state of the last accepted request, once; the worker applies it between frames.
  std::optional<State> takePending() {
    std::lock_guard<std::mutex> lock(mutex_);
    std::optional<State> out;
    out.swap(pending_);
    return out;
  }

 private:
  static std::string describe(const std::string& unit, const std::string& help) {
    return (unit.empty() ? "" : "[" + unit + "] ") + help;
  }
  static const char* typeName(char t) {
    return t == 'i' ? "int" : t == 'b' ? "bool" : t == 's' ? "str" : "double";
  }

  dynamic_reconfigure::Config toConfig(const State& s) const {
    dynamic_reconfigure::Config c;
    for (const Entry& e : entries_) put(c, e.spec.type, e.spec.name, e.get(s));
    dynamic_reconfigure::GroupState g;
    g.name = "Default", g.state = true, g.id = 0, g.parent = 0;
    c.groups.push_back(g);
    return c;
  }
  static void put(dynamic_reconfigure::Config& c, char type, const std::string& name,
                  const std::string& text) {
    if (type == 'i') {
      dynamic_reconfigure::IntParameter p;
      p.name = name, p.value = param_text::toInt(name, text);
      c.ints.push_back(p);
    } else if (type == 'b') {
      dynamic_reconfigure::BoolParameter p;
      p.name = name, p.value = param_text::toBool(name, text);
      c.bools.push_back(p);
    } else if (type == 's') {
      dynamic_reconfigure::StrParameter p;
      p.name = name, p.value = text;
      c.strs.push_back(p);
    } else {
      dynamic_reconfigure::DoubleParameter p;
      p.name = name, p.value = param_text::toDouble(name, text);
      c.doubles.push_back(p);
    }
  }

  dynamic_reconfigure::ConfigDescription description(const State& defaults) const {
    dynamic_reconfigure::ConfigDescription d;
    dynamic_reconfigure::Group g;
    g.name = "Default", g.type = "", g.id = 0, g.parent = 0;
    for (const Entry& e : entries_) {
      dynamic_reconfigure::ParamDescription p;
      p.name = e.spec.name;
      p.type = typeName(e.spec.type);
      p.level = 0;
      p.description = e.description;
      if (e.spec.type == 's') {  // an enum, in the form rqt_reconfigure reads
        std::ostringstream m;
        m << "{'enum': [";
        for (std::size_t i = 0; i < e.spec.choices.size(); ++i)
          m << (i ? ", " : "") << "{'name': '" << e.spec.choices[i]
            << "', 'type': 'str', 'value': '" << e.spec.choices[i]
            << "', 'srcline': 0, 'srcfile': '', 'description': '" << e.spec.choices[i]
            << "', 'ctype': 'std::string', 'cconsttype': 'const char * const'}";
        m << "], 'enum_description': 'one of the choices'}";
        p.edit_method = m.str();
      }
      g.parameters.push_back(p);
      const std::string lo = e.spec.type == 'b' ? "false" : param_text::format(e.spec.min);
      const std::string hi = e.spec.type == 'b' ? "true" : param_text::format(e.spec.max);
      put(d.min, e.spec.type, e.spec.name, e.spec.type == 's' ? "" : lo);
      put(d.max, e.spec.type, e.spec.name, e.spec.type == 's' ? "" : hi);
      put(d.dflt, e.spec.type, e.spec.name, e.get(defaults));
    }
    d.groups.push_back(g);
    dynamic_reconfigure::GroupState gs;
    gs.name = "Default", gs.state = true, gs.id = 0, gs.parent = 0;
    d.min.groups.push_back(gs), d.max.groups.push_back(gs), d.dflt.groups.push_back(gs);
    return d;
  }

  /// The request's values as (name, text) pairs.
  static std::vector<std::pair<std::string, std::string>> texts(
      const dynamic_reconfigure::Config& c) {
    std::vector<std::pair<std::string, std::string>> out;
    for (const auto& p : c.ints) out.emplace_back(p.name, std::to_string(p.value));
    for (const auto& p : c.doubles) {  // 15 digits: what a user typed, read back exactly
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.15g", p.value);
      out.emplace_back(p.name, buf);
    }
    for (const auto& p : c.bools) out.emplace_back(p.name, p.value ? "true" : "false");
    for (const auto& p : c.strs) out.emplace_back(p.name, p.value);
    return out;
  }

  bool onSet(dynamic_reconfigure::Reconfigure::Request& req,
             dynamic_reconfigure::Reconfigure::Response& res) {
    std::lock_guard<std::mutex> lock(mutex_);
    State candidate = current_;
    std::vector<std::string> problems;
    std::string changed;
    for (const auto& [name, text] : texts(req.config)) {
      const Entry* e = nullptr;
      for (const Entry& x : entries_) e = x.spec.name == name ? &x : e;
      if (!e) {
        problems.push_back(name + ": not reconfigurable at runtime here");
        continue;
      }
      if (e->get(candidate) == text) continue;
      try {
        if (e->spec.type == 'd' || e->spec.type == 'i') {
          const double v = param_text::toDouble(name, text);
          if (v < e->spec.min || v > e->spec.max)
            throw std::invalid_argument("must lie in [" + param_text::format(e->spec.min) + ", " +
                                        param_text::format(e->spec.max) + "]");
        } else if (e->spec.type == 's') {
          bool ok = false;
          std::string all;
          for (const auto& c : e->spec.choices) {
            ok = ok || c == text;
            all += (all.empty() ? "" : " | ") + c;
          }
          if (!ok) throw std::invalid_argument("must be " + all);
        }
        e->set(candidate, text);
        changed += (changed.empty() ? "" : ", ") + name + " = " + text;
      } catch (const std::invalid_argument& ex) {
        problems.push_back(name + " = " + text + ": " + ex.what() + " " + e->description);
      }
    }
    if (problems.empty())
      for (const std::string& p : validate_(candidate)) problems.push_back(changed + ": " + p);
    if (!problems.empty()) {
      std::string all;
      for (const auto& p : problems) all += (all.empty() ? "" : "; ") + p;
      ROS_ERROR("%s: reconfiguration refused, old values kept: %s", who_.c_str(), all.c_str());
    } else if (!changed.empty()) {
      current_ = candidate;
      pending_ = candidate;
      ROS_INFO("%s: reconfigured (from the next frame): %s", who_.c_str(), changed.c_str());
      update_pub_.publish(toConfig(current_));
    }
    res.config = toConfig(current_);
    return true;
  }

  std::string who_;
  std::vector<Entry> entries_;
  Validate validate_;
  std::mutex mutex_;
  State current_;
  std::optional<State> pending_;
  ros::Publisher descr_pub_, update_pub_;
  ros::ServiceServer srv_;
};

}  // namespace graph
}  // namespace depth_track
