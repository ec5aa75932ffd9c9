// TruckDRV for the Arduino IDE (Arduino Leonardo): the avr-libc image's own adapter
// (src/avr/truck_board.cpp: receiver pulse capture, motor and steering outputs, Timer1 clock) with
// the host link on the Leonardo's USB port, which the Arduino core provides (the avr-libc image
// speaks on pins 0/1 instead). Copy the sources into this folder's src/ as ../README.md says.
#include <Arduino.h>

#include "src/avr/board.hpp"

// Replace the adapter's weak USART link with the core's USB serial.
void truckLinkBegin(uint32_t baud) { Serial.begin(baud); }
size_t truckLinkRead(uint8_t* out, size_t max) {
  size_t n = 0;
  while (n < max && Serial.available() > 0) out[n++] = static_cast<uint8_t>(Serial.read());
  return n;
}
void truckLinkWrite(const uint8_t* data, size_t n) { Serial.write(data, n); }

void setup() { boardSetup(); }

void loop() { boardLoop(); }
