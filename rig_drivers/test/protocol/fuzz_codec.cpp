// libFuzzer target for the rig serial codec alone (StreamDecoder, frame encoder, payload
// decoders); the boards have their own target (fuzz_firmware.cpp) so this one stays fast.
// Built and run by rig_drivers/scripts/run_codec_fuzz.sh (clang-14, ASan + UBSan).
//
// Input layout:
//   byte 0       bits 0-2: k, the number of chunk-size bytes that follow;
//                bit 3: repair CRCs (every complete frame candidate gets its correct CRC, so
//                mutated headers and payloads reach the checks behind the CRC)
//   bytes 1..k   chunk sizes of the split feed (byte + 1, used in turn); k = 0: byte by byte
//   the rest     the byte stream as it would arrive on a serial link
// The seed corpus (rig_drivers/test/fuzz/corpus/codec) is recorded frames of scenario bags.
//
// Properties checked on every input:
//  - the streaming decoder gives the same events as a plain whole-buffer reference scan written
//    from the frame layout (same errors, same byte counts, same frames), fed in one call and
//    split at the input's chunk sizes;
//  - every decoded frame re-encodes to exactly the bytes it was decoded from;
//  - every byte is accounted for: frames + skipped garbage + one byte per bad CRC / bad length
//    + whole dropped frames + pending = input length, and the decoder's counters say the same;
//  - exactly the payload type of a frame's id decodes it; a wrong length is kPayloadSize; a
//    payload that decodes re-encodes to the identical bytes; decoded values are in range;
//  - flush reports the pending bytes as one truncated frame, and the decoder then decodes a
//    valid frame again.
#include <cmath>
#include <cstring>
#include <vector>

#include "fuzz_check.hpp"
#include "rig_drivers/protocol/codec.hpp"

namespace rp = rig_drivers::protocol;
using rp::DecodeError;

