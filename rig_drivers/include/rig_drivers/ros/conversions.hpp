#pragma once
// ROS adapters of the rig protocol: codec frames and payload structs -> rig_msgs messages. The one
// place these conversions live, used by the live board hosts (track_host, car_host, truck_host)
// and by the offline bag writer (make_scenario_bag), so bags and the live graph carry the same
// messages. ROS side only: the ROS-free rule covers every include/rig_drivers/ folder but ros/.
#include <ros/time.h>

#include <cstdint>
#include <string>
#include <vector>

#include "rig_drivers/protocol/codec.hpp"
#include "rig_msgs/CarriageSensors.h"
#include "rig_msgs/LinkTiming.h"
#include "rig_msgs/RawFrame.h"
#include "rig_msgs/TrackState.h"
#include "rig_msgs/TruckRc.h"

namespace rig_drivers {
namespace conv {

/// TrackDRV state payload as rig_msgs/TrackState (um -> m, ms -> s, flag bits -> bools).
inline rig_msgs::TrackState toMsg(const protocol::TrackStatePayload& p, std::uint32_t frame_seq,
                                  const ros::Time& stamp, const std::string& frame_id) {
  using P = protocol::TrackStatePayload;
  rig_msgs::TrackState m;
  m.header.stamp = stamp;
  m.header.frame_id = frame_id;
  m.track_pos_m = p.pos_um * 1e-6;
  m.track_steps = p.pos_steps;
  m.velocity_mps = p.vel_um_s * 1e-6;
  m.near_end_sensor = p.flags & P::kNearSensor;
  m.far_end_sensor = p.flags & P::kFarSensor;
  m.estop = p.flags & P::kEStopFlag;
  m.homed = p.flags & P::kHomed;
  m.state = static_cast<std::uint8_t>(p.state);
  m.mode = p.mode;
  m.board_time_s = p.board_time_ms * 1e-3;
  m.frame_seq = frame_seq;
  return m;
}

/// CarDRV sensor payload as rig_msgs/CarriageSensors (cdeg -> deg, mg -> g, mm -> m, ms -> s).
inline rig_msgs::CarriageSensors toMsg(const protocol::CarSensorsPayload& p,
                                       std::uint32_t frame_seq, const ros::Time& stamp,
                                       const std::string& frame_id) {
  rig_msgs::CarriageSensors m;
  m.header.stamp = stamp;
  m.header.frame_id = frame_id;
  m.pitch_dem_deg = p.pitch_dem_cdeg * 0.01f;
  m.pitch_deg = p.pitch_cdeg * 0.01f;
  m.yaw_dem_deg = p.yaw_dem_cdeg * 0.01f;
  m.yaw_deg = p.yaw_cdeg * 0.01f;
  m.acc_x_g = p.acc_x_mg * 1e-3f;
  m.acc_y_g = p.acc_y_mg * 1e-3f;
  m.acc_z_g = p.acc_z_mg * 1e-3f;
  m.tf_pos_m = p.tof_mm * 1e-3f;
  m.tf_valid = p.flags & protocol::CarSensorsPayload::kTofValid;
  m.board_time_s = p.board_time_ms * 1e-3;
  m.frame_seq = frame_seq;
  return m;
}

/// TruckDRV RC payload as rig_msgs/TruckRc (permille -> 1, mm/s -> m/s, flag bits -> bools).
inline rig_msgs::TruckRc toMsg(const protocol::TruckRcPayload& p, std::uint32_t frame_seq,
                               const ros::Time& stamp, const std::string& frame_id) {
  using P = protocol::TruckRcPayload;
  rig_msgs::TruckRc m;
  m.header.stamp = stamp;
  m.header.frame_id = frame_id;
  m.ch2_us = p.ch2_us;
  m.ch3_us = p.ch3_us;
  m.ch5_us = p.ch5_us;
  m.ch7_us = p.ch7_us;
  m.steering = p.steering_permille * 1e-3f;
  m.speed_signal = p.speed_permille * 1e-3f;
  m.speed_mps = p.speed_mm_s * 1e-3f;
  m.running = p.flags & P::kRunning;
  m.recording = p.flags & P::kRecording;
  m.signal_ok = p.flags & P::kSignalOk;
  m.board_time_s = p.board_time_ms * 1e-3;
  m.frame_seq = frame_seq;
  return m;
}

namespace detail {
template <class Payload, class Msg>
bool decodeTo(const protocol::Frame& f, const ros::Time& stamp, const std::string& frame_id,
              Msg& out) {
  Payload p;
  if (protocol::decodePayload(f, p) != protocol::DecodeError::kNone) return false;
  out = toMsg(p, f.seq, stamp, frame_id);
  return true;
}
}  // namespace detail

/// Decodes a TrackState frame into `out`; false (out untouched) for any other or a bad frame.
inline bool fromFrame(const protocol::Frame& f, const ros::Time& stamp, const std::string& frame_id,
                      rig_msgs::TrackState& out) {
  return detail::decodeTo<protocol::TrackStatePayload>(f, stamp, frame_id, out);
}
/// Decodes a CarSensors frame into `out`; false (out untouched) for any other or a bad frame.
inline bool fromFrame(const protocol::Frame& f, const ros::Time& stamp, const std::string& frame_id,
                      rig_msgs::CarriageSensors& out) {
  return detail::decodeTo<protocol::CarSensorsPayload>(f, stamp, frame_id, out);
}
/// Decodes a TruckRc frame into `out`; false (out untouched) for any other or a bad frame.
inline bool fromFrame(const protocol::Frame& f, const ros::Time& stamp, const std::string& frame_id,
                      rig_msgs::TruckRc& out) {
  return detail::decodeTo<protocol::TruckRcPayload>(f, stamp, frame_id, out);
}

namespace detail {
/// Link timing stamped `stamp` with every clock and the round trip unmeasured (-1).
inline rig_msgs::LinkTiming unmeasuredLinkTiming(const ros::Time& stamp) {
  rig_msgs::LinkTiming t;
  t.header.stamp = stamp;
  t.time1_s = t.time2_s = t.time3_s = t.time4_s = t.time5_s = t.time6_s = t.round_trip_s = -1.0;
  return t;
}
}  // namespace detail

/// Link timing of one track state: Time1 = TrackDRV clock, Time2 = host clock (s); the clocks
/// not measured on this path and the round trip are -1.
inline rig_msgs::LinkTiming trackLinkTiming(const rig_msgs::TrackState& s, double host_time_s) {
  rig_msgs::LinkTiming t = detail::unmeasuredLinkTiming(s.header.stamp);
  t.time1_s = s.board_time_s;
  t.time2_s = host_time_s;
  return t;
}

/// The carriage path's clocks (thesis 4.2.2.1): Time3 = CarDRV's board clock, Time5 = CarHost's
/// clock; the track path's clocks come from trackLinkTiming.
inline rig_msgs::LinkTiming carLinkTiming(const rig_msgs::CarriageSensors& s, double host_time_s) {
  rig_msgs::LinkTiming t = detail::unmeasuredLinkTiming(s.header.stamp);
  t.time3_s = s.board_time_s;
  t.time5_s = host_time_s;
  return t;
}

/// One wire frame as rig_msgs/RawFrame (`port`: device path, or "sim:<board>" offline).
inline rig_msgs::RawFrame rawFrameMsg(const ros::Time& stamp, const std::string& frame_id,
                                      const std::string& port, protocol::BoardId board,
                                      bool outgoing, const std::vector<std::uint8_t>& bytes) {
  rig_msgs::RawFrame raw;
  raw.header.stamp = stamp;
  raw.header.frame_id = frame_id;
  raw.port = port;
  raw.board = static_cast<std::uint8_t>(board);
  raw.outgoing = outgoing;
  raw.bytes = bytes;
  return raw;
}

}  // namespace conv
}  // namespace rig_drivers
