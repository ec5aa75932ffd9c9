#pragma once
// What a recorded run holds for evaluation (evaluate_bag): the bag opened with a message that says
// how to mend it when it cannot be read, its topics found by type (depth, camera_info, ground
// truth, the rigs' sensor streams, link timing, the static camera mount), and the non-image streams
// read into the core's plain types. The depth frames themselves are read one at a time by the
// caller.
#include <geometry_msgs/PoseStamped.h>
#include <rig_msgs/CarriageSensors.h>
#include <rig_msgs/LinkTiming.h>
#include <rig_msgs/TrackState.h>
#include <rig_msgs/TruckRc.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/tum_io.hpp"
#include "depth_track/ros/conversions.hpp"
#include "tum_bag.hpp"

namespace depth_track {
namespace bag_run {

/// The bag cannot be evaluated at all (unreadable, unindexed); the message says what to do.
class BagInputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Opens `path` for reading; an unreadable or unindexed bag throws BagInputError naming the cure.
inline std::unique_ptr<rosbag::Bag> openBag(const std::string& path) {
  if (!std::filesystem::exists(path)) throw BagInputError(path + ": no such file");
  auto bag = std::make_unique<rosbag::Bag>();
  try {
    bag->open(path, rosbag::bagmode::Read);
  } catch (const rosbag::BagUnindexedException&) {
    throw BagInputError(path +
                        ": the bag is not indexed (its recording did not finish: a crash, a "
                        "killed rosbag record, a .bag.active file). `rosbag reindex " +
                        path + "` mends it (the original is kept as .orig.bag); then run again");
  } catch (const rosbag::BagException& e) {
    throw BagInputError(path + ": cannot read the bag (" + e.what() +
                        "); if it was cut short, `rosbag reindex " + path +
                        "` recovers the complete chunks");
  }
  return bag;
}

/// Topics of one bag by role; empty = not in the bag.
struct Topics {
  std::string depth, info, ground_truth, track, car, truck, tf_static;
  std::vector<std::string> link_timing;
  std::map<std::string, std::string> types;   ///< every topic -> message type
  std::map<std::string, std::size_t> counts;  ///< messages per topic
};

inline std::string listOf(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& t : v) s += (s.empty() ? "" : ", ") + t;
  return s.empty() ? std::string("none") : s;
}

/// Finds the topics: the ones named (when non-empty), else the usual names, else the only topic
/// of the type. Throws BagInputError for a named topic that is missing or of another type, or
/// several candidates without a name.
inline Topics findTopics(rosbag::Bag& bag, const std::string& depth_topic,
                         const std::string& info_topic, const std::string& gt_topic) {
  Topics t;
  std::map<std::string, std::vector<std::string>> by_type;
  rosbag::View all(bag);
  for (const rosbag::ConnectionInfo* c : all.getConnections()) {
    if (!t.types.count(c->topic)) by_type[c->datatype].push_back(c->topic);
    t.types[c->topic] = c->datatype;
  }
  for (const auto& [topic, type] : t.types)
    t.counts[topic] = rosbag::View(bag, rosbag::TopicQuery(topic)).size();
  const auto pick = [&](const std::string& named, const std::string& type,
                        const std::vector<std::string>& usual, const std::string& option) {
    const auto& cands = by_type[type];
    if (!named.empty()) {
      if (!t.types.count(named))
        throw BagInputError(option + " " + named + " is not in the bag (" + type +
                            " topics: " + listOf(cands) + ")");
      if (t.types[named] != type)
        throw BagInputError(option + " " + named + " is a " + t.types[named] + ", not a " + type);
      return named;
    }
    for (const auto& u : usual)
      if (std::find(cands.begin(), cands.end(), u) != cands.end()) return u;
    if (cands.size() == 1) return cands.front();
    if (cands.size() > 1)
      throw BagInputError("several " + type + " topics (" + listOf(cands) + "): choose one with " +
                          option);
    return std::string();
  };
  t.depth = pick(depth_topic, "sensor_msgs/Image", {tum_bag::kDepthTopic}, "--depth-topic");
  const std::string sibling =
      t.depth.empty() ? "" : t.depth.substr(0, t.depth.find_last_of('/') + 1) + "camera_info";
  t.info =
      pick(info_topic, "sensor_msgs/CameraInfo", {sibling, tum_bag::kInfoTopic}, "--info-topic");
  t.ground_truth = pick(gt_topic, "geometry_msgs/PoseStamped",
                        {"/rig_sim/camera_pose", tum_bag::kGroundTruthTopic}, "--gt-topic");
  t.track = pick("", "rig_msgs/TrackState", {"/track_state"}, "");
  t.car = pick("", "rig_msgs/CarriageSensors", {"/carriage_sensors"}, "");
  t.truck = pick("", "rig_msgs/TruckRc", {"/truck_rc"}, "");
  t.link_timing = by_type["rig_msgs/LinkTiming"];
  if (t.types.count(tum_bag::kTfStaticTopic) &&
      t.types[tum_bag::kTfStaticTopic] == "tf2_msgs/TFMessage")
    t.tf_static = tum_bag::kTfStaticTopic;
  return t;
}

/// The non-image content of a run.
struct Streams {
  Trajectory ground_truth;
  RigSensorStreams sensors;
  std::vector<std::pair<std::string, std::vector<LinkClockSample>>> links;
  std::vector<std::string> clocks_missing;          ///< Time1..Time6 never recorded
  std::optional<Eigen::Isometry3d> T_base_optical;  ///< from /tf_static
  std::vector<std::string> problems;                ///< messages left out, and why
  /// /tf_static as child -> (parent, T_parent_child).
  std::map<std::string, std::pair<std::string, Eigen::Isometry3d>> static_tf;
};

namespace detail {

inline double stampOf(const std_msgs::Header& h, const rosbag::MessageInstance& m) {
  return h.stamp.isZero() ? m.getTime().toSec() : h.stamp.toSec();
}

/// Chain parent -> ... -> child through the static transforms (at most a few links).
inline std::optional<Eigen::Isometry3d> chain(
    const std::map<std::string, std::pair<std::string, Eigen::Isometry3d>>& parent_of,
    const std::string& parent, std::string child) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  for (int hops = 0; hops < 8 && child != parent; ++hops) {
    const auto it = parent_of.find(child);
    if (it == parent_of.end()) return std::nullopt;
    T = it->second.second * T;
    child = it->second.first;
  }
  if (child != parent) return std::nullopt;
  return T;
}

/// A stream in stamp order; a sample going back in time is left out (and counted).
template <class Sample>
void keepOrdered(std::vector<Sample>& s, const std::string& topic,
                 std::vector<std::string>& problems) {
  std::vector<Sample> out;
  std::size_t dropped = 0;
  for (const Sample& x : s) {
    if (!out.empty() && !(x.stamp_s > out.back().stamp_s)) {
      ++dropped;
      continue;
    }
    out.push_back(x);
  }
  if (dropped > 0)
    problems.push_back(topic + ": " + std::to_string(dropped) +
                       " messages whose stamp is not after the previous one left out");
  s = std::move(out);
}

}  // namespace detail

