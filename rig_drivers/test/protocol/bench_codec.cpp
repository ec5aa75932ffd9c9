// Codec throughput: encoding the 30 Hz streams and decoding clean and garbage-laden byte streams.
// One 115200 baud link carries 11.5 kB/s; the numbers show how much of a core that costs.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "rig_drivers/protocol/codec.hpp"

namespace rp = rig_drivers::protocol;

namespace {

std::vector<uint8_t> carStream(size_t frames, int garbage_per_frame) {
  std::mt19937 rng(1);
  std::vector<uint8_t> out;
  for (size_t i = 0; i < frames; ++i) {
    rp::CarSensorsPayload s;
    s.board_time_ms = static_cast<uint32_t>(i * 33);
    s.pitch_cdeg = static_cast<int16_t>(i % 4000);
    const auto f = rp::encodeMessage(rp::BoardId::kCar, static_cast<uint32_t>(i), s);
    out.insert(out.end(), f.begin(), f.end());
    for (int g = 0; g < garbage_per_frame; ++g) out.push_back(static_cast<uint8_t>(rng()));
  }
  return out;
}

class CountSink : public rp::FrameSink {
 public:
  void onFrame(const rp::Frame&) override { ++frames; }
  size_t frames = 0;
};

void BM_EncodeCarSensors(benchmark::State& state) {
  rp::CarSensorsPayload s;
  uint8_t buf[rp::kMaxFrameSize];
  uint32_t seq = 0;
  for (auto _ : state) {
    s.board_time_ms = seq;
    benchmark::DoNotOptimize(rp::encodeMessage(rp::BoardId::kCar, seq++, s, buf, sizeof buf));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_EncodeCarSensors);

void BM_DecodeStream(benchmark::State& state) {
  const auto bytes = carStream(1000, static_cast<int>(state.range(0)));
  size_t frames = 0;
  for (auto _ : state) {
    rp::StreamDecoder dec;
    CountSink sink;
    dec.feed(bytes.data(), bytes.size(), sink);
    frames += sink.frames;
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * bytes.size()));
  state.counters["frames_per_iter"] = static_cast<double>(frames) / state.iterations();
}
BENCHMARK(BM_DecodeStream)->Arg(0)->Arg(10)->Arg(100);

}  // namespace

BENCHMARK_MAIN();
