// avr-libc hardware layer of the rig boards: see avr_io.hpp.
#include "avr_io.hpp"

#include <avr/interrupt.h>
#include <util/delay.h>

namespace rig_avr {

// ---- clock --------------------------------------------------------------------------------------

namespace {
volatile uint32_t g_overflows = 0;  // Timer1 overflows since clockBegin (one per 32.768 ms)
uint32_t g_last_us = 0;             // last value micros() returned
}  // namespace

ISR(TIMER1_OVF_vect) { ++g_overflows; }

void clockBegin() {
  cli();
  TCCR1A = 0;
  TCCR1B = 0;
  TCNT1 = 0;
  TIFR1 = _BV(TOV1);
  TIMSK1 = _BV(TOIE1);
  TCCR1B = _BV(CS11);  // normal mode, F_CPU / 8
  sei();
}

uint32_t ticksInIsr() {
  // Interrupts are off: an overflow not counted yet shows as TOV1 with a small counter value.
  const uint16_t count = TCNT1;
  uint32_t overflows = g_overflows;
  if ((TIFR1 & _BV(TOV1)) && count < 0x8000) ++overflows;
  return (overflows << 16) | count;
}

uint32_t micros() {
  // Overflow count, counter, overflow count again, each with interrupts off (the 16-bit counter
  // read goes through a register the pulse-capture handlers share); a wrap in between shows as a
  // changed count once its interrupt has run between the reads, and the reading is repeated.
  const uint8_t sreg = SREG;
  uint32_t overflows, after;
  uint16_t count;
  do {
    cli();
    overflows = g_overflows;
    SREG = sreg;
    cli();
    count = TCNT1;
    SREG = sreg;
    cli();
    after = g_overflows;
    SREG = sreg;
  } while (overflows != after);
  // 65536 ticks of 0.5 us per overflow; the product wraps at 2^32 us as the result should.
  const uint32_t us = overflows * 32768UL + (count >> 1);
  // qemu-system-avr's timer can show the counter wrapped before it raises the overflow (its alarm
  // runs late on a loaded host): a reading that goes back is held at the last one. The board's
  // time never runs backwards; on the chip this never triggers.
  if (static_cast<int32_t>(us - g_last_us) < 0) return g_last_us;
  g_last_us = us;
  return us;
}

// ---- USART --------------------------------------------------------------------------------------

namespace {
// Bit positions, the same in every USART of both chips (the headers name them per USART).
constexpr uint8_t kU2x = 1, kUcsz0 = 1, kUcsz1 = 2, kTxEn = 3, kRxEn = 4, kUdrie = 5, kRxcie = 7;
}  // namespace

void Uart::begin(uint32_t baud) {
  // Double speed: UBRR = F_CPU / (8 baud) - 1, rounded (16 at 115200: 2.1 % fast, as the Arduino
  // core and the boards' USB-serial firmware use).
  *r_.ucsrb = 0;
  *r_.ucsra = _BV(kU2x);
  *r_.ubrr = static_cast<uint16_t>((F_CPU / 4 / baud - 1) / 2);
  *r_.ucsrc = _BV(kUcsz1) | _BV(kUcsz0);  // 8N1
  *r_.ucsrb = _BV(kRxEn) | _BV(kTxEn) | _BV(kRxcie);
}

size_t Uart::read(uint8_t* out, size_t max) {
  size_t n = 0;
  while (n < max && rx_tail_ != rx_head_) {
    out[n++] = rx_[rx_tail_];
    rx_tail_ = static_cast<uint8_t>((rx_tail_ + 1) & (kRxSize - 1));
  }
  return n;
}

void Uart::write(const uint8_t* data, size_t n) {
  for (size_t i = 0; i < n; ++i) {
    const uint8_t next = static_cast<uint8_t>((tx_head_ + 1) & (kTxSize - 1));
    while (next == tx_tail_) {
      // Ring full: wait for the transmitter (it drains at ~11.5 bytes/ms at 115200 baud).
    }
    tx_[tx_head_] = data[i];
    tx_head_ = next;
    *r_.ucsrb |= _BV(kUdrie);
  }
}

void Uart::onReceive() {
  const uint8_t b = *r_.udr;
  const uint8_t next = static_cast<uint8_t>((rx_head_ + 1) & (kRxSize - 1));
  if (next == rx_tail_) {
    ++overruns_;
    return;
  }
  rx_[rx_head_] = b;
  rx_head_ = next;
}

void Uart::onDataRegisterEmpty() {
  if (tx_head_ == tx_tail_) {
    *r_.ucsrb &= static_cast<uint8_t>(~_BV(kUdrie));
    return;
  }
  *r_.udr = tx_[tx_tail_];
  tx_tail_ = static_cast<uint8_t>((tx_tail_ + 1) & (kTxSize - 1));
}

namespace {
#if defined(__AVR_ATmega2560__)
Uart g_uart0({&UCSR0A, &UCSR0B, &UCSR0C, &UBRR0, &UDR0});
#endif
Uart g_uart1({&UCSR1A, &UCSR1B, &UCSR1C, &UBRR1, &UDR1});
}  // namespace

#if defined(__AVR_ATmega2560__)
Uart& uart0() { return g_uart0; }
ISR(USART0_RX_vect) { g_uart0.onReceive(); }
ISR(USART0_UDRE_vect) { g_uart0.onDataRegisterEmpty(); }
#endif
Uart& uart1() { return g_uart1; }
ISR(USART1_RX_vect) { g_uart1.onReceive(); }
ISR(USART1_UDRE_vect) { g_uart1.onDataRegisterEmpty(); }

// ---- ADC ----------------------------------------------------------------------------------------

uint16_t adcRead(uint8_t channel) {
  ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);  // 125 kHz ADC clock
#if defined(MUX5)
  if (channel & 0x08) {
    ADCSRB |= _BV(MUX5);
  } else {
    ADCSRB &= static_cast<uint8_t>(~_BV(MUX5));
  }
#endif
  ADMUX = _BV(REFS0) | (channel & 0x07);  // AVcc reference
  ADCSRA |= _BV(ADSC);
  while (ADCSRA & _BV(ADSC)) {
  }
  return ADC;
}

