// TruckDRV: ServoTruck co-processor (Arduino Leonardo): RC receiver CH2/CH3/CH5/CH7 in, motor
// amplifier and steering out. Logic in rp::TruckDrv.
#include <Servo.h>

#include "src/rig_drivers/firmware/truck_drv.hpp"

namespace rp = rig_drivers::protocol;

constexpr int kPinCh[4] = {2, 3, 7, 8};  // receiver CH2, CH3, CH5, CH7
constexpr int kPinMotorPwm = 9;
constexpr int kPinMotorDir = 10;
constexpr int kPinSteering = 11;

// Pulse widths measured by pin-change interrupts so loop() never blocks on pulseIn().
volatile uint32_t rise_us[4];
volatile uint16_t width_us[4];
volatile uint32_t seen_us[4];
template <int I>
void onEdge() {
  const uint32_t t = micros();
  if (digitalRead(kPinCh[I]) == HIGH) {
    rise_us[I] = t;
  } else {
    width_us[I] = static_cast<uint16_t>(t - rise_us[I]);
    seen_us[I] = t;
  }
}

class LeonardoTruckHardware : public rp::TruckHardware {
 public:
  void begin() {
    for (int i = 0; i < 4; ++i) pinMode(kPinCh[i], INPUT);
    attachInterrupt(digitalPinToInterrupt(kPinCh[0]), onEdge<0>, CHANGE);
    attachInterrupt(digitalPinToInterrupt(kPinCh[1]), onEdge<1>, CHANGE);
    attachInterrupt(digitalPinToInterrupt(kPinCh[2]), onEdge<2>, CHANGE);
    attachInterrupt(digitalPinToInterrupt(kPinCh[3]), onEdge<3>, CHANGE);
    pinMode(kPinMotorPwm, OUTPUT);
    pinMode(kPinMotorDir, OUTPUT);
    steering_.attach(kPinSteering);
  }
  uint16_t pulseUs(rp::RcChannel ch) override {
    const int i = static_cast<int>(ch);
    noInterrupts();
    const uint16_t w = width_us[i];
    const uint32_t seen = seen_us[i];
    interrupts();
    return (micros() - seen) > 100000UL ? 0 : w;  // no pulse for 100 ms: no signal
  }
  void setMotor(double c) override {
    digitalWrite(kPinMotorDir, c < 0 ? LOW : HIGH);
    analogWrite(kPinMotorPwm, static_cast<int>((c < 0 ? -c : c) * 255 + 0.5));
  }
  void setSteering(double c) override {
    steering_.writeMicroseconds(static_cast<int>(1500 + 500 * c));
  }
  void write(const uint8_t* data, size_t n) override { Serial.write(data, n); }

 private:
  Servo steering_;
};

LeonardoTruckHardware hw;
rp::TruckDrv* board = nullptr;

void setup() {
  Serial.begin(rp::kBaudRate);
  hw.begin();
  static rp::TruckDrv drv(rp::TruckDrvConfig::defaults(), hw);  // fig. 5.42 curve in defaults()
  board = &drv;
}

void loop() {
  uint8_t buf[32];
  int n = 0;
  while (n < static_cast<int>(sizeof buf) && Serial.available() > 0) buf[n++] = Serial.read();
  if (n > 0) board->receive(buf, n);
  board->update(micros());
}
