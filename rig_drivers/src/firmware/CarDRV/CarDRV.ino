// CarDRV for the Arduino IDE (Arduino Mega 2560): the avr-libc image's own adapter
// (src/avr/car_board.cpp: ADC, I2C, Maestro on USART1, Timer1 clock, USART0 link) under the Arduino
// core's main(). Copy the sources into this folder's src/ as ../README.md says.
#include "src/avr/board.hpp"

void setup() { boardSetup(); }

void loop() { boardLoop(); }
