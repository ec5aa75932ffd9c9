#pragma once
// Serial wire protocol of the ServoTrack / ServoTruck rig boards (TrackDRV, CarDRV, TruckDRV).
//
// Frame layout (all multi-byte fields little endian), 115200 baud 8N1:
//
//   offset size field
//   0      1    sync0    0xA5
//   1      1    sync1    0x5A
//   2      1    length   payload length in bytes, 0..kMaxPayload
//   3      1    version  kProtocolVersion
//   4      1    board    BoardId (the board that sent it, or that a host command is for)
//   5      1    msg id   MsgId
//   6      4    seq      uint32 sequence number (see below)
//   10     n    payload  message payload (fixed-point integers, see the payload structs)
//   10+n   2    crc      CRC-16/CCITT-FALSE over bytes 2 .. 9+n (length .. end of payload)
//
// Sequence numbers: the host numbers every command with a globally unique, increasing seq (one
// counter across all boards of a rig), the board acknowledges it by echoing that seq in an Ack
// payload (status kAccepted on receipt, kDone when a mode 2 step has completed). Board frames carry
// the board's own frame counter in seq, so the host can count lost frames.
//
// The board part uses only what avr-libc has (<stddef.h>, <stdint.h>), so the same code builds
// freestanding for the boards (no C++ standard library, no exceptions, no heap). The host part
// (names for log lines, std::vector conveniences) exists only where RIG_DRIVERS_HOST is 1.

#include <stddef.h>
#include <stdint.h>

// 1 in host builds (nodes, simulator, tests), 0 on a board: avr-gcc, or the Arduino IDE.
#if !defined(RIG_DRIVERS_HOST)
#if defined(ARDUINO) || defined(__AVR__)
#define RIG_DRIVERS_HOST 0
#else
#define RIG_DRIVERS_HOST 1
#endif
#endif

#if RIG_DRIVERS_HOST
#include <vector>
#endif

namespace rig_drivers {
namespace protocol {

constexpr uint8_t kSync0 = 0xA5;
constexpr uint8_t kSync1 = 0x5A;
constexpr uint8_t kProtocolVersion = 1;
constexpr size_t kHeaderSize = 10;  ///< sync .. seq
constexpr size_t kCrcSize = 2;
constexpr size_t kMaxPayload = 64;
constexpr size_t kMaxFrameSize = kHeaderSize + kMaxPayload + kCrcSize;
constexpr uint32_t kBaudRate = 115200;
constexpr uint32_t kStreamPeriodMs = 33;  ///< 30 Hz streams (TrackDRV uses 100 ms per 3 frames)

/// Board ids. kHost is used only as a sender of host frames that address no board in particular.
enum class BoardId : uint8_t { kHost = 0, kTrack = 1, kCar = 2, kTruck = 3 };

/// Message ids: 0x01..0x3F host -> board commands, 0x80..0xBF board -> host.
enum class MsgId : uint8_t {
  // host -> board, each answered by an Ack with the command's seq
  kInit = 0x01,       ///< no payload; TrackDRV homes to the far sensor, Ack kDone when homed
  kMode = 0x02,       ///< CmdMode
  kStart = 0x03,      ///< no payload
  kStop = 0x04,       ///< no payload; controlled stop
  kReset = 0x05,      ///< no payload; clears latched e-stop / fault, board becomes uninitialised
  kEnd = 0x06,        ///< no payload
  kVers = 0x07,       ///< no payload; answered by VersionInfo then Ack kDone
  kPara = 0x08,       ///< no payload; answered by ParamValue frames then Ack kDone
  kTrackMove = 0x10,  ///< CmdTrackMove (TrackDRV)
  kServo = 0x11,      ///< CmdServo (CarDRV)
  kPing = 0x12,       ///< CmdPing, answered by Pong (round trip measurement, thesis A3.1)
  kWait = 0x13,       ///< CmdWait: mode 2 settle step, Ack kDone after the time elapsed
  // board -> host
  kAck = 0x80,          ///< Ack
  kTrackState = 0x81,   ///< TrackStatePayload, 30 Hz
  kCarSensors = 0x82,   ///< CarSensorsPayload, 30 Hz
  kTruckRc = 0x83,      ///< TruckRcPayload, 30 Hz
  kVersionInfo = 0x84,  ///< VersionInfo
  kParamValue = 0x85,   ///< ParamValue
  kPong = 0x86,         ///< Pong
};

/// True if `id` is one of the MsgId values above.
bool isKnownMsgId(uint8_t id);
/// True if `b` is one of the BoardId values above.
bool isKnownBoard(uint8_t b);

/// Typed results of decoding; kNone means success.
enum class DecodeError : uint8_t {
  kNone = 0,
  kBadCrc,           ///< checksum mismatch (frame dropped, decoder rescans from the next byte)
  kBadLength,        ///< length byte > kMaxPayload (cannot be a frame start)
  kVersionMismatch,  ///< CRC-valid frame of another protocol version (dropped)
  kUnknownMessage,   ///< CRC-valid frame with an unknown message id (dropped)
  kUnknownBoard,     ///< CRC-valid frame with an unknown board id (dropped)
  kTruncated,        ///< a partial frame was pending when the stream was flushed
  kWrongMessage,     ///< decodePayload asked for a different message id than the frame has
  kPayloadSize,      ///< payload length does not match the message's fixed size
  kBadValue,         ///< a payload field is out of its valid range (e.g. mode 3)
  kBufferTooSmall,   ///< encode: output buffer too small
};

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection); check("123456789") = 0x29B1.
uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc = 0xFFFF);

