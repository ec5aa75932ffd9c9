// The tracking graph (launch/tracking.launch, replay mode) against a real roscore, fed frame by
// frame from a generated RT3 scenario bag with /clock: every frame gives odom -> base_link; the
// trajectory equals the core's Tracker run offline on the same frames; 16UC1 and 32FC1 give the
// same poses; a jump back in time (a looped bag) resets the graph; reset / save_trajectory /
// save_map work and their files load; bad input gives a status naming it and no crash; a
// covered lens ends RELOCALISING -> TRACKING near the ground truth; a bad parameter stops a
// nodelet with the parameter's name.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dynamic_reconfigure/Config.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <rig_msgs/ResetToPose.h>
#include <rig_msgs/SaveFile.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/master.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <rosgraph_msgs/Clock.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <tf2_msgs/TFMessage.h>

#include <stdlib.h>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>

#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/tracker.hpp"
#include "depth_track/core/tum_io.hpp"
#include "depth_track/ros/conversions.hpp"

using namespace depth_track;

namespace {

const int kFrames = 150;

/// A folder of this process's own: several test runs may share the machine's /tmp.
const std::string& workDir() {
  static const std::string dir = [] {
    std::string tmpl = ::testing::TempDir() + "/dt_graph_test_XXXXXX";
    if (!mkdtemp(tmpl.data())) throw std::runtime_error("cannot create " + tmpl);
    return tmpl;
  }();
  return dir;
}
const double kDepthScale = 0.00025;  // the scenario bags' L515 units

struct BagData {
  std::vector<sensor_msgs::ImageConstPtr> images;
  std::vector<sensor_msgs::CameraInfoConstPtr> infos;
  tf2_msgs::TFMessage tf_static;
  std::vector<geometry_msgs::PoseStamped> gt;
};

BagData& bag() {
  static BagData data = [] {
    BagData d;
    const std::string& dir = workDir();
    const std::string cmd = std::string(MAKE_SCENARIO_BAG) + " --scenario " + DT_SCENARIO_DIR +
                            "/RT3.yaml --out-dir " + dir + " --max-frames " +
                            std::to_string(kFrames) + " --compression none > " + dir +
                            "/gen.log 2>&1";
    if (std::system(cmd.c_str()) != 0) throw std::runtime_error("make_scenario_bag failed: " + cmd);
    rosbag::Bag b(dir + "/RT3.bag");
    for (const rosbag::MessageInstance& m : rosbag::View(b)) {
      if (m.getTopic() == "/camera/image_rect")
        d.images.push_back(m.instantiate<sensor_msgs::Image>());
      if (m.getTopic() == "/camera/camera_info")
        d.infos.push_back(m.instantiate<sensor_msgs::CameraInfo>());
      if (m.getTopic() == "/tf_static") d.tf_static = *m.instantiate<tf2_msgs::TFMessage>();
      if (m.getTopic() == "/rig_sim/camera_pose")
        d.gt.push_back(*m.instantiate<geometry_msgs::PoseStamped>());
    }
    return d;
  }();
  return data;
}

Eigen::Isometry3d mount(const tf2_msgs::TFMessage& st) {  // base_link -> optical frame
  Eigen::Isometry3d T_base_link = Eigen::Isometry3d::Identity(), T_link_opt = T_base_link;
  for (const auto& t : st.transforms) {
    if (t.child_frame_id == "camera_link") T_base_link = conv::fromTransformMsg(t.transform);
    if (t.child_frame_id == "camera_depth_optical_frame")
      T_link_opt = conv::fromTransformMsg(t.transform);
  }
  return T_base_link * T_link_opt;
}

/// Publishes frames like `rosbag play --clock` does, one at a time, and collects the graph's
/// answers.
class Graph {
 public:
  Graph() {
    clock_ = nh_.advertise<rosgraph_msgs::Clock>("/clock", 10);
    image_ = nh_.advertise<sensor_msgs::Image>("/camera/image_rect", 10);
    info_ = nh_.advertise<sensor_msgs::CameraInfo>("/camera/camera_info", 10);
    tf_static_ = nh_.advertise<tf2_msgs::TFMessage>("/tf_static", 1, true);
    status_sub_ = nh_.subscribe("/status", 200, &Graph::onStatus, this);
    tf_sub_ = nh_.subscribe("/tf", 200, &Graph::onTf, this);
    spinner_.start();
  }
  bool connected(double timeout_s) {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
    while (ros::WallTime::now() < end) {
      if (image_.getNumSubscribers() > 0 && info_.getNumSubscribers() > 0 &&
          status_sub_.getNumPublishers() >= 1 && tf_sub_.getNumPublishers() >= 1 &&
          ros::service::exists("/fusion/save_map", false) && advertised("/loop_closure/status")) {
        // Every nodelet is loaded; give their subscriptions to each other a moment to connect
        // (a mapping nodelet that missed the first frames would count frames differently).
        ros::WallDuration(1.0).sleep();
        return true;
      }
      ros::WallDuration(0.1).sleep();
    }
    return false;
  }
  static bool advertised(const std::string& topic) {
    ros::master::V_TopicInfo topics;
    if (!ros::master::getTopics(topics)) return false;
    for (const auto& t : topics)
      if (t.name == topic) return true;
    return false;
  }
  void setClock(const ros::Time& t) {
    rosgraph_msgs::Clock c;
    c.clock = t;
    clock_.publish(c);
    ros::WallDuration(0.005).sleep();
  }
  /// Publishes one frame (info may be null) and waits for a status of its stamp.
  std::optional<rig_msgs::TrackingStatus> feed(const sensor_msgs::Image& img,
                                               const sensor_msgs::CameraInfo* info,
                                               double timeout_s = 20.0) {
    std::size_t before;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      before = all_.size();
    }
    setClock(img.header.stamp);
    if (info) info_.publish(*info);
    image_.publish(img);
    return waitStatus(img.header.stamp, before, timeout_s);
  }
  /// The first status of `stamp` received after the first `after` ones (a looped bag repeats
  /// stamps: an answer from an earlier pass must not count).
  std::optional<rig_msgs::TrackingStatus> waitStatus(const ros::Time& stamp, std::size_t after,
                                                     double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    std::optional<rig_msgs::TrackingStatus> found;
    cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
      for (std::size_t i = after; i < all_.size() && !found; ++i)
        if (all_[i].header.stamp == stamp) found = all_[i];
      return found.has_value();
    });
    return found;
  }
  /// A status whose failure contains `text` (any stamp), waiting up to timeout_s.
  std::optional<rig_msgs::TrackingStatus> waitFailure(const std::string& text, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    std::optional<rig_msgs::TrackingStatus> found;
    cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
      for (const auto& s : all_)
        if (s.failure.find(text) != std::string::npos) found = s;
      return found.has_value();
    });
    return found;
  }
  /// odom -> base_link transforms received with stamps in [from, to], waiting up to timeout_s
  /// for `expected` of them: /tf and /status are separate connections, so a frame's tf (sent
  /// first) may still arrive after its status.
  int baseTfCount(const ros::Time& from, const ros::Time& to, int expected = 0,
                  double timeout_s = 0.0) {
    std::unique_lock<std::mutex> lock(mutex_);
    int n = 0;
    cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
      n = 0;
      for (const auto& t : base_tf_stamps_) n += t >= from && t <= to;
      return n >= expected;
    });
    return n;
  }
  bool hasBaseTf(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    return base_tf_stamps_.count(stamp) > 0;
  }
  void publishStatic(const tf2_msgs::TFMessage& m) { tf_static_.publish(m); }

 private:
  void onStatus(const rig_msgs::TrackingStatusConstPtr& s) {
    std::lock_guard<std::mutex> lock(mutex_);
    all_.push_back(*s);
    cv_.notify_all();
  }
  void onTf(const tf2_msgs::TFMessageConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& t : m->transforms)
      if (t.header.frame_id == "odom" && t.child_frame_id == "base_link")
        base_tf_stamps_.insert(t.header.stamp);
    cv_.notify_all();
  }
  ros::NodeHandle nh_;
  ros::Publisher clock_, image_, info_, tf_static_;
  ros::Subscriber status_sub_, tf_sub_;
  ros::AsyncSpinner spinner_{2};
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<rig_msgs::TrackingStatus> all_;
  std::set<ros::Time> base_tf_stamps_;
};

