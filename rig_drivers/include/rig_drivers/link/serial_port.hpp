#pragma once
/// Byte-stream port to a rig board (ROS-free): a small interface and its POSIX termios
/// implementation.
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace rig_drivers {

/// Thrown when a port cannot be opened or configured; the message names the device and the errno
/// text.
class SerialError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Settings of one serial link. The rigs run 115200 baud, 8 data bits, no parity, 1 stop bit.
struct SerialConfig {
  std::string device;          ///< device path, e.g. /dev/ttyACM0 or a pty / udev symlink
  int baud = 115200;           ///< line rate in bit/s (ignored by pseudo-terminals)
  int write_timeout_ms = 200;  ///< longest wait for the kernel buffer to take a frame, ms
  /// Every problem with these settings (empty = valid).
  std::vector<std::string> validate() const;
};

/// Outcome of one read.
enum class ReadStatus {
  kData,          ///< at least one byte was read
  kTimeout,       ///< nothing arrived within the timeout; the link is still up
  kDisconnected,  ///< the device went away (unplug, hang-up, EOF, read error); the port is closed
};

struct ReadResult {
  ReadStatus status = ReadStatus::kTimeout;
  std::size_t bytes = 0;  ///< bytes stored in the caller's buffer (kData only)
  std::string error;      ///< why the link dropped (kDisconnected only)
};

/// A byte-stream link to one board. Implementations are not thread-safe: one thread owns a port.
class SerialPort {
 public:
  virtual ~SerialPort() = default;
  /// Opens (or re-opens after a disconnect) the device; throws SerialError naming device and cause.
  virtual void open() = 0;
  /// Closes the device; harmless when already closed.
  virtual void close() = 0;
  /// True between a successful open() and a close() or detected disconnect.
  virtual bool isOpen() const = 0;
  /// Waits at most timeout_ms (>= 0) for bytes and copies up to `capacity` of them into `buffer`.
  virtual ReadResult read(std::uint8_t* buffer, std::size_t capacity, int timeout_ms) = 0;
  /// Writes all bytes; false (with the port closed and lastError() set) when the link dropped.
  virtual bool write(const std::uint8_t* data, std::size_t size) = 0;
  /// The device path this port opens.
  virtual const std::string& device() const = 0;
  /// Text of the last disconnect or write failure (empty when none).
  virtual const std::string& lastError() const = 0;
};

/// SerialPort over a POSIX tty (termios raw mode, 8N1, no flow control, non-blocking reads).
/// Works unchanged on USB CDC devices (/dev/ttyACM*, /dev/ttyUSB*) and on pseudo-terminals.
class PosixSerialPort : public SerialPort {
 public:
  /// Throws SerialError when the settings are invalid (every problem listed).
  explicit PosixSerialPort(SerialConfig config);
  ~PosixSerialPort() override;
  PosixSerialPort(const PosixSerialPort&) = delete;
  PosixSerialPort& operator=(const PosixSerialPort&) = delete;

  void open() override;
  void close() override;
  bool isOpen() const override { return fd_ >= 0; }
  ReadResult read(std::uint8_t* buffer, std::size_t capacity, int timeout_ms) override;
  bool write(const std::uint8_t* data, std::size_t size) override;
  const std::string& device() const override { return config_.device; }
  const std::string& lastError() const override { return last_error_; }

 private:
  void dropLink(const std::string& why);

  SerialConfig config_;
  int fd_ = -1;
  std::string last_error_;
};

/// True when `baud` is a rate the POSIX termios interface can set on Linux.
bool isSupportedBaud(int baud);

}  // namespace rig_drivers
