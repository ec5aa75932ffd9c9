// graph_remote.test: the tracking graph as separate processes with depth over compressedDepth
// (/remote) tracks every frame of a generated RT3 bag and gives the same poses as the
// single-manager graph on raw depth (/single). 16UC1 goes through the PNG losslessly, so both
// graphs see the same depth and the poses must agree to 1e-6 m / rad (the replay is
// deterministic; measured: identical). The master shows what makes it "remote": /remote/ingest
// takes /camera/image_rect/compressedDepth and not the raw topic, and the five nodelets are five
// processes. With the lens covered for 2 s, the remote registration relocalises against the map
// of the fusion process through its ~render_depth service, as the single manager does against
// its shared map: both end RELOCALISING -> TRACKING near the ground truth, with the same poses.
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <rig_msgs/RenderDepth.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/master.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <rosgraph_msgs/Clock.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <xmlrpcpp/XmlRpcValue.h>

#include <stdlib.h>
#include <condition_variable>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>

#include <std_srvs/Trigger.h>

#include "../../src/nodelets/graph_common.hpp"
#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/ros/conversions.hpp"

using namespace depth_track;

namespace {

const int kFrames = 150;   // frames of the bag (the covered-lens run uses all)
const int kTracked = 100;  // frames of the first run

struct Recording {
  std::string dir;
  std::vector<sensor_msgs::Image::ConstPtr> depth;
  std::vector<sensor_msgs::CameraInfo::ConstPtr> info;
  tf2_msgs::TFMessage::ConstPtr tf_static;
  std::vector<Eigen::Isometry3d> gt;  // the optical frame's ground truth per frame
};

const Recording& recording() {
  static const Recording r = [] {
    Recording rec;
    std::string tmpl = ::testing::TempDir() + "/dt_graph_remote_XXXXXX";
    if (!mkdtemp(tmpl.data())) throw std::runtime_error("cannot create " + tmpl);
    rec.dir = tmpl;
    const std::string cmd = std::string(MAKE_SCENARIO_BAG) + " --scenario " + DT_SCENARIO_DIR +
                            "/RT3.yaml --out-dir " + rec.dir + " --max-frames " +
                            std::to_string(kFrames) + " --compression none > " + rec.dir +
                            "/make_scenario_bag.log 2>&1";
    if (std::system(cmd.c_str()) != 0) throw std::runtime_error("failed: " + cmd);
    rosbag::Bag bag(rec.dir + "/RT3.bag");
    rosbag::View view(bag, rosbag::TopicQuery(
                               std::vector<std::string>{"/camera/image_rect", "/camera/camera_info",
                                                        "/tf_static", "/rig_sim/camera_pose"}));
    for (const rosbag::MessageInstance& m : view) {
      if (auto img = m.instantiate<sensor_msgs::Image>()) rec.depth.push_back(img);
      if (auto ci = m.instantiate<sensor_msgs::CameraInfo>()) rec.info.push_back(ci);
      if (auto tf = m.instantiate<tf2_msgs::TFMessage>()) rec.tf_static = tf;
      if (auto p = m.instantiate<geometry_msgs::PoseStamped>())
        rec.gt.push_back(conv::fromPoseMsg(p->pose));
    }
    return rec;
  }();
  return r;
}

/// Statuses by graph namespace, and the odom -> base_link stamps seen on each graph's tf topic.
class Observer {
 public:
  explicit Observer(ros::NodeHandle& nh) {
    for (const std::string ns : {"single", "remote"})
      subs_.push_back(nh.subscribe<rig_msgs::TrackingStatus>(
          "/" + ns + "/status", 500, [this, ns](const rig_msgs::TrackingStatus::ConstPtr& s) {
            std::lock_guard<std::mutex> lock(mutex_);
            status_[ns][s->header.stamp] = *s;
            cv_.notify_all();
          }));
    subs_.push_back(nh.subscribe<tf2_msgs::TFMessage>(
        "/remote/tf", 500, [this](const tf2_msgs::TFMessage::ConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          for (const auto& t : m->transforms)
            if (t.header.frame_id == "odom" && t.child_frame_id == "base_link")
              remote_tf_.insert(t.header.stamp);
          cv_.notify_all();
        }));
    tf_sub_ = subs_.size() - 1;
    subs_.push_back(nh.subscribe<sensor_msgs::CompressedImage>(
        "/camera/image_rect/compressedDepth", 500,
        [this](const sensor_msgs::CompressedImage::ConstPtr& m) {
          std::lock_guard<std::mutex> lock(mutex_);
          compressed_bytes_ += m->data.size();
          ++compressed_frames_;
        }));
  }
  /// Both graphs' status of `stamp`, waiting up to timeout_s.
  bool waitBoth(const ros::Time& stamp, double timeout_s, rig_msgs::TrackingStatus* single,
                rig_msgs::TrackingStatus* remote) {
    std::unique_lock<std::mutex> lock(mutex_);
    const bool ok = cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
      return status_["single"].count(stamp) && status_["remote"].count(stamp);
    });
    if (ok) {  // taken: a looped run brings the same stamps again
      *single = status_["single"][stamp];
      *remote = status_["remote"][stamp];
      status_["single"].erase(stamp);
      status_["remote"].erase(stamp);
    }
    return ok;
  }
  /// odom -> base_link transforms seen on the remote graph's tf, waiting up to timeout_s for
  /// `expected` of them: /remote/tf and /remote/status are separate connections, so a frame's tf
  /// (sent first) may still arrive after its status.
  std::size_t remoteTfCount(std::size_t expected = 0, double timeout_s = 0.0) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                 [&] { return remote_tf_.size() >= expected; });
    return remote_tf_.size();
  }
  bool hasRemoteTf(const ros::Time& stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    return remote_tf_.count(stamp) > 0;
  }
  /// True once the remote graph's tf publisher is connected to this observer (a transform sent
  /// before that is lost).
  bool tfConnected() const { return subs_[tf_sub_].getNumPublishers() >= 1; }
  double compressedBytesPerFrame() {
    std::lock_guard<std::mutex> lock(mutex_);
    return compressed_frames_ ? double(compressed_bytes_) / compressed_frames_ : 0.0;
  }

 private:
  std::vector<ros::Subscriber> subs_;
  std::size_t tf_sub_ = 0;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::map<std::string, std::map<ros::Time, rig_msgs::TrackingStatus>> status_;
  std::set<ros::Time> remote_tf_;
  std::size_t compressed_bytes_ = 0, compressed_frames_ = 0;
};

