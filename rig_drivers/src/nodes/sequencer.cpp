// sequencer: runs a mode 2 step script (config/sequences/*.txt). The whole script is parsed and
// checked first; a malformed one is rejected with its line number before anything moves. Then it
// puts the boards in mode 2 and sends each step to its driver's ~step service, which returns once
// the board acknowledged the step's sequence number as done; `frame` waits until the carriage is
// still and triggers exactly one depth frame. Parameters: config/drivers.yaml.
#include <ros/ros.h>
#include <std_msgs/Bool.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>

#include <atomic>
#include <cmath>
#include <mutex>

#include "rig_drivers/sequencing/step_script.hpp"
#include "rig_msgs/Command.h"
#include "rig_msgs/SequenceStep.h"
#include "rig_msgs/SetMode.h"
#include "rig_msgs/TrackState.h"

using rig_drivers::Step;
using rig_drivers::StepKind;

namespace {

class Sequencer {
 public:
  bool init() {
    ros::NodeHandle pnh("~");
    rig_drivers::StepLimits lim;
    int max_steps = static_cast<int>(lim.max_steps);
    pnh.param<std::string>("script", script_path_, "");
    pnh.param<std::string>("track_step_service", track_step_, "track_host/step");
    pnh.param<std::string>("track_mode_service", track_mode_, "track_host/mode");
    pnh.param<std::string>("track_command_service", track_command_, "track_host/command");
    pnh.param("init_first", init_first_, false);
    pnh.param<std::string>("car_step_service", car_step_, "");
    pnh.param<std::string>("car_mode_service", car_mode_, "");
    pnh.param<std::string>("camera_trigger_service", camera_trigger_, "depth_camera/trigger");
    pnh.param<std::string>("track_state_topic", track_state_topic_, "track_state");
    pnh.param("still_frames", still_frames_, 3);
    pnh.param("still_speed_mps", still_speed_mps_, 0.0005);
    pnh.param("still_timeout_s", still_timeout_s_, 10.0);
    pnh.param("step_timeout_s", step_timeout_s_, 60.0);
    pnh.param("service_wait_s", service_wait_s_, 30.0);
    pnh.param("track_length_mm", lim.track_length_mm, lim.track_length_mm);
    pnh.param("max_speed_mm_s", lim.max_speed_mm_s, lim.max_speed_mm_s);
    pnh.param("max_pitch_deg", lim.max_pitch_deg, lim.max_pitch_deg);
    pnh.param("max_yaw_deg", lim.max_yaw_deg, lim.max_yaw_deg);
    pnh.param("max_steps", max_steps, max_steps);
    lim.max_steps = static_cast<std::size_t>(std::max(0, max_steps));
    status_pub_ = pnh.advertise<std_msgs::String>("status", 1, true);

    std::vector<std::string> problems;
    if (script_path_.empty()) problems.push_back("~script (path of a step script) is required");
    if (still_frames_ < 1 || still_frames_ > 300) problems.push_back("~still_frames in [1, 300]");
    if (!(still_speed_mps_ >= 0)) problems.push_back("~still_speed_mps must be >= 0 (m/s)");
    if (!(still_timeout_s_ > 0)) problems.push_back("~still_timeout_s must be > 0 (s)");
    if (!(step_timeout_s_ > 0)) problems.push_back("~step_timeout_s must be > 0 (s)");
    if (!problems.empty()) {
      std::string msg;
      for (const auto& p : problems) msg += "\n  - " + p;
      return fail("invalid parameters (see config/drivers.yaml):" + msg);
    }
    try {
      script_ = rig_drivers::loadStepScript(script_path_, lim);
    } catch (const rig_drivers::StepScriptError& e) {
      return fail(std::string("script rejected, nothing was moved: ") + e.what());
    }
    for (const Step& s : script_.steps) {
      if ((s.kind == StepKind::kPitch || s.kind == StepKind::kYaw) && car_step_.empty())
        return fail(script_path_ + ":" + std::to_string(s.line) + ": '" +
                    rig_drivers::stepKeyword(s.kind) +
                    "' needs the gimbal, but ~car_step_service is empty; nothing was moved");
      if ((s.kind == StepKind::kMove || s.kind == StepKind::kGoto) && track_step_.empty())
        return fail(script_path_ + ":" + std::to_string(s.line) +
                    ": track move but ~track_step_service is empty; nothing was moved");
    }
    ros::NodeHandle nh;
    state_sub_ = nh.subscribe(track_state_topic_, 50, &Sequencer::onState, this);
    ROS_INFO("sequencer: %s: %zu steps, %zu frames", script_path_.c_str(), script_.steps.size(),
             script_.frameCount());
    return true;
  }

