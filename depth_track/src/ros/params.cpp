#include "depth_track/ros/params.hpp"

#include <XmlRpcValue.h>
#include <ros/console.h>
#include <ros/param.h>

#include <cstdio>
#include <set>
#include <sstream>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/imu_prior.hpp"

namespace depth_track {
namespace rosparams {

namespace {

NodeParamSpec num(const char* node, const char* name, const char* unit, const char* help,
                  double def, double lo, double hi, char type = 'd') {
  NodeParamSpec p;
  p.node = node, p.name = name, p.type = type, p.unit = unit, p.help = help;
  p.default_text = param_text::format(def);
  p.min = lo, p.max = hi;
  return p;
}
NodeParamSpec integer(const char* node, const char* name, const char* unit, const char* help,
                      int def, int lo, int hi) {
  return num(node, name, unit, help, def, lo, hi, 'i');
}
NodeParamSpec flag(const char* node, const char* name, const char* help, bool def) {
  NodeParamSpec p;
  p.node = node, p.name = name, p.type = 'b', p.help = help;
  p.default_text = def ? "true" : "false";
  return p;
}
NodeParamSpec text(const char* node, const char* name, const char* help, const char* def,
                   std::vector<std::string> choices = {}) {
  NodeParamSpec p;
  p.node = node, p.name = name, p.type = 's', p.help = help;
  p.default_text = def;
  p.choices = std::move(choices);
  return p;
}

constexpr double kInf = std::numeric_limits<double>::infinity();

std::vector<NodeParamSpec> makeParams() {
  std::vector<NodeParamSpec> p;
  const char* mode_help =
      "replay: every frame in order, deterministic; live: the freshest frame, skips counted";
  const char* live_queue_help =
      "live: frames that may wait while the stage is busy (oldest first); a newer one beyond them "
      "skips the oldest waiting (counted); 1 = only the freshest; 2 absorbs one frame that "
      "overruns its period, or two delivered at once";
  const char* nice_help =
      "live: nice value of the worker thread (0..19; 0 = as the process; replay ignores it): above "
      "0 the map's work "
      "yields the cores to the tracking chain, so that a map insert or a loop-closure ray cast "
      "does not delay a frame's pose";
  // ---- ingest ----
  p.push_back(text("ingest", "mode", mode_help, "live", {"live", "replay"}));
  p.push_back(num("ingest", "depth_scale", "m",
                  "metres per 16UC1 unit: 0.001 RealSense D4xx / ROS drivers, 0.00025 L515 raw, "
                  "0.0002 TUM",
                  0.001, 1e-7, 1.0));
  p.push_back(
      num("ingest", "d_min", "m", "nearer depths are no return", DepthRange{}.min_m, 0.0, 100.0));
  p.push_back(
      num("ingest", "d_max", "m", "farther depths are no return", DepthRange{}.max_m, 0.01, 100.0));
  p.push_back(text("ingest", "depth_correction",
                   "camera_check YAML whose depth_correction (scale, offset_m) corrects every "
                   "frame, z = (z - offset_m) / scale; empty = none",
                   ""));
  p.push_back(num("ingest", "false_colour_band", "m",
                  "depth per colour band of the false-colour image (thesis: 50 mm)", 0.05, 1e-3,
                  10.0));
  p.push_back(num("ingest", "input_timeout", "s",
                  "warn (naming the topics) when no frame came for this long", 5.0, 0.1, 3600.0));
  p.push_back(text("ingest", "image_transport",
                   "transport of image_rect: raw | compressedDepth (image_transport plugins)",
                   "raw"));
  p.push_back(integer("ingest", "threads", "", "workers of the prefilter", 1, 1, 64));
  p.push_back(integer("ingest", "replay_queue", "frames",
                      "replay: frames held while the graph is behind (then the oldest is dropped "
                      "with an error)",
                      2000, 1, 100000));
  p.push_back(integer("ingest", "live_queue", "frames", live_queue_help, 2, 1, 10));
  // ---- pca_reduce ----
  p.push_back(text("pca_reduce", "mode", mode_help, "live", {"live", "replay"}));
  p.push_back(integer("pca_reduce", "threads", "", "workers of the PCA reduction", 1, 1, 64));
  p.push_back(flag("pca_reduce", "fm_terms",
                   "compute the cells' Förstner–Moonen terms even when the method does not use "
                   "them, so that dynamic_reconfigure can switch the registration to cell_search; "
                   "off keeps the reduction identical to the offline tracker's",
                   false));
  p.push_back(integer("pca_reduce", "live_queue", "frames", live_queue_help, 2, 1, 10));
  // ---- registration ----
  p.push_back(text("registration", "mode", mode_help, "live", {"live", "replay"}));
  p.push_back(text("registration", "odom_frame", "frame of the odometry (REP 105)", "odom"));
  p.push_back(text("registration", "base_frame", "the robot's body frame (REP 105)", "base_link"));
  p.push_back(text("registration", "map_frame", "frame of the loop-closure corrections", "map"));
  p.push_back(text("registration", "guess_frame",
                   "fixed frame of a motion prior from tf (wheel odometry, the rig's sensors): "
                   "the motion of guess_child_frame in it between two frames; empty = constant "
                   "velocity",
                   ""));
  p.push_back(text("registration", "guess_child_frame",
                   "the frame that moves with the robot in guess_frame's tree: base_frame when "
                   "empty; its own frame (rig_odometry: rig_base_link) keeps base_frame with one "
                   "parent",
                   ""));
  p.push_back(num("registration", "guess_timeout", "s", "wait this long for the prior's tf", 0.05,
                  0.0, 10.0));
  p.push_back(num("registration", "static_tf_timeout", "s",
                  "warn about a missing base_frame -> camera transform every this long", 2.0, 0.1,
                  3600.0));
  p.push_back(text("registration", "camera_mount",
                   "'x y z qx qy qz qw' of camera_frame in base_frame (m), published on /tf_static "
                   "by this nodelet, when nothing else does; empty = from tf",
                   ""));
  p.push_back(text("registration", "camera_frame", "the optical frame camera_mount places",
                   "camera_depth_optical_frame"));
  p.push_back(flag("registration", "publish_tf", "publish tf odom_frame -> base_frame", true));
  p.push_back(integer("registration", "path_length", "poses",
                      "poses kept in the published path (oldest dropped)", 2000, 1, 1000000));
  p.push_back(num("registration", "lost_position_var", "m^2",
                  "position variance published while LOST (inflated)", 1.0, 0.0, kInf));
  p.push_back(num("registration", "lost_rotation_var", "rad^2",
                  "rotation variance published while LOST (inflated)", 0.1, 0.0, kInf));
  p.push_back(flag("registration", "relocalise",
                   "while LOST, register against the map's ray cast at the held pose (the fusion "
                   "nodelet's map in this manager, else cast by its render_depth service)",
                   true));
  p.push_back(integer("registration", "relocalise_every", "frames",
                      "attempt a relocalisation every n-th lost frame", 3, 1, 1000));
  p.push_back(text("registration", "render_service",
                   "the fusion nodelet's render_depth service (relative to the graph's "
                   "namespace), asked when fusion runs in another process",
                   "fusion/render_depth"));
  p.push_back(num("registration", "render_timeout", "s",
                  "longest wait for render_depth's answer (replay: after up to 10 s for the map "
                  "to catch up); the frame stays LOST when it comes later",
                  0.5, 0.01, 60.0));
  p.push_back(text("registration", "trajectory_path",
                   "default file of save_trajectory (TUM format; map poses beside it as "
                   "<name>_map.txt)",
                   "/tmp/depth_track_trajectory.txt"));
  p.push_back(flag("registration", "imu",
                   "the camera's IMU as motion prior (topic imu: sensor_msgs/Imu with gyro and "
                   "accelerometer in one message, e.g. realsense2_camera with unite_imu_method; "
                   "its mount from tf, depth optical frame -> the messages' frame); the camera "
                   "must be still for imu_init_window before the first frame; guess_frame wins "
                   "when both are set",
                   false));
  {
    // The filter's settings from its table (imu_prior.hpp), as imu_<name>; their ranges are the
    // config's validate(), which the registration nodelet runs on them (ParamReader::table).
    const ImuPriorConfig d;
    for (const ImuParamSpec& t : imuPriorParams()) {
      NodeParamSpec q;
      q.node = "registration", q.name = "imu_" + t.name, q.type = 'd', q.unit = t.unit;
      q.help = t.help;
      q.default_text = t.get(d);
      p.push_back(q);
    }
    p.push_back(num("registration", "imu_timeout", "s",
                    "wait this long for an IMU reading at or after a frame's stamp", 0.05, 0.0,
                    10.0));
  }
  p.push_back(integer("registration", "live_queue", "frames", live_queue_help, 2, 1, 10));
  // ---- fusion ----
  p.push_back(text("fusion", "mode", mode_help, "live", {"live", "replay"}));
  p.push_back(text("fusion", "map_frame", "frame of the map", "map"));
  p.push_back(text("fusion", "odom_frame", "frame of the odometry", "odom"));
  p.push_back(num("fusion", "publish_period", "s",
                  "minimum time between map publications (voxels, markers)", 1.0, 0.0, 3600.0));
  p.push_back(integer("fusion", "sync_queue", "frames",
                      "depth frames kept while their pose is awaited", 90, 1, 10000));
  p.push_back(text("fusion", "map_path", "default file of save_map (OctoMap .bt)",
                   "/tmp/depth_track_map.bt"));
  p.push_back(integer("fusion", "worker_nice", "", nice_help, 10, 0, 19));
  // ---- loop_closure ----
  p.push_back(text("loop_closure", "mode", mode_help, "live", {"live", "replay"}));
  p.push_back(text("loop_closure", "map_frame", "frame of the map", "map"));
  p.push_back(text("loop_closure", "odom_frame", "frame of the odometry", "odom"));
  p.push_back(num("loop_closure", "tf_rate", "Hz", "rate of map_frame -> odom_frame on tf", 20.0,
                  0.1, 1000.0));
  p.push_back(integer("loop_closure", "sync_queue", "frames",
                      "depth frames kept while their pose is awaited", 90, 1, 10000));
  p.push_back(num("loop_closure", "wait_timeout", "s",
                  "replay: wait this long for the map to catch up before an attempt", 10.0, 0.0,
                  3600.0));
  p.push_back(integer("loop_closure", "worker_nice", "", nice_help, 10, 0, 19));
  // ---- diagnostics: thresholds of every nodelet's /diagnostics (graph_diagnostics.hpp) ----
  p.push_back(
      num("diagnostics", "period", "s", "wall time between /diagnostics updates", 1.0, 0.05, 60.0));
  p.push_back(num("diagnostics", "expected_rate", "Hz",
                  "the camera's frame rate each stage's input rate is checked against", 30.0, 0.1,
                  1000.0));
  p.push_back(
      num("diagnostics", "rate_tolerance", "",
          "input rate WARN outside expected_rate * (1 +- this); ERROR: no frame in the window", 0.2,
          0.0, 10.0));
  p.push_back(integer("diagnostics", "rate_window", "updates",
                      "updates over which the input rate is measured", 5, 1, 100));
  p.push_back(num("diagnostics", "time_warn", "ms",
                  "processing time WARN above this mean per frame (a 30 Hz frame period: beyond "
                  "it live mode skips frames)",
                  33.0, 0.0, kInf));
  p.push_back(num("diagnostics", "time_error", "ms", "processing time ERROR above this mean", 100.0,
                  0.0, kInf));
  p.push_back(num("diagnostics", "latency_warn", "ms",
                  "stamp-to-publish latency WARN when the period's p95 exceeds this", 30.0, 0.0,
                  kInf));
  p.push_back(num("diagnostics", "latency_error", "ms",
                  "stamp-to-publish latency ERROR when the period's median exceeds this", 100.0,
                  0.0, kInf));
  p.push_back(num("diagnostics", "drop_error_fraction", "",
                  "frames dropped: WARN on any in a period, ERROR above this share of its input",
                  0.5, 0.0, 1.0));
  p.push_back(integer("diagnostics", "loop_reject_warn", "attempts",
                      "loop closure WARN after this many rejected attempts in a row", 10, 1,
                      100000));
  return p;
}

}  // namespace

const std::vector<NodeParamSpec>& nodeParams() {
  static const std::vector<NodeParamSpec> params = makeParams();
  return params;
}

namespace {

ReconfigurableSpec rc(const char* node, const char* table, const char* name, char type, double lo,
                      double hi, std::vector<std::string> choices = {}) {
  ReconfigurableSpec r;
  r.node = node, r.table = table, r.name = name, r.type = type, r.min = lo, r.max = hi;
  r.choices = std::move(choices);
  return r;
}

std::vector<ReconfigurableSpec> makeReconfigurable() {
  std::vector<ReconfigurableSpec> r;
  // Ingest: the depth range and the prefilter (rebuilt between two frames).
  r.push_back(rc("ingest", "", "d_min", 'd', 0, 0));
  r.push_back(rc("ingest", "", "d_max", 'd', 0, 0));
  // On / off: a crop needs its window, which is not reconfigurable.
  r.push_back(rc("ingest", "tracker", "prefilter", 's', 0, 0, {"none", "bilateral"}));
  // Registration: the method, the pairing and failure gates, the iterations, the FM gate.
  r.push_back(rc("registration", "tracker", "method", 's', 0, 0, {"p2p", "p2l", "cell_search"}));
  r.push_back(rc("registration", "tracker", "fm_thresh", 'd', 0.01, 1000.0));
  r.push_back(rc("registration", "tracker", "max_iterations", 'i', 1, 1000));
  r.push_back(rc("registration", "tracker", "dist_min", 'd', 0.001, 1.0));
  r.push_back(rc("registration", "tracker", "initial_dist", 'd', 0.0, 2.0));
  r.push_back(rc("registration", "tracker", "cos_min", 'd', -0.99, 1.0));
  r.push_back(rc("registration", "tracker", "search_radius", 'i', 0, 16));
  r.push_back(rc("registration", "tracker", "min_matches", 'i', 6, 100000));
  r.push_back(rc("registration", "tracker", "max_error", 'd', 0.0001, 1.0));
  r.push_back(rc("registration", "tracker", "max_jump", 'd', 0.001, 5.0));
  r.push_back(rc("registration", "tracker", "max_jump_angle", 'd', 0.01, 180.0));
  // Loop closure: how often, and its gates.
  r.push_back(rc("loop_closure", "mapper", "cl_step", 'i', 1, 1000));
  r.push_back(rc("loop_closure", "mapper", "cl_min_model_fraction", 'd', 0.0, 1.0));
  r.push_back(rc("loop_closure", "mapper", "cl_min_matches", 'i', 1, 100000));
  r.push_back(rc("loop_closure", "mapper", "cl_max_correction", 'd', 0.0001, 5.0));
  r.push_back(rc("loop_closure", "mapper", "cl_max_correction_angle", 'd', 0.001, 180.0));
  r.push_back(rc("loop_closure", "mapper", "cl_max_error", 'd', 0.0001, 1.0));
  r.push_back(rc("loop_closure", "mapper", "cl_deadband", 'd', 0.0, 1.0));
  r.push_back(rc("loop_closure", "mapper", "cl_deadband_angle", 'd', 0.0, 45.0));
  for (auto& x : r)
    if (x.table.empty())
      for (const auto& p : nodeParams())
        if (p.node == x.node && p.name == x.name) x.type = p.type, x.min = p.min, x.max = p.max;
  return r;
}

}  // namespace

const std::vector<ReconfigurableSpec>& reconfigurableParams() {
  static const std::vector<ReconfigurableSpec> params = makeReconfigurable();
  return params;
}

std::vector<std::string> nodeNames() {
  std::vector<std::string> names;
  for (const auto& p : nodeParams())
    if (names.empty() || names.back() != p.node) names.push_back(p.node);
  return names;
}

bool readText(const ros::NodeHandle& nh, const std::string& key, std::string* text) {
  XmlRpc::XmlRpcValue v;
  if (!nh.getParam(key, v)) return false;
  switch (v.getType()) {
    case XmlRpc::XmlRpcValue::TypeInt:
      *text = std::to_string(static_cast<int>(v));
      return true;
    case XmlRpc::XmlRpcValue::TypeDouble: {
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.17g", static_cast<double>(v));
      *text = buf;
      return true;
    }
    case XmlRpc::XmlRpcValue::TypeBoolean:
      *text = static_cast<bool>(v) ? "true" : "false";
      return true;
    case XmlRpc::XmlRpcValue::TypeString:
      *text = static_cast<std::string>(v);
      return true;
    default:
      *text = "<not a single value>";
      return true;
  }
}

std::vector<std::string> keysUnder(const ros::NodeHandle& nh) {
  std::vector<std::string> all, out;
  if (!ros::param::getParamNames(all)) return out;
  std::string ns = nh.getNamespace();
  if (ns.empty() || ns.back() != '/') ns += '/';
  std::set<std::string> seen;
  for (const auto& name : all) {
    if (name.rfind(ns, 0) != 0) continue;
    const std::string rest = name.substr(ns.size());
    const std::string key = rest.substr(0, rest.find('/'));
    if (!key.empty() && seen.insert(key).second) out.push_back(key);
  }
  return out;
}

ParamReader::ParamReader(const ros::NodeHandle& private_nh, std::string node)
    : nh_(private_nh), node_(std::move(node)) {
  for (const auto& key : keysUnder(nh_)) {
    bool known = false;
    for (const auto& p : nodeParams()) known = known || (p.node == node_ && p.name == key);
    // Sub-namespaces (e.g. a nodelet's bond or a per-stage table) are not the node's own keys.
    std::string probe;
    XmlRpc::XmlRpcValue v;
    const bool is_struct = nh_.getParam(key, v) && v.getType() == XmlRpc::XmlRpcValue::TypeStruct;
    if (!known && !is_struct) problems_.push_back(nh_.resolveName(key) + ": unknown parameter");
  }
}

const NodeParamSpec& ParamReader::spec(const std::string& name, char type) const {
  for (const auto& p : nodeParams())
    if (p.node == node_ && p.name == name) {
      if (p.type != type)
        throw std::logic_error("parameter " + name + " of " + node_ + " read as the wrong type");
      return p;
    }
  throw std::logic_error("parameter " + name + " is not in nodeParams() for " + node_);
}

std::string ParamReader::raw(const std::string& name, char type) {
  const NodeParamSpec& p = spec(name, type);
  std::string t;
  if (!readText(nh_, name, &t)) t = p.default_text;
  return t;
}

double ParamReader::getDouble(const std::string& name) {
  const NodeParamSpec& p = spec(name, 'd');
  const std::string t = raw(name, 'd');
  try {
    const double v = param_text::toDouble(name, t);
    if (v < p.min || v > p.max) {
      problems_.push_back(nh_.resolveName(name) + " = " + t + ": must lie in [" +
                          param_text::format(p.min) + ", " + param_text::format(p.max) + "]" +
                          (p.unit.empty() ? "" : " " + p.unit));
      return param_text::toDouble(name, p.default_text);
    }
    return v;
  } catch (const std::invalid_argument& e) {
    problems_.push_back(nh_.resolveName(name) + " = '" + t + "': " + e.what());
    return param_text::toDouble(name, p.default_text);
  }
}

int ParamReader::getInt(const std::string& name) {
  const NodeParamSpec& p = spec(name, 'i');
  const std::string t = raw(name, 'i');
  try {
    const int v = param_text::toInt(name, t);
    if (v < p.min || v > p.max) {
      problems_.push_back(nh_.resolveName(name) + " = " + t + ": must lie in [" +
                          param_text::format(p.min) + ", " + param_text::format(p.max) + "]" +
                          (p.unit.empty() ? "" : " " + p.unit));
      return param_text::toInt(name, p.default_text);
    }
    return v;
  } catch (const std::invalid_argument& e) {
    problems_.push_back(nh_.resolveName(name) + " = '" + t + "': " + e.what());
    return param_text::toInt(name, p.default_text);
  }
}

bool ParamReader::getBool(const std::string& name) {
  const NodeParamSpec& p = spec(name, 'b');
  const std::string t = raw(name, 'b');
  try {
    return param_text::toBool(name, t);
  } catch (const std::invalid_argument& e) {
    problems_.push_back(nh_.resolveName(name) + " = '" + t + "': " + e.what());
    return param_text::toBool(name, p.default_text);
  }
}

std::string ParamReader::getString(const std::string& name) {
  const NodeParamSpec& p = spec(name, 's');
  const std::string t = raw(name, 's');
  if (!p.choices.empty()) {
    bool ok = false;
    std::string all;
    for (const auto& c : p.choices) {
      ok = ok || c == t;
      all += (all.empty() ? "" : " | ") + c;
    }
    if (!ok) {
      problems_.push_back(nh_.resolveName(name) + " = '" + t + "': must be " + all);
      return p.default_text;
    }
  }
  return t;
}

void ParamReader::finish() const {
  if (problems_.empty()) return;
  std::string msg = node_ + ": invalid parameters (documented in config/tracking.yaml): ";
  for (std::size_t i = 0; i < problems_.size(); ++i) msg += (i ? "; " : "") + problems_[i];
  // Logged here too: a nodelet manager reports a failed onInit without the exception's text.
  ROS_FATAL("%s", msg.c_str());
  throw ParamError(msg);
}

}  // namespace rosparams
}  // namespace depth_track
