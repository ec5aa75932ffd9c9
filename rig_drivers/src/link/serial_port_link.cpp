#include "rig_drivers/link/serial_port_link.hpp"

#include <chrono>
#include <sstream>
#include <utility>

namespace rig_drivers {

using protocol::AckStatus;
using protocol::BoardId;
using protocol::Frame;
using protocol::MsgId;

std::int64_t steadyMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

namespace {
const char* boardName(BoardId b) {
  switch (b) {
    case BoardId::kTrack:
      return "TrackDRV (board 1)";
    case BoardId::kCar:
      return "CarDRV (board 2)";
    case BoardId::kTruck:
      return "TruckDRV (board 3)";
    default:
      return "host (board 0)";
  }
}
}  // namespace

std::vector<std::string> BoardLinkConfig::validate() const {
  auto p = serial.validate();
  if (board == BoardId::kHost) p.push_back("board must be track, car or truck, not host");
  if (reconnect_period_ms < 10 || reconnect_period_ms > 60000)
    p.push_back("reconnect_period_ms must be in [10, 60000] ms");
  if (handshake_timeout_ms < 10 || handshake_timeout_ms > 60000)
    p.push_back("handshake_timeout_ms must be in [10, 60000] ms");
  if (stale_timeout_ms < 100 || stale_timeout_ms > 600000)
    p.push_back("stale_timeout_ms must be in [100, 600000] ms (streams are 30 Hz)");
  if (read_timeout_ms < 1 || read_timeout_ms > 1000)
    p.push_back("read_timeout_ms must be in [1, 1000] ms");
  return p;
}

BoardLink::BoardLink(BoardLinkConfig config, std::unique_ptr<SerialPort> port,
                     FrameHandler on_frame, EventHandler on_event)
    : config_(std::move(config)),
      port_(std::move(port)),
      on_frame_(std::move(on_frame)),
      on_event_(std::move(on_event)),
      seq_(config_.board,
           // Start numbering from the wall clock so sequence numbers stay unique across restarts.
           static_cast<std::uint32_t>(
               (std::chrono::system_clock::now().time_since_epoch() / std::chrono::seconds(1)) %
               100000) *
               100) {
  const auto problems = config_.validate();
  if (!problems.empty()) {
    std::string msg = "invalid board link settings:";
    for (const auto& p : problems) msg += " " + p + ";";
    throw SerialError(msg);
  }
  if (!port_) throw SerialError("board link needs a port");
}

BoardLink::~BoardLink() { stop(); }

void BoardLink::start() {
  if (running_.exchange(true)) return;
  thread_ = std::thread([this] { run(); });
}

void BoardLink::stop() {
  if (!running_.exchange(false)) return;
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

protocol::VersionInfo BoardLink::boardVersion() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return version_;
}

protocol::DecoderStats BoardLink::decoderStats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

void BoardLink::run() {
  bool reported_down = false;  // one log line per outage, not one per retry
  auto report_down = [&](const std::string& why) {
    if (!reported_down && on_event_)
      on_event_({LinkEvent::kDisconnected,
                 why + "; retrying every " + std::to_string(config_.reconnect_period_ms) + " ms"});
    reported_down = true;
  };
  auto sleep_retry = [&] {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, std::chrono::milliseconds(config_.reconnect_period_ms),
                 [&] { return !running_.load(); });
  };
  while (running_) {
    if (!port_->isOpen()) {
      try {
        port_->open();
      } catch (const SerialError& e) {
        {
          std::lock_guard<std::mutex> lock(mutex_);
          last_error_ = e.what();
        }
        report_down(e.what());
        sleep_retry();
        continue;
      }
      decoder_.reset();
      std::string why;
      if (!handshake(&why)) {
        port_->close();
        failAllPending(why);
        report_down(why);
        sleep_retry();
        continue;
      }
      last_frame_ms_ = steadyMs();
      connected_ = true;
      reported_down = false;
      if (on_event_) {
        const auto v = boardVersion();
        std::ostringstream s;
        s << "connected to " << v.name << " " << int(v.major) << "." << int(v.minor) << "."
          << int(v.patch) << " (protocol " << int(v.protocol) << ") on " << port_->device();
        on_event_({LinkEvent::kConnected, s.str()});
      }
    }
    pumpOnce(config_.read_timeout_ms);
    if (connected_ && steadyMs() - last_frame_ms_ > config_.stale_timeout_ms)
      linkLost("serial device '" + port_->device() + "': no frame for " +
               std::to_string(config_.stale_timeout_ms) + " ms (board silent)");
    if (!port_->isOpen()) {
      std::string why;
      {
        std::lock_guard<std::mutex> lock(mutex_);
        why = last_error_.empty() ? "link lost" : last_error_;
      }
      // Reported once per outage; the reopen is tried at once (a quick replug need not wait).
      report_down(why);
    }
  }
  port_->close();
  connected_ = false;
  failAllPending("link stopped");
}

