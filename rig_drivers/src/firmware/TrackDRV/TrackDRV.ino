// TrackDRV: ServoTrack track electronics (Arduino Mega, stepper driver, two proximity sensors,
// emergency stop). All logic is in rig_drivers::protocol::TrackDrv; this file is the pin adapter.
#include "src/rig_drivers/firmware/track_drv.hpp"

namespace rp = rig_drivers::protocol;

constexpr int kPinStep = 54;     // A0 as digital: step pulse to the driver
constexpr int kPinDir = 55;      // direction
constexpr int kPinEnable = 38;   // driver enable (active low)
constexpr int kPinFar = 3;       // far proximity sensor (homing reference), active low
constexpr int kPinNear = 2;      // near proximity sensor, active low
constexpr int kPinEstop = 18;    // emergency stop button, active low (normally closed loop)

class MegaTrackHardware : public rp::TrackHardware {
 public:
  void begin() {
    pinMode(kPinStep, OUTPUT);
    pinMode(kPinDir, OUTPUT);
    pinMode(kPinEnable, OUTPUT);
    pinMode(kPinFar, INPUT_PULLUP);
    pinMode(kPinNear, INPUT_PULLUP);
    pinMode(kPinEstop, INPUT_PULLUP);
    enableMotor(true);
  }
  void step(int dir) override {
    digitalWrite(kPinDir, dir > 0 ? HIGH : LOW);
    digitalWrite(kPinStep, HIGH);
    delayMicroseconds(2);  // driver minimum pulse width
    digitalWrite(kPinStep, LOW);
  }
  bool farSensor() override { return digitalRead(kPinFar) == LOW; }
  bool nearSensor() override { return digitalRead(kPinNear) == LOW; }
  bool estopPressed() override { return digitalRead(kPinEstop) == LOW; }
  void enableMotor(bool on) override { digitalWrite(kPinEnable, on ? LOW : HIGH); }
  void write(const uint8_t* data, size_t n) override { Serial.write(data, n); }
};

MegaTrackHardware hw;
rp::TrackDrv* board = nullptr;

void setup() {
  Serial.begin(rp::kBaudRate);
  hw.begin();
  static rp::TrackDrv drv(rp::TrackDrvConfig(), hw);  // 20-tooth pulley, 0.0186 mm/step
  board = &drv;
}

void loop() {
  uint8_t buf[32];
  int n = 0;
  while (n < static_cast<int>(sizeof buf) && Serial.available() > 0) buf[n++] = Serial.read();
  if (n > 0) board->receive(buf, n);
  board->update(micros());
}
