// make_scenario_bag: runs one rig simulator scenario offline (no roscore, no wall clock) and writes
// it as a bag: rendered depth (16UC1, noise model of the scenario) + camera_info at the camera's
// exposures, every rig board's state stream and raw frames as the host received them, the exact
// camera pose, and tf. Deterministic: the scenario's seed fixes every random draw.
//
//   make_scenario_bag --scenario config/scenarios/RT1.yaml --out-dir bags/generated
//                     [--compression lz4|bz2|none] [--max-frames N] [--threads N]
//                     [--noise-model FILE]   (a camera_check report instead of the preset)
//
// Topics (stamps = simulated time from a fixed epoch, monotonic per topic):
//   /camera/image_rect            sensor_msgs/Image 16UC1, frame camera_depth_optical_frame; the
//                                 connection header's depth_scale_m is the unit (L515 0.00025 m)
//   /camera/camera_info           sensor_msgs/CameraInfo (same depth_scale_m)
//   /rig_sim/camera_pose          geometry_msgs/PoseStamped, ground truth T_map_camera (optical)
//   /tf                           map -> camera_gt (ground truth, optical frame) per exposure
//   /tf_static                    base_link -> camera_link -> camera_depth_optical_frame (latched)
//   /track_state /link_timing      (ServoTrack, TrackDRV)   the topics of the live graph
//   /carriage_sensors              (ServoTrack, CarDRV)      (launch/servotrack.launch,
//   /truck_rc                      (ServoTruck, TruckDRV)    servotruck.launch)
//   /raw_frames                    rig_msgs/RawFrame of every board, both directions
//   /camera/imu                    with --imu: sensor_msgs/Imu at 200 Hz, frame
//                                  camera_imu_optical_frame (a D435i's with unite_imu_method:
//                                  gyro and accelerometer in one message), simulated along the
//                                  camera's true poses interpolated between exposures; its
//                                  mount on /tf_static
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Imu.h>
#include <tf2_msgs/TFMessage.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <optional>

#include "depth_track/core/se3.hpp"
#include "depth_track/core/sim/imu.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/sim/scene.hpp"
#include "rig_drivers/ros/conversions.hpp"
#include "rig_drivers/ros/sim_conversions.hpp"
#include "rig_drivers/sim/rig_sim.hpp"

using namespace rig_drivers;
namespace dsim = depth_track::sim;

namespace {

/// Bags start at a fixed epoch so that two runs give identical files.
const ros::Time kEpoch(1700000000, 0);
const char* kOpticalFrame = "camera_depth_optical_frame";
const char* kImuFrame = "camera_imu_optical_frame";

/// The IMU's mount in the depth optical frame: a few millimetres off the optical centre, axes
/// aligned, as on a D435i (T_C_I).
Eigen::Isometry3d imuMount() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(-0.006, 0.005, 0.012);
  return T;
}

ros::Time stamp(double t_s) { return kEpoch + ros::Duration(t_s); }

/// Writes one decoded board frame (state streams) and the raw frame itself.
class RigTopics {
 public:
  RigTopics(rosbag::Bag& bag) : bag_(bag) {}

  void write(const SimLinkFrame& lf) {
    const ros::Time t = stamp(lf.t_s);
    const char* ns = lf.board == protocol::BoardId::kTrack ? "/track"
                     : lf.board == protocol::BoardId::kCar ? "/car"
                                                           : "/truck";
    rig_msgs::RawFrame raw =
        conv::rawFrameMsg(t, "", std::string("sim:") + (ns + 1), lf.board, lf.outgoing, lf.bytes);
    raw.header.seq = raw_seq_++;
    bag_.write("/raw_frames", t, raw);
    if (lf.outgoing) return;
    protocol::StreamDecoder dec;
    const auto events = protocol::feed(dec, lf.bytes);
    for (const auto& ev : events) {
      if (ev.error != protocol::DecodeError::kNone) continue;
      writeState(ev.frame, t);
    }
  }

  int stateMessages() const { return states_; }

