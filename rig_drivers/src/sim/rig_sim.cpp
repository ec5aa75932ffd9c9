#include "rig_drivers/sim/rig_sim.hpp"
#include "depth_track/core/angles.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <set>
#include <stdexcept>

#include "rig_drivers/firmware/car_drv.hpp"
#include "rig_drivers/firmware/track_drv.hpp"
#include "rig_drivers/firmware/truck_drv.hpp"

namespace rig_drivers {

using protocol::BoardId;
using protocol::Frame;
using protocol::MsgId;

namespace {

constexpr double kG = 9.80665;  // m/s^2
/// Sequence numbers of the simulator's own host (autopilot) start here, far above any external
/// host's counter, so their acks can be told apart.
constexpr uint32_t kAutopilotSeq = 0xF0000000u;

/// Collects what a board writes during one physics step.
class ByteSink : public protocol::SerialOut {
 public:
  void write(const uint8_t* data, std::size_t n) override { buf.insert(buf.end(), data, data + n); }
  std::vector<uint8_t> buf;
};

/// Cuts a byte stream into frames.
class FrameCutter : public protocol::FrameSink {
 public:
  std::vector<Frame> cut(const std::vector<uint8_t>& bytes) {
    frames_.clear();
    decoder_.feed(bytes.data(), bytes.size(), *this);
    return std::move(frames_);
  }
  void onFrame(const Frame& f) override { frames_.push_back(f); }

 private:
  protocol::StreamDecoder decoder_;
  std::vector<Frame> frames_;
};

/// One board's serial link: a delayed byte stream each way, cut into frames at the far end.
struct SimLink {
  SimLink(BoardId b, const protocol::LinkConfig& cfg, uint64_t seed)
      : board(b), up(cfg, seed), down(cfg, seed ^ 0x9E3779B97F4A7C15ull) {}
  BoardId board;
  protocol::LinkModel up;    ///< board -> host
  protocol::LinkModel down;  ///< host -> board
  FrameCutter up_cut;        ///< at the host end
  FrameCutter down_cut;      ///< at the board end (for the log)
  /// Board -> host chunks not yet fully received: (end offset in the stream, time written).
  std::deque<std::pair<std::size_t, double>> up_sent;
  std::size_t up_bytes_sent = 0;
  std::size_t up_bytes_received = 0;
};

/// TrackDRV's hardware: stepper pulses move the belt's drive side; sensors see the carriage.
class SimTrackHardware : public protocol::TrackHardware {
 public:
  SimTrackHardware(ByteSink& out, const double& carriage_m, double track_length_m)
      : out_(out), carriage_m_(carriage_m), length_m_(track_length_m) {}
  void write(const uint8_t* data, std::size_t n) override { out_.write(data, n); }
  void step(int dir) override { steps += dir; }
  bool farSensor() override { return carriage_m_ <= 0.0; }
  bool nearSensor() override { return carriage_m_ >= length_m_; }
  bool estopPressed() override { return false; }
  int64_t steps = 0;  ///< pulses since power-on (signed)

