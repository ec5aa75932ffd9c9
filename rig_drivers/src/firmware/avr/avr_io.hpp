#pragma once
// Hardware layer of the rig boards on AVR (Arduino Mega 2560: ATmega2560; Arduino Leonardo:
// ATmega32u4; both at 16 MHz), written against avr-libc alone so it builds with Debian's gcc-avr:
// the board clock on a 16-bit timer, interrupt-driven USARTs, digital pins, the ADC and a
// blocking I2C (TWI) master with timeouts. The board adapters (track_board.cpp, car_board.cpp,
// truck_board.cpp) build on it; nothing here knows the rig protocol.
//
// Resources taken: Timer1 (clock), the USARTs a board opens, the ADC and TWI when used. The
// interrupt handlers live in avr_io.cpp.

#include <avr/io.h>
#include <stddef.h>
#include <stdint.h>

namespace rig_avr {

/// Starts the board clock: Timer1 free-running at F_CPU / 8 (0.5 us per tick at 16 MHz), its
/// overflow interrupt extending the count. Enables interrupts.
void clockBegin();
/// Microseconds since clockBegin(), wrapping at 2^32 like Arduino's micros(). Any context.
uint32_t micros();
/// Clock ticks (0.5 us) since clockBegin(), wrapping at 2^32 (35.8 min). Interrupts must be off
/// (an interrupt handler, or inside cli/sei).
uint32_t ticksInIsr();

/// One USART with interrupt-driven ring buffers (receive and transmit), 8N1. write() returns as
/// soon as the bytes are queued and blocks only while the transmit ring is full.
class Uart {
 public:
  // Powers of two. 128 received bytes are 11 ms of the line at 115200 baud: the loop may stall
  // that long (e.g. writing para's frames into a full transmit ring) without losing a command.
  static constexpr uint8_t kRxSize = 128;
  static constexpr uint8_t kTxSize = 128;

  struct Registers {
    volatile uint8_t* ucsra;
    volatile uint8_t* ucsrb;
    volatile uint8_t* ucsrc;
    volatile uint16_t* ubrr;
    volatile uint8_t* udr;
  };
  explicit Uart(const Registers& r) : r_(r) {}

  /// Opens the port at `baud` (double speed, as the Arduino core does at 115200).
  void begin(uint32_t baud);
  /// Copies up to `max` received bytes into `out`; returns how many.
  size_t read(uint8_t* out, size_t max);
  /// Queues `n` bytes for transmission.
  void write(const uint8_t* data, size_t n);
  /// Receive bytes dropped because the ring was full (the loop fell behind).
  uint16_t overruns() const { return overruns_; }

  // Called from the USART's interrupt handlers only.
  void onReceive();
  void onDataRegisterEmpty();

 private:
  Registers r_;
  volatile uint8_t rx_[kRxSize] = {};
  volatile uint8_t rx_head_ = 0, rx_tail_ = 0;
  volatile uint8_t tx_[kTxSize] = {};
  volatile uint8_t tx_head_ = 0, tx_tail_ = 0;
  volatile uint16_t overruns_ = 0;
};

#if defined(__AVR_ATmega2560__)
Uart& uart0();  ///< Mega: pins 0/1, wired to the board's USB-serial chip
#endif
Uart& uart1();  ///< Mega: pins 19/18 (RX1/TX1); Leonardo: pins 0/1

/// A digital pin as its port's PINx register and bit mask (DDRx and PORTx follow PINx).
struct Pin {
  volatile uint8_t* pin_reg;
  uint8_t mask;
  void output() const { pin_reg[1] |= mask; }
  void inputPullup() const {
    pin_reg[1] &= static_cast<uint8_t>(~mask);
    pin_reg[2] |= mask;
  }
  void input() const {
    pin_reg[1] &= static_cast<uint8_t>(~mask);
    pin_reg[2] &= static_cast<uint8_t>(~mask);
  }
  void set(bool high) const {
    if (high) {
      pin_reg[2] |= mask;
    } else {
      pin_reg[2] &= static_cast<uint8_t>(~mask);
    }
  }
  bool high() const { return (*pin_reg & mask) != 0; }
};

/// One conversion of ADC channel `channel` (0..15 on the Mega) against AVcc; 0..1023.
uint16_t adcRead(uint8_t channel);

/// Blocking I2C master at 400 kHz; every wait is bounded, so a missing device reads as a failure
/// instead of hanging the board.
void twiBegin();
/// Writes `n` bytes to register `reg` of device `address` (7-bit); false on any NACK or timeout.
bool twiWrite(uint8_t address, uint8_t reg, const uint8_t* data, uint8_t n);
/// Reads `n` bytes from register `reg` of device `address`; false on any NACK or timeout.
bool twiRead(uint8_t address, uint8_t reg, uint8_t* out, uint8_t n);

/// Blinks the on-board LED (pin 13) forever: the board refuses to run (e.g. a bad config).
[[noreturn]] void halt(uint8_t blinks);

}  // namespace rig_avr
