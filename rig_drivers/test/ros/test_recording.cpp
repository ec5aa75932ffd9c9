// rostests: recording exactly as the rig launch files do it (recording.test: a Ctrl-C;
// recording_fault.test: a disk that fills). servotrack.launch and
// servotruck.launch include launch/record.launch; this test runs that same file through roslaunch
// (1 MB splits instead of 1 GB) and stops it with SIGINT to roslaunch, as Ctrl-C does: roslaunch
// passes SIGINT on to rosbag record. Every bag left behind must open through its index
// (rosbag::Bag throws on an unindexed bag), no .active file may remain, and the recorded depth
// frames must be contiguous: nothing lost inside the recording, nothing after the stop.
#include <dirent.h>
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "depth_track/core/tracker.hpp"
#include "depth_track/ros/conversions.hpp"
#include "launch_tools.hpp"
#include "rig_msgs/TrackState.h"
#include "rig_msgs/TrackingStatus.h"

namespace dt = depth_track;
namespace dtconv = depth_track::conv;
using rig_drivers::test::Child;
using rig_drivers::test::Diagnostics;
using rig_drivers::test::filesEndingIn;
using rig_drivers::test::subscribersOf;
using rig_drivers::test::tempDir;
using rig_drivers::test::waitUntil;

namespace {
std::vector<std::string> listDir(const std::string& dir) {
  std::vector<std::string> out;
  if (DIR* d = ::opendir(dir.c_str())) {
    while (dirent* e = ::readdir(d))
      if (e->d_name[0] != '.') out.push_back(e->d_name);
    ::closedir(d);
  }
  std::sort(out.begin(), out.end());
  return out;
}
bool endsWith(const std::string& s, const std::string& e) {
  return s.size() >= e.size() && s.compare(s.size() - e.size(), e.size(), e) == 0;
}
}  // namespace

