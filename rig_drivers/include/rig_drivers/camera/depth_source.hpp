#pragma once
/// A depth camera as the camera node sees it (ROS-free): a device that may be missing, may go away
/// and may come back. Every backend (V4L2, the simulator's renderer, a recorded folder) implements
/// this; CameraLink adds the waiting, the reconnecting and the gap accounting they all share.
#include <cstdint>
#include <string>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

namespace rig_drivers {

/// One frame in metres with its capture time.
struct DepthFrame {
  depth_track::DepthImage depth;
  std::int64_t stamp_ns = 0;  ///< capture time, ns since the Unix epoch (the source's clock)
};

/// What one grab returned.
enum class GrabStatus {
  kFrame,    ///< a frame was filled in
  kNoFrame,  ///< none this time, the device is fine (the reason says why)
  kLost,     ///< the device went away (unplugged, reset, stream stopped): close and reopen
  kEnded,    ///< a finite source is done (a folder played to its end)
};

/// A depth camera device. Called from one thread at a time (CameraLink's caller).
class DepthSource {
 public:
  virtual ~DepthSource() = default;
  /// What the node waits for when the device is missing, for log lines and diagnostics
  /// ("/dev/video0", "poses on /rig_sim/camera_pose").
  virtual std::string device() const = 0;
  /// Opens the device; false with the reason (naming the device and what was tried) in *why.
  virtual bool open(std::string* why) = 0;
  /// Releases the device; safe to call when closed.
  virtual void close() = 0;
  /// Next frame (may block up to about a second waiting for it). *why is set unless kFrame.
  virtual GrabStatus grab(DepthFrame* out, std::string* why) = 0;
  /// Intrinsics of the frames this source delivers.
  virtual depth_track::PinholeIntrinsics intrinsics() const = 0;
};

}  // namespace rig_drivers
