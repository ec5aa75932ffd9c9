// rostest: the rig launch files as an owner runs them on a fresh machine, through roslaunch.
//  - servotrack.launch / servotruck.launch sim:=true with a bag folder that does not exist: the
//    folder is made, recording starts with the drivers, and after Ctrl-C the bags hold the camera,
//    camera_info, sensor and tf topics, every frame the camera published while recording.
//  - servotrack.launch with no device at all: every node stays up and its diagnostics say what it
//    waits for; a depth camera whose device (the simulator's pose stream, fed by this test)
//    appears, goes and comes back streams again without a restart, and the gap is counted from the
//    frames' stamps.
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <topic_tools/shape_shifter.h>

#include <limits.h>
#include <stdlib.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "launch_tools.hpp"

using namespace rig_drivers::test;

namespace {

/// The repository's launch folder, symlinks resolved: roslaunch resolves a launch file's own
/// relative paths from the name it was given.
std::string launchDir() {
  std::string d;
  ros::param::get("~launch_dir", d);
  char real[PATH_MAX];
  return ::realpath(d.c_str(), real) ? real : d;
}

/// Counts messages of any type on a topic, and keeps the image stamps.
class Counter {
 public:
  void image(const std::string& topic) {
    subs_.push_back(
        nh_.subscribe<sensor_msgs::Image>(topic, 100,
                                          boost::function<void(const sensor_msgs::ImageConstPtr&)>(
                                              [this, topic](const sensor_msgs::ImageConstPtr& m) {
                                                std::lock_guard<std::mutex> l(m_);
                                                ++n_[topic];
                                                stamps_.push_back(m->header.stamp);
                                              })));
  }
  void any(const std::string& topic) {
    subs_.push_back(nh_.subscribe<topic_tools::ShapeShifter>(
        topic, 100,
        boost::function<void(const topic_tools::ShapeShifter::ConstPtr&)>(
            [this, topic](const topic_tools::ShapeShifter::ConstPtr&) {
              std::lock_guard<std::mutex> l(m_);
              ++n_[topic];
            })));
  }
  int count(const std::string& t) {
    std::lock_guard<std::mutex> l(m_);
    return n_[t];
  }
  std::vector<ros::Time> stamps() {
    std::lock_guard<std::mutex> l(m_);
    return stamps_;
  }

 private:
  ros::NodeHandle nh_;
  std::vector<ros::Subscriber> subs_;
  std::mutex m_;
  std::map<std::string, int> n_;
  std::vector<ros::Time> stamps_;
};

/// Runs `launch_file` sim:=true into a bag folder that does not exist yet, waits for 30 camera
/// frames and every `topics` entry, stops it with Ctrl-C and checks what was recorded.
void recordsFromTheStart(const std::string& launch_file, const std::string& scenario,
                         const std::vector<std::string>& topics) {
  const std::string tmp = tempDir("rig_launch_rec");
  const std::string bag_dir = tmp + "/home/rig_bags";  // neither folder exists
  Counter c;
  c.image("/camera/image_rect");
  for (const auto& t : topics) c.any(t);
  Diagnostics diag;
  const ros::WallTime t0 = ros::WallTime::now();
  Child launch({"roslaunch", launchDir() + "/" + launch_file, "sim:=true", "scenario:=" + scenario,
                "bag_dir:=" + bag_dir, "sim_link_dir:=" + tmp + "/sim"});
  ASSERT_TRUE(waitUntil([&] { return !filesEndingIn(bag_dir, ".bag.active").empty(); }, 60))
      << "no bag in " << bag_dir;
  std::printf("%s: a bag in %s %.1f s after roslaunch started\n", launch_file.c_str(),
              bag_dir.c_str(), (ros::WallTime::now() - t0).toSec());
  EXPECT_TRUE(diag.waitFor("recorder: recording", "recording into " + bag_dir + "/", 30))
      << diag.describe("recorder: recording");
  const bool flowing = waitUntil(
      [&] {
        bool all = c.count("/camera/image_rect") >= 30;
        for (const auto& t : topics) all = all && c.count(t) > 0;
        return all;
      },
      90);
  ASSERT_TRUE(launch.stop(30)) << "roslaunch did not stop within 30 s of Ctrl-C";
  ASSERT_TRUE(flowing) << c.count("/camera/image_rect") << " frames";

  EXPECT_TRUE(filesEndingIn(bag_dir, ".active").empty()) << "a bag was left open";
  const auto bags = filesEndingIn(bag_dir, ".bag");
  ASSERT_FALSE(bags.empty()) << "no bag in " << bag_dir;
  std::map<std::string, int> n;
  std::set<ros::Time> recorded;
  for (const auto& b : bags) {
    for (const auto& [topic, count] : topicCounts(bag_dir + "/" + b)) n[topic] += count;
    rosbag::Bag bag(bag_dir + "/" + b, rosbag::bagmode::Read);
    for (const auto& m : rosbag::View(bag, rosbag::TopicQuery("/camera/image_rect")))
      if (auto im = m.instantiate<sensor_msgs::Image>()) recorded.insert(im->header.stamp);
  }
  for (const auto& t : topics) EXPECT_GT(n[t], 0) << t << " not recorded";
  EXPECT_NEAR(n["/camera/camera_info"], n["/camera/image_rect"], 1);  // the stop may fall between
  // Recording from the start: the recorder had the camera's first frames, and every frame the
  // camera published after its first recorded one is in the bags.
  const auto seen = c.stamps();
  ASSERT_FALSE(recorded.empty());
  std::size_t first = 0;
  while (first < seen.size() && seen[first] < *recorded.begin()) ++first;
  std::printf("%s: %zu frames recorded, the first is the camera's frame %zu\n", launch_file.c_str(),
              recorded.size(), first);
  EXPECT_EQ(first, 0u) << "the recorder missed the camera's first frames";
  int missing = 0;
  for (std::size_t i = first; i < seen.size() && seen[i] <= *recorded.rbegin(); ++i)
    missing += !recorded.count(seen[i]);
  EXPECT_EQ(missing, 0);
  std::filesystem::remove_all(tmp);
}

}  // namespace

