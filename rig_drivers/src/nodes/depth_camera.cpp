// depth_camera: publishes image_rect (16UC1, ~depth_scale_m metres per unit) + camera_info in
// camera_depth_optical_frame from one of three backends:
//   v4l2  RealSense Z16 stream through the V4L2 ioctl/mmap interface (no vendor SDK)
//   sim   renders depth_track's analytic scene from the simulator's true camera pose (T_W_C on
//         ~pose_topic) with the L515 / D435 noise model of depth_track_sim, or a measured one
//         (~noise_model_file: camera_check's YAML)
//   tum   plays a recorded sequence folder at its timestamps: the TUM RGB-D layout (depth.txt +
//         16-bit PNGs) or the 7-Scenes layout (frame-*.depth.png), depth_track's readDepthSequence
// Continuous at ~rate_hz, or with ~triggered one frame per ~trigger call (mode 2 sequencer).
// Parameters: config/drivers.yaml.
#include <fcntl.h>
#include <geometry_msgs/PoseStamped.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/sim/scene.hpp"
#include "depth_track/core/tum_cameras.hpp"
#include "depth_track/core/tum_io.hpp"

namespace dt = depth_track;

namespace {

/// One grabbed frame in metres with its capture time.
struct Grab {
  dt::DepthImage depth;
  ros::Time stamp;
};

class Backend {
 public:
  virtual ~Backend() = default;
  /// Next frame; false when none is available yet (message in *why) or the source ended.
  virtual bool grab(Grab* out, std::string* why) = 0;
  virtual dt::PinholeIntrinsics intrinsics() const = 0;
  virtual bool finished() const { return false; }
};

// ---- v4l2 -----------------------------------------------------------------------------------
class V4l2Backend : public Backend {
 public:
  V4l2Backend(const std::string& device, const dt::PinholeIntrinsics& K, double device_scale_m,
              const dt::DepthRange& range)
      : device_(device), K_(K), scale_(device_scale_m), range_(range) {
    fd_ = ::open(device.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd_ < 0)
      fail("cannot open " + device + ": " + std::strerror(errno) +
           " (is the RealSense plugged in and its depth node this /dev/video*?)");
    v4l2_capability cap{};
    if (xioctl(VIDIOC_QUERYCAP, &cap) != 0) fail("VIDIOC_QUERYCAP failed: " + err());
    if (!(cap.capabilities & V4L2_CAP_VIDEO_CAPTURE) || !(cap.capabilities & V4L2_CAP_STREAMING))
      fail(device + " is not a streaming video capture device");
    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    fmt.fmt.pix.width = K.width;
    fmt.fmt.pix.height = K.height;
    fmt.fmt.pix.pixelformat = V4L2_PIX_FMT_Z16;
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    if (xioctl(VIDIOC_S_FMT, &fmt) != 0) fail("VIDIOC_S_FMT Z16 failed: " + err());
    if (fmt.fmt.pix.pixelformat != V4L2_PIX_FMT_Z16 ||
        static_cast<int>(fmt.fmt.pix.width) != K.width ||
        static_cast<int>(fmt.fmt.pix.height) != K.height)
      fail(device + " does not offer Z16 at " + std::to_string(K.width) + "x" +
           std::to_string(K.height) + " (is this the depth node of the camera?)");
    stride_ = fmt.fmt.pix.bytesperline ? fmt.fmt.pix.bytesperline : 2u * K.width;
    v4l2_requestbuffers req{};
    req.count = 4;
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = V4L2_MEMORY_MMAP;
    if (xioctl(VIDIOC_REQBUFS, &req) != 0 || req.count < 2) fail("VIDIOC_REQBUFS failed: " + err());
    for (unsigned i = 0; i < req.count; ++i) {
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      b.memory = V4L2_MEMORY_MMAP;
      b.index = i;
      if (xioctl(VIDIOC_QUERYBUF, &b) != 0) fail("VIDIOC_QUERYBUF failed: " + err());
      void* p = ::mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, b.m.offset);
      if (p == MAP_FAILED) fail("mmap failed: " + err());
      buffers_.push_back({p, b.length});
      if (xioctl(VIDIOC_QBUF, &b) != 0) fail("VIDIOC_QBUF failed: " + err());
    }
    v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (xioctl(VIDIOC_STREAMON, &type) != 0) fail("VIDIOC_STREAMON failed: " + err());
  }
  ~V4l2Backend() override {
    if (fd_ >= 0) {
      v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      xioctl(VIDIOC_STREAMOFF, &type);
    }
    for (auto& b : buffers_) ::munmap(b.first, b.second);
    if (fd_ >= 0) ::close(fd_);
  }
  bool grab(Grab* out, std::string* why) override {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 1000) <= 0) {
      *why = "v4l2: no frame from " + device_ + " within 1 s";
      return false;
    }
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    if (xioctl(VIDIOC_DQBUF, &b) != 0) {
      *why = "v4l2: VIDIOC_DQBUF on " + device_ + " failed: " + err() + " (unplugged?)";
      return false;
    }
    out->stamp = ros::Time::now();
    try {
      out->depth = dt::depthFromRaw(buffers_[b.index].first, K_.width, K_.height, stride_,
                                    dt::DepthEncoding::kU16, scale_, range_);
    } catch (const std::exception& e) {
      *why = std::string("v4l2: ") + e.what();
      xioctl(VIDIOC_QBUF, &b);
      return false;
    }
    xioctl(VIDIOC_QBUF, &b);
    return true;
  }
  dt::PinholeIntrinsics intrinsics() const override { return K_; }

 private:
  int xioctl(unsigned long request, void* arg) {
    int r;
    do r = ::ioctl(fd_, request, arg);
    while (r < 0 && errno == EINTR);
    return r;
  }
  static std::string err() { return std::strerror(errno); }
  [[noreturn]] void fail(const std::string& what) {
    for (auto& b : buffers_) ::munmap(b.first, b.second);
    buffers_.clear();
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    throw std::runtime_error("v4l2 backend: " + what);
  }
  std::string device_;
  dt::PinholeIntrinsics K_;
  double scale_;
  dt::DepthRange range_;
  int fd_ = -1;
  std::size_t stride_ = 0;
  std::vector<std::pair<void*, std::size_t>> buffers_;
};