 private:
  ByteSink& out_;
  const double& carriage_m_;
  double length_m_;
};

/// CarDRV's hardware: pulses drive the servo models, the pots and the IMU see the true state.
class SimCarHardware : public protocol::CarHardware {
 public:
  SimCarHardware(ByteSink& out, const protocol::CarDrvConfig& board_cfg, const RigSimConfig& cfg,
                 uint64_t seed)
      : out_(out),
        board_(board_cfg),
        cfg_(cfg),
        adc_pitch_(cfg.adc, seed ^ 0x11),
        adc_yaw_(cfg.adc, seed ^ 0x22),
        imu_{protocol::NoisySensor(cfg.accel, seed ^ 0x33),
             protocol::NoisySensor(cfg.accel, seed ^ 0x44),
             protocol::NoisySensor(cfg.accel, seed ^ 0x55)},
        tof_(cfg.tof, seed ^ 0x66) {}
  void write(const uint8_t* data, std::size_t n) override { out_.write(data, n); }
  void setServoPulse(protocol::GimbalAxis axis, double pulse_us) override {
    const bool pitch = axis == protocol::GimbalAxis::kPitch;
    const protocol::AxisCalibration& cal = pitch ? board_.pitch : board_.yaw;
    // The angle the servo really goes to for this pulse differs from CarDRV's calibration.
    const double meant = cal.pulse_us_of_deg.inverse(pulse_us);
    (pitch ? pitch_target_deg : yaw_target_deg) =
        meant * (1.0 + cfg_.servo_gain_error) + cfg_.servo_offset_deg;
  }
  int readAdc(protocol::GimbalAxis axis) override {
    const bool pitch = axis == protocol::GimbalAxis::kPitch;
    const protocol::AxisCalibration& cal = pitch ? board_.pitch : board_.yaw;
    const double a = pitch ? pitch_deg : yaw_deg;
    const double g = pitch ? cfg_.pitch_sensor_gain_error : cfg_.yaw_sensor_gain_error;
    const double o = pitch ? cfg_.pitch_sensor_offset_deg : cfg_.yaw_sensor_offset_deg;
    // The pot's true voltage is the one CarDRV's curve maps to a * (1 + g) + o.
    const double volts = cal.deg_of_volts.inverse(a * (1.0 + g) + o);
    return (pitch ? adc_pitch_ : adc_yaw_).read(volts);
  }
  bool readImu(int16_t raw[3]) override {
    for (int i = 0; i < 3; ++i) {
      const double g = imu_[i].read(accel_C_g[i]);
      raw[i] =
          static_cast<int16_t>(std::clamp(std::lround(g * board_.imu_lsb_per_g), -32768l, 32767l));
    }
    return true;
  }
  bool readTof(uint16_t& range_mm) override {
    const double r = tof_.read(carriage_m);
    if (!(r > 0.0 && r < 60.0)) return false;
    range_mm = static_cast<uint16_t>(std::lround(r * 1e3));
    return true;
  }
  // Written by the simulator each step (true state), read through the sensor models.
  double pitch_deg = 0.0, yaw_deg = 0.0, carriage_m = 0.0;
  Eigen::Vector3d accel_C_g = Eigen::Vector3d(0, -1, 0);
  // Set by CarDRV's pulses: where the servos are going (true degrees).
  double pitch_target_deg = 0.0, yaw_target_deg = 0.0;

 private:
  ByteSink& out_;
  protocol::CarDrvConfig board_;
  const RigSimConfig& cfg_;
  protocol::AdcModel adc_pitch_, adc_yaw_;
  protocol::NoisySensor imu_[3];
  protocol::NoisySensor tof_;
};

/// TruckDRV's hardware: the RC receiver's pulses come from the scenario (the driver's sticks and
/// switches, with the receiver's pulse jitter); the motor and steering outputs drive the plant.
class SimTruckHardware : public protocol::TruckHardware {
 public:
  SimTruckHardware(ByteSink& out, const protocol::TruckDrvConfig& board_cfg,
                   const TruckScenario& run, uint64_t seed)
      : out_(out), board_(board_cfg), run_(run), rng_(seed) {}
  void write(const uint8_t* data, std::size_t n) override { out_.write(data, n); }
  uint16_t pulseUs(protocol::RcChannel ch) override {
    const TruckSegment* seg = segmentAt(t);
    double us = board_.center_us;
    switch (ch) {
      case protocol::RcChannel::kCh2:
        us += (seg ? seg->steering : 0.0) * board_.half_range_us;
        break;
      case protocol::RcChannel::kCh3:
        us += (seg ? seg->throttle : 0.0) * board_.half_range_us;
        break;
      case protocol::RcChannel::kCh5:  // start/stop switch: on for the whole run
      case protocol::RcChannel::kCh7:  // record switch: on for the whole run
        us += (seg ? 1.0 : -1.0) * board_.half_range_us;
        break;
    }
    us += rng_.uniform(-kJitterUs, kJitterUs);
    return static_cast<uint16_t>(std::lround(us));
  }
  void setMotor(double command) override { motor = command; }
  void setSteering(double command) override { steering = command; }
  /// Speed the motor drives towards for the current command: the speed curve of fig. 5.42 (the
  /// plant adds its calibration error, TruckModelConfig::speed_scale_error).
  double speedDemandMps() const {
    const double m = std::abs(motor);
    if (m < board_.speed_curve.xMin()) return 0.0;  // motor stiction
    return (motor < 0 ? -1.0 : 1.0) * board_.speed_curve(m);
  }
  double t = 0.0;         ///< simulation time, s
  double motor = 0.0;     ///< TruckDRV's motor command, -1..1
  double steering = 0.0;  ///< TruckDRV's steering command, -1 (left)..1 (right)

