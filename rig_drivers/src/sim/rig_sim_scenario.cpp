#include "rig_drivers/sim/rig_sim_scenario.hpp"

#include <dirent.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <type_traits>

namespace rig_drivers {

namespace {

// Reads one mapping, remembering which keys were consumed so unknown keys can be named.
class Fields {
 public:
  Fields(const YAML::Node& node, std::string prefix, const std::string& source)
      : node_(node), prefix_(std::move(prefix)), source_(source) {
    if (!node_.IsMap())
      fail(node_, prefix_.empty() ? "(top level)" : prefixName(), "must be a mapping");
  }

  template <typename T>
  void get(const std::string& key, T* out) {
    seen_.insert(key);
    const YAML::Node v = node_[key];
    if (!v) return;
    if (!v.IsScalar()) fail(v, prefix_ + key, "must be a single value");
    try {
      *out = v.as<T>();
    } catch (const YAML::Exception&) {
      fail(v, prefix_ + key, "cannot read '" + v.Scalar() + "' as " + typeName<T>());
    }
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(*out)) fail(v, prefix_ + key, "must be a finite number");
    }
    lines_[key] = v.Mark().line + 1;
  }

  YAML::Node child(const std::string& key) {
    seen_.insert(key);
    return node_[key];
  }

  void rejectUnknown() const {
    for (auto it = node_.begin(); it != node_.end(); ++it) {
      const std::string key = it->first.as<std::string>("?");
      if (!seen_.count(key)) fail(it->first, prefix_ + key, "unknown field");
    }
  }

  int line(const std::string& key) const {
    auto it = lines_.find(key);
    return it == lines_.end() ? node_.Mark().line + 1 : it->second;
  }

  [[noreturn]] void fail(const YAML::Node& at, const std::string& field,
                         const std::string& what) const {
    std::ostringstream os;
    os << source_;
    if (at && !at.Mark().is_null()) os << ":" << at.Mark().line + 1;
    os << ": " << field << ": " << what;
    throw ScenarioError(os.str());
  }

 private:
  template <typename T>
  static const char* typeName() {
    if constexpr (std::is_same_v<T, bool>) return "true/false";
    if constexpr (std::is_integral_v<T>) return "an integer";
    if constexpr (std::is_floating_point_v<T>) return "a number";
    return "text";
  }
  std::string prefixName() const { return prefix_.substr(0, prefix_.size() - 1); }

  YAML::Node node_;
  std::string prefix_;
  const std::string& source_;
  std::set<std::string> seen_;
  std::map<std::string, int> lines_;
};

RigKind parseRig(const std::string& s, bool* ok) {
  *ok = true;
  if (s == "servotrack") return RigKind::kServoTrack;
  if (s == "servotruck") return RigKind::kServoTruck;
  if (s == "tripod") return RigKind::kTripod;
  *ok = false;
  return RigKind::kServoTrack;
}

ServoAxis parseAxis(const std::string& s, bool* ok) {
  *ok = true;
  if (s == "none") return ServoAxis::kNone;
  if (s == "pitch") return ServoAxis::kPitch;
  if (s == "yaw") return ServoAxis::kYaw;
  *ok = false;
  return ServoAxis::kNone;
}

std::string num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

}  // namespace

const char* toString(RigKind rig) {
  switch (rig) {
    case RigKind::kServoTrack:
      return "servotrack";
    case RigKind::kServoTruck:
      return "servotruck";
    default:
      return "tripod";
  }
}

const char* toString(ServoAxis axis) {
  switch (axis) {
    case ServoAxis::kPitch:
      return "pitch";
    case ServoAxis::kYaw:
      return "yaw";
    default:
      return "none";
  }
}

double TruckScenario::duration() const {
  double d = 0.0;
  for (const auto& s : segments) d += s.duration_s;
  return d;
}

double TripodScenario::duration() const {
  if (distances_m.empty()) return 0.0;
  return distances_m.size() * hold_s + (distances_m.size() - 1) * move_s;
}

double TripodScenario::distanceAt(double t_s) const {
  if (distances_m.empty()) return 0.0;
  const double period = hold_s + move_s;
  const double k = std::floor(std::max(t_s, 0.0) / period);
  const std::size_t i = std::min(static_cast<std::size_t>(k), distances_m.size() - 1);
  const double in = t_s - i * period;
  if (i + 1 >= distances_m.size() || in <= hold_s) return distances_m[i];
  // Smoothstep: starts and stops at rest, as a camera carried by hand or on a trolley would.
  const double u = std::min((in - hold_s) / std::max(move_s, 1e-12), 1.0);
  const double w = u * u * (3.0 - 2.0 * u);
  return distances_m[i] + w * (distances_m[i + 1] - distances_m[i]);
}

