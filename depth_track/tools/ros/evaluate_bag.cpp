// evaluate_bag: replays a recorded run (a rig bag, or a TUM sequence through tum_to_bag) through
// the core's tracking stages (the Tracker and Mapper the nodelets run) and scores the tracked
// trajectory against every reference the bag holds: the rig's own sensors through the rig's
// kinematics (the thesis's method, ch. 5) and ground truth. Reads the bag with the rosbag API, no
// roscore; deterministic; as fast as the CPU allows.
//
//   rosrun depth_track evaluate_bag BAG [--out-dir DIR] [--plots] [tracker and map options]
//
// Writes into --out-dir: trajectory.txt (TUM, camera-to-world), frames.csv (per frame: tracked,
// reference and error per angle and axis, ICP error, matches, ms per stage), reference_*.txt
// (each reference at its own stamps, TUM), scores.csv, latency.csv, link_timing.csv, report.txt
// (what is printed), map_voxels.f32 (with a map) and, with --plots, PNGs made by
// scripts/evaluate_plots.py. Last line:
//   frames=N tracked=M ate_rmse_m=X max_err_deg=a,b,c max_err_mm=x,y,z median_ms=T
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "../tracking_options.hpp"
#include "bag_run.hpp"
#include "depth_track/core/angles.hpp"
#include "depth_track/core/depth_correction.hpp"
#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tum_io.hpp"
#include "depth_track/ros/conversions.hpp"

#ifndef DT_SCRIPTS_DIR
#define DT_SCRIPTS_DIR ""
#endif

namespace fs = std::filesystem;
using namespace depth_track;
using Clock = std::chrono::steady_clock;

namespace {

std::string fmt(const char* format, ...) __attribute__((format(printf, 1, 2)));
std::string fmt(const char* format, ...) {
  char buf[2048];
  va_list args;
  va_start(args, format);
  std::vsnprintf(buf, sizeof(buf), format, args);
  va_end(args);
  return buf;
}

/// Everything printed goes to stdout and into report.txt.
class Report {
 public:
  void line(const std::string& s) {
    std::fputs(s.c_str(), stdout);
    if (s.empty() || s.back() != '\n') std::fputc('\n', stdout);
    std::fflush(stdout);
    text_ += s;
    if (s.empty() || s.back() != '\n') text_ += '\n';
  }
  const std::string& text() const { return text_; }

 private:
  std::string text_;
};

/// Progress on stderr: a bar rewritten in place on a terminal, a plain line every 10 % otherwise.
class Progress {
 public:
  explicit Progress(std::size_t total, bool enabled)
      : total_(std::max<std::size_t>(total, 1)), tty_(isatty(2)), enabled_(enabled) {}
  void update(std::size_t done) {
    if (!enabled_) return;
    const double s = std::chrono::duration<double>(Clock::now() - start_).count();
    const double rate = s > 0 ? done / s : 0.0;
    const double eta = rate > 0 ? (total_ - std::min(done, total_)) / rate : 0.0;
    if (tty_) {
      if (done != total_ && std::chrono::duration<double>(Clock::now() - last_).count() < 0.2)
        return;
      last_ = Clock::now();
      const int width = 30, fill = static_cast<int>(width * done / total_);
      std::fprintf(stderr, "\r[%s%s] %zu/%zu frames %.1f frames/s ETA %.0f s   ",
                   std::string(fill, '#').c_str(), std::string(width - fill, '.').c_str(), done,
                   total_, rate, eta);
      if (done >= total_) std::fputc('\n', stderr);
    } else {
      const std::size_t decile = 10 * done / total_;
      if (decile == last_decile_ && done != total_) return;
      last_decile_ = decile;
      std::fprintf(stderr, "evaluate_bag: %zu/%zu frames (%zu %%), %.1f frames/s, ETA %.0f s\n",
                   done, total_, 100 * done / total_, rate, eta);
    }
    std::fflush(stderr);
  }
  void finish(std::size_t done) {
    if (enabled_ && tty_ && done < total_) std::fputc('\n', stderr);
  }

 private:
  std::size_t total_;
  bool tty_, enabled_;
  std::size_t last_decile_ = static_cast<std::size_t>(-1);
  Clock::time_point start_ = Clock::now(), last_ = Clock::time_point{};
};

/// One frame as processed.
struct FrameRecord {
  std::size_t message = 0;  ///< index in the depth topic
  double stamp_s = 0.0;
  bool tracked = false;
  std::string failure;
  int cells = 0, matches = 0, fm_matches = 0, iterations = 0;
  double error_rms_m = 0.0;
  bool keyframe = false, loop_attempted = false, loop_accepted = false;
  int held_directions = 0;  ///< directions the view did not fix, kept at the motion guess
  bool prior = false;       ///< --motion-prior gave this frame's guess
  bool retried = false;     ///< registered again from the previous pose (retry_pairs_below)
  bool retry_kept = false;  ///< ... and that registration kept
  bool unconfirmed = false;  ///< the basin probe found the weakest direction unfixed
  bool deep_kept = false;    ///< held or flagged, and fixed by the deep returns (basin_deep_floor)
  double ms_decode = 0, ms_prefilter = 0, ms_reduce = 0, ms_register = 0, ms_track = 0, ms_map = 0;
  double cpu_ms = 0;  ///< process CPU time of tracking + mapping (all threads)
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
};

/// Process CPU time, ms: on a shared machine the wall clock of a frame is mostly other work.
double cpuMs() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return 1e3 * t.tv_sec + 1e-6 * t.tv_nsec;
}