 private:
  void writeState(const protocol::Frame& f, const ros::Time& t) {
    rig_msgs::TrackState track;
    rig_msgs::CarriageSensors car;
    rig_msgs::TruckRc truck;
    if (conv::fromFrame(f, t, "base_link", track)) {
      bag_.write("/track_state", t, track);
      bag_.write("/link_timing", t, conv::trackLinkTiming(track, (t - kEpoch).toSec()));
    } else if (conv::fromFrame(f, t, "base_link", car)) {
      bag_.write("/carriage_sensors", t, car);
    } else if (conv::fromFrame(f, t, "base_link", truck)) {
      bag_.write("/truck_rc", t, truck);
    } else {
      return;  // acks, version and parameter replies: in /raw_frames only
    }
    ++states_;
  }

  rosbag::Bag& bag_;
  uint32_t raw_seq_ = 0;
  int states_ = 0;
};

dsim::Scene sceneByName(const std::string& name) {
  if (name == "chair_room") return dsim::chairRoomScene();
  if (name == "furnished_room") return dsim::furnishedRoomScene();
  if (name == "hall") return dsim::hallwayScene();
  if (name == "calibration_target") return dsim::calibrationTargetScene();
  throw std::invalid_argument("unknown scene '" + name + "'");
}

/// A connection header for topic `M` with extra fields. A custom header replaces rosbag's own, so
/// it carries the message's type fields too.
template <class M>
boost::shared_ptr<ros::M_string> connectionHeader(const std::map<std::string, std::string>& extra) {
  auto hdr = boost::make_shared<ros::M_string>();
  (*hdr)["type"] = ros::message_traits::DataType<M>::value();
  (*hdr)["md5sum"] = ros::message_traits::MD5Sum<M>::value();
  (*hdr)["message_definition"] = ros::message_traits::Definition<M>::value();
  (*hdr)["callerid"] = "/make_scenario_bag";
  for (const auto& [key, value] : extra) (*hdr)[key] = value;
  return hdr;
}

sensor_msgs::CameraInfo cameraInfo(const depth_track::PinholeIntrinsics& K) {
  sensor_msgs::CameraInfo ci;
  ci.header.frame_id = kOpticalFrame;
  ci.width = K.width;
  ci.height = K.height;
  ci.distortion_model = "plumb_bob";
  ci.D.assign(5, 0.0);
  ci.K = {K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1};
  ci.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  ci.P = {K.fx, 0, K.cx, 0, 0, K.fy, K.cy, 0, 0, 0, 1, 0};
  return ci;
}

