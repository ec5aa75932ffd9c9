#pragma once
// Shared by the rig_drivers rostests that run the rigs' launch files as a user does: a child
// process (roslaunch, rosrun) on the rostest's master, /diagnostics collected by status name,
// nodes pinged through their XML-RPC, bags read back through their index.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dirent.h>
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <ros/master.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "wait_until.hpp"

extern char** environ;

namespace rig_drivers::test {

/// A command run as a child (output into the test's log) until stop(); `env` adds NAME=value
/// entries to the inherited environment.
class Child {
 public:
  explicit Child(const std::vector<std::string>& argv, const std::vector<std::string>& env = {}) {
    std::vector<std::string> envs(env);
    for (char** e = environ; *e; ++e) envs.push_back(*e);
    // argv and envp are built before fork: the child only calls async-signal-safe functions.
    std::vector<char*> a, e;
    for (const auto& s : argv) a.push_back(const_cast<char*>(s.c_str()));
    for (const auto& s : envs) e.push_back(const_cast<char*>(s.c_str()));
    a.push_back(nullptr);
    e.push_back(nullptr);
    pid_ = ::fork();
    if (pid_ == 0) {
      ::execvpe(a[0], a.data(), e.data());
      ::_exit(127);
    }
  }
  ~Child() { stop(20.0); }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  /// SIGINT (Ctrl-C), then waits up to timeout_s (SIGKILL after it); true when it stopped in time.
  bool stop(double timeout_s) {
    if (pid_ <= 0) return true;
    ::kill(pid_, SIGINT);
    bool gone = waitUntil([&] { return ::waitpid(pid_, &status_, WNOHANG) == pid_; }, timeout_s);
    if (!gone) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, &status_, 0);
    }
    pid_ = -1;
    return gone;
  }
  bool running() {
    if (pid_ > 0 && ::waitpid(pid_, &status_, WNOHANG) == pid_) pid_ = -1;
    return pid_ > 0;
  }
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
  int status_ = 0;
};

/// The latest status of every diagnostics task, by its name ("track_host: board link").
class Diagnostics {
 public:
  Diagnostics() { sub_ = nh_.subscribe("/diagnostics", 100, &Diagnostics::on, this); }
  std::optional<diagnostic_msgs::DiagnosticStatus> get(const std::string& name) {
    std::lock_guard<std::mutex> l(m_);
    auto it = latest_.find(name);
    if (it == latest_.end()) return std::nullopt;
    return it->second;
  }
  /// True once the task's summary contains `text` (and its level is `level`, when given).
  bool waitFor(const std::string& name, const std::string& text, double timeout_s, int level = -1) {
    return waitUntil([&] { return has(name, text, level); }, timeout_s);
  }
  bool has(const std::string& name, const std::string& text, int level = -1) {
    const auto s = get(name);
    return s && s->message.find(text) != std::string::npos && (level < 0 || s->level == level);
  }
  /// A key's value of the task's latest status ("" when absent).
  std::string value(const std::string& name, const std::string& key) {
    const auto s = get(name);
    if (s)
      for (const auto& kv : s->values)
        if (kv.key == key) return kv.value;
    return "";
  }
  std::string describe(const std::string& name) {
    const auto s = get(name);
    return s ? "[" + std::to_string(s->level) + "] " + s->message : "(no status from " + name + ")";
  }

 private:
  void on(const diagnostic_msgs::DiagnosticArray& a) {
    std::lock_guard<std::mutex> l(m_);
    for (const auto& s : a.status) latest_[s.name] = s;
  }
  ros::NodeHandle nh_;
  ros::Subscriber sub_;
  std::mutex m_;
  std::map<std::string, diagnostic_msgs::DiagnosticStatus> latest_;
};

/// The pid a node reports through its XML-RPC server, or -1 when it does not answer (gone).
inline int nodePid(const std::string& node) {
  XmlRpc::XmlRpcValue req, resp, payload;
  req[0] = ros::this_node::getName();
  req[1] = node;
  if (!ros::master::execute("lookupNode", req, resp, payload, false)) return -1;
  std::string host;
  std::uint32_t port = 0;
  if (!ros::network::splitURI(static_cast<std::string>(resp[2]), host, port)) return -1;
  XmlRpc::XmlRpcClient c(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue r2, p2;
  r2[0] = ros::this_node::getName();
  if (!c.execute("getPid", r2, p2) || c.isFault() || !p2.valid() || p2.size() < 3 ||
      static_cast<int>(p2[0]) != 1)
    return -1;
  return static_cast<int>(p2[2]);
}

/// Nodes subscribed to `topic`, from the master.
inline std::vector<std::string> subscribersOf(const std::string& topic) {
  XmlRpc::XmlRpcValue req, resp, payload;
  req[0] = ros::this_node::getName();
  std::vector<std::string> out;
  if (!ros::master::execute("getSystemState", req, resp, payload, false)) return out;
  const XmlRpc::XmlRpcValue& subs = payload[1];
  for (int i = 0; i < subs.size(); ++i)
    if (static_cast<std::string>(subs[i][0]) == topic)
      for (int j = 0; j < subs[i][1].size(); ++j) out.push_back(subs[i][1][j]);
  return out;
}

/// File names in `dir` ending in `suffix`, sorted.
inline std::vector<std::string> filesEndingIn(const std::string& dir, const std::string& suffix) {
  std::vector<std::string> out;
  if (DIR* d = ::opendir(dir.c_str())) {
    while (dirent* e = ::readdir(d)) {
      const std::string n = e->d_name;
      if (n.size() >= suffix.size() &&
          n.compare(n.size() - suffix.size(), suffix.size(), suffix) == 0)
        out.push_back(n);
    }
    ::closedir(d);
  }
  std::sort(out.begin(), out.end());
  return out;
}

/// Messages per topic in a bag, read through its index (throws rosbag::BagException when the bag
/// has none, as a bag left open has).
inline std::map<std::string, int> topicCounts(const std::string& path) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  std::map<std::string, int> n;
  for (const auto& m : view) ++n[m.getTopic()];
  return n;
}

/// A fresh folder under /tmp.
inline std::string tempDir(const char* stem) {
  std::string t = std::string("/tmp/") + stem + "XXXXXX";
  std::vector<char> buf(t.begin(), t.end());
  buf.push_back('\0');
  const char* d = ::mkdtemp(buf.data());
  return d ? d : "/tmp";
}

/// The sim camera's pose (T_W_C, its optical frame in the map) 0.8 m up in the chair room,
/// looking along the world x axis at the chair, moved by (x_m, y_m).
inline geometry_msgs::PoseStamped chairViewPose(const ros::Time& stamp, double x_m, double y_m) {
  geometry_msgs::PoseStamped p;
  p.header.stamp = stamp;
  p.header.frame_id = "map";
  p.pose.position.x = x_m;
  p.pose.position.y = y_m;
  p.pose.position.z = 0.8;
  p.pose.orientation.x = -0.5;  // optical z = world x, x = -y, y = -z
  p.pose.orientation.y = 0.5;
  p.pose.orientation.z = -0.5;
  p.pose.orientation.w = 0.5;
  return p;
}

/// main() of a rostest node: gtest, ROS with two spinner threads, shutdown before returning.
inline int rostestMain(int argc, char** argv, const char* node_name) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, node_name);
  ros::NodeHandle nh;
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}

}  // namespace rig_drivers::test
