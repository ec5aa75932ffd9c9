// Host part of the codec: names for log lines and messages, std::vector conveniences. Not built
// for the boards (codec.cpp is).
#include <vector>

#include "rig_drivers/protocol/codec.hpp"

namespace rig_drivers {
namespace protocol {

const char* msgName(MsgId id) {
  switch (id) {
    case MsgId::kInit:
      return "init";
    case MsgId::kMode:
      return "mode";
    case MsgId::kStart:
      return "start";
    case MsgId::kStop:
      return "stop";
    case MsgId::kReset:
      return "reset";
    case MsgId::kEnd:
      return "end";
    case MsgId::kVers:
      return "vers";
    case MsgId::kPara:
      return "para";
    case MsgId::kTrackMove:
      return "TrackMove";
    case MsgId::kServo:
      return "Servo";
    case MsgId::kPing:
      return "Ping";
    case MsgId::kWait:
      return "Wait";
    case MsgId::kAck:
      return "Ack";
    case MsgId::kTrackState:
      return "TrackState";
    case MsgId::kCarSensors:
      return "CarSensors";
    case MsgId::kTruckRc:
      return "TruckRc";
    case MsgId::kVersionInfo:
      return "VersionInfo";
    case MsgId::kParamValue:
      return "ParamValue";
    case MsgId::kPong:
      return "Pong";
  }
  return "unknown";
}

const char* errorName(DecodeError e) {
  switch (e) {
    case DecodeError::kNone:
      return "no error";
    case DecodeError::kBadCrc:
      return "bad CRC";
    case DecodeError::kBadLength:
      return "bad length (payload longer than 64 bytes)";
    case DecodeError::kVersionMismatch:
      return "protocol version mismatch";
    case DecodeError::kUnknownMessage:
      return "unknown message id";
    case DecodeError::kUnknownBoard:
      return "unknown board id";
    case DecodeError::kTruncated:
      return "truncated frame";
    case DecodeError::kWrongMessage:
      return "wrong message id for this payload type";
    case DecodeError::kPayloadSize:
      return "payload size does not match the message";
    case DecodeError::kBadValue:
      return "payload field out of range";
    case DecodeError::kBufferTooSmall:
      return "output buffer too small";
  }
  return "unknown error";
}

const char* ackStatusName(AckStatus s) {
  switch (s) {
    case AckStatus::kAccepted:
      return "accepted";
    case AckStatus::kDone:
      return "done";
    case AckStatus::kBusy:
      return "busy";
    case AckStatus::kNotReady:
      return "not ready (not initialised or wrong mode)";
    case AckStatus::kBadArgument:
      return "bad argument";
    case AckStatus::kUnsupported:
      return "unsupported on this board";
    case AckStatus::kEStop:
      return "emergency stop";
    case AckStatus::kEndOfTrack:
      return "end of track";
    case AckStatus::kFailed:
      return "failed";
    case AckStatus::kAborted:
      return "aborted";
  }
  return "unknown status";
}

namespace {
class CollectSink : public FrameSink {
 public:
  explicit CollectSink(std::vector<DecodeEvent>& out) : out_(out) {}
  void onFrame(const Frame& f) override {
    DecodeEvent e;
    e.frame = f;
    out_.push_back(e);
  }
  void onError(DecodeError error, size_t discarded) override {
    DecodeEvent e;
    e.error = error;
    e.discarded = discarded;
    out_.push_back(e);
  }

 private:
  std::vector<DecodeEvent>& out_;
};
}  // namespace

std::vector<DecodeEvent> feed(StreamDecoder& decoder, const uint8_t* data, size_t n) {
  std::vector<DecodeEvent> events;
  CollectSink sink(events);
  decoder.feed(data, n, sink);
  return events;
}

std::vector<uint8_t> encodeCommand(BoardId board, MsgId id, uint32_t seq) {
  std::vector<uint8_t> out(kMaxFrameSize);
  out.resize(encodeCommand(board, id, seq, out.data(), out.size()));
  return out;
}

std::vector<uint8_t> frameBytes(const Frame& f) {
  std::vector<uint8_t> out(kMaxFrameSize);
  out.resize(encodeFrame(f.board, f.id, f.seq, f.payload, f.length, out.data(), out.size()));
  return out;
}

}  // namespace protocol
}  // namespace rig_drivers