/// Reads ground truth, sensor streams, link clocks and the static camera mount (base_link ->
/// `optical_frame`).
inline Streams readStreams(rosbag::Bag& bag, const Topics& t, const std::string& optical_frame) {
  Streams out;
  std::vector<std::string> topics;
  for (const std::string& x : {t.ground_truth, t.track, t.car, t.truck, t.tf_static})
    if (!x.empty()) topics.push_back(x);
  for (const std::string& x : t.link_timing) topics.push_back(x);
  if (topics.empty()) return out;
  // Clock pairs (sender, receiver) of the thesis's network (4.2.2.1); -1 = not on this path.
  struct Pair {
    int from, to;
    const char* name;
  };
  const Pair pairs[] = {{1, 2, "TrackDRV -> TrackHost (Time1 -> Time2)"},
                        {3, 5, "CarDRV -> CarHost (Time3 -> Time5)"},
                        {2, 5, "TrackHost -> CarHost (Time2 -> Time5)"},
                        {5, 4, "CarHost -> CarCam (Time5 -> Time4)"},
                        {6, 4, "camera -> CarCam (Time6 -> Time4)"}};
  std::map<std::string, std::vector<LinkClockSample>> links;
  std::set<int> seen_clocks;
  std::vector<LinkClockSample> car_rx, truck_rx, track_rx;
  std::map<std::string, std::pair<std::string, Eigen::Isometry3d>> parent_of;
  std::size_t bad_gt = 0;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery(topics))) {
    const std::string& topic = m.getTopic();
    if (topic == t.ground_truth) {
      const auto p = m.instantiate<geometry_msgs::PoseStamped>();
      if (!p) continue;
      try {
        out.ground_truth.push_back({detail::stampOf(p->header, m), conv::fromPoseMsg(p->pose)});
      } catch (const std::exception&) {
        ++bad_gt;
      }
    } else if (topic == t.track) {
      const auto s = m.instantiate<rig_msgs::TrackState>();
      if (!s) continue;
      const double stamp = detail::stampOf(s->header, m);
      out.sensors.track.push_back({stamp, s->track_pos_m});
      track_rx.push_back({s->board_time_s, stamp});
    } else if (topic == t.car) {
      const auto s = m.instantiate<rig_msgs::CarriageSensors>();
      if (!s) continue;
      const double stamp = detail::stampOf(s->header, m);
      out.sensors.gimbal.push_back({stamp, s->pitch_deg, s->yaw_deg});
      car_rx.push_back({s->board_time_s, stamp});
    } else if (topic == t.truck) {
      const auto s = m.instantiate<rig_msgs::TruckRc>();
      if (!s) continue;
      const double stamp = detail::stampOf(s->header, m);
      out.sensors.truck.push_back({stamp, s->speed_mps, s->steering});
      truck_rx.push_back({s->board_time_s, stamp});
    } else if (topic == t.tf_static) {
      const auto tf = m.instantiate<tf2_msgs::TFMessage>();
      if (!tf) continue;
      for (const auto& x : tf->transforms) {
        try {
          parent_of[x.child_frame_id] = {x.header.frame_id, conv::fromTransformMsg(x.transform)};
        } catch (const std::exception&) {
        }
      }
    } else {  // link timing
      const auto l = m.instantiate<rig_msgs::LinkTiming>();
      if (!l) continue;
      const double c[7] = {0.0,        l->time1_s, l->time2_s, l->time3_s,
                           l->time4_s, l->time5_s, l->time6_s};
      for (int k = 1; k <= 6; ++k)
        if (c[k] >= 0.0) seen_clocks.insert(k);
      for (const Pair& p : pairs)
        if (c[p.from] >= 0.0 && c[p.to] >= 0.0) links[p.name].push_back({c[p.from], c[p.to]});
    }
  }
  if (bad_gt > 0)
    out.problems.push_back(t.ground_truth + ": " + std::to_string(bad_gt) +
                           " poses with non-finite values or a non-unit quaternion left out");
  for (const Pair& p : pairs)
    if (links.count(p.name)) out.links.emplace_back(p.name, links[p.name]);
  // Boards whose clock no LinkTiming carries: the state message's board clock against its
  // receive stamp is the same measurement.
  if (!seen_clocks.count(1) && !track_rx.empty())
    out.links.emplace_back("TrackDRV -> host (Time1 -> receive stamp)", track_rx);
  if (!seen_clocks.count(3) && !car_rx.empty())
    out.links.emplace_back("CarDRV -> host (Time3 -> receive stamp)", car_rx);
  if (!truck_rx.empty())
    out.links.emplace_back("TruckDRV -> host (board -> receive stamp)", truck_rx);
  if (!track_rx.empty()) seen_clocks.insert(1);
  if (!car_rx.empty()) seen_clocks.insert(3);
  for (int k = 1; k <= 6; ++k)
    if (!seen_clocks.count(k)) out.clocks_missing.push_back("Time" + std::to_string(k));
  std::sort(out.ground_truth.begin(), out.ground_truth.end(),
            [](const StampedPose& a, const StampedPose& b) { return a.stamp_s < b.stamp_s; });
  detail::keepOrdered(out.sensors.track, t.track, out.problems);
  detail::keepOrdered(out.sensors.gimbal, t.car, out.problems);
  detail::keepOrdered(out.sensors.truck, t.truck, out.problems);
  if (const auto T = detail::chain(parent_of, "base_link", optical_frame)) out.T_base_optical = *T;
  out.static_tf = std::move(parent_of);
  return out;
}

/// A camera IMU's readings (sensor_msgs/Imu with angular velocity and linear acceleration, as a
/// RealSense driver publishes them with unite_imu_method) in stamp order, and their frame id.
struct ImuStream {
  std::vector<ImuSample> samples;
  std::string frame_id;
  std::size_t left_out = 0;  ///< non-finite or going back in time
};

inline ImuStream readImu(rosbag::Bag& bag, const std::string& topic) {
  ImuStream out;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery(topic))) {
    const auto msg = m.instantiate<sensor_msgs::Imu>();
    if (!msg) continue;
    if (out.frame_id.empty()) out.frame_id = msg->header.frame_id;
    ImuSample s = conv::imuSampleFromMsg(*msg);
    s.stamp_s = detail::stampOf(msg->header, m);
    if (!std::isfinite(s.stamp_s) || !s.gyro_rad_s.allFinite() || !s.accel_m_s2.allFinite() ||
        (!out.samples.empty() && !(s.stamp_s > out.samples.back().stamp_s))) {
      ++out.left_out;
      continue;
    }
    out.samples.push_back(s);
  }
  return out;
}

}  // namespace bag_run
}  // namespace depth_track