int Scenario::frameCount() const {
  if (rig == RigKind::kTripod)
    return static_cast<int>(std::floor(tripod.duration() * frame_rate_hz + 1e-9));
  if (rig == RigKind::kServoTrack) {
    return track.mode == 2 ? track.still_frames + track.steps : track.frames;
  }
  return static_cast<int>(std::floor(truck.duration() * frame_rate_hz + 1e-9));
}

double Scenario::durationS() const {
  if (rig == RigKind::kServoTruck) return truck.duration();
  if (rig == RigKind::kTripod) return tripod.duration();
  if (track.mode == 1) return track.duration_s;
  // Cruise-only estimate plus settling per step; the simulator reports the real length.
  const double per_step =
      std::abs(track.step_mm) / std::max(track.step_speed_mm_s, 1e-9) + track.settle_s;
  return (track.still_frames + 1) / frame_rate_hz + track.steps * per_step;
}

std::vector<std::string> Scenario::validate() const {
  std::vector<std::string> p;
  auto positive = [&p](const std::string& field, double v) {
    if (!(v > 0.0)) p.push_back(field + ": must be > 0 (got " + num(v) + ")");
  };
  if (name.empty()) p.push_back("name: must not be empty");
  if (name.find_first_of("/ \t") != std::string::npos)
    p.push_back("name: must be usable as a file name (got '" + name + "')");
  if (scene != "chair_room" && scene != "furnished_room" && scene != "hall" &&
      scene != "calibration_target")
    p.push_back("scene: must be chair_room, furnished_room, hall or calibration_target (got '" +
                scene + "')");
  // The tripod's poses are defined by the distance to the calibration target's face.
  if ((rig == RigKind::kTripod) != (scene == "calibration_target"))
    p.push_back(rig == RigKind::kTripod
                    ? "scene: a tripod run stands before the calibration target: scene must be "
                      "calibration_target (got '" +
                          scene + "')"
                    : "scene: calibration_target is for rig tripod (got rig " +
                          std::string(toString(rig)) + ")");
  if (noise != "l515" && noise != "d435" && noise != "none")
    p.push_back("noise: must be l515, d435 or none (got '" + noise + "')");
  positive("frame_rate_hz", frame_rate_hz);
  if (rig == RigKind::kServoTrack) {
    const TrackScenario& t = track;
    if (t.mode != 1 && t.mode != 2)
      p.push_back("track.mode: must be 1 (continuous) or 2 (step sequence) (got " + num(t.mode) +
                  ")");
    if (t.start_position_m < 0.0 || t.start_position_m > 1.2)
      p.push_back("track.start_position_m: must lie on the track, 0..1.2 m (got " +
                  num(t.start_position_m) + ")");
    if (t.mode == 1) {
      positive("track.set_speed_mm_s", t.set_speed_mm_s);
      positive("track.achieved_speed_mm_s", t.achieved_speed_mm_s);
      if (t.achieved_speed_mm_s > t.set_speed_mm_s)
        p.push_back("track.achieved_speed_mm_s: cannot exceed track.set_speed_mm_s");
      positive("track.duration_s", t.duration_s);
      if (t.frames <= 0) p.push_back("track.frames: must be > 0 (got " + num(t.frames) + ")");
      const double expected = t.duration_s * frame_rate_hz;
      if (t.frames > 0 && t.duration_s > 0 && std::abs(t.frames - expected) > 1.0)
        p.push_back("track.frames: " + num(t.frames) +
                    " does not match duration_s x frame_rate_hz = " + num(expected));
      const double travel_m = t.achieved_speed_mm_s * 1e-3 * t.duration_s;
      if (t.achieved_speed_mm_s > 0 && t.duration_s > 0 && t.start_position_m + travel_m > 1.2)
        p.push_back("track.duration_s: the carriage would run " + num(travel_m) + " m from " +
                    num(t.start_position_m) + " m, past the 1.2 m track end");
      if (t.servo_axis != ServoAxis::kNone) {
        positive("track.amplitude_deg", t.amplitude_deg);
        if (t.amplitude_deg > 30.0)
          p.push_back("track.amplitude_deg: gimbal travel is +/-30 deg (got " +
                      num(t.amplitude_deg) + ")");
        positive("track.frequency_hz", t.frequency_hz);
        if (t.frequency_hz > 2.0)
          p.push_back("track.frequency_hz: servos cannot follow above 2 Hz (got " +
                      num(t.frequency_hz) + ")");
      } else if (t.amplitude_deg != 0.0) {
        p.push_back("track.amplitude_deg: set but track.servo_axis is none");
      }
    } else if (t.mode == 2) {
      if (t.still_frames < 0) p.push_back("track.still_frames: must be >= 0");
      if (t.steps <= 0) p.push_back("track.steps: must be > 0 (got " + num(t.steps) + ")");
      if (t.step_mm == 0.0 || std::abs(t.step_mm) > 100.0)
        p.push_back("track.step_mm: must be non-zero and at most 100 mm (got " + num(t.step_mm) +
                    ")");
      positive("track.step_speed_mm_s", t.step_speed_mm_s);
      if (t.settle_s < 0.0) p.push_back("track.settle_s: must be >= 0");
      const double end_m = t.start_position_m + t.steps * t.step_mm * 1e-3;
      if (end_m < 0.0 || end_m > 1.2)
        p.push_back("track.steps: the sequence ends at " + num(end_m) +
                    " m, off the 0..1.2 m track");
    }
  } else if (rig == RigKind::kTripod) {
    const TripodScenario& t = tripod;
    if (t.distances_m.empty()) p.push_back("tripod.distances_m: at least one distance is needed");
    for (std::size_t i = 0; i < t.distances_m.size(); ++i) {
      // The face beyond the renderer's 0.53 m near limit, the wall 0.6 m behind it within 4 m.
      const double d = t.distances_m[i];
      if (!(d >= 0.55 && d <= 3.4))
        p.push_back("tripod.distances_m: [" + std::to_string(i) + "] must be 0.55..3.4 m (got " +
                    num(d) + ")");
    }
    positive("tripod.hold_s", t.hold_s);
    if (!(t.move_s >= 0.0)) p.push_back("tripod.move_s: must be >= 0 (got " + num(t.move_s) + ")");
    if (t.hold_s > 0.0 && t.hold_s * frame_rate_hz < 1.0)
      p.push_back("tripod.hold_s: shorter than one frame at frame_rate_hz");
  } else {
    if (truck.segments.empty()) p.push_back("truck.segments: at least one segment is needed");
    for (std::size_t i = 0; i < truck.segments.size(); ++i) {
      const TruckSegment& s = truck.segments[i];
      const std::string f = "truck.segments[" + std::to_string(i) + "].";
      positive(f + "duration_s", s.duration_s);
      if (std::abs(s.throttle) > 1.0) p.push_back(f + "throttle: must lie in -1..1");
      if (std::abs(s.steering) > 1.0) p.push_back(f + "steering: must lie in -1..1");
    }
  }
  return p;
}