bool BoardLink::handshake(std::string* why) {
  const std::uint32_t seq = nextSeq();
  std::vector<std::uint8_t> bytes = protocol::encodeCommand(config_.board, MsgId::kVers, seq);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Pending p;
    p.id = MsgId::kVers;
    pending_[seq] = p;
    outgoing_.push_back(std::move(bytes));
  }
  const std::int64_t deadline = steadyMs() + config_.handshake_timeout_ms;
  bool done = false;
  Pending result;
  while (running_ && port_->isOpen() && steadyMs() < deadline) {
    pumpOnce(config_.read_timeout_ms);
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = pending_.find(seq);
    if (it != pending_.end() && it->second.final) {
      result = it->second;
      done = true;
      break;
    }
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    pending_.erase(seq);
  }
  const std::string dev = "serial device '" + config_.serial.device + "'";
  if (!port_->isOpen()) {
    *why = port_->lastError().empty() ? dev + " closed during handshake" : port_->lastError();
    return false;
  }
  if (!done) {
    *why = dev + ": no answer to 'vers' within " + std::to_string(config_.handshake_timeout_ms) +
           " ms (wrong baud, wrong device, or board not running)";
    return false;
  }
  if (result.status != AckStatus::kDone) {
    *why = dev + ": board rejected 'vers' (" + protocol::ackStatusName(result.status) + ")";
    return false;
  }
  for (const Frame& f : result.replies) {
    protocol::VersionInfo v;
    if (protocol::decodePayload(f, v) != protocol::DecodeError::kNone) continue;
    if (f.board != config_.board) {
      *why = dev + " has " + boardName(f.board) + " but this driver expects " +
             boardName(config_.board);
      return false;
    }
    if (v.protocol != protocol::kProtocolVersion) {
      *why = dev + ": board speaks protocol " + std::to_string(v.protocol) + ", host speaks " +
             std::to_string(protocol::kProtocolVersion);
      return false;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    version_ = v;
    return true;
  }
  *why = dev + ": 'vers' acknowledged without a VersionInfo frame";
  return false;
}

void BoardLink::pumpOnce(int timeout_ms) {
  flushOutgoing();
  if (!port_->isOpen()) return;
  std::uint8_t buf[512];
  const ReadResult r = port_->read(buf, sizeof buf, timeout_ms);
  if (r.status == ReadStatus::kDisconnected) {
    linkLost(r.error);
    return;
  }
  if (r.status != ReadStatus::kData) return;
  const auto events = protocol::feed(decoder_, buf, r.bytes);
  for (const auto& ev : events)
    if (ev.error == protocol::DecodeError::kNone) handleFrame(ev.frame);
  std::lock_guard<std::mutex> lock(mutex_);
  stats_ = decoder_.stats();
}