/// topic -> subscribing nodes, from the master's system state.
std::map<std::string, std::set<std::string>> subscribers() {
  std::map<std::string, std::set<std::string>> out;
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  if (!ros::master::execute("getSystemState", args, result, payload, true)) return out;
  XmlRpc::XmlRpcValue& subs = payload[1];
  for (int i = 0; i < subs.size(); ++i)
    for (int j = 0; j < subs[i][1].size(); ++j)
      out[static_cast<std::string>(subs[i][0])].insert(static_cast<std::string>(subs[i][1][j]));
  return out;
}

std::string nodeUri(const std::string& node) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = node;
  if (!ros::master::execute("lookupNode", args, result, payload, false)) return "";
  return static_cast<std::string>(payload);
}

bool graphsUp(const ros::Publisher& depth, const Observer& obs, double timeout_s) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
  const std::vector<std::string> needed = {"/single/loop_closure/status",
                                           "/remote/loop_closure/status", "/single/status",
                                           "/remote/status"};
  while (ros::WallTime::now() < end) {
    ros::master::V_TopicInfo topics;
    ros::master::getTopics(topics);
    std::size_t found = 0;
    for (const auto& n : needed)
      for (const auto& t : topics) found += t.name == n;
    const auto subs = subscribers();
    const bool compressed_in =
        subs.count("/camera/image_rect/compressedDepth") &&
        subs.at("/camera/image_rect/compressedDepth").count("/remote/ingest");
    if (found == needed.size() && compressed_in && depth.getNumSubscribers() >= 2 &&
        obs.tfConnected()) {
      ros::WallDuration(1.5).sleep();  // let the nodelets' own subscriptions connect
      return true;
    }
    ros::WallDuration(0.2).sleep();
  }
  return false;
}

}  // namespace

