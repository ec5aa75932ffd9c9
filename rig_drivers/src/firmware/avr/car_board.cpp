// CarDRV on an Arduino Mega 2560 (ServoTrack carriage: Pololu Maestro servo controller on USART1,
// pitch/yaw potentiometers on A0/A1, MPU6050 on I2C), avr-libc only. All logic is
// rig_drivers::protocol::CarDrv; this file is its hardware adapter and main loop. The host link is
// USART0 (the board's USB port).
//
// The time-of-flight ranger has no driver yet: readTof() reports no return, and the stream's TFPos
// stays invalid until one is written for the rig's sensor.
//
// RIG_EMULATED_INPUTS=1 builds the image for qemu-system-avr, which emulates neither the ADC nor
// I2C: both pots then read kStubAdcCounts (mid-rail, about 0 deg), the accelerometer 1 g straight
// down the camera's y axis, and the ranger kStubTofMm. The Maestro commands are only kept there:
// the emulated board restarts when its USART1 raises the transmit interrupt (qemu 7.2).
#include "avr_io.hpp"
#include "board.hpp"
#include "rig_drivers/firmware/car_drv.hpp"

namespace rp = rig_drivers::protocol;

namespace {

constexpr uint8_t kAdcPitch = 0;      // A0
constexpr uint8_t kAdcYaw = 1;        // A1
constexpr uint8_t kMaestroPitch = 0;  // Maestro channels
constexpr uint8_t kMaestroYaw = 1;
constexpr uint8_t kMpuAddress = 0x68;
constexpr uint32_t kMaestroBaud = 115200;  // Maestro in UART mode (appendix B1)
#if RIG_EMULATED_INPUTS
constexpr uint16_t kStubAdcCounts = 512;
constexpr uint16_t kStubTofMm = 500;
#endif

class MegaCarHardware : public rp::CarHardware {
 public:
  MegaCarHardware(rig_avr::Uart& link, rig_avr::Uart& maestro) : link_(link), maestro_(maestro) {}
  void begin() {
#if !RIG_EMULATED_INPUTS
    maestro_.begin(kMaestroBaud);
    rig_avr::twiBegin();
    const uint8_t wake = 0;  // PWR_MGMT_1 = 0: out of sleep, +-2 g range (16384 LSB/g)
    rig_avr::twiWrite(kMpuAddress, 0x6B, &wake, 1);
#endif
  }
  void setServoPulse(rp::GimbalAxis axis, double pulse_us) override {
    // Maestro compact protocol "set target": 0x84, channel, target in quarter microseconds.
    const uint16_t q = static_cast<uint16_t>(pulse_us * 4 + 0.5);
    const uint8_t cmd[4] = {0x84, axis == rp::GimbalAxis::kPitch ? kMaestroPitch : kMaestroYaw,
                            static_cast<uint8_t>(q & 0x7F), static_cast<uint8_t>((q >> 7) & 0x7F)};
#if RIG_EMULATED_INPUTS
    for (int i = 0; i < 4; ++i) last_maestro_[i] = cmd[i];
#else
    maestro_.write(cmd, sizeof cmd);
#endif
  }
#if RIG_EMULATED_INPUTS
  int readAdc(rp::GimbalAxis) override { return kStubAdcCounts; }
  bool readImu(int16_t raw[3]) override {
    raw[0] = 0;
    raw[1] = 16384;
    raw[2] = 0;
    return true;
  }
  bool readTof(uint16_t& range_mm) override {
    range_mm = kStubTofMm;
    return true;
  }
#else
  int readAdc(rp::GimbalAxis axis) override {
    return rig_avr::adcRead(axis == rp::GimbalAxis::kPitch ? kAdcPitch : kAdcYaw);
  }
  bool readImu(int16_t raw[3]) override {
    uint8_t b[6];
    if (!rig_avr::twiRead(kMpuAddress, 0x3B, b, sizeof b)) return false;  // ACCEL_XOUT_H ..
    int16_t a[3];
    for (int i = 0; i < 3; ++i) a[i] = static_cast<int16_t>((b[2 * i] << 8) | b[2 * i + 1]);
    // sensor axes -> camera axes (x lateral, y vertical, z longitudinal) for this mounting
    raw[0] = a[1];
    raw[1] = a[2];
    raw[2] = a[0];
    return true;
  }
  bool readTof(uint16_t& range_mm) override {
    range_mm = 0;
    return false;
  }
#endif
  void write(const uint8_t* data, size_t n) override { link_.write(data, n); }

 private:
  rig_avr::Uart& link_;
  rig_avr::Uart& maestro_;
#if RIG_EMULATED_INPUTS
  uint8_t last_maestro_[4] = {};
#endif
};

MegaCarHardware g_hw(rig_avr::uart0(), rig_avr::uart1());
rp::CarDrv g_board(rp::CarDrvConfig::defaults(), g_hw);  // put the rig's B2/B3 tables here

rig_avr::LoopPass g_loop;

}  // namespace

void boardSetup() {
  if (g_board.config().problems() != 0) rig_avr::halt(3);
  g_hw.begin();
  rig_avr::startLinkAndClock(rig_avr::uart0());
}

void boardLoop() { g_loop.run(g_board, rig_avr::uart0()); }