TEST(RigLaunch, ServoTrackSimRecordsFromTheStartIntoAFolderItMakes) {
  recordsFromTheStart("servotrack.launch", "RT1",
                      {"/camera/camera_info", "/track_state", "/carriage_sensors", "/link_timing",
                       "/raw_frames", "/tf", "/rig_sim/camera_pose"});
}

TEST(RigLaunch, ServoTruckSimRecordsFromTheStartIntoAFolderItMakes) {
  recordsFromTheStart(
      "servotruck.launch", "Chair3",
      {"/camera/camera_info", "/truck_rc", "/raw_frames", "/tf", "/rig_sim/camera_pose"});
}

TEST(RigLaunch, NoDevicesEveryNodeWaitsAndTheCameraComesBack) {
  const std::string tmp = tempDir("rig_launch_nodev");
  const std::string dev = tmp + "/dev", bag_dir = tmp + "/rig_bags";
  Diagnostics diag;
  const ros::WallTime t0 = ros::WallTime::now();
  Child launch({"roslaunch", launchDir() + "/servotrack.launch", "track_port:=" + dev + "/ttyACM0",
                "car_port:=" + dev + "/ttyUSB0", "camera_device:=" + dev + "/video0",
                "bag_dir:=" + bag_dir});
  // A second camera whose "device" is a pose stream this test feeds: it can appear and go.
  Child camera({"rosrun", "rig_drivers", "depth_camera", "__name:=fake_camera",
                "image_rect:=/fake/image_rect", "camera_info:=/fake/camera_info", "_backend:=sim",
                "_pose_topic:=/fake/pose", "_noise:=none", "_retry_period_s:=0.1",
                "_stale_timeout_s:=0.5"});
  using S = diagnostic_msgs::DiagnosticStatus;
  const std::vector<std::pair<std::string, std::string>> waits = {
      {"track_host: board link", "waiting for " + dev + "/ttyACM0: cannot open serial device"},
      {"car_host: board link", "waiting for " + dev + "/ttyUSB0: cannot open serial device"},
      {"depth_camera: depth camera",
       "waiting for " + dev + "/video0: cannot open " + dev + "/video0: No such file or directory"},
      {"fake_camera: depth camera", "waiting for poses on /fake/pose: no pose yet"},
      {"recorder: recording", "recording into " + bag_dir + "/"}};
  for (const auto& [name, text] : waits)
    EXPECT_TRUE(diag.waitFor(name, text, 60)) << name << ": " << diag.describe(name);
  // Still up and still saying so 10 s after the launch.
  const double left = 10.0 - (ros::WallTime::now() - t0).toSec();
  if (left > 0) ros::WallDuration(left).sleep();
  ros::WallDuration(1.5).sleep();  // a fresh round of diagnostics (1 s period)
  for (const auto& node :
       {"/track_host", "/car_host", "/depth_camera", "/recorder", "/fake_camera"})
    EXPECT_GT(nodePid(node), 0) << node << " is not running";
  for (const auto& [name, text] : waits)
    EXPECT_TRUE(diag.has(name, text)) << name << ": " << diag.describe(name);
  EXPECT_EQ(diag.get("track_host: board link")->level, S::WARN);
  EXPECT_EQ(diag.get("depth_camera: depth camera")->level, S::WARN);
  EXPECT_NE(diag.describe("recorder: recording").find("waiting for publishers on"),
            std::string::npos)
      << diag.describe("recorder: recording");
  EXPECT_EQ(::access(bag_dir.c_str(), F_OK), 0) << "the bag folder was not made";

  // The fake device appears: frames flow from the same process.
  ros::NodeHandle nh;
  auto pose_pub = nh.advertise<geometry_msgs::PoseStamped>("/fake/pose", 10);
  std::mutex m;
  std::vector<ros::Time> got;
  auto sub =
      nh.subscribe<sensor_msgs::Image>("/fake/image_rect", 100,
                                       boost::function<void(const sensor_msgs::ImageConstPtr&)>(
                                           [&](const sensor_msgs::ImageConstPtr& im) {
                                             std::lock_guard<std::mutex> l(m);
                                             got.push_back(im->header.stamp);
                                           }));
  const int pid = nodePid("/fake_camera");
  ASSERT_GT(pid, 0);
  ASSERT_TRUE(waitUntil(
      [&] { return sub.getNumPublishers() > 0 && pose_pub.getNumSubscribers() > 0; }, 30));
  const ros::Time T0 = ros::Time::now();
  auto stampOf = [&](int k) { return T0 + ros::Duration(k / 30.0); };
  // Frame k: the pose 0.8 m up looking at the chair, moving 2 mm along the view per frame.
  auto feed = [&](int k) {
    pose_pub.publish(chairViewPose(stampOf(k), 0.002 * k, 0.0));
    return waitUntil(
        [&] {
          std::lock_guard<std::mutex> l(m);
          return !got.empty() && got.back() == stampOf(k);
        },
        10);
  };
  for (int k = 0; k < 30; ++k) ASSERT_TRUE(feed(k)) << "no frame for pose " << k;
  EXPECT_TRUE(
      diag.waitFor("fake_camera: depth camera", "streaming from poses on /fake/pose", 5, S::OK))
      << diag.describe("fake_camera: depth camera");
  // It goes: lost after the stale timeout, and said so.
  EXPECT_TRUE(diag.waitFor("fake_camera: depth camera", "to come back", 10, S::ERROR))
      << diag.describe("fake_camera: depth camera");
  // And comes back 1.5 s of stamps later: frames again, the 45 frames between counted. The stream
  // is fed on until the diagnostics show the frames after the gap (it would be lost again when
  // fed no more).
  for (int k = 75; k < 105; ++k) ASSERT_TRUE(feed(k)) << "no frame for pose " << k;
  int k = 105;
  const std::string cam = "fake_camera: depth camera";
  while (k < 400 &&
         !(diag.has(cam, "streaming", S::OK) && std::atoi(diag.value(cam, "frames").c_str()) >= 60))
    ASSERT_TRUE(feed(k++)) << "no frame for pose " << k - 1;
  EXPECT_EQ(nodePid("/fake_camera"), pid) << "the camera was restarted";
  EXPECT_EQ(diag.value(cam, "frames missing in gaps"), "45");
  EXPECT_EQ(diag.value(cam, "losses"), "1");
  EXPECT_EQ(diag.value(cam, "reconnects"), "1");
  {
    std::lock_guard<std::mutex> l(m);
    ASSERT_EQ(got.size(), static_cast<std::size_t>(k - 75 + 30)) << "one frame per pose";
    EXPECT_EQ(got[29], stampOf(29));
    EXPECT_EQ(got[30], stampOf(75)) << "the gap shows in the stamps";
  }
  EXPECT_TRUE(camera.stop(20));
  EXPECT_TRUE(launch.stop(30));
  std::filesystem::remove_all(tmp);
}

int main(int argc, char** argv) { return rostestMain(argc, argv, "test_rig_launch"); }
