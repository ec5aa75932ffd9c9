#include "depth_track/core/map/mapper.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <stdexcept>

namespace depth_track {

std::vector<std::string> MapperConfig::validate(const PinholeIntrinsics& intrinsics) const {
  std::vector<std::string> p = intrinsics.validate();
  for (const auto& s : map.validate()) p.push_back("map: " + s);
  for (const auto& s : range.validate()) p.push_back("range: " + s);
  if (loop.enabled)
    for (const auto& s : loop.validate(intrinsics)) p.push_back("loop closure: " + s);
  if (flush_every < 0) p.push_back("flush_every must be >= 0 frames");
  return p;
}

namespace {
const MapConfig& checked(const PinholeIntrinsics& k, const MapperConfig& c) {
  const auto problems = c.validate(k);
  if (!problems.empty()) throw std::invalid_argument("mapper config: " + joinProblems(problems));
  return c.map;
}
}  // namespace

Mapper::Mapper(const PinholeIntrinsics& intrinsics, const MapperConfig& config,
               const Eigen::Isometry3d& T_W_C0)
    : intrinsics_(intrinsics),
      config_(config),
      map_(checked(intrinsics, config)),
      fuser_(map_, intrinsics),
      raycaster_(map_, intrinsics, config.range) {
  map_.placeRegion(T_W_C0);
  if (config.loop.enabled)
    loop_ = std::make_unique<LoopCloser>(map_, intrinsics, config.range, config.loop);
}

FuseStats Mapper::fuse(const DepthImage& depth, const Eigen::Isometry3d& T_W_C) {
  const FuseStats st = fuser_.fuse(depth, T_W_C);
  fuse_ms_.add(st.ms);
  if (config_.flush_every > 0 && map_.framesFused() % config_.flush_every == 0) map_.flush();
  return st;
}

MapperFrame Mapper::process(const DepthImage& depth, const Eigen::Isometry3d& T_W_C) {
  // The identity correction: T_M_O T_O_C is T_W_C exactly.
  return step(depth, 0.0, T_W_C, Eigen::Isometry3d::Identity());
}

MapperFrame Mapper::processOdom(const DepthImage& depth, double stamp_s,
                                const Eigen::Isometry3d& T_O_C) {
  MapperFrame out = step(depth, stamp_s, T_O_C, correction_.T_M_O);
  correction_ = out.correction;
  return out;
}

MapperFrame Mapper::step(const DepthImage& depth, double stamp_s, const Eigen::Isometry3d& T_O_C,
                         const Eigen::Isometry3d& T_M_O) {
  MapperFrame out;
  out.T_W_C = T_M_O * T_O_C;
  out.correction = {correction_.stamp_s, T_M_O};
  ++frames_;
  if (loop_ && frames_ % config_.loop.cl_step == 0 && map_.occupiedCount() > 0) {
    out.loop_attempted = true;
    out.loop = loop_->attempt(depth, stamp_s, T_O_C, T_M_O);
    raycast_ms_.add(out.loop.ms_raycast);
    ++loop_attempts_;
    if (out.loop.accepted) {
      ++loop_accepted_;
      out.T_W_C = out.loop.T_W_C;
      out.correction = out.loop.correction;
    }
  }
  out.fuse = fuse(depth, out.T_W_C);
  if (loop_) loop_->observe(depth, out.T_W_C);
  return out;
}

DepthImage Mapper::raycast(const Eigen::Isometry3d& T_W_C) {
  DepthImage d = raycaster_.cast(T_W_C);
  raycast_ms_.add(raycaster_.timing().last());
  return d;
}

void Mapper::save(const std::string& path) { map_.save(path); }

std::string Mapper::summary() const {
  char buf[200];
  std::snprintf(
      buf, sizeof(buf),
      "fuse_median_ms=%.2f raycast_median_ms=%.2f loop_median_ms=%.2f loop_closures=%d/%d",
      fuseMedianMs(), raycastMedianMs(), loop_ ? loop_->timing().median() : 0.0, loop_accepted_,
      loop_attempts_);
  return buf;
}

}  // namespace depth_track
