// CarDRV: ServoTrack carriage (Arduino, Pololu Maestro servo controller on Serial1, pitch/yaw
// potentiometers, MPU6050 on I2C, time-of-flight ranger on I2C). Logic in rp::CarDrv.
#include <Wire.h>

#include "src/rig_drivers/firmware/car_drv.hpp"

namespace rp = rig_drivers::protocol;

constexpr int kPinPitchPot = A0;
constexpr int kPinYawPot = A1;
constexpr uint8_t kMaestroPitch = 0;  // Maestro channels
constexpr uint8_t kMaestroYaw = 1;
constexpr uint8_t kMpuAddress = 0x68;

class CarBoardHardware : public rp::CarHardware {
 public:
  void begin() {
    Serial1.begin(115200);  // Maestro in USB dual port / UART mode at 115200 baud (appendix B1)
    Wire.begin();
    Wire.beginTransmission(kMpuAddress);  // wake the MPU6050, +-2 g range (16384 LSB/g)
    Wire.write(0x6B);
    Wire.write(0);
    Wire.endTransmission();
  }
  void setServoPulse(rp::GimbalAxis axis, double pulse_us) override {
    // Maestro compact protocol "set target": 0x84, channel, target in quarter microseconds
    const uint16_t q = static_cast<uint16_t>(pulse_us * 4 + 0.5);
    Serial1.write(0x84);
    Serial1.write(axis == rp::GimbalAxis::kPitch ? kMaestroPitch : kMaestroYaw);
    Serial1.write(q & 0x7F);
    Serial1.write((q >> 7) & 0x7F);
  }
  int readAdc(rp::GimbalAxis axis) override {
    return analogRead(axis == rp::GimbalAxis::kPitch ? kPinPitchPot : kPinYawPot);
  }
  bool readImu(int16_t raw[3]) override {
    Wire.beginTransmission(kMpuAddress);
    Wire.write(0x3B);  // ACCEL_XOUT_H
    if (Wire.endTransmission(false) != 0) return false;
    if (Wire.requestFrom(kMpuAddress, static_cast<uint8_t>(6)) != 6) return false;
    int16_t a[3];
    for (int i = 0; i < 3; ++i) a[i] = static_cast<int16_t>((Wire.read() << 8) | Wire.read());
    // sensor axes -> camera axes (x lateral, y vertical, z longitudinal) for this mounting
    raw[0] = a[1];
    raw[1] = a[2];
    raw[2] = a[0];
    return true;
  }
  bool readTof(uint16_t& range_mm) override {
    // Placeholder for the laser ranger driver (VL53L0X-class): returns false until wired.
    range_mm = 0;
    return false;
  }
  void write(const uint8_t* data, size_t n) override { Serial.write(data, n); }
};

CarBoardHardware hw;
rp::CarDrv* board = nullptr;

void setup() {
  Serial.begin(rp::kBaudRate);
  hw.begin();
  static rp::CarDrv drv(rp::CarDrvConfig::defaults(), hw);  // put the rig's B2/B3 tables here
  board = &drv;
}

void loop() {
  uint8_t buf[32];
  int n = 0;
  while (n < static_cast<int>(sizeof buf) && Serial.available() > 0) buf[n++] = Serial.read();
  if (n > 0) board->receive(buf, n);
  board->update(micros());
}