TEST(Recording, SigintLeavesSplitIndexedBags) {
  ros::NodeHandle nh;
  auto img_pub = nh.advertise<sensor_msgs::Image>("camera/image_rect", 30);
  auto state_pub = nh.advertise<rig_msgs::TrackState>("track_state", 30);
  char tmpl[] = "/tmp/rig_rec_testXXXXXX";
  ASSERT_NE(::mkdtemp(tmpl), nullptr);
  const std::string dir = tmpl;

  std::string launch_file;
  ASSERT_TRUE(ros::param::get("~record_launch", launch_file))
      << "recording.test sets ~record_launch";
  ASSERT_EQ(::access(launch_file.c_str(), R_OK), 0) << launch_file;
  const std::string bag_dir = "bag_dir:=" + dir;  // built before fork: no allocation in the child
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::execlp("roslaunch", "roslaunch", launch_file.c_str(), bag_dir.c_str(), "bag_prefix:=rec",
             "split_size_mb:=1", "topics:=/camera/image_rect /track_state",
             static_cast<char*>(nullptr));
    ::_exit(127);
  }
  // Wait for the recorder to subscribe before publishing (its first frames would be lost);
  // roslaunch itself takes a few seconds to start on a loaded machine.
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(60);
  while ((img_pub.getNumSubscribers() == 0 || state_pub.getNumSubscribers() == 0) &&
         ros::WallTime::now() < deadline)
    ros::WallDuration(0.05).sleep();
  if (img_pub.getNumSubscribers() == 0) {
    ::kill(pid, SIGINT);
    ::waitpid(pid, nullptr, 0);
    FAIL() << "the recorder of " << launch_file << " did not subscribe within 60 s";
  }
  ros::WallDuration(0.3).sleep();

  // 3 s of 30 Hz 640x480 16UC1 frames (614 kB each): ~55 MB, many 1 MB splits.
  sensor_msgs::Image img;
  img.width = 640;
  img.height = 480;
  img.encoding = "16UC1";
  img.step = 1280;
  img.data.resize(img.step * img.height);
  std::uint32_t n = 0;
  ros::WallRate rate(30);
  for (; n < 90; ++n) {
    img.header.seq = n;
    img.header.stamp = ros::Time::now();
    // Noise-like content: lz4 cannot shrink it, so the split size is reached as on real depth.
    std::uint32_t x = 2463534242u + n;
    for (auto& b : img.data) {
      x ^= x << 13;
      x ^= x >> 17;
      x ^= x << 5;
      b = static_cast<std::uint8_t>(x);
    }
    img_pub.publish(img);
    rig_msgs::TrackState s;
    s.header.stamp = img.header.stamp;
    s.frame_seq = n;
    state_pub.publish(s);
    rate.sleep();
  }
  ros::WallDuration(0.5).sleep();
  ASSERT_EQ(::kill(pid, SIGINT), 0);  // Ctrl-C on roslaunch
  int status = 0;
  pid_t r = 0;
  // roslaunch escalates to SIGTERM 15 s after its SIGINT; a bag closed by SIGINT is done sooner.
  for (int i = 0; i < 400 && r == 0; ++i) {  // up to 20 s
    r = ::waitpid(pid, &status, WNOHANG);
    if (r == 0) ros::WallDuration(0.05).sleep();
  }
  if (r == 0) {
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
    FAIL() << "roslaunch " << launch_file << " did not stop within 20 s of SIGINT";
  }

  const auto files = listDir(dir);
  int bags = 0;
  std::vector<std::uint32_t> seqs;
  int states = 0;
  for (const auto& f : files) {
    EXPECT_FALSE(endsWith(f, ".active")) << f << " left unclosed";
    if (!endsWith(f, ".bag")) continue;
    ++bags;
    rosbag::Bag bag;
    ASSERT_NO_THROW(bag.open(dir + "/" + f, rosbag::bagmode::Read)) << f << " is not indexed";
    rosbag::View view(bag);
    for (const auto& m : view) {
      if (auto im = m.instantiate<sensor_msgs::Image>()) {
        EXPECT_EQ(im->data.size(), 640u * 480u * 2u);
        seqs.push_back(im->header.seq);
      } else if (m.instantiate<rig_msgs::TrackState>()) {
        ++states;
      }
    }
    bag.close();
  }
  EXPECT_GE(bags, 3) << "--split --size=1 should have split ~55 MB of frames";
  ASSERT_FALSE(seqs.empty());
  std::sort(seqs.begin(), seqs.end());
  // Recorded after subscription: all 90 frames, contiguous, none duplicated across splits.
  EXPECT_EQ(seqs.size(), 90u);
  for (std::size_t i = 0; i < seqs.size(); ++i) EXPECT_EQ(seqs[i], i);
  EXPECT_EQ(states, 90);
  for (const auto& f : files) ::unlink((dir + "/" + f).c_str());
  ::rmdir(dir.c_str());
}