// ---- sim ------------------------------------------------------------------------------------
class SimBackend : public Backend {
 public:
  SimBackend(ros::NodeHandle& nh, const std::string& scene, const dt::sim::NoiseConfig& noise,
             const std::string& pose_topic, const std::vector<double>& static_pose,
             double pose_wait_s, std::uint64_t seed, const dt::DepthRange& range)
      : noise_(noise), seed_(seed), range_(range), pose_wait_s_(pose_wait_s) {
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
      if (!have_pose_) throw std::runtime_error("sim backend: ~static_pose has a zero quaternion");
      pose_topic_ = "~static_pose";
    } else {
      sub_ = nh.subscribe(pose_topic, 10, &SimBackend::onPose, this);
    }
  }
  bool grab(Grab* out, std::string* why) override {
    Eigen::Isometry3d T_W_C;
    ros::Time stamp;
    // The simulator may start a moment after the camera: wait a little for its first pose.
    const ros::WallTime until = ros::WallTime::now() + ros::WallDuration(pose_wait_s_);
    while (ros::ok() && ros::WallTime::now() < until) {
      {
        std::lock_guard<std::mutex> l(mutex_);
        if (have_pose_) break;
      }
      ros::WallDuration(0.01).sleep();
    }
    {
      std::lock_guard<std::mutex> l(mutex_);
      if (!have_pose_) {
        *why = "sim: no true camera pose on " + pose_topic_ + " (is rig_sim running?)";
        return false;
      }
      T_W_C = T_W_C_;
      stamp = pose_stamp_;
    }
    const auto clean = dt::sim::renderDepth(scene_, K_, T_W_C, range_);
    out->depth = dt::sim::applyNoise(clean, noise_, dt::sim::frameSeed(seed_, index_++), range_);
    // Stamp = the pose's time: the frame shows the scene exactly as seen from that pose.
    out->stamp = stamp.isZero() ? ros::Time::now() : stamp;
    return true;
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
    std::lock_guard<std::mutex> l(mutex_);
    T_W_C_ = Eigen::Isometry3d::Identity();
    T_W_C_.linear() = qd.normalized().toRotationMatrix();
    T_W_C_.translation() << p.pose.position.x, p.pose.position.y, p.pose.position.z;
    pose_stamp_ = p.header.stamp;
    have_pose_ = true;
  }
  dt::sim::Scene scene_;
  dt::PinholeIntrinsics K_ = dt::sim::l515Intrinsics();
  dt::sim::NoiseConfig noise_;
  std::uint64_t seed_;
  std::uint64_t index_ = 0;
  dt::DepthRange range_;
  ros::Subscriber sub_;
  double pose_wait_s_;
  std::string pose_topic_;
  std::mutex mutex_;
  bool have_pose_ = false;
  Eigen::Isometry3d T_W_C_ = Eigen::Isometry3d::Identity();
  ros::Time pose_stamp_;
};

