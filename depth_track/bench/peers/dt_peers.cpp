// dt_peers: our tracker and its peers side by side on the same frames in the same run. Every
// frame is loaded (or rendered) once and handed to each method in turn: depth_track::Tracker with
// the default configuration and with the Kinect preset, Open3D point-to-plane ICP, PCL GICP and
// PCL NDT (frame to frame). Prints per method the ATE RMSE (our evaluation code), RPE, time per
// frame around the whole per-frame call (input cloud preparation included, one thread: wall clock
// and process CPU time) and the ratios to ours, and writes every trajectory in TUM format for
// shared/tools/eval_traj.py (bench/peers/run_peers.sh runs both and compares).
//
//   dt_peers --tum DIR --camera fr1|fr2|fr3 [--frames N] [--out-dir DIR]
//   dt_peers --render rt3 [--noise l515|d435] [--seed S] [--frames N] [--out-dir DIR]
//
// A benchmark, not a test: it asserts nothing. Parameters of the peers: bench/peers/README.md.
#include <tbb/global_control.h>
#include <CLI/CLI.hpp>

#ifdef _OPENMP
#include <omp.h>
#endif

#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>

#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/core/tum_cameras.hpp"
#include "depth_track/core/tum_io.hpp"
#include "peers.hpp"

namespace fs = std::filesystem;
using namespace depth_track;

namespace depth_track {
namespace peers {

std::vector<Eigen::Vector3f> backProject(const DepthImage& depth, const PinholeIntrinsics& K) {
  std::vector<Eigen::Vector3f> out;
  out.reserve(depth.data.size() / 2);
  for (int v = 0; v < depth.height; ++v)
    for (int u = 0; u < depth.width; ++u) {
      const float z = depth.at(u, v);
      if (z > 0.0f) out.push_back(K.backProject(static_cast<float>(u), static_cast<float>(v), z));
    }
  return out;
}

}  // namespace peers
}  // namespace depth_track

namespace {

using Clock = std::chrono::steady_clock;

// Frames from a TUM folder or the renderer, with the ground truth to score against.
struct Input {
  std::string label;  ///< for file names: "tum_fr3_teddy", "rt3_l515"
  PinholeIntrinsics K;
  DepthRange range;
  std::vector<double> stamps_s;
  Trajectory truth;
  std::function<DepthImage(std::size_t)> frame;
};

Input tumInput(const std::string& dir, const std::string& camera, const DepthRange& range) {
  const auto K = tumIntrinsics(camera);
  if (!K) throw std::invalid_argument("--camera '" + camera + "': expected fr1, fr2 or fr3");
  Input in;
  in.label = fs::path(dir).lexically_normal().filename().string();
  if (in.label.empty()) in.label = fs::path(dir).lexically_normal().parent_path().filename();
  in.K = *K;
  in.range = range;
  auto frames = std::make_shared<std::vector<TumFrame>>(readTumFrameList(dir + "/depth.txt"));
  for (const TumFrame& f : *frames) in.stamps_s.push_back(f.stamp_s);
  in.truth = readTumTrajectory(dir + "/groundtruth.txt");
  in.frame = [frames, range](std::size_t i) {
    return loadTumDepth((*frames)[i].path, kTumDepthScaleM, range);
  };
  return in;
}

Input renderInput(const std::string& name, const std::string& noise_name, std::uint64_t seed) {
  auto run = std::make_shared<sim::RenderedRun>(sim::makeRun(name));
  const sim::NoiseConfig noise = sim::NoiseConfig::forModel(sim::parseNoiseModel(noise_name));
  Input in;
  in.label = name + "_" + noise_name;
  in.K = run->intrinsics;
  in.range = run->range;
  in.stamps_s = run->stamps_s;
  for (std::size_t i = 0; i < run->size(); ++i)
    in.truth.push_back({run->stamps_s[i], run->T_W_C.front().inverse() * run->T_W_C[i]});
  in.frame = [run, noise, seed](std::size_t i) { return run->renderFrame(i, noise, seed, 1); };
  return in;
}

// Our tracker behind the peers' interface, so all five run through one loop.
class Ours : public peers::Odometry {
 public:
  Ours(std::string name, const PinholeIntrinsics& K, const TrackerConfig& config,
       std::string described)
      : name_(std::move(name)), described_(std::move(described)), tracker_(K, config) {}
  std::string name() const override { return name_; }
  std::string params() const override { return described_; }
  Eigen::Isometry3d track(const DepthImage& depth, bool* registered) override {
    const FrameStatus st = tracker_.track(depth, stamp_s_);
    *registered = st.tracked;
    return st.T_W_C;
  }
  void setStamp(double s) { stamp_s_ = s; }

