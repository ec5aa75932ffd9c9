// The compressedDepth plugins as image_transport loads them (pluginlib, real roscore): an
// image_transport publisher offers <base>/compressedDepth (sensor_msgs/CompressedImage, listed
// by `rostopic list` and `list_transports`); subscribers asking for compressedDepth get 16UC1
// back bit for bit and 32FC1 within the quantisation error, from our publisher and from
// image_transport's republish; a bad payload is dropped and the next good one still arrives.
#include <gtest/gtest.h>
#include <image_transport/image_transport.h>
#include <ros/master.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>

#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <mutex>

#include "depth_track/ros/compressed_depth.hpp"

namespace cd = depth_track::compressed_depth;

namespace {

std::string run(const std::string& cmd) {
  std::string out;
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return out;
  char buf[512];
  while (std::fgets(buf, sizeof(buf), p)) out += buf;
  pclose(p);
  return out;
}

std::string topicType(const std::string& name) {
  ros::master::V_TopicInfo topics;
  ros::master::getTopics(topics);
  for (const auto& t : topics)
    if (t.name == name) return t.datatype;
  return "";
}

/// Collects the images one image_transport subscription delivers.
class Sink {
 public:
  Sink(image_transport::ImageTransport& it, const std::string& base) {
    sub_ =
        it.subscribe(base, 10, &Sink::on, this, image_transport::TransportHints("compressedDepth"));
  }
  std::vector<sensor_msgs::ImageConstPtr> waitFor(std::size_t n, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] { return got_.size() >= n; });
    return got_;
  }
  std::string topic() const { return sub_.getTopic(); }
  uint32_t publishers() const { return sub_.getNumPublishers(); }

 private:
  void on(const sensor_msgs::ImageConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    got_.push_back(m);
    cv_.notify_all();
  }
  image_transport::Subscriber sub_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<sensor_msgs::ImageConstPtr> got_;
};

sensor_msgs::Image depth16(int w, int h, std::uint32_t stamp_s) {
  sensor_msgs::Image img;
  img.header.stamp = ros::Time(stamp_s, 0);
  img.header.frame_id = "camera_depth_optical_frame";
  img.encoding = "16UC1";
  img.width = w;
  img.height = h;
  img.step = 2 * w;
  img.data.resize(img.step * h);
  auto* px = reinterpret_cast<std::uint16_t*>(img.data.data());
  for (int i = 0; i < w * h; ++i) px[i] = static_cast<std::uint16_t>(i % 5 == 0 ? 0 : 3000 + i * 7);
  return img;
}

bool waitConnected(const std::vector<Sink*>& sinks, const ros::Publisher* extra, double timeout_s) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(timeout_s);
  while (ros::WallTime::now() < end) {
    bool all = true;
    for (auto* s : sinks) all = all && s->publishers() > 0;
    if (extra) all = all && extra->getNumSubscribers() > 0;
    if (all) {
      ros::WallDuration(0.5).sleep();
      return true;
    }
    ros::WallDuration(0.05).sleep();
  }
  return false;
}

}  // namespace

TEST(CompressedDepthTransport, PublishedListedAndDecoded) {
  ros::NodeHandle nh;
  image_transport::ImageTransport it(nh);
  image_transport::Publisher pub = it.advertise("/cd_test/depth", 10);
  Sink direct(it, "/cd_test/depth"), republished(it, "/cd_test/republished");
  EXPECT_EQ(direct.topic(), "/cd_test/depth/compressedDepth");
  ASSERT_TRUE(waitConnected({&direct, &republished}, nullptr, 30.0))
      << "no compressedDepth publisher connected (republish running? plugin found?)";

  EXPECT_EQ(topicType("/cd_test/depth/compressedDepth"), "sensor_msgs/CompressedImage");
  EXPECT_EQ(topicType("/cd_test/republished/compressedDepth"), "sensor_msgs/CompressedImage");
  const std::string listed = run("rostopic list");
  EXPECT_NE(listed.find("/cd_test/depth/compressedDepth\n"), std::string::npos) << listed;
  EXPECT_NE(listed.find("/cd_test/republished/compressedDepth\n"), std::string::npos) << listed;
  const std::string transports = run("rosrun image_transport list_transports");
  EXPECT_NE(transports.find("image_transport/compressedDepth"), std::string::npos) << transports;
  EXPECT_EQ(transports.find("***"), std::string::npos)
      << "a plugin that does not load: " << transports;

  const sensor_msgs::Image a = depth16(640, 480, 10);
  sensor_msgs::Image b;  // 32FC1 metres
  b.header.stamp = ros::Time(11, 0);
  b.encoding = "32FC1";
  b.width = 4;
  b.height = 1;
  b.step = 16;
  const float zb[4] = {0.5f, 2.0f, 5.0f, NAN};
  b.data.resize(16);
  std::memcpy(b.data.data(), zb, 16);
  // republish keeps one message in its queues: one frame at a time.
  pub.publish(a);
  for (Sink* s : {&direct, &republished}) s->waitFor(1, 10.0);
  pub.publish(b);
  for (Sink* s : {&direct, &republished}) {
    const auto got = s->waitFor(2, 10.0);
    ASSERT_EQ(got.size(), 2u) << s->topic();
    EXPECT_EQ(got[0]->encoding, "16UC1");
    EXPECT_EQ(got[0]->header.stamp, a.header.stamp);
    EXPECT_EQ(got[0]->header.frame_id, a.header.frame_id);
    EXPECT_TRUE(got[0]->data == a.data) << s->topic() << ": 16UC1 not bit for bit";
    ASSERT_EQ(got[1]->encoding, "32FC1");
    float z[4];
    std::memcpy(z, got[1]->data.data(), 16);
    for (int i = 0; i < 3; ++i)
      EXPECT_NEAR(z[i], zb[i], cd::maxQuantisationError(zb[i], cd::EncoderConfig{}) + 1e-6) << i;
    EXPECT_TRUE(std::isnan(z[3]));
  }
}

TEST(CompressedDepthTransport, BadPayloadIsDroppedAndTheNextArrives) {
  ros::NodeHandle nh;
  image_transport::ImageTransport it(nh);
  ros::Publisher raw =
      nh.advertise<sensor_msgs::CompressedImage>("/cd_test/bad/compressedDepth", 10);
  Sink sink(it, "/cd_test/bad");
  ASSERT_TRUE(waitConnected({&sink}, &raw, 30.0));
  sensor_msgs::CompressedImage good = cd::encode(depth16(32, 24, 20), cd::EncoderConfig{});
  sensor_msgs::CompressedImage truncated = good;
  truncated.data.resize(good.data.size() / 2);
  sensor_msgs::CompressedImage jpeg = good;
  jpeg.format = "rgb8; jpeg compressed bgr8";
  raw.publish(truncated);
  raw.publish(jpeg);
  good.header.stamp = ros::Time(21, 0);
  raw.publish(good);
  const auto got = sink.waitFor(1, 10.0);
  ros::WallDuration(0.5).sleep();  // anything the bad ones might have produced arrives by now
  const auto all = sink.waitFor(2, 0.0);
  ASSERT_EQ(all.size(), 1u) << "only the good payload decodes";
  EXPECT_EQ(all[0]->header.stamp, good.header.stamp);
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "dt_test_compressed_depth_ros");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}