Graph& graph() {
  static Graph g;
  return g;
}

/// The 16UC1 frame as 32FC1 metres, through the same conversion the graph applies.
sensor_msgs::Image toFloat(const sensor_msgs::Image& raw) {
  const DepthImage d = conv::depthFromMsg(raw, kDepthScale, DepthRange{0.0, 1e9});
  sensor_msgs::Image out = *conv::depthToMsg(d, raw.header);
  return out;
}

/// Runs frames [0, n) through the graph (16UC1 or 32FC1); returns the camera poses (odom).
std::vector<Eigen::Isometry3d> runGraph(int n, bool as_float,
                                        std::vector<rig_msgs::TrackingStatus>* out) {
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < n; ++i) {
    const auto& img = *bag().images[i];
    const auto st = graph().feed(as_float ? toFloat(img) : img, bag().infos[i].get());
    EXPECT_TRUE(st.has_value()) << "no status for frame " << i;
    if (!st) break;
    poses.push_back(conv::fromPoseMsg(st->camera_pose));
    if (out) out->push_back(*st);
  }
  return poses;
}

std::vector<Eigen::Isometry3d> groundTruth(int n) {
  std::vector<Eigen::Isometry3d> gt;
  for (int i = 0; i < n; ++i) gt.push_back(conv::fromPoseMsg(bag().gt[i].pose));
  return gt;
}

std::vector<Eigen::Isometry3d> run16;

}  // namespace

