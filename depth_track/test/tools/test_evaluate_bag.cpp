// evaluate_bag on recorded runs: a short generated RT2 bag (ServoTrack, yaw sine) scored against
// ground truth and the rig's sensors, checked against the independent checkers; the thesis's
// latency experiment (sensor stream delayed by 4 frames) found by the scan; every kind of bad
// input (no depth, no camera_info, stamps going back, an unindexed bag that `rosbag reindex`
// mends, no sensor topics, no reference at all) named, with what can still be evaluated; and the
// TUM fr3/teddy sequence through tum_to_bag with its ATE checked by eval_traj.py and its
// trajectory equal to track_sequence's on the same folder; the same frames written in the
// 7-Scenes layout read by track_sequence and tum_to_bag. Runs the tools; no roscore.
#include <gtest/gtest.h>
#include <rig_msgs/CarriageSensors.h>
#include <rig_msgs/TrackState.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/tum_io.hpp"
#include "../shared_data.hpp"
#include "tool_test.hpp"

#if !defined(EVALUATE_BAG) || !defined(MAKE_SCENARIO_BAG) || !defined(TUM_TO_BAG) || \
    !defined(TRACK_SEQUENCE) || !defined(REGISTRATION_BASIN)
#error "EVALUATE_BAG, MAKE_SCENARIO_BAG, TUM_TO_BAG, TRACK_SEQUENCE, REGISTRATION_BASIN: tool paths"
#endif

namespace fs = std::filesystem;
using namespace depth_track;
using tool_test::TmpDir;
using tool_test::ToolRun;

namespace {


ToolRun evaluate(const std::string& args, const std::string& dir) {
  return tool_test::runTool(EVALUATE_BAG, args + " --quiet", dir);
}

// The final line's fields.
struct Summary {
  int frames = -1, tracked = -1;
  std::string ate, deg, mm, median;
};
Summary lastLine(const std::string& output) {
  static const std::regex re(
      R"(frames=(\d+) tracked=(\d+) ate_rmse_m=(\S+) max_err_deg=(\S+),(\S+),(\S+) )"
      R"(max_err_mm=(\S+),(\S+),(\S+) median_ms=(\S+)\n?$)");
  std::smatch m;
  Summary s;
  std::string last =
      output.substr(output.rfind("frames=") == std::string::npos ? 0 : output.rfind("frames="));
  if (!std::regex_search(last, m, re)) {
    ADD_FAILURE() << "no final line in:\n" << output;
    return s;
  }
  s.frames = std::stoi(m[1]);
  s.tracked = std::stoi(m[2]);
  s.ate = m[3];
  s.deg = std::string(m[4]) + "," + std::string(m[5]) + "," + std::string(m[6]);
  s.mm = std::string(m[7]) + "," + std::string(m[8]) + "," + std::string(m[9]);
  s.median = m[10];
  return s;
}

// One python checker's output line.
// `tools` = the shared checkers' folder (DT_SHARED_DATA_OR_SKIP(tools, "tools", ...)).
std::string checker(const std::string& tools, const std::string& script, const std::string& est,
                    const std::string& gt, const std::string& dir) {
  const ToolRun r =
      tool_test::runTool("/usr/bin/python3 " + tools + "/" + script, est + " " + gt, dir);
  EXPECT_EQ(r.rc, 0) << r.output;
  return r.output;
}

std::string field(const std::string& line, const std::string& key) {
  const auto at = line.find(key + "=");
  if (at == std::string::npos) return "";
  const auto from = at + key.size() + 1;
  return line.substr(from, line.find_first_of(" \n", from) - from);
}

/// Two printed figure lists ("0.38,0.15,0.14") of the same values, rounded to `unit` by two
/// programs: each pair may differ by one unit, where a value sitting on a rounding boundary
/// rounds up in one and down in the other (the C++ tool and the Python checkers compute in
/// different orders, so their doubles differ in the last bits).
void expectSameRounded(const std::string& a, const std::string& b, double unit,
                       const std::string& context) {
  std::vector<double> va, vb;
  for (auto [text, out] : {std::pair{&a, &va}, std::pair{&b, &vb}}) {
    std::stringstream in(*text);
    for (std::string item; std::getline(in, item, ',');) out->push_back(std::stod(item));
  }
  ASSERT_EQ(va.size(), vb.size()) << a << " vs " << b << "\n" << context;
  ASSERT_FALSE(va.empty()) << context;
  for (std::size_t i = 0; i < va.size(); ++i)
    EXPECT_LE(std::abs(va[i] - vb[i]), unit * 1.001) << a << " vs " << b << "\n" << context;
}

/// Copies a bag message by message; `edit` may rewrite a message (return false to drop it).
using Edit = std::function<bool(const rosbag::MessageInstance&, rosbag::Bag&)>;
void copyBag(const std::string& in, const std::string& out, const Edit& edit) {
  rosbag::Bag src(in, rosbag::bagmode::Read), dst(out, rosbag::bagmode::Write);
  for (const rosbag::MessageInstance& m : rosbag::View(src))
    if (!edit || edit(m, dst)) dst.write(m.getTopic(), m.getTime(), m, m.getConnectionHeader());
  dst.close();
}

Edit dropTopics(const std::set<std::string>& topics) {
  return [topics](const rosbag::MessageInstance& m, rosbag::Bag&) {
    return !topics.count(m.getTopic());
  };
}

// A short generated ServoTrack run shared by the tests: RT2 (95 mm/s, yaw 10 deg at 1/12 Hz),
// its first 60 frames (2 s).
class EvaluateBag : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new TmpDir;
    const ToolRun r =
        tool_test::runTool(MAKE_SCENARIO_BAG,
                           std::string("--scenario ") + DT_SCENARIO_DIR + "/RT2.yaml --out-dir " +
                               tmp_->path + " --max-frames 60 --compression none --threads 2",
                           tmp_->path);
    ASSERT_EQ(r.rc, 0) << r.output;
    bag_ = tmp_->path + "/RT2.bag";
  }
  static void TearDownTestSuite() {
    delete tmp_;
    tmp_ = nullptr;
  }
  static TmpDir* tmp_;
  static std::string bag_;
};
TmpDir* EvaluateBag::tmp_ = nullptr;
std::string EvaluateBag::bag_;

