// render_sequence: renders a named synthetic run (depth_track_sim) into a TUM RGB-D style folder:
//   DIR/depth/<stamp>.png   16-bit depth, 5000 units per metre (TUM convention), 0 = no return
//   DIR/depth.txt           "stamp depth/<stamp>.png" per frame
//   DIR/groundtruth.txt     "t tx ty tz qx qy qz qw", camera (optical frame) to world T_W_C
//   DIR/rig.txt             ServoTrack runs only: "t track_pos_m pitch_deg yaw_deg" per frame
// Example: render_sequence --run xtest1_05_chair --noise l515 --seed 1 --out /tmp/xtest1
//          render_sequence --run rt3 --noise-model my_camera.yaml --out /tmp/rt3  (camera_check's
//          YAML)
#include <CLI/CLI.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tum_io.hpp"

using namespace depth_track;

namespace {

constexpr double kTumScale_m = 1.0 / 5000.0;

std::string stampName(double t) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(6) << t;
  return s.str();
}

void writeTextOrThrow(const std::string& path, const std::string& text) {
  std::ofstream f(path);
  f << text;
  if (!f) throw std::runtime_error("cannot write " + path);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Render a synthetic depth run into a TUM-layout folder (depth PNGs at 5000 units/m, "
      "depth.txt, groundtruth.txt camera-to-world)."};
  std::string run_name, noise_name = "l515", out_dir;
  std::uint64_t seed = 1;
  int threads = 0;
  int max_frames = -1;
  double depth_bias = 0.0;
  double scan_time_ms = 0.0;
  std::string known;
  for (const auto& k : sim::knownRuns()) known += (known.empty() ? "" : ", ") + k;
  app.add_option("--run", run_name, "run name: " + known)->required();
  auto* noise_opt = app.add_option("--noise", noise_name, "noise model: l515 | d435 | none")
                        ->capture_default_str();
  std::string noise_model_path;
  app.add_option("--noise-model", noise_model_path,
                 "noise model YAML (camera_check's noise_model section) instead of --noise; "
                 "--depth-bias, when given, overrides its bias")
      ->excludes(noise_opt);
  app.add_option("--seed", seed, "noise seed (same seed = same frames)")->capture_default_str();
  app.add_option("--out", out_dir, "output folder (created; existing files are overwritten)")
      ->required();
  app.add_option("--threads", threads, "TBB threads for rendering (0 = default)")
      ->capture_default_str();
  app.add_option("--max-frames", max_frames, "render only the first N frames (-1 = all)")
      ->capture_default_str();
  auto* bias_opt = app.add_option("--depth-bias", depth_bias,
                                  "systematic depth scale error (0.0063 = the thesis's L515, "
                                  "table 4.2)")
                       ->capture_default_str();
  app.add_option("--scan-time-ms", scan_time_ms,
                 "row-scan time of a frame, ms (0 = all rows at the stamp; moving runs only)")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  try {
    sim::RenderedRun run = sim::makeRun(run_name);
    if (!(scan_time_ms >= 0.0 && scan_time_ms <= 1000.0))
      throw std::invalid_argument("--scan-time-ms must be in [0, 1000]");
    run.scan_time_s = scan_time_ms / 1000.0;
    sim::NoiseConfig noise = noise_model_path.empty()
                                 ? sim::NoiseConfig::forModel(sim::parseNoiseModel(noise_name))
                                 : sim::loadNoiseModelYaml(noise_model_path);
    if (noise_model_path.empty() || bias_opt->count() > 0) noise.depth_scale_bias = depth_bias;
    if (!noise_model_path.empty()) noise_name = noise_model_path;
    if (threads < 0) throw std::invalid_argument("--threads must be >= 0");
    namespace fs = std::filesystem;
    fs::create_directories(fs::path(out_dir) / "depth");

    const std::size_t n =
        max_frames < 0 ? run.size() : std::min<std::size_t>(run.size(), max_frames);
    std::ostringstream depth_list, rig_list;
    depth_list << "# depth maps of rendered run " << run.name << " (noise " << noise_name
               << ", seed " << seed << "): " << run.description << "\n# timestamp filename\n";
    rig_list << "# ServoTrack readings of rendered run " << run.name
             << "\n# timestamp track_pos_m pitch_deg yaw_deg\n";
    Trajectory gt;
    double render_ms = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      const auto t0 = std::chrono::steady_clock::now();
      const DepthImage d = run.renderFrame(i, noise, seed, threads);
      render_ms +=
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      const std::string name = "depth/" + stampName(run.stamps_s[i]) + ".png";
      saveTumDepth((fs::path(out_dir) / name).string(), d, kTumScale_m);
      depth_list << stampName(run.stamps_s[i]) << " " << name << "\n";
      gt.push_back({run.stamps_s[i], run.T_W_C[i]});
      if (run.on_track) {
        const sim::RigSample& r = run.rig[i];
        rig_list << stampName(run.stamps_s[i]) << " " << std::setprecision(6) << r.track_pos_m
                 << " " << r.pitch_rad * kRadToDeg << " " << r.yaw_rad * kRadToDeg << "\n";
      }
    }
    writeTextOrThrow((fs::path(out_dir) / "depth.txt").string(), depth_list.str());
    writeTumTrajectory((fs::path(out_dir) / "groundtruth.txt").string(), gt,
                       "ground truth T_W_C (optical frame to world) of rendered run " + run.name);
    if (run.on_track) writeTextOrThrow((fs::path(out_dir) / "rig.txt").string(), rig_list.str());
    std::printf("%s: %zu frames (%s noise, seed %llu) -> %s; render+noise %.1f ms/frame\n",
                run.name.c_str(), n, noise_name.c_str(), static_cast<unsigned long long>(seed),
                out_dir.c_str(), n ? render_ms / n : 0.0);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "render_sequence: %s\n", e.what());
    return 1;
  }
  return 0;
}
