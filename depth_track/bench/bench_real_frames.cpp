// The tracking core on real 640x480 Kinect frames, one core: whole tracker frames (reduction +
// registration + bookkeeping) through a TUM sequence with the defaults and their automatic noise
// adaptation, and the reduction alone with the adapted settings. Frames are decoded before the
// clock starts, so PNG decoding is not counted (track_sequence's per-frame figures leave it out
// as well). Issue 12's target: tracking <= 5 ms median per frame.
//
//   DT_BENCH_TUM=/path/to/tum_folder DT_BENCH_CAMERA=fr1|fr2|fr3 dt_bench_real_frames
//
// Without DT_BENCH_TUM it looks for the shared TUM fr3/teddy sequence where the tests do
// (test/shared_data_paths.hpp) and reports an error row when there is none. DT_BENCH_FRAMES
// (default 90) caps the frames loaded.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "../test/shared_data_paths.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tum_cameras.hpp"
#include "depth_track/core/tum_io.hpp"

using namespace depth_track;

namespace {

std::string env(const char* name, const std::string& fallback = "") {
  const char* v = std::getenv(name);
  return v != nullptr && *v != '\0' ? std::string(v) : fallback;
}

struct Sequence {
  std::string folder, error;
  PinholeIntrinsics intrinsics;
  std::vector<DepthImage> frames;
  std::vector<double> stamps;
  Sequence() {
    folder = env("DT_BENCH_TUM", dt_test::findSharedData("data/tum_fr3_teddy", "depth.txt"));
    const std::string camera = env("DT_BENCH_CAMERA", env("DT_BENCH_TUM").empty() ? "fr3" : "");
    if (folder.empty()) {
      error = "no TUM sequence: set DT_BENCH_TUM (and DT_BENCH_CAMERA) or provide shared data";
      return;
    }
    const auto k = tumIntrinsics(camera);
    if (!k) {
      error = camera.empty() ? "DT_BENCH_TUM is set: give DT_BENCH_CAMERA (fr1, fr2 or fr3) too"
                             : "DT_BENCH_CAMERA '" + camera + "': expected fr1, fr2 or fr3";
      return;
    }
    intrinsics = *k;
    const int cap = std::max(2, std::atoi(env("DT_BENCH_FRAMES", "90").c_str()));
    try {
      for (const TumFrame& f : readTumFrameList(folder + "/depth.txt")) {
        if (static_cast<int>(frames.size()) >= cap) break;
        frames.push_back(loadTumDepth(f.path, kTumDepthScaleM, DepthRange()));
        stamps.push_back(f.stamp_s);
      }
    } catch (const std::exception& e) {
      error = e.what();
      return;
    }
    if (frames.size() < 2)
      error = folder + ": " + std::to_string(frames.size()) + " depth frames, at least 2 needed";
  }
};

const Sequence& sequence() {
  static const Sequence s;
  return s;
}

// One iteration tracks every loaded frame after the first with a tracker made (and noise-adapted
// on frame 0) outside the clock. per_frame is the mean CPU time per frame (one thread);
// frame_ms_median (the target's figure) and the stage counters are medians, over the last
// iteration's frames, of FrameStatus's wall-clock times. The argument: 1 = the defaults (the
// registration model on since 2026-12-03; its fusion and keyframe refinement are in the frame's
// total, neither in reduce nor register), 0 = the defaults with the model off.
void BM_RealTrackerFrames(benchmark::State& state) {
  const Sequence& s = sequence();
  if (!s.error.empty()) {
    state.SkipWithError(s.error.c_str());
    return;
  }
  RunningStats total_ms(s.frames.size()), reduce_ms(s.frames.size()), register_ms(s.frames.size());
  int lost = 0;
  for (auto _ : state) {
    state.PauseTiming();
    TrackerConfig config;
    config.model.enabled = state.range(0) != 0;
    Tracker tracker(s.intrinsics, config);
    tracker.track(s.frames[0], s.stamps[0]);
    total_ms.clear();
    reduce_ms.clear();
    register_ms.clear();
    lost = 0;
    state.ResumeTiming();
    for (std::size_t i = 1; i < s.frames.size(); ++i) {
      const FrameStatus st = tracker.track(s.frames[i], s.stamps[i]);
      total_ms.add(st.ms_total);
      reduce_ms.add(st.ms_reduce);
      register_ms.add(st.ms_register);
      lost += st.tracked ? 0 : 1;
    }
  }
  const double frames = static_cast<double>(s.frames.size() - 1);
  state.counters["per_frame"] = benchmark::Counter(
      frames, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  state.counters["frame_ms_median"] = total_ms.median();
  state.counters["reduce_ms_median"] = reduce_ms.median();
  state.counters["register_ms_median"] = register_ms.median();
  state.counters["frames"] = frames;
  state.counters["lost"] = lost;
  state.SetLabel(std::filesystem::path(s.folder).filename().string() +
                 (state.range(0) ? " model" : ""));
}
BENCHMARK(BM_RealTrackerFrames)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// The reduction alone on every loaded frame, with the settings the noise adaptation chose.
void BM_RealReduce(benchmark::State& state) {
  const Sequence& s = sequence();
  if (!s.error.empty()) {
    state.SkipWithError(s.error.c_str());
    return;
  }
  Tracker tracker(s.intrinsics, TrackerConfig());
  tracker.track(s.frames[0], s.stamps[0]);
  const PcaConfig pca = tracker.config().reducerConfig();
  const WorkerPool pool(1);
  std::size_t cells = 0;
  for (auto _ : state) {
    for (const DepthImage& d : s.frames) {
      CellCloud c = reduceToCells(d, s.intrinsics, pca, pool);
      cells += c.cells.size();
      benchmark::DoNotOptimize(c);
    }
  }
  const double frames = static_cast<double>(s.frames.size());
  state.counters["per_frame"] = benchmark::Counter(
      frames, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
  state.counters["cells_per_frame"] =
      static_cast<double>(cells) / (frames * static_cast<double>(state.iterations()));
  state.counters["normal_radius_cells"] = pca.normal_radius_cells;
  state.SetLabel(std::filesystem::path(s.folder).filename().string());
}
BENCHMARK(BM_RealReduce)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