// ---- TWI (I2C) ----------------------------------------------------------------------------------

namespace {
constexpr uint16_t kTwiSpins = 4000;  // ~1 ms at 16 MHz: far longer than one byte at 400 kHz

bool twiWait() {
  for (uint16_t i = 0; i < kTwiSpins; ++i)
    if (TWCR & _BV(TWINT)) return true;
  return false;
}
bool twiStart() {
  TWCR = _BV(TWINT) | _BV(TWSTA) | _BV(TWEN);
  return twiWait() && ((TWSR & 0xF8) == 0x08 || (TWSR & 0xF8) == 0x10);
}
bool twiSend(uint8_t b, uint8_t ack_status) {
  TWDR = b;
  TWCR = _BV(TWINT) | _BV(TWEN);
  return twiWait() && (TWSR & 0xF8) == ack_status;
}
void twiStop() { TWCR = _BV(TWINT) | _BV(TWSTO) | _BV(TWEN); }
}  // namespace

void twiBegin() {
  TWSR = 0;
  TWBR = static_cast<uint8_t>((F_CPU / 400000UL - 16) / 2);
  TWCR = _BV(TWEN);
}

bool twiWrite(uint8_t address, uint8_t reg, const uint8_t* data, uint8_t n) {
  bool ok = twiStart() && twiSend(static_cast<uint8_t>(address << 1), 0x18) && twiSend(reg, 0x28);
  for (uint8_t i = 0; ok && i < n; ++i) ok = twiSend(data[i], 0x28);
  twiStop();
  return ok;
}

bool twiRead(uint8_t address, uint8_t reg, uint8_t* out, uint8_t n) {
  bool ok = twiStart() && twiSend(static_cast<uint8_t>(address << 1), 0x18) && twiSend(reg, 0x28) &&
            twiStart() && twiSend(static_cast<uint8_t>((address << 1) | 1), 0x40);
  for (uint8_t i = 0; ok && i < n; ++i) {
    const bool last = i + 1 == n;
    TWCR = _BV(TWINT) | _BV(TWEN) | (last ? 0 : _BV(TWEA));
    ok = twiWait() && (TWSR & 0xF8) == (last ? 0x58 : 0x50);
    if (ok) out[i] = TWDR;
  }
  twiStop();
  return ok;
}

// ---- halt ---------------------------------------------------------------------------------------

void halt(uint8_t blinks) {
  cli();
#if defined(__AVR_ATmega32U4__)
  const Pin led{&PINC, _BV(PC7)};
#else
  const Pin led{&PINB, _BV(PB7)};
#endif
  led.output();
  for (;;) {
    for (uint8_t i = 0; i < blinks; ++i) {
      led.set(true);
      _delay_ms(200);
      led.set(false);
      _delay_ms(200);
    }
    _delay_ms(1000);
  }
}

}  // namespace rig_avr

#if !defined(ARDUINO)
// Freestanding C++ runtime pieces the compiler refers to. Nothing is ever allocated (no heap), but
// classes with virtual destructors name the deleting operator.
extern "C" void __cxa_pure_virtual() { rig_avr::halt(5); }
void operator delete(void*) {}
void operator delete(void*, size_t) {}
#endif
