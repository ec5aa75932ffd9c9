#pragma once
/// A stage's parameters as one table: name, unit, meaning, and typed get/set on its config
/// struct. The front ends (the offline tools' options, YAML files, the ROS adapter's private
/// parameters) all read the table, so a parameter is declared once. ROS-free core.
#include <functional>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace depth_track {

template <class Config>
struct BasicParamSpec {
  std::string name;  ///< snake_case key ("dist_min"); command-line option "--dist-min"
  std::string unit;  ///< "m", "deg", "px", "" for dimensionless / choices
  std::string help;  ///< one line of meaning
  std::function<std::string(const Config&)> get;         ///< value as text
  std::function<void(Config&, const std::string&)> set;  ///< throws std::invalid_argument
};

namespace param_text {
/// Parses a finite number; throws std::invalid_argument naming the parameter and the text.
double toDouble(const std::string& name, const std::string& text);
/// Parses an integer (a whole number within +-1e9); throws as toDouble.
int toInt(const std::string& name, const std::string& text);
/// Parses on/off, true/false, yes/no, 1/0; throws as toDouble.
bool toBool(const std::string& name, const std::string& text);
/// Shortest text of a number that reads back as the same value in the table's format.
std::string format(double value);
}  // namespace param_text

/// A numeric or boolean parameter bound to the member that `member(config)` returns by
/// reference (int, double or bool).
template <class Config, class Member>
BasicParamSpec<Config> numParam(const char* name, const char* unit, const char* help,
                                Member member) {
  return {name, unit, help,
          [member](const Config& c) {
            const auto value = member(const_cast<Config&>(c));
            if constexpr (std::is_same_v<std::decay_t<decltype(value)>, bool>) {
              return std::string(value ? "true" : "false");
            } else {
              return param_text::format(value);
            }
          },
          [member, name](Config& c, const std::string& v) {
            using T = std::remove_reference_t<decltype(member(c))>;
            if constexpr (std::is_same_v<T, int>) {
              member(c) = param_text::toInt(name, v);
            } else if constexpr (std::is_same_v<T, bool>) {
              member(c) = param_text::toBool(name, v);
            } else {
              member(c) = param_text::toDouble(name, v);
            }
          }};
}

/// Sets parameter `name` of `table` from text; throws std::invalid_argument naming the parameter
/// and value (unknown name - `what` names the table -, not a number, not one of the choices).
template <class Config>
void setParam(const std::vector<BasicParamSpec<Config>>& table, Config& config,
              const std::string& name, const std::string& value, const std::string& what) {
  for (const auto& p : table)
    if (p.name == name) {
      try {
        p.set(config, value);
      } catch (const std::invalid_argument& e) {
        const std::string msg = e.what();
        if (msg.rfind("parameter ", 0) == 0) throw;
        throw std::invalid_argument("parameter " + name + ": " + msg);
      }
      return;
    }
  throw std::invalid_argument("unknown " + what + " parameter '" + name + "'");
}

}  // namespace depth_track
