// Board part of the codec: builds for the boards (avr-libc only) and for the host. The host's
// names and std::vector conveniences are in codec_host.cpp.
#include "rig_drivers/protocol/codec.hpp"

#include <string.h>

namespace rig_drivers {
namespace protocol {

using namespace wire;

bool isKnownMsgId(uint8_t id) {
  switch (static_cast<MsgId>(id)) {
    case MsgId::kInit:
    case MsgId::kMode:
    case MsgId::kStart:
    case MsgId::kStop:
    case MsgId::kReset:
    case MsgId::kEnd:
    case MsgId::kVers:
    case MsgId::kPara:
    case MsgId::kTrackMove:
    case MsgId::kServo:
    case MsgId::kPing:
    case MsgId::kWait:
    case MsgId::kAck:
    case MsgId::kTrackState:
    case MsgId::kCarSensors:
    case MsgId::kTruckRc:
    case MsgId::kVersionInfo:
    case MsgId::kParamValue:
    case MsgId::kPong:
      return true;
  }
  return false;
}

bool isKnownBoard(uint8_t b) { return b <= static_cast<uint8_t>(BoardId::kTruck); }

uint16_t crc16(const uint8_t* data, size_t n, uint16_t crc) {
  for (size_t i = 0; i < n; ++i) {
    crc ^= static_cast<uint16_t>(data[i]) << 8;
    for (int b = 0; b < 8; ++b) {
      crc = (crc & 0x8000) ? static_cast<uint16_t>((crc << 1) ^ 0x1021)
                           : static_cast<uint16_t>(crc << 1);
    }
  }
  return crc;
}

size_t encodeFrame(BoardId board, MsgId id, uint32_t seq, const uint8_t* payload,
                   size_t payload_len, uint8_t* out, size_t cap) {
  if (payload_len > kMaxPayload) return 0;
  const size_t total = kHeaderSize + payload_len + kCrcSize;
  if (cap < total) return 0;
  uint8_t* p = out;
  putU8(p, kSync0);
  putU8(p, kSync1);
  putU8(p, static_cast<uint8_t>(payload_len));
  putU8(p, kProtocolVersion);
  putU8(p, static_cast<uint8_t>(board));
  putU8(p, static_cast<uint8_t>(id));
  putU32(p, seq);
  if (payload_len > 0) memcpy(p, payload, payload_len);
  p += payload_len;
  putU16(p, crc16(out + 2, kHeaderSize - 2 + payload_len));
  return total;
}

size_t encodeCommand(BoardId board, MsgId id, uint32_t seq, uint8_t* out, size_t cap) {
  return encodeFrame(board, id, seq, nullptr, 0, out, cap);
}

// ---- payloads
// ----------------------------------------------------------------------------------------

namespace {
void copyName(char* dst, const char* src) {
  size_t i = 0;
  for (; src != nullptr && src[i] != '\0' && i < kNameLen; ++i) dst[i] = src[i];
  for (; i <= kNameLen; ++i) dst[i] = '\0';
}
void putName(uint8_t*& p, const char* name) {
  for (size_t i = 0; i < kNameLen; ++i) *p++ = static_cast<uint8_t>(name[i]);
}
// Names must be printable ASCII, NUL padded (no printable byte after the first NUL).
bool getName(const uint8_t*& p, char* name) {
  bool ended = false;
  for (size_t i = 0; i < kNameLen; ++i) {
    const uint8_t c = *p++;
    if (c == 0) {
      ended = true;
    } else if (ended || c < 0x20 || c > 0x7E) {
      return false;
    }
    name[i] = static_cast<char>(c);
  }
  name[kNameLen] = '\0';
  return true;
}
}  // namespace

void CmdMode::encode(uint8_t* out) const { putU8(out, mode); }
DecodeError CmdMode::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  mode = getU8(in);
  return (mode == 1 || mode == 2) ? DecodeError::kNone : DecodeError::kBadValue;
}

void CmdTrackMove::encode(uint8_t* out) const {
  putI32(out, target_um);
  putU8(out, flags);
  putU16(out, max_speed_mm_s);
  putU16(out, accel_mm_s2);
}
DecodeError CmdTrackMove::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  target_um = getI32(in);
  flags = getU8(in);
  max_speed_mm_s = getU16(in);
  accel_mm_s2 = getU16(in);
  return (flags & ~kRelative) == 0 ? DecodeError::kNone : DecodeError::kBadValue;
}

void CmdServo::encode(uint8_t* out) const {
  putI16(out, pitch_cdeg);
  putI16(out, yaw_cdeg);
  putU8(out, flags);
}
DecodeError CmdServo::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  pitch_cdeg = getI16(in);
  yaw_cdeg = getI16(in);
  flags = getU8(in);
  return (flags & ~kRelative) == 0 ? DecodeError::kNone : DecodeError::kBadValue;
}

