// Real bytes through the real PosixSerialPort over a pseudo-terminal pair. The test holds the
// master side (the "board"); unplugging the board is closing the master; replugging is a new pty
// behind the same udev-style symlink.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "rig_drivers/link/serial_port.hpp"

using rig_drivers::PosixSerialPort;
using rig_drivers::ReadStatus;
using rig_drivers::SerialConfig;
using rig_drivers::SerialError;

namespace {

/// One pseudo-terminal; the slave is kept open in raw mode so nothing is echoed or translated
/// before the port under test configures it.
class FakeBoard {
 public:
  FakeBoard() {
    termios raw{};
    ::cfmakeraw(&raw);
    char name[256] = {0};
    if (::openpty(&master_, &slave_, name, &raw, nullptr) != 0) {
      ADD_FAILURE() << "openpty failed";
      return;
    }
    slave_name_ = name;
    ::fcntl(master_, F_SETFL, ::fcntl(master_, F_GETFL) | O_NONBLOCK);
  }
  ~FakeBoard() { unplug(); }
  const std::string& slaveName() const { return slave_name_; }
  void unplug() {
    if (master_ >= 0) ::close(master_);
    if (slave_ >= 0) ::close(slave_);
    master_ = slave_ = -1;
  }
  void send(const std::vector<std::uint8_t>& bytes) {
    std::size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t n = ::write(master_, bytes.data() + done, bytes.size() - done);
      if (n > 0) {
        done += static_cast<std::size_t>(n);
      } else {
        pollfd p{master_, POLLOUT, 0};
        ::poll(&p, 1, 100);
      }
    }
  }
  /// Reads until `count` bytes arrived or `timeout_ms` passed without any byte.
  std::vector<std::uint8_t> receive(std::size_t count, int timeout_ms = 1000) {
    std::vector<std::uint8_t> out;
    std::uint8_t buf[4096];
    while (out.size() < count) {
      pollfd p{master_, POLLIN, 0};
      if (::poll(&p, 1, timeout_ms) <= 0) break;
      const ssize_t n = ::read(master_, buf, sizeof buf);
      if (n <= 0) break;
      out.insert(out.end(), buf, buf + n);
    }
    return out;
  }

 private:
  int master_ = -1;
  int slave_ = -1;
  std::string slave_name_;
};

std::string tempDir() {
  char tmpl[] = "/tmp/rig_port_testXXXXXX";
  const char* d = ::mkdtemp(tmpl);
  return d ? d : "/tmp";
}

std::vector<std::uint8_t> allByteValues(int repeats) {
  std::vector<std::uint8_t> v;
  for (int r = 0; r < repeats; ++r)
    for (int b = 0; b < 256; ++b) v.push_back(static_cast<std::uint8_t>(b));
  return v;
}

std::vector<std::uint8_t> readAll(PosixSerialPort& port, std::size_t count) {
  std::vector<std::uint8_t> got;
  std::uint8_t buf[1024];
  while (got.size() < count) {
    const auto r = port.read(buf, sizeof buf, 1000);
    if (r.status != ReadStatus::kData) break;
    got.insert(got.end(), buf, buf + r.bytes);
  }
  return got;
}

}  // namespace

TEST(SerialConfig, ReportsEveryProblemAtOnce) {
  SerialConfig c;
  c.device = "";
  c.baud = 12345;
  c.write_timeout_ms = 0;
  EXPECT_EQ(c.validate().size(), 3u);
  try {
    PosixSerialPort p(c);
    FAIL() << "invalid settings accepted";
  } catch (const SerialError& e) {
    EXPECT_NE(std::string(e.what()).find("12345"), std::string::npos) << e.what();
  }
  c.device = "/dev/ttyACM0";
  c.baud = 115200;
  c.write_timeout_ms = 200;
  EXPECT_TRUE(c.validate().empty());
}

TEST(PosixSerialPort, MissingDeviceErrorNamesDeviceAndCause) {
  SerialConfig c;
  c.device = "/dev/does_not_exist_rig0";
  PosixSerialPort port(c);
  try {
    port.open();
    FAIL() << "opened a missing device";
  } catch (const SerialError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("/dev/does_not_exist_rig0"), std::string::npos) << msg;
    EXPECT_NE(msg.find("No such file"), std::string::npos) << msg;
  }
  EXPECT_FALSE(port.isOpen());
  std::uint8_t b[4];
  EXPECT_EQ(port.read(b, 4, 0).status, ReadStatus::kDisconnected);
}