TEST(Graph, TracksEveryFrameLikeTheOfflineTracker) {
  ASSERT_EQ(static_cast<int>(bag().images.size()), kFrames);
  ASSERT_TRUE(graph().connected(60.0)) << "the graph's nodelets did not come up";
  graph().publishStatic(bag().tf_static);
  std::vector<rig_msgs::TrackingStatus> st;
  run16 = runGraph(kFrames, false, &st);
  ASSERT_EQ(static_cast<int>(run16.size()), kFrames);
  for (const auto& s : st)
    EXPECT_EQ(s.state_name, "TRACKING") << s.header.stamp << " " << s.failure;
  // tf odom -> base_link for every frame (it goes out before the status).
  EXPECT_EQ(graph().baseTfCount(bag().images.front()->header.stamp,
                                bag().images.back()->header.stamp, kFrames, 5.0),
            kFrames);
  for (int i = 0; i < kFrames; ++i)
    EXPECT_TRUE(graph().hasBaseTf(bag().images[i]->header.stamp)) << "no tf for frame " << i;

  // The same frames through the core's Tracker, as track_sequence runs it.
  const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(*bag().infos[0]);
  Tracker tracker(K, TrackerConfig{}, mount(bag().tf_static));
  double max_dt = 0, max_dr = 0, max_dinfo = 0;
  int held_offline = 0, held_graph = 0;
  for (int i = 0; i < kFrames; ++i) {
    const auto& img = *bag().images[i];
    const FrameStatus fs =
        tracker.track(conv::depthFromMsg(img, kDepthScale, DepthRange{}), img.header.stamp.toSec());
    max_dt = std::max(max_dt, (fs.T_W_C.translation() - run16[i].translation()).norm());
    max_dr = std::max(max_dr, rotationAngle(fs.T_W_C.inverse() * run16[i]));
    // The status carries the odometry's degeneracy result, not a computation of its own.
    EXPECT_EQ(st[i].degenerate_directions, fs.degenerate_directions) << i;
    held_offline += fs.degenerate_directions > 0;
    held_graph += st[i].degenerate_directions > 0;
    max_dinfo = std::max(max_dinfo, std::abs(st[i].weakest_information - fs.weakest_information) /
                                        std::max(1.0, std::abs(fs.weakest_information)));
  }
  // Both ran the noise calibration of the same first frame.
  ASSERT_TRUE(tracker.noiseCalibration().has_value());
  EXPECT_TRUE(tracker.noiseCalibration()->measured) << tracker.noiseCalibration()->summary;
  std::printf("held frames: graph %d, offline %d; weakest information differs by %.2g (relative)\n",
              held_graph, held_offline, max_dinfo);
  EXPECT_LT(max_dinfo, 1e-6);
  EXPECT_LT(max_dt, 1e-6) << "graph vs offline, m";
  EXPECT_LT(max_dr, 1e-6) << "graph vs offline, rad";

  // Against the bag's ground truth (relative to the first pose). The offline tracker measures
  // ~0.6 mm / 0.01 deg on these frames; 3 mm / 0.1 deg is the L515 run's documented envelope.
  const ThesisErrors e = computeThesisErrors(run16, groundTruth(kFrames));
  EXPECT_LT(e.max_err_mm.maxCoeff(), 3.0);
  EXPECT_LT(e.max_err_deg.maxCoeff(), 0.1);
  std::printf(
      "graph on RT3 (%d frames): max_err_deg=%.3f,%.3f,%.3f max_err_mm=%.2f,%.2f,%.2f vs offline "
      "%.2g m %.2g rad\n",
      kFrames, e.max_err_deg.x(), e.max_err_deg.y(), e.max_err_deg.z(), e.max_err_mm.x(),
      e.max_err_mm.y(), e.max_err_mm.z(), max_dt, max_dr);
}

TEST(Graph, SavedTrajectoryAndMapLoad) {
  ASSERT_EQ(static_cast<int>(run16.size()), kFrames);
  const std::string& dir = workDir();
  rig_msgs::SaveFile traj;
  traj.request.path = dir + "/traj.txt";
  ASSERT_TRUE(ros::service::call("/registration/save_trajectory", traj));
  ASSERT_TRUE(traj.response.success) << traj.response.message;
  const Trajectory t = readTumTrajectory(traj.request.path);
  ASSERT_EQ(static_cast<int>(t.size()), kFrames);
  for (int i = 0; i < kFrames; ++i)  // written with 6 decimals
    EXPECT_LT((t[i].T_W_C.translation() - run16[i].translation()).norm(), 2e-6);
  EXPECT_EQ(readTumTrajectory(dir + "/traj_map.txt").size(), t.size());

  rig_msgs::SaveFile map;
  map.request.path = dir + "/map.bt";
  ASSERT_TRUE(ros::service::call("/fusion/save_map", map));
  ASSERT_TRUE(map.response.success) << map.response.message;
  const std::string cmd =
      "convert_octree " + map.request.path + " " + dir + "/map.ot > /dev/null 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
  const VoxelMap reader{MapConfig{}};
  const auto keys = reader.loadOccupiedKeys(map.request.path);
  EXPECT_GT(keys.size(), 100000u) << "the chair room seen for 5 s fills far more 5 mm voxels";
}