TEST(GraphRemote, SeparateProcessesOverCompressedDepthTrackLikeOneManager) {
  const Recording& rec = recording();
  ASSERT_EQ(static_cast<int>(rec.depth.size()), kFrames);
  ASSERT_EQ(rec.info.size(), rec.depth.size());
  ASSERT_TRUE(rec.tf_static);
  ros::NodeHandle nh;
  Observer obs(nh);
  ros::Publisher clock = nh.advertise<rosgraph_msgs::Clock>("/clock", 10);
  ros::Publisher depth = nh.advertise<sensor_msgs::Image>("/camera/image_rect", 10);
  ros::Publisher info = nh.advertise<sensor_msgs::CameraInfo>("/camera/camera_info", 10);
  ros::Publisher tf_static = nh.advertise<tf2_msgs::TFMessage>("/tf_static", 1, true);
  ASSERT_TRUE(graphsUp(depth, obs, 90.0)) << "the two graphs did not come up";

  // What makes it remote: depth reaches /remote/ingest only as compressedDepth, and each of its
  // nodelets is a process of its own (its own XML-RPC URI).
  const auto subs = subscribers();
  EXPECT_TRUE(subs.at("/camera/image_rect")
                  .count("/single/depth_track_manager"));  // a nodelet in a manager
  EXPECT_FALSE(subs.at("/camera/image_rect").count("/remote/ingest"));
  std::set<std::string> uris;
  for (const std::string n : {"ingest", "pca_reduce", "registration", "fusion", "loop_closure"})
    uris.insert(nodeUri("/remote/" + n));
  uris.erase("");
  EXPECT_EQ(uris.size(), 5u) << "five nodelets, five processes";

  tf_static.publish(*rec.tf_static);
  double max_dt = 0.0, max_dr = 0.0, raw_bytes = 0.0;
  int tracked = 0;
  for (int i = 0; i < kTracked; ++i) {
    const sensor_msgs::Image& img = *rec.depth[i];
    rosgraph_msgs::Clock c;
    c.clock = img.header.stamp;
    clock.publish(c);
    ros::WallDuration(0.005).sleep();
    info.publish(*rec.info[i]);
    depth.publish(img);
    raw_bytes += img.data.size();
    rig_msgs::TrackingStatus s, r;
    ASSERT_TRUE(obs.waitBoth(img.header.stamp, 30.0, &s, &r)) << "no status of frame " << i;
    EXPECT_EQ(s.state_name, "TRACKING") << i << " single: " << s.failure;
    EXPECT_EQ(r.state_name, "TRACKING") << i << " remote: " << r.failure;
    tracked += r.tracked;
    const Eigen::Isometry3d Ts = conv::fromPoseMsg(s.camera_pose);
    const Eigen::Isometry3d Tr = conv::fromPoseMsg(r.camera_pose);
    max_dt = std::max(max_dt, (Ts.translation() - Tr.translation()).norm());
    max_dr = std::max(max_dr, rotationAngle(Ts.inverse() * Tr));
  }
  EXPECT_EQ(tracked, kTracked);
  EXPECT_LT(max_dt, 1e-6) << "m, remote vs single manager";
  EXPECT_LT(max_dr, 1e-6) << "rad, remote vs single manager";
  // tf odom -> base_link for every frame on the remote graph's tf (it goes out before status).
  EXPECT_EQ(obs.remoteTfCount(kTracked, 5.0), static_cast<std::size_t>(kTracked));
  for (int i = 0; i < kTracked; ++i)
    EXPECT_TRUE(obs.hasRemoteTf(rec.depth[i]->header.stamp)) << "no remote tf for frame " << i;
  std::printf(
      "remote graph (%d frames, separate processes, compressedDepth): %d tracked, vs single "
      "manager %.2g m %.2g rad; depth %.0f B/frame raw, %.0f B/frame compressedDepth (png_level "
      "1)\n",
      kTracked, tracked, max_dt, max_dr, raw_bytes / kTracked, obs.compressedBytesPerFrame());
}

