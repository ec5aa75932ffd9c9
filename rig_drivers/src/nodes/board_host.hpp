#pragma once
// ROS adapter shared by track_host, car_host and truck_host: loads BoardLinkConfig from private
// parameters, runs a BoardLink (rig_link), publishes the board's 30 Hz state message and every raw
// frame, serves the console's command services, and says on /diagnostics whether the board is
// connected or what the link waits for. All protocol logic lives in rig_link and rig_protocol.
#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>
#include <std_msgs/Bool.h>

#include <cmath>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

#include "rig_drivers/link/serial_port_link.hpp"
#include "rig_drivers/ros/conversions.hpp"
#include "rig_msgs/Command.h"
#include "rig_msgs/Parameters.h"
#include "rig_msgs/SequenceStep.h"
#include "rig_msgs/SetMode.h"
#include "rig_msgs/Version.h"

namespace rig_drivers {

/// Converts one board frame into the node's state message and publishes it; returns false when
/// the frame is not the board's state frame.
using StatePublisher = std::function<bool(const protocol::Frame& frame, const ros::Time& stamp)>;
/// Handles one SequenceStep for this board (track move, gimbal move, wait).
using StepHandler = std::function<void(BoardLink& link, const rig_msgs::SequenceStep::Request& req,
                                       rig_msgs::SequenceStep::Response& res, double timeout_s)>;

class BoardHost {
 public:
  BoardHost(protocol::BoardId board, const std::string& program_name)
      : nh_(), pnh_("~"), board_(board), program_(program_name) {}

  /// Reads parameters (every one documented in config/drivers.yaml); false on a bad config.
  bool configure() {
    BoardLinkConfig c;
    c.board = board_;
    double reconnect_s = c.reconnect_period_ms * 1e-3, handshake_s = c.handshake_timeout_ms * 1e-3,
           stale_s = c.stale_timeout_ms * 1e-3;
    pnh_.param<std::string>("port", c.serial.device, "");
    pnh_.param("baud", c.serial.baud, c.serial.baud);
    pnh_.param("reconnect_period_s", reconnect_s, reconnect_s);
    pnh_.param("handshake_timeout_s", handshake_s, handshake_s);
    pnh_.param("stale_timeout_s", stale_s, stale_s);
    pnh_.param("command_timeout_s", command_timeout_s_, 5.0);
    pnh_.param("init_timeout_s", init_timeout_s_, 120.0);
    pnh_.param("step_timeout_s", step_timeout_s_, 60.0);
    pnh_.param("publish_raw", publish_raw_, true);
    pnh_.param<std::string>("frame_id", frame_id_, "base_link");
    c.reconnect_period_ms = static_cast<int>(reconnect_s * 1000.0);
    c.handshake_timeout_ms = static_cast<int>(handshake_s * 1000.0);
    c.stale_timeout_ms = static_cast<int>(stale_s * 1000.0);
    auto problems = c.validate();
    if (!(command_timeout_s_ > 0)) problems.push_back("~command_timeout_s must be > 0 (s)");
    if (!(init_timeout_s_ > 0)) problems.push_back("~init_timeout_s must be > 0 (s)");
    if (!(step_timeout_s_ > 0)) problems.push_back("~step_timeout_s must be > 0 (s)");
    if (!problems.empty()) {
      std::string msg;
      for (const auto& p : problems) msg += "\n  - " + p;
      ROS_FATAL("%s: invalid parameters (see config/drivers.yaml):%s", program_.c_str(),
                msg.c_str());
      return false;
    }
    config_ = c;
    return true;
  }

  /// Advertises, starts the link and serves until shutdown.
  int run(const StatePublisher& publish_state, const StepHandler& step) {
    publish_state_ = publish_state;
    step_ = step;
    raw_pub_ = nh_.advertise<rig_msgs::RawFrame>("raw_frames", 100);
    connected_pub_ = pnh_.advertise<std_msgs::Bool>("connected", 1, true);
    publishConnected(false);
    link_ = std::make_unique<BoardLink>(
        config_, std::make_unique<PosixSerialPort>(config_.serial),
        [this](const protocol::Frame& f, const std::vector<std::uint8_t>& w, bool out) {
          onFrame(f, w, out);
        },
        [this](const LinkEvent& e) { onEvent(e); });
    services_.push_back(pnh_.advertiseService("command", &BoardHost::onCommand, this));
    services_.push_back(pnh_.advertiseService("mode", &BoardHost::onMode, this));
    services_.push_back(pnh_.advertiseService("vers", &BoardHost::onVers, this));
    services_.push_back(pnh_.advertiseService("para", &BoardHost::onPara, this));
    services_.push_back(pnh_.advertiseService("step", &BoardHost::onStep, this));
    ROS_INFO("%s: opening %s at %d baud", program_.c_str(), config_.serial.device.c_str(),
             config_.serial.baud);
    diag_.setHardwareID(config_.serial.device);
    diag_.add("board link", this, &BoardHost::diagnose);
    diag_timer_ = nh_.createWallTimer(ros::WallDuration(0.5),
                                      [this](const ros::WallTimerEvent&) { diag_.update(); });
    link_->start();
    // Several threads: a long init or step must not block stop/reset from the console.
    ros::AsyncSpinner spinner(3);
    spinner.start();
    ros::waitForShutdown();
    link_->stop();
    return 0;
  }