TEST(Graph, LoopedBagResetsAndFloatDepthGivesTheSamePoses) {
  ASSERT_EQ(static_cast<int>(run16.size()), kFrames);
  // The clock jumps back to the bag's start, as `rosbag play -l` does: the graph resets.
  graph().setClock(bag().images.front()->header.stamp - ros::Duration(0.1));
  std::vector<rig_msgs::TrackingStatus> st;
  const auto run32 = runGraph(kFrames, true, &st);
  ASSERT_EQ(static_cast<int>(run32.size()), kFrames);
  EXPECT_EQ(st.front().frame, 1u) << "the frame count restarts";
  double max_dt = 0, max_dr = 0;
  for (int i = 0; i < kFrames; ++i) {
    EXPECT_EQ(st[i].state_name, "TRACKING");
    max_dt = std::max(max_dt, (run32[i].translation() - run16[i].translation()).norm());
    max_dr = std::max(max_dr, rotationAngle(run32[i].inverse() * run16[i]));
  }
  EXPECT_LT(max_dt, 1e-9);
  EXPECT_LT(max_dr, 1e-9);
}

TEST(Graph, BadInputGetsAStatusAndNoCrash) {
  const auto& good = *bag().images[0];
  const auto& info = *bag().infos[0];
  ros::Time t = bag().images.back()->header.stamp + ros::Duration(1.0);
  auto next = [&t](sensor_msgs::Image img) {
    t += ros::Duration(1.0 / 30);
    img.header.stamp = t;
    return img;
  };
  auto info_at = [&info](const ros::Time& s) {
    sensor_msgs::CameraInfo c = info;
    c.header.stamp = s;
    return c;
  };
  // Wrong encoding.
  sensor_msgs::Image rgb = next(good);
  rgb.encoding = "rgb8";
  auto c = info_at(t);
  auto s = graph().feed(rgb, &c);
  ASSERT_TRUE(s);
  EXPECT_TRUE(s->input_rejected);
  EXPECT_NE(s->failure.find("rgb8"), std::string::npos) << s->failure;
  // Image size that does not match camera_info.
  sensor_msgs::Image small = next(good);
  small.width = 320, small.height = 240, small.step = 640;
  small.data.resize(640 * 240);
  c = info_at(t);
  s = graph().feed(small, &c);
  ASSERT_TRUE(s);
  EXPECT_NE(s->failure.find("camera_info says 640x480"), std::string::npos) << s->failure;
  // NaN / Inf / zero depth everywhere: a frame without cells, flagged LOST with the reason.
  sensor_msgs::Image nan = toFloat(next(good));
  float* px = reinterpret_cast<float*>(nan.data.data());
  for (std::size_t i = 0; i < nan.data.size() / 4; ++i)
    px[i] = i % 3 == 0 ? std::nanf("") : i % 3 == 1 ? INFINITY : 0.0f;
  c = info_at(t);
  s = graph().feed(nan, &c);
  ASSERT_TRUE(s);
  EXPECT_FALSE(s->tracked);
  EXPECT_EQ(s->state_name, "LOST");
  EXPECT_NE(s->failure.find("usable cells"), std::string::npos) << s->failure;
  // A stamp that does not increase.
  sensor_msgs::Image same = good;
  same.header.stamp = t - ros::Duration(0.5);
  c = info_at(same.header.stamp);
  s = graph().feed(same, &c);
  ASSERT_TRUE(s);
  EXPECT_NE(s->failure.find("does not increase"), std::string::npos) << s->failure;
  // A corrupt pose for reset_to_pose.
  rig_msgs::ResetToPose r;
  r.request.pose.orientation.w = 0.0;
  ASSERT_TRUE(ros::service::call("/registration/reset_to_pose", r));
  EXPECT_FALSE(r.response.success);
  EXPECT_NE(r.response.message.find("quaternion"), std::string::npos) << r.response.message;
  // Missing camera_info: an image alone, then the graph goes on with good frames.
  graph().feed(next(good), nullptr, 0.2);
  for (int i = 0; i < 12; ++i) {
    const auto img = next(good);
    c = info_at(t);
    s = graph().feed(img, &c);
    ASSERT_TRUE(s) << "the graph stopped answering after bad input";
  }
  EXPECT_TRUE(graph().waitFailure("missing camera_info", 5.0).has_value());
  EXPECT_TRUE(s->tracked) << "good frames after bad input: " << s->failure;
}

TEST(Graph, ResetServiceRestartsAtTheOrigin) {
  std_srvs::Trigger tr;
  ASSERT_TRUE(ros::service::call("/registration/reset", tr));
  EXPECT_TRUE(tr.response.success);
  sensor_msgs::Image img = *bag().images[10];
  sensor_msgs::CameraInfo info = *bag().infos[10];
  img.header.stamp = info.header.stamp =
      ros::Time(bag().images.back()->header.stamp.toSec() + 30.0);
  const auto s = graph().feed(img, &info);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->frame, 1u);
  const Eigen::Isometry3d T = conv::fromPoseMsg(s->camera_pose);
  EXPECT_LT((T.translation() - mount(bag().tf_static).translation()).norm(), 1e-9);
}