std::string csvText(std::string s) {
  for (char& c : s)
    if (c == '"') c = '\'';
  return "\"" + s + "\"";
}

/// frames.csv: tracked pose (thesis angles, position in the start camera frame), each reference
/// and the error against it, tracker status, ms per stage. Empty cells where a reference has no
/// pose for the frame.
void writeFramesCsv(const std::string& path, const std::vector<FrameRecord>& frames,
                    const RunEvaluation& run) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "frame,message,stamp_s,tracked,pTx,pTy,pTz,pDx,pDy,pDz";
  const char* keys[] = {"gt", "sens"};
  std::vector<std::string> prefixes;
  for (const ReferenceScore& s : run.scores) prefixes.push_back(keys[s.exact ? 0 : 1]);
  for (const std::string& p : prefixes)
    for (const char* c : {"Tx", "Ty", "Tz", "Dx", "Dy", "Dz", "errTx", "errTy", "errTz", "errRx",
                          "errRy", "errRz", "errDx", "errDy", "errDz"})
      out << "," << p << "_" << c;
  out << ",icp_error_mm,cells,matches,fm_matches,iterations,keyframe,loop_attempted,loop_accepted,"
         "held_directions,prior,retried,retry_kept,unconfirmed,deep_kept,ms_decode,ms_prefilter,ms_reduce,ms_register,"
         "ms_track,ms_map,ms_frame,cpu_ms,failure\n";
  // Per reference: frame index -> its row of errors.
  std::vector<std::vector<const FrameError*>> by_frame(
      run.scores.size(), std::vector<const FrameError*>(frames.size()));
  for (std::size_t r = 0; r < run.scores.size(); ++r)
    for (std::size_t k = 0; k < run.scores[r].est_index.size(); ++k)
      by_frame[r][run.scores[r].est_index[k]] = &run.scores[r].frames[k];
  const Eigen::Isometry3d T_C0_W =
      frames.empty() ? Eigen::Isometry3d::Identity() : frames.front().T_W_C.inverse();
  char buf[256];
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const FrameRecord& f = frames[i];
    const Eigen::Isometry3d T = T_C0_W * f.T_W_C;
    const Eigen::Vector3d e = thesisEulerFromRotation(T.rotation()) * kRadToDeg;
    const Eigen::Vector3d p = 1000.0 * T.translation();
    std::snprintf(buf, sizeof(buf), "%zu,%zu,%.6f,%d,%.5f,%.5f,%.5f,%.3f,%.3f,%.3f", i, f.message,
                  f.stamp_s, f.tracked ? 1 : 0, e.x(), e.y(), e.z(), p.x(), p.y(), p.z());
    out << buf;
    for (std::size_t r = 0; r < run.scores.size(); ++r) {
      const FrameError* fe = by_frame[r][i];
      if (!fe) {
        out << std::string(15, ',');
        continue;
      }
      std::snprintf(buf, sizeof(buf),
                    ",%.5f,%.5f,%.5f,%.3f,%.3f,%.3f,%.5f,%.5f,%.5f,%.5f,%.5f,%.5f,%.3f,%.3f,%.3f",
                    fe->euler_gt_deg.x(), fe->euler_gt_deg.y(), fe->euler_gt_deg.z(),
                    fe->pos_gt_mm.x(), fe->pos_gt_mm.y(), fe->pos_gt_mm.z(), fe->euler_err_deg.x(),
                    fe->euler_err_deg.y(), fe->euler_err_deg.z(), fe->rot_err_deg.x(),
                    fe->rot_err_deg.y(), fe->rot_err_deg.z(), fe->pos_err_mm.x(),
                    fe->pos_err_mm.y(), fe->pos_err_mm.z());
      out << buf;
    }
    std::snprintf(
        buf, sizeof(buf),
        ",%.4f,%d,%d,%d,%d,%d,%d,%d,%d,%d,%d,%d,%d,%d,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,",
        1000.0 * f.error_rms_m, f.cells, f.matches, f.fm_matches, f.iterations, f.keyframe ? 1 : 0,
        f.loop_attempted ? 1 : 0, f.loop_accepted ? 1 : 0, f.held_directions, f.prior ? 1 : 0,
        f.retried ? 1 : 0, f.retry_kept ? 1 : 0, f.unconfirmed ? 1 : 0,
        f.deep_kept ? 1 : 0, f.ms_decode, f.ms_prefilter, f.ms_reduce,
        f.ms_register, f.ms_track, f.ms_map, f.ms_track + f.ms_map, f.cpu_ms);
    out << buf << csvText(f.failure) << "\n";
  }
}