// ---- tum ------------------------------------------------------------------------------------
class TumBackend : public Backend {
 public:
  // The intrinsics, by `camera` (~tum_camera): "fr1" | "fr2" | "fr3" the TUM benchmark's
  // published calibration; "params" the given `K` (~fx..~cy, ~width, ~height); "" the folder's own
  // intrinsics file (intrinsics.txt, camera-intrinsics.txt, or 7-Scenes' published calibration),
  // else, for a folder whose name or depth.txt points at a TUM camera, an error naming it (the
  // ~fx..~cy defaults are another camera's), else `K` with a warning. The image size of the
  // first two comes from the first frame. scale_m <= 0 takes the folder's unit. Stamps that begin
  // before 1 s (7-Scenes: frame i at i / 30 s) are published 1 s later: a stamp of 0 reads as
  // "the latest" to a tf lookup.
  TumBackend(const std::string& folder, const std::string& camera, const dt::PinholeIntrinsics& K,
             double scale_m, const dt::DepthRange& range, bool loop, bool file_stamps)
      : seq_(dt::readDepthSequence(folder)),
        K_(K),
        scale_(scale_m > 0.0 ? scale_m : seq_.depth_scale_m),
        range_(range),
        loop_(loop),
        file_stamps_(file_stamps) {
    if (seq_.frames.empty()) throw std::runtime_error("tum backend: " + seq_.frames_source + " lists no frames");
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
      throw std::runtime_error(
          "tum backend: " + folder + " has no intrinsics file and looks like a TUM " + hint +
          " sequence: set ~tum_camera " + hint + " (its published calibration), or ~tum_camera "
          "params to play it with ~fx ~fy ~cx ~cy (now fx=" + std::to_string(K.fx) + ")");
    } else {
      source = "~fx ~fy ~cx ~cy (the folder has no intrinsics file)";
      ROS_WARN("depth_camera: %s has no intrinsics file and ~tum_camera is empty: playing it with "
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
    ROS_INFO("depth_camera: %s folder %s, %zu frames, intrinsics fx=%.2f fy=%.2f cx=%.2f cy=%.2f "
             "%dx%d from %s, %g m per unit%s",
             seq_.layout.c_str(), folder.c_str(), seq_.frames.size(), K_.fx, K_.fy, K_.cx, K_.cy,
             K_.width, K_.height, source.c_str(), scale_,
             stamp_offset_s_ > 0.0 && file_stamps_ ? "; stamps 1 s later than the files'" : "");
  }
  bool grab(Grab* out, std::string* why) override {
    if (next_ >= seq_.frames.size()) {
      if (!loop_) {
        *why = "tum: end of the sequence";
        done_ = true;
        return false;
      }
      next_ = 0;
      start_ = ros::WallTime();
    }
    const auto& f = seq_.frames[next_];
    if (start_.isZero()) {
      start_ = ros::WallTime::now();
      first_stamp_ = f.stamp_s;
    }
    // Play at the recorded timestamps: frame i is due (stamp_i - stamp_0) after the start.
    const ros::WallTime due = start_ + ros::WallDuration(f.stamp_s - first_stamp_);
    const ros::WallDuration wait = due - ros::WallTime::now();
    if (wait > ros::WallDuration(0)) wait.sleep();
    out->depth = dt::loadSequenceDepth(seq_, next_, scale_, range_);
    dt::checkFrameSize(out->depth, K_);
    out->stamp = file_stamps_ ? ros::Time(f.stamp_s + stamp_offset_s_) : ros::Time::now();
    ++next_;
    return true;
  }
  dt::PinholeIntrinsics intrinsics() const override { return K_; }
  bool finished() const override { return done_; }

 private:
  dt::DepthSequence seq_;
  dt::PinholeIntrinsics K_;
  double scale_;
  dt::DepthRange range_;
  bool loop_, file_stamps_;
  double stamp_offset_s_ = 0.0;
  std::size_t next_ = 0;
  ros::WallTime start_;
  double first_stamp_ = 0;
  bool done_ = false;
};

// ---- node -----------------------------------------------------------------------------------
class DepthCameraNode {
 public:
  bool init() {
    ros::NodeHandle nh, pnh("~");
    std::string backend, noise, scene, pose_topic, device, tum_folder, tum_camera;
    double fx, fy, cx, cy, min_m, max_m, device_scale_m, tum_scale_m;
    int width, height, seed;
    bool loop, file_stamps;
    pnh.param<std::string>("backend", backend, "sim");
    pnh.param<std::string>("frame_id", frame_id_, "camera_depth_optical_frame");
    pnh.param("rate_hz", rate_hz_, 30.0);
    pnh.param("triggered", triggered_, false);
    pnh.param("depth_scale_m", out_scale_m_, 0.001);
    pnh.param("min_depth_m", min_m, 0.53);
    pnh.param("max_depth_m", max_m, 4.0);
    const auto L = dt::sim::l515Intrinsics();
    pnh.param("width", width, L.width);
    pnh.param("height", height, L.height);
    pnh.param("fx", fx, L.fx);
    pnh.param("fy", fy, L.fy);
    pnh.param("cx", cx, L.cx);
    pnh.param("cy", cy, L.cy);
    pnh.param<std::string>("device", device, "/dev/video0");
    pnh.param("device_depth_scale_m", device_scale_m, 0.00025);
    pnh.param<std::string>("scene", scene, "chair_room");
    pnh.param<std::string>("noise", noise, "l515");
    std::string noise_model_file;
    pnh.param<std::string>("noise_model_file", noise_model_file, "");
    pnh.param<std::string>("pose_topic", pose_topic, "/rig_sim/camera_pose");
    pnh.param("seed", seed, 1);
    std::vector<double> static_pose;
    double pose_wait_s;
    pnh.param("static_pose", static_pose, static_pose);
    pnh.param("pose_wait_s", pose_wait_s, 2.0);
    pnh.param<std::string>("tum_folder", tum_folder, "");
    pnh.param("tum_depth_scale_m", tum_scale_m, 0.0);
    pnh.param<std::string>("tum_camera", tum_camera, "");
    pnh.param("loop", loop, false);
    pnh.param("use_file_stamps", file_stamps, true);

    std::vector<std::string> problems;
    dt::PinholeIntrinsics K;
    K.width = width;
    K.height = height;
    K.fx = fx;
    K.fy = fy;
    K.cx = cx;
    K.cy = cy;
    dt::DepthRange range;
    range.min_m = min_m;
    range.max_m = max_m;
    for (const auto& p : K.validate()) problems.push_back("intrinsics: " + p);
    for (const auto& p : range.validate()) problems.push_back("depth range: " + p);
    if (!(rate_hz_ > 0 && rate_hz_ <= 1000)) problems.push_back("~rate_hz must be in (0, 1000] Hz");
    if (!(out_scale_m_ > 0 && out_scale_m_ <= 0.01))
      problems.push_back("~depth_scale_m must be in (0, 0.01] m per unit");
    else if (max_m / out_scale_m_ > 65535)
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
    if (!(pose_wait_s >= 0 && pose_wait_s <= 60)) problems.push_back("~pose_wait_s in [0, 60] s");
    if (backend != "v4l2" && backend != "sim" && backend != "tum")
      problems.push_back("~backend '" + backend + "' unknown (v4l2, sim, tum)");
    if (!problems.empty()) {
      std::string msg;
      for (const auto& p : problems) msg += "\n  - " + p;
      ROS_FATAL("depth_camera: invalid parameters (see config/drivers.yaml):%s", msg.c_str());
      return false;
    }
    try {
      if (backend == "v4l2") {
        backend_ = std::make_unique<V4l2Backend>(device, K, device_scale_m, range);
      } else if (backend == "sim") {
        const dt::sim::NoiseConfig noise_config =
            noise_model_file.empty()
                ? dt::sim::NoiseConfig::forModel(dt::sim::parseNoiseModel(noise))
                : dt::sim::loadNoiseModelYaml(noise_model_file);
        backend_ =
            std::make_unique<SimBackend>(nh, scene, noise_config, pose_topic, static_pose,
                                         pose_wait_s, static_cast<std::uint64_t>(seed), range);
      } else {
        backend_ =
            std::make_unique<TumBackend>(tum_folder, tum_camera, K, tum_scale_m, range, loop,
                                         file_stamps);
      }
    } catch (const std::exception& e) {
      ROS_FATAL("depth_camera: %s", e.what());
      return false;
    }
    image_pub_ = nh.advertise<sensor_msgs::Image>("image_rect", 5);
    info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("camera_info", 5);
    trigger_srv_ = pnh.advertiseService("trigger", &DepthCameraNode::onTrigger, this);
    ROS_INFO("depth_camera: %s backend, %dx%d, %s, frame_id %s", backend.c_str(),
             backend_->intrinsics().width, backend_->intrinsics().height,
             triggered_ ? "one frame per ~trigger" : "continuous", frame_id_.c_str());
    return true;
  }