  /// Runs the script; returns the process exit code.
  int run() {
    ros::AsyncSpinner spinner(1);
    spinner.start();
    // Every service must be there before the first step: a half-run sequence is worse than none.
    std::vector<std::string> needed{camera_trigger_};
    if (!track_step_.empty()) needed.push_back(track_step_);
    if (!track_mode_.empty()) needed.push_back(track_mode_);
    if (init_first_) needed.push_back(track_command_);
    if (!car_step_.empty()) needed.push_back(car_step_);
    if (!car_mode_.empty()) needed.push_back(car_mode_);
    for (const auto& s : needed)
      if (!ros::service::waitForService(s, ros::Duration(service_wait_s_))) {
        fail("service " + s + " not available after " + std::to_string(service_wait_s_) +
             " s; nothing was moved");
        return 1;
      }
    // A driver serves its services before its board link is up: wait for "<driver>/connected".
    for (const auto& step_srv : {track_step_, car_step_}) {
      const auto slash = step_srv.rfind('/');
      if (step_srv.empty() || slash == std::string::npos) continue;
      const std::string topic = step_srv.substr(0, slash) + "/connected";
      if (!waitConnected(topic)) {
        fail("driver not connected to its board (" + topic + ") after " +
             std::to_string(service_wait_s_) + " s; nothing was moved");
        return 1;
      }
    }
    if (init_first_) {  // home the carriage (TrackDRV refuses moves until initialised)
      rig_msgs::Command init;
      init.request.command = rig_msgs::Command::Request::INIT;
      if (!ros::service::call(track_command_, init) || !init.response.success) {
        fail("init through " + track_command_ + " failed: " + init.response.message);
        return 1;
      }
    }
    for (const auto& m : {track_mode_, car_mode_}) {
      if (m.empty()) continue;
      rig_msgs::SetMode mode;
      mode.request.mode = rig_msgs::SetMode::Request::STEP_SEQUENCE;
      if (!ros::service::call(m, mode) || !mode.response.success) {
        fail("could not set mode 2 through " + m + ": " + mode.response.message);
        return 1;
      }
    }
    publishStatus("running");
    std::size_t frames = 0, index = 0;
    for (const Step& s : script_.steps) {
      ++index;
      if (!ros::ok()) return 1;
      std::string why;
      if (!execute(s, &why)) {
        publishStatus("failed");
        ROS_ERROR("sequencer: step %zu/%zu (%s:%d '%s') failed: %s", index, script_.steps.size(),
                  script_path_.c_str(), s.line, rig_drivers::stepKeyword(s.kind), why.c_str());
        return 1;
      }
      frames += s.kind == StepKind::kFrame;
    }
    ROS_INFO("sequencer: done: %zu steps, %zu frames", script_.steps.size(), frames);
    publishStatus("done " + std::to_string(frames) + " frames");
    ros::WallDuration(0.5).sleep();  // let the latched status go out
    return 0;
  }