// Runs after the test above (same graphs, same master): the clock jumps back to the bag's start,
// so both graphs reset (the remote fusion process learns it from the statuses' epoch), and
// frames 45..104 (2 s) come with the lens covered, as in graph.test.
TEST(GraphRemote, CoveredLensRelocalisesAgainstTheMapOfTheFusionProcess) {
  const Recording& rec = recording();
  ASSERT_EQ(rec.gt.size(), rec.depth.size());
  ros::NodeHandle nh;
  ros::Publisher clock = nh.advertise<rosgraph_msgs::Clock>("/clock", 10);
  ros::Publisher depth = nh.advertise<sensor_msgs::Image>("/camera/image_rect", 10);
  ros::Publisher info = nh.advertise<sensor_msgs::CameraInfo>("/camera/camera_info", 10);
  Observer obs(nh);
  ASSERT_TRUE(graphsUp(depth, obs, 60.0));
  rosgraph_msgs::Clock c;
  c.clock = rec.depth.front()->header.stamp - ros::Duration(0.1);
  clock.publish(c);
  ros::WallDuration(0.2).sleep();

  const int gap0 = 45, gap1 = 105;
  std::map<std::string, std::vector<Eigen::Isometry3d>> est;
  std::map<std::string, std::vector<std::string>> states, failures;
  for (int i = 0; i < kFrames; ++i) {
    sensor_msgs::Image img = *rec.depth[i];
    if (i >= gap0 && i < gap1) std::fill(img.data.begin(), img.data.end(), 0);
    c.clock = img.header.stamp;
    clock.publish(c);
    ros::WallDuration(0.005).sleep();
    info.publish(*rec.info[i]);
    depth.publish(img);
    rig_msgs::TrackingStatus st[2];
    ASSERT_TRUE(obs.waitBoth(img.header.stamp, 30.0, &st[0], &st[1])) << "frame " << i;
    for (int g = 0; g < 2; ++g) {
      const std::string ns = g == 0 ? "single" : "remote";
      est[ns].push_back(conv::fromPoseMsg(st[g].camera_pose));
      states[ns].push_back(st[g].state_name);
      failures[ns].push_back(st[g].failure);
    }
  }
  for (const std::string ns : {"single", "remote"}) {
    const auto& s = states[ns];
    EXPECT_EQ(s[gap0 - 1], "TRACKING") << ns;
    EXPECT_EQ(s[gap0 + 1], "LOST") << ns;
    EXPECT_NE(std::find(s.begin() + gap0, s.begin() + gap1, "RELOCALISING"), s.begin() + gap1)
        << ns << ": never attempted (" << failures[ns][gap0 + 3] << ")";
    int back = -1;
    for (int i = gap1; i < kFrames && back < 0; ++i)
      if (s[i] == "TRACKING") back = i;
    ASSERT_GE(back, 0) << ns << ": never tracked again after the gap: " << failures[ns][gap1 + 3];
    // graph.test's bound: a relocalisation is tried on every 3rd lost frame; two tries.
    EXPECT_LE(back, gap1 + 6) << ns << ": relocalised only " << back - gap1
                              << " frames after the gap";
    for (int i = back; i < kFrames; ++i) EXPECT_EQ(s[i], "TRACKING") << ns << " " << i;
    const auto errs = frameErrors(est[ns], rec.gt);
    for (int i : {back, kFrames - 1}) {
      EXPECT_LT(errs[i].pos_err_mm.norm(), 20.0) << ns << " frame " << i;
      EXPECT_LT(errs[i].rot_err_deg.norm(), 1.0) << ns << " frame " << i;
    }
    std::printf(
        "%s: lens covered %d..%d, TRACKING again at frame %d (%s); %.2f mm / %.3f deg from "
        "ground truth there, %.2f mm / %.3f deg at the end\n",
        ns.c_str(), gap0, gap1 - 1, back, failures[ns][back].c_str(), errs[back].pos_err_mm.norm(),
        errs[back].rot_err_deg.norm(), errs[kFrames - 1].pos_err_mm.norm(),
        errs[kFrames - 1].rot_err_deg.norm());
  }
  // The remote map is the single manager's (same frames, same poses) and the cast travels as
  // 32FC1 bit for bit: the relocalised poses must agree as the tracked ones do.
  double max_dt = 0.0;
  for (int i = 0; i < kFrames; ++i)
    max_dt =
        std::max(max_dt, (est["single"][i].translation() - est["remote"][i].translation()).norm());
  EXPECT_LT(max_dt, 1e-6) << "m, remote vs single manager through the gap";

  // The service itself: a pose in a frame it does not know is refused by name; a pose in the
  // odom frame gives the camera_info's size in 32FC1 with the view mostly on the map.
  rig_msgs::RenderDepth srv;
  srv.request.header.stamp = rec.depth.back()->header.stamp;
  srv.request.header.frame_id = "base_link";
  srv.request.pose = conv::toPoseMsg(est["remote"].back());
  srv.request.camera_info = *rec.info.back();
  ASSERT_TRUE(ros::service::call("/remote/fusion/render_depth", srv));
  EXPECT_FALSE(srv.response.success);
  EXPECT_NE(srv.response.message.find("'base_link'"), std::string::npos) << srv.response.message;
  srv.request.header.frame_id = "odom";
  ASSERT_TRUE(ros::service::call("/remote/fusion/render_depth", srv));
  ASSERT_TRUE(srv.response.success) << srv.response.message;
  EXPECT_EQ(srv.response.depth.encoding, "32FC1");
  EXPECT_EQ(srv.response.depth.width, rec.info.back()->width);
  EXPECT_EQ(srv.response.depth.height, rec.info.back()->height);
  const DepthImage virt = conv::depthFromMsg(srv.response.depth, 1.0, DepthRange{0.0, 1e9});
  EXPECT_GT(virt.countValid(), virt.data.size() / 2) << srv.response.message;
  EXPECT_GT(srv.response.occupied_voxels, 100000u);
}

