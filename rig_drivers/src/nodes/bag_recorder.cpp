// bag_recorder: the rigs' recording. Runs rosbag record (split by size, compressed) into ~bag_dir,
// which it creates when missing, and keeps it running: when the recorder stops on its own (disk
// below the reserve, folder removed, no permission, a crash) it says so by name in the log and on
// /diagnostics, with the bags it closed and any it left unindexed, and starts it again once the
// folder allows. Nothing else depends on it, so drivers and tracking go on either way. Ctrl-C
// reaches rosbag record with roslaunch's SIGINT: the open bag is closed and indexed.
// Logic: RecorderSupervisor (rig_recording). Parameters: config/drivers.yaml.
#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/package.h>
#include <ros/ros.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "rig_drivers/recording/recorder_supervisor.hpp"

using namespace rig_drivers;

namespace {

double steadyS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

/// "~/x" and "$HOME/x" as the shell would read them (roslaunch passes arguments verbatim).
std::string expandHome(const std::string& p) {
  const char* home = ::getenv("HOME");
  if (home && (p == "~" || p.rfind("~/", 0) == 0)) return home + p.substr(1);
  return p;
}

/// rosbag's record executable: <prefix>/lib/rosbag/record beside <prefix>/share/rosbag (Debian's
/// /usr and /opt/ros/<distro> alike), run directly so the recorder subscribes as early as the
/// drivers publish; else through rosrun.
std::vector<std::string> recordCommandHead() {
  const std::string share = ros::package::getPath("rosbag");
  const std::string suffix = "/share/rosbag";
  if (share.size() > suffix.size() &&
      share.compare(share.size() - suffix.size(), suffix.size(), suffix) == 0) {
    const std::string exe = share.substr(0, share.size() - suffix.size()) + "/lib/rosbag/record";
    if (::access(exe.c_str(), X_OK) == 0) return {exe};
  }
  return {"rosrun", "rosbag", "record"};
}

std::vector<std::string> splitWords(const std::string& s) {
  std::istringstream in(s);
  std::vector<std::string> out;
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

class BagRecorderNode {
 public:
  bool init() {
    ros::NodeHandle pnh("~");
    RecorderConfig c;
    std::string topics;
    pnh.param<std::string>("bag_dir", c.bag_dir, "");
    c.bag_dir = expandHome(c.bag_dir);
    while (c.bag_dir.size() > 1 && c.bag_dir.back() == '/') c.bag_dir.pop_back();
    pnh.param<std::string>("bag_prefix", c.bag_prefix, c.bag_prefix);
    pnh.param<std::string>("topics", topics, "");
    c.topics = splitWords(topics);
    pnh.param("split_size_mb", c.split_size_mb, c.split_size_mb);
    pnh.param<std::string>("compression", c.compression, c.compression);
    pnh.param("min_free_mb", c.min_free_mb, c.min_free_mb);
    pnh.param("restart_period_s", c.restart_period_s, c.restart_period_s);
    pnh.param("max_restart_period_s", c.max_restart_period_s, c.max_restart_period_s);
    // The recorder process is named after this node, so rosnode list shows whose it is.
    const std::string me = ros::this_node::getName();
    c.recorder = recordCommandHead();
    c.recorder.push_back("__name:=" + me.substr(me.rfind('/') + 1) + "_rosbag");
    const auto problems = c.validate();
    if (!problems.empty()) {
      std::string msg;
      for (const auto& p : problems) msg += "\n  - ~" + p;
      ROS_FATAL("bag_recorder: invalid parameters (see config/drivers.yaml):%s", msg.c_str());
      return false;
    }
    supervisor_ = std::make_unique<RecorderSupervisor>(
        c, [](const RecorderEvent& e) { log(e.level, e.message); },
        // The recorder's error lines, as it wrote them, into this node's output.
        [](const std::string& line) { std::fprintf(stderr, "%s\n", line.c_str()); });
    diag_.setHardwareID(c.bag_dir);
    diag_.add("recording", this, &BagRecorderNode::diagnose);
    return true;
  }

  int spin() {
    ros::WallRate rate(10);
    double next_topics_s = 0;
    while (ros::ok()) {
      const double now = steadyS();
      supervisor_->step(now);
      if (now >= next_topics_s) {
        next_topics_s = now + 2.0;
        updateSilentTopics();
      }
      // A reminder every minute while nothing records (the stop itself was reported at once).
      const RecorderStatus s = supervisor_->status();
      if (s.state != RecorderState::kWaiting) {
        remind_at_ = 0;
      } else if (remind_at_ == 0) {
        remind_at_ = now + 60;
      } else if (now >= remind_at_) {
        remind_at_ = now + 60;
        ROS_ERROR("bag_recorder: still %s", s.summary.c_str());
      }
      diag_.update();
      ros::spinOnce();
      rate.sleep();
    }
    // roslaunch's SIGINT went to the recorder too; stop() waits for it to close its bag (and
    // sends the SIGINT itself when this node was shut down otherwise). roslaunch escalates after
    // 15 s.
    supervisor_->stop(14.0);
    return 0;
  }

 private:
  static void log(int level, const std::string& m) {
    if (level >= 2) {
      ROS_ERROR("bag_recorder: %s", m.c_str());
    } else if (level == 1) {
      ROS_WARN("bag_recorder: %s", m.c_str());
    } else {
      ROS_INFO("bag_recorder: %s", m.c_str());
    }
  }
  /// Topics to record that nobody publishes yet: what the recording waits for.
  void updateSilentTopics() {
    ros::master::V_TopicInfo advertised;
    if (!ros::master::getTopics(advertised)) return;
    std::set<std::string> have;
    for (const auto& t : advertised) have.insert(t.name);
    silent_.clear();
    for (const auto& t : supervisor_->config().topics) {
      const std::string name = ros::names::resolve(t);
      if (!have.count(name)) silent_.push_back(name);
    }
  }
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& d) {
    using S = diagnostic_msgs::DiagnosticStatus;
    const RecorderStatus s = supervisor_->status();
    std::string summary = s.summary;
    int level = s.level;
    if (s.state == RecorderState::kRecording && !silent_.empty()) {
      summary += "; waiting for publishers on";
      for (const auto& t : silent_) summary += " " + t;
      level = std::max(level, 1);
    }
    d.summary(level == 0 ? S::OK : level == 1 ? S::WARN : S::ERROR, summary);
    d.add("bag folder", supervisor_->config().bag_dir);
    d.add("recording", s.state == RecorderState::kRecording);
    d.add("open bag", s.active_bag);
    d.addf("open bag (MB)", "%.1f", s.active_bytes * 1e-6);
    d.add("bags closed", s.closed_bags);
    d.addf("bags closed (MB)", "%.1f", s.closed_bytes * 1e-6);
    d.add("bags left unindexed", s.unindexed_bags);
    d.addf("free (MB)", "%.0f", s.free_bytes ? *s.free_bytes * 1e-6 : -1.0);
    d.add("recorder starts", s.starts);
    d.add("last recorder error", s.last_error);
  }

  std::unique_ptr<RecorderSupervisor> supervisor_;
  diagnostic_updater::Updater diag_;
  std::vector<std::string> silent_;
  double remind_at_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "bag_recorder");
  BagRecorderNode node;
  if (!node.init()) return 1;
  return node.spin();
}