/// One complete, checksum-verified frame (fixed storage, no heap).
struct Frame {
  uint8_t version = kProtocolVersion;
  BoardId board = BoardId::kHost;
  MsgId id = MsgId::kAck;
  uint32_t seq = 0;
  uint8_t length = 0;  ///< payload bytes used
  uint8_t payload[kMaxPayload] = {};
};

/// Encodes a frame into `out` (capacity `cap`); returns the frame size, 0 if `cap` or
/// `payload_len` is too large. Thread-safe (pure).
size_t encodeFrame(BoardId board, MsgId id, uint32_t seq, const uint8_t* payload,
                   size_t payload_len, uint8_t* out, size_t cap);

// ---- little-endian field helpers used by the payload structs ------------------------------------
namespace wire {
inline void putU8(uint8_t*& p, uint8_t v) { *p++ = v; }
inline void putU16(uint8_t*& p, uint16_t v) {
  *p++ = static_cast<uint8_t>(v);
  *p++ = static_cast<uint8_t>(v >> 8);
}
inline void putU32(uint8_t*& p, uint32_t v) {
  for (int i = 0; i < 4; ++i) *p++ = static_cast<uint8_t>(v >> (8 * i));
}
inline void putI16(uint8_t*& p, int16_t v) { putU16(p, static_cast<uint16_t>(v)); }
inline void putI32(uint8_t*& p, int32_t v) { putU32(p, static_cast<uint32_t>(v)); }
inline uint8_t getU8(const uint8_t*& p) { return *p++; }
inline uint16_t getU16(const uint8_t*& p) {
  uint16_t v = static_cast<uint16_t>(p[0] | (p[1] << 8));
  p += 2;
  return v;
}
inline uint32_t getU32(const uint8_t*& p) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= static_cast<uint32_t>(p[i]) << (8 * i);
  p += 4;
  return v;
}
inline int16_t getI16(const uint8_t*& p) { return static_cast<int16_t>(getU16(p)); }
inline int32_t getI32(const uint8_t*& p) { return static_cast<int32_t>(getU32(p)); }
}  // namespace wire

// ---- payloads
// -------------------------------------------------------------------------------------- Each
// payload struct has kId, kSize (fixed payload length), encode(out) writing kSize bytes, and
// decode(in, n) returning kPayloadSize / kBadValue / kNone. Physical values are fixed-point
// integers on the wire, the unit is in the field name (cdeg = 0.01 deg, mg = 0.001 g, um =
// micrometre).

