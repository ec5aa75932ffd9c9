// libFuzzer target for the rig serial codec (built by scripts/run_codec_fuzz.sh with clang).
// Properties checked on arbitrary input, fed in input-chosen chunk sizes:
//  - no crash / sanitizer report;
//  - every frame the decoder returns re-encodes to bytes that occur verbatim in the input;
//  - every payload that decodes re-encodes to the identical payload bytes;
//  - chunking does not change the result (same frames as feeding everything at once).
#include <cstdlib>
#include <string>
#include <vector>

#include "rig_drivers/protocol/codec.hpp"

namespace rp = rig_drivers::protocol;

namespace {

void check(bool ok) {
  if (!ok) std::abort();
}

template <class P>
void payloadRoundTrip(const rp::Frame& f) {
  P p;
  if (rp::decodePayload(f, p) != rp::DecodeError::kNone) return;
  uint8_t buf[P::kSize];
  p.encode(buf);
  check(f.length == P::kSize);
  for (size_t i = 0; i < P::kSize; ++i) check(buf[i] == f.payload[i]);
}

void checkFrame(const rp::Frame& f, const uint8_t* data, size_t n) {
  const auto bytes = rp::frameBytes(f);
  check(!bytes.empty());
  const std::string hay(reinterpret_cast<const char*>(data), n);
  const std::string needle(bytes.begin(), bytes.end());
  check(hay.find(needle) != std::string::npos);
  payloadRoundTrip<rp::CmdMode>(f);
  payloadRoundTrip<rp::CmdTrackMove>(f);
  payloadRoundTrip<rp::CmdServo>(f);
  payloadRoundTrip<rp::CmdPing>(f);
  payloadRoundTrip<rp::CmdWait>(f);
  payloadRoundTrip<rp::Ack>(f);
  payloadRoundTrip<rp::TrackStatePayload>(f);
  payloadRoundTrip<rp::CarSensorsPayload>(f);
  payloadRoundTrip<rp::TruckRcPayload>(f);
  payloadRoundTrip<rp::VersionInfo>(f);
  payloadRoundTrip<rp::ParamValue>(f);
  payloadRoundTrip<rp::Pong>(f);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  // First byte chooses the chunk size of the streamed feed (1..32 bytes).
  const size_t chunk = 1 + (data[0] & 31);
  const uint8_t* stream = data + 1;
  const size_t n = size - 1;

  rp::StreamDecoder whole;
  const auto ev_whole = rp::feed(whole, stream, n);

  rp::StreamDecoder split;
  std::vector<rp::DecodeEvent> ev_split;
  for (size_t pos = 0; pos < n; pos += chunk) {
    const size_t m = pos + chunk <= n ? chunk : n - pos;
    auto ev = rp::feed(split, stream + pos, m);
    ev_split.insert(ev_split.end(), ev.begin(), ev.end());
  }
  check(ev_whole.size() == ev_split.size());
  for (size_t i = 0; i < ev_whole.size(); ++i) {
    check(ev_whole[i].error == ev_split[i].error);
    if (ev_whole[i].error != rp::DecodeError::kNone) continue;
    check(rp::frameBytes(ev_whole[i].frame) == rp::frameBytes(ev_split[i].frame));
    checkFrame(ev_whole[i].frame, stream, n);
  }
  check(whole.pending() == split.pending());
  check(whole.pending() < rp::kMaxFrameSize);
  return 0;
}