TEST(Graph, CoveredLensEndsRelocalisingThenTracking) {
  // Loop back to the start; frames 45..104 (2 s) come with the lens covered (no return).
  graph().setClock(bag().images.front()->header.stamp - ros::Duration(0.1));
  const int gap0 = 45, gap1 = 105;
  std::vector<Eigen::Isometry3d> est;
  std::vector<std::string> states, failures;
  for (int i = 0; i < kFrames; ++i) {
    sensor_msgs::Image img = *bag().images[i];
    if (i >= gap0 && i < gap1) std::fill(img.data.begin(), img.data.end(), 0);
    const auto s = graph().feed(img, bag().infos[i].get());
    ASSERT_TRUE(s) << i;
    est.push_back(conv::fromPoseMsg(s->camera_pose));
    states.push_back(s->state_name);
    failures.push_back(s->failure);
  }
  EXPECT_EQ(states[gap0 - 1], "TRACKING");
  EXPECT_EQ(states[gap0 + 1], "LOST");
  EXPECT_NE(std::find(states.begin() + gap0, states.begin() + gap1, "RELOCALISING"),
            states.begin() + gap1);
  int back = -1;
  for (int i = gap1; i < kFrames && back < 0; ++i)
    if (states[i] == "TRACKING") back = i;
  ASSERT_GE(back, 0) << "never tracked again after the gap";
  std::printf("covered lens: frames %d..%d, TRACKING again at frame %d (%s)\n", gap0, gap1 - 1,
              back, failures[back].c_str());
  EXPECT_LE(back, gap1 + 6) << "relocalised only " << back - gap1 << " frames after the gap";
  for (int i = back; i < kFrames; ++i) EXPECT_EQ(states[i], "TRACKING") << i;
  const auto gt = groundTruth(kFrames);
  const auto errs = frameErrors(est, gt);
  for (int i : {back, kFrames - 1}) {
    EXPECT_LT(errs[i].pos_err_mm.norm(), 20.0) << "frame " << i;
    EXPECT_LT(errs[i].rot_err_deg.norm(), 1.0) << "frame " << i;
    std::printf("after the gap, frame %d: %.2f mm, %.3f deg from ground truth\n", i,
                errs[i].pos_err_mm.norm(), errs[i].rot_err_deg.norm());
  }
}

/// Collects /diagnostics, /rosout and the registration's parameter updates while a test runs.
class Watch {
 public:
  Watch() {
    diag_sub_ = nh_.subscribe("/diagnostics", 200, &Watch::onDiag, this);
    log_sub_ = nh_.subscribe("/rosout", 200, &Watch::onLog, this);
    updates_sub_ = nh_.subscribe("/registration/parameter_updates", 5, &Watch::onUpdate, this);
  }
  struct Entry {
    ros::WallTime at;
    diagnostic_msgs::DiagnosticStatus status;
  };
  /// Waits until a status named `name` received after `after` satisfies `pred`.
  std::optional<diagnostic_msgs::DiagnosticStatus> waitDiag(
      const std::string& name, const ros::WallTime& after, double timeout_s,
      const std::function<bool(const diagnostic_msgs::DiagnosticStatus&)>& pred) {
    std::unique_lock<std::mutex> lock(mutex_);
    std::optional<diagnostic_msgs::DiagnosticStatus> found;
    cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
      for (const auto& e : diags_)
        if (e.at >= after && e.status.name == name && pred(e.status)) found = e.status;
      return found.has_value();
    });
    return found;
  }
  std::vector<diagnostic_msgs::DiagnosticStatus> since(const std::string& name,
                                                       const ros::WallTime& after) {
    std::lock_guard<std::mutex> lock(mutex_);
    std::vector<diagnostic_msgs::DiagnosticStatus> out;
    for (const auto& e : diags_)
      if (e.at >= after && e.status.name == name) out.push_back(e.status);
    return out;
  }
  bool waitLog(const std::string& text, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    return cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
      for (const auto& l : logs_)
        if (l.find(text) != std::string::npos) return true;
      return false;
    });
  }
  std::optional<dynamic_reconfigure::Config> lastUpdate() {
    std::lock_guard<std::mutex> lock(mutex_);
    return update_;
  }

 private:
  void onDiag(const diagnostic_msgs::DiagnosticArrayConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& s : m->status) diags_.push_back({ros::WallTime::now(), s});
    cv_.notify_all();
  }
  void onLog(const rosgraph_msgs::LogConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    logs_.push_back(m->msg);
    cv_.notify_all();
  }
  void onUpdate(const dynamic_reconfigure::ConfigConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    update_ = *m;
  }
  ros::NodeHandle nh_;
  ros::Subscriber diag_sub_, log_sub_, updates_sub_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<Entry> diags_;
  std::vector<std::string> logs_;
  std::optional<dynamic_reconfigure::Config> update_;
};

std::string value(const diagnostic_msgs::DiagnosticStatus& s, const std::string& key) {
  for (const auto& kv : s.values)
    if (kv.key == key) return kv.value;
  return "";
}