std::vector<std::string> readLines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> out;
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

int bestShift(const std::string& output, const std::string& against) {
  const auto at = output.find("shifted against " + against);
  if (at == std::string::npos) return 999;
  const auto b = output.find("best shift ", at);
  return std::stoi(output.substr(b + 11, output.find(' ', b + 11) - b - 11));
}

}  // namespace

TEST_F(EvaluateBag, ScoresAgainstGroundTruthAndSensorsAsTheCheckersDo) {
  DT_SHARED_DATA_OR_SKIP(tools, "tools", "eval_traj.py");
  TmpDir out;
  const ToolRun r = evaluate(bag_ + " --out-dir " + out.path + " --plots", out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_EQ(s.frames, 60);
  EXPECT_EQ(s.tracked, 60);
  // The unit came from the bag (L515 raw: 0.25 mm), not from a guess.
  EXPECT_NE(r.output.find("0.00025 m per unit of 16UC1, recorded in the bag"), std::string::npos)
      << r.output;
  // The summary uses ground truth, and both references are in the table.
  EXPECT_NE(r.output.find("* ground truth /rig_sim/camera_pose"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("  rig sensors (track_state + carriage_sensors)"), std::string::npos);

  // The independent checkers on the written files print the same numbers (both round the same
  // way: 4 decimals of metres, 3 of degrees, 2 of millimetres; a figure on a rounding boundary
  // may differ by one unit).
  const std::string est = out.path + "/trajectory.txt",
                    gt = out.path + "/reference_ground_truth.txt";
  ASSERT_TRUE(fs::exists(est) && fs::exists(gt));
  EXPECT_EQ(field(checker(tools, "eval_traj.py", est, gt, out.path), "ate_rmse_m"), s.ate);
  const std::string pe = checker(tools, "pose_errors.py", est, gt, out.path);
  expectSameRounded(field(pe, "max_err_deg"), s.deg, 0.001, pe);
  expectSameRounded(field(pe, "max_err_mm"), s.mm, 0.01, pe);
  // The L515 defaults on 2 s of RT2: well inside the 0.25 deg / 3 mm chair-run targets.
  EXPECT_LT(std::stod(s.ate), 0.003);

  // The sensors against ground truth: the yaw pots read 3 % low (table B2) and the ZigBee link
  // delays them 15-25 ms, so their yaw error is at least the gain error on the yaw travelled
  // (2 s of a 10 deg sine at 1/12 Hz: 8.7 deg -> 0.26 deg) and at most that plus the lag
  // (5.2 deg/s * one frame + the link's 25 ms: 0.3 deg) and half an ADC step (10 bits over the
  // pot's range: ~0.1 deg).
  const auto at = r.output.find("sensors vs ground truth /rig_sim/camera_pose");
  ASSERT_NE(at, std::string::npos) << r.output;
  std::istringstream row(r.output.substr(at + 45));
  int frames = 0;
  double tx = 0, ty = 0, tz = 0;
  row >> frames >> tx >> ty >> tz;
  EXPECT_GT(ty, 0.2) << r.output.substr(at, 200);
  EXPECT_LT(ty, 0.7) << r.output.substr(at, 200);
  // The link's delay is under one frame: the scan against ground truth puts the sensors 0 or 1
  // frame late, never early.
  const int lag = bestShift(r.output, "ground truth");
  EXPECT_TRUE(lag == 0 || lag == 1) << r.output;

  // Per-frame CSV: one row per frame, the thesis's columns for both references.
  const auto csv = readLines(out.path + "/frames.csv");
  ASSERT_EQ(csv.size(), 61u);
  for (const char* col : {"pTx", "pDz", "gt_Ty", "gt_errTy", "sens_Ty", "sens_errDz",
                          "icp_error_mm", "matches", "fm_matches", "held_directions", "prior", "unconfirmed",
                          "ms_register", "ms_frame"})
    EXPECT_NE(csv[0].find(col), std::string::npos) << col << " missing in " << csv[0];
  EXPECT_EQ(readTumTrajectory(est).size(), 60u);
  for (const char* png :
       {"tracking.png", "frame_time.png", "matches.png", "latency.png", "map_views.png"})
    EXPECT_GT(fs::exists(out.path + "/" + png) ? fs::file_size(out.path + "/" + png) : 0u, 20000u)
        << png;
  // Link timing: both boards' links summarised; the ZigBee link (15-25 ms) jitters more than the
  // USB one (2-4 ms).
  const auto link = [&](const std::string& name) {
    const auto row = readLines(out.path + "/link_timing.csv");
    for (const std::string& l : row)
      if (l.rfind("\"" + name + "\"", 0) == 0) {
        std::vector<double> v;
        std::stringstream ss(l.substr(name.size() + 3));
        for (std::string x; std::getline(ss, x, ',');) v.push_back(std::stod(x));
        return v;  // frames, periods, sd, drift, latency mean/p95/max, jitter, gaps
      }
    ADD_FAILURE() << name << " not in link_timing.csv";
    return std::vector<double>(10, 0.0);
  };
  const auto usb = link("TrackDRV -> TrackHost (Time1 -> Time2)");
  const auto zigbee = link("CarDRV -> host (Time3 -> receive stamp)");
  ASSERT_EQ(usb.size(), 10u);
  ASSERT_EQ(zigbee.size(), 10u);
  EXPECT_LT(usb[8], 1.0);  // uniform over 2 ms: 0.58 ms
  EXPECT_GT(zigbee[8], 2.0 * usb[8]);
  EXPECT_LT(zigbee[6], 12.0);  // p95 above the fastest frame within the 10 ms spread
}

TEST_F(EvaluateBag, LatencyScanFindsSensorsDelayedByFourFrames) {
  // Thesis 5.4.1: the sensor data shifted by 4 frames against the camera. Here the rig's streams
  // are recorded 4 frames (133 ms) late; the scan against the tracked trajectory must find them
  // 4 frames late plus the link's own fraction of a frame.
  TmpDir out;
  const std::string late = out.path + "/late.bag";
  const ros::Duration d(4.0 / 30.0);
  copyBag(bag_, late, [&](const rosbag::MessageInstance& m, rosbag::Bag& dst) {
    if (m.getTopic() == "/track_state") {
      auto s = m.instantiate<rig_msgs::TrackState>();
      s->header.stamp += d;
      dst.write(m.getTopic(), m.getTime() + d, *s);
      return false;
    }
    if (m.getTopic() == "/carriage_sensors") {
      auto s = m.instantiate<rig_msgs::CarriageSensors>();
      s->header.stamp += d;
      dst.write(m.getTopic(), m.getTime() + d, *s);
      return false;
    }
    return true;
  });
  const ToolRun r = evaluate(late + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const int k = bestShift(r.output, "the tracked trajectory");
  EXPECT_TRUE(k == 4 || k == 5) << r.output;
  EXPECT_EQ(bestShift(r.output, "ground truth"), k) << r.output;
  // The bag's rig moves enough per frame for the minimum to mean a latency; the summary file
  // says so for both scans.
  const std::vector<std::string> best = readLines(out.path + "/latency_best.csv");
  ASSERT_EQ(best.size(), 3u) << r.output;
  EXPECT_EQ(best[1].rfind("tracked,", 0), 0u) << best[1];
  EXPECT_EQ(best[1].substr(best[1].size() - 2), ",1") << best[1];
  EXPECT_EQ(best[2].substr(best[2].size() - 2), ",1") << best[2];
  EXPECT_NE(r.output.find("  resolved: two steps either side the error rises by"),
            std::string::npos)
      << r.output;
}

TEST_F(EvaluateBag, WithoutDepthTheSensorsAndLinksAreStillEvaluated) {
  TmpDir out;
  const std::string b = out.path + "/nodepth.bag";
  copyBag(bag_, b, dropTopics({"/camera/image_rect"}));
  const ToolRun r = evaluate(b + " --out-dir " + out.path, out.path);
  EXPECT_EQ(r.rc, 2) << r.output;
  EXPECT_NE(r.output.find("depth         MISSING"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("cannot track: the bag has no depth images"), std::string::npos);
  EXPECT_NE(r.output.find("still evaluated: the rig sensors"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("what could still be evaluated: sensors vs ground truth, link timing"),
            std::string::npos);
  EXPECT_EQ(lastLine(r.output).frames, 0);
}

TEST_F(EvaluateBag, WithoutCameraInfoTheIntrinsicsAreAskedFor) {
  TmpDir out;
  const std::string b = out.path + "/noinfo.bag";
  copyBag(bag_, b, dropTopics({"/camera/camera_info"}));
  ToolRun r = evaluate(b + " --out-dir " + out.path, out.path);
  EXPECT_EQ(r.rc, 2) << r.output;
  EXPECT_NE(r.output.find("camera_info   MISSING"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("give the intrinsics with --fx --fy --cx --cy"), std::string::npos);
  EXPECT_NE(r.output.find("still evaluated"), std::string::npos);
  // The scenario camera (l515Intrinsics: 458 px, centred): the run then goes through.
  r = evaluate(b + " --out-dir " + out.path + " --fx 458 --fy 458 --cx 320 --cy 240", out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_EQ(lastLine(r.output).tracked, 60);
}

TEST_F(EvaluateBag, StampsGoingBackAreSkippedAndSaid) {
  TmpDir out;
  const std::string b = out.path + "/order.bag";
  // Frames 10 and 11 carry each other's stamps: frame 11's goes back in time.
  ros::Time t10, t11;
  {
    rosbag::Bag src(bag_, rosbag::bagmode::Read);
    int i = 0;
    for (const rosbag::MessageInstance& m :
         rosbag::View(src, rosbag::TopicQuery("/camera/image_rect"))) {
      if (i == 10) t10 = m.instantiate<sensor_msgs::Image>()->header.stamp;
      if (i == 11) t11 = m.instantiate<sensor_msgs::Image>()->header.stamp;
      ++i;
    }
  }
  copyBag(bag_, b, [&](const rosbag::MessageInstance& m, rosbag::Bag& dst) {
    if (m.getTopic() != "/camera/image_rect") return true;
    auto img = m.instantiate<sensor_msgs::Image>();
    if (img->header.stamp == t10)
      img->header.stamp = t11;
    else if (img->header.stamp == t11)
      img->header.stamp = t10;
    else
      return true;
    dst.write(m.getTopic(), m.getTime(), *img, m.getConnectionHeader());
    return false;
  });
  const ToolRun r = evaluate(b + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("1 frames skipped because their stamps go back in time (first: "
                          "message 11 of /camera/image_rect"),
            std::string::npos)
      << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_EQ(s.frames, 59);
  EXPECT_NE(s.ate, "nan");
}

TEST_F(EvaluateBag, UnindexedBagIsNamedAndReindexMendsIt) {
  // What a killed `rosbag record` leaves: chunks without the index (the file header's index
  // position still 0) and a last chunk cut short.
  TmpDir out;
  const std::string b = out.path + "/crashed.bag";
  {
    std::ifstream in(bag_, std::ios::binary);
    std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const auto at = data.find("index_pos=");
    ASSERT_NE(at, std::string::npos);
    std::uint64_t index_pos = 0;
    std::memcpy(&index_pos, data.data() + at + 10, 8);
    ASSERT_GT(index_pos, 0u);
    std::memset(&data[at + 10], 0, 8);
    data.resize(index_pos * 6 / 10);  // inside the chunks: the last one is cut
    std::ofstream(b, std::ios::binary).write(data.data(), data.size());
  }
  ToolRun r = evaluate(b + " --out-dir " + out.path, out.path);
  EXPECT_EQ(r.rc, 2) << r.output;
  EXPECT_NE(r.output.find("the bag is not indexed"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("`rosbag reindex " + b + "` mends it"), std::string::npos) << r.output;
  EXPECT_EQ(lastLine(r.output).frames, 0);
  // The advice works: the complete chunks come back and are evaluated.
  const ToolRun fix = tool_test::runTool("/usr/bin/rosbag", "reindex " + b, out.path);
  ASSERT_EQ(fix.rc, 0) << fix.output;
  r = evaluate(b + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_GT(s.frames, 10);
  EXPECT_LT(s.frames, 60);
  EXPECT_EQ(s.tracked, s.frames);
}

TEST_F(EvaluateBag, WithoutSensorsGroundTruthAloneIsUsedAndSaid) {
  TmpDir out;
  const std::string b = out.path + "/nosensors.bag";
  copyBag(bag_, b, dropTopics({"/track_state", "/carriage_sensors", "/link_timing"}));
  ToolRun r = evaluate(b + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("sensors       MISSING"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no sensor reference"), std::string::npos);
  EXPECT_NE(r.output.find("* ground truth /rig_sim/camera_pose"), std::string::npos);
  EXPECT_EQ(r.output.find("rig sensors ("), std::string::npos);
  EXPECT_NE(r.output.find("no latency scan: it needs the rig's sensor topics"), std::string::npos);
  EXPECT_NE(lastLine(r.output).ate, "nan");
  // No reference at all: the trajectory is still written, the table says why it is empty.
  const std::string bare = out.path + "/bare.bag";
  copyBag(b, bare, dropTopics({"/rig_sim/camera_pose"}));
  r = evaluate(bare + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("note: no ground truth"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("note: no rig sensor topics"), std::string::npos) << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_EQ(s.tracked, 60);
  EXPECT_EQ(s.ate, "nan");
  EXPECT_EQ(readTumTrajectory(out.path + "/trajectory.txt").size(), 60u);
}

TEST(EvaluateBagTum, TeddyAteMatchesEvalTrajAndTrackSequence) {
  TmpDir out;
  DT_TEDDY_OR_SKIP(teddy);
  DT_SHARED_DATA_OR_SKIP(tools, "tools", "eval_traj.py");
  const std::string bag = out.path + "/teddy.bag";
  ToolRun r = tool_test::runTool(TUM_TO_BAG, teddy + " " + bag + " --camera fr3", out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const std::string preset = std::string(DT_SOURCE_DIR) + "/../config/tum_kinect.yaml";
  r = evaluate(bag + " --out-dir " + out.path + " --config " + preset, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("* ground truth /ground_truth/camera_pose"), std::string::npos)
      << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_EQ(s.frames, 200);
  // eval_traj.py against the sequence's own groundtruth.txt (not the bag's copy).
  const std::string check =
      checker(tools, "eval_traj.py", out.path + "/trajectory.txt", teddy + "/groundtruth.txt", out.path);
  EXPECT_EQ(field(check, "ate_rmse_m"), s.ate) << check;
  EXPECT_EQ(field(check, "frames"), "196") << check;  // frames with motion capture
  // The README's figure for this preset: 0.056 m (P2L); a tracker gone wrong scores >= 0.2 m.
  EXPECT_LT(std::stod(s.ate), 0.08);
  // Same core objects as track_sequence: the same trajectory from the same frames.
  // evaluate_bag starts at the camera mount the bag records (tum_to_bag: base_link ->
  // camera_link at the origin, then the optical axes), as the graph does; track_sequence is
  // started at the same pose.
  EXPECT_NE(r.output.find("start pose    the camera mount"), std::string::npos) << r.output;
  const Eigen::Quaterniond mount(rotationBodyFromOptical());
  char initial_pose[160];
  std::snprintf(initial_pose, sizeof initial_pose, "'0 0 0 %.17g %.17g %.17g %.17g'", mount.x(),
                mount.y(), mount.z(), mount.w());
  const std::string ts = out.path + "/ts.txt";
  r = tool_test::runTool(TRACK_SEQUENCE,
                         "--tum " + teddy +
                             " --fx 535.4 --fy 539.2 --cx 320.1 --cy 247.6 --config " + preset +
                             " --initial-pose " + initial_pose + " --out " + ts,
                         out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const Trajectory a = readTumTrajectory(out.path + "/trajectory.txt"), b = readTumTrajectory(ts);
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_NEAR(a[i].stamp_s, b[i].stamp_s, 1e-6);
    // Files carry 6 decimals of metres and 9 of the quaternion.
    EXPECT_LT((a[i].T_W_C.translation() - b[i].T_W_C.translation()).norm(), 2e-6) << i;
    EXPECT_LT((a[i].T_W_C.linear() - b[i].T_W_C.linear()).norm(), 1e-7) << i;
  }
}

// The bag the repository ships (the first 14 frames of XTest1_05_Chair, L515 noise, 0.25 mm per
// unit) is evaluated with no flags: its camera connections carry the unit (depth_scale_m), as
// every generated scenario bag's do. Before they did (until 2026-12-05) evaluate_bag read it as
// millimetres, four times too near, and tracked 0 of 14 frames.
TEST(EvaluateBagSample, TheShippedSampleTracksWithoutFlags) {
  TmpDir out;
  const std::string bag = std::string(DT_SOURCE_DIR) + "/../bags/sample_xtest1_05_chair.bag";
  const ToolRun r = evaluate(bag + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_EQ(s.frames, 14);
  EXPECT_EQ(s.tracked, 14);
  EXPECT_LT(std::stod(s.ate), 0.001) << r.output;
}

// track_sequence chooses a recorded folder's intrinsics as tum_to_bag does (one function,
// sequence_intrinsics.hpp): some but not all of --fx --fy --cx --cy are refused (before
// 2026-12-05 --fx and --fy alone were taken, with cx = cy = 0), a TUM folder without a file needs
// a camera and the error names the one its name points at, an unknown camera is named.
TEST(TrackSequenceIntrinsics, RefusedAsTumToBagRefusesThem) {
  TmpDir out;
  DT_TEDDY_OR_SKIP(teddy);
  const std::vector<std::pair<std::string, std::string>> cases = {
      {" --fx 535.4 --fy 539.2", "--fx --fy --cx --cy go together"},
      {"", "has no intrinsics file): give --camera fr1|fr2|fr3 or all of --fx --fy --cx --cy"},
      {"", "looks like a fr3 sequence: --camera fr3"},
      {" --camera fr4", "--camera 'fr4': expected fr1, fr2 or fr3"}};
  for (const auto& [args, message] : cases) {
    const ToolRun r = tool_test::runTool(TRACK_SEQUENCE, "--tum " + teddy + args, out.path);
    EXPECT_EQ(r.rc, 2) << args << "\n" << r.output;
    EXPECT_NE(r.output.find(message), std::string::npos) << args << "\n" << r.output;
    EXPECT_EQ(r.output.find("frames="), std::string::npos) << "tracked anyway: " << r.output;
  }
}

// The teddy frames written in the 7-Scenes layout (millimetre PNGs with 65535 where there is no
// return, one 4x4 camera-to-world pose file per frame, camera-intrinsics.txt, in data/), as a
// user with a 7-Scenes sequence has them: track_sequence and tum_to_bag read the folder with no
// flags, its ground truth is every frame's pose file (written out by --gt-out, stamped i / 30 s
// and scored by eval_traj.py), and it tracks as the TUM folder does. The frames with no motion
// capture within 20 ms are left out, as a 7-Scenes sequence has a pose for every frame.
TEST(TrackSequenceSevenScenes, TeddyWrittenAsSevenScenesTracksLikeTheTumFolder) {
  TmpDir out;
  DT_TEDDY_OR_SKIP(teddy);
  DT_SHARED_DATA_OR_SKIP(tools, "tools", "eval_traj.py");
  const DepthSequence tum = readDepthSequence(teddy);
  std::vector<double> frame_s, gt_s;
  for (const TumFrame& f : tum.frames) frame_s.push_back(f.stamp_s);
  for (const StampedPose& p : tum.ground_truth) gt_s.push_back(p.stamp_s);
  const std::string dir = out.path + "/teddy7", data = dir + "/data";
  fs::create_directories(data);
  std::ofstream(data + "/camera-intrinsics.txt") << "535.4 0 320.1\n0 539.2 247.6\n0 0 1\n";
  std::vector<Eigen::Isometry3d> written;  // the poses in file order
  for (const auto& [fi, gi] : associateStamps(frame_s, gt_s, 0.02)) {
    int w = 0, h = 0;
    std::vector<std::uint16_t> raw = readPng16(tum.frames[fi].path, &w, &h);
    for (std::uint16_t& v : raw) v = v == 0 ? 65535 : static_cast<std::uint16_t>((v + 2) / 5);
    char name[64];
    std::snprintf(name, sizeof name, "/frame-%06zu", written.size());
    writePng16(data + name + ".depth.png", raw, w, h);
    const Eigen::Matrix4d M = tum.ground_truth[gi].T_W_C.matrix();
    std::ofstream pose(data + name + ".pose.txt");
    pose.precision(9);
    for (int r = 0; r < 4; ++r)
      pose << M(r, 0) << ' ' << M(r, 1) << ' ' << M(r, 2) << ' ' << M(r, 3) << '\n';
    written.push_back(tum.ground_truth[gi].T_W_C);
  }
  ASSERT_EQ(written.size(), 196u);

  const std::string est = out.path + "/est.txt", gt = out.path + "/gt.txt";
  ToolRun r = tool_test::runTool(TRACK_SEQUENCE,
                                 "--sequence " + dir + " --out " + est + " --gt-out " + gt, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("sequence: 7-Scenes, 196 frames, with ground truth; intrinsics "
                          "fx=535.40 fy=539.20 cx=320.10 cy=247.60 from " +
                          data + "/camera-intrinsics.txt; depth unit 0.001 m"),
            std::string::npos)
      << r.output;
  const Trajectory truth = readTumTrajectory(gt);
  ASSERT_EQ(truth.size(), written.size());
  for (std::size_t i = 0; i < truth.size(); ++i) {
    EXPECT_NEAR(truth[i].stamp_s, i / 30.0, 1e-6);
    EXPECT_LT((truth[i].T_W_C.translation() - written[i].translation()).norm(), 2e-6) << i;
  }
  const std::string ate7 = field(r.output, "ate_rmse_m");
  const std::string check = checker(tools, "eval_traj.py", est, gt, out.path);
  expectSameRounded(field(check, "ate_rmse_m"), ate7, 1e-4, check);
  EXPECT_EQ(field(check, "frames"), "196") << check;
  // The issue's bound on real Kinect data, and the TUM folder's own run of the same frames
  // (0.0094 m; 0.0088 m from the millimetre frames, 2026-12-05): millimetres instead of fifths
  // and stamps at i / 30 s move it by well under a third.
  r = tool_test::runTool(TRACK_SEQUENCE, "--tum " + teddy + " --camera fr3", out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const double ate_tum = std::stod(field(r.output, "ate_rmse_m"));
  EXPECT_LT(std::stod(ate7), 0.03);
  EXPECT_NEAR(std::stod(ate7), ate_tum, ate_tum / 3) << r.output;

  // tum_to_bag takes the folder as it is; a bag cannot hold time 0, so it is written 1 s later.
  const std::string bag = out.path + "/teddy7.bag";
  r = tool_test::runTool(TUM_TO_BAG, dir + " " + bag, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("196 depth frames 640x480 (fx=535.4 fy=539.2 cx=320.1 cy=247.6, "
                          "0.001 m per unit), 196 ground-truth poses (196 of 196"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("written 1 s later"), std::string::npos) << r.output;
  {  // 65535 (7-Scenes' no return) goes into the bag as 0 (REP 118), every other value as it was
    int w = 0, h = 0;
    const std::vector<std::uint16_t> png = readPng16(data + "/frame-000000.depth.png", &w, &h);
    rosbag::Bag b(bag);
    rosbag::View view(b, rosbag::TopicQuery("/camera/image_rect"));
    ASSERT_NE(view.begin(), view.end());
    const auto img = view.begin()->instantiate<sensor_msgs::Image>();
    ASSERT_TRUE(img && img->data.size() == png.size() * 2);
    std::size_t no_return = 0, differ = 0;
    for (std::size_t i = 0; i < png.size(); ++i) {
      std::uint16_t v;
      std::memcpy(&v, &img->data[2 * i], 2);
      if (png[i] == 65535) no_return += v == 0;
      else differ += v != png[i];
    }
    EXPECT_GT(no_return, 1000u);
    EXPECT_EQ(no_return, static_cast<std::size_t>(std::count(png.begin(), png.end(), 65535)));
    EXPECT_EQ(differ, 0u);
  }
  r = evaluate(bag + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_EQ(s.tracked, 196);
  EXPECT_LT(std::stod(s.ate), 0.03);
  const Trajectory bag_traj = readTumTrajectory(out.path + "/trajectory.txt");
  ASSERT_EQ(bag_traj.size(), 196u);
  EXPECT_NEAR(bag_traj.back().stamp_s, 1.0 + 195 / 30.0, 1e-6);
}

// A camera at 5 Hz (fr1/xyz, every 6th frame, as a bag): the frames the tracker registered once
// more from the previous pose (retry_pairs_below) are counted in the report and marked in
// frames.csv (retried, retry_kept), as track_sequence counts them. Measured 2026-12-05 through
// track_sequence: 1 frame retried and kept, 0.0176 m (0.2257 m without the retry).
TEST(EvaluateBagTum, Fr1XyzAtFiveHertzCountsTheRetries) {
  TmpDir out;
  DT_FR1_XYZ_OR_SKIP(fr1);
  const std::string dir = out.path + "/fr1_5hz";
  fs::create_directories(dir);
  {
    const std::vector<TumFrame> all = readTumFrameList(fr1 + "/depth.txt");
    std::ofstream list(dir + "/depth.txt");
    list.precision(17);
    for (std::size_t i = 0; i < all.size(); i += 6) list << all[i].stamp_s << ' ' << all[i].path << '\n';
    fs::create_symlink(fs::absolute(fr1 + "/groundtruth.txt"), dir + "/groundtruth.txt");
  }
  const std::string bag = out.path + "/fr1_5hz.bag";
  ToolRun r = tool_test::runTool(TUM_TO_BAG, dir + " " + bag + " --camera fr1", out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  r = evaluate(bag + " --out-dir " + out.path, out.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const Summary s = lastLine(r.output);
  EXPECT_GE(s.tracked, 130);
  EXPECT_LT(std::stod(s.ate), 0.025) << r.output;
  static const std::regex re(R"(registered again from the previous pose: (\d+) frames, (\d+) kept)");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(r.output, m, re)) << r.output;
  const int retried = std::stoi(m[1]), kept = std::stoi(m[2]);
  EXPECT_GE(retried, 1);
  EXPECT_GE(kept, 1);
  EXPECT_LE(kept, retried);
  // frames.csv marks the same frames.
  const auto csv = readLines(out.path + "/frames.csv");
  ASSERT_GT(csv.size(), 1u);
  const auto column = [&](const std::string& name) {
    std::stringstream ss(csv[0]);
    int k = 0;
    for (std::string c; std::getline(ss, c, ','); ++k)
      if (c == name) return k;
    ADD_FAILURE() << name << " missing in " << csv[0];
    return -1;
  };
  const int c_retried = column("retried"), c_kept = column("retry_kept");
  int sum_retried = 0, sum_kept = 0;
  for (std::size_t i = 1; i < csv.size(); ++i) {
    std::stringstream ss(csv[i]);
    int k = 0;
    for (std::string c; std::getline(ss, c, ','); ++k) {
      if (k == c_retried) sum_retried += std::stoi(c);
      if (k == c_kept) sum_kept += std::stoi(c);
    }
  }
  EXPECT_EQ(sum_retried, retried);
  EXPECT_EQ(sum_kept, kept);
}

// track_sequence --render renders over --d-min/--d-max, as a camera driver set to that range
// would deliver: the map of the chair run's still frames (camera at rest) with --d-max 2.5 holds
// no voxel deeper than 2.5 m along the optical axis, while the default range (4 m) maps the room
// behind the chair to its far wall, 3.2 m away. (Before 2026-12-04 the range was applied to TUM
// input only.)
TEST(TrackSequenceRender, DepthRangeAppliesToRenderedFrames) {
  TmpDir out;
  // Depth along the start camera's optical axis of every occupied voxel of a map file.
  auto depths = [&](const std::string& extra) {
    const std::string bt = out.path + "/m.bt", gt = out.path + "/gt.txt";
    const ToolRun r = tool_test::runTool(
        TRACK_SEQUENCE,
        "--render xtest1_05_chair --frames 3 --map " + bt + " --gt-out " + gt + " " + extra,
        out.path);
    EXPECT_EQ(r.rc, 0) << r.output;
    std::vector<double> z;
    const Trajectory truth = readTumTrajectory(gt);
    if (truth.empty()) return z;
    const VoxelMap map{MapConfig{}};
    const Eigen::Isometry3d C_W = truth.front().T_W_C.inverse();
    for (const VoxelKey& k : map.loadOccupiedKeys(bt)) z.push_back((C_W * map.centerOf(k)).z());
    return z;
  };
  const std::vector<double> full = depths(""), near = depths("--d-max 2.5");
  ASSERT_FALSE(full.empty());
  ASSERT_FALSE(near.empty());
  const double far_full = *std::max_element(full.begin(), full.end());
  const double far_near = *std::max_element(near.begin(), near.end());
  EXPECT_GT(far_full, 3.0);                // the default range reaches the far wall (3.2 m)
  // A voxel's centre lies at most half a 5 mm voxel's diagonal (4.3 mm) deeper than the return in
  // it; 0.7 mm more for the tracked pose of the still frames (measured 2.5025 m).
  EXPECT_LT(far_near, 2.5 + 0.005);
  EXPECT_LT(near.size(), full.size() / 2) << near.size() << " of " << full.size();
}

// --map-quality scores the map of a rendered run against the scene it was rendered from, in the
// run's world whatever pose the tracker started at: with the map's frame taken for the run's
// world (the first version of the option) precision read 0.4 % on this run.
TEST(TrackSequenceRender, MapQualityScoresTheMapAgainstTheScene) {
  TmpDir out;
  auto quality = [&](const std::string& extra) {
    const ToolRun r = tool_test::runTool(
        TRACK_SEQUENCE,
        "--render xtest1_05_chair --frames 21 --map " + out.path + "/m.bt --map-quality " + extra,
        out.path);
    EXPECT_EQ(r.rc, 0) << r.output;
    double precision = -1.0, completeness = -1.0;
    const std::size_t at = r.output.find("map quality: precision ");
    if (at != std::string::npos)
      std::sscanf(r.output.c_str() + at,
                  "map quality: precision %lf %% (%*s of %*s occupied voxels within %*s mm of the "
                  "scene), completeness %lf",
                  &precision, &completeness);
    return std::make_pair(precision, completeness);
  };
  const auto [p, c] = quality("");
  // L515 noise, one-hit threshold, 21 frames of the whole run's 103 (which reads 86.6 / 99.9 %).
  EXPECT_GT(p, 80.0);
  EXPECT_LE(p, 100.0);
  EXPECT_GT(c, 95.0);
  EXPECT_LE(c, 100.0);
  const auto [p_moved, c_moved] = quality("--initial-pose '1 2 3 0 0 0.3826834 0.9238795'");
  EXPECT_NEAR(p_moved, p, 1.0);
  EXPECT_NEAR(c_moved, c, 1.0);
  const ToolRun no_map =
      tool_test::runTool(TRACK_SEQUENCE, "--render xtest1_05_chair --frames 2 --map-quality",
                         out.path);
  EXPECT_NE(no_map.rc, 0);
  EXPECT_NE(no_map.output.find("--map-quality needs"), std::string::npos) << no_map.output;
}

namespace {
// Runs registration_basin with `args` and returns its CSV rows (the lines that start with a
// frame index) as numbers, each checked to have the tool's 12 columns.
std::vector<std::vector<double>> basinRows(const std::string& args, const std::string& dir) {
  const ToolRun r = tool_test::runTool(REGISTRATION_BASIN, args, dir);
  EXPECT_EQ(r.rc, 0) << r.output;
  std::vector<std::vector<double>> rows;
  std::istringstream lines(r.output);
  for (std::string line; std::getline(lines, line);) {
    if (line.empty() || !std::isdigit(static_cast<unsigned char>(line[0]))) continue;
    std::vector<double> v;
    std::istringstream fields(line);
    for (std::string f; std::getline(fields, f, ',');) v.push_back(std::stod(f));
    EXPECT_EQ(v.size(), 12u) << line;
    if (v.size() == 12u) rows.push_back(v);
  }
  return rows;
}
}  // namespace

// registration_basin on the noise-free Hall1 start: one basin (the zero guess and the true one
// converge to the same translation, near the truth: measured 28.66 / 28.68 mm of 30 along the
// corridor), one CSV row per frame and guess; the guesses and tracker options are applied; a
// reference outside the run is refused by name.
TEST(RegistrationBasin, OneBasinOnNoiseFreeFramesAndBadIndexNamed) {
  TmpDir out;
  const auto rows =
      basinRows("--render hall1 --noise none --ref 0 --frames 5 --guesses 0,1", out.path);
  ASSERT_EQ(rows.size(), 2u);
  for (const auto& v : rows) {
    EXPECT_EQ(v[0], 5);
    EXPECT_NEAR(v[4], 30.0, 1e-6);  // the truth: at rest to frame 2, then 10 mm a frame along z
    EXPECT_LT(v[8], 3.0) << "guess " << v[1] << ": converged " << v[5] << " " << v[6] << " "
                         << v[7] << " mm";
  }
  EXPECT_EQ(rows[0][1], 0.0);
  EXPECT_EQ(rows[1][1], 1.0);
  EXPECT_NEAR(rows[0][7], rows[1][7], 0.5);  // one basin: the guess does not decide

  // The guesses and the tracker options reach the registration: one iteration from zero motion
  // stops short of the truth (measured 40.4 of 60 mm at frame 8), one from the truth stays there.
  const auto one = basinRows(
      "--render hall1 --noise none --ref 0 --frames 8 --guesses 0,1 --max-iterations 1", out.path);
  ASSERT_EQ(one.size(), 2u);
  for (const auto& v : one) {
    EXPECT_EQ(v[0], 8);
    EXPECT_EQ(v[9], 1);  // iterations
  }
  EXPECT_LT(one[0][7], 55.0);
  EXPECT_GT(one[1][7], 58.0);

  const ToolRun bad =
      tool_test::runTool(REGISTRATION_BASIN, "--render hall1 --ref 5000 --frames 3", out.path);
  EXPECT_NE(bad.rc, 0);
  EXPECT_NE(bad.output.find("--ref 5000"), std::string::npos) << bad.output;
}