/// Operating mode (thesis 4.2.2): 1 continuous real time, 2 step sequence.
struct CmdMode {
  static constexpr MsgId kId = MsgId::kMode;
  static constexpr size_t kSize = 1;
  uint8_t mode = 1;
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// Trapezoidal carriage move. Target in micrometres from the far sensor (absolute) or an increment.
struct CmdTrackMove {
  static constexpr MsgId kId = MsgId::kTrackMove;
  static constexpr size_t kSize = 9;
  static constexpr uint8_t kRelative = 0x01;
  int32_t target_um = 0;
  uint8_t flags = 0;
  uint16_t max_speed_mm_s = 0;  ///< 0 = board default
  uint16_t accel_mm_s2 = 0;     ///< 0 = board default
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// Gimbal demands for CarDRV (absolute, or increments with kRelative).
struct CmdServo {
  static constexpr MsgId kId = MsgId::kServo;
  static constexpr size_t kSize = 5;
  static constexpr uint8_t kRelative = 0x01;
  int16_t pitch_cdeg = 0;
  int16_t yaw_cdeg = 0;
  uint8_t flags = 0;
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// Round-trip probe: the board answers with a Pong echoing host_time_ms.
struct CmdPing {
  static constexpr MsgId kId = MsgId::kPing;
  static constexpr size_t kSize = 4;
  uint32_t host_time_ms = 0;
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// Mode 2 settle/wait step: Ack kDone after wait_ms of board time.
struct CmdWait {
  static constexpr MsgId kId = MsgId::kWait;
  static constexpr size_t kSize = 4;
  uint32_t wait_ms = 0;
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// Acknowledgement status codes.
enum class AckStatus : uint8_t {
  kAccepted = 0,     ///< command received and started
  kDone = 1,         ///< command (step) completed
  kBusy = 2,         ///< rejected: a move is in progress
  kNotReady = 3,     ///< rejected: not initialised (homed) / not in the right mode
  kBadArgument = 4,  ///< rejected: value out of range (e.g. target beyond the track)
  kUnsupported = 5,  ///< rejected: this board does not implement that command
  kEStop = 6,        ///< rejected or aborted: emergency stop active
  kEndOfTrack = 7,   ///< aborted: end-of-track sensor tripped during the move
  kFailed = 8,       ///< aborted: e.g. homing did not find the far sensor
  kAborted = 9,      ///< aborted by stop/reset, or superseded by a newer mode 1 demand
};
constexpr uint8_t kMaxAckStatus = 9;

struct Ack {
  static constexpr MsgId kId = MsgId::kAck;
  static constexpr size_t kSize = 6;
  uint32_t acked_seq = 0;  ///< seq of the command this answers
  MsgId acked_id = MsgId::kInit;
  AckStatus status = AckStatus::kAccepted;
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// TrackDRV state values (same numbers as rig_msgs/TrackState STATE_*).
enum class TrackStateCode : uint8_t {
  kUninitialised = 0,
  kHoming = 1,
  kReady = 2,
  kMoving = 3,
  kEndOfTrack = 4,
  kEStop = 5,
  kFault = 6,
};
constexpr uint8_t kMaxTrackState = 6;

struct TrackStatePayload {
  static constexpr MsgId kId = MsgId::kTrackState;
  static constexpr size_t kSize = 20;
  static constexpr uint8_t kNearSensor = 0x01;
  static constexpr uint8_t kFarSensor = 0x02;
  static constexpr uint8_t kEStopFlag = 0x04;
  static constexpr uint8_t kHomed = 0x08;
  uint32_t board_time_ms = 0;  ///< Time1
  int32_t pos_steps = 0;       ///< stepper count from the far sensor
  int32_t pos_um = 0;          ///< TrackPos (micrometres from the far sensor)
  int32_t vel_um_s = 0;        ///< profile velocity (micrometres/s)
  TrackStateCode state = TrackStateCode::kUninitialised;
  uint8_t flags = 0;  ///< kNearSensor | kFarSensor | kEStopFlag | kHomed
  uint8_t mode = 1;
  uint8_t reserved = 0;
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

struct CarSensorsPayload {
  static constexpr MsgId kId = MsgId::kCarSensors;
  static constexpr size_t kSize = 21;
  static constexpr uint8_t kTofValid = 0x01;
  uint32_t board_time_ms = 0;  ///< Time3
  int16_t pitch_dem_cdeg = 0;
  int16_t pitch_cdeg = 0;
  int16_t yaw_dem_cdeg = 0;
  int16_t yaw_cdeg = 0;
  int16_t acc_x_mg = 0;
  int16_t acc_y_mg = 0;
  int16_t acc_z_mg = 0;
  uint16_t tof_mm = 0;  ///< TFPos
  uint8_t flags = 0;    ///< kTofValid
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

struct TruckRcPayload {
  static constexpr MsgId kId = MsgId::kTruckRc;
  static constexpr size_t kSize = 19;
  static constexpr uint8_t kRunning = 0x01;
  static constexpr uint8_t kRecording = 0x02;
  static constexpr uint8_t kSignalOk = 0x04;
  uint32_t board_time_ms = 0;
  uint16_t ch2_us = 0;            ///< steering pulse
  uint16_t ch3_us = 0;            ///< speed/direction pulse
  uint16_t ch5_us = 0;            ///< start/stop switch pulse
  uint16_t ch7_us = 0;            ///< record switch pulse
  int16_t steering_permille = 0;  ///< -1000 .. 1000
  int16_t speed_permille = 0;     ///< -1000 .. 1000 (sign = direction)
  int16_t speed_mm_s = 0;         ///< calibrated forward speed
  uint8_t flags = 0;              ///< kRunning | kRecording | kSignalOk
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

constexpr size_t kNameLen = 16;  ///< fixed, NUL padded name fields

struct VersionInfo {
  static constexpr MsgId kId = MsgId::kVersionInfo;
  static constexpr size_t kSize = 4 + kNameLen;
  uint8_t major = 0, minor = 0, patch = 0;
  uint8_t protocol = kProtocolVersion;
  char name[kNameLen + 1] = {};  ///< e.g. "TrackDRV" (always NUL terminated in memory)
  void setName(const char* s);
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// One board parameter: value = mantissa * 10^exp10, unit in the name ("mm_per_step").
struct ParamValue {
  static constexpr MsgId kId = MsgId::kParamValue;
  static constexpr size_t kSize = 7 + kNameLen;
  uint8_t index = 0;
  uint8_t count = 0;  ///< total number of parameters the board reports
  int32_t mantissa = 0;
  int8_t exp10 = 0;
  char name[kNameLen + 1] = {};
  void setName(const char* s);
  double value() const;
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

struct Pong {
  static constexpr MsgId kId = MsgId::kPong;
  static constexpr size_t kSize = 8;
  uint32_t host_time_ms = 0;   ///< echoed from the ping
  uint32_t board_time_ms = 0;  ///< board clock when the ping was handled
  void encode(uint8_t* out) const;
  DecodeError decode(const uint8_t* in, size_t n);
};

/// Encodes a typed payload as a complete frame; returns the frame size (0 if cap too small).
template <class P>
size_t encodeMessage(BoardId board, uint32_t seq, const P& payload, uint8_t* out, size_t cap) {
  uint8_t buf[P::kSize];
  payload.encode(buf);
  return encodeFrame(board, P::kId, seq, buf, P::kSize, out, cap);
}

/// Encodes a command without payload (init/start/stop/reset/end/vers/para).
size_t encodeCommand(BoardId board, MsgId id, uint32_t seq, uint8_t* out, size_t cap);

/// Decodes the payload of `f` as P: kWrongMessage if the id differs, else P::decode's result.
template <class P>
DecodeError decodePayload(const Frame& f, P& out) {
  if (f.id != P::kId) return DecodeError::kWrongMessage;
  return out.decode(f.payload, f.length);
}

/// Receives decoder output.
class FrameSink {
 public:
  virtual ~FrameSink() = default;
  virtual void onFrame(const Frame& frame) = 0;
  /// `discarded` = bytes dropped because of this error (0 for errors that drop no bytes).
  virtual void onError(DecodeError error, size_t discarded) {
    (void)error;
    (void)discarded;
  }
};

/// Counters kept by the decoder (for diagnostics topics and tests).
struct DecoderStats {
  uint32_t frames = 0;
  uint32_t bad_crc = 0;
  uint32_t bad_length = 0;
  uint32_t version_mismatch = 0;
  uint32_t unknown = 0;  ///< unknown message or board id
  uint32_t truncated = 0;
  uint32_t bytes_discarded = 0;  ///< garbage bytes skipped while hunting for sync
};

/// Streaming decoder: feed any byte chunks (split anywhere), get complete CRC-checked frames.
/// After a bad frame it rescans from the byte after the failed sync, so a valid frame that starts
/// inside garbage or inside a corrupted/truncated frame is still found. Not thread-safe; one per
/// link. Fixed storage (kMaxFrameSize), no heap.
class StreamDecoder {
 public:
  /// Feeds `n` bytes; calls sink.onFrame / sink.onError for every frame / error found, in order.
  void feed(const uint8_t* data, size_t n, FrameSink& sink);
  /// Reports kTruncated if a partial frame is pending (e.g. the port closed) and clears it.
  void flush(FrameSink& sink);
  /// The line has gone quiet, so a pending candidate can never complete (garbage that looked like
  /// a frame start, with a length reaching past what arrived). Gives up candidate starts one byte
  /// at a time (each reported as kTruncated) and rescans, so every complete frame still buffered
  /// is delivered. Leaves nothing pending.
  void expire(FrameSink& sink);
  /// Drops any partial frame without reporting (e.g. after reopening a port).
  void reset() { len_ = 0; }
  /// Bytes of a partial frame currently buffered.
  size_t pending() const { return len_; }
  const DecoderStats& stats() const { return stats_; }

