#include "depth_track/core/map/mapper_params.hpp"

#include <sstream>
#include <stdexcept>

namespace depth_track {

namespace {

template <typename Member>
MapperParamSpec num(const char* name, const char* unit, const char* help, Member member) {
  return numParam<MapperConfig>(name, unit, help, member);
}

std::vector<MapperParamSpec> makeParams() {
  std::vector<MapperParamSpec> p;
  // ---- voxel map ----
  p.push_back(num("voxel_size", "m", "map voxel edge",
                  [](MapperConfig& c) -> double& { return c.map.voxel_size_m; }));
  p.push_back({"map_region", "m",
               "region WxHxD around the start camera (middle of its back face), or unbounded",
               [](const MapperConfig& c) { return mapRegionText(c.map); },
               [](MapperConfig& c, const std::string& v) { setMapRegion(c.map, v); }});
  p.push_back({"carving", "", "carve free space along rays (probabilistic model): on | off",
               [](const MapperConfig& c) {
                 return std::string(c.map.model == UpdateModel::kProbabilistic ? "on" : "off");
               },
               [](MapperConfig& c, const std::string& v) {
                 c.map.model = param_text::toBool("carving", v) ? UpdateModel::kProbabilistic
                                                                : UpdateModel::kHitOnly;
               }});
  p.push_back(num("occupancy_threshold", "", "probability above which a voxel is occupied",
                  [](MapperConfig& c) -> double& { return c.map.occupancy_threshold; }));
  p.push_back(num("prob_hit", "", "occupancy probability after a hit",
                  [](MapperConfig& c) -> double& { return c.map.prob_hit; }));
  p.push_back(num("prob_miss", "", "occupancy probability after a miss (carving)",
                  [](MapperConfig& c) -> double& { return c.map.prob_miss; }));
  p.push_back(num("clamp_min", "", "lower clamp of a voxel's probability",
                  [](MapperConfig& c) -> double& { return c.map.clamp_min; }));
  p.push_back(num("clamp_max", "", "upper clamp of a voxel's probability",
                  [](MapperConfig& c) -> double& { return c.map.clamp_max; }));
  p.push_back(num("carve_stride", "px", "carve along every n-th pixel ray in u and v",
                  [](MapperConfig& c) -> int& { return c.map.carve_stride_px; }));
  p.push_back(num("carve_margin", "m", "stop carving this far in front of a return",
                  [](MapperConfig& c) -> double& { return c.map.carve_margin_m; }));
  p.push_back(num("max_fuse_depth", "m",
                  "fuse (and carve) returns only up to this depth; 0 = the whole depth range",
                  [](MapperConfig& c) -> double& { return c.map.max_fuse_depth_m; }));
  p.push_back(num("max_fuse_noise", "voxels",
                  "fuse (and carve) returns only where the depth noise measured on the first "
                  "frames stays below this many voxels; 0 = off",
                  [](MapperConfig& c) -> double& { return c.map.max_fuse_noise_voxels; }));
  p.push_back(num("snap_cell", "px",
                  "fuse each planar cell's returns at its fitted plane, cells this many pixels "
                  "square; 0 = fuse returns as measured",
                  [](MapperConfig& c) -> int& { return c.map.snap_cell_px; }));
  p.push_back(num("snap_step_sigmas", "",
                  "snap_cell: where the noise exceeds a voxel, a cell is one plane only if the mean "
                  "residual of each quarter and of each quarter-wide band is within this many "
                  "standard errors of its plane (a step under the noise); 0 = off",
                  [](MapperConfig& c) -> double& { return c.map.snap_step_sigmas; }));
  p.push_back(num("edge_margin", "px",
                  "leave out of the hits the returns with a return this many pixels away that "
                  "lies deeper by edge_jump (the near side of a depth edge); 0 = off",
                  [](MapperConfig& c) -> int& { return c.map.edge_margin_px; }));
  p.push_back(num("edge_jump", "",
                  "edge_margin: the depth step, as a share of the depth, that makes a depth edge",
                  [](MapperConfig& c) -> double& { return c.map.edge_jump; }));
  p.push_back(num("drop_unplaced", "",
                  "snap_cell: leave out of the hits the returns of cells with too few returns to "
                  "place their plane to half a voxel (true | false: snap or fuse as measured)",
                  [](MapperConfig& c) -> bool& { return c.map.drop_unplaced; }));
  p.push_back(num("flush_every", "frames", "frames between OcTree flushes (0 = when saving)",
                  [](MapperConfig& c) -> int& { return c.flush_every; }));
  // ---- ray-cast range (virtual images) ----
  p.push_back(num("raycast_min", "m", "nearest depth of a virtual image",
                  [](MapperConfig& c) -> double& { return c.range.min_m; }));
  p.push_back(num("raycast_max", "m", "farthest depth of a virtual image",
                  [](MapperConfig& c) -> double& { return c.range.max_m; }));
  // ---- loop closure (ClosedLoop, CLStep) ----
  p.push_back(num("loop_closure", "", "correct the pose against the map (ClosedLoop): on | off",
                  [](MapperConfig& c) -> bool& { return c.loop.enabled; }));
  p.push_back(num("cl_step", "frames", "loop-closure attempt every n-th frame (CLStep)",
                  [](MapperConfig& c) -> int& { return c.loop.cl_step; }));
  p.push_back(
      {"cl_reference", "",
       "what loop closure registers against: raycast (a virtual image of the occupancy "
       "map) | surface (a mean-surface layer of the frames fused cl_min_model_age ago)",
       [](const MapperConfig& c) { return toString(c.loop.reference); },
       [](MapperConfig& c, const std::string& v) { c.loop.reference = parseLoopReference(v); }});
  p.push_back(num("cl_surface_voxel", "m",
                  "cl_reference surface: voxel edge of the loop closer's mean-surface layer",
                  [](MapperConfig& c) -> double& { return c.loop.surface.voxel_m; }));
  p.push_back(num("cl_surface_min_weight", "frames",
                  "cl_reference surface: frames that saw a layer voxel before its plane is used",
                  [](MapperConfig& c) -> int& { return c.loop.surface.min_weight; }));
  p.push_back(num("cl_surface_reach", "m",
                  "surface layer: the first round looks this far along each cell's normal for the "
                  "layer's plane (0 = about a voxel and a half)",
                  [](MapperConfig& c) -> double& { return c.loop.surface_reach_m; }));
  p.push_back(num("cl_surface_after_raycast", "",
                  "cl_reference surface: start from the ray cast's correction when it passes "
                  "its gates (reaches drift beyond the layer's 3 cm): on | off",
                  [](MapperConfig& c) -> bool& { return c.loop.surface_after_raycast; }));
  p.push_back(num("cl_downsample", "", "ray-cast the virtual image at 1/n resolution: 1 | 2",
                  [](MapperConfig& c) -> int& { return c.loop.raycast_downsample; }));
  p.push_back(num("cl_min_model_age", "frames",
                  "the model leaves out blocks first seen in the last n fused frames",
                  [](MapperConfig& c) -> int& { return c.loop.min_model_age_frames; }));
  p.push_back(num("cl_min_model_fraction", "", "gate: share of virtual pixels with a return",
                  [](MapperConfig& c) -> double& { return c.loop.min_model_fraction; }));
  p.push_back(num("cl_min_model_cells", "", "gate: cells of the virtual image",
                  [](MapperConfig& c) -> int& { return c.loop.min_model_cells; }));
  p.push_back(num("cl_min_normal_spread", "", "gate: smallest eigenvalue of the normal scatter",
                  [](MapperConfig& c) -> double& { return c.loop.min_normal_spread; }));
  p.push_back(num("cl_min_incidence_cos", "",
                  "cells seen at grazing incidence (|cos| below this) are left out",
                  [](MapperConfig& c) -> double& { return c.loop.min_incidence_cos; }));
  p.push_back(num("cl_min_matches", "", "gate: pairs in the final iteration",
                  [](MapperConfig& c) -> int& { return c.loop.min_matches; }));
  p.push_back(num("cl_max_correction", "m", "gate: larger corrections are mismatches",
                  [](MapperConfig& c) -> double& { return c.loop.max_correction_m; }));
  p.push_back(num("cl_max_correction_angle", "deg", "gate: ... larger rotations",
                  [](MapperConfig& c) -> double& { return c.loop.max_correction_deg; }));
  p.push_back(num("cl_max_error", "m", "gate: residual RMS above this is a poor fit",
                  [](MapperConfig& c) -> double& { return c.loop.max_error_rms_m; }));
  p.push_back(num("cl_deadband", "m", "corrections below this (and cl_deadband_angle) not applied",
                  [](MapperConfig& c) -> double& { return c.loop.deadband_m; }));
  p.push_back(num("cl_deadband_angle", "deg", "... and below this rotation",
                  [](MapperConfig& c) -> double& { return c.loop.deadband_deg; }));
  return p;
}

}  // namespace

const std::vector<MapperParamSpec>& mapperParams() {
  static const std::vector<MapperParamSpec> params = makeParams();
  return params;
}

void setMapperParam(MapperConfig& config, const std::string& name, const std::string& value) {
  setParam(mapperParams(), config, name, value, "mapper");
}

void setMapRegion(MapConfig& config, const std::string& text) {
  if (text == "unbounded") {
    config.bounded = false;
    return;
  }
  double w = 0, h = 0, d = 0;
  char x1 = 0, x2 = 0;
  std::istringstream in(text);
  if (!(in >> w >> x1 >> h >> x2 >> d) || x1 != 'x' || x2 != 'x' || !in.eof() ||
      !(w > 0 && h > 0 && d > 0))
    throw std::invalid_argument("parameter map_region: '" + text +
                                "': expected WxHxD in metres (e.g. 4x3x4) or unbounded");
  config.bounded = true;
  config.region_size_m = Eigen::Vector3d(w, h, d);
  config.start_in_region_m = Eigen::Vector3d(w / 2, h / 2, 0.0);
}

std::string mapRegionText(const MapConfig& config) {
  if (!config.bounded) return "unbounded";
  return param_text::format(config.region_size_m.x()) + "x" +
         param_text::format(config.region_size_m.y()) + "x" +
         param_text::format(config.region_size_m.z());
}

}  // namespace depth_track