Scenario parseScenario(const std::string& yaml_text, const std::string& source) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::ParserException& e) {
    throw ScenarioError(source + ":" + std::to_string(e.mark.line + 1) + ": (syntax): " + e.msg);
  }
  if (!root || root.IsNull()) throw ScenarioError(source + ": (top level): the file is empty");
  Scenario s;
  Fields top(root, "", source);
  std::string rig = "servotrack";
  top.get("name", &s.name);
  top.get("description", &s.description);
  top.get("rig", &rig);
  top.get("scene", &s.scene);
  top.get("noise", &s.noise);
  top.get("frame_rate_hz", &s.frame_rate_hz);
  top.get("seed", &s.seed);
  bool ok = false;
  s.rig = parseRig(rig, &ok);
  if (!ok)
    top.fail(root["rig"], "rig", "must be servotrack, servotruck or tripod (got '" + rig + "')");

  // Field name -> line, for the problems validate() finds after parsing.
  std::map<std::string, int> lines;
  for (const char* k : {"name", "scene", "noise", "frame_rate_hz"}) lines[k] = top.line(k);

  YAML::Node track = top.child("track");
  YAML::Node truck = top.child("truck");
  YAML::Node tripod = top.child("tripod");
  top.rejectUnknown();
  if (s.rig != RigKind::kTripod && tripod)
    top.fail(tripod, "tripod", std::string("not allowed for rig ") + toString(s.rig));
  if (s.rig == RigKind::kTripod) {
    if (!tripod) top.fail(root, "tripod", "missing (needed for rig tripod)");
    for (const auto& [node, key] : {std::pair{track, "track"}, std::pair{truck, "truck"}})
      if (node) top.fail(node, key, "not allowed for rig tripod");
    Fields f(tripod, "tripod.", source);
    f.get("hold_s", &s.tripod.hold_s);
    f.get("move_s", &s.tripod.move_s);
    YAML::Node dist = f.child("distances_m");
    f.rejectUnknown();
    if (!dist || !dist.IsSequence())
      f.fail(dist ? dist : tripod, "tripod.distances_m", "must be a list of distances, m");
    for (std::size_t i = 0; i < dist.size(); ++i) {
      const std::string field = "tripod.distances_m[" + std::to_string(i) + "]";
      double d = 0.0;
      try {
        d = dist[i].as<double>();
      } catch (const YAML::Exception&) {
        f.fail(dist[i], field, "cannot read '" + dist[i].Scalar() + "' as a number");
      }
      if (!std::isfinite(d)) f.fail(dist[i], field, "must be a finite number");
      s.tripod.distances_m.push_back(d);
    }
    lines["tripod.hold_s"] = f.line("hold_s");
    lines["tripod.move_s"] = f.line("move_s");
    lines["tripod.distances_m"] = dist.Mark().line + 1;
  } else if (s.rig == RigKind::kServoTrack) {
    if (!track) top.fail(root, "track", "missing (needed for rig servotrack)");
    if (truck) top.fail(truck, "truck", "not allowed for rig servotrack");
    Fields f(track, "track.", source);
    TrackScenario& t = s.track;
    std::string axis = "none";
    f.get("mode", &t.mode);
    f.get("start_position_m", &t.start_position_m);
    f.get("set_speed_mm_s", &t.set_speed_mm_s);
    f.get("achieved_speed_mm_s", &t.achieved_speed_mm_s);
    f.get("duration_s", &t.duration_s);
    f.get("frames", &t.frames);
    f.get("servo_axis", &axis);
    f.get("amplitude_deg", &t.amplitude_deg);
    f.get("frequency_hz", &t.frequency_hz);
    f.get("still_frames", &t.still_frames);
    f.get("steps", &t.steps);
    f.get("step_mm", &t.step_mm);
    f.get("step_speed_mm_s", &t.step_speed_mm_s);
    f.get("settle_s", &t.settle_s);
    f.rejectUnknown();
    t.servo_axis = parseAxis(axis, &ok);
    if (!ok)
      f.fail(track["servo_axis"], "track.servo_axis",
             "must be none, pitch or yaw (got '" + axis + "')");
    for (const char* k : {"mode", "start_position_m", "set_speed_mm_s", "achieved_speed_mm_s",
                          "duration_s", "frames", "servo_axis", "amplitude_deg", "frequency_hz",
                          "still_frames", "steps", "step_mm", "step_speed_mm_s", "settle_s"})
      lines[std::string("track.") + k] = f.line(k);
  } else {
    if (!truck) top.fail(root, "truck", "missing (needed for rig servotruck)");
    if (track) top.fail(track, "track", "not allowed for rig servotruck");
    Fields f(truck, "truck.", source);
    f.get("start_x_m", &s.truck.start_x_m);
    f.get("start_y_m", &s.truck.start_y_m);
    f.get("start_heading_deg", &s.truck.start_heading_deg);
    YAML::Node segs = f.child("segments");
    f.rejectUnknown();
    if (!segs || !segs.IsSequence())
      f.fail(segs ? segs : truck, "truck.segments", "must be a list");
    for (std::size_t i = 0; i < segs.size(); ++i) {
      const std::string prefix = "truck.segments[" + std::to_string(i) + "].";
      Fields sf(segs[i], prefix, source);
      TruckSegment seg;
      sf.get("duration_s", &seg.duration_s);
      sf.get("throttle", &seg.throttle);
      sf.get("steering", &seg.steering);
      sf.rejectUnknown();
      for (const char* k : {"duration_s", "throttle", "steering"}) lines[prefix + k] = sf.line(k);
      s.truck.segments.push_back(seg);
    }
    lines["truck.segments"] = f.line("segments");
  }

  const std::vector<std::string> problems = s.validate();
  if (!problems.empty()) {
    // Each problem starts with its field name; put the line of that field in front.
    std::ostringstream os;
    for (std::size_t i = 0; i < problems.size(); ++i) {
      const std::string field = problems[i].substr(0, problems[i].find(':'));
      auto it = lines.find(field);
      os << (i ? "\n" : "") << source;
      if (it != lines.end()) os << ":" << it->second;
      os << ": " << problems[i];
    }
    throw ScenarioError(os.str());
  }
  return s;
}

Scenario loadScenario(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ScenarioError(path + ": cannot open the scenario file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parseScenario(ss.str(), path);
}

std::vector<std::string> listScenarioFiles(const std::string& folder) {
  DIR* d = opendir(folder.c_str());
  if (!d) throw ScenarioError(folder + ": cannot open the scenario folder");
  std::vector<std::string> out;
  while (dirent* e = readdir(d)) {
    const std::string n = e->d_name;
    if (n.size() > 5 && n.compare(n.size() - 5, 5, ".yaml") == 0) out.push_back(folder + "/" + n);
  }
  closedir(d);
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace rig_drivers