void CmdPing::encode(uint8_t* out) const { putU32(out, host_time_ms); }
DecodeError CmdPing::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  host_time_ms = getU32(in);
  return DecodeError::kNone;
}

void CmdWait::encode(uint8_t* out) const { putU32(out, wait_ms); }
DecodeError CmdWait::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  wait_ms = getU32(in);
  return DecodeError::kNone;
}

void Ack::encode(uint8_t* out) const {
  putU32(out, acked_seq);
  putU8(out, static_cast<uint8_t>(acked_id));
  putU8(out, static_cast<uint8_t>(status));
}
DecodeError Ack::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  acked_seq = getU32(in);
  const uint8_t id = getU8(in);
  const uint8_t st = getU8(in);
  if (!isKnownMsgId(id) || st > kMaxAckStatus) return DecodeError::kBadValue;
  acked_id = static_cast<MsgId>(id);
  status = static_cast<AckStatus>(st);
  return DecodeError::kNone;
}

void TrackStatePayload::encode(uint8_t* out) const {
  putU32(out, board_time_ms);
  putI32(out, pos_steps);
  putI32(out, pos_um);
  putI32(out, vel_um_s);
  putU8(out, static_cast<uint8_t>(state));
  putU8(out, flags);
  putU8(out, mode);
  putU8(out, reserved);
}
DecodeError TrackStatePayload::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  board_time_ms = getU32(in);
  pos_steps = getI32(in);
  pos_um = getI32(in);
  vel_um_s = getI32(in);
  const uint8_t st = getU8(in);
  flags = getU8(in);
  mode = getU8(in);
  reserved = getU8(in);
  if (st > kMaxTrackState || (mode != 1 && mode != 2) || (flags & 0xF0) != 0)
    return DecodeError::kBadValue;
  state = static_cast<TrackStateCode>(st);
  return DecodeError::kNone;
}

void CarSensorsPayload::encode(uint8_t* out) const {
  putU32(out, board_time_ms);
  putI16(out, pitch_dem_cdeg);
  putI16(out, pitch_cdeg);
  putI16(out, yaw_dem_cdeg);
  putI16(out, yaw_cdeg);
  putI16(out, acc_x_mg);
  putI16(out, acc_y_mg);
  putI16(out, acc_z_mg);
  putU16(out, tof_mm);
  putU8(out, flags);
}
DecodeError CarSensorsPayload::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  board_time_ms = getU32(in);
  pitch_dem_cdeg = getI16(in);
  pitch_cdeg = getI16(in);
  yaw_dem_cdeg = getI16(in);
  yaw_cdeg = getI16(in);
  acc_x_mg = getI16(in);
  acc_y_mg = getI16(in);
  acc_z_mg = getI16(in);
  tof_mm = getU16(in);
  flags = getU8(in);
  return (flags & ~kTofValid) == 0 ? DecodeError::kNone : DecodeError::kBadValue;
}

void TruckRcPayload::encode(uint8_t* out) const {
  putU32(out, board_time_ms);
  putU16(out, ch2_us);
  putU16(out, ch3_us);
  putU16(out, ch5_us);
  putU16(out, ch7_us);
  putI16(out, steering_permille);
  putI16(out, speed_permille);
  putI16(out, speed_mm_s);
  putU8(out, flags);
}
DecodeError TruckRcPayload::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  board_time_ms = getU32(in);
  ch2_us = getU16(in);
  ch3_us = getU16(in);
  ch5_us = getU16(in);
  ch7_us = getU16(in);
  steering_permille = getI16(in);
  speed_permille = getI16(in);
  speed_mm_s = getI16(in);
  flags = getU8(in);
  const bool ok = steering_permille >= -1000 && steering_permille <= 1000 &&
                  speed_permille >= -1000 && speed_permille <= 1000 &&
                  (flags & ~(kRunning | kRecording | kSignalOk)) == 0;
  return ok ? DecodeError::kNone : DecodeError::kBadValue;
}

void VersionInfo::setName(const char* s) { copyName(name, s); }
void VersionInfo::encode(uint8_t* out) const {
  putU8(out, major);
  putU8(out, minor);
  putU8(out, patch);
  putU8(out, protocol);
  putName(out, name);
}
DecodeError VersionInfo::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  major = getU8(in);
  minor = getU8(in);
  patch = getU8(in);
  protocol = getU8(in);
  return getName(in, name) ? DecodeError::kNone : DecodeError::kBadValue;
}

