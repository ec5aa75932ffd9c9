// Where registration converges from a range of initial guesses: a rendered run's frame `--ref`
// is the reference, each of `--frames` is registered onto it from guesses whose translation is
// a fraction of the true one (the rotation kept at the truth), and the converged translation is
// printed beside the truth. One basin around the truth means any guess within it is pulled to
// the truth; several minima along one direction mean the estimate there follows the guess.
//
// It runs the tracker's frame-to-frame registration with the tracker's settings after its
// noise calibration on the reference frame (auto_noise), including any prefilter: no motion
// prior, no degeneracy hold, no keyframes, no registration model. docs/tracking.md
// "Hall1 with D435 noise, seed 6" shows what it found there.
//
//   registration_basin --render hall1 --noise d435 --seed 6 --ref 0 --frames 3,5,8
#include <CLI/CLI.hpp>

#include <cmath>
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include "depth_track/core/cells.hpp"
#include "depth_track/core/prefilter.hpp"
#include "depth_track/core/registration.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "tracking_options.hpp"

using namespace depth_track;

int main(int argc, char** argv) {
  CLI::App app{
      "Registration from a range of initial guesses on a rendered run: for each frame of "
      "--frames, registered onto frame --ref from guesses whose translation is each fraction of "
      "--guesses times the true one (rotation at the truth), the converged translation against "
      "the truth. Frame-to-frame registration with the tracker's settings after its noise "
      "calibration on --ref: no motion prior, degeneracy hold, keyframes or registration model."};
  std::string render_name, noise_name = "l515";
  unsigned seed = 1;
  int ref = 0;
  std::vector<int> frames;
  std::vector<double> guesses = {0.0, 0.25, 0.5, 0.75, 1.0, 1.5};
  app.add_option("--render", render_name, "rendered run name (e.g. hall1, rt3)")->required();
  app.add_option("--noise", noise_name, "rendered noise model: l515 | d435 | none")
      ->capture_default_str();
  app.add_option("--seed", seed, "noise seed")->capture_default_str();
  app.add_option("--ref", ref, "reference frame index")->capture_default_str();
  app.add_option("--frames", frames, "frames to register onto --ref (indices, comma-separated)")
      ->delimiter(',')
      ->required();
  app.add_option("--guesses", guesses,
                 "initial translations as fractions of the true one (comma-separated)")
      ->delimiter(',')
      ->capture_default_str();
  tool_options::TrackingOptions options;
  tool_options::addTrackerParamOptions(app, options);
  CLI11_PARSE(app, argc, argv);

  try {
    const sim::RenderedRun run = sim::makeRun(render_name);
    const sim::NoiseConfig noise = sim::NoiseConfig::forModel(sim::parseNoiseModel(noise_name));
    const int n = static_cast<int>(run.size());
    auto checkIndex = [n, &render_name](int i, const char* what) {
      if (i < 0 || i >= n)
        throw std::invalid_argument(std::string(what) + " " + std::to_string(i) + ": run " +
                                    render_name + " has frames 0.." + std::to_string(n - 1));
    };
    checkIndex(ref, "--ref");
    for (int k : frames) checkIndex(k, "--frames:");
    for (double g : guesses)
      if (!std::isfinite(g)) throw std::invalid_argument("--guesses: a fraction is not finite");

    const TrackerConfig requested = options.trackerConfig();
    Tracker tracker(run.intrinsics, requested);
    const DepthImage ref_depth = run.renderFrame(ref, noise, seed);
    tracker.track(ref_depth, run.stamps_s[ref]);  // the noise calibration (auto_noise)
    const TrackerConfig& config = tracker.config();
    const PcaConfig pca = config.reducerConfig();
    const RegistrationConfig reg = config.odometryConfig().registration;
    auto cellsOf = [&](const DepthImage& depth) {
      const DepthImage filtered = config.prefilter.type == PrefilterType::kNone
                                      ? depth
                                      : applyPrefilter(depth, config.prefilter);
      return reduceToCells(filtered, run.intrinsics, pca, 1);
    };
    if (tracker.noiseCalibration() && tracker.noiseCalibration()->measured)
      std::printf("noise: %s\n", tracker.noiseCalibration()->summary.c_str());
    const CellCloud reference = cellsOf(ref_depth);
    std::printf("reference frame %d: %zu cells\n", ref, reference.cells.size());
    std::printf("frame,guess_fraction,true_x_mm,true_y_mm,true_z_mm,est_x_mm,est_y_mm,est_z_mm,"
                "error_mm,iterations,pairs,residual_rms_mm\n");
    for (int k : frames) {
      const CellCloud current = cellsOf(run.renderFrame(k, noise, seed));
      const Eigen::Isometry3d truth = run.T_W_C[ref].inverse() * run.T_W_C[k];
      const Eigen::Vector3d t = 1e3 * truth.translation();
      for (double g : guesses) {
        Eigen::Isometry3d guess = truth;
        guess.translation() = g * truth.translation();
        const RegistrationResult r = registerCells(reference, current, run.intrinsics, guess, reg);
        const Eigen::Vector3d e = 1e3 * r.T_ref_cur.translation();
        std::printf("%d,%.2f,%.2f,%.2f,%.2f,%.2f,%.2f,%.2f,%.2f,%d,%d,%.3f\n", k, g, t.x(), t.y(),
                    t.z(), e.x(), e.y(), e.z(), (e - t).norm(), r.iterations, r.matches,
                    1e3 * r.error_rms_m);
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "registration_basin: %s\n", e.what());
    return 1;
  }
  return 0;
}
