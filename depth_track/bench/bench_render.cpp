// Renderer speed: ms per 640x480 frame of the chair room (about 50 primitives) from the
// XTest1_05_Chair start pose, serial and on 2 TBB threads, plus the L515 and D435 noise passes
// (CPU time per frame, one core and two) and the edge distance transform alone.
#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

using namespace depth_track;
using namespace depth_track::sim;

namespace {

void BM_RenderChairRoom(benchmark::State& state) {
  const Scene scene = chairRoomScene();
  const PinholeIntrinsics K = l515Intrinsics();
  const Eigen::Isometry3d T_W_C = cameraPoseOnTrack(0.0, 0.0, 0.0);
  const int threads = static_cast<int>(state.range(0));
  std::size_t valid = 0;
  for (auto _ : state) {
    const DepthImage d = renderDepth(scene, K, T_W_C, DepthRange{}, threads);
    valid = d.countValid();
    benchmark::DoNotOptimize(d.data.data());
  }
  state.counters["primitives"] = static_cast<double>(scene.primitives.size());
  state.counters["valid_px"] = static_cast<double>(valid);
}
BENCHMARK(BM_RenderChairRoom)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_RenderChairRoomWithIncidence(benchmark::State& state) {
  const Scene scene = chairRoomScene();
  const Eigen::Isometry3d T_W_C = cameraPoseOnTrack(0.0, 0.0, 0.0);
  const int threads = static_cast<int>(state.range(0));
  for (auto _ : state) {
    const RenderedDepth r =
        renderDepthWithIncidence(scene, l515Intrinsics(), T_W_C, DepthRange{}, threads);
    benchmark::DoNotOptimize(r.cos_incidence.data());
  }
}
BENCHMARK(BM_RenderChairRoomWithIncidence)
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

void BM_RenderFurnishedRoom(benchmark::State& state) {
  const RenderedRun run = makeRun("room3");
  const int threads = static_cast<int>(state.range(0));
  for (auto _ : state) {
    const DepthImage d = renderDepth(run.scene, run.intrinsics, run.T_W_C[200], run.range, threads);
    benchmark::DoNotOptimize(d.data.data());
  }
  state.counters["primitives"] = static_cast<double>(run.scene.primitives.size());
}
BENCHMARK(BM_RenderFurnishedRoom)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

// Noise pass on the chair room frame with its incidence (as rendered runs use it). Arg 0: model
// (0 = L515, 1 = D435); arg 1: TBB threads (1 = one core, the cost per frame in CPU time).
void BM_Noise(benchmark::State& state) {
  const RenderedDepth clean = renderDepthWithIncidence(
      chairRoomScene(), l515Intrinsics(), cameraPoseOnTrack(0.0, 0.0, 0.0), DepthRange{});
  const NoiseConfig c =
      NoiseConfig::forModel(state.range(0) == 0 ? NoiseModel::kL515 : NoiseModel::kD435);
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              static_cast<std::size_t>(state.range(1)));
  std::uint64_t seed = 0;
  std::size_t valid = 0;
  for (auto _ : state) {
    const DepthImage d = applyNoise(clean.depth, c, ++seed, DepthRange{}, &clean.cos_incidence);
    valid = d.countValid();
    benchmark::DoNotOptimize(d.data.data());
  }
  state.counters["valid_px"] = static_cast<double>(valid);
  state.SetLabel(noiseModelName(c.model));
}
BENCHMARK(BM_Noise)
    ->Args({0, 1})
    ->Args({1, 1})
    ->Args({0, 2})
    ->Args({1, 2})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime();

// Edge distance transform alone (part of every noise pass), one core.
void BM_EdgeDistance(benchmark::State& state) {
  const DepthImage clean = renderDepth(chairRoomScene(), l515Intrinsics(),
                                       cameraPoseOnTrack(0.0, 0.0, 0.0), DepthRange{});
  const NoiseConfig c = NoiseConfig::forModel(NoiseModel::kD435);
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism, 1);
  for (auto _ : state) {
    const std::vector<std::uint8_t> e = edgeDistance(clean, c);
    benchmark::DoNotOptimize(e.data());
  }
}
BENCHMARK(BM_EdgeDistance)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime();

}  // namespace

BENCHMARK_MAIN();