/// scores.csv: one row per reference that scores (and the sensors against ground truth), for
/// scripts (scripts/make_results.py).
void writeScoresCsv(const std::string& path, const RunEvaluation& run) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "reference,role,frames,errTx,errTy,errTz,errDx,errDy,errDz,euler_x,euler_y,euler_z,"
         "ate_rmse_m,ate_max_m,rpe_1f_m,rpe_1f_deg,rpe_1s_m,rpe_1s_deg,end_drift_mm\n";
  const auto row = [&out](const ReferenceScore& s, const std::string& role) {
    if (!s.evaluation) return;
    const TrajectoryEvaluation& e = *s.evaluation;
    const ThesisErrors& t = e.thesis;
    out << fmt(
        "\"%s\",%s,%zu,%.5f,%.5f,%.5f,%.4f,%.4f,%.4f,%.5f,%.5f,%.5f,%.6f,%.6f,%.6f,%.5f,"
        "%.6f,%.5f,%.4f\n",
        s.name.c_str(), role.c_str(), t.frames, t.max_err_deg.x(), t.max_err_deg.y(),
        t.max_err_deg.z(), t.max_err_mm.x(), t.max_err_mm.y(), t.max_err_mm.z(),
        t.max_euler_err_deg.x(), t.max_euler_err_deg.y(), t.max_euler_err_deg.z(),
        e.standard.ate_rmse_m, e.standard.ate_max_m, e.standard.rpe_1f_m, e.standard.rpe_1f_deg,
        e.rpe_1s.rms_m, e.rpe_1s.rms_deg, t.end_drift_mm);
  };
  for (std::size_t i = 0; i < run.scores.size(); ++i)
    row(run.scores[i], std::string(run.scores[i].exact ? "ground_truth" : "sensors") +
                           (static_cast<int>(i) == run.table ? "_table" : ""));
  if (run.sensors_vs_truth) row(*run.sensors_vs_truth, "sensors_vs_ground_truth");
}

void writeLatencyCsv(const std::string& path, const RunEvaluation& run) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "against,shift_frames,shift_ms,rms_rot_deg,rms_pos_mm\n";
  const auto rows = [&out](const LatencyScan& l, const char* against) {
    for (std::size_t i = 0; i < l.shifts.size(); ++i)
      out << fmt("%s,%d,%.2f,%.5f,%.4f\n", against, l.shifts[i], 1000.0 * l.shifts[i] * l.period_s,
                 l.rms_rot_deg[i], l.rms_pos_mm[i]);
  };
  if (run.latency) rows(*run.latency, "tracked");
  if (run.sensor_latency) rows(*run.sensor_latency, "ground_truth");
}

/// One row per scan: its minimum and whether the rig moved enough to resolve it.
void writeLatencyBestCsv(const std::string& path, const RunEvaluation& run) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "against,criterion,best_shift,best_rot_shift,best_pos_shift,rise_rot_deg,rise_pos_mm,"
         "jitter_rot_deg,jitter_pos_mm,rot_resolved,pos_resolved,resolved\n";
  const auto row = [&out](const LatencyScan& l, const char* against) {
    out << fmt("%s,%s,%d,%d,%d,%.5f,%.4f,%.5f,%.4f,%d,%d,%d\n", against, l.criterion.c_str(),
               l.best_shift, l.best_rot_shift, l.best_pos_shift, l.rise_rot_deg, l.rise_pos_mm,
               l.jitter_rot_deg, l.jitter_pos_mm, int(l.rot_resolved), int(l.pos_resolved),
               int(l.resolved));
  };
  if (run.latency) row(*run.latency, "tracked");
  if (run.sensor_latency) row(*run.sensor_latency, "ground_truth");
}

/// Occupied voxel centres in the start camera frame (x right, y down, z ahead), float32 triples.
void writeMapVoxels(const std::string& path, const VoxelMap& map, const Eigen::Isometry3d& T_W_C0) {
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error("cannot write " + path);
  const Eigen::Isometry3d T_C0_W = T_W_C0.inverse();
  map.forEachOccupied([&](const VoxelKey& k) {
    const Eigen::Vector3f p = (T_C0_W * map.centerOf(k)).cast<float>();
    out.write(reinterpret_cast<const char*>(p.data()), 3 * sizeof(float));
  });
}

