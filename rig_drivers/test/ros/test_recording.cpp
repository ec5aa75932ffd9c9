// rostest: recording exactly as the rig launch files do it. servotrack.launch and
// servotruck.launch include launch/record.launch; this test runs that same file through roslaunch
// (1 MB splits instead of 1 GB) and stops it with SIGINT to roslaunch, as Ctrl-C does: roslaunch
// passes SIGINT on to rosbag record. Every bag left behind must open through its index
// (rosbag::Bag throws on an unindexed bag), no .active file may remain, and the recorded depth
// frames must be contiguous: nothing lost inside the recording, nothing after the stop.
#include <dirent.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <string>
#include <vector>

#include "rig_msgs/TrackState.h"

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
  ASSERT_TRUE(ros::param::get("~record_launch", launch_file)) << "recording.test sets ~record_launch";
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

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_recording");
  ros::NodeHandle nh;
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}