 private:
  bool fail(const std::string& why) {
    ROS_FATAL("sequencer: %s", why.c_str());
    publishStatus("rejected: " + why);
    return false;
  }
  void publishStatus(const std::string& s) {
    std_msgs::String m;
    m.data = s;
    status_pub_.publish(m);
  }
  void onState(const rig_msgs::TrackState& s) {
    const bool still = s.state != rig_msgs::TrackState::STATE_MOVING &&
                       s.state != rig_msgs::TrackState::STATE_HOMING &&
                       std::fabs(s.velocity_mps) <= still_speed_mps_;
    std::lock_guard<std::mutex> l(mutex_);
    still_count_ = still ? still_count_ + 1 : 0;
    ++states_;
  }
  /// Waits for `still_frames_` consecutive still track states received after this call.
  bool waitStill(std::string* why) {
    {
      std::lock_guard<std::mutex> l(mutex_);
      still_count_ = 0;
    }
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(still_timeout_s_);
    while (ros::ok() && ros::WallTime::now() < end) {
      {
        std::lock_guard<std::mutex> l(mutex_);
        if (still_count_ >= still_frames_) return true;
      }
      ros::WallDuration(0.005).sleep();
    }
    std::lock_guard<std::mutex> l(mutex_);
    *why = states_ == 0 ? "no track state on " + track_state_topic_ + " (is track_host running?)"
                        : "carriage not still within " + std::to_string(still_timeout_s_) + " s";
    return false;
  }
  bool waitConnected(const std::string& topic) {
    std::atomic<bool> up{false};
    ros::NodeHandle nh;
    auto sub = nh.subscribe<std_msgs::Bool>(
        topic, 1, [&up](const std_msgs::BoolConstPtr& b) { up = b->data; });
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(service_wait_s_);
    while (ros::ok() && !up && ros::WallTime::now() < end) ros::WallDuration(0.02).sleep();
    return up;
  }
  bool callStep(const std::string& service, rig_msgs::SequenceStep& st, std::string* why) {
    st.request.timeout_s = step_timeout_s_;
    if (!ros::service::call(service, st)) {
      *why = "service " + service + " call failed";
      return false;
    }
    if (!st.response.success) {
      *why = st.response.message;
      return false;
    }
    ROS_DEBUG("sequencer: %s", st.response.message.c_str());
    return true;
  }
  bool execute(const Step& s, std::string* why) {
    using Req = rig_msgs::SequenceStep::Request;
    rig_msgs::SequenceStep st;
    switch (s.kind) {
      case StepKind::kSpeed:
        speed_mm_s_ = s.value;
        return true;
      case StepKind::kMove:
      case StepKind::kGoto:
        st.request.target = Req::TARGET_TRACK;
        st.request.relative = s.kind == StepKind::kMove;
        st.request.track_pos_m = s.value * 1e-3;
        st.request.max_speed_mps = speed_mm_s_ * 1e-3;
        return callStep(track_step_, st, why);
      case StepKind::kPitch:
      case StepKind::kYaw:
        (s.kind == StepKind::kPitch ? pitch_deg_ : yaw_deg_) = s.value;
        st.request.target = Req::TARGET_GIMBAL;
        st.request.pitch_deg = pitch_deg_;
        st.request.yaw_deg = yaw_deg_;
        return callStep(car_step_, st, why);
      case StepKind::kWait:
        if (track_step_.empty()) {
          ros::WallDuration(s.value * 1e-3).sleep();
          return true;
        }
        st.request.target = Req::TARGET_WAIT;
        st.request.wait_s = s.value * 1e-3;
        return callStep(track_step_, st, why);
      case StepKind::kFrame: {
        if (!track_step_.empty() && !waitStill(why)) return false;
        std_srvs::Trigger t;
        if (!ros::service::call(camera_trigger_, t)) {
          *why = "camera trigger " + camera_trigger_ + " call failed";
          return false;
        }
        if (!t.response.success) {
          *why = "camera: " + t.response.message;
          return false;
        }
        return true;
      }
    }
    *why = "unknown step";
    return false;
  }

  bool init_first_ = false;
  std::string track_command_;
  std::string script_path_, track_step_, track_mode_, car_step_, car_mode_, camera_trigger_,
      track_state_topic_;
  int still_frames_ = 3;
  double still_speed_mps_ = 0.0005, still_timeout_s_ = 10, step_timeout_s_ = 60,
         service_wait_s_ = 30;
  rig_drivers::StepScript script_;
  double speed_mm_s_ = 0, pitch_deg_ = 0, yaw_deg_ = 0;
  ros::Publisher status_pub_;
  ros::Subscriber state_sub_;
  std::mutex mutex_;
  int still_count_ = 0;
  long states_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "sequencer");
  Sequencer seq;
  if (!seq.init()) {
    ros::WallDuration(0.3).sleep();  // let the latched status reach subscribers
    return 1;
  }
  return seq.run();
}
