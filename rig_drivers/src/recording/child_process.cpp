#include "rig_drivers/recording/child_process.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <thread>

namespace rig_drivers {

ChildProcess::~ChildProcess() {
  if (running()) {
    signal(SIGINT);
    int st = 0;
    for (int i = 0; i < 250 && !reap(&st); ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (running()) {
      signal(SIGKILL);
      ::waitpid(pid_, &st, 0);
    }
  }
  if (err_fd_ >= 0) ::close(err_fd_);
}

bool ChildProcess::start(const std::vector<std::string>& argv, std::string* why) {
  if (running()) {
    *why = "a child is still running";
    return false;
  }
  if (argv.empty()) {
    *why = "empty command";
    return false;
  }
  if (err_fd_ >= 0) ::close(err_fd_);
  err_fd_ = -1;
  partial_.clear();
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) {
    *why = std::string("pipe: ") + std::strerror(errno);
    return false;
  }
  // Everything the child needs is built before fork: only async-signal-safe calls after it.
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const std::string exec_failed = "cannot run " + argv[0] + ": ";
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid < 0) {
    *why = std::string("fork: ") + std::strerror(errno);
    ::close(fds[0]);
    ::close(fds[1]);
    return false;
  }
  if (pid == 0) {
    ::dup2(fds[1], STDERR_FILENO);
    sigset_t none;
    sigemptyset(&none);
    ::sigprocmask(SIG_SETMASK, &none, nullptr);
    ::signal(SIGPIPE, SIG_DFL);
    // If the supervisor dies, the recorder still gets its Ctrl-C and closes the bag.
    ::prctl(PR_SET_PDEATHSIG, SIGINT);
    if (::getppid() != parent) ::raise(SIGINT);
    ::execvp(args[0], args.data());
    const char* e = std::strerror(errno);
    (void)!::write(STDERR_FILENO, exec_failed.data(), exec_failed.size());
    (void)!::write(STDERR_FILENO, e, std::strlen(e));
    (void)!::write(STDERR_FILENO, "\n", 1);
    ::_exit(127);
  }
  ::close(fds[1]);
  err_fd_ = fds[0];
  ::fcntl(err_fd_, F_SETFL, ::fcntl(err_fd_, F_GETFL) | O_NONBLOCK);
  pid_ = pid;
  return true;
}

void ChildProcess::readLines(std::vector<std::string>* lines) {
  if (err_fd_ < 0) return;
  char buf[4096];
  for (;;) {
    const ssize_t n = ::read(err_fd_, buf, sizeof buf);
    if (n > 0) {
      partial_.append(buf, static_cast<std::size_t>(n));
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    break;  // EAGAIN (nothing more now) or 0 (the child closed its end)
  }
  std::size_t start = 0, nl;
  while ((nl = partial_.find('\n', start)) != std::string::npos) {
    lines->push_back(partial_.substr(start, nl - start));
    start = nl + 1;
  }
  partial_.erase(0, start);
  if (!running() && !partial_.empty()) {  // the last line of a child that has gone
    lines->push_back(partial_);
    partial_.clear();
  }
}

bool ChildProcess::reap(int* wait_status) {
  if (!running()) return false;
  const pid_t r = ::waitpid(pid_, wait_status, WNOHANG);
  if (r == pid_ || (r < 0 && errno == ECHILD)) {
    pid_ = -1;
    return true;
  }
  return false;
}

void ChildProcess::signal(int sig) {
  if (running()) ::kill(pid_, sig);
}

}  // namespace rig_drivers