  ros::NodeHandle& nh() { return nh_; }
  ros::NodeHandle& pnh() { return pnh_; }
  const std::string& frameId() const { return frame_id_; }
  double stepTimeout() const { return step_timeout_s_; }

 private:
  void publishConnected(bool up) {
    std_msgs::Bool b;
    b.data = up;
    connected_pub_.publish(b);
  }
  void onEvent(const LinkEvent& e) {
    // BoardLink reports each transition once, so this never floods while unplugged.
    if (e.type == LinkEvent::kConnected) {
      ROS_INFO("%s: %s", program_.c_str(), e.message.c_str());
    } else {
      ROS_WARN("%s: board link down: %s", program_.c_str(), e.message.c_str());
    }
    {
      std::lock_guard<std::mutex> l(diag_mutex_);
      if (e.type == LinkEvent::kConnected) {
        ever_connected_ = true;
      } else if (ever_connected_) {
        ++drops_;
      }
      last_event_ = e.message;
    }
    publishConnected(e.type == LinkEvent::kConnected);
  }
  /// OK while connected; waiting for a board that never answered is a warning, one that went away
  /// an error. The summary names the port and what the link tried.
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& d) {
    using S = diagnostic_msgs::DiagnosticStatus;
    // The link's own state first: its lock is never held together with diag_mutex_.
    const bool connected = link_ && link_->connected();
    const auto st = link_ ? link_->decoderStats() : protocol::DecoderStats{};
    std::lock_guard<std::mutex> l(diag_mutex_);
    const std::string& port = config_.serial.device;
    if (connected) {
      d.summary(S::OK, last_event_);
    } else if (!ever_connected_) {
      d.summary(S::WARN, "waiting for " + port + (last_event_.empty() ? "" : ": " + last_event_));
    } else {
      d.summary(S::ERROR, "waiting for " + port + " to come back: " + last_event_);
    }
    d.add("port", port);
    d.add("connected", connected);
    d.add("link drops", drops_);
    d.add("frames", st.frames);
    d.add("bad CRC", st.bad_crc);
  }
  void onFrame(const protocol::Frame& f, const std::vector<std::uint8_t>& wire, bool outgoing) {
    const ros::Time now = ros::Time::now();
    if (publish_raw_) {
      raw_pub_.publish(
          conv::rawFrameMsg(now, frame_id_, config_.serial.device, f.board, outgoing, wire));
    }
    if (!outgoing && publish_state_) publish_state_(f, now);
  }
  static double orDefault(double v, double def) { return v > 0 ? v : def; }