  int spin() {
    ros::AsyncSpinner spinner(2);
    spinner.start();
    ros::WallRate rate(rate_hz_);
    while (ros::ok()) {
      if (!triggered_) {
        std::string why;
        if (!grabAndPublish(&why)) {
          if (backend_->finished()) {
            ROS_INFO("depth_camera: %s; %u frames published", why.c_str(), published_);
            break;
          }
          ROS_WARN_THROTTLE(5, "depth_camera: %s", why.c_str());
        }
        rate.sleep();
      } else {
        ros::WallDuration(0.05).sleep();
      }
    }
    ros::waitForShutdown();
    return 0;
  }

 private:
  bool grabAndPublish(std::string* why) {
    std::lock_guard<std::mutex> l(grab_mutex_);
    Grab g;
    try {
      if (!backend_->grab(&g, why)) return false;
    } catch (const std::exception& e) {
      *why = e.what();
      return false;
    }
    const dt::PinholeIntrinsics K = backend_->intrinsics();
    sensor_msgs::Image img;
    img.header.stamp = g.stamp;
    img.header.frame_id = frame_id_;
    img.width = static_cast<std::uint32_t>(g.depth.width);
    img.height = static_cast<std::uint32_t>(g.depth.height);
    img.encoding = "16UC1";
    img.is_bigendian = false;
    img.step = img.width * 2;
    img.data.resize(static_cast<std::size_t>(img.step) * img.height);
    auto* px = reinterpret_cast<std::uint16_t*>(img.data.data());
    const double inv = 1.0 / out_scale_m_;
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
    ++published_;
    return true;
  }
  bool onTrigger(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    std::string why;
    res.success = grabAndPublish(&why);
    res.message = res.success ? "frame " + std::to_string(published_) + " published" : why;
    return true;
  }

  std::unique_ptr<Backend> backend_;
  std::string frame_id_;
  double rate_hz_ = 30, out_scale_m_ = 0.001;
  bool triggered_ = false;
  unsigned published_ = 0;
  std::mutex grab_mutex_;
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
