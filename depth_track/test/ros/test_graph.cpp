// The tracking graph (launch/tracking.launch, replay mode) against a real roscore, fed frame by
// frame from a generated RT3 scenario bag with /clock: every frame gives odom -> base_link; the
// trajectory equals the core's Tracker run offline on the same frames; 16UC1 and 32FC1 give the
// same poses; a jump back in time (a looped bag) resets the graph; reset / save_trajectory /
// save_map work and their files load; bad input gives a status naming it and no crash; a
// covered lens ends RELOCALISING -> TRACKING near the ground truth; a bad parameter stops a
// nodelet with the parameter's name.
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
          ros::service::exists("/fusion/save_map", false) &&
          advertised("/loop_closure/status")) {
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
  int baseTfCount(const ros::Time& from, const ros::Time& to) {
    std::lock_guard<std::mutex> lock(mutex_);
    int n = 0;
    for (const auto& t : base_tf_stamps_) n += t >= from && t <= to;
    return n;
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
  EXPECT_EQ(
      graph().baseTfCount(bag().images.front()->header.stamp, bag().images.back()->header.stamp),
      kFrames);

  // The same frames through the core's Tracker, as track_sequence runs it.
  const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(*bag().infos[0]);
  Tracker tracker(K, TrackerConfig{}, mount(bag().tf_static));
  double max_dt = 0, max_dr = 0;
  for (int i = 0; i < kFrames; ++i) {
    const auto& img = *bag().images[i];
    const FrameStatus fs =
        tracker.track(conv::depthFromMsg(img, kDepthScale, DepthRange{}), img.header.stamp.toSec());
    max_dt = std::max(max_dt, (fs.T_W_C.translation() - run16[i].translation()).norm());
    max_dr = std::max(max_dr, rotationAngle(fs.T_W_C.inverse() * run16[i]));
  }
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
