#include "rig_drivers/link/serial_port.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/file.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <utility>

namespace rig_drivers {
namespace {

struct BaudEntry {
  int baud;
  speed_t code;
};

constexpr BaudEntry kBauds[] = {
    {1200, B1200},       {2400, B2400},       {4800, B4800},       {9600, B9600},
    {19200, B19200},     {38400, B38400},     {57600, B57600},     {115200, B115200},
    {230400, B230400},   {460800, B460800},   {500000, B500000},   {921600, B921600},
    {1000000, B1000000}, {2000000, B2000000}, {4000000, B4000000},
};

bool baudCode(int baud, speed_t* code) {
  for (const auto& e : kBauds) {
    if (e.baud == baud) {
      *code = e.code;
      return true;
    }
  }
  return false;
}

std::string errnoText(int err) { return std::string(std::strerror(err)); }

}  // namespace

bool isSupportedBaud(int baud) {
  speed_t unused;
  return baudCode(baud, &unused);
}

std::vector<std::string> SerialConfig::validate() const {
  std::vector<std::string> problems;
  if (device.empty()) problems.push_back("serial device path is empty");
  if (!isSupportedBaud(baud))
    problems.push_back("baud " + std::to_string(baud) +
                       " is not a standard rate (e.g. 9600, 57600, 115200, 921600)");
  if (write_timeout_ms <= 0 || write_timeout_ms > 10000)
    problems.push_back("write_timeout_ms " + std::to_string(write_timeout_ms) +
                       " must be in (0, 10000]");
  return problems;
}

PosixSerialPort::PosixSerialPort(SerialConfig config) : config_(std::move(config)) {
  const auto problems = config_.validate();
  if (!problems.empty()) {
    std::string msg = "invalid serial settings for '" + config_.device + "': ";
    for (std::size_t i = 0; i < problems.size(); ++i) msg += (i ? "; " : "") + problems[i];
    throw SerialError(msg);
  }
}

PosixSerialPort::~PosixSerialPort() { close(); }

void PosixSerialPort::open() {
  close();
  const std::string& dev = config_.device;
  const int fd = ::open(dev.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int err = errno;
    throw SerialError("cannot open serial device '" + dev + "': " + errnoText(err));
  }
  auto fail = [&](const std::string& what, int err) {
    ::close(fd);
    throw SerialError("serial device '" + dev + "': " + what + ": " + errnoText(err));
  };
  if (!::isatty(fd)) fail("is not a terminal device", ENOTTY);
  // Two drivers on one board would interleave frames; refuse instead.
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) fail("is in use by another process", errno);

  termios tio{};
  if (::tcgetattr(fd, &tio) != 0) fail("tcgetattr failed", errno);
  ::cfmakeraw(&tio);
  tio.c_cflag &= ~static_cast<tcflag_t>(PARENB | CSTOPB | CSIZE | CRTSCTS);
  tio.c_cflag |= CS8 | CLOCAL | CREAD;
  tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  speed_t code = B115200;
  baudCode(config_.baud, &code);
  if (::cfsetispeed(&tio, code) != 0 || ::cfsetospeed(&tio, code) != 0)
    fail("cannot set baud " + std::to_string(config_.baud), errno);
  if (::tcsetattr(fd, TCSANOW, &tio) != 0) fail("tcsetattr failed", errno);
  // Bytes queued before we opened belong to nobody's frame boundary; start clean.
  ::tcflush(fd, TCIFLUSH);
  fd_ = fd;
  last_error_.clear();
}

void PosixSerialPort::close() {
  if (fd_ >= 0) {
    ::flock(fd_, LOCK_UN);
    ::close(fd_);
    fd_ = -1;
  }
}

void PosixSerialPort::dropLink(const std::string& why) {
  last_error_ = "serial device '" + config_.device + "' " + why;
  close();
}

ReadResult PosixSerialPort::read(std::uint8_t* buffer, std::size_t capacity, int timeout_ms) {
  ReadResult result;
  if (fd_ < 0) {
    result.status = ReadStatus::kDisconnected;
    result.error =
        last_error_.empty() ? "serial device '" + config_.device + "' is not open" : last_error_;
    return result;
  }
  if (capacity == 0) return result;
  pollfd pfd{fd_, POLLIN, 0};
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                          deadline - std::chrono::steady_clock::now())
                          .count();
    const int rc = ::poll(&pfd, 1, left > 0 ? static_cast<int>(left) : 0);
    if (rc < 0) {
      if (errno == EINTR) continue;
      dropLink("poll failed: " + errnoText(errno));
      break;
    }
    if (rc == 0) return result;  // timeout, link still up
    if (pfd.revents & POLLNVAL) {
      dropLink("descriptor became invalid");
      break;
    }
    // Read even when POLLHUP is set: bytes sent just before the hang-up are still queued.
    const ssize_t n = ::read(fd_, buffer, capacity);
    if (n > 0) {
      result.status = ReadStatus::kData;
      result.bytes = static_cast<std::size_t>(n);
      return result;
    }
    if (n == 0) {
      dropLink("reached end of file (hang-up or unplug)");
      break;
    }
    const int err = errno;
    if (err == EINTR) continue;
    if (err == EAGAIN || err == EWOULDBLOCK) {
      if (pfd.revents & (POLLHUP | POLLERR)) {
        dropLink("hung up (unplugged)");
        break;
      }
      continue;
    }
    dropLink("read failed (unplugged?): " + errnoText(err));
    break;
  }
  result.status = ReadStatus::kDisconnected;
  result.error = last_error_;
  return result;
}

bool PosixSerialPort::write(const std::uint8_t* data, std::size_t size) {
  if (fd_ < 0) {
    if (last_error_.empty()) last_error_ = "serial device '" + config_.device + "' is not open";
    return false;
  }
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::milliseconds(config_.write_timeout_ms);
  std::size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(fd_, data + done, size - done);
    if (n > 0) {
      done += static_cast<std::size_t>(n);
      continue;
    }
    const int err = errno;
    if (n < 0 && err == EINTR) continue;
    if (n < 0 && (err == EAGAIN || err == EWOULDBLOCK)) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                            deadline - std::chrono::steady_clock::now())
                            .count();
      if (left <= 0) {
        dropLink("write timed out after " + std::to_string(config_.write_timeout_ms) +
                 " ms (board not reading)");
        return false;
      }
      pollfd pfd{fd_, POLLOUT, 0};
      ::poll(&pfd, 1, static_cast<int>(left));
      if (pfd.revents & (POLLHUP | POLLERR | POLLNVAL)) {
        dropLink("hung up during write");
        return false;
      }
      continue;
    }
    dropLink("write failed (unplugged?): " + errnoText(n < 0 ? err : EIO));
    return false;
  }
  return true;
}

}  // namespace rig_drivers
