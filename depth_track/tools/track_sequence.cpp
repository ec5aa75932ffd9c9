// track_sequence: runs the tracker over a recorded depth sequence (TUM RGB-D or 7-Scenes layout)
// or a rendered run and writes the camera trajectory in TUM format. The same core objects as the
// nodelets.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <vector>

#include "depth_track/core/depth_correction.hpp"
#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/map/map_quality.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/core/sim/imu.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/core/tum_io.hpp"
#include "tracking_options.hpp"
#include "sequence_intrinsics.hpp"

using namespace depth_track;

namespace {

// A sequence of depth frames with stamps, from files or the renderer.
class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual std::size_t size() const = 0;
  virtual double stamp(std::size_t i) const = 0;
  /// Loads frame i; throws DepthInputError / FileFormatError for a bad frame.
  virtual DepthImage frame(std::size_t i) const = 0;
  virtual const PinholeIntrinsics& intrinsics() const = 0;
};

// A recorded sequence folder (TUM RGB-D or 7-Scenes layout, readDepthSequence).
class SequenceSource : public FrameSource {
 public:
  SequenceSource(DepthSequence seq, PinholeIntrinsics k, double scale, DepthRange range)
      : seq_(std::move(seq)), k_(k), scale_(scale), range_(range) {
    if (seq_.frames.empty()) throw FileFormatError(seq_.frames_source + " lists no frames");
    if (k_.width <= 0 || k_.height <= 0) {  // image size from the first frame
      readPng16(seq_.frames.front().path, &k_.width, &k_.height);
    }
  }
  std::size_t size() const override { return seq_.frames.size(); }
  double stamp(std::size_t i) const override { return seq_.frames[i].stamp_s; }
  DepthImage frame(std::size_t i) const override {
    return loadSequenceDepth(seq_, i, scale_, range_);
  }
  const PinholeIntrinsics& intrinsics() const override { return k_; }
  const DepthSequence& sequence() const { return seq_; }

 private:
  DepthSequence seq_;
  PinholeIntrinsics k_;
  double scale_;
  DepthRange range_;
};

class RenderSource : public FrameSource {
 public:
  // The run is rendered over `range` (--d-min/--d-max), the range a real sensor would be set to:
  // returns outside it are dropped before the noise is applied, as the camera driver would.
  RenderSource(const std::string& name, const sim::NoiseConfig& noise, std::uint64_t seed,
               const DepthRange& range)
      : run_(sim::makeRun(name)), noise_(noise), seed_(seed) {
    run_.range = range;
  }
  std::size_t size() const override { return run_.size(); }
  double stamp(std::size_t i) const override { return run_.stamps_s[i]; }
  DepthImage frame(std::size_t i) const override { return run_.renderFrame(i, noise_, seed_); }
  const PinholeIntrinsics& intrinsics() const override { return run_.intrinsics; }
  const sim::RenderedRun& run() const { return run_; }

 private:
  sim::RenderedRun run_;
  sim::NoiseConfig noise_;
  std::uint64_t seed_;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Track a depth sequence with the depth_track core and write the camera trajectory (TUM "
      "format, camera-to-world). Input: a recorded sequence folder (--tum / --sequence: TUM "
      "RGB-D or 7-Scenes layout) or a rendered run (--render)."};
  std::string tum_dir, render_name, noise_name = "l515", out_path, gt_out_path, status_path;
  double depth_scale = 0.0002;
  int max_frames = 0;
  std::uint64_t seed = 1;
  bool verbose = false;