 private:
  std::string name_, described_;
  Tracker tracker_;
  double stamp_s_ = 0.0;
};

struct MethodRun {
  std::unique_ptr<peers::Odometry> odometry;
  Ours* ours = nullptr;
  Trajectory est;
  std::vector<double> ms;      ///< wall clock per frame
  std::vector<double> cpu_ms;  ///< process CPU time per frame (all threads)
  int flagged = 0;
  std::optional<TrajectoryEvaluation> eval;
  std::string eval_error;
};

// CPU time of the whole process: on a machine shared with other work, the wall clock of a call
// includes the time others ran; CPU time does not (with one thread, it is the call's own work).
double processCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

double mean(const std::vector<double>& v) {
  double s = 0.0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / v.size();
}

std::string describeConfig(const TrackerConfig& c) {
  std::ostringstream s;
  s << toString(c.registration.method) << " cell_size=" << c.pca.cell_size
    << " normal_radius=" << c.pca.normal_radius_cells << " icp_frames=" << c.icp_frames;
  return s.str();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Our tracker beside Open3D ICP, PCL GICP and PCL NDT on the same frames."};
  std::string tum_dir, camera, render_name, noise_name = "l515", out_dir = ".";
  std::string preset = std::string(DT_SOURCE_DIR) + "/../config/tum_kinect.yaml";
  std::string methods = "ours,ours_kinect,open3d_p2l,pcl_gicp,pcl_ndt", init = "velocity";
  std::uint64_t seed = 1;
  int max_frames = 0, threads = 1;
  DepthRange range;
  peers::Open3dParams o3d;
  peers::GicpParams gicp;
  peers::NdtParams ndt;
  auto* tum_opt = app.add_option("--tum", tum_dir, "TUM-layout folder with groundtruth.txt");
  app.add_option("--camera", camera, "TUM camera: fr1 | fr2 | fr3 (--tum)");
  app.add_option("--render", render_name, "rendered run (rt3, xtest1_05_chair, ...)")
      ->excludes(tum_opt);
  app.add_option("--noise", noise_name, "rendered noise: l515 | d435 | none")
      ->capture_default_str();
  app.add_option("--seed", seed, "noise seed (rendered runs)")->capture_default_str();
  app.add_option("--d-min", range.min_m, "nearest valid depth, m (TUM)")->capture_default_str();
  app.add_option("--d-max", range.max_m, "farthest valid depth, m (TUM)")->capture_default_str();
  app.add_option("--frames", max_frames, "use the first N frames (0 = all)");
  app.add_option("--out-dir", out_dir, "trajectories go here as <input>_<method>.txt")
      ->capture_default_str();
  app.add_option("--methods", methods, "comma-separated subset to run")->capture_default_str();
  app.add_option("--preset", preset, "tracker YAML of the ours_kinect method")
      ->capture_default_str();
  app.add_option("--peer-init", init, "peers' initial guess: velocity | identity")
      ->check(CLI::IsMember({"velocity", "identity"}))
      ->capture_default_str();
  app.add_option("--threads", threads, "worker threads for every library (1 = one core)")
      ->capture_default_str();
  app.add_option("--o3d-voxel", o3d.voxel_m, "Open3D voxel size, m")->capture_default_str();
  app.add_option("--o3d-max-corr", o3d.max_corr_m, "Open3D max correspondence distance, m")
      ->capture_default_str();
  app.add_option("--o3d-normal-radius", o3d.normal_radius_m, "Open3D normal search radius, m")
      ->capture_default_str();
  app.add_option("--o3d-max-iter", o3d.max_iterations, "Open3D ICP iterations")
      ->capture_default_str();
  app.add_option("--gicp-voxel", gicp.voxel_m, "GICP voxel size, m")->capture_default_str();
  app.add_option("--gicp-max-corr", gicp.max_corr_m, "GICP max correspondence distance, m")
      ->capture_default_str();
  app.add_option("--gicp-max-iter", gicp.max_iterations, "GICP iterations")->capture_default_str();
  app.add_option("--ndt-voxel", ndt.voxel_m, "NDT input voxel size, m")->capture_default_str();
  app.add_option("--ndt-resolution", ndt.resolution_m, "NDT cell size, m")->capture_default_str();
  app.add_option("--ndt-step", ndt.step_size_m, "NDT line-search step, m")->capture_default_str();
  app.add_option("--ndt-max-iter", ndt.max_iterations, "NDT iterations")->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  try {
    if (tum_dir.empty() == render_name.empty())
      throw std::invalid_argument("give one input: --tum DIR --camera frN, or --render NAME");
    if (threads < 1) throw std::invalid_argument("--threads must be >= 1");
    // One core for everyone unless asked: Open3D parallelises with OpenMP and TBB, we with TBB.
    tbb::global_control tbb_threads(tbb::global_control::max_allowed_parallelism, threads);
#ifdef _OPENMP
    omp_set_num_threads(threads);
#endif
    Input in = tum_dir.empty() ? renderInput(render_name, noise_name, seed)
                               : tumInput(tum_dir, camera, range);
    const peers::InitialGuess guess =
        init == "velocity" ? peers::InitialGuess::kVelocity : peers::InitialGuess::kIdentity;

    std::vector<MethodRun> runs;
    std::vector<std::string> unknown;
    std::stringstream list(methods);
    for (std::string m; std::getline(list, m, ',');) {
      MethodRun r;
      if (m == "ours" || m == "ours_kinect") {
        TrackerConfig config;
        config.threads = threads;
        if (m == "ours_kinect") loadTrackerParamsYaml(preset, config);
        auto o = std::make_unique<Ours>(
            m, in.K, config,
            describeConfig(config) +
                (m == "ours" ? " (defaults)" : " (" + fs::weakly_canonical(preset).string() + ")"));
        r.ours = o.get();
        r.odometry = std::move(o);
      } else if (m == "open3d_p2l") {
#ifdef DT_HAVE_OPEN3D
        r.odometry = peers::makeOpen3dIcp(in.K, o3d, guess);
#endif
      } else if (m == "pcl_gicp") {
#ifdef DT_HAVE_PCL
        r.odometry = peers::makePclGicp(in.K, gicp, guess);
#endif
      } else if (m == "pcl_ndt") {
#ifdef DT_HAVE_PCL
        r.odometry = peers::makePclNdt(in.K, ndt, guess);
#endif
      } else {
        unknown.push_back(m);
        continue;
      }
      if (!r.odometry) {
        std::cerr << "dt_peers: " << m << " not built (library not found at configure time)\n";
        continue;
      }
      runs.push_back(std::move(r));
    }
    if (!unknown.empty())
      throw std::invalid_argument("--methods: unknown '" + unknown.front() +
                                  "' (ours, ours_kinect, open3d_p2l, pcl_gicp, pcl_ndt)");
    if (runs.empty()) throw std::invalid_argument("--methods: nothing to run");

    const std::size_t n =
        max_frames > 0 ? std::min<std::size_t>(max_frames, in.stamps_s.size()) : in.stamps_s.size();
    std::printf(
        "input %s: %zu frames %dx%d fx=%g fy=%g cx=%g cy=%g, depth %.2f-%.2f m, %d thread(s)\n",
        in.label.c_str(), n, in.K.width, in.K.height, in.K.fx, in.K.fy, in.K.cx, in.K.cy,
        in.range.min_m, in.range.max_m, threads);
    for (const MethodRun& r : runs)
      std::printf("  %-12s %s\n", r.odometry->name().c_str(), r.odometry->params().c_str());
    std::printf("  peers' initial guess: %s\n", init.c_str());
    std::fflush(stdout);

    const auto t_start = Clock::now();
    for (std::size_t i = 0; i < n; ++i) {
      const DepthImage depth = in.frame(i);
      for (MethodRun& r : runs) {
        if (r.ours) r.ours->setStamp(in.stamps_s[i]);
        bool ok = false;
        const double cpu0 = processCpuMs();
        const auto t0 = Clock::now();
        const Eigen::Isometry3d T_W_C = r.odometry->track(depth, &ok);
        r.ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        r.cpu_ms.push_back(processCpuMs() - cpu0);
        r.est.push_back({in.stamps_s[i], T_W_C});
        if (!ok) ++r.flagged;
      }
      if ((i + 1) % 100 == 0 || i + 1 == n) {
        std::fprintf(stderr, "  frame %zu/%zu (%.0f s)\n", i + 1, n,
                     std::chrono::duration<double>(Clock::now() - t_start).count());
      }
    }

    fs::create_directories(out_dir);
    if (!tum_dir.empty()) {
      std::printf("ground truth: %s/groundtruth.txt\n", tum_dir.c_str());
    } else {
      const std::string gt_path = out_dir + "/" + in.label + "_gt.txt";
      Trajectory gt(in.truth.begin(), in.truth.begin() + n);
      writeTumTrajectory(gt_path, gt, "ground truth of rendered run " + in.label);
      std::printf("ground truth: %s\n", gt_path.c_str());
    }
    for (MethodRun& r : runs) {
      const std::string path = out_dir + "/" + in.label + "_" + r.odometry->name() + ".txt";
      writeTumTrajectory(
          path, r.est,
          "dt_peers " + in.label + " " + r.odometry->name() + ": " + r.odometry->params());
      std::printf("trajectory %-12s %s\n", r.odometry->name().c_str(), path.c_str());
      try {
        r.eval = evaluateTrajectory(r.est, in.truth);
      } catch (const std::exception& e) {
        r.eval_error = e.what();
      }
    }

    // Ratios against each of our two configurations (whichever ran).
    const MethodRun* ref[2] = {nullptr, nullptr};
    for (const MethodRun& r : runs) {
      if (r.odometry->name() == "ours") ref[0] = &r;
      if (r.odometry->name() == "ours_kinect") ref[1] = &r;
    }
    std::printf("\n%-12s %7s %9s %9s %8s %8s %8s %8s %9s %9s %9s %9s\n", "method", "frames",
                "ate_m", "rpe_1f_m", "med_ms", "mean_ms", "flagged", "cpu_ms", "ate/ours",
                "cpu/ours", "ate/kin", "cpu/kin");
    for (const MethodRun& r : runs) {
      const double med = median(r.ms);
      if (!r.eval) {
        std::printf("%-12s no evaluation: %s\n", r.odometry->name().c_str(), r.eval_error.c_str());
        continue;
      }
      const double cpu = median(r.cpu_ms);
      std::printf("%-12s %7zu %9.5f %9.5f %8.2f %8.2f %8d %8.2f", r.odometry->name().c_str(),
                  r.eval->standard.frames, r.eval->standard.ate_rmse_m, r.eval->standard.rpe_1f_m,
                  med, mean(r.ms), r.flagged, cpu);
      for (const MethodRun* o : ref) {
        if (o && o->eval && o->eval->standard.ate_rmse_m > 0 && median(o->cpu_ms) > 0)
          std::printf(" %9.2f %9.1f", r.eval->standard.ate_rmse_m / o->eval->standard.ate_rmse_m,
                      cpu / median(o->cpu_ms));
        else
          std::printf(" %9s %9s", "-", "-");
      }
      std::printf("\n");
    }
    std::printf(
        "(med_ms, mean_ms: wall clock per frame around the whole call; cpu_ms: median process CPU "
        "time per frame. ate/ours, cpu/ours: ratios to ours with the default config; ate/kin, "
        "cpu/kin: to ours_kinect.)\n");
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "dt_peers: " << e.what() << "\n";
    return 2;
  }
}
