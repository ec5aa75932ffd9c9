#include "depth_track/core/param_table.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace depth_track {
namespace param_text {

double toDouble(const std::string& name, const std::string& v) {
  std::size_t used = 0;
  double d;
  try {
    d = std::stod(v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != v.size() || !std::isfinite(d))
    throw std::invalid_argument("parameter " + name + ": '" + v + "' is not a finite number");
  return d;
}

int toInt(const std::string& name, const std::string& v) {
  const double d = toDouble(name, v);
  if (d != std::floor(d) || std::abs(d) > 1e9)
    throw std::invalid_argument("parameter " + name + ": '" + v + "' is not an integer");
  return static_cast<int>(d);
}

bool toBool(const std::string& name, const std::string& v) {
  if (v == "true" || v == "on" || v == "1" || v == "yes") return true;
  if (v == "false" || v == "off" || v == "0" || v == "no") return false;
  throw std::invalid_argument("parameter " + name + ": '" + v + "' is not on/off (true/false)");
}

std::string format(double d) {
  std::ostringstream s;
  s << d;
  return s.str();
}

}  // namespace param_text
}  // namespace depth_track