  bool onCommand(rig_msgs::Command::Request& req, rig_msgs::Command::Response& res) {
    protocol::MsgId id;
    switch (req.command) {
      case rig_msgs::Command::Request::INIT:
        id = protocol::MsgId::kInit;
        break;
      case rig_msgs::Command::Request::START:
        id = protocol::MsgId::kStart;
        break;
      case rig_msgs::Command::Request::STOP:
        id = protocol::MsgId::kStop;
        break;
      case rig_msgs::Command::Request::RESET:
        id = protocol::MsgId::kReset;
        break;
      case rig_msgs::Command::Request::END:
        id = protocol::MsgId::kEnd;
        break;
      default:
        res.success = false;
        res.message = "unknown command " + std::to_string(req.command) +
                      " (expected INIT=1, START=3, STOP=4, RESET=5, END=6)";
        return true;
    }
    // init completes when the carriage is homed; the others when the board accepted them.
    const bool is_init = id == protocol::MsgId::kInit;
    const auto r = link_->command(
        id, {}, orDefault(req.timeout_s, is_init ? init_timeout_s_ : command_timeout_s_), is_init);
    res.success = r.success;
    res.message = r.message;
    res.seq = r.seq;
    res.status = static_cast<std::uint8_t>(r.status);
    logResult(r);
    return true;
  }
  bool onMode(rig_msgs::SetMode::Request& req, rig_msgs::SetMode::Response& res) {
    if (req.mode != 1 && req.mode != 2) {
      res.success = false;
      res.message = "mode " + std::to_string(req.mode) + " unknown (1 continuous, 2 step sequence)";
      return true;
    }
    protocol::CmdMode m;
    m.mode = req.mode;
    const auto r = link_->send(m, command_timeout_s_, false);
    res.success = r.success;
    res.message = r.message;
    res.seq = r.seq;
    logResult(r);
    return true;
  }
  bool onVers(rig_msgs::Version::Request&, rig_msgs::Version::Response& res) {
    res.components.push_back(program_);
    res.versions.push_back("0.1.0");
    res.protocol_version = protocol::kProtocolVersion;
    const auto r = link_->command(protocol::MsgId::kVers, {}, command_timeout_s_, true);
    res.success = r.success;
    res.message = r.message;
    for (const auto& f : r.replies) {
      protocol::VersionInfo v;
      if (protocol::decodePayload(f, v) != protocol::DecodeError::kNone) continue;
      res.components.push_back(v.name);
      res.versions.push_back(std::to_string(v.major) + "." + std::to_string(v.minor) + "." +
                             std::to_string(v.patch));
      res.protocol_version = v.protocol;
    }
    return true;
  }
  bool onPara(rig_msgs::Parameters::Request&, rig_msgs::Parameters::Response& res) {
    const auto r = link_->command(protocol::MsgId::kPara, {}, command_timeout_s_, true);
    res.success = r.success;
    res.message = r.message;
    for (const auto& f : r.replies) {
      protocol::ParamValue p;
      if (protocol::decodePayload(f, p) != protocol::DecodeError::kNone) continue;
      res.names.push_back(p.name);
      res.values.push_back(p.value());
    }
    return true;
  }
  bool onStep(rig_msgs::SequenceStep::Request& req, rig_msgs::SequenceStep::Response& res) {
    res.seq = req.seq;
    if (!step_) {
      res.success = false;
      res.message = program_ + " does not execute sequence steps";
      return true;
    }
    try {
      step_(*link_, req, res, orDefault(req.timeout_s, step_timeout_s_));
    } catch (const std::exception& e) {
      res.success = false;
      res.message = program_ + ": step failed: " + e.what();
    }
    return true;
  }
  void logResult(const CommandResult& r) {
    if (r.success) {
      ROS_INFO("%s: %s", program_.c_str(), r.message.c_str());
    } else {
      ROS_WARN("%s: %s", program_.c_str(), r.message.c_str());
    }
  }

  ros::NodeHandle nh_, pnh_;
  protocol::BoardId board_;
  std::string program_;
  BoardLinkConfig config_;
  double command_timeout_s_ = 5.0, init_timeout_s_ = 120.0, step_timeout_s_ = 60.0;
  bool publish_raw_ = true;
  std::string frame_id_;
  std::unique_ptr<BoardLink> link_;
  ros::Publisher raw_pub_, connected_pub_;
  std::vector<ros::ServiceServer> services_;
  diagnostic_updater::Updater diag_;
  ros::WallTimer diag_timer_;
  std::mutex diag_mutex_;  ///< guards the three below (link events arrive on the IO thread)
  bool ever_connected_ = false;
  unsigned drops_ = 0;
  std::string last_event_;
  StatePublisher publish_state_;
  StepHandler step_;
};

/// Fills the common part of a step response from a command result.
inline void fillStepResult(const CommandResult& r, rig_msgs::SequenceStep::Response& res) {
  res.success = r.success;
  res.message = r.message;
  res.seq = r.seq;
  res.status = static_cast<std::uint8_t>(r.status);
}

/// Executes a TARGET_WAIT step (a board-side wait of a mode 2 sequence) and fills `res`; false
/// when the step was rejected before reaching the board (wait_s out of range).
inline bool runWaitStep(BoardLink& link, const rig_msgs::SequenceStep::Request& req,
                        rig_msgs::SequenceStep::Response& res, double timeout_s) {
  if (!(req.wait_s >= 0 && req.wait_s < 3600)) {
    res.success = false;
    res.message = "wait step rejected: wait_s must be in [0, 3600) s";
    return false;
  }
  protocol::CmdWait w;
  w.wait_ms = static_cast<std::uint32_t>(std::lround(req.wait_s * 1e3));
  fillStepResult(link.send(w, timeout_s + req.wait_s, true, req.seq), res);
  return true;
}

/// Answers a step whose target this board does not execute (`accepted`: the targets it does).
inline void rejectStepTarget(const std::string& program, const std::string& accepted,
                             std::uint8_t target, rig_msgs::SequenceStep::Response& res) {
  res.success = false;
  res.message =
      program + " executes " + accepted + " steps only (got target " + std::to_string(target) + ")";
}

}  // namespace rig_drivers
