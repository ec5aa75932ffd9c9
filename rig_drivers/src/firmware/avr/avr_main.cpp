// main() of the avr-libc images: the board adapter's setup, then its loop forever. Under the
// Arduino core (the .ino sketches) the core's main() calls setup() and loop() instead.
#include "board.hpp"

#if !defined(ARDUINO)
int main() {
  boardSetup();
  for (;;) boardLoop();
}
#endif