  auto* tum_opt = app.add_option(
      "--tum,--sequence", tum_dir,
      "recorded sequence folder: TUM RGB-D (depth.txt, depth/*.png, groundtruth.txt, optional "
      "intrinsics.txt 'fx fy cx cy units_per_metre') or 7-Scenes (frame-*.depth.png and "
      "frame-*.pose.txt, here or in data/; optional camera-intrinsics.txt)");
  auto* render_opt =
      app.add_option("--render", render_name, "rendered run name (e.g. xtest1_05_chair, rt3)");
  tum_opt->excludes(render_opt);
  tool_options::IntrinsicsOptions intrinsics;
  tool_options::addIntrinsicsOptions(app, intrinsics,
                                     "a sequence without an intrinsics file; override it");
  std::string tum_camera;
  auto* camera_opt = app.add_option(
      "--camera", tum_camera, "a TUM sequence's camera: fr1 | fr2 | fr3 (the published calibration)");
  for (const char* name : {"--fx", "--fy", "--cx", "--cy"}) app.get_option(name)->excludes(camera_opt);
  auto* scale_opt = app.add_option(
      "--depth-scale", depth_scale,
      "metres per 16-bit depth unit (default: the sequence's own: TUM 0.0002 = 1/5000, 7-Scenes "
      "0.001, or intrinsics.txt's)");
  app.add_option("--noise", noise_name, "rendered noise model: l515 | d435 | none")
      ->capture_default_str();
  app.add_option("--seed", seed, "noise seed (rendered runs)")->capture_default_str();
  app.add_option("--frames", max_frames, "process at most this many frames (0 = all)");
  app.add_option("--out", out_path, "write the tracked trajectory here (TUM format)");
  app.add_option("--gt-out", gt_out_path,
                 "write the ground truth here (TUM format; a rendered run's, or the sequence's)");
  app.add_option("--status-out", status_path, "per-frame status as CSV");
  app.add_flag("--verbose", verbose, "print one line per frame");
  bool map_quality = false;
  app.add_flag("--map-quality", map_quality,
               "rendered run with --map: the map's precision and completeness against the scene "
               "(true surface sampled on every 20th frame's noise-free render, every 4th pixel)");
  std::string fuse_poses;
  app.add_option("--fuse-poses", fuse_poses,
                 "fuse the frames at this TUM trajectory's poses instead of tracking");
  // A simulated camera IMU as motion prior (rendered runs).
  std::string imu_noise;
  std::uint64_t imu_seed = 0;
  ImuPriorConfig imu_config;
  imu_config.T_C_I.translation() = Eigen::Vector3d(-0.006, 0.005, 0.012);
  app.add_option("--imu-sim", imu_noise,
                 "rendered runs: a camera IMU as motion prior, its readings simulated along the "
                 "run: bmi055 (a D435i's / D455's, noise and bias) | none (exact readings)");
  app.add_option("--imu-seed", imu_seed, "seed of the simulated IMU's noise and bias (0 = --seed)");
  tool_options::addImuOptions(app, imu_config);

  // Tracker and map options, shared with evaluate_bag.
  tool_options::TrackingOptions options;
  tool_options::addTrackingOptions(app, options);
  CLI11_PARSE(app, argc, argv);

