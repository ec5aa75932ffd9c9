#pragma once
// The depth_camera node's ROS-side sources (the V4L2 one is ROS-free, rig_camera):
//   SimSource  renders depth_track's analytic scene from the simulator's true camera pose (T_W_C
//              on ~pose_topic) with a noise model; its "device" is that pose stream: missing until
//              the first pose, lost when the poses stop, back when they resume.
//   TumSource  plays a recorded sequence folder at its timestamps (TUM RGB-D or 7-Scenes layout).
// Both implement rig_drivers::DepthSource, so CameraLink waits for and reconnects them as it does
// a V4L2 camera.
#include <geometry_msgs/PoseStamped.h>
#include <ros/ros.h>

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/sim/scene.hpp"
#include "depth_track/core/tum_cameras.hpp"
#include "depth_track/core/tum_io.hpp"
#include "rig_drivers/camera/depth_source.hpp"

namespace rig_drivers {

namespace dt = depth_track;

inline std::int64_t stampNs(const ros::Time& t) { return static_cast<std::int64_t>(t.toNSec()); }

// ---- sim ------------------------------------------------------------------------------------
class SimSource : public DepthSource {
 public:
  /// `repeat`: every grab renders the latest pose, new or not (one frame per trigger); otherwise
  /// each pose is rendered once and grab waits up to 0.1 s for the next. `static_pose` (7 numbers,
  /// T_W_C) replaces the topic: a still camera rendered at `rate_hz`, stamped on the host clock.
  SimSource(ros::NodeHandle& nh, const std::string& scene, const dt::sim::NoiseConfig& noise,
            const std::string& pose_topic, const std::vector<double>& static_pose,
            std::uint64_t seed, const dt::DepthRange& range, bool repeat, double rate_hz)
      : noise_(noise), seed_(seed), range_(range), repeat_(repeat), rate_hz_(rate_hz) {
    if (scene == "chair_room") {
      scene_ = dt::sim::chairRoomScene();
    } else if (scene == "furnished_room") {
      scene_ = dt::sim::furnishedRoomScene();
    } else if (scene == "hall") {
      scene_ = dt::sim::hallwayScene();
    } else if (scene == "calibration_target") {
      scene_ = dt::sim::calibrationTargetScene();
    } else {
      throw std::runtime_error("sim backend: unknown ~scene '" + scene +
                               "' (chair_room, furnished_room, hall, calibration_target)");
    }
    pose_topic_ = pose_topic;
    if (!static_pose.empty()) {  // fixed pose [x y z qx qy qz qw] (metres, T_W_C)
      geometry_msgs::PoseStamped p;
      p.pose.position.x = static_pose[0];
      p.pose.position.y = static_pose[1];
      p.pose.position.z = static_pose[2];
      p.pose.orientation.x = static_pose[3];
      p.pose.orientation.y = static_pose[4];
      p.pose.orientation.z = static_pose[5];
      p.pose.orientation.w = static_pose[6];
      onPose(p);
      if (pose_seq_ == 0)
        throw std::runtime_error("sim backend: ~static_pose has a zero quaternion");
      static_ = true;
    } else {
      sub_ = nh.subscribe(pose_topic, 10, &SimSource::onPose, this);
    }
  }
  std::string device() const override {
    return static_ ? "~static_pose" : "poses on " + pose_topic_;
  }
  bool open(std::string* why) override {
    std::lock_guard<std::mutex> l(mutex_);
    if (static_ || pose_seq_ > closed_at_seq_) return true;
    *why = closed_at_seq_ == 0 ? "no pose yet (is rig_sim running?)"
                               : "no new pose since the stream stopped";
    return false;
  }
  void close() override {
    std::lock_guard<std::mutex> l(mutex_);
    closed_at_seq_ = pose_seq_;
  }
  GrabStatus grab(DepthFrame* out, std::string* why) override {
    Eigen::Isometry3d T_W_C;
    ros::Time stamp;
    if (static_) {
      paceStatic();
      std::lock_guard<std::mutex> l(mutex_);
      T_W_C = T_W_C_;
      stamp = ros::Time::now();
    } else {
      std::unique_lock<std::mutex> l(mutex_);
      if (!repeat_)
        cv_.wait_for(l, std::chrono::milliseconds(100),
                     [this] { return pose_seq_ != rendered_seq_; });
      if (pose_seq_ == 0 || (!repeat_ && pose_seq_ == rendered_seq_)) {
        *why = "no new pose on " + pose_topic_;
        return GrabStatus::kNoFrame;
      }
      rendered_seq_ = pose_seq_;
      T_W_C = T_W_C_;
      stamp = pose_stamp_.isZero() ? ros::Time::now() : pose_stamp_;
    }
    const auto clean = dt::sim::renderDepth(scene_, K_, T_W_C, range_);
    out->depth = dt::sim::applyNoise(clean, noise_, dt::sim::frameSeed(seed_, index_++), range_);
    // Stamp = the pose's time: the frame shows the scene exactly as seen from that pose.
    out->stamp_ns = stampNs(stamp);
    return GrabStatus::kFrame;
  }
  dt::PinholeIntrinsics intrinsics() const override { return K_; }

