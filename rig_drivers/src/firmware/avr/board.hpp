#pragma once
// Entry points of a board adapter (track_board.cpp, car_board.cpp, truck_board.cpp). The
// avr-libc images call them from their own main(); the Arduino IDE sketches (TrackDRV.ino, ...)
// from setup() and loop(), under the Arduino core's main().

/// Checks the board's config (halts blinking the LED when it has a problem), then starts the
/// hardware, the host link and the board clock.
void boardSetup();
/// One pass of the main loop: received bytes to the board, then the board's update.
void boardLoop();
