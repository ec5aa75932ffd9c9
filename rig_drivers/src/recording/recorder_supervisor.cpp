#include "rig_drivers/recording/recorder_supervisor.hpp"

#include <signal.h>
#include <sys/wait.h>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <thread>
#include <utility>

namespace rig_drivers {

namespace {

/// A recorder started with less room than a few of rosbag's 768 KiB chunks fails at once.
constexpr std::uint64_t kStartRoomBytes = 4 * 768 * 1024;
/// A bag file this small holds its version line and file header only: no message.
constexpr std::uint64_t kEmptyBagBytes = 13 + 4096;

/// The reserve in bytes: rosbag record reads --min-space=<n>M as n MiB.
std::uint64_t reserveBytes(const RecorderConfig& c) {
  return static_cast<std::uint64_t>(c.min_free_mb) * 1024 * 1024;
}

std::string seconds(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g s", s);
  return buf;
}

/// A rosconsole line without its colour codes.
std::string plain(const std::string& line) {
  std::string out;
  for (std::size_t i = 0; i < line.size(); ++i) {
    if (line[i] == '\x1b' && i + 1 < line.size() && line[i + 1] == '[') {
      i += 2;
      while (i < line.size() && !(line[i] >= '@' && line[i] <= '~')) ++i;
      continue;
    }
    out += line[i];
  }
  return out;
}

/// The message of an error line ("[ERROR] [stamp]: message"), or "" for any other line.
std::string errorMessage(const std::string& raw) {
  const std::string line = plain(raw);
  const bool error = line.rfind("[ERROR]", 0) == 0 || line.rfind("[FATAL]", 0) == 0;
  const bool exec_failed = line.rfind("cannot run ", 0) == 0;
  if (!error && !exec_failed) return "";
  if (exec_failed) return line;
  const std::size_t colon = line.find("]: ");
  return colon == std::string::npos ? line.substr(7) : line.substr(colon + 3);
}

std::string describeExit(int st) {
  if (WIFEXITED(st)) return "exited with status " + std::to_string(WEXITSTATUS(st));
  if (WIFSIGNALED(st)) {
    const int sig = WTERMSIG(st);
    return "was killed by signal " + std::to_string(sig) + " (" + ::strsignal(sig) + ")";
  }
  return "stopped (wait status " + std::to_string(st) + ")";
}

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

}  // namespace

std::vector<std::string> RecorderConfig::validate() const {
  std::vector<std::string> p;
  if (bag_dir.empty() || bag_dir[0] != '/')
    p.push_back("bag_dir must be an absolute path (got '" + bag_dir + "')");
  if (bag_prefix.empty() || bag_prefix.find('/') != std::string::npos)
    p.push_back("bag_prefix must be a non-empty file name prefix without '/'");
  if (topics.empty()) p.push_back("topics: nothing to record");
  if (split_size_mb < 1 || split_size_mb > 1048576)
    p.push_back("split_size_mb must be in [1, 1048576] MiB");
  if (compression != "none" && compression != "lz4" && compression != "bz2")
    p.push_back("compression must be none, lz4 or bz2 (got '" + compression + "')");
  if (min_free_mb < 0 || min_free_mb > 1048576)
    p.push_back("min_free_mb must be in [0, 1048576] MiB");
  if (!(restart_period_s >= 0.1 && restart_period_s <= 3600))
    p.push_back("restart_period_s must be in [0.1, 3600] s");
  if (!(max_restart_period_s >= restart_period_s && max_restart_period_s <= 86400))
    p.push_back("max_restart_period_s must be in [restart_period_s, 86400] s");
  if (!(check_period_s >= 0.05 && check_period_s <= 60))
    p.push_back("check_period_s must be in [0.05, 60] s");
  if (recorder.empty()) p.push_back("recorder: no command");
  return p;
}

std::vector<std::string> recordCommand(const RecorderConfig& c) {
  std::vector<std::string> a = c.recorder;
  a.push_back("--split");
  a.push_back("--size=" + std::to_string(c.split_size_mb));
  if (c.compression != "none") a.push_back("--" + c.compression);
  // rosbag record closes its bag and stops once the file system has less than this free.
  a.push_back("--min-space=" + std::to_string(c.min_free_mb) + "M");
  a.push_back("-o");
  a.push_back(c.bag_dir + "/" + c.bag_prefix);
  a.insert(a.end(), c.topics.begin(), c.topics.end());
  return a;
}

RecorderSupervisor::RecorderSupervisor(RecorderConfig config, EventHandler on_event,
                                       OutputHandler on_output)
    : config_(std::move(config)),
      on_event_(std::move(on_event)),
      on_output_(std::move(on_output)),
      period_s_(config_.restart_period_s) {
  const auto problems = config_.validate();
  if (!problems.empty()) {
    std::string msg = "invalid recorder settings:";
    for (const auto& p : problems) msg += " " + p + ";";
    throw std::invalid_argument(msg);
  }
  const auto before = listBags(config_.bag_dir, config_.bag_prefix);
  for (const auto* v : {&before.closed, &before.active})
    for (const auto& b : *v) known_before_.push_back(b.name);
}

RecorderSupervisor::~RecorderSupervisor() { stop(10.0); }

void RecorderSupervisor::report(int level, const std::string& message) {
  if (on_event_) on_event_({level, message});
}

void RecorderSupervisor::forwardOutput() {
  std::vector<std::string> lines;
  child_.readLines(&lines);
  for (const auto& l : lines) {
    if (on_output_) on_output_(l);
    const std::string e = errorMessage(l);
    if (!e.empty() && first_error_.empty()) first_error_ = e;  // the cause; later ones follow it
  }
}

void RecorderSupervisor::step(double now_s) {
  forwardOutput();
  if (child_.running()) {
    int st = 0;
    if (child_.reap(&st)) {
      forwardOutput();
      onExit(st, now_s);
    } else if (now_s >= next_check_s_) {
      next_check_s_ = now_s + config_.check_period_s;
      checkFolder(now_s);
    }
  }
  if (!child_.running() && state_ == RecorderState::kWaiting) tryStart(now_s);
}

void RecorderSupervisor::tryStart(double now_s) {
  if (now_s < next_start_s_) return;
  const std::string& dir = config_.bag_dir;
  std::string why;
  if (ensureFolder(dir, &why)) {
    const auto free = freeBytes(dir);
    const std::uint64_t reserve = reserveBytes(config_);
    if (free && *free < reserve) {
      why = "only " + humanBytes(*free) + " free on the file system of " + dir +
            ", below the reserve of " + std::to_string(config_.min_free_mb) +
            " MiB (min_free_mb): free some space";
    } else if (free && *free < kStartRoomBytes) {
      why =
          "only " + humanBytes(*free) + " free on the file system of " + dir + ": the disk is full";
    }
  }
  if (why.empty()) {
    folder_ = folderId(dir);
    closed_at_start_ = status().closed_bags;
    first_error_.clear();
    removed_note_.clear();
    if (!child_.start(recordCommand(config_), &why)) why = "cannot start the recorder: " + why;
  }
  if (!why.empty()) {
    next_start_s_ = now_s + config_.restart_period_s;
    if (why != folder_problem_)  // once per reason, not once per attempt
      report(2,
             "not recording: " + why + "; trying again every " + seconds(config_.restart_period_s));
    folder_problem_ = why;
    return;
  }
  folder_problem_.clear();
  stopped_reason_.clear();
  state_ = RecorderState::kRecording;
  next_check_s_ = now_s + config_.check_period_s;
  ++starts_;
  report(0, std::string(starts_ == 1 ? "recording " : "recording again: ") +
                std::to_string(config_.topics.size()) + " topics into " + dir + "/" +
                config_.bag_prefix + "_*.bag (a new bag every " +
                std::to_string(config_.split_size_mb) + " MiB, " + config_.compression +
                "; the recorder stops below " + std::to_string(config_.min_free_mb) + " MiB free)");
}

void RecorderSupervisor::checkFolder(double) {
  const auto id = folderId(config_.bag_dir);
  if (removed_note_.empty() && !(id && folder_ && *id == *folder_)) {
    removed_note_ = "the bag folder " + config_.bag_dir +
                    " was removed while recording (the open bag went with it)";
    report(2, removed_note_ +
                  ": stopping the recorder; the folder is made again and recording "
                  "goes on in a new bag");
    child_.signal(SIGINT);
  }
}

void RecorderSupervisor::onExit(int wait_status, double now_s) {
  const RecorderStatus s = status();
  std::string bags = std::to_string(s.closed_bags) + " bags closed and readable in " +
                     config_.bag_dir + " (" + humanBytes(s.closed_bytes) + ")";
  for (const auto& b : listBags(config_.bag_dir, config_.bag_prefix).active) {
    if (contains(known_before_, b.name) || contains(reported_open_, b.name)) continue;
    const std::string path = config_.bag_dir + "/" + b.name;
    if (b.bytes <= kEmptyBagBytes && ::unlink(path.c_str()) == 0) {
      bags += "; removed " + b.name + " (no message in it)";
      continue;
    }
    reported_open_.push_back(b.name);
    bags += "; " + b.name + " was left open and is not indexed: once the disk has room, run " +
            "rosbag reindex " + path;
  }
  if (state_ == RecorderState::kStopping) {
    state_ = RecorderState::kStopped;
    report(0, "recorder stopped, " + bags);
    return;
  }
  state_ = RecorderState::kWaiting;
  const bool closed_some = s.closed_bags > closed_at_start_;
  if (closed_some) period_s_ = config_.restart_period_s;
  next_start_s_ = now_s + period_s_;
  std::string why = "the recorder " + describeExit(wait_status);
  if (!first_error_.empty()) why += ": " + first_error_;
  if (!removed_note_.empty()) why += "; " + removed_note_;
  stopped_reason_ = why;
  const std::string room =
      config_.min_free_mb > 0 ? " with " + std::to_string(config_.min_free_mb) + " MiB free" : "";
  report(2, "recording into " + config_.bag_dir + " stopped: " + why + "; " + bags +
                "; starting it again in " + seconds(period_s_) + " once the folder is writable" +
                room);
  // A recorder that stops before closing a single bag waits twice as long next time.
  if (!closed_some) period_s_ = std::min(2.0 * period_s_, config_.max_restart_period_s);
}

void RecorderSupervisor::stop(double timeout_s) {
  if (!child_.running()) {
    state_ = RecorderState::kStopped;
    return;
  }
  state_ = RecorderState::kStopping;
  child_.signal(SIGINT);  // as Ctrl-C: rosbag record closes and indexes its bag
  const auto t0 = std::chrono::steady_clock::now();
  auto elapsed = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  };
  int st = 0;
  bool gone = false;
  bool termed = false;
  while (!(gone = child_.reap(&st))) {
    forwardOutput();
    if (!termed && elapsed() > timeout_s) {
      report(2, "the recorder did not stop within " + seconds(timeout_s) + " of SIGINT: SIGTERM");
      child_.signal(SIGTERM);
      termed = true;
    } else if (termed && elapsed() > timeout_s + 2.0) {
      child_.signal(SIGKILL);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  forwardOutput();
  onExit(st, 0.0);
}

RecorderStatus RecorderSupervisor::status() const {
  RecorderStatus s;
  s.state = state_;
  s.starts = starts_;
  s.last_error = first_error_;
  s.free_bytes = freeBytes(config_.bag_dir);
  const BagFiles files = listBags(config_.bag_dir, config_.bag_prefix);
  for (const auto& b : files.closed) {
    if (contains(known_before_, b.name)) continue;
    ++s.closed_bags;
    s.closed_bytes += b.bytes;
  }
  const BagFile* newest = nullptr;
  for (const auto& b : files.active) {
    if (contains(known_before_, b.name)) continue;
    ++s.unindexed_bags;
    if (!newest || b.mtime_ns > newest->mtime_ns) newest = &b;
  }
  const std::string free =
      s.free_bytes ? humanBytes(*s.free_bytes) + " free" : "free space unknown";
  if (state_ == RecorderState::kRecording) {
    if (newest) {  // the recorder writes the newest; older .active files were left by others
      s.active_bag = newest->name;
      s.active_bytes = newest->bytes;
      --s.unindexed_bags;
    }
    s.summary = "recording into " + config_.bag_dir + "/" +
                (newest ? newest->name + " (" + humanBytes(newest->bytes) + ")" : "(opening)") +
                ", " + std::to_string(s.closed_bags) + " bags closed, " + free;
    const std::uint64_t reserve = reserveBytes(config_);
    // rosbag record checks its reserve every 20 s: warn while twice the reserve is left.
    s.level = s.free_bytes && *s.free_bytes < 2 * reserve ? 1 : 0;
    if (s.level) s.summary += " (the recorder stops below " + humanBytes(reserve) + ")";
  } else if (state_ == RecorderState::kWaiting) {
    s.level = 2;
    s.summary = "not recording into " + config_.bag_dir + ": " +
                (!folder_problem_.empty()   ? folder_problem_
                 : !stopped_reason_.empty() ? stopped_reason_
                                            : std::string("starting"));
  } else {
    s.summary = "stopped, " + std::to_string(s.closed_bags) + " bags closed in " + config_.bag_dir;
  }
  return s;
}

}  // namespace rig_drivers
