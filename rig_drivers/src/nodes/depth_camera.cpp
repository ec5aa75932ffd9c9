// depth_camera: publishes image_rect (16UC1, ~depth_scale_m metres per unit) + camera_info in
// camera_depth_optical_frame from one of three backends:
//   v4l2  RealSense Z16 stream through the V4L2 ioctl/mmap interface (no vendor SDK; rig_camera)
//   sim   renders depth_track's analytic scene from the simulator's true camera pose (T_W_C on
//         ~pose_topic) with the L515 / D435 noise model of depth_track_sim, or a measured one
//         (~noise_model_file: camera_check's YAML)
//   tum   plays a recorded sequence folder at its timestamps: the TUM RGB-D layout (depth.txt +
//         16-bit PNGs) or the 7-Scenes layout (frame-*.depth.png), depth_track's readDepthSequence
// Continuous (each source at its own pace, see ~rate_hz), or with ~triggered one frame per
// ~trigger call (mode 2 sequencer).
// Every backend sits behind CameraLink (rig_camera): a missing device is waited for, a lost one
// reopened, and the frames missing across a gap are counted; diagnostics say which.
// Parameters: config/drivers.yaml.
#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "depth_camera_sources.hpp"
#include "rig_drivers/camera/camera_link.hpp"
#include "rig_drivers/camera/v4l2_source.hpp"

namespace dt = depth_track;
using namespace rig_drivers;

namespace {

double steadyS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

/// Every parameter of the node, read once (defaults and meaning: config/drivers.yaml).
struct CameraParams {
  std::string backend, frame_id, noise, scene, pose_topic, device, tum_folder, tum_camera;
  std::string noise_model_file;
  double rate_hz, out_scale_m, device_scale_m, tum_scale_m;
  bool triggered, loop, file_stamps;
  int seed;
  std::vector<double> static_pose;
  dt::PinholeIntrinsics K;
  dt::DepthRange range;
  CameraLinkConfig link;

  void read(ros::NodeHandle& pnh) {
    pnh.param<std::string>("backend", backend, "sim");
    pnh.param<std::string>("frame_id", frame_id, "camera_depth_optical_frame");
    pnh.param("rate_hz", rate_hz, 30.0);
    pnh.param("triggered", triggered, false);
    pnh.param("depth_scale_m", out_scale_m, 0.001);
    pnh.param("min_depth_m", range.min_m, 0.53);
    pnh.param("max_depth_m", range.max_m, 4.0);
    const auto L = dt::sim::l515Intrinsics();
    pnh.param("width", K.width, L.width);
    pnh.param("height", K.height, L.height);
    pnh.param("fx", K.fx, L.fx);
    pnh.param("fy", K.fy, L.fy);
    pnh.param("cx", K.cx, L.cx);
    pnh.param("cy", K.cy, L.cy);
    pnh.param("retry_period_s", link.retry_period_s, link.retry_period_s);
    pnh.param("stale_timeout_s", link.stale_timeout_s, link.stale_timeout_s);
    link.rate_hz = rate_hz;
    pnh.param<std::string>("device", device, "/dev/video0");
    pnh.param("device_depth_scale_m", device_scale_m, 0.00025);
    pnh.param<std::string>("scene", scene, "chair_room");
    pnh.param<std::string>("noise", noise, "l515");
    pnh.param<std::string>("noise_model_file", noise_model_file, "");
    pnh.param<std::string>("pose_topic", pose_topic, "/rig_sim/camera_pose");
    pnh.param("seed", seed, 1);
    pnh.param("static_pose", static_pose, static_pose);
    pnh.param<std::string>("tum_folder", tum_folder, "");
    pnh.param("tum_depth_scale_m", tum_scale_m, 0.0);
    pnh.param<std::string>("tum_camera", tum_camera, "");
    pnh.param("loop", loop, false);
    pnh.param("use_file_stamps", file_stamps, true);
  }