 private:
  void onPose(const geometry_msgs::PoseStamped& p) {
    const auto& q = p.pose.orientation;
    Eigen::Quaterniond qd(q.w, q.x, q.y, q.z);
    if (!(qd.norm() > 1e-6) || !std::isfinite(qd.norm())) {
      ROS_WARN_THROTTLE(5, "sim: ignoring a pose with an invalid quaternion on %s",
                        pose_topic_.c_str());
      return;
    }
    {
      std::lock_guard<std::mutex> l(mutex_);
      T_W_C_ = Eigen::Isometry3d::Identity();
      T_W_C_.linear() = qd.normalized().toRotationMatrix();
      T_W_C_.translation() << p.pose.position.x, p.pose.position.y, p.pose.position.z;
      pose_stamp_ = p.header.stamp;
      ++pose_seq_;
    }
    cv_.notify_all();
  }
  /// A still camera delivers at its frame rate, as a real one does.
  void paceStatic() {
    const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(1.0 / rate_hz_));
    const auto now = std::chrono::steady_clock::now();
    if (next_static_ > now) std::this_thread::sleep_until(next_static_);
    next_static_ = std::max(now, next_static_) + period;
  }

  dt::sim::Scene scene_;
  dt::PinholeIntrinsics K_ = dt::sim::l515Intrinsics();
  dt::sim::NoiseConfig noise_;
  std::uint64_t seed_;
  std::uint64_t index_ = 0;
  dt::DepthRange range_;
  bool repeat_;
  double rate_hz_;
  bool static_ = false;
  ros::Subscriber sub_;
  std::string pose_topic_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::uint64_t pose_seq_ = 0;       ///< poses received
  std::uint64_t rendered_seq_ = 0;   ///< the pose the last frame shows
  std::uint64_t closed_at_seq_ = 0;  ///< poses received when the source was last closed
  Eigen::Isometry3d T_W_C_ = Eigen::Isometry3d::Identity();
  ros::Time pose_stamp_;
  std::chrono::steady_clock::time_point next_static_{};
};

