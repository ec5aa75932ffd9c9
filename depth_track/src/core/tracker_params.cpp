#include "depth_track/core/tracker_params.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace depth_track {

namespace {

using param_text::toBool;
using param_text::toDouble;
using param_text::toInt;

template <typename Member>
ParamSpec num(const char* name, const char* unit, const char* help, Member member) {
  return numParam<TrackerConfig>(name, unit, help, member);
}

std::vector<ParamSpec> makeParams() {
  std::vector<ParamSpec> p;
  // ---- prefilter (thesis fig. 5.1 PreFilter, Ksz, Spatial_Const, Depth_Const) ----
  p.push_back(
      {"prefilter", "", "depth prefilter: none | bilateral | crop",
       [](const TrackerConfig& c) { return toString(c.prefilter.type); },
       [](TrackerConfig& c, const std::string& v) { c.prefilter.type = parsePrefilterType(v); }});
  p.push_back({"bilateral_mode", "", "bilateral kernel: full (Ksz x Ksz) | separable",
               [](const TrackerConfig& c) {
                 return std::string(
                     c.prefilter.bilateral_mode == BilateralMode::kFull ? "full" : "separable");
               },
               [](TrackerConfig& c, const std::string& v) {
                 c.prefilter.bilateral_mode = parseBilateralMode(v);
               }});
  p.push_back(num("bilateral_kernel", "px", "bilateral kernel side Ksz (odd)",
                  [](TrackerConfig& c) -> int& { return c.prefilter.kernel_size_px; }));
  p.push_back(num("bilateral_spatial_sigma", "px", "bilateral spatial sigma (Spatial_Const)",
                  [](TrackerConfig& c) -> double& { return c.prefilter.spatial_sigma_px; }));
  p.push_back(num("bilateral_depth_sigma", "m", "bilateral depth sigma (Depth_Const in metres)",
                  [](TrackerConfig& c) -> double& { return c.prefilter.depth_sigma_m; }));
  p.push_back(num("crop_x", "px", "crop: left column kept",
                  [](TrackerConfig& c) -> int& { return c.prefilter.crop_x_px; }));
  p.push_back(num("crop_y", "px", "crop: top row kept",
                  [](TrackerConfig& c) -> int& { return c.prefilter.crop_y_px; }));
  p.push_back(num("crop_width", "px", "crop: columns kept",
                  [](TrackerConfig& c) -> int& { return c.prefilter.crop_width_px; }));
  p.push_back(num("crop_height", "px", "crop: rows kept",
                  [](TrackerConfig& c) -> int& { return c.prefilter.crop_height_px; }));
  // ---- PCA reduction (CellIX) ----
  p.push_back(num("cell_size", "px", "PCA cell side: 2, 4, 5, 8, 10, 16 or 32 (CellIX)",
                  [](TrackerConfig& c) -> int& { return c.pca.cell_size; }));
  p.push_back(num("min_valid_fraction", "",
                  "share of valid pixels a cell needs (1 = thesis drop-out rule)",
                  [](TrackerConfig& c) -> double& { return c.pca.min_valid_fraction; }));
  p.push_back(
      num("edge_jump_rel", "",
          "prune cells whose neighbouring depths jump by more than this share of depth (0 = off)",
          [](TrackerConfig& c) -> double& { return c.pca.edge_jump_rel; }));
  p.push_back(num("edge_jump_min", "m", "... and by more than this",
                  [](TrackerConfig& c) -> double& { return c.pca.edge_jump_min_m; }));
  p.push_back(num("edge_jump_sigmas", "",
                  "... and by more than this many times the depth noise sigma(z) below",
                  [](TrackerConfig& c) -> double& { return c.pca.edge_jump_sigmas; }));
  p.push_back(num("noise_sigma_const", "m",
                  "depth noise sigma(z) = const + quad z^2 (auto_noise sets it)",
                  [](TrackerConfig& c) -> double& { return c.pca.noise_sigma_const_m; }));
  p.push_back(num("noise_sigma_quad", "1/m", "... its quad term",
                  [](TrackerConfig& c) -> double& { return c.pca.noise_sigma_quad_per_m; }));
  p.push_back(num("normal_radius", "cells",
                  "normals pooled over (2r+1)^2 cells; 0 = per cell (thesis)",
                  [](TrackerConfig& c) -> int& { return c.pca.normal_radius_cells; }));
  p.push_back(num("normal_merge_dist", "m", "neighbour cells farther than this are not pooled",
                  [](TrackerConfig& c) -> double& { return c.pca.normal_merge_dist_m; }));
  p.push_back(num("crease_sigmas", "",
                  "a cell whose pooled patch is thicker than this many sigma(z) is pooled again "
                  "over the neighbours on its own plane; 0 = off",
                  [](TrackerConfig& c) -> double& { return c.pca.crease_sigmas; }));
  p.push_back(num("crease_min_radius", "cells",
                  "... only where normals are pooled over at least this radius",
                  [](TrackerConfig& c) -> int& { return c.pca.crease_min_radius_cells; }));
  p.push_back(num("cov_regulariser", "m^2", "added to cell covariances for the FM metric",
                  [](TrackerConfig& c) -> double& { return c.pca.min_eigenvalue_m2; }));
  // ---- matching (DistMin, CosMin) ----
  p.push_back(num("dist_min", "m", "max distance between paired cell vertices (DistMin)",
                  [](TrackerConfig& c) -> double& { return c.registration.match.dist_min_m; }));
  p.push_back(num("initial_dist", "m",
                  "first-iteration pairing gate, halved per iteration to dist_min",
                  [](TrackerConfig& c) -> double& { return c.registration.match.initial_dist_m; }));
  p.push_back(num("cos_min", "", "min cosine between paired normals (CosMin)",
                  [](TrackerConfig& c) -> double& { return c.registration.match.cos_min; }));
  p.push_back(
      num("normal_weight", "m", "weight of the normal difference in the 6-vector distance",
          [](TrackerConfig& c) -> double& { return c.registration.match.normal_weight_m; }));
  p.push_back(
      num("search_radius", "cells", "image-grid search window around the prediction",
          [](TrackerConfig& c) -> int& { return c.registration.match.search_radius_cells; }));
  // ---- registration (RegMethod, FMThresh) ----
  p.push_back({"method", "", "registration: p2p | p2l | cell_search (RegMethod)",
               [](const TrackerConfig& c) { return toString(c.registration.method); },
               [](TrackerConfig& c, const std::string& v) {
                 c.registration.method = parseRegistrationMethod(v);
               }});
  p.push_back(num("fm_thresh", "", "Förstner–Moonen gate for cell_search (FMThresh)",
                  [](TrackerConfig& c) -> double& { return c.registration.fm_thresh; }));
  p.push_back(num("max_iterations", "", "ICP iterations (re-matching after each)",
                  [](TrackerConfig& c) -> int& { return c.registration.max_iterations; }));
  p.push_back(num("patience", "", "stop after this many iterations without a lower error",
                  [](TrackerConfig& c) -> int& { return c.registration.patience; }));
  p.push_back(num("tolerance", "m", "stop when an update moves less than this",
                  [](TrackerConfig& c) -> double& { return c.registration.tolerance_m; }));
  p.push_back(num("tolerance_angle", "rad", "... and rotates less than this",
                  [](TrackerConfig& c) -> double& { return c.registration.tolerance_rad; }));
  p.push_back(num("robust", "", "Huber weighting of residuals (on/off)",
                  [](TrackerConfig& c) -> bool& { return c.registration.robust; }));
  p.push_back(num("huber_delta", "m", "Huber threshold",
                  [](TrackerConfig& c) -> double& { return c.registration.huber_delta_m; }));
  p.push_back(num("overlap_mask", "", "drop cells predicted outside the other view (on/off)",
                  [](TrackerConfig& c) -> bool& { return c.registration.overlap_mask; }));
  p.push_back(num("min_matches", "", "fewer pairs = failed frame",
                  [](TrackerConfig& c) -> int& { return c.registration.min_matches; }));
  p.push_back(num("noise_weighting", "",
                  "pairs deeper than noise_weighting_depth weigh by their inverse depth-noise "
                  "variance, (sigma(z_ref)/sigma(z))^2 (on/off; needs a noise model: auto_noise)",
                  [](TrackerConfig& c) -> bool& { return c.registration.noise_weighting; }));
  p.push_back(num("noise_weighting_depth", "m",
                  "... z_ref: nearer pairs weigh 1 (0 = every pair alike)",
                  [](TrackerConfig& c) -> double& { return c.registration.noise_ref_depth_m; }));
  p.push_back(num("noise_weighting_min", "",
                  "... the smallest weight factor a deep pair gets (1/32 = noise 5.7x the "
                  "reference depth's; 0 = unbounded)",
                  [](TrackerConfig& c) -> double& { return c.registration.noise_weighting_min; }));
  p.push_back(
      num("degeneracy_margin", "",
          "pose information below this many times its normal-noise floor counts as none; "
          "directions without information keep the motion prior (0 = off)",
          [](TrackerConfig& c) -> double& { return c.registration.degeneracy.noise_margin; }));
  p.push_back(num(
      "degeneracy_release_margin", "",
      "... after a frame that held directions, a direction is registered again only above this "
      "many times its floor (>= degeneracy_margin; equal = no hysteresis)",
      [](TrackerConfig& c) -> double& { return c.registration.degeneracy.release_margin; }));
  // ---- tracker ----
  p.push_back(num("icp_frames", "",
                  "frames between reference refreshes (ICPFrames); 0 = adaptive keyframes",
                  [](TrackerConfig& c) -> int& { return c.icp_frames; }));
  p.push_back(num("keyframe_dist", "m", "adaptive keyframes: new keyframe after this much travel",
                  [](TrackerConfig& c) -> double& { return c.keyframe_dist_m; }));
  p.push_back(num("keyframe_angle", "deg", "... or this much rotation",
                  [](TrackerConfig& c) -> double& { return c.keyframe_angle_deg; }));
  p.push_back(num("keyframe_min_overlap", "",
                  "... or when fewer of its cells than this share find a partner",
                  [](TrackerConfig& c) -> double& { return c.keyframe_min_overlap; }));
  p.push_back(num("max_error", "m", "larger registration residual RMS = failed frame",
                  [](TrackerConfig& c) -> double& { return c.max_error_rms_m; }));
  p.push_back(num("max_jump", "m", "larger correction of the prediction = failed frame",
                  [](TrackerConfig& c) -> double& { return c.max_jump_m; }));
  p.push_back(num("max_jump_angle", "deg", "larger rotation correction = failed frame",
                  [](TrackerConfig& c) -> double& { return c.max_jump_deg; }));
  p.push_back(num("velocity_span", "s",
                  "held directions follow the velocity fitted over the fully constrained frames "
                  "of this many seconds (0.65 s = 20 frames at 30 Hz; 0 = the last frame's)",
                  [](TrackerConfig& c) -> double& { return c.velocity_span_s; }));
  p.push_back(num("velocity_firm_information", "",
                  "held directions follow the velocity of the window's frames whose weakest "
                  "direction had at least this many times its noise floor (0 = all frames)",
                  [](TrackerConfig& c) -> double& { return c.velocity_firm_information; }));
  p.push_back(num("retry_pairs_below", "",
                  "a frame that holds directions with fewer pairs than this fraction of the last "
                  "fully constrained frame's is registered again from the previous pose (0 = off)",
                  [](TrackerConfig& c) -> double& { return c.retry_pairs_below; }));
  p.push_back(num("basin_probe_below", "",
                  "a fully constrained frame whose weakest direction has less than this many "
                  "times its noise floor is registered from either side of its result along it; "
                  "flagged (unconfirmed) when a probe ends beyond basin_probe_tolerance (0 = off)",
                  [](TrackerConfig& c) -> double& { return c.basin_probe_below; }));
  p.push_back(num("basin_probe_step", "m",
                  "how far either side of the result the basin probe starts",
                  [](TrackerConfig& c) -> double& { return c.basin_probe_step_m; }));
  p.push_back(num("basin_probe_tolerance", "m",
                  "a probe ending farther than this from the result flags the direction",
                  [](TrackerConfig& c) -> double& { return c.basin_probe_tolerance_m; }));
  p.push_back(num("basin_deep_floor", "",
                  "a frame that holds directions or that the basin probe flags is registered "
                  "again with the depth-noise weighting's floor raised to this, and kept when "
                  "probes either side confirm it (0 = off)",
                  [](TrackerConfig& c) -> double& { return c.basin_deep_floor; }));
  p.push_back(num("auto_noise", "",
                  "measure the depth noise on the first frame and set edge test, pooling and "
                  "gates from it (on/off)",
                  [](TrackerConfig& c) -> bool& { return c.auto_noise; }));
  p.push_back(num("constant_velocity", "", "predict with the last motion (on/off)",
                  [](TrackerConfig& c) -> bool& { return c.constant_velocity; }));
  // ---- registration model ----
  p.push_back(num("model", "",
                  "register keyframes against the tracked cells averaged per voxel (on/off)",
                  [](TrackerConfig& c) -> bool& { return c.model.enabled; }));
  p.push_back(num("model_voxel", "m", "voxel edge of the registration model",
                  [](TrackerConfig& c) -> double& { return c.model.voxel_m; }));
  p.push_back(num("model_max_weight", "", "observations after which a voxel follows new ones",
                  [](TrackerConfig& c) -> int& { return c.model.max_weight; }));
  p.push_back(num("model_min_weight", "", "observations before a voxel refines a keyframe cell",
                  [](TrackerConfig& c) -> int& { return c.model.min_weight; }));
  p.push_back(num("model_max_offset", "m",
                  "a keyframe cell farther than this from the model plane keeps its own",
                  [](TrackerConfig& c) -> double& { return c.model.max_offset_m; }));
  p.push_back(num("model_max_offset_sigmas", "",
                  "... or farther than this many depth-noise sigmas (auto_noise's model)",
                  [](TrackerConfig& c) -> double& { return c.model.max_offset_sigmas; }));
  p.push_back(num("model_keep_radius", "m",
                  "voxels farther than this from the camera are dropped (0 = keep all)",
                  [](TrackerConfig& c) -> double& { return c.model.keep_radius_m; }));
  p.push_back(num("model_prune_every", "frames", "... checked every this many fused frames",
                  [](TrackerConfig& c) -> int& { return c.model.prune_every; }));
  p.push_back(num("model_cos_min", "", "... and one whose normal differs more from the plane's",
                  [](TrackerConfig& c) -> double& { return c.model.cos_min; }));
  return p;
}

}  // namespace

const std::vector<ParamSpec>& trackerParams() {
  static const std::vector<ParamSpec> params = makeParams();
  return params;
}

void setTrackerParam(TrackerConfig& config, const std::string& name, const std::string& value) {
  setParam(trackerParams(), config, name, value, "tracker");
}

void loadTrackerParamsYaml(const std::string& path, TrackerConfig& config) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw std::invalid_argument(path + ": cannot open the config file");
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(path + ":" + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
  if (root["tracker"]) root = root["tracker"];
  if (!root.IsMap()) throw std::invalid_argument(path + ": expected a map of tracker parameters");
  for (const auto& kv : root) {
    const std::string key = kv.first.as<std::string>();
    const int line = kv.first.Mark().line + 1;
    if (!kv.second.IsScalar())
      throw std::invalid_argument(path + ":" + std::to_string(line) + ": " + key +
                                  " must be a single value");
    try {
      setTrackerParam(config, key, kv.second.as<std::string>());
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument(path + ":" + std::to_string(line) + ": " + e.what());
    }
  }
}

}  // namespace depth_track
