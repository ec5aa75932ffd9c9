#pragma once
// The tracker and map options of the offline tools (track_sequence, evaluate_bag), declared once:
// every tracker parameter from the tracker's table (tracker_params), every mapper parameter from
// the mapper's table (mapper_params: --voxel-size, --map-region, --loop-closure, --cl-step, ...),
// and --config, --depth-correction, --d-min/--d-max, --threads, --initial-pose, --map. A tool
// declares its own input and output options and calls addTrackingOptions once.
#include <CLI/CLI.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_correction.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/map/mapper_params.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tracker_params.hpp"

namespace depth_track {
namespace tool_options {

inline std::string dashed(std::string s) {
  std::replace(s.begin(), s.end(), '_', '-');
  return s;
}

/// An option's help: a table row's meaning and, when it has one, its unit in brackets.
template <class Spec>
std::string optionHelp(const Spec& p) {
  return p.help + (p.unit.empty() ? "" : " [" + p.unit + "]");
}

/// What the options hold after parsing; resolve the configs through the accessors.
struct TrackingOptions {
  std::string config_path;            ///< --config: YAML of tracker parameters
  std::string depth_correction_path;  ///< --depth-correction: camera_check YAML
  std::string initial_pose;           ///< --initial-pose 'tx ty tz qx qy qz qw'
  std::string map_path;               ///< --map: save the fused map here (.bt)
  DepthRange range;                   ///< --d-min / --d-max
  int threads = 1;
  std::map<std::string, std::string> tracker_values, mapper_values;
  std::map<std::string, CLI::Option*> tracker_opts, mapper_opts;

  /// The tracker's configuration: defaults, then --config, then each option given. Throws
  /// std::invalid_argument naming a bad file, parameter or value.
  TrackerConfig trackerConfig() const {
    TrackerConfig config;
    if (!config_path.empty()) loadTrackerParamsYaml(config_path, config);
    for (const auto& [name, opt] : tracker_opts)
      if (opt->count() > 0) setTrackerParam(config, name, tracker_values.at(name));
    config.threads = threads;
    return config;
  }

  /// The mapper's configuration: defaults, then each option given; the ray-cast range follows
  /// --d-min/--d-max unless --raycast-min/--raycast-max are given.
  MapperConfig mapperConfig() const {
    MapperConfig config;
    config.range = range;
    for (const auto& [name, opt] : mapper_opts)
      if (opt->count() > 0) setMapperParam(config, name, mapper_values.at(name));
    return config;
  }

  /// True when the run needs a map: --map or loop closure.
  bool mapWanted() const { return !map_path.empty() || mapperConfig().loop.enabled; }

  /// The depth range, checked (throws std::invalid_argument naming the problems).
  DepthRange depthRange() const {
    const auto problems = range.validate();
    if (!problems.empty()) throw std::invalid_argument(joinProblems(problems));
    return range;
  }

  /// --depth-correction's section, or the identity.
  DepthCorrection depthCorrection() const {
    return depth_correction_path.empty() ? DepthCorrection{}
                                         : loadDepthCorrectionYaml(depth_correction_path);
  }

