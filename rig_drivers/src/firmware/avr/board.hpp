#pragma once
// Entry points of a board adapter (track_board.cpp, car_board.cpp, truck_board.cpp), and the main
// loop pass they share. The avr-libc images call the entry points from avr_main.cpp; the Arduino
// IDE sketches (TrackDRV.ino, ...) from setup() and loop(), under the Arduino core's main().
#include <stddef.h>
#include <stdint.h>

#include "avr_io.hpp"
#include "rig_drivers/firmware/firmware.hpp"

/// Checks the board's config (halts blinking the LED when it has a problem), then starts the
/// hardware, the host link and the board clock.
void boardSetup();
/// One pass of the main loop (LoopPass with the board's link).
void boardLoop();

namespace rig_avr {

/// Opens the host link at the protocol's baud rate, then starts the board clock.
inline void startLinkAndClock(Uart& link) {
  link.begin(rig_drivers::protocol::kBaudRate);
  clockBegin();
}

/// Quiet time after which a frame still incomplete is given up. A host writes a frame in one go,
/// so on the wire its bytes follow each other within microseconds; the emulator hands them over
/// one at a time from a thread that a loaded machine can hold back for tens of milliseconds.
constexpr uint32_t kLineIdleUs = 200000;

/// The main loop's pass: received bytes to the board (a frame left incomplete while the line
/// stays quiet for kLineIdleUs is given up, so garbage that looks like a frame start cannot hold
/// a command back), then the board's update.
class LoopPass {
 public:
  /// The pass with the host link on a USART.
  void run(rig_drivers::protocol::FirmwareBoard& board, Uart& link) {
    run(
        board, [&link](uint8_t* buf, size_t max) { return link.read(buf, max); }, micros());
  }
  /// `read(buf, max)` returns the bytes received since the last call; `now_us` is micros().
  template <class ReadFn>
  void run(rig_drivers::protocol::FirmwareBoard& board, ReadFn read, uint32_t now_us) {
    uint8_t buf[32];
    const size_t n = read(buf, sizeof buf);
    if (n > 0) {
      board.receive(buf, n);
      last_rx_us_ = now_us;
    } else if (board.rxPending() > 0 && now_us - last_rx_us_ > kLineIdleUs) {
      board.lineIdle();
    }
    board.update(now_us);
  }

 private:
  uint32_t last_rx_us_ = 0;
};

}  // namespace rig_avr