namespace {

struct RefEvent {
  DecodeError error = DecodeError::kNone;
  size_t offset = 0;  ///< first byte of the frame / of the dropped bytes
  size_t size = 0;    ///< frame size, or bytes dropped by the error
};

struct RefResult {
  std::vector<RefEvent> events;
  size_t garbage = 0;  ///< bytes skipped while hunting for sync (no event)
  size_t pending = 0;  ///< bytes of an incomplete candidate at the end
};

// Whole-buffer scan straight from the frame layout in codec.hpp: at each position either a frame
// starts (sync, length <= kMaxPayload, complete, CRC valid) or it does not and the scan moves on
// by one byte; CRC-valid frames of another version / board / id are dropped whole.
RefResult referenceDecode(const uint8_t* s, size_t n) {
  RefResult r;
  size_t i = 0;
  while (i < n) {
    if (s[i] != rp::kSync0) {
      ++r.garbage;
      ++i;
      continue;
    }
    if (i + 1 >= n) break;
    if (s[i + 1] != rp::kSync1) {
      ++r.garbage;
      ++i;
      continue;
    }
    if (i + 2 >= n) break;
    const size_t plen = s[i + 2];
    if (plen > rp::kMaxPayload) {
      r.events.push_back({DecodeError::kBadLength, i, 1});
      ++i;
      continue;
    }
    const size_t total = rp::kHeaderSize + plen + rp::kCrcSize;
    if (i + total > n) break;
    const uint16_t crc = static_cast<uint16_t>(s[i + total - 2] | (s[i + total - 1] << 8));
    if (rp::crc16(s + i + 2, rp::kHeaderSize - 2 + plen) != crc) {
      r.events.push_back({DecodeError::kBadCrc, i, 1});
      ++i;
      continue;
    }
    DecodeError e = DecodeError::kNone;
    if (s[i + 3] != rp::kProtocolVersion)
      e = DecodeError::kVersionMismatch;
    else if (!rp::isKnownBoard(s[i + 4]))
      e = DecodeError::kUnknownBoard;
    else if (!rp::isKnownMsgId(s[i + 5]))
      e = DecodeError::kUnknownMessage;
    r.events.push_back({e, i, total});
    i += total;
  }
  r.pending = n - i;
  return r;
}

// Rewrites the CRC of every complete frame candidate (sync + valid length) in place.
void repairCrcs(std::vector<uint8_t>& s) {
  size_t i = 0;
  while (i + 2 < s.size()) {
    const size_t total = rp::kHeaderSize + s[i + 2] + rp::kCrcSize;
    if (s[i] == rp::kSync0 && s[i + 1] == rp::kSync1 && s[i + 2] <= rp::kMaxPayload &&
        i + total <= s.size()) {
      const uint16_t crc = rp::crc16(s.data() + i + 2, total - 4);
      s[i + total - 2] = static_cast<uint8_t>(crc);
      s[i + total - 1] = static_cast<uint8_t>(crc >> 8);
      i += total;
    } else {
      ++i;
    }
  }
}

bool sameFrame(const rp::Frame& a, const rp::Frame& b) {
  return a.version == b.version && a.board == b.board && a.id == b.id && a.seq == b.seq &&
         a.length == b.length && std::memcmp(a.payload, b.payload, rp::kMaxPayload) == 0;
}

void compareEvents(const std::vector<rp::DecodeEvent>& got, const RefResult& ref, const char* how) {
  FUZZ_CHECK(got.size() == ref.events.size(), "%s: %zu events, reference %zu", how, got.size(),
             ref.events.size());
  for (size_t i = 0; i < got.size(); ++i) {
    const RefEvent& r = ref.events[i];
    FUZZ_CHECK(got[i].error == r.error, "%s: event %zu is '%s', reference '%s' at byte %zu", how, i,
               rp::errorName(got[i].error), rp::errorName(r.error), r.offset);
    if (r.error != DecodeError::kNone)
      FUZZ_CHECK(got[i].discarded == r.size, "%s: event %zu dropped %zu bytes, reference %zu", how,
                 i, got[i].discarded, r.size);
  }
}

// The valid ranges as codec.hpp documents them, checked on every payload that decoded.
bool known(rp::MsgId id) { return std::strcmp(rp::msgName(id), "unknown") != 0; }
bool validName(const char* name) {
  if (name[rp::kNameLen] != '\0') return false;
  for (const char* c = name; *c; ++c)
    if (*c < 0x20 || *c > 0x7E) return false;
  return true;
}
bool inRange(const rp::CmdMode& p) { return p.mode == 1 || p.mode == 2; }
bool inRange(const rp::CmdTrackMove& p) { return (p.flags & ~rp::CmdTrackMove::kRelative) == 0; }
bool inRange(const rp::CmdServo& p) { return (p.flags & ~rp::CmdServo::kRelative) == 0; }
bool inRange(const rp::CmdPing&) { return true; }
bool inRange(const rp::CmdWait&) { return true; }
bool inRange(const rp::Ack& p) {
  return known(p.acked_id) && static_cast<uint8_t>(p.status) <= rp::kMaxAckStatus &&
         std::strcmp(rp::ackStatusName(p.status), "unknown status") != 0;
}
bool inRange(const rp::TrackStatePayload& p) {
  return static_cast<uint8_t>(p.state) <= rp::kMaxTrackState && (p.mode == 1 || p.mode == 2) &&
         (p.flags & 0xF0) == 0;
}
bool inRange(const rp::CarSensorsPayload& p) {
  return (p.flags & ~rp::CarSensorsPayload::kTofValid) == 0;
}
bool inRange(const rp::TruckRcPayload& p) {
  const int all =
      rp::TruckRcPayload::kRunning | rp::TruckRcPayload::kRecording | rp::TruckRcPayload::kSignalOk;
  return p.steering_permille >= -1000 && p.steering_permille <= 1000 && p.speed_permille >= -1000 &&
         p.speed_permille <= 1000 && (p.flags & ~all) == 0;
}
bool inRange(const rp::VersionInfo& p) { return validName(p.name); }
bool inRange(const rp::ParamValue& p) {
  if (!validName(p.name) || p.index >= p.count || p.exp10 < -12 || p.exp10 > 12) return false;
  const double want = p.mantissa * std::pow(10.0, p.exp10);
  return std::fabs(p.value() - want) <= 1e-12 * std::fabs(want);
}
bool inRange(const rp::Pong&) { return true; }

// Payload checks for one payload type P against a decoded frame.
template <class P>
void checkTyped(const rp::Frame& f, int& decoders_for_id) {
  P p;
  const DecodeError e = rp::decodePayload(f, p);
  if (f.id != P::kId) {
    FUZZ_CHECK(e == DecodeError::kWrongMessage, "%s decoded a %s frame: %s", rp::msgName(P::kId),
               rp::msgName(f.id), rp::errorName(e));
    return;
  }
  ++decoders_for_id;
  if (f.length != P::kSize) {
    FUZZ_CHECK(e == DecodeError::kPayloadSize, "%s with %u payload bytes: %s", rp::msgName(f.id),
               f.length, rp::errorName(e));
    return;
  }
  FUZZ_CHECK(e == DecodeError::kNone || e == DecodeError::kBadValue, "%s: %s", rp::msgName(f.id),
             rp::errorName(e));
  if (e != DecodeError::kNone) return;
  FUZZ_CHECK(inRange(p), "%s decoded a value outside its range", rp::msgName(f.id));
  uint8_t buf[P::kSize];
  p.encode(buf);
  FUZZ_CHECK(std::memcmp(buf, f.payload, P::kSize) == 0, "%s payload does not re-encode",
             rp::msgName(f.id));
}

void checkFrame(const rp::Frame& f, const uint8_t* at, size_t size) {
  const auto bytes = rp::frameBytes(f);
  FUZZ_CHECK(bytes.size() == size && std::memcmp(bytes.data(), at, size) == 0,
             "frame (%s, %zu bytes) does not re-encode to its input bytes", rp::msgName(f.id),
             size);
  for (size_t i = f.length; i < rp::kMaxPayload; ++i)
    FUZZ_CHECK(f.payload[i] == 0, "stale payload byte %zu after %u used", i, f.length);
  int decoders = 0;
  checkTyped<rp::CmdMode>(f, decoders);
  checkTyped<rp::CmdTrackMove>(f, decoders);
  checkTyped<rp::CmdServo>(f, decoders);
  checkTyped<rp::CmdPing>(f, decoders);
  checkTyped<rp::CmdWait>(f, decoders);
  checkTyped<rp::Ack>(f, decoders);
  checkTyped<rp::TrackStatePayload>(f, decoders);
  checkTyped<rp::CarSensorsPayload>(f, decoders);
  checkTyped<rp::TruckRcPayload>(f, decoders);
  checkTyped<rp::VersionInfo>(f, decoders);
  checkTyped<rp::ParamValue>(f, decoders);
  checkTyped<rp::Pong>(f, decoders);
  FUZZ_CHECK(decoders <= 1, "%d payload types claim id %s", decoders, rp::msgName(f.id));
}

// Payload decoders fed the raw stream directly (no CRC in the way): right size decodes or is a
// bad value and re-encodes identically, a size one off either way is kPayloadSize.
template <class P>
void checkRawPayload(const uint8_t* s, size_t n) {
  if (n < P::kSize + 1) return;
  P p;
  FUZZ_CHECK(p.decode(s, P::kSize - 1) == DecodeError::kPayloadSize, "%s short",
             rp::msgName(P::kId));
  FUZZ_CHECK(p.decode(s, P::kSize + 1) == DecodeError::kPayloadSize, "%s long",
             rp::msgName(P::kId));
  const DecodeError e = p.decode(s, P::kSize);
  FUZZ_CHECK(e == DecodeError::kNone || e == DecodeError::kBadValue, "%s: %s", rp::msgName(P::kId),
             rp::errorName(e));
  if (e != DecodeError::kNone) return;
  FUZZ_CHECK(inRange(p), "%s decoded a value outside its range", rp::msgName(P::kId));
  uint8_t buf[P::kSize];
  p.encode(buf);
  FUZZ_CHECK(std::memcmp(buf, s, P::kSize) == 0, "%s does not re-encode", rp::msgName(P::kId));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const size_t k = data[0] & 7;
  const bool repair = (data[0] & 8) != 0;
  if (size < 1 + k) return 0;
  const uint8_t* chunks = data + 1;
  std::vector<uint8_t> stream(data + 1 + k, data + size);
  if (repair) repairCrcs(stream);
  const uint8_t* s = stream.data();
  const size_t n = stream.size();

  const RefResult ref = referenceDecode(s, n);

  rp::StreamDecoder whole;
  const auto ev_whole = rp::feed(whole, s, n);
  compareEvents(ev_whole, ref, "one feed");

  rp::StreamDecoder split;
  std::vector<rp::DecodeEvent> ev_split;
  for (size_t pos = 0, c = 0; pos < n; ++c) {
    const size_t want = k == 0 ? 1 : static_cast<size_t>(chunks[c % k]) + 1;
    const size_t m = pos + want <= n ? want : n - pos;
    const auto ev = rp::feed(split, s + pos, m);
    ev_split.insert(ev_split.end(), ev.begin(), ev.end());
    pos += m;
  }
  compareEvents(ev_split, ref, "split feed");

  size_t frame_bytes = 0, dropped_whole = 0, bad_crc = 0, bad_length = 0, version = 0, unknown = 0,
         frames = 0;
  for (size_t i = 0; i < ev_whole.size(); ++i) {
    const RefEvent& r = ref.events[i];
    switch (r.error) {
      case DecodeError::kNone:
        FUZZ_CHECK(sameFrame(ev_whole[i].frame, ev_split[i].frame), "split changed frame %zu", i);
        checkFrame(ev_whole[i].frame, s + r.offset, r.size);
        frame_bytes += r.size;
        ++frames;
        break;
      case DecodeError::kBadCrc:
        ++bad_crc;
        break;
      case DecodeError::kBadLength:
        ++bad_length;
        break;
      case DecodeError::kVersionMismatch:
        ++version;
        dropped_whole += r.size;
        break;
      default:
        ++unknown;
        dropped_whole += r.size;
        break;
    }
  }
  FUZZ_CHECK(frame_bytes + ref.garbage + bad_crc + bad_length + dropped_whole + ref.pending == n,
             "bytes not accounted for: %zu frame + %zu garbage + %zu crc + %zu length + %zu "
             "dropped + %zu pending != %zu",
             frame_bytes, ref.garbage, bad_crc, bad_length, dropped_whole, ref.pending, n);
  for (const rp::StreamDecoder* d : {&whole, &split}) {
    const rp::DecoderStats& st = d->stats();
    FUZZ_CHECK(st.frames == frames && st.bad_crc == bad_crc && st.bad_length == bad_length &&
                   st.version_mismatch == version && st.unknown == unknown &&
                   st.bytes_discarded == ref.garbage && st.truncated == 0,
               "decoder counters (%u frames %u crc %u length %u version %u unknown %u garbage) "
               "differ from the events",
               st.frames, st.bad_crc, st.bad_length, st.version_mismatch, st.unknown,
               st.bytes_discarded);
    FUZZ_CHECK(d->pending() == ref.pending, "pending %zu, reference %zu", d->pending(),
               ref.pending);
  }

  checkRawPayload<rp::CmdMode>(s, n);
  checkRawPayload<rp::CmdTrackMove>(s, n);
  checkRawPayload<rp::CmdServo>(s, n);
  checkRawPayload<rp::CmdPing>(s, n);
  checkRawPayload<rp::CmdWait>(s, n);
  checkRawPayload<rp::Ack>(s, n);
  checkRawPayload<rp::TrackStatePayload>(s, n);
  checkRawPayload<rp::CarSensorsPayload>(s, n);
  checkRawPayload<rp::TruckRcPayload>(s, n);
  checkRawPayload<rp::VersionInfo>(s, n);
  checkRawPayload<rp::ParamValue>(s, n);
  checkRawPayload<rp::Pong>(s, n);

  // flush: the pending bytes become one truncated frame; then the decoder starts clean.
  std::vector<rp::DecodeEvent> flushed;
  struct Sink : rp::FrameSink {
    std::vector<rp::DecodeEvent>* out;
    void onFrame(const rp::Frame& f) override {
      rp::DecodeEvent e;
      e.frame = f;
      out->push_back(e);
    }
    void onError(DecodeError e, size_t discarded) override {
      rp::DecodeEvent ev;
      ev.error = e;
      ev.discarded = discarded;
      out->push_back(ev);
    }
  } sink;
  sink.out = &flushed;
  split.flush(sink);
  if (ref.pending > 0) {
    FUZZ_CHECK(flushed.size() == 1 && flushed[0].error == DecodeError::kTruncated &&
                   flushed[0].discarded == ref.pending && split.stats().truncated == 1,
               "flush of %zu pending bytes gave %zu events", ref.pending, flushed.size());
  } else {
    FUZZ_CHECK(flushed.empty() && split.stats().truncated == 0, "flush with nothing pending");
  }
  FUZZ_CHECK(split.pending() == 0, "flush left %zu bytes", split.pending());
  rp::Pong pong;
  pong.host_time_ms = 1;
  const auto probe = rp::encodeMessage(rp::BoardId::kCar, 7, pong);
  const auto after = rp::feed(split, probe);
  FUZZ_CHECK(after.size() == 1 && after[0].error == DecodeError::kNone &&
                 rp::frameBytes(after[0].frame) == probe,
             "decoder did not decode a valid frame after flush (%zu events)", after.size());
  return 0;
}