  /// The start pose (identity unless --initial-pose). Throws std::invalid_argument.
  Eigen::Isometry3d startPose() const {
    if (initial_pose.empty()) return Eigen::Isometry3d::Identity();
    std::istringstream in(initial_pose);
    double v[7];
    for (double& x : v)
      if (!(in >> x))
        throw std::invalid_argument("--initial-pose needs 7 numbers: tx ty tz qx qy qz qw");
    Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
    if (!(q.norm() > 0.5))
      throw std::invalid_argument("--initial-pose quaternion is not a unit quaternion");
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = q.normalized().toRotationMatrix();
    T.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
    return T;
  }
};

/// Pinhole intrinsics given on the command line (--fx --fy --cx --cy, pixels).
struct IntrinsicsOptions {
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
  bool given() const { return fx > 0.0 && fy > 0.0; }
  /// The intrinsics with the image size left to the caller (0 x 0).
  PinholeIntrinsics intrinsics() const {
    PinholeIntrinsics k;
    k.width = k.height = 0;
    k.fx = fx, k.fy = fy, k.cx = cx, k.cy = cy;
    return k;
  }
};

/// Declares --fx --fy --cx --cy; `when` says when they are needed (e.g. "--tum").
inline void addIntrinsicsOptions(CLI::App& app, IntrinsicsOptions& k, const std::string& when) {
  app.add_option("--fx", k.fx, "focal length x, px (" + when + ")");
  app.add_option("--fy", k.fy, "focal length y, px (" + when + ")");
  app.add_option("--cx", k.cx, "principal point x, px (" + when + ")");
  app.add_option("--cy", k.cy, "principal point y, px (" + when + ")");
}

/// Declares every tracker parameter (declared once in tracker_params) as an option, and
/// --config; TrackingOptions::trackerConfig() resolves them.
inline void addTrackerParamOptions(CLI::App& app, TrackingOptions& o) {
  app.add_option("--config", o.config_path,
                 "YAML file of tracker parameters (see config/tracker.yaml)");
  const TrackerConfig tracker_defaults;
  for (const ParamSpec& p : trackerParams()) {
    o.tracker_opts[p.name] =
        app.add_option("--" + dashed(p.name), o.tracker_values[p.name], optionHelp(p))
            ->default_str(p.get(tracker_defaults))
            ->group("Tracker");
  }
}

/// The camera-IMU prior's filter settings (track_sequence --imu-sim, evaluate_bag --motion-prior
/// imu) as --imu-<name>, one per row of imuPriorParams() (the graph's ~imu_<name>), bound to `c`
/// (which must outlive the parse; its T_C_I is the tool's to set). A value that is not a number
/// is refused at the parse; the ranges are the config's validate(), when the prior is built.
inline void addImuOptions(CLI::App& app, ImuPriorConfig& c) {
  for (const ImuParamSpec& p : imuPriorParams()) {
    app.add_option_function<std::string>(
           "--imu-" + dashed(p.name),
           [&c, p](const std::string& v) {
             try {
               p.set(c, v);
             } catch (const std::invalid_argument& e) {
               throw CLI::ValidationError("--imu-" + dashed(p.name), e.what());
             }
           },
           "IMU prior: " + optionHelp(p))
        ->default_str(p.get(c))
        ->group("IMU prior");
  }
}

/// Declares the shared options on `app`, bound to `o` (which must outlive the parse).
inline void addTrackingOptions(CLI::App& app, TrackingOptions& o) {
  app.add_option("--d-min", o.range.min_m, "nearest valid depth, m")->capture_default_str();
  app.add_option("--d-max", o.range.max_m, "farthest valid depth, m")->capture_default_str();
  app.add_option("--depth-correction", o.depth_correction_path,
                 "camera_check YAML whose depth_correction (scale, offset_m) is applied to every "
                 "frame: z = (z - offset_m) / scale");
  app.add_option("--threads", o.threads, "worker threads for prefilter and PCA (1 = one core)")
      ->capture_default_str();
  app.add_option("--initial-pose", o.initial_pose,
                 "first pose 'tx ty tz qx qy qz qw' (default identity; evaluate_bag: the "
                 "bag's camera mount from /tf_static when it records one)");
  app.add_option("--map", o.map_path, "fuse the frames into a voxel map and save it here (.bt)");
  addTrackerParamOptions(app, o);
  // Every mapper parameter (map, ray cast, loop closure), declared once in mapper_params. Any of
  // --map and --loop-closure on builds the map.
  const MapperConfig mapper_defaults;
  for (const MapperParamSpec& p : mapperParams()) {
    std::string help = optionHelp(p);
    if (p.name == "raycast_min" || p.name == "raycast_max") help += " (default: --d-min / --d-max)";
    o.mapper_opts[p.name] = app.add_option("--" + dashed(p.name), o.mapper_values[p.name], help)
                                ->default_str(p.get(mapper_defaults))
                                ->group("Map");
  }
}

}  // namespace tool_options
}  // namespace depth_track
