// Bag check of the rig simulator: a short generated scenario bag has the expected topics, message
// counts and monotonic stamps, every connection carries its type for other readers, its depth is
// 16UC1 L515 data within the camera's range, and it is deterministic. Whether the rig readings in
// such a bag agree with its ground truth is checked by dt_test_evaluate_bag (sensor errors within
// their physical bounds) and rig_test_rig_sim. Runs make_scenario_bag (no roscore needed).
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <rig_msgs/CarriageSensors.h>
#include <rig_msgs/RawFrame.h>
#include <rig_msgs/TrackState.h>
#include <rig_msgs/TruckRc.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#ifndef MAKE_SCENARIO_BAG
#error "MAKE_SCENARIO_BAG must name the make_scenario_bag executable"
#endif
#ifndef RIG_SCENARIO_DIR
#error "RIG_SCENARIO_DIR must name config/scenarios"
#endif

namespace {

constexpr int kFrames = 24;  // 0.8 s of a 30 Hz run: enough for every stream, quick to render

std::string tmpDir() {
  char tmpl[] = "/tmp/rig_sim_bag_XXXXXX";
  const char* d = mkdtemp(tmpl);
  return d ? d : "/tmp";
}

std::string makeBag(const std::string& scenario, const std::string& dir,
                    const std::string& compression = "lz4") {
  const std::string cmd = std::string(MAKE_SCENARIO_BAG) + " --scenario " + RIG_SCENARIO_DIR + "/" +
                          scenario + ".yaml --out-dir " + dir + " --max-frames " +
                          std::to_string(kFrames) + " --compression " + compression + " > " + dir +
                          "/log.txt 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
  return dir + "/" + scenario + ".bag";
}

struct TopicStats {
  int count = 0;
  bool monotonic = true;  ///< receive times and header stamps never go backwards
  ros::Time first, last;
};

std::map<std::string, TopicStats> scan(const std::string& path) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  std::map<std::string, TopicStats> out;
  std::map<std::string, ros::Time> last_header;
  for (const rosbag::MessageInstance& m : view) {
    TopicStats& s = out[m.getTopic()];
    if (s.count > 0 && m.getTime() < s.last) s.monotonic = false;
    if (s.count == 0) s.first = m.getTime();
    s.last = m.getTime();
    ++s.count;
    ros::Time h;
    bool has = true;
    if (auto p = m.instantiate<sensor_msgs::Image>())
      h = p->header.stamp;
    else if (auto p = m.instantiate<rig_msgs::TrackState>())
      h = p->header.stamp;
    else if (auto p = m.instantiate<rig_msgs::CarriageSensors>())
      h = p->header.stamp;
    else if (auto p = m.instantiate<rig_msgs::TruckRc>())
      h = p->header.stamp;
    else if (auto p = m.instantiate<geometry_msgs::PoseStamped>())
      h = p->header.stamp;
    else
      has = false;
    if (has) {
      auto it = last_header.find(m.getTopic());
      if (it != last_header.end() && h <= it->second) s.monotonic = false;
      last_header[m.getTopic()] = h;
    }
  }
  return out;
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(ScenarioBag, ServoTrackRunHasEveryTopicAtItsRate) {
  const std::string dir = tmpDir();
  const auto topics = scan(makeBag("RT3", dir));
  for (const char* t :
       {"/camera/image_rect", "/camera/camera_info", "/rig_sim/camera_pose", "/tf", "/tf_static",
        "/track_state", "/link_timing", "/raw_frames", "/carriage_sensors"}) {
    ASSERT_TRUE(topics.count(t)) << "missing topic " << t;
    EXPECT_TRUE(topics.at(t).monotonic) << t << " stamps go backwards";
  }
  EXPECT_EQ(topics.at("/camera/image_rect").count, kFrames);
  EXPECT_EQ(topics.at("/camera/camera_info").count, kFrames);
  EXPECT_EQ(topics.at("/rig_sim/camera_pose").count, kFrames);
  EXPECT_EQ(topics.at("/tf").count, kFrames);
  EXPECT_EQ(topics.at("/tf_static").count, 1);
  // The boards stream at 30 Hz from power-on: count = 30 Hz x recorded span, +-2 at the ends.
  for (const char* t : {"/track_state", "/carriage_sensors"}) {
    const TopicStats& s = topics.at(t);
    const double span = (s.last - s.first).toSec();
    EXPECT_GT(span, kFrames / 30.0) << t;
    EXPECT_NEAR(s.count, span * 30.0 + 1.0, 2.0) << t;
  }
  // Camera frames are 1/30 s apart.
  const TopicStats& img = topics.at("/camera/image_rect");
  EXPECT_NEAR((img.last - img.first).toSec(), (kFrames - 1) / 30.0, 1e-3);
}

TEST(ScenarioBag, EveryConnectionCarriesItsTypeForOtherReaders) {
  // rosbag's Python reader (rosbag info/play) needs type, md5sum and definition on every
  // connection, including the latched /tf_static written with a custom connection header.
  rosbag::Bag bag(makeBag("RT1", tmpDir()), rosbag::bagmode::Read);
  rosbag::View view(bag);
  int latched = 0;
  for (const rosbag::ConnectionInfo* c : view.getConnections()) {
    ASSERT_TRUE(c->header);
    for (const char* field : {"type", "md5sum", "message_definition"}) {
      EXPECT_TRUE(c->header->count(field)) << c->topic << " lacks " << field;
    }
    EXPECT_EQ(c->header->at("md5sum"), c->md5sum) << c->topic;
    if (c->header->count("latching") && c->header->at("latching") == "1") ++latched;
  }
  EXPECT_EQ(latched, 1);  // /tf_static only
}

TEST(ScenarioBag, ImagesAreL515DepthOfTheChairRoom) {
  const std::string dir = tmpDir();
  rosbag::Bag bag(makeBag("RT1", dir), rosbag::bagmode::Read);
  rosbag::View view(bag, rosbag::TopicQuery("/camera/image_rect"));
  int n = 0;
  for (const rosbag::MessageInstance& m : view) {
    auto img = m.instantiate<sensor_msgs::Image>();
    ASSERT_TRUE(img);
    EXPECT_EQ(img->encoding, "16UC1");
    EXPECT_EQ(img->width, 640u);
    EXPECT_EQ(img->height, 480u);
    EXPECT_EQ(img->step, 1280u);
    EXPECT_EQ(img->header.frame_id, "camera_depth_optical_frame");
    // The room is closed (walls within 4 m): most pixels return; values in 0.25 mm units stay
    // inside the L515 range 0.53..4.0 m.
    const uint16_t* d = reinterpret_cast<const uint16_t*>(img->data.data());
    int valid = 0;
    for (std::size_t i = 0; i < img->width * img->height; ++i) {
      if (d[i] == 0) continue;
      ++valid;
      ASSERT_GE(d[i] * 0.00025, 0.53 - 1e-9);
      ASSERT_LE(d[i] * 0.00025, 4.0 + 1e-9);
    }
    EXPECT_GT(valid, 640 * 480 / 2);
    ++n;
  }
  EXPECT_EQ(n, kFrames);
}

TEST(ScenarioBag, TruckRunHasRcStreamAndGroundTruth) {
  const std::string dir = tmpDir();
  const std::string path = makeBag("Chair3", dir);
  const auto topics = scan(path);
  for (const char* t :
       {"/camera/image_rect", "/rig_sim/camera_pose", "/truck_rc", "/raw_frames", "/tf_static"}) {
    ASSERT_TRUE(topics.count(t)) << "missing topic " << t;
    EXPECT_TRUE(topics.at(t).monotonic) << t;
  }
  EXPECT_EQ(topics.at("/camera/image_rect").count, kFrames);
  EXPECT_FALSE(topics.count("/track_state"));
}

TEST(ScenarioBag, SameScenarioGivesTheSameBag) {
  const std::string a = makeBag("XTest1_05_Chair", tmpDir(), "none");
  const std::string b = makeBag("XTest1_05_Chair", tmpDir(), "none");
  const std::string da = slurp(a), db = slurp(b);
  ASSERT_GT(da.size(), 1000u);
  EXPECT_TRUE(da == db) << "bags differ: " << a << " " << b;
}

}  // namespace

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
