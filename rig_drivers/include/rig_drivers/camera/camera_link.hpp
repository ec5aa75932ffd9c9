#pragma once
/// The camera node's device layer (ROS-free): waits for a DepthSource that is missing, reopens it
/// after it went away, and counts the frames missing across each gap from the frames' own stamps.
/// Shared by every backend, so the V4L2 camera and the simulator's behave alike.
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "rig_drivers/camera/depth_source.hpp"

namespace rig_drivers {

/// Settings of the device layer (the camera node's ~retry_period_s, ~stale_timeout_s, ~rate_hz).
struct CameraLinkConfig {
  double retry_period_s = 0.5;  ///< period of open attempts while the device is missing, s
  double stale_timeout_s =
      2.0;                ///< an open device without a frame this long is lost, s (0 = never)
  double rate_hz = 30.0;  ///< nominal frame rate the gap is counted at, Hz
  /// Every problem with these settings (empty = valid).
  std::vector<std::string> validate() const;
};

/// Where the link stands.
enum class CameraState {
  kWaiting,    ///< never opened yet: waiting for the device
  kStreaming,  ///< open
  kLost,       ///< was open, went away: reopening
  kEnded,      ///< a finite source is done
};

/// Transitions, each reported once (never per frame or per failed retry with the same reason).
struct CameraEvent {
  enum Type {
    kWaiting,  ///< an open attempt failed (first time, or for a new reason)
    kOpened,   ///< the device opened (first time or again after a loss)
    kLost,     ///< an open device went away
    kResumed,  ///< first frame after a loss: the message gives the gap
    kEnded,    ///< the source ended
  } type = kWaiting;
  std::string message;
};

/// Counters since the start.
struct CameraLinkStats {
  std::uint64_t frames = 0;        ///< frames delivered
  std::uint64_t failed_opens = 0;  ///< open attempts that failed
  std::uint64_t losses = 0;        ///< times an open device went away
  std::uint64_t reconnects = 0;    ///< times it was opened again after a loss
  std::uint64_t gap_frames = 0;    ///< frames missing across all gaps, at rate_hz by stamps
  double last_gap_s = 0.0;         ///< stamp difference across the latest gap, s
};

class CameraLink {
 public:
  using EventHandler = std::function<void(const CameraEvent& event)>;

  /// Throws std::invalid_argument on an invalid config or a null source. Opens nothing yet.
  CameraLink(CameraLinkConfig config, std::unique_ptr<DepthSource> source, EventHandler on_event);
  ~CameraLink();
  CameraLink(const CameraLink&) = delete;
  CameraLink& operator=(const CameraLink&) = delete;

  /// One step at time now_s (a monotonic clock, s): opens the device when it is closed and an
  /// attempt is due, then, when `out` is given and the device is open, grabs. True when *out holds
  /// a new frame. A null `out` only keeps the device open (a triggered camera between triggers).
  /// Not thread-safe: one caller at a time.
  bool step(double now_s, DepthFrame* out);
  /// Closes the device (the node shuts down).
  void close();

  CameraState state() const { return state_; }
  const CameraLinkStats& stats() const { return stats_; }
  /// One line for diagnostics: what the link does or waits for, and why.
  std::string status() const;
  /// Why the latest step delivered no frame (empty after a frame).
  const std::string& lastProblem() const { return last_problem_; }
  /// Seconds until the next open attempt is due (0 when open or due now).
  double secondsToRetry(double now_s) const;
  DepthSource& source() { return *source_; }
  const CameraLinkConfig& config() const { return config_; }

 private:
  bool tryOpen(double now_s);
  void lose(double now_s, const std::string& why);
  void countGap(std::int64_t stamp_ns);
  void emit(CameraEvent::Type type, const std::string& message);

  CameraLinkConfig config_;
  std::unique_ptr<DepthSource> source_;
  EventHandler on_event_;
  CameraState state_ = CameraState::kWaiting;
  CameraLinkStats stats_;
  bool open_ = false;
  bool gap_pending_ = false;     ///< lost after a stamped frame: count the gap at the next one
  double next_open_s_ = -1e300;  ///< time of the next open attempt
  double last_frame_s_ = 0.0;    ///< link time of the last frame (or of the open)
  double lost_at_s_ = 0.0;       ///< link time of the latest loss
  std::int64_t last_stamp_ns_ = 0;
  std::string open_why_;  ///< reason of the latest failed open
  std::string lost_why_;  ///< reason of the latest loss
  std::string end_why_;
  std::string last_problem_;
};

}  // namespace rig_drivers