int runTool(const std::string& cmd, std::string* out = nullptr) {
  // dynparam runs on `env python3`: the ROS one, not a python3 earlier on PATH.
  FILE* p = popen(("PATH=/usr/bin:$PATH " + cmd + " 2>&1").c_str(), "r");
  if (!p) return -1;
  char buf[512];
  while (std::fgets(buf, sizeof(buf), p))
    if (out) *out += buf;
  return pclose(p);
}

TEST(Graph, DiagnosticsFollowTrackingInputAndLoss) {
  Watch watch;
  // graph.test measures the rate over 2 updates (2 s): the test feeds faster than real time.
  graph().setClock(bag().images.front()->header.stamp - ros::Duration(0.1));
  const ros::WallTime t0 = ros::WallTime::now();
  runGraph(kFrames, false, nullptr);
  const ros::WallTime t1 = ros::WallTime::now();
  std::printf("diagnostics: %d frames fed in %.1f s of wall time\n", kFrames, (t1 - t0).toSec());
  // While frames come at the bag's 30 Hz (on its clock), the input rate is met and the state
  // is TRACKING; the registration reports its latency and time per frame.
  const auto rate = watch.waitDiag("registration: input rate", t0, 5.0, [&](const auto& s) {
    return s.level == diagnostic_msgs::DiagnosticStatus::OK;
  });
  ASSERT_TRUE(rate) << "no OK input rate while frames came at 30 Hz";
  const double hz = std::stod(value(*rate, "Actual frequency (Hz)"));
  EXPECT_NEAR(hz, 30.0, 30.0 * 0.2) << "30 Hz frames within the 20 % tolerance";
  const auto state = watch.waitDiag("registration: tracking state", t0, 5.0, [](const auto& s) {
    return s.level == diagnostic_msgs::DiagnosticStatus::OK;
  });
  ASSERT_TRUE(state);
  EXPECT_EQ(state->message.rfind("TRACKING", 0), 0u) << state->message;
  EXPECT_EQ(value(*state, "method"), "p2l");
  EXPECT_GT(std::stoi(value(*state, "matches")), 100);
  const auto lat = watch.waitDiag("registration: latency", t0, 5.0,
                                  [](const auto& s) { return s.values.size() >= 3; });
  ASSERT_TRUE(lat);
  EXPECT_GE(std::stod(value(*lat, "median (ms)")), 0.0);
  for (const char* name : {"ingest: input rate", "pca_reduce: processing time", "fusion: map",
                           "loop_closure: loop closure", "ingest: frames dropped"})
    EXPECT_TRUE(watch.waitDiag(name, t0, 5.0, [](const auto&) { return true; })) << name;
  // The chair room seen for 5 s at 5 mm voxels: far more than 100k occupied voxels.
  const auto map = watch.waitDiag("fusion: map", t0, 5.0, [](const auto& s) {
    return std::stoul(value(s, "occupied voxels")) > 100000;
  });
  EXPECT_TRUE(map) << "the map status never showed the fused room";

  // A covered lens: LOST is an ERROR of the tracking state, RELOCALISING (lost, and a
  // relocalisation against the map was tried and refused) a WARN.
  ros::Time t = bag().images.back()->header.stamp;
  for (int i = 0; i < 10; ++i) {
    sensor_msgs::Image img = *bag().images.back();
    sensor_msgs::CameraInfo info = *bag().infos.back();
    t += ros::Duration(1.0 / 30);
    img.header.stamp = info.header.stamp = t;
    std::fill(img.data.begin(), img.data.end(), 0);
    ASSERT_TRUE(graph().feed(img, &info));
  }
  const ros::WallTime t2 = ros::WallTime::now();
  const auto lost = watch.waitDiag("registration: tracking state", t2, 5.0, [](const auto& s) {
    return s.level != diagnostic_msgs::DiagnosticStatus::OK;
  });
  ASSERT_TRUE(lost) << "a covered lens left the tracking state OK";
  if (lost->level == diagnostic_msgs::DiagnosticStatus::ERROR)
    EXPECT_EQ(lost->message.rfind("LOST", 0), 0u) << lost->message;
  else
    EXPECT_EQ(lost->message.rfind("RELOCALISING", 0), 0u) << lost->message;
  // No input: the rate turns ERROR once a whole window (2 updates) saw no frame.
  const auto stopped = watch.waitDiag("registration: input rate", t2, 8.0, [](const auto& s) {
    return s.level == diagnostic_msgs::DiagnosticStatus::ERROR;
  });
  ASSERT_TRUE(stopped) << "input stopped but the rate stayed OK";
  EXPECT_EQ(stopped->message, "No events recorded.");
  std::printf("diagnostics: rate %.1f Hz while fed, '%s' when lost, '%s' when stopped\n", hz,
              lost->message.c_str(), stopped->message.c_str());
}

