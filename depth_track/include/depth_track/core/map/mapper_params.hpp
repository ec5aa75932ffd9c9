#pragma once
/// The mapping stage's parameters (voxel map, loop closure, ray-cast range) as one table, like
/// tracker_params for the tracker: the names are track_sequence's map options (--voxel-size for
/// voxel_size) and the private parameters of the fusion and loop-closure nodelets.
#include <string>
#include <vector>

#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/param_table.hpp"

namespace depth_track {

using MapperParamSpec = BasicParamSpec<MapperConfig>;

/// All mapper parameters. Thread-safe.
const std::vector<MapperParamSpec>& mapperParams();

/// Sets mapper parameter `name` from text; throws std::invalid_argument naming the parameter and
/// value.
void setMapperParam(MapperConfig& config, const std::string& name, const std::string& value);

/// Applies a map region given as "WxHxD" metres (the start camera at the middle of the region's
/// back face, looking in) or "unbounded"; throws std::invalid_argument naming the text.
void setMapRegion(MapConfig& config, const std::string& text);
/// "WxHxD" of a bounded region, "unbounded" otherwise.
std::string mapRegionText(const MapConfig& config);

}  // namespace depth_track
