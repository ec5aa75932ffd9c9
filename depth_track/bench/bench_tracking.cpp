// Per-stage cost of the tracking core on one core: PCA reduction, registration (P2L, Cell
// Search, P2P) and a whole tracker frame, 640x480 rendered L515 frames of the chair run.
#include <benchmark/benchmark.h>

#include "depth_track/core/registration.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"

using namespace depth_track;

namespace {
struct Frames {
  sim::RenderedRun run = sim::makeRun("xtest1_05_chair");
  DepthImage a, b;
  Frames() {
    const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
    a = run.renderFrame(10, noise, 1);
    b = run.renderFrame(11, noise, 1);
  }
};
const Frames& frames() {
  static const Frames f;
  return f;
}

void BM_PcaReduce(benchmark::State& state) {
  const auto& f = frames();
  PcaConfig cfg;
  cfg.cell_size = static_cast<int>(state.range(0));
  cfg.normal_radius_cells = static_cast<int>(state.range(1));
  cfg.compute_inv_sqrt = false;  // as the tracker runs it for P2L/P2P
  std::size_t cells = 0;
  for (auto _ : state) {
    CellCloud c = reduceToCells(f.a, f.run.intrinsics, cfg);
    cells = c.cells.size();
    benchmark::DoNotOptimize(c);
  }
  state.counters["cells"] = static_cast<double>(cells);
}
BENCHMARK(BM_PcaReduce)->Args({5, 0})->Args({5, 1})->Args({10, 2})->Unit(benchmark::kMillisecond);

void BM_Register(benchmark::State& state) {
  const auto& f = frames();
  PcaConfig pca;
  const CellCloud a = reduceToCells(f.a, f.run.intrinsics, pca);
  const CellCloud b = reduceToCells(f.b, f.run.intrinsics, pca);
  RegistrationConfig cfg;
  cfg.method = static_cast<RegistrationMethod>(state.range(0));
  // The previous frame's motion as the guess, as the tracker's constant-velocity prediction.
  const Eigen::Isometry3d guess = f.run.T_W_C[9].inverse() * f.run.T_W_C[10];
  int iterations = 0, matches = 0;
  for (auto _ : state) {
    const RegistrationResult r = registerCells(a, b, f.run.intrinsics, guess, cfg);
    iterations = r.iterations;
    matches = r.matches;
    benchmark::DoNotOptimize(r);
  }
  state.counters["iterations"] = iterations;
  state.counters["matches"] = matches;
  state.SetLabel(toString(cfg.method));
}
BENCHMARK(BM_Register)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

// A whole tracker frame (reduction + registration + bookkeeping), alternating two frames.
void BM_TrackerFrame(benchmark::State& state) {
  const auto& f = frames();
  TrackerConfig cfg;
  cfg.registration.method = static_cast<RegistrationMethod>(state.range(0));
  Tracker tracker(f.run.intrinsics, cfg);
  tracker.track(f.a, 0.0);
  double t = 0.0;
  bool flip = false;
  for (auto _ : state) {
    t += 1.0 / 30.0;
    flip = !flip;
    benchmark::DoNotOptimize(tracker.track(flip ? f.b : f.a, t));
  }
  state.SetLabel(toString(cfg.registration.method));
}
BENCHMARK(BM_TrackerFrame)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);
}  // namespace

BENCHMARK_MAIN();
