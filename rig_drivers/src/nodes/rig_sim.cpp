// rig_sim: the rig simulator as a ROS node. Runs the boards' firmware logic (TrackDRV + CarDRV for
// ServoTrack, TruckDRV for ServoTruck) against the physical models in real time, each board on
// its own pseudo-terminal speaking the rig protocol (with the modelled link latency and jitter),
// so the driver nodes run unchanged against it. Publishes the exact camera pose as ground truth,
// apart from the sensor readings that reach the drivers through the ptys:
//   /rig_sim/camera_pose  geometry_msgs/PoseStamped  T_map_camera (optical frame), per exposure
//   /tf                   map -> camera_gt           same pose
//   ~<board>_port         (param, set by the node)   slave pty path of each board
// Parameters (private):
//   ~scenario       path of a scenario file (config/scenarios/NAME.yaml)          [required]
//   ~rig            servotrack | servotruck: checked against the scenario         [unset]
//   ~link_dir       folder for stable symlinks <link_dir>/<board> -> pty slave   ["/tmp/rig_sim"]
//   ~autopilot      run the scenario's mode 1 motion after the host's start       [true]
//   ~publish_static_tf  base_link -> camera_link -> camera_depth_optical_frame    [false]
//   ~loop_rate_hz   how often the simulator catches up with the wall clock, Hz    [500]
// Services: ~unplug_<board> (std_srvs/SetBool): true pulls the board's USB (pty closed, symlink
// removed), false plugs it back in (a new pty behind the same symlink).
#include <fcntl.h>
#include <geometry_msgs/PoseStamped.h>
#include <pty.h>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>
#include <sys/stat.h>
#include <termios.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <map>

#include "rig_drivers/ros/sim_conversions.hpp"
#include "rig_drivers/sim/rig_sim.hpp"

using namespace rig_drivers;

namespace {

const char* boardName(protocol::BoardId b) {
  switch (b) {
    case protocol::BoardId::kTrack:
      return "track";
    case protocol::BoardId::kCar:
      return "car";
    case protocol::BoardId::kTruck:
      return "truck";
    default:
      return "host";
  }
}

/// One board's end of a pseudo-terminal pair, plus a stable symlink to the slave side.
class PtyBoard {
 public:
  PtyBoard(protocol::BoardId board, std::string link_path)
      : board_(board), link_(std::move(link_path)) {}
  ~PtyBoard() { unplug(); }

  /// Opens a new pty (raw, non-blocking master) and points the symlink at its slave.
  void plug() {
    if (master_ >= 0) return;
    char name[256] = {};
    if (openpty(&master_, &slave_, name, nullptr, nullptr) != 0)
      throw std::runtime_error(std::string("openpty failed: ") + std::strerror(errno));
    termios tio{};
    tcgetattr(slave_, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave_, TCSANOW, &tio);
    fcntl(master_, F_SETFL, fcntl(master_, F_GETFL) | O_NONBLOCK);
    slave_path_ = name;
    if (!link_.empty()) {
      ::unlink(link_.c_str());
      if (::symlink(slave_path_.c_str(), link_.c_str()) != 0)
        throw std::runtime_error("cannot create symlink " + link_ + ": " + std::strerror(errno));
    }
  }

  /// Closes the pty: the driver sees a hang-up, like an unplugged USB board.
  void unplug() {
    if (master_ < 0) return;
    if (!link_.empty()) ::unlink(link_.c_str());
    ::close(master_);
    ::close(slave_);
    master_ = slave_ = -1;
  }

  bool plugged() const { return master_ >= 0; }
  const std::string& slavePath() const { return slave_path_; }
  const std::string& linkPath() const { return link_; }
  protocol::BoardId board() const { return board_; }

  /// Bytes the host wrote since the last call.
  std::vector<uint8_t> read() {
    std::vector<uint8_t> out;
    if (master_ < 0) return out;
    uint8_t buf[1024];
    for (;;) {
      const ssize_t n = ::read(master_, buf, sizeof buf);
      if (n <= 0) break;  // EAGAIN (nothing), or EIO while no one holds the slave
      out.insert(out.end(), buf, buf + n);
    }
    return out;
  }

  /// Writes board bytes; dropped (like a full USB buffer) when the host does not read.
  void write(const std::vector<uint8_t>& bytes) {
    if (master_ < 0) return;
    std::size_t off = 0;
    while (off < bytes.size()) {
      const ssize_t n = ::write(master_, bytes.data() + off, bytes.size() - off);
      if (n <= 0) break;
      off += static_cast<std::size_t>(n);
    }
  }

