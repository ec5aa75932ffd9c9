// TrackDRV on an Arduino Mega 2560 (ServoTrack track electronics: stepper driver, two proximity
// sensors, emergency stop), avr-libc only. All logic is rig_drivers::protocol::TrackDrv; this file
// is its hardware adapter and main loop. The host link is USART0 (the board's USB port).
//
// Pins (Arduino numbering): step A0, direction A1, driver enable 38 (active low), far sensor 3,
// near sensor 2, emergency stop 18 (sensors and stop active low, with pull-ups). Set them to the
// rig's wiring here and in nowhere else.
//
// RIG_EMULATED_INPUTS=1 builds the image for qemu-system-avr, which emulates no pins: the three
// inputs then come from a stub carriage that counts the board's own step pulses, starts
// kStubStartSteps from the far sensor, trips the far sensor at or below 0 and the near sensor at
// or beyond the track's length, and never presses the emergency stop. Everything else (the step
// pulses, the link, the clock) is the flashed code.
#include <util/delay.h>

#include "avr_io.hpp"
#include "board.hpp"
#include "rig_drivers/firmware/track_drv.hpp"

namespace rp = rig_drivers::protocol;

namespace {

const rig_avr::Pin kStep{&PINF, _BV(PF0)};    // A0
const rig_avr::Pin kDir{&PINF, _BV(PF1)};     // A1
const rig_avr::Pin kEnable{&PIND, _BV(PD7)};  // 38
const rig_avr::Pin kFar{&PINE, _BV(PE5)};     // 3
const rig_avr::Pin kNear{&PINE, _BV(PE4)};    // 2
const rig_avr::Pin kEStop{&PIND, _BV(PD3)};   // 18

#if RIG_EMULATED_INPUTS
constexpr int32_t kStubStartSteps = 1000;  // 18.6 mm from the far sensor with the 20-tooth pulley
#endif

class MegaTrackHardware : public rp::TrackHardware {
 public:
  explicit MegaTrackHardware(rig_avr::Uart& link) : link_(link) {}
  void begin(int32_t track_steps) {
    track_steps_ = track_steps;
    kStep.output();
    kDir.output();
    kEnable.output();
    kFar.inputPullup();
    kNear.inputPullup();
    kEStop.inputPullup();
    enableMotor(true);
  }
  void step(int dir) override {
    kDir.set(dir > 0);
    kStep.set(true);
    _delay_us(2);  // the driver's minimum pulse width
    kStep.set(false);
    stub_steps_ += dir;
  }
#if RIG_EMULATED_INPUTS
  bool farSensor() override { return stub_steps_ <= 0; }
  bool nearSensor() override { return stub_steps_ >= track_steps_; }
  bool estopPressed() override { return false; }
#else
  bool farSensor() override { return !kFar.high(); }
  bool nearSensor() override { return !kNear.high(); }
  bool estopPressed() override { return !kEStop.high(); }
#endif
  void enableMotor(bool on) override { kEnable.set(!on); }
  void write(const uint8_t* data, size_t n) override { link_.write(data, n); }

 private:
  rig_avr::Uart& link_;
  int32_t track_steps_ = 0;
#if RIG_EMULATED_INPUTS
  int32_t stub_steps_ = kStubStartSteps;
#else
  int32_t stub_steps_ = 0;  // unused on the rig
#endif
};

MegaTrackHardware g_hw(rig_avr::uart0());
rp::TrackDrv g_board(rp::TrackDrvConfig(), g_hw);  // 20-tooth pulley, 0.0186 mm/step

rig_avr::LoopPass g_loop;

}  // namespace

void boardSetup() {
  if (g_board.config().problems() != 0) rig_avr::halt(3);
  const rp::TrackDrvConfig& c = g_board.config();
  g_hw.begin(static_cast<int32_t>(c.track_length_m / c.metresPerStep() + 0.5));
  rig_avr::startLinkAndClock(rig_avr::uart0());
}

void boardLoop() { g_loop.run(g_board, rig_avr::uart0()); }