// How the registration asks the map's process: a slow server costs the caller at most the
// timeout, a call still out refuses the next one, a missing server is named.
TEST(GraphRemote, TimedServiceCallWaitsAtMostItsTimeout) {
  ros::NodeHandle nh;
  boost::function<bool(std_srvs::Trigger::Request&, std_srvs::Trigger::Response&)> answer =
      [](std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
        ros::WallDuration(1.0).sleep();
        res.success = true;
        res.message = "slow answer";
        return true;
      };
  ros::ServiceServer slow = nh.advertiseService("/test_slow_service", answer);
  graph::TimedServiceCall<std_srvs::Trigger> call("/test_slow_service");
  std::string why;
  EXPECT_FALSE(call.call({}, 0.2, &why)) << "the answer takes 1 s";
  EXPECT_NE(why.find("no answer within 0.2"), std::string::npos) << why;
  EXPECT_FALSE(call.call({}, 0.2, &why));
  EXPECT_NE(why.find("still out"), std::string::npos) << why;
  ros::WallDuration(1.2).sleep();  // the first call's answer has come meanwhile
  const auto res = call.call({}, 5.0, &why);
  ASSERT_TRUE(res) << why;
  EXPECT_EQ(res->message, "slow answer");
  graph::TimedServiceCall<std_srvs::Trigger> none("/no_such_service");
  EXPECT_FALSE(none.call({}, 5.0, &why));
  EXPECT_NE(why.find("/no_such_service: call failed"), std::string::npos) << why;
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "dt_test_graph_remote");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int rc = RUN_ALL_TESTS();
  try {
    std::filesystem::remove_all(recording().dir);
  } catch (const std::exception&) {  // the bag never got made; the test said why
  }
  ros::shutdown();
  return rc;
}