 private:
  static constexpr double kJitterUs = 2.0;  ///< RC receiver pulse jitter, +/- us
  const TruckSegment* segmentAt(double time_s) const {
    double t0 = 0.0;
    for (const TruckSegment& s : run_.segments) {
      if (time_s < t0 + s.duration_s) return &s;
      t0 += s.duration_s;
    }
    return nullptr;  // after the run: sticks centred, switches off
  }
  ByteSink& out_;
  protocol::TruckDrvConfig board_;
  TruckScenario run_;
  protocol::Rng rng_;
};

uint64_t mix(uint64_t seed, uint64_t k) {
  uint64_t z = seed + 0x9E3779B97F4A7C15ull * (k + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

void appendProblems(std::vector<std::string>& out, const std::string& prefix,
                    const std::string& problems) {
  if (!problems.empty()) out.push_back(prefix + ": " + problems);
}

}  // namespace

// ---- config
// ----------------------------------------------------------------------------------------

std::vector<std::string> RigSimConfig::validate() const {
  std::vector<std::string> p;
  if (!(physics_rate_hz >= 300.0 && physics_rate_hz <= 20000.0))
    p.push_back("physics_rate_hz: must lie in 300..20000 Hz");
  appendProblems(p, "belt", belt.validate());
  appendProblems(p, "pitch_servo", pitch_servo.validate());
  appendProblems(p, "yaw_servo", yaw_servo.validate());
  appendProblems(p, "adc", adc.validate());
  appendProblems(p, "accel", accel.validate());
  appendProblems(p, "tof", tof.validate());
  appendProblems(p, "track_link", track_link.validate());
  appendProblems(p, "car_link", car_link.validate());
  appendProblems(p, "truck_link", truck_link.validate());
  for (auto [name, v] : {std::pair<const char*, double>{"servo_gain_error", servo_gain_error},
                         {"pitch_sensor_gain_error", pitch_sensor_gain_error},
                         {"yaw_sensor_gain_error", yaw_sensor_gain_error}}) {
    if (!(std::abs(v) < 0.2)) p.push_back(std::string(name) + ": must lie in (-0.2, 0.2)");
  }
  for (auto [name, v] : {std::pair<const char*, double>{"servo_offset_deg", servo_offset_deg},
                         {"pitch_sensor_offset_deg", pitch_sensor_offset_deg},
                         {"yaw_sensor_offset_deg", yaw_sensor_offset_deg}}) {
    if (!(std::abs(v) < 5.0)) p.push_back(std::string(name) + ": must lie in (-5, 5) deg");
  }
  if (!(camera_phase_s >= 0.0 && camera_phase_s < 1.0))
    p.push_back("camera_phase_s: must lie in [0, 1) s");
  if (!(carriage_power_on_m >= 0.0 && carriage_power_on_m < 1.0))
    p.push_back("carriage_power_on_m: must lie in [0, 1) m");
  for (const auto& s : track_geometry.validate()) p.push_back("track_geometry." + s);
  for (const auto& s : truck.validate()) p.push_back("truck." + s);
  return p;
}

// ---- implementation
// ------------------------------------------------------------------------------

struct RigSimulator::Impl {
  Impl(const Scenario& sc, const RigSimConfig& cfg);

  // time
  const Scenario& sc;
  const RigSimConfig& cfg;
  double dt = 0.0;
  uint64_t step_index = 0;
  double t = 0.0;

  // links and logs
  std::vector<std::unique_ptr<SimLink>> links;
  std::vector<SimLinkFrame> host_bytes;  ///< for an external host
  std::vector<SimLinkFrame> log;
  std::vector<SimCameraFrame> camera;
  std::vector<std::string> events;
  std::set<uint32_t> own_seqs;  ///< autopilot commands (their acks stay inside)

  // ServoTrack
  ByteSink track_out, car_out, truck_out;
  double carriage_m = 0.0;  ///< true carriage position (the track sensors see this)
  std::unique_ptr<SimTrackHardware> track_hw;
  std::unique_ptr<protocol::TrackDrv> track;
  std::unique_ptr<protocol::BeltCarriageModel> belt;
  double m_per_step = 0.0;
  std::unique_ptr<SimCarHardware> car_hw;
  std::unique_ptr<protocol::CarDrv> car;
  std::unique_ptr<protocol::ServoModel> pitch_servo, yaw_servo;

  // ServoTruck
  std::unique_ptr<SimTruckHardware> truck_hw;
  std::unique_ptr<protocol::TruckDrv> truck_board;
  std::unique_ptr<TruckModel> truck;

  // scripted host / autopilot
  enum class Phase {
    kIdle,
    kInit,
    kMode,
    kToStart,
    kSettle,
    kRun,
    kStep,
    kSettleStep,
    kDone,
    kFailed
  };
  Phase phase = Phase::kIdle;
  uint32_t next_seq = 1;
  std::set<uint32_t> waiting;  ///< commands waiting for their Ack kDone
  double phase_t0 = 0.0;
  double motion_t0 = -1.0;  ///< start of the mode 1 motion / mode 2 sequence / truck run
  int frames = 0;           ///< camera frames taken
  int steps_done = 0;
  double next_servo_t = 0.0;
  bool external_started = false;  ///< the external host sent start to the track board

  SimLink* link(BoardId b) {
    for (auto& l : links)
      if (l->board == b) return l.get();
    return nullptr;
  }
  void sendCommand(BoardId b, const std::vector<uint8_t>& bytes, uint32_t seq, bool wait_done);
  uint32_t seq() { return (cfg.scripted_host ? 0u : kAutopilotSeq) + next_seq++; }
  void stepOnce();
  void deliverToBoards();
  void collectFromBoards();
  void physics();
  void host();
  double runTarget() const;
  void sendServoDemand();
  void takeFrame();
  void onAck(const protocol::Ack& ack);
  RigTruth truthNow() const;
  double servoDemand(ServoAxis axis, double t_run) const;
};

}  // namespace rig_drivers

// ---- (continued) ------------------------------------------------------------------------------
namespace rig_drivers {

RigSimulator::Impl::Impl(const Scenario& s, const RigSimConfig& c) : sc(s), cfg(c) {
  dt = 1.0 / cfg.physics_rate_hz;
  const uint64_t seed = sc.seed;
  if (sc.rig == RigKind::kServoTrack) {
    links.push_back(std::make_unique<SimLink>(BoardId::kTrack, cfg.track_link, mix(seed, 1)));
    links.push_back(std::make_unique<SimLink>(BoardId::kCar, cfg.car_link, mix(seed, 2)));
    protocol::TrackDrvConfig tc;
    track_hw = std::make_unique<SimTrackHardware>(track_out, carriage_m, tc.track_length_m);
    track = std::make_unique<protocol::TrackDrv>(tc, *track_hw);
    m_per_step = tc.metresPerStep();
    belt = std::make_unique<protocol::BeltCarriageModel>(cfg.belt);
    carriage_m = cfg.carriage_power_on_m;
    belt->reset(carriage_m);
    const protocol::CarDrvConfig cc = protocol::CarDrvConfig::defaults();
    car_hw = std::make_unique<SimCarHardware>(car_out, cc, cfg, mix(seed, 3));
    car = std::make_unique<protocol::CarDrv>(cc, *car_hw);
    pitch_servo = std::make_unique<protocol::ServoModel>(cfg.pitch_servo, mix(seed, 6));
    yaw_servo = std::make_unique<protocol::ServoModel>(cfg.yaw_servo, mix(seed, 7));
    pitch_servo->reset(0.0);
    yaw_servo->reset(0.0);
    car_hw->carriage_m = carriage_m;
  } else if (sc.rig == RigKind::kServoTruck) {
    links.push_back(std::make_unique<SimLink>(BoardId::kTruck, cfg.truck_link, mix(seed, 4)));
    TruckState start;
    start.x_m = sc.truck.start_x_m;
    start.y_m = sc.truck.start_y_m;
    start.heading_rad = sc.truck.start_heading_deg * depth_track::kDegToRad;
    truck = std::make_unique<TruckModel>(cfg.truck, start);
    const protocol::TruckDrvConfig tc = protocol::TruckDrvConfig::defaults();
    truck_hw = std::make_unique<SimTruckHardware>(truck_out, tc, sc.truck, mix(seed, 5));
    truck_board = std::make_unique<protocol::TruckDrv>(tc, *truck_hw);
  }
  phase = cfg.scripted_host ? Phase::kInit : Phase::kIdle;
}

void RigSimulator::Impl::sendCommand(BoardId b, const std::vector<uint8_t>& bytes, uint32_t s,
                                     bool wait_done) {
  SimLink* l = link(b);
  l->down.send(t, bytes);
  own_seqs.insert(s);
  if (wait_done) waiting.insert(s);
  if (!cfg.scripted_host) return;
  SimLinkFrame lf;
  lf.t_s = t;
  lf.sent_t_s = t;
  lf.board = b;
  lf.outgoing = true;
  lf.bytes = bytes;
  log.push_back(std::move(lf));
}

void RigSimulator::Impl::deliverToBoards() {
  for (auto& l : links) {
    const std::vector<uint8_t> bytes = l->down.receive(t);
    if (bytes.empty()) continue;
    if (l->board == BoardId::kTrack) track->receive(bytes.data(), bytes.size());
    if (l->board == BoardId::kCar) car->receive(bytes.data(), bytes.size());
    if (l->board == BoardId::kTruck) truck_board->receive(bytes.data(), bytes.size());
  }
}

void RigSimulator::Impl::collectFromBoards() {
  auto push = [this](BoardId b, ByteSink& out) {
    if (out.buf.empty()) return;
    SimLink* l = link(b);
    l->up.send(t, out.buf);
    l->up_sent.push_back({l->up_bytes_sent + out.buf.size(), t});
    l->up_bytes_sent += out.buf.size();
    out.buf.clear();
  };
  push(BoardId::kTrack, track_out);
  push(BoardId::kCar, car_out);
  push(BoardId::kTruck, truck_out);
  // Frames complete at the host end.
  for (auto& l : links) {
    const std::vector<uint8_t> bytes = l->up.receive(t);
    if (bytes.empty()) continue;
    std::size_t offset = l->up_bytes_received;
    l->up_bytes_received += bytes.size();
    for (const Frame& f : l->up_cut.cut(bytes)) {
      // Sent time of the chunk holding this frame's first byte (frames are written whole).
      while (!l->up_sent.empty() && l->up_sent.front().first <= offset) l->up_sent.pop_front();
      offset += protocol::kHeaderSize + f.length + protocol::kCrcSize;
      SimLinkFrame lf;
      lf.t_s = t;
      lf.sent_t_s = l->up_sent.empty() ? t : l->up_sent.front().second;
      lf.board = l->board;
      lf.bytes = protocol::frameBytes(f);
      bool own = false;
      if (f.id == MsgId::kAck) {
        protocol::Ack ack;
        if (protocol::decodePayload(f, ack) == protocol::DecodeError::kNone) {
          own = own_seqs.count(ack.acked_seq) > 0;
          if (own) onAck(ack);
        }
      }
      if (!cfg.scripted_host && !own) host_bytes.push_back(lf);
      if (cfg.scripted_host) log.push_back(std::move(lf));
    }
  }
}

void RigSimulator::Impl::onAck(const protocol::Ack& ack) {
  using protocol::AckStatus;
  if (ack.status == AckStatus::kAccepted) return;
  if (ack.status == AckStatus::kDone) {
    waiting.erase(ack.acked_seq);
    return;
  }
  // A streamed servo demand superseded by the next one (see sendServoDemand), or the run's move
  // ended by the stop after the last frame.
  if (ack.status == AckStatus::kAborted && (ack.acked_id == MsgId::kServo || phase == Phase::kDone))
    return;
  events.push_back(
      std::string("t=") + std::to_string(t) + " s: " + protocol::msgName(ack.acked_id) + " (seq " +
      std::to_string(ack.acked_seq) + ") answered " + protocol::ackStatusName(ack.status));
  waiting.erase(ack.acked_seq);
  if (cfg.scripted_host) phase = Phase::kFailed;
}

double RigSimulator::Impl::servoDemand(ServoAxis axis, double t_run) const {
  if (sc.track.servo_axis != axis || sc.track.mode != 1) return 0.0;
  return sc.track.amplitude_deg * std::sin(2.0 * M_PI * sc.track.frequency_hz * t_run);
}

RigTruth RigSimulator::Impl::truthNow() const {
  RigTruth r;
  r.t_s = t;
  if (sc.rig == RigKind::kServoTrack) {
    r.track_pos_m = belt->position();
    r.motor_pos_m = belt->motorPosition();
    r.pitch_deg = pitch_servo->angle();
    r.yaw_deg = yaw_servo->angle();
    r.pitch_dem_deg = car_hw->pitch_target_deg;
    r.yaw_dem_deg = car_hw->yaw_target_deg;
    r.T_W_C =
        depth_track::cameraPoseOnTrack(r.track_pos_m, r.pitch_deg * depth_track::kDegToRad,
                                       r.yaw_deg * depth_track::kDegToRad, cfg.track_geometry);
    r.T_W_B = r.T_W_C;
    r.T_W_B.linear() = r.T_W_C.linear() * depth_track::rotationBodyFromOptical().transpose();
    // Specific force in camera optical axes: carriage acceleration along the track minus gravity.
    Eigen::Vector3d dir = cfg.track_geometry.direction_W.normalized();
    const Eigen::Vector3d f_W = belt->acceleration() * dir + Eigen::Vector3d(0, 0, kG);
    r.accel_C_g = r.T_W_C.rotation().transpose() * f_W / kG;
  } else if (sc.rig == RigKind::kTripod) {
    // On the target's axis at its centre height, looking at its face (the scene's frame: face at
    // x = 0 facing -x, centre 1 m up); base_link is the camera body.
    r.T_W_C.linear() = depth_track::rotationBodyFromOptical();
    const double t_run = motion_t0 < 0.0 ? 0.0 : t - motion_t0 - cfg.camera_phase_s;
    r.T_W_C.translation() = Eigen::Vector3d(-sc.tripod.distanceAt(t_run), 0.0, 1.0);
    r.T_W_B = r.T_W_C;
    r.T_W_B.linear() = Eigen::Matrix3d::Identity();
    r.accel_C_g = r.T_W_C.rotation().transpose() * Eigen::Vector3d(0, 0, 1.0);
  } else {
    r.truck = truck->state();
    r.T_W_B = truck->T_W_B();
    r.T_W_C = truck->T_W_C();
  }
  return r;
}

void RigSimulator::Impl::takeFrame() {
  SimCameraFrame f;
  f.index = frames++;
  f.truth = truthNow();
  camera.push_back(f);
}

void RigSimulator::Impl::stepOnce() {
  ++step_index;
  t = static_cast<double>(step_index) * dt;
  const uint32_t now_us = static_cast<uint32_t>(static_cast<uint64_t>(std::llround(t * 1e6)));
  deliverToBoards();
  if (track) track->update(now_us);
  if (car) car->update(now_us);
  if (truck_board) truck_board->update(now_us);
  collectFromBoards();
  physics();
  host();
}

}  // namespace rig_drivers

namespace rig_drivers {

void RigSimulator::Impl::host() {
  using protocol::encodeCommand;
  using protocol::encodeMessage;
  const double frame_dt = 1.0 / sc.frame_rate_hz;
  const int total = sc.frameCount();

  if (sc.rig == RigKind::kTripod) {
    // No boards: the camera records from t = 0 until the last station's hold is over.
    if (motion_t0 < 0.0) motion_t0 = 0.0;
    const double next = motion_t0 + cfg.camera_phase_s + frames * frame_dt;
    if (t + 1e-12 >= next && frames < total) takeFrame();
    if (frames >= total) phase = Phase::kDone;
    return;
  }
  if (sc.rig == RigKind::kServoTruck) {
    // The RC transmitter drives the truck from t = 0; the camera records throughout.
    if (motion_t0 < 0.0) motion_t0 = 0.0;
    const double next = motion_t0 + cfg.camera_phase_s + frames * frame_dt;
    if (t + 1e-12 >= next && (!cfg.scripted_host || frames < total)) takeFrame();
    if (cfg.scripted_host && frames >= total) phase = Phase::kDone;
    return;
  }

  // ServoTrack, external host: the camera runs at 30 Hz; the autopilot runs mode 1 motion after
  // the host's start.
  if (!cfg.scripted_host) {
    const double next = cfg.camera_phase_s + frames * frame_dt;
    if (t + 1e-12 >= next) takeFrame();
    if (!cfg.autopilot || sc.track.mode != 1 || !external_started) return;
    if (phase == Phase::kIdle) {
      phase = Phase::kRun;
      motion_t0 = t;
      next_servo_t = t;
      const uint32_t s = seq();
      protocol::CmdTrackMove mv;
      mv.target_um = static_cast<int32_t>(std::lround(runTarget() * 1e6));
      mv.max_speed_mm_s = static_cast<uint16_t>(std::lround(sc.track.achieved_speed_mm_s));
      sendCommand(BoardId::kTrack, encodeMessage(BoardId::kTrack, s, mv), s, false);
    }
    if (phase == Phase::kRun) {
      sendServoDemand();
      if (t - motion_t0 >= sc.track.duration_s) {
        const uint32_t s = seq();
        sendCommand(BoardId::kTrack, encodeCommand(BoardId::kTrack, MsgId::kStop, s), s, false);
        phase = Phase::kDone;
      }
    }
    return;
  }

  // ServoTrack, scripted host: init, mode, (move to start), then the run.
  if (!waiting.empty()) return;
  switch (phase) {
    case Phase::kInit: {
      if (t < 0.05) return;  // boards booting
      const uint32_t s = seq();
      sendCommand(BoardId::kTrack, encodeCommand(BoardId::kTrack, MsgId::kInit, s), s, true);
      phase = Phase::kMode;
      return;
    }
    case Phase::kMode: {
      protocol::CmdMode m;
      m.mode = static_cast<uint8_t>(sc.track.mode);
      for (BoardId b : {BoardId::kTrack, BoardId::kCar}) {
        const uint32_t s = seq();
        sendCommand(b, encodeMessage(b, s, m), s, true);
      }
      phase = Phase::kToStart;
      return;
    }
    case Phase::kToStart: {
      if (sc.track.start_position_m > 0.0) {
        const uint32_t s = seq();
        protocol::CmdTrackMove mv;
        mv.target_um = static_cast<int32_t>(std::lround(sc.track.start_position_m * 1e6));
        sendCommand(BoardId::kTrack, encodeMessage(BoardId::kTrack, s, mv), s, true);
      }
      phase = Phase::kSettle;
      phase_t0 = -1.0;
      return;
    }
    case Phase::kSettle: {
      // Let the belt ring down before the run, then start.
      if (phase_t0 < 0.0) phase_t0 = t;
      if (t - phase_t0 < 0.5) return;
      const uint32_t s = seq();
      sendCommand(BoardId::kTrack, encodeCommand(BoardId::kTrack, MsgId::kStart, s), s, true);
      motion_t0 = -1.0;
      phase = sc.track.mode == 1 ? Phase::kRun : Phase::kStep;
      return;
    }
    case Phase::kRun: {
      if (motion_t0 < 0.0) {
        motion_t0 = t;
        next_servo_t = t;
        const uint32_t s = seq();
        protocol::CmdTrackMove mv;
        mv.target_um = static_cast<int32_t>(std::lround(runTarget() * 1e6));
        mv.max_speed_mm_s = static_cast<uint16_t>(std::lround(sc.track.achieved_speed_mm_s));
        sendCommand(BoardId::kTrack, encodeMessage(BoardId::kTrack, s, mv), s, false);
      }
      sendServoDemand();
      const double next = motion_t0 + cfg.camera_phase_s + frames * frame_dt;
      if (t + 1e-12 >= next && frames < total) takeFrame();
      if (frames >= total) {
        const uint32_t s = seq();
        sendCommand(BoardId::kTrack, encodeCommand(BoardId::kTrack, MsgId::kStop, s), s, false);
        phase = Phase::kDone;
      }
      return;
    }
    case Phase::kStep: {
      // Mode 2: still frames first (rig at rest), then one frame after each step has settled.
      if (motion_t0 < 0.0) motion_t0 = t;
      if (frames < sc.track.still_frames) {
        const double next = motion_t0 + cfg.camera_phase_s + frames * frame_dt;
        if (t + 1e-12 >= next) takeFrame();
        return;
      }
      if (steps_done > 0 && frames < sc.track.still_frames + steps_done) {
        takeFrame();  // the previous step and its settle wait are done
      }
      if (steps_done >= sc.track.steps) {
        phase = Phase::kDone;
        return;
      }
      const uint32_t s = seq();
      protocol::CmdTrackMove mv;
      mv.target_um = static_cast<int32_t>(std::lround(sc.track.step_mm * 1e3));
      mv.flags = protocol::CmdTrackMove::kRelative;
      mv.max_speed_mm_s = static_cast<uint16_t>(std::lround(sc.track.step_speed_mm_s));
      sendCommand(BoardId::kTrack, encodeMessage(BoardId::kTrack, s, mv), s, true);
      phase = Phase::kSettleStep;
      return;
    }
    case Phase::kSettleStep: {
      const uint32_t s = seq();
      protocol::CmdWait w;
      w.wait_ms = static_cast<uint32_t>(std::lround(sc.track.settle_s * 1e3));
      sendCommand(BoardId::kTrack, encodeMessage(BoardId::kTrack, s, w), s, true);
      ++steps_done;
      phase = Phase::kStep;
      return;
    }
    default:
      return;
  }
}

double RigSimulator::Impl::runTarget() const {
  // Far enough that the carriage is still cruising at the last frame, short of the near sensor.
  const double travel = sc.track.achieved_speed_mm_s * 1e-3 * (sc.track.duration_s + 0.5);
  return std::min(sc.track.start_position_m + travel, 1.2 - 0.01);
}

void RigSimulator::Impl::sendServoDemand() {
  if (sc.track.servo_axis == ServoAxis::kNone || t + 1e-12 < next_servo_t) return;
  next_servo_t += 1.0 / 30.0;  // CarHost sends demands at the 30 Hz frame rate
  const double tr = t - motion_t0;
  protocol::CmdServo cmd;
  cmd.pitch_cdeg = static_cast<int16_t>(std::lround(servoDemand(ServoAxis::kPitch, tr) * 100.0));
  cmd.yaw_cdeg = static_cast<int16_t>(std::lround(servoDemand(ServoAxis::kYaw, tr) * 100.0));
  // The car board is in mode 1 here: each demand replaces the one still settling (that one is
  // acked "aborted", see onAck).
  const uint32_t s = seq();
  sendCommand(BoardId::kCar, protocol::encodeMessage(BoardId::kCar, s, cmd), s, false);
}

}  // namespace rig_drivers

namespace rig_drivers {

void RigSimulator::Impl::physics() {
  if (sc.rig == RigKind::kServoTrack) {
    const double motor_m = cfg.carriage_power_on_m + track_hw->steps * m_per_step;
    belt->advance(dt, motor_m);
    carriage_m = belt->position();
    pitch_servo->advance(dt, car_hw->pitch_target_deg);
    yaw_servo->advance(dt, car_hw->yaw_target_deg);
    car_hw->pitch_deg = pitch_servo->angle();
    car_hw->yaw_deg = yaw_servo->angle();
    car_hw->carriage_m = carriage_m;
    car_hw->accel_C_g = truthNow().accel_C_g;
  } else if (sc.rig == RigKind::kServoTruck) {
    truck_hw->t = t;
    truck->step(dt, truck_hw->speedDemandMps(), truck_hw->steering);
  }
}

// ---- RigSimulator
// --------------------------------------------------------------------------------

RigSimulator::RigSimulator(const Scenario& scenario, const RigSimConfig& config)
    : scenario_(scenario), config_(config) {
  std::vector<std::string> problems = scenario_.validate();
  for (const auto& p : config_.validate()) problems.push_back("RigSimConfig." + p);
  if (!problems.empty()) {
    std::string msg = "rig simulator: scenario '" + scenario_.name + "':";
    for (const auto& p : problems) msg += " " + p + ";";
    throw std::invalid_argument(msg);
  }
  impl_ = std::make_unique<Impl>(scenario_, config_);
}

RigSimulator::~RigSimulator() = default;

std::vector<BoardId> RigSimulator::boards() const {
  std::vector<BoardId> out;
  for (const auto& l : impl_->links) out.push_back(l->board);
  return out;
}

void RigSimulator::hostSend(BoardId board, const uint8_t* data, std::size_t n) {
  SimLink* l = impl_->link(board);
  if (!l) throw std::invalid_argument("rig simulator: no such board on this rig");
  if (n == 0) return;
  l->down.send(impl_->t, data, n);
  // Watch for the external host's start of a mode 1 run (the autopilot's trigger).
  if (board == BoardId::kTrack) {
    for (const Frame& f : l->down_cut.cut(std::vector<uint8_t>(data, data + n)))
      if (f.id == MsgId::kStart) impl_->external_started = true;
  }
}

void RigSimulator::advanceTo(double t_s) {
  while ((static_cast<double>(impl_->step_index) + 1.0) * impl_->dt <= t_s + 1e-12)
    impl_->stepOnce();
}

bool RigSimulator::runToEnd(double t_max_s) {
  while (!finished() && impl_->t < t_max_s) impl_->stepOnce();
  return finished();
}

double RigSimulator::now() const { return impl_->t; }

template <typename T>
static std::vector<T> takeAll(std::vector<T>& v) {
  std::vector<T> out;
  out.swap(v);
  return out;
}

std::vector<SimLinkFrame> RigSimulator::takeHostBytes() { return takeAll(impl_->host_bytes); }
std::vector<SimLinkFrame> RigSimulator::takeLinkLog() { return takeAll(impl_->log); }
std::vector<SimCameraFrame> RigSimulator::takeCameraFrames() { return takeAll(impl_->camera); }
std::vector<std::string> RigSimulator::takeEvents() { return takeAll(impl_->events); }
RigTruth RigSimulator::truth() const { return impl_->truthNow(); }
int RigSimulator::framesTaken() const { return impl_->frames; }

bool RigSimulator::failed() const { return impl_->phase == Impl::Phase::kFailed; }

bool RigSimulator::finished() const {
  return impl_->phase == Impl::Phase::kDone || impl_->phase == Impl::Phase::kFailed;
}

}  // namespace rig_drivers