  try {
    if (tum_dir.empty() && render_name.empty())
      throw std::invalid_argument("give an input: --tum DIR or --render NAME (" + [] {
        std::string s;
        for (const auto& n : sim::knownRuns()) s += (s.empty() ? "" : ", ") + n;
        return s;
      }() + ")");
    if (depth_scale > 1.0)
      throw std::invalid_argument("--depth-scale is metres per unit; " +
                                  std::to_string(depth_scale) +
                                  " looks like units per metre (TUM: 0.0002 = 1/5000)");
    const DepthCorrection correction = options.depthCorrection();
    const TrackerConfig config = options.trackerConfig();
    const DepthRange range = options.depthRange();

    std::unique_ptr<FrameSource> source;
    const RenderSource* rendered = nullptr;
    const SequenceSource* recorded = nullptr;
    if (!tum_dir.empty()) {
      DepthSequence seq = readDepthSequence(tum_dir);
      IntrinsicsFlags flags{intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, 0};
      for (const char* name : {"--fx", "--fy", "--cx", "--cy"})
        flags.given += app.get_option(name)->count() > 0;
      const ChosenIntrinsics chosen = chooseIntrinsics(seq, tum_dir, tum_camera, flags);
      const PinholeIntrinsics& K = chosen.K;
      const std::string& k_from = chosen.source;
      const double scale = scale_opt->count() > 0 ? depth_scale : seq.depth_scale_m;
      std::printf("sequence: %s, %zu frames, %s ground truth; intrinsics fx=%.2f fy=%.2f "
                  "cx=%.2f cy=%.2f from %s; depth unit %g m%s\n",
                  seq.layout.c_str(), seq.frames.size(),
                  seq.ground_truth.empty() ? "no" : "with", K.fx, K.fy, K.cx, K.cy,
                  k_from.c_str(), scale, scale_opt->count() > 0 ? " (--depth-scale)" : "");
      auto r = std::make_unique<SequenceSource>(std::move(seq), K, scale, range);
      recorded = r.get();
      source = std::move(r);
    } else {
      auto r = std::make_unique<RenderSource>(
          render_name, sim::NoiseConfig::forModel(sim::parseNoiseModel(noise_name)), seed, range);
      rendered = r.get();
      source = std::move(r);
    }
    if (map_quality && (!rendered || !options.mapWanted()))
      throw std::invalid_argument("--map-quality needs a rendered run (--render) and --map");
    const PinholeIntrinsics& K = source->intrinsics();
    Tracker tracker(K, config, options.startPose());

    std::optional<ImuMotionPrior> imu;
    std::vector<ImuSample> imu_samples;
    std::size_t imu_fed = 0;
    int imu_guesses = 0;
    if (!imu_noise.empty()) {
      if (!rendered)
        throw std::invalid_argument("--imu-sim simulates an IMU along a rendered run (--render)");
      imu.emplace(imu_config);
      imu_samples = sim::simulateImu(rendered->run(), imu_config.T_C_I,
                                     sim::ImuNoiseConfig::parse(imu_noise),
                                     imu_seed != 0 ? imu_seed : seed);
    }

    std::unique_ptr<Mapper> mapper;
    Trajectory fuse_traj;
    Eigen::Isometry3d T_run_map = Eigen::Isometry3d::Identity();  // rendered run's world <- map
    if (options.mapWanted() || !fuse_poses.empty()) {
      MapperConfig mc = options.mapperConfig();
      mc.loop.enabled = mc.loop.enabled && fuse_poses.empty();
      if (!fuse_poses.empty()) {
        fuse_traj = readTumTrajectory(fuse_poses);
        if (fuse_traj.empty())
          throw std::invalid_argument("--fuse-poses " + fuse_poses + " has no poses");
      }
      const Eigen::Isometry3d T_M_C0 = fuse_traj.empty() ? tracker.pose() : fuse_traj.front().T_W_C;
      mapper = std::make_unique<Mapper>(K, mc, T_M_C0);
      // The map's frame puts the first camera at T_M_C0, the run's world at T_W_C[0].
      if (rendered) T_run_map = rendered->run().T_W_C.front() * T_M_C0.inverse();
    }

    std::FILE* status = nullptr;
    if (!status_path.empty()) {
      status = std::fopen(status_path.c_str(), "w");
      if (!status) throw std::invalid_argument("cannot write --status-out " + status_path);
      std::fprintf(
          status,
          "stamp_s,tracked,cells,candidates,matches,fm_matches,duplicates_broken,iterations,"
          "error_rms_m,degenerate,weakest_information,unconfirmed,probe_spread_m,deep_kept,"
          "new_keyframe,ms_prefilter,ms_reduce,ms_register,ms_total,failure\n");
    }
    const std::size_t n =
        max_frames > 0 ? std::min<std::size_t>(max_frames, source->size()) : source->size();
    // Frame i is fused at fuse_traj[fuse_pose_of[i]], the nearest stamp within 20 ms (-1: none).
    std::vector<long> fuse_pose_of(n, -1);
    if (!fuse_traj.empty()) {
      std::vector<double> frame_s(n), pose_s(fuse_traj.size());
      for (std::size_t i = 0; i < n; ++i) frame_s[i] = source->stamp(i);
      for (std::size_t j = 0; j < fuse_traj.size(); ++j) pose_s[j] = fuse_traj[j].stamp_s;
      for (const auto& [i, j] : associateStamps(frame_s, pose_s, 0.02))
        fuse_pose_of[i] = static_cast<long>(j);
    }
    Trajectory est, gt;
    std::vector<Eigen::Vector3d> surface;  // --map-quality: the visible true surface
    const Eigen::Isometry3d T_map_run = T_run_map.inverse();
    RunningStats ms(std::max<std::size_t>(1, n));  // a window of the whole run: exact quantiles
    int tracked = 0, bad_frames = 0;
    long keyframe_cells = 0, refined_cells = 0;  // registration model: keyframes' cells, refined
    int retried = 0, retry_kept = 0;             // registered again from the previous pose
    int probed = 0, unconfirmed = 0;             // the basin probe
    int deep_retried = 0, deep_kept = 0;         // held or flagged frames, deep returns weighted up
    std::map<std::string, int> failures;
    long long snapped_returns = 0, fused_returns = 0;  // returns snapped / within the fuse depth
    // Returns left out of the hits: the near side of a depth edge; cells too small to place.
    long long edge_returns = 0, unplaced_returns = 0;
    for (std::size_t i = 0; i < n; ++i) {
      FrameStatus st;
      try {
        DepthImage depth = source->frame(i);
        applyDepthCorrection(depth, correction);
        if (!fuse_traj.empty()) {  // known poses (thesis ImageTest=2): nearest stamp within 20 ms
          if (fuse_pose_of[i] < 0)
            throw std::invalid_argument("no pose in --fuse-poses within 20 ms of this frame");
          const StampedPose& known = fuse_traj[static_cast<std::size_t>(fuse_pose_of[i])];
          const FuseStats fs = mapper->fuse(depth, known.T_W_C);
          snapped_returns += fs.snapped_pixels;
          edge_returns += fs.edge_dropped;
          unplaced_returns += fs.unplaced_dropped;
          fused_returns += fs.returnsWithinFuseDepth();
          st.stamp_s = source->stamp(i);
          st.tracked = true;
          st.T_W_C = known.T_W_C;
        } else {
          std::optional<Eigen::Isometry3d> guess;
          std::optional<InertialHold> hold;
          if (imu) {
            imu_fed = imu->addUpTo(imu_samples, imu_fed, source->stamp(i));
            if (const auto g = imu->guess(source->stamp(i))) {
              guess = g->T_Cprev_Ccur;
              hold = g->hold;
            }
            imu_guesses += guess.has_value();
          }
          st = tracker.track(depth, source->stamp(i), guess, hold);
          keyframe_cells += st.model.cells;
          refined_cells += st.model.refined;
          retried += st.retried;
          retry_kept += st.retry_kept;
          probed += st.basin_probed;
          unconfirmed += st.unconfirmed_directions > 0;
          deep_retried += st.basin_deep_retried;
          deep_kept += st.basin_deep_kept;
          if (mapper) {
            // Accepted corrections move the tracker (its world is the map frame), which keeps
            // this tool's trajectories as they were; the graph keeps the tracker in odom and a
            // map -> odom correction instead (Mapper::processOdom: the same poses up to rounding,
            // test_map_stages).
            const MapperFrame mf = mapper->process(depth, st.T_W_C);
            snapped_returns += mf.fuse.snapped_pixels;
            edge_returns += mf.fuse.edge_dropped;
            unplaced_returns += mf.fuse.unplaced_dropped;
            fused_returns += mf.fuse.returnsWithinFuseDepth();
            if (mf.loop_attempted && mf.loop.accepted) {
              tracker.correctPose(mf.T_W_C);
              st.T_W_C = mf.T_W_C;
            }
            if (verbose && mf.loop_attempted)
              std::printf("%5zu loop closure: %s\n", i, mf.loop.reason.c_str());
          }
          if (imu) imu->update(source->stamp(i), tracker.pose(), trackedPoseCovariance(st));
        }
      } catch (const std::exception& e) {  // unreadable or wrong-size frame: flag it, go on
        ++bad_frames;
        st.tracked = false;  // the tracker may have succeeded before the mapper threw
        st.stamp_s = source->stamp(i);
        st.failure = e.what();
        st.T_W_C = tracker.pose();
        std::cerr << "frame " << i << ": " << e.what() << "\n";
      }
      if (map_quality && i % 20 == 0)
        for (const Eigen::Vector3d& p_run : rendered->run().visibleSurface(i, 4)) {
          const Eigen::Vector3d p = T_map_run * p_run;
          if (mapper->map().region().contains(p)) surface.push_back(p);
        }
      if (st.tracked)
        ++tracked;
      else
        failures[st.failure.substr(0, st.failure.find(':'))]++;
      if (st.ms_total > 0) ms.add(st.ms_total);
      est.push_back({st.stamp_s, st.T_W_C});
      if (rendered) {
        const auto& T = rendered->run().T_W_C;
        gt.push_back({source->stamp(i), T.front().inverse() * T[i]});
      }
      if (verbose) {
        const Eigen::Vector3d t = st.T_W_C.translation();
        std::printf(
            "%5zu t=%.3f %s cells=%d matches=%d fm=%d it=%d err=%.2fmm xyz=%.4f,%.4f,%.4f ms=%.2f "
            "%s\n",
            i, st.stamp_s, st.tracked ? "ok  " : "FAIL", st.cells, st.matches, st.fm_matches,
            st.iterations, st.error_rms_m * 1000, t.x(), t.y(), t.z(), st.ms_total,
            st.failure.c_str());
      }
      if (status)
        std::fprintf(status,
                     "%.6f,%d,%d,%d,%d,%d,%d,%d,%.6f,%d,%.3f,%d,%.5f,%d,%d,%.3f,%.3f,%.3f,%.3f,"
                     "\"%s\"\n",
                     st.stamp_s, st.tracked, st.cells, st.candidates, st.matches, st.fm_matches,
                     st.duplicates_broken, st.iterations, st.error_rms_m, st.degenerate_directions,
                     st.weakest_information, st.unconfirmed_directions, st.probe_spread_m,
                     st.basin_deep_kept ? 1 : 0, st.new_keyframe, st.ms_prefilter, st.ms_reduce,
                     st.ms_register, st.ms_total, st.failure.c_str());
    }
    if (status) std::fclose(status);
    const std::string what =
        tum_dir.empty() ? "render " + render_name + " noise " + noise_name
                        : recorded->sequence().layout + " " + tum_dir;
    if (!out_path.empty())
      writeTumTrajectory(out_path, est,
                         "depth_track track_sequence: " + what + " method " +
                             toString(config.registration.method));
    // Ground truth: the rendered run's, or the recorded sequence's.
    const Trajectory& truth = rendered ? gt : recorded->sequence().ground_truth;
    if (!gt_out_path.empty()) {
      if (truth.empty())
        throw std::invalid_argument("--gt-out: " + tum_dir + " has no ground truth");
      writeTumTrajectory(gt_out_path, truth,
                         rendered ? "ground truth of rendered run " + render_name +
                                        ", relative to its first pose"
                                  : "ground truth of " + tum_dir + " (" +
                                        recorded->sequence().ground_truth_source + ")");
    }
    if (truth.size() >= 2) {
      try {
        std::printf("%s\n", formatEvaluation(evaluateTrajectory(est, truth)).c_str());
      } catch (const std::invalid_argument& e) {
        std::printf("no evaluation: %s\n", e.what());
      }
    }
    for (const auto& [reason, count] : failures)
      std::printf("flagged %d frames: %s\n", count, reason.c_str());
    if (retried > 0)
      std::printf("registered again from the previous pose: %d frames, %d kept (retry_pairs_below)\n",
                  retried, retry_kept);
    if (probed > 0)
      std::printf("basin probe: %d frames probed, %d flagged unconfirmed (a direction the view "
                  "does not fix, the pose kept; basin_probe_below)\n",
                  probed, unconfirmed);
    if (deep_retried > 0)
      std::printf("deep returns: %d frames held or flagged registered again with the deep returns "
                  "weighted up, %d of them confirmed and kept (basin_deep_floor)\n",
                  deep_retried, deep_kept);
    if (imu) {
      std::printf("imu prior (simulated %s): %d of %zu frames guessed by it", imu_noise.c_str(),
                  imu_guesses, n);
      if (imu->started())
        std::printf(", gravity %.3f m/s^2; at the end: gravity error %.3f m/s^2, accelerometer "
                    "bias %.3f m/s^2\n",
                    imu->gravity().norm(), imu->gravityError().norm(), imu->accelBias().norm());
      else
        std::printf("; not started: %s\n", imu->reason().c_str());
    }
    if (tracker.noiseCalibration())
      std::printf("noise: %s\n", tracker.noiseCalibration()->summary.c_str());
    const CellCloud& cells = tracker.lastCells();
    std::printf(
        "cells (last frame, cell size %d px): total=%d retained=%d pruned_invalid=%d "
        "pruned_edge=%d "
        "pruned_degenerate=%d\n",
        config.pca.cell_size, cells.stats.total, cells.stats.retained, cells.stats.pruned_invalid,
        cells.stats.pruned_edge, cells.stats.pruned_degenerate);
    if (tracker.config().model.enabled) {
      const SurfaceModel& model = tracker.odometry().model();
      std::printf(
          "registration model: voxel=%.3f m voxels=%zu MB=%.1f (%.1f B per voxel); keyframe "
          "cells refined: %ld of %ld\n",
          model.config().voxel_m, model.voxelCount(), model.memoryBytes() / 1e6,
          model.bytesPerVoxel(), refined_cells, keyframe_cells);
    }
    if (mapper) {
      if (!options.map_path.empty()) mapper->save(options.map_path);
      const VoxelMap& vm = mapper->map();
      const double occ = static_cast<double>(std::max<std::size_t>(1, vm.occupiedCount()));
      // The OcTree holds what was flushed (all of it once saved).
      std::printf(
          "map: voxel=%.4f m occupied=%zu observed=%zu blocks=%zu grid_MB=%.1f (%.1f B per "
          "occupied voxel) octree_MB=%.1f (%.1f B per occupied voxel)%s\n",
          vm.config().voxel_size_m, vm.occupiedCount(), vm.observedCount(), vm.blockCount(),
          vm.memoryBytes() / 1e6, vm.memoryBytes() / occ, vm.octreeMemoryBytes() / 1e6,
          vm.octreeMemoryBytes() / occ,
          options.map_path.empty() ? " (octree not flushed: no --map)" : "");
      const std::string noise_limit = vm.fuseNoiseSummary();
      if (!noise_limit.empty()) std::printf("map noise limit: %s\n", noise_limit.c_str());
      if (vm.config().snap_cell_px > 0)
        std::printf("map snap: %.1f %% of the returns within the fuse depth fused at their cell's "
                    "plane (%lld of %lld)\n",
                    fused_returns > 0 ? 100.0 * snapped_returns / fused_returns : 0.0,
                    snapped_returns, fused_returns);
      if (vm.config().edge_margin_px > 0 || vm.config().drop_unplaced) {
        const auto share = [&](long long k) {
          return fused_returns > 0 ? 100.0 * static_cast<double>(k) / fused_returns : 0.0;
        };
        std::printf("map left out of the hits: %.1f %% of the returns within the fuse depth on "
                    "the near side of a depth edge, %.1f %% in cells too small to place "
                    "(%lld, %lld of %lld)\n",
                    share(edge_returns), share(unplaced_returns), edge_returns, unplaced_returns,
                    fused_returns);
      }
      if (map_quality) {
        const double tol = oneVoxelTolerance(vm.config().voxel_size_m);
        const sim::Scene& scene = rendered->run().scene;
        const SurfaceQuality q = surfaceQuality(
            vm, [&](const Eigen::Vector3d& p) { return scene.distanceTo(T_run_map * p); }, surface,
            tol);
        std::printf(
            "map quality: precision %.2f %% (%zu of %zu occupied voxels within %.1f mm of the "
            "scene), completeness %.2f %% (of %zu visible surface samples)\n",
            100.0 * q.precision, q.near_surface, q.occupied, 1e3 * tol, 100.0 * q.completeness,
            q.surface_samples);
      }
      const LoopCloser* lc = mapper->loopCloser();
      if (lc && lc->layer()) {
        const SurfaceModel& layer = *lc->layer();
        std::printf(
            "loop-closure layer: voxel=%.3f m voxels=%zu MB=%.1f (%.1f B per voxel) "
            "pending_MB=%.1f observe_median_ms=%.2f\n",
            layer.config().voxel_m, layer.voxelCount(), layer.memoryBytes() / 1e6,
            layer.bytesPerVoxel(), lc->pendingBytes() / 1e6, lc->observeTiming().median());
      }
    }
    std::printf("frames=%zu tracked=%d median_ms=%.2f p95_ms=%.2f%s\n", n, tracked, ms.median(),
                ms.p95(), mapper ? (" " + mapper->summary()).c_str() : "");
    return bad_frames > 0 && tracked == 0 ? 1 : 0;
  } catch (const std::exception& e) {
    std::cerr << "track_sequence: " << e.what() << "\n";
    return 2;
  }
}