TEST(Graph, ReconfigureSwitchesTheMethodBetweenFramesAndRefusesOutOfRange) {
  Watch watch;
  graph().setClock(bag().images.front()->header.stamp - ros::Duration(0.1));
  const int switch_at = 60;
  std::vector<rig_msgs::TrackingStatus> st;
  runGraph(switch_at, false, &st);
  ASSERT_EQ(static_cast<int>(st.size()), switch_at);
  EXPECT_EQ(st.back().method, "p2l");
  // dynamic_reconfigure's own client (dynparam) switches the method mid-replay, to
  // point-to-point. Cell Search is refused: pca_reduce does not compute the FM terms here
  // (pca_reduce/fm_terms off keeps the reduction identical to the offline tracker's).
  std::string out;
  runTool("rosrun dynamic_reconfigure dynparam set /registration method cell_search", &out);
  EXPECT_TRUE(watch.waitLog("cell_search needs the cells' FM (Foerstner-Moonen) terms", 10.0))
      << out;
  ASSERT_EQ(runTool("rosrun dynamic_reconfigure dynparam set /registration method p2p", &out), 0)
      << out;
  for (int i = switch_at; i < kFrames; ++i) {
    const auto s = graph().feed(*bag().images[i], bag().infos[i].get());
    ASSERT_TRUE(s) << i;
    st.push_back(*s);
  }
  ASSERT_EQ(static_cast<int>(st.size()), kFrames);
  // Applied from the next frame on (the request came between frames 59 and 60), every frame.
  for (int i = switch_at; i < kFrames; ++i) EXPECT_EQ(st[i].method, "p2p") << i;
  // No restart: the same epoch and the frame count goes on (a reset starts both anew); the
  // first p2p frame registered (against the p2l keyframe, kept across the switch). How well
  // point-to-point does here is printed, not asserted: on these L515 cells its residual passes
  // max_error within a few frames, and the status then says LOST, as it should.
  EXPECT_EQ(st[switch_at].epoch, st[switch_at - 1].epoch);
  EXPECT_EQ(st[switch_at].frame, st[switch_at - 1].frame + 1);
  EXPECT_GT(st[switch_at].iterations, 0);
  EXPECT_GT(st[switch_at].matches, 0);
  const auto gt = groundTruth(kFrames);
  const auto errs =
      frameErrors(std::vector<Eigen::Isometry3d>{conv::fromPoseMsg(st[0].camera_pose),
                                                 conv::fromPoseMsg(st[switch_at].camera_pose)},
                  std::vector<Eigen::Isometry3d>{gt[0], gt[switch_at]});
  int p2p_tracked = 0;
  for (int i = switch_at; i < kFrames; ++i) p2p_tracked += st[i].tracked;
  std::printf(
      "reconfigure: p2l -> p2p at frame %d: first p2p frame %.1f mm / %.2f deg from ground "
      "truth, %d of %d p2p frames tracked\n",
      switch_at, errs[1].pos_err_mm.norm(), errs[1].rot_err_deg.norm(), p2p_tracked,
      kFrames - switch_at);
  const auto diag = watch.waitDiag("registration: tracking state", ros::WallTime::now(), 5.0,
                                   [](const auto& s) { return value(s, "method") == "p2p"; });
  EXPECT_TRUE(diag) << "the diagnostics do not show the new method";

  // Out of range, an unknown choice, a value validate() refuses: nothing changes, each named.
  out.clear();
  runTool("rosrun dynamic_reconfigure dynparam set /registration max_iterations 5000", &out);
  EXPECT_TRUE(watch.waitLog("max_iterations = 5000: must lie in [1, 1000]", 10.0)) << out;
  runTool("rosrun dynamic_reconfigure dynparam set /registration method icp", &out);
  EXPECT_TRUE(watch.waitLog("method = icp: must be p2p | p2l | cell_search", 10.0)) << out;
  dynamic_reconfigure::Reconfigure req;
  dynamic_reconfigure::DoubleParameter d;
  d.name = "dist_min", d.value = -0.1;
  req.request.config.doubles.push_back(d);
  ASSERT_TRUE(ros::service::call("/registration/set_parameters", req));
  EXPECT_TRUE(watch.waitLog("dist_min = -0.1: must lie in [0.001, 1]", 10.0));
  int iterations = -1;
  std::string method;
  for (const auto& p : req.response.config.ints)
    if (p.name == "max_iterations") iterations = p.value;
  for (const auto& p : req.response.config.strs)
    if (p.name == "method") method = p.value;
  EXPECT_EQ(iterations, TrackerConfig{}.registration.max_iterations) << "old value kept";
  EXPECT_EQ(method, "p2p") << "old value kept";
  // The next frames run on, with the accepted method.
  sensor_msgs::Image img = *bag().images.back();
  sensor_msgs::CameraInfo info = *bag().infos.back();
  img.header.stamp = info.header.stamp = img.header.stamp + ros::Duration(1.0 / 30);
  const auto s = graph().feed(img, &info);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->method, "p2p");
  // Back to the launch file's method for the tests after this one.
  ASSERT_EQ(runTool("rosrun dynamic_reconfigure dynparam set /registration method p2l", &out), 0)
      << out;
  std::string published;
  for (int i = 0; i < 50 && published != "p2l"; ++i) {
    if (const auto upd = watch.lastUpdate())
      for (const auto& p : upd->strs)
        if (p.name == "method") published = p.value;
    ros::WallDuration(0.1).sleep();
  }
  EXPECT_EQ(published, "p2l") << "parameter_updates did not follow";
}