 private:
  protocol::BoardId board_;
  std::string link_;
  std::string slave_path_;
  int master_ = -1;
  int slave_ = -1;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "rig_sim");
  ros::NodeHandle nh, pnh("~");
  std::string scenario_path, link_dir = "/tmp/rig_sim";
  bool autopilot = true, publish_static = false;
  double loop_hz = 500.0;
  pnh.param<std::string>("scenario", scenario_path, "");
  pnh.param<std::string>("link_dir", link_dir, link_dir);
  pnh.param("autopilot", autopilot, autopilot);
  pnh.param("publish_static_tf", publish_static, publish_static);
  pnh.param("loop_rate_hz", loop_hz, loop_hz);
  if (scenario_path.empty()) {
    ROS_FATAL("rig_sim: ~scenario (path of a config/scenarios/*.yaml file) is required");
    return 1;
  }
  if (!(loop_hz >= 30.0 && loop_hz <= 5000.0)) {
    ROS_FATAL("rig_sim: ~loop_rate_hz must lie in 30..5000 Hz (got %g)", loop_hz);
    return 1;
  }

  std::unique_ptr<RigSimulator> sim;
  std::vector<std::unique_ptr<PtyBoard>> ptys;
  try {
    const Scenario scenario = loadScenario(scenario_path);
    std::string rig;
    if (pnh.getParam("rig", rig) && rig != toString(scenario.rig))
      throw std::invalid_argument("~rig is '" + rig + "' but scenario " + scenario.name + " is a " +
                                  toString(scenario.rig) + " run");
    RigSimConfig cfg;
    cfg.scripted_host = false;
    cfg.autopilot = autopilot;
    sim = std::make_unique<RigSimulator>(scenario, cfg);
    if (!link_dir.empty()) ::mkdir(link_dir.c_str(), 0755);
    for (protocol::BoardId b : sim->boards()) {
      auto p = std::make_unique<PtyBoard>(b, link_dir.empty() ? "" : link_dir + "/" + boardName(b));
      p->plug();
      pnh.setParam(std::string(boardName(b)) + "_port",
                   p->linkPath().empty() ? p->slavePath() : p->linkPath());
      ROS_INFO("rig_sim: %s board on %s%s%s", boardName(b), p->slavePath().c_str(),
               p->linkPath().empty() ? "" : " (link ",
               p->linkPath().empty() ? "" : (p->linkPath() + ")").c_str());
      ptys.push_back(std::move(p));
    }
    ROS_INFO("rig_sim: scenario %s (%s), %d frames", scenario.name.c_str(), toString(scenario.rig),
             scenario.frameCount());
  } catch (const std::exception& e) {
    ROS_FATAL("rig_sim: %s", e.what());
    return 1;
  }

  ros::Publisher pose_pub = nh.advertise<geometry_msgs::PoseStamped>("rig_sim/camera_pose", 30);
  tf2_ros::TransformBroadcaster tf_pub;
  std::unique_ptr<tf2_ros::StaticTransformBroadcaster> static_pub;
  if (publish_static) {
    static_pub = std::make_unique<tf2_ros::StaticTransformBroadcaster>();
    static_pub->sendTransform(
        conv::rigStaticTransforms(*sim, ros::Time::now(), "camera_depth_optical_frame"));
  }

  std::vector<ros::ServiceServer> services;
  for (auto& p : ptys) {
    PtyBoard* pty = p.get();
    services.push_back(
        pnh.advertiseService<std_srvs::SetBool::Request, std_srvs::SetBool::Response>(
            std::string("unplug_") + boardName(pty->board()),
            [pty](std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
              try {
                if (req.data) {
                  pty->unplug();
                  res.message = "unplugged";
                } else {
                  pty->plug();
                  res.message = "plugged in on " + pty->slavePath();
                }
                res.success = true;
              } catch (const std::exception& e) {
                res.success = false;
                res.message = e.what();
              }
              return true;
            }));
  }

  const ros::WallTime t0 = ros::WallTime::now();
  const ros::Time ros_t0 = ros::Time::now();
  ros::WallRate rate(loop_hz);
  bool reported_done = false;
  while (ros::ok()) {
    ros::spinOnce();
    try {
      for (auto& p : ptys) {
        const std::vector<uint8_t> in = p->read();
        if (!in.empty()) sim->hostSend(p->board(), in.data(), in.size());
      }
      sim->advanceTo((ros::WallTime::now() - t0).toSec());
      for (const SimLinkFrame& f : sim->takeHostBytes()) {
        for (auto& p : ptys)
          if (p->board() == f.board) p->write(f.bytes);
      }
      for (const SimCameraFrame& cf : sim->takeCameraFrames()) {
        const ros::Time stamp = ros_t0 + ros::Duration(cf.truth.t_s);
        pose_pub.publish(conv::toPoseStamped(stamp, "map", cf.truth.T_W_C));
        tf_pub.sendTransform(conv::toTransformStamped(stamp, "map", "camera_gt", cf.truth.T_W_C));
      }
      for (const std::string& e : sim->takeEvents()) ROS_WARN("rig_sim: %s", e.c_str());
      if (sim->finished() && !reported_done) {
        ROS_INFO("rig_sim: scenario motion finished at t = %.2f s", sim->now());
        reported_done = true;
      }
    } catch (const std::exception& e) {
      ROS_ERROR_THROTTLE(1.0, "rig_sim: %s", e.what());
    }
    rate.sleep();
  }
  return 0;
}
