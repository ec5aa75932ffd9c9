// The `compressedDepth` image_transport publisher / subscriber pair over the codec in
// depth_track/ros/compressed_depth.hpp. Debian packages no compressed_depth_image_transport;
// registering under the community plugin's lookup names (image_transport/compressedDepth_pub,
// _sub) lets every image_transport user here (republish, our ingest, rviz) pick it by the
// transport name, and the wire format lets either end be the community's plugin.
#include <image_transport/simple_publisher_plugin.h>
#include <image_transport/simple_subscriber_plugin.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <pluginlib/class_list_macros.hpp>

#include "depth_track/ros/compressed_depth.hpp"

namespace depth_track {
namespace transport {

/// Publishes `<base>/compressedDepth`. Settings are read per frame (cached parameters, so a
/// `rosparam set` takes effect) from `<base>/compressedDepth/{depth_max, depth_quantization,
/// png_level, format}`, the community plugin's names.
class CompressedDepthPublisher
    : public image_transport::SimplePublisherPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressedDepth"; }

 protected:
  void publish(const sensor_msgs::Image& image, const PublishFn& publish_fn) const override {
    compressed_depth::EncoderConfig c;
    nh().getParamCached("depth_max", c.depth_max);
    nh().getParamCached("depth_quantization", c.depth_quantization);
    nh().getParamCached("png_level", c.png_level);
    nh().getParamCached("format", c.format);
    try {
      publish_fn(compressed_depth::encode(image, c));
    } catch (const std::exception& e) {
      // No exception may escape into the publishing node; the frame is not sent.
      ROS_ERROR_THROTTLE(
          1.0, "compressedDepth: frame at %.3f not sent on %s: %s (parameters in %s)",
          image.header.stamp.toSec(), getTopic().c_str(), e.what(), nh().getNamespace().c_str());
    }
  }
};

/// Subscribes `<base>/compressedDepth` and hands decoded images to the user's callback; a bad
/// payload is dropped with a throttled error naming the topic and the problem.
class CompressedDepthSubscriber
    : public image_transport::SimpleSubscriberPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressedDepth"; }

 protected:
  void internalCallback(const sensor_msgs::CompressedImageConstPtr& message,
                        const Callback& user_cb) override {
    sensor_msgs::ImagePtr image;
    try {
      image = compressed_depth::decode(*message);
    } catch (const std::exception& e) {
      ROS_ERROR_THROTTLE(1.0, "compressedDepth: frame at %.3f on %s dropped: %s",
                         message->header.stamp.toSec(), getTopic().c_str(), e.what());
      return;
    }
    user_cb(image);
  }
};

}  // namespace transport
}  // namespace depth_track

PLUGINLIB_EXPORT_CLASS(depth_track::transport::CompressedDepthPublisher,
                       image_transport::PublisherPlugin)
PLUGINLIB_EXPORT_CLASS(depth_track::transport::CompressedDepthSubscriber,
                       image_transport::SubscriberPlugin)