TEST(Graph, BadParameterStopsTheNodeletNamingIt) {
  ros::param::set("/bad_graph/tracker/cell_size", 7);
  ros::param::set("/bad_graph/pca_reduce/threads", 0);
  const std::string cmd =
      "timeout 60 rosrun nodelet nodelet standalone depth_track/pca_reduce __ns:=/bad_graph "
      "__name:=pca_reduce 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string out;
  char buf[512];
  while (std::fgets(buf, sizeof(buf), p)) out += buf;
  const int rc = pclose(p);
  EXPECT_NE(rc, 0) << out;
  EXPECT_NE(out.find("/bad_graph/tracker/cell_size = 7"), std::string::npos) << out;
  EXPECT_NE(out.find("/bad_graph/pca_reduce/threads = 0: must lie in [1, 64]"), std::string::npos)
      << out;
  // A wait for the map's process that cannot get an answer (0 s) stops the registration.
  ros::param::set("/bad_graph/registration/render_timeout", 0.0);
  FILE* q = popen(
      "timeout 60 rosrun nodelet nodelet standalone depth_track/registration __ns:=/bad_graph "
      "__name:=registration 2>&1",
      "r");
  ASSERT_NE(q, nullptr);
  out.clear();
  while (std::fgets(buf, sizeof(buf), q)) out += buf;
  EXPECT_NE(pclose(q), 0) << out;
  EXPECT_NE(out.find("/bad_graph/registration/render_timeout = 0: must lie in"), std::string::npos)
      << out;
}

// graph_loop.test: the same graph with loop closure on and the thesis's frame-to-frame tracking
// (icp_frames 1), whose drift the map corrects. The map-frame trajectory (map -> odom decided by
// the loop_closure nodelet, times odom -> camera) must equal the offline Tracker + Mapper run,
// the way track_sequence --loop-closure on composes them: that holds only if the two mapping
// nodelets keep the offline order (frame k's loop closure sees the map up to frame k-1, frame k
// is fused at the pose it decided).
TEST(GraphLoop, MapTrajectoryEqualsTheOfflineMapper) {
  ASSERT_TRUE(graph().connected(60.0));
  graph().publishStatic(bag().tf_static);
  std::vector<rig_msgs::TrackingStatus> st;
  const auto odom = runGraph(kFrames, false, &st);
  ASSERT_EQ(static_cast<int>(odom.size()), kFrames);
  // The map -> odom decisions, from the saved map-frame trajectory.
  rig_msgs::SaveFile traj;
  traj.request.path = workDir() + "/loop_traj.txt";
  ASSERT_TRUE(ros::service::call("/registration/save_trajectory", traj));
  ASSERT_TRUE(traj.response.success) << traj.response.message;
  const Trajectory graph_map = readTumTrajectory(workDir() + "/loop_traj_map.txt");
  ASSERT_EQ(static_cast<int>(graph_map.size()), kFrames);

  const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(*bag().infos[0]);
  TrackerConfig tc;
  tc.icp_frames = 1;
  Tracker tracker(K, tc, mount(bag().tf_static));
  MapperConfig mc;
  mc.loop.enabled = true;
  mc.loop.deadband_m = mc.loop.deadband_deg = 0.0;  // as graph_loop.test sets them
  mc.loop.min_model_age_frames = 20;
  Mapper mapper(K, mc, tracker.pose());
  int accepted = 0;
  double max_dt = 0, max_dr = 0;
  for (int i = 0; i < kFrames; ++i) {
    const auto& img = *bag().images[i];
    const DepthImage depth = conv::depthFromMsg(img, kDepthScale, DepthRange{});
    FrameStatus fs = tracker.track(depth, img.header.stamp.toSec());
    const MapperFrame mf = mapper.process(depth, fs.T_W_C);
    if (mf.loop_attempted && mf.loop.accepted) {
      tracker.correctPose(mf.T_W_C);
      fs.T_W_C = mf.T_W_C;
      ++accepted;
    }
    // Written with 6 decimals (1e-6 m); the comparison allows that rounding.
    max_dt = std::max(max_dt, (fs.T_W_C.translation() - graph_map[i].T_W_C.translation()).norm());
    max_dr = std::max(max_dr, rotationAngle(fs.T_W_C.inverse() * graph_map[i].T_W_C));
  }
  std::printf("loop closure: %d/%d accepted offline; graph vs offline %.2g m %.2g rad\n", accepted,
              mapper.loopAttempts(), max_dt, max_dr);
  EXPECT_GT(mapper.loopAttempts(), 10);
  EXPECT_GE(accepted, 1)
      << "no correction applied: nothing tests the order of the mapping nodelets";
  EXPECT_LT(max_dt, 2e-6);
  EXPECT_LT(max_dr, 2e-6);
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "dt_test_graph");
  const int rc = RUN_ALL_TESTS();
  std::filesystem::remove_all(workDir());
  ros::shutdown();
  return rc;
}