std::string stageLine(const char* name, const std::vector<double>& v) {
  if (v.empty()) return "";
  RunningStats s(v.size());
  for (const double x : v) s.add(x);
  return fmt("  %-28s median %7.2f  mean %7.2f  p95 %7.2f  max %7.2f ms\n", name, s.median(),
             s.mean(), s.p95(), s.max());
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Replay a recorded run (rosbag) through the tracker and score it against the rig's sensors "
      "and ground truth: the thesis-style error table, ATE/RPE, latency scan, link timing, per-"
      "frame CSV, trajectory and plots."};
  std::string bag_path, out_dir = ".", depth_topic, info_topic, gt_topic, label;
  double depth_scale = 0.0;
  int max_frames = 0, latency_frames = 8;
  bool plots = false, quiet = false;
  app.add_option("bag", bag_path, "the bag to evaluate")->required();
  app.add_option("--out-dir", out_dir, "folder for the outputs (created)")->capture_default_str();
  app.add_option("--label", label, "name of the run in plots and the report (default: bag name)");
  app.add_option("--depth-topic", depth_topic,
                 "depth images (default /camera/image_rect, or the only sensor_msgs/Image)");
  app.add_option("--info-topic", info_topic, "camera_info (default: next to the depth topic)");
  app.add_option("--gt-topic", gt_topic,
                 "ground truth PoseStamped (default /rig_sim/camera_pose or "
                 "/ground_truth/camera_pose)");
  app.add_option("--depth-scale", depth_scale,
                 "metres per 16-bit unit (default: the bag's depth_scale_m, else 0.001 = REP 118)");
  tool_options::IntrinsicsOptions given_k;
  tool_options::addIntrinsicsOptions(app, given_k, "instead of the bag's camera_info");
  app.add_option("--frames", max_frames, "evaluate at most this many frames (0 = all)");
  app.add_option("--latency-scan", latency_frames,
                 "latency scan over +-N sensor intervals (0 = none)")
      ->capture_default_str();
  app.add_flag("--plots", plots,
               "draw the plots (scripts/evaluate_plots.py; builds the map for its views)");
  app.add_flag("--quiet", quiet, "no progress output");
  RigGeometry geometry;
  app.add_option("--truck-wheelbase", geometry.truck.wheelbase_m, "ServoTruck wheelbase, m")
      ->capture_default_str();
  app.add_option("--truck-max-steer", geometry.truck.max_steer_deg,
                 "ServoTruck front wheel angle at full lock, deg")
      ->capture_default_str();
  app.add_option("--truck-speed-lag", geometry.truck.speed_lag_s,
                 "ServoTruck drive lag behind the speed demand (time constant), s")
      ->capture_default_str();
  app.add_option("--truck-steer-lag", geometry.truck.steer_lag_s,
                 "ServoTruck steering lag behind CH2 (time constant), s")
      ->capture_default_str();
  std::string motion_prior = "none";
  app.add_option("--motion-prior", motion_prior,
                 "the tracker's motion guess: none (constant velocity) | sensors (the rig's "
                 "sensors' motion between frames, as the graph's ~guess_frame) | imu (the "
                 "camera's IMU, --imu-topic, as the registration nodelet's ~imu)")
      ->check(CLI::IsMember({"none", "sensors", "imu"}))
      ->capture_default_str();
  std::string imu_topic = "/camera/imu";
  app.add_option("--imu-topic", imu_topic,
                 "sensor_msgs/Imu topic for --motion-prior imu (gyro and accelerometer in one "
                 "message); its frame's mount on the depth frame from /tf_static")
      ->capture_default_str();
  ImuPriorConfig imu_config;  // its mount (T_C_I) from the bag's /tf_static
  tool_options::addImuOptions(app, imu_config);
  tool_options::TrackingOptions options;
  tool_options::addTrackingOptions(app, options);
  CLI11_PARSE(app, argc, argv);

  Report report;
  try {
    if (label.empty()) label = fs::path(bag_path).stem().string();
    const TrackerConfig config = options.trackerConfig();
    const DepthRange range = options.depthRange();
    const DepthCorrection correction = options.depthCorrection();
    if (depth_scale < 0.0 || depth_scale > 1.0)
      throw std::invalid_argument("--depth-scale is metres per unit, in (0, 1]");
    if (latency_frames < 0) throw std::invalid_argument("--latency-scan must be >= 0");
    fs::create_directories(out_dir);

    // ---- what the bag holds ----
    std::unique_ptr<rosbag::Bag> bag = bag_run::openBag(bag_path);
    const bag_run::Topics topics = bag_run::findTopics(*bag, depth_topic, info_topic, gt_topic);
    report.line(fmt("evaluate_bag: %s (%s)", bag_path.c_str(), label.c_str()));
    const auto count = [&](const std::string& t) {
      return topics.counts.count(t) ? topics.counts.at(t) : std::size_t{0};
    };
    const auto have = [&](const std::string& t, const char* role, const char* missing) {
      report.line(t.empty() ? fmt("  %-13s MISSING: %s", role, missing)
                            : fmt("  %-13s %s (%zu messages)", role, t.c_str(), count(t)));
    };
    have(topics.depth, "depth", "no sensor_msgs/Image topic: nothing to track");
    have(topics.info, "camera_info",
         "no sensor_msgs/CameraInfo: the intrinsics must come from --fx --fy --cx --cy");
    have(topics.ground_truth, "ground truth",
         "no /rig_sim/camera_pose or /ground_truth/camera_pose: scored against the sensors only");
    const bool servotrack = !topics.track.empty() || !topics.car.empty();
    if (servotrack) {
      have(topics.track, "track_state", "ServoTrack without track_state: no sensor reference");
      have(topics.car, "carriage", "ServoTrack without carriage_sensors: no sensor reference");
    } else if (!topics.truck.empty()) {
      have(topics.truck, "truck_rc", "");
    } else {
      report.line(
          "  sensors       MISSING: no track_state + carriage_sensors (ServoTrack) or truck_rc "
          "(ServoTruck): no sensor reference, no latency scan");
    }
    report.line(topics.link_timing.empty()
                    ? std::string("  link timing   none (clocks from the state messages only)")
                    : "  link timing   " + bag_run::listOf(topics.link_timing));

    // The optical frame is the depth images' frame id, else the usual name.
    std::string optical_frame = tum_bag::kOpticalFrame;
    if (!topics.depth.empty())
      for (const rosbag::MessageInstance& m :
           rosbag::View(*bag, rosbag::TopicQuery(topics.depth))) {
        if (const auto img = m.instantiate<sensor_msgs::Image>())
          if (!img->header.frame_id.empty()) optical_frame = img->header.frame_id;
        break;
      }
    bag_run::Streams streams = bag_run::readStreams(*bag, topics, optical_frame);
    for (const std::string& p : streams.problems) report.line("  note: " + p);
    if (streams.sensors.hasServoTruck()) {
      if (streams.T_base_optical) {
        geometry.truck.T_B_C = *streams.T_base_optical;
      } else {
        // Without the mount the camera's axes are still known (optical z ahead, y down).
        geometry.truck.T_B_C.linear() = rotationBodyFromOptical();
        report.line("  note: no base_link -> " + optical_frame +
                    " in /tf_static: the truck reference assumes the camera at base_link, "
                    "looking ahead");
      }
    }
    RunReferences refs;
    refs.ground_truth = streams.ground_truth;
    refs.ground_truth_name = topics.ground_truth;
    refs.sensors = streams.sensors;
    refs.geometry = geometry;
    RunEvaluationOptions eval_options;
    eval_options.latency_scan = latency_frames;

    std::vector<LinkTiming> links;
    for (const auto& [name, samples] : streams.links)
      links.push_back(summariseLinkTiming(name, samples));
    const auto printLinks = [&]() {
      if (links.empty()) return;
      report.line("link timing (thesis 4.2.3):");
      report.line(formatLinkTiming(links));
      if (!streams.clocks_missing.empty())
        report.line("  clocks not recorded in this bag: " +
                    bag_run::listOf(streams.clocks_missing));
    };

    // What can be said without tracking: the sensors against ground truth, the links.
    const auto withoutTracking = [&](const std::string& why) {
      report.line("cannot track: " + why);
      std::vector<std::string> still;
      if ((refs.sensors.hasServoTrack() || refs.sensors.hasServoTruck()) &&
          refs.ground_truth.size() >= 2) {
        std::vector<double> stamps;
        for (const StampedPose& p : refs.ground_truth) stamps.push_back(p.stamp_s);
        const Trajectory sens = sensorTrajectory(refs.sensors, stamps, refs.geometry);
        RunReferences gt_only;
        gt_only.ground_truth = refs.ground_truth;
        gt_only.ground_truth_name = refs.ground_truth_name;
        RunEvaluation r = evaluateRun(sens, gt_only, RunEvaluationOptions{});
        if (r.table >= 0) {
          report.line("still evaluated: the rig sensors (" + refs.sensors.describe() +
                      ") against ground truth, as if they were the tracker:");
          report.line(formatRunEvaluation(r));
          still.push_back("sensors vs ground truth");
        }
      }
      if (!links.empty()) {
        printLinks();
        still.push_back("link timing");
      }
      report.line(still.empty() ? std::string("nothing else can be evaluated from this bag")
                                : "what could still be evaluated: " + bag_run::listOf(still));
      report.line(
          "frames=0 tracked=0 ate_rmse_m=nan max_err_deg=nan,nan,nan max_err_mm=nan,nan,nan "
          "median_ms=nan");
      std::ofstream(out_dir + "/report.txt") << report.text();
      return 2;
    };
    if (topics.depth.empty()) return withoutTracking("the bag has no depth images");

    // ---- intrinsics and depth unit ----
    PinholeIntrinsics K;
    bool have_k = false;
    std::string k_source;
    if (given_k.given()) {
      K = given_k.intrinsics();  // the image size from the first image
      have_k = true;
      k_source = "--fx/--fy/--cx/--cy";
    } else if (!topics.info.empty()) {
      std::string last_problem;
      for (const rosbag::MessageInstance& m : rosbag::View(*bag, rosbag::TopicQuery(topics.info))) {
        const auto ci = m.instantiate<sensor_msgs::CameraInfo>();
        if (!ci) continue;
        try {
          K = conv::intrinsicsFromCameraInfo(*ci);
          have_k = true;
          k_source = topics.info;
          break;
        } catch (const DepthInputError& e) {
          last_problem = e.what();
        }
      }
      if (!have_k)
        return withoutTracking(topics.info + " holds no usable camera_info (" + last_problem +
                               "): give --fx --fy --cx --cy");
    } else {
      return withoutTracking(
          "the bag has no camera_info: give the intrinsics with --fx --fy --cx --cy");
    }
    std::optional<double> recorded_scale;
    std::string image_encoding;
    {
      rosbag::View v(*bag, rosbag::TopicQuery(topics.depth));
      for (const rosbag::ConnectionInfo* c : v.getConnections())
        if (c->header)
          if (const auto s = tum_bag::depthScaleOf(*c->header)) recorded_scale = *s;
      if (!topics.info.empty() && !recorded_scale) {
        rosbag::View vi(*bag, rosbag::TopicQuery(topics.info));
        for (const rosbag::ConnectionInfo* c : vi.getConnections())
          if (c->header)
            if (const auto s = tum_bag::depthScaleOf(*c->header)) recorded_scale = *s;
      }
      for (const rosbag::MessageInstance& m : v) {
        const auto img = m.instantiate<sensor_msgs::Image>();
        if (!img) continue;
        image_encoding = img->encoding;
        if (K.width <= 0) K.width = img->width, K.height = img->height;
        break;
      }
    }
    const bool float_depth = image_encoding == "32FC1";
    double scale = 0.001;
    std::string scale_source = "assumed (REP 118: mm); --depth-scale sets it";
    if (depth_scale > 0.0) {
      scale = depth_scale, scale_source = "--depth-scale";
    } else if (recorded_scale) {
      scale = *recorded_scale, scale_source = "recorded in the bag (depth_scale_m)";
    }
    if (float_depth) scale_source = "32FC1: metres";
    report.line(fmt("  intrinsics    %dx%d fx %.2f fy %.2f cx %.2f cy %.2f (%s)", K.width, K.height,
                    K.fx, K.fy, K.cx, K.cy, k_source.c_str()));
    report.line(float_depth ? fmt("  depth unit    %s", scale_source.c_str())
                            : fmt("  depth unit    %g m per unit of %s, %s", scale,
                                  image_encoding.c_str(), scale_source.c_str()));
    if (!float_depth && !recorded_scale && !(depth_scale > 0.0))
      std::fprintf(stderr,
                   "evaluate_bag: warning: %s records no depth unit; assuming 1 mm per unit "
                   "(REP 118). Give --depth-scale if that is wrong (L515 raw 0.00025)\n",
                   topics.depth.c_str());

    // ---- the run ----
    // The start pose: --initial-pose, else the camera mount the bag records (base_link ->
    // optical in /tf_static), where the graph's odometry starts too (REP 105: odom is base_link
    // at the start), so the two compute in the same frame and print the same figures.
    const bool mount_start = options.initial_pose.empty() && streams.T_base_optical.has_value();
    const Eigen::Isometry3d T_W_C0 = mount_start ? *streams.T_base_optical : options.startPose();
    if (!options.initial_pose.empty())
      report.line("  start pose    --initial-pose " + options.initial_pose);
    else if (mount_start)
      report.line("  start pose    the camera mount (base_link -> " + optical_frame +
                  " in /tf_static), as the graph's odometry");
    else
      report.line("  start pose    identity (no camera mount in /tf_static)");
    Tracker tracker(K, config, T_W_C0);
    // --motion-prior sensors: the rig's sensors' motion between frames replaces the constant-
    // velocity guess, as the graph's ~guess_frame does from tf (a wheel odometry).
    std::optional<SensorMotionPrior> sensor_prior;
    if (motion_prior == "sensors") {
      try {  // no stream, an unordered or non-finite one: named by the prior's own checks
        sensor_prior.emplace(refs.sensors, refs.geometry);
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(std::string("--motion-prior sensors: ") + e.what());
      }
      report.line("  motion prior  the rig's sensors (" + refs.sensors.describe() +
                  "): their motion between frames is the tracker's guess");
    }
    // --motion-prior imu: the camera's IMU (ImuMotionPrior), its mount from /tf_static.
    std::optional<ImuMotionPrior> imu_prior;
    bag_run::ImuStream imu;
    std::size_t imu_fed = 0;
    if (motion_prior == "imu") {
      imu = bag_run::readImu(*bag, imu_topic);
      if (imu.samples.size() < 2)
        throw std::invalid_argument("--motion-prior imu: " + imu_topic + " holds " +
                                    std::to_string(imu.samples.size()) +
                                    " usable sensor_msgs/Imu messages (give --imu-topic)");
      ImuPriorConfig ic = imu_config;
      const auto T_C_I = bag_run::detail::chain(streams.static_tf, optical_frame, imu.frame_id);
      if (!T_C_I && imu.frame_id != optical_frame)
        throw std::invalid_argument("--motion-prior imu: no " + optical_frame + " -> " +
                                    imu.frame_id + " (the IMU's mount) in /tf_static");
      if (T_C_I) ic.T_C_I = *T_C_I;
      imu_prior.emplace(ic);
      report.line(fmt("  motion prior  the camera's IMU (%s, %zu readings at %.0f Hz, frame %s at "
                      "(%.3f, %.3f, %.3f) m in %s)%s",
                      imu_topic.c_str(), imu.samples.size(),
                      (imu.samples.size() - 1) /
                          (imu.samples.back().stamp_s - imu.samples.front().stamp_s),
                      imu.frame_id.c_str(), ic.T_C_I.translation().x(),
                      ic.T_C_I.translation().y(), ic.T_C_I.translation().z(),
                      optical_frame.c_str(),
                      imu.left_out > 0
                          ? fmt("; %zu non-finite or out of order left out", imu.left_out).c_str()
                          : ""));
    }
    std::unique_ptr<Mapper> mapper;
    if (options.mapWanted() || plots)
      mapper = std::make_unique<Mapper>(K, options.mapperConfig(), tracker.pose());
    report.line(fmt(
        "tracker: method %s, cell size %d px, %s reference, prefilter %s; map %s",
        toString(config.registration.method).c_str(), config.pca.cell_size,
        config.icp_frames == 0 ? "adaptive" : fmt("fixed (%d frames)", config.icp_frames).c_str(),
        (config.prefilter.type == PrefilterType::kBilateral
             ? "bilateral " + toString(config.prefilter.bilateral_mode)
             : toString(config.prefilter.type))
            .c_str(),
        !mapper ? "off"
        : mapper->config().loop.enabled
            ? fmt("on, loop closure every %d frames", mapper->config().loop.cl_step).c_str()
            : "on, no loop closure"));

    const std::size_t in_bag = count(topics.depth);
    const std::size_t total = max_frames > 0 ? std::min<std::size_t>(in_bag, max_frames) : in_bag;
    Progress progress(total, !quiet);
    std::vector<FrameRecord> frames;
    std::size_t message = 0, out_of_order = 0, bad_frames = 0, map_failures = 0;
    std::string first_out_of_order, first_bad, first_map_failure, read_error;
    double last_stamp = -std::numeric_limits<double>::infinity();
    try {
      for (const rosbag::MessageInstance& m :
           rosbag::View(*bag, rosbag::TopicQuery(topics.depth))) {
        if (frames.size() + out_of_order >= total) break;
        const std::size_t index = message++;
        const auto t0 = Clock::now();
        const auto img = m.instantiate<sensor_msgs::Image>();
        if (!img) continue;
        const double stamp =
            img->header.stamp.isZero() ? m.getTime().toSec() : img->header.stamp.toSec();
        if (!(stamp > last_stamp)) {
          if (out_of_order++ == 0)
            first_out_of_order =
                fmt("message %zu of %s: stamp %.6f s is not after the previous frame's %.6f s",
                    index, topics.depth.c_str(), stamp, last_stamp);
          continue;
        }
        last_stamp = stamp;
        FrameRecord f;
        f.message = index;
        f.stamp_s = stamp;
        try {
          conv::checkImageMatchesInfo(*img, K);
          DepthImage depth = conv::depthFromMsg(*img, scale, range);
          applyDepthCorrection(depth, correction);
          f.ms_decode = msSince(t0);
          const double cpu0 = cpuMs();
          std::optional<Eigen::Isometry3d> prior;
          std::optional<InertialHold> hold;
          if (sensor_prior) prior = sensor_prior->next(stamp);
          if (imu_prior) {
            imu_fed = imu_prior->addUpTo(imu.samples, imu_fed, stamp);
            prior.reset();
            if (const auto g = imu_prior->guess(stamp)) {
              prior = g->T_Cprev_Ccur;
              hold = g->hold;
            }
          }
          const FrameStatus st = tracker.track(depth, stamp, prior, hold);
          f.tracked = st.tracked;
          f.failure = st.failure;
          f.cells = st.cells, f.matches = st.matches, f.fm_matches = st.fm_matches;
          f.iterations = st.iterations;
          f.error_rms_m = st.error_rms_m;
          f.keyframe = st.new_keyframe;
          f.held_directions = st.degenerate_directions;
          f.prior = prior.has_value();
          f.retried = st.retried, f.retry_kept = st.retry_kept;
          f.unconfirmed = st.unconfirmed_directions > 0;
          f.deep_kept = st.basin_deep_kept;
          f.ms_prefilter = st.ms_prefilter, f.ms_reduce = st.ms_reduce;
          f.ms_register = st.ms_register, f.ms_track = st.ms_total;
          f.T_W_C = st.T_W_C;
          if (mapper) {
            const auto tm = Clock::now();
            try {
              const MapperFrame mf = mapper->process(depth, st.T_W_C);
              if (mf.loop_attempted) {
                f.loop_attempted = true;
                f.loop_accepted = mf.loop.accepted;
                if (mf.loop.accepted) {
                  tracker.correctPose(mf.T_W_C);
                  f.T_W_C = mf.T_W_C;
                }
              }
            } catch (const std::exception& e) {  // e.g. no return to fuse: the pose stands
              if (map_failures++ == 0) first_map_failure = fmt("message %zu: %s", index, e.what());
            }
            f.ms_map = msSince(tm);
          }
          if (imu_prior) imu_prior->update(stamp, tracker.pose(), trackedPoseCovariance(st));
          f.cpu_ms = cpuMs() - cpu0;
        } catch (const std::exception& e) {  // wrong encoding or size: flag the frame, go on
          ++bad_frames;
          if (first_bad.empty()) first_bad = fmt("message %zu: %s", index, e.what());
          f.tracked = false;
          f.failure = e.what();
          f.T_W_C = tracker.pose();
        }
        frames.push_back(f);
        progress.update(frames.size() + out_of_order);
      }
    } catch (const rosbag::BagException& e) {
      read_error = e.what();
    }
    progress.finish(frames.size() + out_of_order);

    // ---- what happened ----
    if (!read_error.empty())
      report.line(
          fmt("note: the bag could not be read past depth message %zu (%s): evaluated the "
              "%zu frames before it; if the bag was cut short, `rosbag reindex %s` "
              "recovers its complete chunks",
              message, read_error.c_str(), frames.size(), bag_path.c_str()));
    const auto frames_with = [&](bool FrameRecord::*flag) {
      return static_cast<std::size_t>(std::count_if(
          frames.begin(), frames.end(), [&](const FrameRecord& f) { return f.*flag; }));
    };
    if (sensor_prior)
      report.line(fmt("motion prior: the sensors' motion guided %zu of %zu frames (the others, the "
                      "first and any outside the sensor streams, the constant-velocity guess)",
                      frames_with(&FrameRecord::prior), frames.size()));
    if (imu_prior) {
      report.line(fmt("motion prior: the IMU guided %zu of %zu frames", frames_with(&FrameRecord::prior),
                      frames.size()));
      if (!imu_prior->started())
        report.line("  note: the IMU prior never started: " + imu_prior->reason());
    }
    if (out_of_order > 0)
      report.line(
          fmt("note: %zu frames skipped because their stamps go back in time (first: "
              "%s); the rest is evaluated",
              out_of_order, first_out_of_order.c_str()));
    if (bad_frames > 0)
      report.line(
          fmt("note: %zu frames could not be used (first: %s)", bad_frames, first_bad.c_str()));
    if (map_failures > 0)
      report.line(fmt("note: %zu frames were tracked but not fused into the map (first: %s)",
                      map_failures, first_map_failure.c_str()));
    std::size_t tracked = 0;
    std::map<std::string, int> failures;
    Trajectory est;
    std::vector<double> ms_decode, ms_pre, ms_reduce, ms_reg, ms_track, ms_map, ms_frame, cpu_frame;
    for (const FrameRecord& f : frames) {
      tracked += f.tracked;
      if (!f.tracked) failures[f.failure.substr(0, f.failure.find(':'))]++;
      est.push_back({f.stamp_s, f.T_W_C});
      if (f.ms_track <= 0.0) continue;  // unusable frames have no timing
      ms_decode.push_back(f.ms_decode);
      ms_pre.push_back(f.ms_prefilter);
      ms_reduce.push_back(f.ms_reduce);
      ms_reg.push_back(f.ms_register);
      ms_track.push_back(f.ms_track);
      if (mapper) ms_map.push_back(f.ms_map);
      ms_frame.push_back(f.ms_track + f.ms_map);
      cpu_frame.push_back(f.cpu_ms);
    }
    for (const auto& [reason, n] : failures)
      report.line(fmt("flagged %d frames: %s", n, reason.c_str()));
    if (const std::size_t retried = frames_with(&FrameRecord::retried); retried > 0)
      report.line(fmt("registered again from the previous pose: %zu frames, %zu kept "
                      "(retry_pairs_below; frames.csv: retried, retry_kept)",
                      retried, frames_with(&FrameRecord::retry_kept)));
    if (const std::size_t n = frames_with(&FrameRecord::unconfirmed); n > 0)
      report.line(fmt("flagged %zu tracked frames unconfirmed: the basin probe found a direction "
                      "the view does not fix, the pose kept (basin_probe_below; frames.csv: "
                      "unconfirmed)",
                      n));
    if (const std::size_t n = frames_with(&FrameRecord::deep_kept); n > 0)
      report.line(fmt("confirmed %zu frames the near surfaces left unfixed (held, or flagged by "
                      "the basin probe) by registering them again with the deep returns weighted "
                      "up (basin_deep_floor; frames.csv: deep_kept)",
                      n));

    const RunEvaluation run = evaluateRun(est, refs, eval_options);
    report.line(formatRunEvaluation(run));
    printLinks();
    report.line(fmt("time per frame (%zu frames, one thread unless --threads):", ms_frame.size()));
    report.line(stageLine("bag read + depth conversion", ms_decode) +
                stageLine("prefilter", ms_pre) + stageLine("cell reduction", ms_reduce) +
                stageLine("registration", ms_reg) + stageLine("tracker (whole)", ms_track) +
                stageLine("map (fusion + loop closure)", ms_map) +
                stageLine("frame (tracker + map)", ms_frame) +
                stageLine("frame, process CPU time", cpu_frame));
    if (mapper) report.line("map: " + mapper->summary());

    // ---- files ----
    writeTumTrajectory(out_dir + "/trajectory.txt", est,
                       "depth_track evaluate_bag: " + bag_path + " method " +
                           toString(config.registration.method));
    if (!refs.ground_truth.empty())
      writeTumTrajectory(out_dir + "/reference_ground_truth.txt", refs.ground_truth,
                         "ground truth " + topics.ground_truth + " of " + bag_path);
    for (const ReferenceScore& s : run.scores)
      if (!s.exact) {
        std::vector<double> stamps;
        for (const StampedPose& p : est) stamps.push_back(p.stamp_s);
        writeTumTrajectory(out_dir + "/reference_sensors.txt",
                           sensorTrajectory(refs.sensors, stamps, refs.geometry),
                           "camera poses from the rig sensors (" + refs.sensors.describe() +
                               ") at the frames of " + bag_path);
      }
    writeFramesCsv(out_dir + "/frames.csv", frames, run);
    writeScoresCsv(out_dir + "/scores.csv", run);
    if (run.latency || run.sensor_latency) writeLatencyCsv(out_dir + "/latency.csv", run);
    if (run.latency || run.sensor_latency) writeLatencyBestCsv(out_dir + "/latency_best.csv", run);
    if (!links.empty()) {
      std::ofstream l(out_dir + "/link_timing.csv");
      l << "link,frames,sender_period_ms,receiver_period_ms,receiver_period_sd_ms,drift_ms_per_s,"
           "latency_mean_ms,latency_p95_ms,latency_max_ms,jitter_ms,gaps\n";
      for (const LinkTiming& x : links)
        l << fmt("\"%s\",%zu,%.3f,%.3f,%.3f,%.4f,%.3f,%.3f,%.3f,%.3f,%zu\n", x.name.c_str(),
                 x.frames, x.sender_period_ms, x.receiver_period_ms, x.receiver_period_sd_ms,
                 x.drift_ms_per_s, x.latency_mean_ms, x.latency_p95_ms, x.latency_max_ms,
                 x.jitter_ms, x.gaps);
    }
    if (mapper) {
      writeMapVoxels(out_dir + "/map_voxels.f32", mapper->map(), T_W_C0);
      if (!options.map_path.empty()) mapper->save(options.map_path);
    }
    RunningStats frame_stats(std::max<std::size_t>(1, ms_frame.size()));
    for (const double x : ms_frame) frame_stats.add(x);
    const std::string final_line =
        fmt("frames=%zu tracked=%zu %s median_ms=%.2f", frames.size(), tracked,
            formatSummaryFields(run).c_str(), frame_stats.median());
    std::ofstream(out_dir + "/report.txt") << report.text() << final_line << "\n";
    if (plots) {
      const std::string script = std::string(DT_SCRIPTS_DIR) + "/evaluate_plots.py";
      const std::string cmd =
          "/usr/bin/python3 '" + script + "' '" + out_dir + "' --label '" + label + "'";
      const int rc = std::system(cmd.c_str());
      if (rc != 0) report.line("note: the plot script failed (" + cmd + ")");
    }
    report.line(final_line);
    return frames.empty() ? 2 : 0;
  } catch (const bag_run::BagInputError& e) {
    std::cerr << "evaluate_bag: " << e.what() << "\n";
    std::printf(
        "frames=0 tracked=0 ate_rmse_m=nan max_err_deg=nan,nan,nan max_err_mm=nan,nan,nan "
        "median_ms=nan\n");
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "evaluate_bag: " << e.what() << "\n";
    return 2;
  }
}
