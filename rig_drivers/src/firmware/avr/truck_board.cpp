// TruckDRV on an Arduino Leonardo (ServoTruck co-processor: RC receiver CH2/CH3/CH5/CH7 in, motor
// amplifier and steering servo out), avr-libc only. All logic is rig_drivers::protocol::TruckDrv;
// this file is its hardware adapter and main loop.
//
// The host link is the Leonardo's hardware USART (pins 0 RX / 1 TX, Arduino's Serial1), reached
// through a 5 V USB-serial adapter: the chip's own USB port needs a USB device stack, which
// avr-libc does not have. The three truckLink* functions are weak: TruckDRV.ino, built with the
// Arduino IDE, replaces them with the Arduino core's USB serial and keeps everything else.
//
// Pins (Arduino numbering): receiver CH2 on 2 (INT1), CH3 on 3 (INT0), CH5 on 7 (INT6), CH7 on 8
// (pin change); motor PWM on 11 (Timer0, 976 Hz), motor direction on 10, steering servo on 5
// (Timer3, 50 Hz). Pulse widths are timed on the board clock (Timer1, 0.5 us).
//
// RIG_EMULATED_INPUTS=1 builds the logic for qemu-system-avr's Mega 2560 instead (no Leonardo is
// emulated): USART0 stands in for the USB link, the receiver is a stub with sticks centred and
// both switches off (kStubPulseUs), and the motor and steering commands are only kept.
#include <avr/interrupt.h>

#include "avr_io.hpp"
#include "board.hpp"
#include "rig_drivers/firmware/truck_drv.hpp"

#if !RIG_EMULATED_INPUTS && !defined(__AVR_ATmega32U4__)
#error "truck_board.cpp drives a Leonardo (ATmega32u4); other chips only with RIG_EMULATED_INPUTS"
#endif

namespace rp = rig_drivers::protocol;

void truckLinkBegin(uint32_t baud);
size_t truckLinkRead(uint8_t* out, size_t max);
void truckLinkWrite(const uint8_t* data, size_t n);

namespace {

#if RIG_EMULATED_INPUTS

constexpr uint16_t kStubPulseUs[4] = {1500, 1500, 1000, 1000};  // CH2, CH3, CH5, CH7
rig_avr::Uart& link() { return rig_avr::uart0(); }
void disableUsb() {}
void hardwareBegin() {}
uint16_t pulseWidthUs(int ch) { return kStubPulseUs[ch]; }
void writeMotor(double) {}
void writeSteering(double) {}

#else  // the Leonardo

rig_avr::Uart& link() { return rig_avr::uart1(); }

constexpr uint32_t kSignalLostTicks = 200000;  // no pulse for 100 ms: no signal
volatile uint32_t g_rise[4];
volatile uint16_t g_width_us[4];
volatile uint32_t g_seen[4];

inline void edge(uint8_t ch, bool high) {
  const uint32_t t = rig_avr::ticksInIsr();
  if (high) {
    g_rise[ch] = t;
  } else {
    g_width_us[ch] = static_cast<uint16_t>((t - g_rise[ch]) >> 1);
    g_seen[ch] = t;
  }
}

const rig_avr::Pin kMotorPwm{&PINB, _BV(PB7)};  // 11, OC0A
const rig_avr::Pin kMotorDir{&PINB, _BV(PB6)};  // 10
const rig_avr::Pin kSteering{&PINC, _BV(PC6)};  // 5, OC3A

void disableUsb() {
  // The bootloader may leave the USB controller running; its interrupts have no handler here.
  USBCON = 0;
  UDIEN = 0;
}

void hardwareBegin() {
  const rig_avr::Pin inputs[4] = {
      {&PIND, _BV(PD1)}, {&PIND, _BV(PD0)}, {&PINE, _BV(PE6)}, {&PINB, _BV(PB4)}};
  for (const auto& p : inputs) p.input();
  EICRA = _BV(ISC10) | _BV(ISC00);  // INT1 (CH2), INT0 (CH3): any edge
  EICRB = _BV(ISC60);               // INT6 (CH5): any edge
  EIMSK = _BV(INT1) | _BV(INT0) | _BV(INT6);
  PCMSK0 = _BV(PCINT4);  // CH7
  PCICR = _BV(PCIE0);
  kMotorPwm.output();
  kMotorDir.output();
  kSteering.output();
  TCCR0A = _BV(COM0A1) | _BV(WGM01) | _BV(WGM00);  // fast PWM on OC0A
  TCCR0B = _BV(CS01) | _BV(CS00);                  // F_CPU / 64 / 256 = 976 Hz
  OCR0A = 0;
  ICR3 = 39999;                                  // 20 ms at 0.5 us
  OCR3A = 3000;                                  // 1500 us: straight ahead
  TCCR3A = _BV(COM3A1) | _BV(WGM31);             // fast PWM, TOP = ICR3
  TCCR3B = _BV(WGM33) | _BV(WGM32) | _BV(CS31);  // F_CPU / 8
}

uint16_t pulseWidthUs(int ch) {
  cli();
  const uint16_t w = g_width_us[ch];
  const uint32_t age = rig_avr::ticksInIsr() - g_seen[ch];
  sei();
  return age > kSignalLostTicks ? 0 : w;
}

void writeMotor(double c) {
  kMotorDir.set(c >= 0);
  const double duty = (c < 0 ? -c : c) * 255 + 0.5;
  OCR0A = static_cast<uint8_t>(duty > 255 ? 255 : duty);
}

void writeSteering(double c) { OCR3A = static_cast<uint16_t>((1500 + 500 * c) * 2); }

#endif

}  // namespace

__attribute__((weak)) void truckLinkBegin(uint32_t baud) {
  disableUsb();
  link().begin(baud);
}
__attribute__((weak)) size_t truckLinkRead(uint8_t* out, size_t max) {
  return link().read(out, max);
}
__attribute__((weak)) void truckLinkWrite(const uint8_t* data, size_t n) { link().write(data, n); }

namespace {

class TruckBoardHardware : public rp::TruckHardware {
 public:
  uint16_t pulseUs(rp::RcChannel ch) override { return pulseWidthUs(static_cast<int>(ch)); }
  void setMotor(double command) override { writeMotor(command); }
  void setSteering(double command) override { writeSteering(command); }
  void write(const uint8_t* data, size_t n) override { truckLinkWrite(data, n); }
};

TruckBoardHardware g_hw;
rp::TruckDrv g_board(rp::TruckDrvConfig::defaults(), g_hw);  // fig. 5.42 curve in defaults()
rig_avr::LoopPass g_loop;

}  // namespace

#if !RIG_EMULATED_INPUTS
ISR(INT1_vect) { edge(0, PIND & _BV(PD1)); }
ISR(INT0_vect) { edge(1, PIND & _BV(PD0)); }
ISR(INT6_vect) { edge(2, PINE & _BV(PE6)); }
ISR(PCINT0_vect) { edge(3, PINB & _BV(PB4)); }
#endif

void boardSetup() {
  if (g_board.config().problems() != 0) rig_avr::halt(3);
  hardwareBegin();
  truckLinkBegin(rp::kBaudRate);
  rig_avr::clockBegin();
}

void boardLoop() {
  g_loop.run(
      g_board, [](uint8_t* buf, size_t max) { return truckLinkRead(buf, max); }, rig_avr::micros());
}
