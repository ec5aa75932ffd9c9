// Prefilter speed on a 640x480 frame: ms per frame (wall time; the CPU column sums all threads) for
// the thesis's bilateral filter (Ksz 31, 15 px, 0.05 m), full and separable, 1 and 2 threads, and
// the crop. Uses the first TUM teddy frame when the shared data is present, else a synthetic noisy
// scene of the same size.
#include <benchmark/benchmark.h>

#include <fstream>
#include <random>
#include <string>

#include "depth_track/core/prefilter.hpp"
#include "depth_track/core/tum_io.hpp"

using namespace depth_track;

namespace {

const DepthImage& frame() {
  static const DepthImage d = [] {
    const std::string list =
        std::string(DT_SOURCE_DIR) + "/../../shared/data/tum_fr3_teddy/depth.txt";
    if (std::ifstream(list)) {
      const auto frames = readTumFrameList(list);
      return loadTumDepth(frames.front().path, 1.0 / 5000.0, DepthRange{0.1, 10.0});
    }
    std::mt19937 rng(1);
    std::normal_distribution<float> noise(0.0f, 0.01f);
    DepthImage s(640, 480);
    for (int v = 0; v < 480; ++v)
      for (int u = 0; u < 640; ++u)
        s.at(u, v) = (u % 97 == 0) ? 0.0f : 1.5f + 0.5f * (u > 320) + noise(rng);
    return s;
  }();
  return d;
}

void BM_Bilateral(benchmark::State& state) {
  PrefilterConfig c;
  c.type = PrefilterType::kBilateral;
  c.bilateral_mode = state.range(0) == 0 ? BilateralMode::kFull : BilateralMode::kSeparable;
  const int threads = static_cast<int>(state.range(1));
  const DepthImage& d = frame();
  for (auto _ : state) {
    DepthImage f = applyPrefilter(d, c, threads);
    benchmark::DoNotOptimize(f.data.data());
  }
  state.SetLabel(std::string(state.range(0) == 0 ? "full 31x31" : "separable 2x31") + ", " +
                 std::to_string(threads) + " thread(s), " + std::to_string(d.countValid()) +
                 " valid px");
}
BENCHMARK(BM_Bilateral)
    ->Args({0, 1})
    ->Args({0, 2})
    ->Args({1, 1})
    ->Args({1, 2})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()  // CPU column = all threads' CPU, so 2 threads show their total
    ->UseRealTime();

void BM_Crop(benchmark::State& state) {
  PrefilterConfig c;
  c.type = PrefilterType::kCrop;
  c.crop_x_px = 40;
  c.crop_y_px = 30;
  c.crop_width_px = 560;
  c.crop_height_px = 420;
  const DepthImage& d = frame();
  for (auto _ : state) {
    DepthImage f = applyPrefilter(d, c);
    benchmark::DoNotOptimize(f.data.data());
  }
}
BENCHMARK(BM_Crop)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