int run(int argc, char** argv) {
  CLI::App app{"Writes one rig simulator scenario as a bag (offline, deterministic)."};
  std::string scenario_path, out_dir = ".", compression = "lz4", noise_model_path, imu_noise;
  int max_frames = 0, threads = 1;
  app.add_option("--scenario", scenario_path, "scenario YAML (config/scenarios/*.yaml)")
      ->required();
  app.add_option("--out-dir", out_dir, "output folder; the bag is <out-dir>/<name>.bag");
  app.add_option("--compression", compression, "none | lz4 | bz2");
  app.add_option("--max-frames", max_frames, "stop after this many camera frames (0 = all)");
  app.add_option("--threads", threads, "render threads (1 = serial; <= 0 = all cores)");
  app.add_option("--noise-model", noise_model_path,
                 "noise model YAML (camera_check's noise_model section) instead of the "
                 "scenario's noise preset: a run as a measured camera would record it");
  app.add_option("--imu", imu_noise,
                 "also write a camera IMU (/camera/imu, 200 Hz): bmi055 (a D435i's / D455's "
                 "noise and bias) | none (exact readings); default: no IMU");
  CLI11_PARSE(app, argc, argv);
  std::optional<dsim::ImuNoiseConfig> imu_config;
  if (!imu_noise.empty()) imu_config = dsim::ImuNoiseConfig::parse(imu_noise);
  if (compression != "none" && compression != "lz4" && compression != "bz2") {
    std::cerr << "make_scenario_bag: --compression must be none, lz4 or bz2 (got '" << compression
              << "')\n";
    return 2;
  }
  if (max_frames < 0) {
    std::cerr << "make_scenario_bag: --max-frames must be >= 0\n";
    return 2;
  }

  const auto t_start = std::chrono::steady_clock::now();
  const Scenario scenario = loadScenario(scenario_path);
  RigSimulator sim(scenario);
  const dsim::Scene scene = sceneByName(scenario.scene);
  const dsim::NoiseConfig noise =
      noise_model_path.empty() ? dsim::NoiseConfig::forModel(dsim::parseNoiseModel(scenario.noise))
                               : dsim::loadNoiseModelYaml(noise_model_path);
  // A measured model's own unit when it has one that still spans the depth range in 16 bits.
  const double depth_scale =
      noise.quantum_m >= 1e-4 ? noise.quantum_m : dsim::nativeDepthScale(noise.model);
  const depth_track::PinholeIntrinsics K = dsim::l515Intrinsics();
  const depth_track::DepthRange range;
  const int want_frames =
      max_frames > 0 ? std::min(max_frames, scenario.frameCount()) : scenario.frameCount();

  const std::string path = out_dir + "/" + scenario.name + ".bag";
  rosbag::Bag bag;
  bag.open(path, rosbag::bagmode::Write);
  if (compression == "lz4") bag.setCompression(rosbag::compression::LZ4);
  if (compression == "bz2") bag.setCompression(rosbag::compression::BZ2);

  // Static frames, latched like a live static_transform_publisher.
  {
    tf2_msgs::TFMessage st;
    st.transforms = conv::rigStaticTransforms(sim, kEpoch, kOpticalFrame);
    if (imu_config)
      st.transforms.push_back(conv::toTransformStamped(kEpoch, kOpticalFrame, kImuFrame, imuMount()));
    bag.write("/tf_static", kEpoch, st, connectionHeader<tf2_msgs::TFMessage>({{"latching", "1"}}));
  }

  // The depth unit travels with the images (connection field depth_scale_m, as tum_to_bag writes
  // it): L515 raw units are 0.25 mm, not the REP 118 millimetre a reader would otherwise assume.
  char unit[32];
  std::snprintf(unit, sizeof(unit), "%.10g", depth_scale);
  const auto image_hdr = connectionHeader<sensor_msgs::Image>({{"depth_scale_m", unit}});
  const auto info_hdr = connectionHeader<sensor_msgs::CameraInfo>({{"depth_scale_m", unit}});
  const sensor_msgs::CameraInfo info0 = cameraInfo(K);
  RigTopics rig(bag);
  int frames = 0, image_seq = 0;
  std::vector<double> truth_t;  // the exposures' true poses, for the IMU
  std::vector<Eigen::Isometry3d> truth_T;
  double render_ms = 0.0;
  const double slice_s = 0.02;
  const double t_limit = scenario.durationS() * 3.0 + 60.0;  // mode 2 timing is only estimated
  while (frames < want_frames) {
    if (sim.now() > t_limit) {
      std::cerr << "make_scenario_bag: " << scenario.name << " did not finish within " << t_limit
                << " s of simulated time (" << frames << "/" << want_frames << " frames)\n";
      for (const auto& e : sim.takeEvents()) std::cerr << "  " << e << "\n";
      bag.close();
      return 1;
    }
    sim.advanceTo(sim.now() + slice_s);
    for (const auto& e : sim.takeEvents()) std::cerr << scenario.name << ": " << e << "\n";
    // Link frames and camera exposures of this slice, written in time order.
    std::vector<SimLinkFrame> link = sim.takeLinkLog();
    std::vector<SimCameraFrame> cams = sim.takeCameraFrames();
    std::size_t li = 0;
    for (const SimCameraFrame& cf : cams) {
      while (li < link.size() && link[li].t_s <= cf.truth.t_s) rig.write(link[li++]);
      if (frames >= want_frames) break;
      const ros::Time t = stamp(cf.truth.t_s);
      const auto r0 = std::chrono::steady_clock::now();
      const depth_track::DepthImage clean =
          dsim::renderDepth(scene, K, cf.truth.T_W_C, range, threads);
      const depth_track::DepthImage noisy =
          dsim::applyNoise(clean, noise, dsim::frameSeed(scenario.seed, cf.index), range);
      const dsim::RawDepth16 raw = dsim::toRaw16(noisy, depth_scale);
      render_ms +=
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - r0).count();
      sensor_msgs::Image img;
      img.header.stamp = t;
      img.header.seq = image_seq;
      img.header.frame_id = kOpticalFrame;
      img.width = raw.width;
      img.height = raw.height;
      img.encoding = "16UC1";
      img.is_bigendian = 0;
      img.step = raw.width * 2;
      img.data.resize(raw.data.size() * 2);
      std::memcpy(img.data.data(), raw.data.data(), img.data.size());
      bag.write("/camera/image_rect", t, img, image_hdr);
      sensor_msgs::CameraInfo info = info0;
      info.header.stamp = t;
      info.header.seq = image_seq++;
      bag.write("/camera/camera_info", t, info, info_hdr);
      bag.write("/rig_sim/camera_pose", t, conv::toPoseStamped(t, "map", cf.truth.T_W_C));
      tf2_msgs::TFMessage tf;
      tf.transforms.push_back(conv::toTransformStamped(t, "map", "camera_gt", cf.truth.T_W_C));
      bag.write("/tf", t, tf);
      truth_t.push_back(cf.truth.t_s);
      truth_T.push_back(cf.truth.T_W_C);
      ++frames;
    }
    for (; li < link.size(); ++li) rig.write(link[li]);
  }
  int imu_messages = 0;
  if (imu_config && !truth_t.empty()) {
    // Between exposures the camera moves along the chord of its true poses (position linear,
    // rotation slerp); before the first it stands where the first exposure finds it. rosbag
    // indexes by stamp, so writing the readings after the frames replays them in time order.
    auto pose_at = [&](double t) {
      if (t <= truth_t.front()) return truth_T.front();
      if (t >= truth_t.back()) return truth_T.back();
      const std::size_t b = static_cast<std::size_t>(
          std::upper_bound(truth_t.begin(), truth_t.end(), t) - truth_t.begin());
      const double f = (t - truth_t[b - 1]) / (truth_t[b] - truth_t[b - 1]);
      return depth_track::interpolatePose(truth_T[b - 1], truth_T[b], f);
    };
    const double t0 = std::max(0.0, truth_t.front() - 0.5);
    const auto readings =
        dsim::simulateImu(pose_at, t0, truth_t.back(), imuMount(), *imu_config, scenario.seed);
    std::uint32_t seq = 0;
    for (const auto& r : readings) {
      sensor_msgs::Imu m;
      m.header.stamp = stamp(r.stamp_s);
      m.header.seq = seq++;
      m.header.frame_id = kImuFrame;
      m.orientation_covariance[0] = -1.0;  // no orientation, as the camera's driver
      m.angular_velocity.x = r.gyro_rad_s.x();
      m.angular_velocity.y = r.gyro_rad_s.y();
      m.angular_velocity.z = r.gyro_rad_s.z();
      m.linear_acceleration.x = r.accel_m_s2.x();
      m.linear_acceleration.y = r.accel_m_s2.y();
      m.linear_acceleration.z = r.accel_m_s2.z();
      bag.write("/camera/imu", m.header.stamp, m);
    }
    imu_messages = static_cast<int>(readings.size());
  }
  bag.close();
  const double total_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_start).count();
  std::printf(
      "make_scenario_bag: %s: %d frames, %d rig state messages, %d IMU readings, %.1f s "
      "simulated -> %s (%.0f ms total, render+noise %.1f ms/frame)\n",
      scenario.name.c_str(), frames, rig.stateMessages(), imu_messages, sim.now(), path.c_str(),
      total_ms,
      frames ? render_ms / frames : 0.0);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "make_scenario_bag: " << e.what() << "\n";
    return 1;
  }
}
