#pragma once
/// Host side of one rig board link (ROS-free): owns a SerialPort and the codec's StreamDecoder,
/// runs the handshake, numbers and acknowledges commands, and reconnects after unplug/replug.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "rig_drivers/link/serial_port.hpp"
#include "rig_drivers/protocol/codec.hpp"

namespace rig_drivers {

/// Settings of one board link (one per driver node).
struct BoardLinkConfig {
  SerialConfig serial;                                  ///< device, baud
  protocol::BoardId board = protocol::BoardId::kTrack;  ///< board expected on this link
  int reconnect_period_ms = 500;    ///< retry period for opening a missing device (ms)
  int handshake_timeout_ms = 1500;  ///< vers must be answered within this after open (ms)
  int stale_timeout_ms = 1000;  ///< no frame at all for this long = link lost (ms; 30 Hz streams)
  int read_timeout_ms = 10;     ///< IO loop poll period; bounds command send latency (ms)
  /// Every problem with these settings (empty = valid).
  std::vector<std::string> validate() const;
};

/// Connection changes, reported once per transition (never per frame).
struct LinkEvent {
  enum Type { kConnected, kDisconnected } type = kDisconnected;
  std::string message;  ///< why (disconnect) or which board/version (connect)
};

/// Outcome of one command.
struct CommandResult {
  bool success = false;  ///< acknowledged with the awaited status
  bool acked = false;    ///< at least one Ack with this seq arrived
  std::uint32_t seq = 0;
  protocol::AckStatus status = protocol::AckStatus::kAccepted;  ///< last Ack status
  std::string message;                                          ///< human readable result
  std::vector<protocol::Frame> replies;  ///< VersionInfo / ParamValue frames received meanwhile
};

/// Globally unique, increasing command sequence numbers shared by every board of a rig: each
/// board's host uses its own residue class (seq = n * 4 + board id), so two hosts never collide.
class SequenceCounter {
 public:
  explicit SequenceCounter(protocol::BoardId board, std::uint32_t start_n = 1)
      : board_(static_cast<std::uint32_t>(board)), n_(start_n) {}
  /// Next sequence number. Thread-safe.
  std::uint32_t next() { return n_.fetch_add(1) * 4u + board_; }

 private:
  std::uint32_t board_;
  std::atomic<std::uint32_t> n_;
};

class BoardLink {
 public:
  /// Called from the IO thread for every checksum-valid frame in either direction, with the exact
  /// wire bytes (for raw-frame recording).
  using FrameHandler = std::function<void(const protocol::Frame& frame,
                                          const std::vector<std::uint8_t>& wire, bool outgoing)>;
  using EventHandler = std::function<void(const LinkEvent& event)>;

  /// Throws SerialError when the config is invalid. Nothing is opened until start().
  BoardLink(BoardLinkConfig config, std::unique_ptr<SerialPort> port, FrameHandler on_frame,
            EventHandler on_event);
  ~BoardLink();
  BoardLink(const BoardLink&) = delete;
  BoardLink& operator=(const BoardLink&) = delete;

  /// Starts the IO thread (open, handshake, read; reopen after unplug).
  void start();
  /// Stops the IO thread and closes the port; pending commands fail.
  void stop();
  /// True after a successful handshake and until the link drops. Thread-safe.
  bool connected() const { return connected_.load(); }
  /// Version the board reported in the last handshake. Thread-safe.
  protocol::VersionInfo boardVersion() const;
  /// Decoder counters (frames, CRC errors, garbage bytes). Thread-safe.
  protocol::DecoderStats decoderStats() const;

  /// Sends a command frame (payload may be empty) and waits for its acknowledgement: for
  /// wait_done, until an Ack other than kAccepted (kDone = success); else the first Ack
  /// (kAccepted or kDone = success). Never throws; blocks at most timeout_s. Thread-safe.
  CommandResult command(protocol::MsgId id, const std::vector<std::uint8_t>& payload,
                        double timeout_s, bool wait_done, std::uint32_t seq = 0);
  /// Typed convenience for payload structs of the codec.
  template <class P>
  CommandResult send(const P& payload, double timeout_s, bool wait_done, std::uint32_t seq = 0) {
    std::vector<std::uint8_t> buf(P::kSize);
    payload.encode(buf.data());
    return command(P::kId, buf, timeout_s, wait_done, seq);
  }
  /// Next sequence number of this link's counter. Thread-safe.
  std::uint32_t nextSeq() { return seq_.next(); }

 private:
  struct Pending {
    protocol::MsgId id;
    bool acked = false;
    bool final = false;
    bool wait_done = true;
    protocol::AckStatus status = protocol::AckStatus::kAccepted;
    std::vector<protocol::Frame> replies;
    std::string failure;  ///< set when the link dropped while waiting
  };

  void run();
  bool tryOpen(bool* reported);
  bool handshake(std::string* why);
  void pumpOnce(int timeout_ms);
  void handleFrame(const protocol::Frame& f);
  void flushOutgoing();
  void linkLost(const std::string& why);
  void failAllPending(const std::string& why);

  BoardLinkConfig config_;
  std::unique_ptr<SerialPort> port_;
  FrameHandler on_frame_;
  EventHandler on_event_;
  SequenceCounter seq_;
  protocol::StreamDecoder decoder_;

  std::thread thread_;
  std::atomic<bool> running_{false};
  std::atomic<bool> connected_{false};

  mutable std::mutex mutex_;  ///< guards everything below
  std::condition_variable cv_;
  std::deque<std::vector<std::uint8_t>> outgoing_;
  std::map<std::uint32_t, Pending> pending_;
  protocol::VersionInfo version_;
  protocol::DecoderStats stats_;
  std::int64_t last_frame_ms_ = 0;
  std::string last_error_;  ///< why the link is (or last was) down
};

/// Monotonic milliseconds (steady clock), shared by the link and its tests.
std::int64_t steadyMs();

}  // namespace rig_drivers
