#pragma once
/// A child process whose error lines the parent reads (ROS-free): the rig's recorder runs as one.
#include <sys/types.h>

#include <string>
#include <vector>

namespace rig_drivers {

/// A child process with its stderr on a pipe (its stdout is the parent's).
class ChildProcess {
 public:
  ChildProcess() = default;
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  /// Starts argv (argv[0] looked up on PATH); false with the reason when fork or pipe fail. An
  /// exec failure shows as an exit with status 127 and a line on stderr. The child gets SIGINT
  /// when this process dies, so a recorder always closes its bag.
  bool start(const std::vector<std::string>& argv, std::string* why);
  bool running() const { return pid_ > 0; }
  pid_t pid() const { return pid_; }
  /// Appends the complete lines the child wrote to stderr since the last call (non-blocking).
  void readLines(std::vector<std::string>* lines);
  /// True once the child has exited (non-blocking); *wait_status as from waitpid.
  bool reap(int* wait_status);
  void signal(int sig);

 private:
  pid_t pid_ = -1;
  int err_fd_ = -1;
  std::string partial_;
};

}  // namespace rig_drivers