void BoardLink::handleFrame(const Frame& f) {
  last_frame_ms_ = steadyMs();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (f.id == MsgId::kAck) {
      protocol::Ack ack;
      if (protocol::decodePayload(f, ack) == protocol::DecodeError::kNone) {
        auto it = pending_.find(ack.acked_seq);
        if (it != pending_.end()) {
          Pending& p = it->second;
          p.acked = true;
          p.status = ack.status;
          p.final = ack.status != AckStatus::kAccepted || !p.wait_done;
          cv_.notify_all();
        }
      }
    } else if (f.id == MsgId::kVersionInfo || f.id == MsgId::kParamValue) {
      const MsgId cmd = f.id == MsgId::kVersionInfo ? MsgId::kVers : MsgId::kPara;
      for (auto& kv : pending_)
        if (kv.second.id == cmd) kv.second.replies.push_back(f);
    }
  }
  if (on_frame_) on_frame_(f, protocol::frameBytes(f), false);
}

void BoardLink::flushOutgoing() {
  for (;;) {
    std::vector<std::uint8_t> bytes;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (outgoing_.empty()) return;
      bytes = std::move(outgoing_.front());
      outgoing_.pop_front();
    }
    if (!port_->isOpen() || !port_->write(bytes.data(), bytes.size())) {
      linkLost(port_->lastError().empty() ? "write failed" : port_->lastError());
      return;
    }
    if (on_frame_) {
      protocol::StreamDecoder d;
      for (const auto& ev : protocol::feed(d, bytes))
        if (ev.error == protocol::DecodeError::kNone) on_frame_(ev.frame, bytes, true);
    }
  }
}

void BoardLink::linkLost(const std::string& why) {
  port_->close();
  decoder_.reset();
  connected_ = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    outgoing_.clear();
  }
  failAllPending(why);  // also records `why` as the reason run() reports, once per outage
}

void BoardLink::failAllPending(const std::string& why) {
  std::lock_guard<std::mutex> lock(mutex_);
  last_error_ = why;
  for (auto& kv : pending_)
    if (!kv.second.final) kv.second.failure = why;
  cv_.notify_all();
}

CommandResult BoardLink::command(MsgId id, const std::vector<std::uint8_t>& payload,
                                 double timeout_s, bool wait_done, std::uint32_t seq) {
  CommandResult result;
  result.seq = seq ? seq : nextSeq();
  const std::string name = protocol::msgName(id);
  if (!connected_) {
    std::string why;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      why = last_error_;
    }
    result.message = "'" + name + "' not sent: board link on '" + config_.serial.device +
                     "' is not connected" + (why.empty() ? "" : " (" + why + ")");
    return result;
  }
  if (!(timeout_s > 0) || timeout_s > 3600) {
    result.message = "'" + name + "' not sent: timeout must be in (0, 3600] s";
    return result;
  }
  std::vector<std::uint8_t> bytes(protocol::kMaxFrameSize);
  bytes.resize(protocol::encodeFrame(config_.board, id, result.seq, payload.data(), payload.size(),
                                     bytes.data(), bytes.size()));
  if (bytes.empty()) {
    result.message = "'" + name + "' not sent: payload of " + std::to_string(payload.size()) +
                     " bytes does not fit a frame";
    return result;
  }
  std::unique_lock<std::mutex> lock(mutex_);
  Pending p;
  p.id = id;
  p.wait_done = wait_done;
  pending_[result.seq] = p;
  outgoing_.push_back(std::move(bytes));
  const bool finished = cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] {
    const Pending& q = pending_[result.seq];
    return q.final || !q.failure.empty() || !running_.load();
  });
  Pending q = pending_[result.seq];
  pending_.erase(result.seq);
  lock.unlock();
  result.acked = q.acked;
  result.status = q.status;
  result.replies = std::move(q.replies);
  const std::string tag = "'" + name + "' (seq " + std::to_string(result.seq) + ")";
  if (!q.failure.empty()) {
    result.message = tag + " failed: link lost: " + q.failure;
  } else if (!finished || !q.final) {
    std::ostringstream s;
    s << tag << (q.acked ? " accepted but not completed" : " not acknowledged") << " within "
      << timeout_s << " s";
    result.message = s.str();
  } else {
    result.success =
        q.status == AckStatus::kDone || (!wait_done && q.status == AckStatus::kAccepted);
    result.message = tag + ": " + protocol::ackStatusName(q.status);
  }
  return result;
}

}  // namespace rig_drivers