  std::vector<std::string> validate() const {
    std::vector<std::string> problems;
    for (const auto& p : K.validate()) problems.push_back("intrinsics: " + p);
    for (const auto& p : range.validate()) problems.push_back("depth range: " + p);
    for (const auto& p : link.validate()) problems.push_back("~" + p);
    if (!(out_scale_m > 0 && out_scale_m <= 0.01))
      problems.push_back("~depth_scale_m must be in (0, 0.01] m per unit");
    else if (range.max_m / out_scale_m > 65535)
      problems.push_back("~max_depth_m / ~depth_scale_m exceeds the 16-bit range");
    if (backend == "tum" && tum_folder.empty()) problems.push_back("~tum_folder is required");
    if (!tum_camera.empty() && tum_camera != "params" && !dt::tumIntrinsics(tum_camera))
      problems.push_back("~tum_camera '" + tum_camera +
                         "' unknown (empty = the folder's intrinsics file, fr1, fr2, fr3, params)");
    if (!(tum_scale_m >= 0.0 && tum_scale_m <= 1.0))
      problems.push_back("~tum_depth_scale_m must be in [0, 1] m per unit (0 = the folder's own)");
    if (!static_pose.empty() && static_pose.size() != 7)
      problems.push_back("~static_pose needs 7 numbers [x y z qx qy qz qw] (m, T_W_C)");
    for (double v : static_pose)
      if (!std::isfinite(v)) problems.push_back("~static_pose has a non-finite number");
    if (backend != "v4l2" && backend != "sim" && backend != "tum")
      problems.push_back("~backend '" + backend + "' unknown (v4l2, sim, tum)");
    return problems;
  }

  /// The backend's source; throws std::runtime_error on a setting only it can check.
  std::unique_ptr<DepthSource> makeSource(ros::NodeHandle& nh) const {
    if (backend == "v4l2") return std::make_unique<V4l2Source>(device, K, device_scale_m, range);
    if (backend == "sim") {
      const dt::sim::NoiseConfig noise_config =
          noise_model_file.empty() ? dt::sim::NoiseConfig::forModel(dt::sim::parseNoiseModel(noise))
                                   : dt::sim::loadNoiseModelYaml(noise_model_file);
      return std::make_unique<SimSource>(nh, scene, noise_config, pose_topic, static_pose,
                                         static_cast<std::uint64_t>(seed), range, triggered,
                                         rate_hz);
    }
    return std::make_unique<TumSource>(tum_folder, tum_camera, K, tum_scale_m, range, loop,
                                       file_stamps, rate_hz);
  }
};

class DepthCameraNode {
 public:
  bool init() {
    ros::NodeHandle nh, pnh("~");
    params_.read(pnh);
    // A triggered camera delivers nothing between triggers: silence is not a lost device.
    if (params_.triggered) params_.link.stale_timeout_s = 0.0;
    const auto problems = params_.validate();
    if (!problems.empty()) {
      std::string msg;
      for (const auto& p : problems) msg += "\n  - " + p;
      ROS_FATAL("depth_camera: invalid parameters (see config/drivers.yaml):%s", msg.c_str());
      return false;
    }
    try {
      link_ = std::make_unique<CameraLink>(params_.link, params_.makeSource(nh),
                                           [](const CameraEvent& e) { logEvent(e); });
    } catch (const std::exception& e) {
      ROS_FATAL("depth_camera: %s", e.what());
      return false;
    }
    image_pub_ = nh.advertise<sensor_msgs::Image>("image_rect", 5);
    info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("camera_info", 5);
    trigger_srv_ = pnh.advertiseService("trigger", &DepthCameraNode::onTrigger, this);
    diag_.setHardwareID(link_->source().device());
    diag_.add("depth camera", this, &DepthCameraNode::diagnose);
    const auto K = link_->source().intrinsics();
    ROS_INFO("depth_camera: %s backend on %s, %dx%d, %s, frame_id %s", params_.backend.c_str(),
             link_->source().device().c_str(), K.width, K.height,
             params_.triggered ? "one frame per ~trigger" : "continuous", params_.frame_id.c_str());
    return true;
  }

