#pragma once
/// A RealSense-class camera's depth node through the V4L2 ioctl/mmap interface (Z16, no vendor
/// SDK), as a DepthSource: open() fails with the reason while the device is missing, grab()
/// reports kLost when the device disappears (unplugged, USB reset). ROS-free.
#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include "rig_drivers/camera/depth_source.hpp"

namespace rig_drivers {

class V4l2Source : public DepthSource {
 public:
  /// `device_scale_m`: metres per Z16 unit (L515 0.00025, D4xx 0.001). `K`: the stream's size and
  /// intrinsics; `range`: readings outside it become "no return".
  V4l2Source(std::string device, const depth_track::PinholeIntrinsics& K, double device_scale_m,
             const depth_track::DepthRange& range);
  ~V4l2Source() override;
  std::string device() const override { return device_; }
  bool open(std::string* why) override;
  void close() override;
  /// Waits up to 1 s for a frame; stamps it with the system clock at dequeue.
  GrabStatus grab(DepthFrame* out, std::string* why) override;
  depth_track::PinholeIntrinsics intrinsics() const override { return K_; }

 private:
  bool setUp(std::string* why);
  int xioctl(unsigned long request, void* arg);

  std::string device_;
  depth_track::PinholeIntrinsics K_;
  double scale_m_;
  depth_track::DepthRange range_;
  int fd_ = -1;
  bool streaming_ = false;
  std::size_t stride_ = 0;
  std::vector<std::pair<void*, std::size_t>> buffers_;
};

}  // namespace rig_drivers