TEST(PosixSerialPort, RegularFileIsRejectedAsNotATerminal) {
  const std::string path = tempDir() + "/not_a_tty";
  std::FILE* f = std::fopen(path.c_str(), "w");
  ASSERT_NE(f, nullptr);
  std::fclose(f);
  SerialConfig c;
  c.device = path;
  PosixSerialPort port(c);
  try {
    port.open();
    FAIL() << "opened a regular file as a serial port";
  } catch (const SerialError& e) {
    EXPECT_NE(std::string(e.what()).find("not a terminal"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
}

TEST(PosixSerialPort, RawModePassesEveryByteValueBothWays) {
  FakeBoard board;
  SerialConfig c;
  c.device = board.slaveName();
  PosixSerialPort port(c);
  ASSERT_NO_THROW(port.open());
  ASSERT_TRUE(port.isOpen());

  // Board -> host: CR, LF, ^C, XON/XOFF and 0xFF must arrive untranslated (no cooked mode).
  const auto sent = allByteValues(4);
  board.send(sent);
  EXPECT_EQ(readAll(port, sent.size()), sent);

  // Host -> board.
  ASSERT_TRUE(port.write(sent.data(), sent.size())) << port.lastError();
  EXPECT_EQ(board.receive(sent.size()), sent);
  // Nothing echoed back to the host.
  std::uint8_t b[16];
  EXPECT_EQ(port.read(b, sizeof b, 50).status, ReadStatus::kTimeout);
}

TEST(PosixSerialPort, TimeoutKeepsTheLinkUp) {
  FakeBoard board;
  SerialConfig c;
  c.device = board.slaveName();
  PosixSerialPort port(c);
  port.open();
  std::uint8_t b[8];
  const auto r = port.read(b, sizeof b, 20);
  EXPECT_EQ(r.status, ReadStatus::kTimeout);
  EXPECT_EQ(r.bytes, 0u);
  EXPECT_TRUE(port.isOpen());
}

TEST(PosixSerialPort, LargeTransferWithSlowReaderLosesNothing) {
  // 256 KiB is far more than the pty buffer, so the port's write must wait for the reader.
  FakeBoard board;
  SerialConfig c;
  c.device = board.slaveName();
  c.write_timeout_ms = 2000;
  PosixSerialPort port(c);
  port.open();
  std::vector<std::uint8_t> data(256 * 1024);
  std::mt19937 rng(7);
  for (auto& x : data) x = static_cast<std::uint8_t>(rng());
  std::vector<std::uint8_t> got;
  std::thread reader([&] { got = board.receive(data.size(), 3000); });
  const bool ok = port.write(data.data(), data.size());
  reader.join();
  EXPECT_TRUE(ok) << port.lastError();
  EXPECT_EQ(got.size(), data.size());
  EXPECT_TRUE(got == data);
}

TEST(PosixSerialPort, SecondOpenerIsRefused) {
  FakeBoard board;
  SerialConfig c;
  c.device = board.slaveName();
  PosixSerialPort a(c), b(c);
  a.open();
  try {
    b.open();
    FAIL() << "two ports opened one device";
  } catch (const SerialError& e) {
    EXPECT_NE(std::string(e.what()).find("in use"), std::string::npos) << e.what();
  }
  a.close();
  EXPECT_NO_THROW(b.open());
}

TEST(PosixSerialPort, UnplugIsDetectedAndReplugRecovers) {
  const std::string link = tempDir() + "/ttyRIG";
  auto board = std::make_unique<FakeBoard>();
  ASSERT_EQ(::symlink(board->slaveName().c_str(), link.c_str()), 0);
  SerialConfig c;
  c.device = link;
  PosixSerialPort port(c);
  port.open();
  const std::vector<std::uint8_t> hello{'h', 'i', 0x00, 0xA5};
  board->send(hello);
  EXPECT_EQ(readAll(port, hello.size()), hello);

  // Unplug: the master goes away (the kernel's hang-up discards bytes still in flight, as a USB
  // unplug does). The next read reports disconnected: not a timeout, not a crash.
  board->unplug();
  std::uint8_t buf[64];
  const auto r = port.read(buf, sizeof buf, 500);
  EXPECT_EQ(r.status, ReadStatus::kDisconnected);
  EXPECT_FALSE(r.error.empty());
  EXPECT_NE(r.error.find(link), std::string::npos) << r.error;
  EXPECT_FALSE(port.isOpen());
  EXPECT_FALSE(port.write(hello.data(), hello.size()));

  // While unplugged the device node is gone: open fails with a clear error.
  EXPECT_THROW(port.open(), SerialError);

  // Replug: a new pty behind the same symlink, as udev does for a USB board.
  board = std::make_unique<FakeBoard>();
  ::unlink(link.c_str());
  ASSERT_EQ(::symlink(board->slaveName().c_str(), link.c_str()), 0);
  ASSERT_NO_THROW(port.open());
  board->send(hello);
  EXPECT_EQ(readAll(port, hello.size()), hello);
  ASSERT_TRUE(port.write(hello.data(), hello.size()));
  EXPECT_EQ(board->receive(hello.size()), hello);
  ::unlink(link.c_str());
}