  int spin() {
    ros::AsyncSpinner spinner(2);
    spinner.start();
    while (ros::ok()) {
      bool idle = true;
      {
        std::lock_guard<std::mutex> l(mutex_);
        if (link_->state() == CameraState::kEnded) break;
        if (!params_.triggered) {
          DepthFrame f;
          if (link_->step(steadyS(), &f)) {
            publish(f);
          } else if (link_->state() == CameraState::kStreaming && !link_->lastProblem().empty()) {
            ROS_WARN_THROTTLE(5, "depth_camera: %s", link_->lastProblem().c_str());
          }
          idle = link_->state() != CameraState::kStreaming;
        } else {
          link_->step(steadyS(), nullptr);  // keep the device open between triggers
        }
      }
      diag_.update();
      // Sources pace themselves while streaming (V4L2 and the pose stream block, a folder plays at
      // its stamps); in between, a short sleep bounds the latency of the next open attempt.
      if (idle) ros::WallDuration(0.05).sleep();
    }
    if (link_->state() == CameraState::kEnded)
      ROS_INFO("depth_camera: %s; %llu frames published", link_->status().c_str(),
               static_cast<unsigned long long>(link_->stats().frames));
    diag_.force_update();
    ros::waitForShutdown();
    std::lock_guard<std::mutex> l(mutex_);
    link_->close();
    return 0;
  }

 private:
  static void logEvent(const CameraEvent& e) {
    switch (e.type) {
      case CameraEvent::kWaiting:
      case CameraEvent::kLost:
      case CameraEvent::kResumed:
        ROS_WARN("depth_camera: %s", e.message.c_str());
        break;
      default:
        ROS_INFO("depth_camera: %s", e.message.c_str());
    }
  }
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& d) {
    std::lock_guard<std::mutex> l(mutex_);
    using S = diagnostic_msgs::DiagnosticStatus;
    const CameraState st = link_->state();
    // Waiting for a device that never came is a warning; one that went away is an error.
    const auto level = st == CameraState::kStreaming || st == CameraState::kEnded ? S::OK
                       : st == CameraState::kWaiting                              ? S::WARN
                                                                                  : S::ERROR;
    d.summary(level, link_->status());
    const auto& s = link_->stats();
    d.add("device", link_->source().device());
    d.add("frames", s.frames);
    d.add("failed opens", s.failed_opens);
    d.add("losses", s.losses);
    d.add("reconnects", s.reconnects);
    d.add("frames missing in gaps", s.gap_frames);
    d.addf("last gap (s)", "%.3f", s.last_gap_s);
    d.addf("retry period (s)", "%.3f", params_.link.retry_period_s);
  }
  void publish(const DepthFrame& g) {
    const dt::PinholeIntrinsics K = link_->source().intrinsics();
    sensor_msgs::Image img;
    img.header.stamp.fromNSec(static_cast<std::uint64_t>(g.stamp_ns));
    img.header.frame_id = params_.frame_id;
    img.width = static_cast<std::uint32_t>(g.depth.width);
    img.height = static_cast<std::uint32_t>(g.depth.height);
    img.encoding = "16UC1";
    img.is_bigendian = false;
    img.step = img.width * 2;
    img.data.resize(static_cast<std::size_t>(img.step) * img.height);
    auto* px = reinterpret_cast<std::uint16_t*>(img.data.data());
    const double inv = 1.0 / params_.out_scale_m;
    for (std::size_t i = 0; i < g.depth.data.size(); ++i) {
      const float z = g.depth.data[i];
      const double u = std::isfinite(z) && z > 0 ? std::round(z * inv) : 0.0;
      px[i] = static_cast<std::uint16_t>(u > 65535 ? 0 : u);  // out of 16-bit range = no return
    }
    sensor_msgs::CameraInfo info;
    info.header = img.header;
    info.width = img.width;
    info.height = img.height;
    info.distortion_model = "plumb_bob";
    info.D.assign(5, 0.0);  // image_rect: already rectified
    info.K = {K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1};
    info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    info.P = {K.fx, 0, K.cx, 0, 0, K.fy, K.cy, 0, 0, 0, 1, 0};
    info_pub_.publish(info);
    image_pub_.publish(img);
  }
  bool onTrigger(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    std::lock_guard<std::mutex> l(mutex_);
    DepthFrame f;
    res.success = link_->step(steadyS(), &f);
    if (res.success) {
      publish(f);
      res.message = "frame " + std::to_string(link_->stats().frames) + " published";
    } else {
      res.message = link_->lastProblem();
    }
    return true;
  }

  CameraParams params_;
  std::unique_ptr<CameraLink> link_;
  std::mutex mutex_;  ///< the link is driven from the loop and the trigger service
  diagnostic_updater::Updater diag_;
  ros::Publisher image_pub_, info_pub_;
  ros::ServiceServer trigger_srv_;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "depth_camera");
  DepthCameraNode node;
  if (!node.init()) return 1;
  return node.spin();
}