// ---- tum ------------------------------------------------------------------------------------
class TumSource : public DepthSource {
 public:
  // The intrinsics, by `camera` (~tum_camera): "fr1" | "fr2" | "fr3" the TUM benchmark's
  // published calibration; "params" the given `K` (~fx..~cy, ~width, ~height); "" the folder's own
  // intrinsics file (intrinsics.txt, camera-intrinsics.txt, or 7-Scenes' published calibration),
  // else, for a folder whose name or depth.txt points at a TUM camera, an error naming it (the
  // ~fx..~cy defaults are another camera's), else `K` with a warning. The image size of the
  // first two comes from the first frame. scale_m <= 0 takes the folder's unit. Stamps that begin
  // before 1 s (7-Scenes: frame i at i / 30 s) are published 1 s later: a stamp of 0 reads as
  // "the latest" to a tf lookup. Frames play no faster than `rate_hz`.
  TumSource(const std::string& folder, const std::string& camera, const dt::PinholeIntrinsics& K,
            double scale_m, const dt::DepthRange& range, bool loop, bool file_stamps,
            double rate_hz)
      : folder_(folder),
        seq_(dt::readDepthSequence(folder)),
        K_(K),
        scale_(scale_m > 0.0 ? scale_m : seq_.depth_scale_m),
        range_(range),
        loop_(loop),
        file_stamps_(file_stamps),
        min_period_s_(1.0 / rate_hz) {
    if (seq_.frames.empty())
      throw std::runtime_error("tum backend: " + seq_.frames_source + " lists no frames");
    std::string source = "~fx ~fy ~cx ~cy (~tum_camera params)";
    std::optional<dt::PinholeIntrinsics> chosen;
    if (camera == "params") {
      // K as given
    } else if (!camera.empty()) {
      chosen = dt::tumIntrinsics(camera);  // the name was validated with the parameters
      source = "~tum_camera " + camera + " (the TUM benchmark's published calibration)";
    } else if (seq_.intrinsics) {
      chosen = seq_.intrinsics;
      source = seq_.intrinsics_source;
    } else if (const std::string hint = dt::folderCameraHint(folder); !hint.empty()) {
      throw std::runtime_error("tum backend: " + folder +
                               " has no intrinsics file and looks like a TUM " + hint +
                               " sequence: set ~tum_camera " + hint +
                               " (its published calibration), or ~tum_camera "
                               "params to play it with ~fx ~fy ~cx ~cy (now fx=" +
                               std::to_string(K.fx) + ")");
    } else {
      source = "~fx ~fy ~cx ~cy (the folder has no intrinsics file)";
      ROS_WARN(
          "depth_camera: %s has no intrinsics file and ~tum_camera is empty: playing it with "
          "~fx=%.2f ~fy=%.2f ~cx=%.2f ~cy=%.2f; set ~tum_camera (fr1, fr2, fr3) or write an "
          "intrinsics.txt (docs/formats.md) if these are not its camera's",
          folder.c_str(), K.fx, K.fy, K.cx, K.cy);
    }
    if (chosen) {
      K_ = *chosen;
      dt::readPng16(seq_.frames.front().path, &K_.width, &K_.height);
      const auto problems = K_.validate();
      if (!problems.empty())
        throw std::runtime_error("tum backend: " + source + ": " + dt::joinProblems(problems));
    }
    if (seq_.frames.front().stamp_s < 1.0) stamp_offset_s_ = 1.0;
    ROS_INFO(
        "depth_camera: %s folder %s, %zu frames, intrinsics fx=%.2f fy=%.2f cx=%.2f cy=%.2f "
        "%dx%d from %s, %g m per unit%s",
        seq_.layout.c_str(), folder.c_str(), seq_.frames.size(), K_.fx, K_.fy, K_.cx, K_.cy,
        K_.width, K_.height, source.c_str(), scale_,
        stamp_offset_s_ > 0.0 && file_stamps_ ? "; stamps 1 s later than the files'" : "");
  }
  std::string device() const override { return folder_; }
  bool open(std::string*) override { return true; }  // read whole at construction
  void close() override {}
  GrabStatus grab(DepthFrame* out, std::string* why) override {
    if (next_ >= seq_.frames.size()) {
      if (!loop_) {
        *why = "end of the sequence";
        return GrabStatus::kEnded;
      }
      next_ = 0;
      start_ = ros::WallTime();
    }
    const auto& f = seq_.frames[next_];
    if (start_.isZero()) {
      start_ = ros::WallTime::now();
      first_stamp_ = f.stamp_s;
    }
    // Play at the recorded timestamps (frame i is due stamp_i - stamp_0 after the start), no
    // faster than the frame rate.
    ros::WallTime due = start_ + ros::WallDuration(f.stamp_s - first_stamp_);
    if (!last_.isZero() && due < last_ + ros::WallDuration(min_period_s_))
      due = last_ + ros::WallDuration(min_period_s_);
    const ros::WallDuration wait = due - ros::WallTime::now();
    if (wait > ros::WallDuration(0)) wait.sleep();
    last_ = ros::WallTime::now();
    ++next_;  // a frame that cannot be read is skipped (the link reports it), not retried
    out->depth = dt::loadSequenceDepth(seq_, next_ - 1, scale_, range_);
    dt::checkFrameSize(out->depth, K_);
    out->stamp_ns =
        stampNs(file_stamps_ ? ros::Time(f.stamp_s + stamp_offset_s_) : ros::Time::now());
    return GrabStatus::kFrame;
  }
  dt::PinholeIntrinsics intrinsics() const override { return K_; }

 private:
  std::string folder_;
  dt::DepthSequence seq_;
  dt::PinholeIntrinsics K_;
  double scale_;
  dt::DepthRange range_;
  bool loop_, file_stamps_;
  double min_period_s_;
  double stamp_offset_s_ = 0.0;
  std::size_t next_ = 0;
  ros::WallTime start_, last_;
  double first_stamp_ = 0;
};

}  // namespace rig_drivers
