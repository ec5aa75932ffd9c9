// Fusion speed: ms per 640x480 frame fused into the voxel map on one core (Release), for the
// rendered XTest1_05_Chair run with L515 noise at its ground-truth poses, 5 mm voxels, default
// 4x3x4 m region, returns snapped to their cell's plane (snap_cell 16) unless the row says
// otherwise. Frames cycle through the run, so the map is warm (as in a long run). Reports
// the median ms per frame, the OctoMap flush cost amortised per frame, memory per occupied voxel,
// the fusion cost while another thread ray-casts the same map (the loop-closure stage sharing
// it), and, for scale and only with DT_BENCH_OCTOMAP=1, OctoMap's own insertPointCloud on the
// same frame.
#include <benchmark/benchmark.h>
#include <octomap/OcTree.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <ctime>
#include <string>
#include <thread>
#include <vector>

#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/map/map_fuser.hpp"
#include "depth_track/core/map/map_raycaster.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

using namespace depth_track;

namespace {

struct Frames {
  sim::RenderedRun run;
  std::vector<DepthImage> depth;
  std::vector<Eigen::Isometry3d> T_W_C;
};

const Frames& frames() {
  static const Frames f = [] {
    Frames out{sim::makeRun("xtest1_05_chair"), {}, {}};
    const auto noise = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
    for (std::size_t i = 0; i < out.run.size(); i += 4) {
      out.depth.push_back(out.run.renderFrame(i, noise, 42, 2));
      out.T_W_C.push_back(out.run.T_W_C[i]);
    }
    return out;
  }();
  return f;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// CPU time of this thread, ms: on a machine shared with other jobs the wall time also counts
// waiting for a core.
double threadCpuMs() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// state.range(0): 0 = hit-only, 1 = probabilistic; range(1): carve stride (px); range(2): snap
// cell (px, 0 = returns fused as measured); range(3): 1 = the defaults leave the near side of
// depth edges and cells too small to place out of the hits, 0 = neither (before 2026-12-06);
// range(4): snap_step_sigmas (the quarters' and bands' planarity test; 0 = off).
void BM_Fuse(benchmark::State& state) {
  const Frames& f = frames();
  MapConfig cfg;
  cfg.model = state.range(0) == 0 ? UpdateModel::kHitOnly : UpdateModel::kProbabilistic;
  cfg.carve_stride_px = static_cast<int>(state.range(1));
  cfg.snap_cell_px = static_cast<int>(state.range(2));
  cfg.snap_step_sigmas = static_cast<double>(state.range(4));
  if (state.range(3) == 0) {
    cfg.edge_margin_px = 0;
    cfg.drop_unplaced = false;
  }
  VoxelMap map(cfg);
  map.placeRegion(f.T_W_C.front());
  MapFuser fuser(map, f.run.intrinsics);
  for (std::size_t i = 0; i < f.depth.size(); ++i) fuser.fuse(f.depth[i], f.T_W_C[i]);
  std::vector<double> ms, cpu_ms;
  std::size_t i = 0;
  double hits = 0, misses = 0, rays = 0, snapped = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = threadCpuMs();
    const FuseStats st = fuser.fuse(f.depth[i], f.T_W_C[i]);
    cpu_ms.push_back(threadCpuMs() - c0);
    ms.push_back(msSince(t0));
    hits += st.hit_updates, misses += st.miss_updates, rays += st.carve_rays;
    snapped += st.snapped_pixels;
    i = (i + 1) % f.depth.size();
  }
  const double n = std::max<double>(1.0, static_cast<double>(ms.size()));
  state.counters["hits_per_frame"] = hits / n;
  state.counters["misses_per_frame"] = misses / n;
  state.counters["carve_rays_per_frame"] = rays / n;
  if (cfg.snap_cell_px > 0) state.counters["snapped_per_frame"] = snapped / n;
  state.counters["median_ms"] = median(ms);
  state.counters["median_cpu_ms"] = median(cpu_ms);
  state.counters["occupied"] = static_cast<double>(map.occupiedCount());
  state.counters["B_per_occ"] =
      static_cast<double>(map.memoryBytes()) / std::max<std::size_t>(1, map.occupiedCount());
  state.counters["grid_MB"] = map.memoryBytes() / 1e6;
  state.SetLabel(toString(cfg.model) +
                 (cfg.model == UpdateModel::kProbabilistic
                      ? ", carve stride " + std::to_string(cfg.carve_stride_px)
                      : std::string()) +
                 (cfg.snap_cell_px > 0
                      ? ", returns snapped (snap_cell " + std::to_string(cfg.snap_cell_px) + ")"
                      : ", returns as measured (snap_cell 0)") +
                 (state.range(3) == 0 ? ", no edge margin, unplaced cells fused" : "") +
                 (state.range(4) == 0 ? ", no quarters' and bands' test" : ""));
}
BENCHMARK(BM_Fuse)
    ->Args({0, 1, 16, 1, 3})
    ->Args({1, 8, 16, 1, 3})  // the defaults
    ->Args({1, 8, 16, 1, 0})  // the snap's RMS test alone (before 2026-12-06)
    ->Args({1, 8, 16, 0, 0})  // ... and every return within the fuse depth hits
    ->Args({1, 8, 0, 1, 3})   // returns fused as measured
    ->Args({1, 12, 16, 1, 3})
    ->Args({1, 4, 16, 1, 3})
    ->Args({1, 1, 16, 1, 3})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// Fusion while a loop-closure thread ray-casts the same map back to back (320x240 virtual views,
// loop closure's size): what sharing one map between a fusion and a loop-closure stage costs the
// fuser. The map's lock lets a waiting fuse in before new casts, so a fuse waits at most for the
// cast in flight. median_ms is the fusion itself, wait_ms the time spent waiting for the lock.
void BM_FuseWhileCasting(benchmark::State& state) {
  const Frames& f = frames();
  VoxelMap map{MapConfig{}};
  map.placeRegion(f.T_W_C.front());
  MapFuser fuser(map, f.run.intrinsics);
  for (std::size_t i = 0; i < f.depth.size(); ++i) fuser.fuse(f.depth[i], f.T_W_C[i]);
  std::atomic<bool> stop{false};
  std::atomic<int> casts{0};
  std::thread reader([&] {
    MapRayCaster caster(map, downsampledIntrinsics(f.run.intrinsics, 2), f.run.range);
    for (std::size_t j = 0; !stop.load(); j = (j + 3) % f.T_W_C.size()) {
      benchmark::DoNotOptimize(caster.cast(f.T_W_C[j]));
      ++casts;
    }
  });
  std::vector<double> ms, wait_ms;
  std::size_t i = 0;
  for (auto _ : state) {
    const FuseStats st = fuser.fuse(f.depth[i], f.T_W_C[i]);
    ms.push_back(st.ms);
    wait_ms.push_back(st.ms_lock_wait);
    i = (i + 1) % f.depth.size();
  }
  stop = true;
  reader.join();
  state.counters["median_ms"] = median(ms);
  state.counters["median_wait_ms"] = median(wait_ms);
  std::sort(wait_ms.begin(), wait_ms.end());
  state.counters["p95_wait_ms"] = wait_ms.empty() ? 0.0 : wait_ms[wait_ms.size() * 95 / 100];
  state.counters["casts_per_fuse"] =
      static_cast<double>(casts.load()) / std::max<std::size_t>(1, ms.size());
  state.SetLabel("probabilistic, stride 8, one thread ray-casting meanwhile");
}
BENCHMARK(BM_FuseWhileCasting)->Unit(benchmark::kMillisecond)->UseRealTime();

// Flush into the OcTree after every k frames; time per frame = (fuse k frames + flush) / k.
void BM_FuseAndFlush(benchmark::State& state) {
  const Frames& f = frames();
  const int k = static_cast<int>(state.range(0));
  MapConfig cfg;
  VoxelMap map(cfg);
  map.placeRegion(f.T_W_C.front());
  std::vector<double> flush_ms;
  std::size_t i = 0;
  for (auto _ : state) {
    for (int j = 0; j < k; ++j) {
      map.fuse(f.depth[i], f.run.intrinsics, f.T_W_C[i]);
      i = (i + 1) % f.depth.size();
    }
    const auto t0 = std::chrono::steady_clock::now();
    benchmark::DoNotOptimize(&map.flush());
    flush_ms.push_back(msSince(t0));
  }
  state.counters["flush_ms_per_frame"] = median(flush_ms) / k;
  state.counters["octree_MB"] = map.octreeMemoryBytes() / 1e6;
  state.counters["octree_B_per_occ"] =
      static_cast<double>(map.octreeMemoryBytes()) / std::max<std::size_t>(1, map.occupiedCount());
  state.SetLabel("probabilistic, flush every " + std::to_string(k) + " frames (time per batch)");
}
BENCHMARK(BM_FuseAndFlush)
    ->Arg(1)
    ->Arg(30)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(20);

// OctoMap's own insertPointCloud (discretised, ray-cast carving) of the same full frame.
void BM_OctomapInsertPointCloud(benchmark::State& state) {
  const Frames& f = frames();
  octomap::OcTree tree(0.005);
  std::size_t i = 0;
  for (auto _ : state) {
    state.PauseTiming();
    octomap::Pointcloud cloud;
    const DepthImage& d = f.depth[i];
    for (int v = 0; v < d.height; ++v)
      for (int u = 0; u < d.width; ++u)
        if (d.at(u, v) > 0) {
          const Eigen::Vector3d p =
              f.T_W_C[i] * f.run.intrinsics.backProject(u, v, d.at(u, v)).cast<double>();
          cloud.push_back(static_cast<float>(p.x()), static_cast<float>(p.y()),
                          static_cast<float>(p.z()));
        }
    const Eigen::Vector3d o = f.T_W_C[i].translation();
    state.ResumeTiming();
    tree.insertPointCloud(cloud, octomap::point3d(o.x(), o.y(), o.z()), -1.0, false, true);
    i = (i + 1) % f.depth.size();
  }
  state.SetLabel("OctoMap insertPointCloud, 5 mm, full frame");
}

}  // namespace

// OctoMap's insertPointCloud takes minutes and several GB on a warm 5 mm map, so it runs only on
// request: DT_BENCH_OCTOMAP=1 dt_bench_fusion.
int main(int argc, char** argv) {
  const char* octomap = std::getenv("DT_BENCH_OCTOMAP");
  if (octomap && std::string(octomap) == "1")
    benchmark::RegisterBenchmark("BM_OctomapInsertPointCloud", BM_OctomapInsertPointCloud)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime()
        ->Iterations(1);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
