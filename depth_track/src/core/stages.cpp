// The front-end stages: prefilter and cell reduction, each built once and timed per call.
#include <chrono>
#include <stdexcept>

#include "depth_track/core/cell_reducer.hpp"
#include "depth_track/core/prefilter_stage.hpp"

namespace depth_track {

namespace {
std::shared_ptr<const WorkerPool> orSerial(std::shared_ptr<const WorkerPool> pool) {
  return pool ? std::move(pool) : std::make_shared<const WorkerPool>(1);
}
}  // namespace

PrefilterStage::PrefilterStage(const PinholeIntrinsics& intrinsics, const PrefilterConfig& config,
                               std::shared_ptr<const WorkerPool> pool)
    : intrinsics_(intrinsics), config_(config), pool_(orSerial(std::move(pool))) {
  std::vector<std::string> problems = intrinsics.validate();
  for (const auto& s : config.validate(intrinsics.width, intrinsics.height)) problems.push_back(s);
  if (!problems.empty()) throw std::invalid_argument("prefilter stage: " + joinProblems(problems));
}

DepthImage PrefilterStage::apply(const DepthImage& depth) {
  const auto t0 = std::chrono::steady_clock::now();
  checkFrameSize(depth, intrinsics_);
  DepthImage out = applyPrefilter(depth, config_, *pool_);
  timing_.add(msSince(t0));
  return out;
}

CellReducer::CellReducer(const PinholeIntrinsics& intrinsics, const PcaConfig& config,
                         std::shared_ptr<const WorkerPool> pool)
    : intrinsics_(intrinsics), config_(config), pool_(orSerial(std::move(pool))) {
  std::vector<std::string> problems = intrinsics.validate();
  for (const auto& s : config.validate(intrinsics.width, intrinsics.height)) problems.push_back(s);
  if (!problems.empty()) throw std::invalid_argument("cell reducer: " + joinProblems(problems));
}

std::shared_ptr<const CellCloud> CellReducer::reduce(const DepthImage& depth, double stamp_s,
                                                     const std::string& frame_id) {
  const auto t0 = std::chrono::steady_clock::now();
  auto cells = std::make_shared<CellCloud>(reduceToCells(depth, intrinsics_, config_, *pool_));
  cells->stamp_s = stamp_s;
  cells->frame_id = frame_id;
  timing_.add(msSince(t0));
  return cells;
}

}  // namespace depth_track