 private:
  void process(FrameSink& sink);
  void drop(size_t n);

  uint8_t buf_[kMaxFrameSize] = {};
  size_t len_ = 0;
  DecoderStats stats_;
  Frame frame_;
};

#if RIG_DRIVERS_HOST
// ---- host conveniences (codec_host.cpp) ---------------------------------------------------------

/// Short name of a message id ("TrackState", ...), "unknown" otherwise.
const char* msgName(MsgId id);
/// Human readable name of an error ("bad CRC", ...).
const char* errorName(DecodeError e);
/// Name of an ack status ("done", "busy", ...).
const char* ackStatusName(AckStatus s);

/// One decoder output: error == kNone means `frame` is valid.
struct DecodeEvent {
  DecodeError error = DecodeError::kNone;
  size_t discarded = 0;
  Frame frame;
};

/// Feeds bytes and returns all events (frames and errors) in order.
std::vector<DecodeEvent> feed(StreamDecoder& decoder, const uint8_t* data, size_t n);
inline std::vector<DecodeEvent> feed(StreamDecoder& decoder, const std::vector<uint8_t>& bytes) {
  return feed(decoder, bytes.data(), bytes.size());
}

/// Frame as a byte vector (host side).
template <class P>
std::vector<uint8_t> encodeMessage(BoardId board, uint32_t seq, const P& payload) {
  std::vector<uint8_t> out(kMaxFrameSize);
  out.resize(encodeMessage(board, seq, payload, out.data(), out.size()));
  return out;
}
std::vector<uint8_t> encodeCommand(BoardId board, MsgId id, uint32_t seq);

/// The frame re-encoded exactly as it was on the wire (for rig_msgs/RawFrame recording).
std::vector<uint8_t> frameBytes(const Frame& f);

#endif  // RIG_DRIVERS_HOST

}  // namespace protocol
}  // namespace rig_drivers