// A disk that fills mid-run: record.launch through roslaunch with a quota on the bag folder
// (write_fault.c, preloaded: past 4 MiB every write fails with ENOSPC, as on a full disk), while
// the rig's depth camera renders poses this test feeds and the tracking graph tracks them.
// The recorder's stop is reported by name (diagnostics, log), every bag it closed before the
// fault reads back whole with consecutive frames, and the graph tracks every frame, before and
// after, exactly as the offline tracker does on the same frames.
TEST(Recording, DiskFullMidRunReportsAndLeavesClosedBagsWhole) {
  using S = diagnostic_msgs::DiagnosticStatus;
  ros::NodeHandle nh;
  Diagnostics diag;
  std::mutex m;
  std::map<ros::Time, sensor_msgs::ImageConstPtr> images;
  sensor_msgs::CameraInfoConstPtr info;
  std::map<ros::Time, rig_msgs::TrackingStatus> status;
  std::vector<rosgraph_msgs::Log> errors;
  auto s1 =
      nh.subscribe<sensor_msgs::Image>("/camera/image_rect", 100,
                                       boost::function<void(const sensor_msgs::ImageConstPtr&)>(
                                           [&](const sensor_msgs::ImageConstPtr& i) {
                                             std::lock_guard<std::mutex> l(m);
                                             images[i->header.stamp] = i;
                                           }));
  auto s2 = nh.subscribe<sensor_msgs::CameraInfo>(
      "/camera/camera_info", 10,
      boost::function<void(const sensor_msgs::CameraInfoConstPtr&)>(
          [&](const sensor_msgs::CameraInfoConstPtr& c) {
            std::lock_guard<std::mutex> l(m);
            info = c;
          }));
  auto s3 = nh.subscribe<rig_msgs::TrackingStatus>(
      "/status", 100,
      boost::function<void(const rig_msgs::TrackingStatusConstPtr&)>(
          [&](const rig_msgs::TrackingStatusConstPtr& st) {
            std::lock_guard<std::mutex> l(m);
            status[st->header.stamp] = *st;
          }));
  auto s4 = nh.subscribe<rosgraph_msgs::Log>(
      "/rosout", 100,
      boost::function<void(const rosgraph_msgs::LogConstPtr&)>(
          [&](const rosgraph_msgs::LogConstPtr& g) {
            std::lock_guard<std::mutex> l(m);
            if (g->name == "/recorder" && g->level >= rosgraph_msgs::Log::ERROR)
              errors.push_back(*g);
          }));
  auto pose_pub = nh.advertise<geometry_msgs::PoseStamped>("/test/camera_pose", 10);
  ASSERT_TRUE(
      waitUntil([&] { return pose_pub.getNumSubscribers() > 0 && s3.getNumPublishers() > 0; }, 60))
      << "the camera or the tracking graph did not come up";

  const std::string root = tempDir("rig_rec_full"), dir = root + "/bags";
  std::string launch_file;
  ASSERT_TRUE(ros::param::get("~record_launch", launch_file));
  Child launch(
      {"roslaunch", launch_file, "bag_dir:=" + dir, "bag_prefix:=full", "split_size_mb:=1",
       "min_free_mb:=0", "topics:=/camera/image_rect /camera/camera_info"},
      {"LD_PRELOAD=" WRITE_FAULT_LIBRARY, "RIG_FAULT_DIR=" + dir, "RIG_FAULT_QUOTA_BYTES=4194304"});
  ASSERT_TRUE(waitUntil(
      [&] {
        const auto subs = subscribersOf("/camera/image_rect");
        return std::find(subs.begin(), subs.end(), "/recorder_rosbag") != subs.end();
      },
      60))
      << "rosbag record did not subscribe";

  // Frame k: 0.8 m up looking along the world x axis at the chair, 2 mm nearer and 1 mm to the
  // side per frame; each frame waits for the graph's answer before the next.
  std::vector<ros::Time> stamps;
  int fault_at = -1;
  for (int k = 0; k < 400 && (fault_at < 0 || k < fault_at + 30); ++k) {
    const auto p = rig_drivers::test::chairViewPose(ros::Time::now(), 0.002 * k, 0.001 * k);
    pose_pub.publish(p);
    const bool answered = waitUntil(
        [&] {
          std::lock_guard<std::mutex> l(m);
          return status.count(p.header.stamp) > 0;
        },
        20);
    ASSERT_TRUE(answered) << "no tracking status for frame " << k;
    stamps.push_back(p.header.stamp);
    if (fault_at < 0 && diag.has("recorder: recording", "not recording into " + dir, S::ERROR))
      fault_at = k;
  }
  ASSERT_GE(fault_at, 0) << "the recorder never stopped: " << diag.describe("recorder: recording");
  std::printf("the recorder stopped at frame %d: %s\n", fault_at,
              diag.describe("recorder: recording").c_str());
  EXPECT_TRUE(launch.stop(30));

  // Said loudly and by name: an error on /rosout naming the folder, the bags and the open one.
  {
    std::lock_guard<std::mutex> l(m);
    bool named = false;
    for (const auto& g : errors)
      named = named || (g.msg.find("recording into " + dir + " stopped") != std::string::npos &&
                        g.msg.find("bags closed and readable") != std::string::npos &&
                        g.msg.find("was left open and is not indexed") != std::string::npos);
    EXPECT_TRUE(named) << errors.size() << " errors from /recorder"
                       << (errors.empty() ? "" : ", the first: " + errors.front().msg);
  }
  // Every bag the first recorder closed before the fault reads back whole: full frames,
  // consecutive, in order. rosbag names each split <prefix>_<its date>_<n>, n from 0 for each
  // recorder, so the first recorder's files are those up to the next _0.
  std::vector<std::string> files = filesEndingIn(dir, ".bag");
  for (const auto& f : filesEndingIn(dir, ".bag.active")) files.push_back(f);
  std::sort(files.begin(), files.end());
  std::vector<std::string> bags;
  bool left_open = false;
  for (std::size_t i = 0; i < files.size(); ++i) {
    const bool starts_run = files[i].find("_0.bag") != std::string::npos;
    if (i > 0 && starts_run) break;
    if (files[i].size() > 4 && files[i].compare(files[i].size() - 4, 4, ".bag") == 0) {
      bags.push_back(files[i]);
    } else {
      left_open = true;
    }
  }
  std::string listing;
  for (const auto& f : files) listing += " " + f;
  EXPECT_TRUE(left_open) << "the bag open at the fault stays, unindexed; the folder:" << listing;
  EXPECT_GE(bags.size(), 2u) << "1 MiB splits under a 4 MiB quota; the folder:" << listing;
  std::vector<ros::Time> recorded;
  for (const auto& b : bags) {
    rosbag::Bag bag;
    ASSERT_NO_THROW(bag.open(dir + "/" + b, rosbag::bagmode::Read)) << b << " is not indexed";
    for (const auto& msg : rosbag::View(bag, rosbag::TopicQuery("/camera/image_rect"))) {
      auto im = msg.instantiate<sensor_msgs::Image>();
      ASSERT_TRUE(im);
      EXPECT_EQ(im->data.size(), 640u * 480u * 2u);
      recorded.push_back(im->header.stamp);
    }
  }
  ASSERT_FALSE(recorded.empty());
  const auto first = std::find(stamps.begin(), stamps.end(), recorded.front());
  ASSERT_NE(first, stamps.end());
  ASSERT_LE(static_cast<std::size_t>(stamps.end() - first), stamps.size());
  for (std::size_t i = 0; i < recorded.size(); ++i)
    EXPECT_EQ(recorded[i], *(first + static_cast<long>(i))) << "closed bags: frame " << i;
  std::printf("%zu bags closed before the fault (%zu files in all), frames %ld..%ld of %zu\n",
              bags.size(), files.size(), static_cast<long>(first - stamps.begin()),
              static_cast<long>(first - stamps.begin()) + static_cast<long>(recorded.size()) - 1,
              stamps.size());
  EXPECT_LT(static_cast<long>(first - stamps.begin()) + static_cast<long>(recorded.size()),
            fault_at + 1);

  // The tracking graph: every frame tracked, the same poses as the offline tracker on the frames.
  std::lock_guard<std::mutex> l(m);
  ASSERT_TRUE(info);
  const dt::PinholeIntrinsics K = dtconv::intrinsicsFromCameraInfo(*info);
  Eigen::Isometry3d mount = Eigen::Isometry3d::Identity();
  mount.linear() = Eigen::Quaterniond(0.5, -0.5, 0.5, -0.5).toRotationMatrix();
  dt::Tracker tracker(K, dt::TrackerConfig{}, mount);
  double max_dt = 0, max_dr = 0;
  int tracking = 0;
  for (const auto& t : stamps) {
    ASSERT_TRUE(images.count(t)) << "frame " << t << " not seen";
    const auto& st = status.at(t);
    tracking += st.state_name == "TRACKING";
    const auto fs =
        tracker.track(dtconv::depthFromMsg(*images.at(t), 0.001, dt::DepthRange{}), t.toSec());
    const Eigen::Isometry3d g = dtconv::fromPoseMsg(st.camera_pose);
    max_dt = std::max(max_dt, (fs.T_W_C.translation() - g.translation()).norm());
    max_dr = std::max(max_dr, Eigen::AngleAxisd((fs.T_W_C.inverse() * g).linear()).angle());
  }
  std::printf("graph vs offline tracker over %zu frames: %.3g m, %.3g rad; %d tracking\n",
              stamps.size(), max_dt, max_dr, tracking);
  EXPECT_EQ(tracking, static_cast<int>(stamps.size()));
  EXPECT_LT(max_dt, 1e-6);
  EXPECT_LT(max_dr, 1e-6);
  std::filesystem::remove_all(root);
}

int main(int argc, char** argv) {
  return rig_drivers::test::rostestMain(argc, argv, "test_recording");
}