void ParamValue::setName(const char* s) { copyName(name, s); }
double ParamValue::value() const {
  double v = mantissa;
  for (int i = 0; i < exp10; ++i) v *= 10.0;
  for (int i = 0; i > exp10; --i) v /= 10.0;
  return v;
}
void ParamValue::encode(uint8_t* out) const {
  putU8(out, index);
  putU8(out, count);
  putI32(out, mantissa);
  putU8(out, static_cast<uint8_t>(exp10));
  putName(out, name);
}
DecodeError ParamValue::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  index = getU8(in);
  count = getU8(in);
  mantissa = getI32(in);
  exp10 = static_cast<int8_t>(getU8(in));
  if (!getName(in, name)) return DecodeError::kBadValue;
  return (index < count && exp10 >= -12 && exp10 <= 12) ? DecodeError::kNone
                                                        : DecodeError::kBadValue;
}

void Pong::encode(uint8_t* out) const {
  putU32(out, host_time_ms);
  putU32(out, board_time_ms);
}
DecodeError Pong::decode(const uint8_t* in, size_t n) {
  if (n != kSize) return DecodeError::kPayloadSize;
  host_time_ms = getU32(in);
  board_time_ms = getU32(in);
  return DecodeError::kNone;
}

// ---- streaming decoder
// ---------------------------------------------------------------------------------

void StreamDecoder::drop(size_t n) {
  if (n >= len_) {
    len_ = 0;
    return;
  }
  memmove(buf_, buf_ + n, len_ - n);
  len_ -= n;
}

void StreamDecoder::feed(const uint8_t* data, size_t n, FrameSink& sink) {
  for (size_t i = 0; i < n; ++i) {
    buf_[len_++] = data[i];
    process(sink);
  }
}

// Examines the buffer from its start until it needs more bytes. Every byte of the buffer is a
// possible frame start until proven otherwise, so a failed candidate drops only its first byte.
void StreamDecoder::process(FrameSink& sink) {
  size_t garbage = 0;
  auto flushGarbage = [&]() {
    if (garbage > 0) {
      stats_.bytes_discarded += static_cast<uint32_t>(garbage);
      garbage = 0;
    }
  };
  while (len_ > 0) {
    if (buf_[0] != kSync0 || (len_ >= 2 && buf_[1] != kSync1)) {
      drop(1);
      ++garbage;
      continue;
    }
    if (len_ < 3) break;
    const size_t plen = buf_[2];
    if (plen > kMaxPayload) {
      flushGarbage();
      ++stats_.bad_length;
      drop(1);
      sink.onError(DecodeError::kBadLength, 1);
      continue;
    }
    const size_t total = kHeaderSize + plen + kCrcSize;
    if (len_ < total) break;
    const uint16_t want = static_cast<uint16_t>(buf_[total - 2] | (buf_[total - 1] << 8));
    if (crc16(buf_ + 2, kHeaderSize - 2 + plen) != want) {
      flushGarbage();
      ++stats_.bad_crc;
      drop(1);
      sink.onError(DecodeError::kBadCrc, 1);
      continue;
    }
    flushGarbage();
    // A CRC-valid frame: whatever is wrong with it now is a real protocol error, skip it whole.
    DecodeError err = DecodeError::kNone;
    if (buf_[3] != kProtocolVersion) {
      err = DecodeError::kVersionMismatch;
      ++stats_.version_mismatch;
    } else if (!isKnownBoard(buf_[4])) {
      err = DecodeError::kUnknownBoard;
      ++stats_.unknown;
    } else if (!isKnownMsgId(buf_[5])) {
      err = DecodeError::kUnknownMessage;
      ++stats_.unknown;
    }
    if (err != DecodeError::kNone) {
      drop(total);
      sink.onError(err, total);
      continue;
    }
    frame_.version = buf_[3];
    frame_.board = static_cast<BoardId>(buf_[4]);
    frame_.id = static_cast<MsgId>(buf_[5]);
    const uint8_t* p = buf_ + 6;
    frame_.seq = getU32(p);
    frame_.length = static_cast<uint8_t>(plen);
    memcpy(frame_.payload, buf_ + kHeaderSize, plen);
    memset(frame_.payload + plen, 0, kMaxPayload - plen);
    ++stats_.frames;
    drop(total);
    sink.onFrame(frame_);
  }
  flushGarbage();
}

void StreamDecoder::expire(FrameSink& sink) {
  while (len_ > 0) {
    ++stats_.truncated;
    drop(1);
    sink.onError(DecodeError::kTruncated, 1);
    process(sink);
  }
}

void StreamDecoder::flush(FrameSink& sink) {
  if (len_ == 0) return;
  const size_t n = len_;
  len_ = 0;
  ++stats_.truncated;
  sink.onError(DecodeError::kTruncated, n);
}

}  // namespace protocol
}  // namespace rig_drivers
