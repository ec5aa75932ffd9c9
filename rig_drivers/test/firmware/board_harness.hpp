#pragma once
// Test helpers: capture a board's serial output as decoded frames, build host command frames.
#include <gtest/gtest.h>

#include <vector>

#include "rig_drivers/firmware/firmware.hpp"
#include "rig_drivers/protocol/codec.hpp"

namespace rig_test {

namespace rp = rig_drivers::protocol;

/// Decodes everything the board writes.
class CaptureOut : public rp::SerialOut {
 public:
  void write(const uint8_t* data, size_t n) override {
    bytes_written += n;
    for (const auto& e : rp::feed(decoder_, data, n)) {
      EXPECT_EQ(e.error, rp::DecodeError::kNone) << rp::errorName(e.error);
      if (e.error == rp::DecodeError::kNone) frames.push_back(e.frame);
    }
  }
  std::vector<rp::Frame> frames;
  size_t bytes_written = 0;

  /// Acks for `seq`, in order.
  std::vector<rp::Ack> acksFor(uint32_t seq) const {
    std::vector<rp::Ack> out;
    for (const auto& f : frames) {
      rp::Ack a;
      if (rp::decodePayload(f, a) == rp::DecodeError::kNone && a.acked_seq == seq) out.push_back(a);
    }
    return out;
  }
  /// Last ack status for seq, or -1 if none.
  int lastStatus(uint32_t seq) const {
    const auto a = acksFor(seq);
    return a.empty() ? -1 : static_cast<int>(a.back().status);
  }
  template <class P>
  std::vector<P> all() const {
    std::vector<P> out;
    for (const auto& f : frames) {
      P p;
      if (rp::decodePayload(f, p) == rp::DecodeError::kNone) out.push_back(p);
    }
    return out;
  }

 private:
  rp::StreamDecoder decoder_;
};

inline int st(rp::AckStatus s) { return static_cast<int>(s); }

/// Sends a typed command to a board.
template <class P>
void sendTo(rp::FirmwareBoard& b, uint32_t seq, const P& p) {
  const auto bytes = rp::encodeMessage(b.board(), seq, p);
  b.receive(bytes.data(), bytes.size());
}
inline void sendCmd(rp::FirmwareBoard& b, uint32_t seq, rp::MsgId id) {
  const auto bytes = rp::encodeCommand(b.board(), id, seq);
  b.receive(bytes.data(), bytes.size());
}

}  // namespace rig_test
