// evaluator: scores the tracking graph while a bag replays (launch/replay.launch eval:=true).
// Subscribes the graph's per-frame `status` (camera pose in odom), the bag's ground truth
// (~reference_topic, geometry_msgs/PoseStamped of the camera's optical frame) and the rig's own
// sensors (~track_state_topic + ~carriage_topic, or ~truck_topic), takes map -> odom from tf,
// associates by stamp (20 ms), and publishes the running errors against ground truth
// (`evaluator/errors`, rig_msgs/TrackingErrors) and the ground truth anchored at the first
// tracked pose beside the tracked path (`evaluator/gt_path`, `evaluator/path`, map frame). When
// the input stops (~end_timeout of wall time after the last frame) it saves the trajectory and
// the map through the graph's services, prints the core's evaluateRun table (formatRunEvaluation:
// the same function and so the same table as evaluate_bag on the same bag; ~table_path writes it
// to a file too) and a summary line, and exits. Parameters: see docs/graph.md.
#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Path.h>
#include <rig_msgs/CarriageSensors.h>
#include <rig_msgs/ReductionStats.h>
#include <rig_msgs/SaveFile.h>
#include <rig_msgs/TrackState.h>
#include <rig_msgs/TrackingErrors.h>
#include <rig_msgs/TrackingStatus.h>
#include <rig_msgs/TruckRc.h>
#include <ros/ros.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>

#include "depth_track/core/evaluation.hpp"
#include "depth_track/core/tum_io.hpp"
#include "depth_track/ros/conversions.hpp"

using namespace depth_track;

namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

class Evaluator {
 public:
  Evaluator() : pnh_("~"), tf_listener_(tf_buffer_) {
    pnh_.param<std::string>("reference_topic", reference_topic_, "/rig_sim/camera_pose");
    pnh_.param<std::string>("map_frame", map_frame_, "map");
    pnh_.param<std::string>("odom_frame", odom_frame_, "odom");
    pnh_.param("end_timeout", end_timeout_s_, 3.0);
    pnh_.param<std::string>("trajectory_path", trajectory_path_, "");
    pnh_.param<std::string>("map_path", map_path_, "");
    pnh_.param("exit_at_end", exit_at_end_, true);
    pnh_.param<std::string>("table_path", table_path_, "");
    pnh_.param("latency_scan", latency_scan_, 8);  // evaluate_bag's --latency-scan default
    pnh_.param<std::string>("base_frame", base_frame_, "base_link");
    pnh_.param<std::string>("optical_frame", optical_frame_, "camera_depth_optical_frame");
    std::string track_topic, car_topic, truck_topic;
    pnh_.param<std::string>("track_state_topic", track_topic, "/track_state");
    pnh_.param<std::string>("carriage_topic", car_topic, "/carriage_sensors");
    pnh_.param<std::string>("truck_topic", truck_topic, "/truck_rc");
    if (latency_scan_ < 0) throw std::invalid_argument("~latency_scan must be >= 0");
    errors_pub_ = nh_.advertise<rig_msgs::TrackingErrors>("evaluator/errors", 10);
    gt_path_pub_ = nh_.advertise<nav_msgs::Path>("evaluator/gt_path", 1, true);
    path_pub_ = nh_.advertise<nav_msgs::Path>("evaluator/path", 1, true);
    status_sub_ = nh_.subscribe("status", 200, &Evaluator::onStatus, this);
    stats_sub_ = nh_.subscribe("cells/stats", 200, &Evaluator::onStats, this);
    ref_sub_ = nh_.subscribe(reference_topic_, 200, &Evaluator::onReference, this);
    track_sub_ = nh_.subscribe(track_topic, 500, &Evaluator::onTrack, this);
    car_sub_ = nh_.subscribe(car_topic, 500, &Evaluator::onCarriage, this);
    truck_sub_ = nh_.subscribe(truck_topic, 500, &Evaluator::onTruck, this);
    timer_ = nh_.createWallTimer(ros::WallDuration(0.5), &Evaluator::onTimer, this);
    ROS_INFO("evaluator: %s against %s; final table %.0f s after the last frame",
             status_sub_.getTopic().c_str(), ref_sub_.getTopic().c_str(), end_timeout_s_);
  }

 private:
  void onReference(const geometry_msgs::PoseStampedConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    try {
      gt_[m->header.stamp.toSec()] = conv::fromPoseMsg(m->pose);
    } catch (const std::exception& e) {
      ROS_ERROR_THROTTLE(1.0, "evaluator: reference pose at %.3f ignored: %s",
                         m->header.stamp.toSec(), e.what());
    }
  }
  // The sensors keyed by stamp: evaluate_bag reads them in stamp order, a subscriber gets them
  // in arrival order; the first of equal stamps is kept, as evaluate_bag keeps it.
  static double stampOf(const std_msgs::Header& h) {
    return (h.stamp.isZero() ? ros::Time::now() : h.stamp).toSec();
  }
  void onTrack(const rig_msgs::TrackStateConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    track_.emplace(stampOf(m->header), TrackSensorSample{stampOf(m->header), m->track_pos_m});
  }
  void onCarriage(const rig_msgs::CarriageSensorsConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    gimbal_.emplace(stampOf(m->header),
                    GimbalSensorSample{stampOf(m->header), m->pitch_deg, m->yaw_deg});
  }
  void onTruck(const rig_msgs::TruckRcConstPtr& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    truck_.emplace(stampOf(m->header),
                   TruckRcSample{stampOf(m->header), m->speed_mps, m->steering});
  }
  void onStats(const rig_msgs::ReductionStatsConstPtr& s) {
    std::lock_guard<std::mutex> lock(mutex_);
    reduce_ms_[s->header.stamp.toSec()] = s->ms_reduce;
  }
  void onStatus(const rig_msgs::TrackingStatusConstPtr& s) {
    std::lock_guard<std::mutex> lock(mutex_);
    last_input_ = ros::WallTime::now();
    if (s->input_rejected) {
      ++rejected_;
      return;
    }
    const double t = s->header.stamp.toSec();
    if (!est_.empty() && t < est_.back().stamp_s) {  // a looped bag: start over
      ROS_WARN("evaluator: time jumped back; the evaluation starts over");
      est_.clear();
      gt_path_.poses.clear();
      path_.poses.clear();
      tracked_ = 0;
    }
    Eigen::Isometry3d T_map_odom = Eigen::Isometry3d::Identity();
    // No waiting: a timeout runs on the bag's clock, which stops when the bag ends. The
    // steady-rate correction may not reach this stamp yet; the latest one is then the same.
    try {
      const ros::Time at = tf_buffer_.canTransform(map_frame_, odom_frame_, s->header.stamp)
                               ? s->header.stamp
                               : ros::Time(0);
      T_map_odom =
          conv::fromTransformMsg(tf_buffer_.lookupTransform(map_frame_, odom_frame_, at).transform);
    } catch (const std::exception&) {
    }
    const Eigen::Isometry3d T_map_C = T_map_odom * conv::fromPoseMsg(s->camera_pose);
    est_.push_back({t, T_map_C});
    tracked_ += s->tracked;
    register_ms_.push_back(s->ms_register);
    latency_ms_.push_back(s->latency_ms);
    dropped_ = s->frames_dropped;
    publishRunning(*s);
  }

  /// Errors so far against the reference; the ground truth path anchored at the first pose.
  void publishRunning(const rig_msgs::TrackingStatus& s) {
    std::vector<double> gt_stamps;
    Trajectory gt;
    for (const auto& [t, T] : gt_) gt.push_back({t, T});
    const AssociatedTrajectories a =
        associateTrajectories(Trajectory(est_.begin(), est_.end()), gt);
    geometry_msgs::PoseStamped ps;
    ps.header.stamp = s.header.stamp;
    ps.header.frame_id = map_frame_;
    ps.pose = conv::toPoseMsg(est_.back().T_W_C);
    path_.header = ps.header;
    path_.poses.push_back(ps);
    path_pub_.publish(path_);
    if (a.est_T_W_C.size() < 2) return;
    const auto errs = frameErrors(a.est_T_W_C, a.gt_T_W_C);
    const ThesisErrors th = computeThesisErrors(a.est_T_W_C, a.gt_T_W_C);
    const AteRpe ate = computeAteRpe(a.est_T_W_C, a.gt_T_W_C);
    rig_msgs::TrackingErrors e;
    e.header = ps.header;
    e.reference = ref_sub_.getTopic();
    e.frames = a.est_T_W_C.size();
    e.ate_rmse_m = ate.ate_rmse_m;
    e.rpe_1f_m = ate.rpe_1f_m;
    for (int i = 0; i < 3; ++i) {
      e.err_deg[i] = errs.back().rot_err_deg(i);
      e.err_mm[i] = errs.back().pos_err_mm(i);
      e.max_err_deg[i] = th.max_err_deg(i);
      e.max_err_mm[i] = th.max_err_mm(i);
    }
    errors_pub_.publish(e);
    // Ground truth drawn in the map frame from the first tracked pose on.
    const Eigen::Isometry3d anchor = a.est_T_W_C.front() * a.gt_T_W_C.front().inverse();
    geometry_msgs::PoseStamped g;
    g.header.frame_id = map_frame_;
    g.header.stamp = ps.header.stamp;
    g.pose = conv::toPoseMsg(anchor * a.gt_T_W_C.back());
    gt_path_.header = g.header;
    gt_path_.poses.push_back(g);
    gt_path_pub_.publish(gt_path_);
  }

  void onTimer(const ros::WallTimerEvent&) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (done_ || est_.size() < 2 || (ros::WallTime::now() - last_input_).toSec() < end_timeout_s_)
      return;
    done_ = true;
    finish();
    if (exit_at_end_) ros::shutdown();
  }

  void finish() {
    std::string saved;
    auto save = [&saved](const char* service, const std::string& path, const char* what) {
      if (path.empty()) return;
      rig_msgs::SaveFile f;
      f.request.path = path;
      if (ros::service::call(service, f) && f.response.success)
        saved += std::string(" ") + what + "=" + f.response.path;
      else
        ROS_ERROR("evaluator: %s failed: %s", service, f.response.message.c_str());
    };
    save("registration/save_trajectory", trajectory_path_, "trajectory");
    save("fusion/save_map", map_path_, "map");
    Trajectory gt;
    for (const auto& [t, T] : gt_) gt.push_back({t, T});
    std::vector<double> frame_ms;
    for (std::size_t i = 0; i < est_.size(); ++i) {
      auto it = reduce_ms_.find(est_[i].stamp_s);
      frame_ms.push_back(register_ms_[i] + (it == reduce_ms_.end() ? 0.0 : it->second));
    }
    // Frames of the bag that never produced a status: gone somewhere in the graph.
    std::size_t missing = 0;
    if (!gt.empty()) {
      std::size_t in_range = 0;
      for (const auto& p : gt)
        in_range += p.stamp_s >= est_.front().stamp_s && p.stamp_s <= est_.back().stamp_s;
      missing = in_range > est_.size() ? in_range - est_.size() : 0;
    }
    std::printf("\n==== evaluator: %zu frames against %s ====\n", est_.size(),
                ref_sub_.getTopic().c_str());
    RunReferences refs;
    refs.ground_truth = gt;
    refs.ground_truth_name = ref_sub_.getTopic();
    for (const auto& [t, x] : track_) refs.sensors.track.push_back(x);
    for (const auto& [t, x] : gimbal_) refs.sensors.gimbal.push_back(x);
    for (const auto& [t, x] : truck_) refs.sensors.truck.push_back(x);
    if (refs.sensors.hasServoTruck()) {
      // evaluate_bag takes the mount from /tf_static; without one the camera looks ahead.
      refs.geometry.truck.T_B_C.linear() = rotationBodyFromOptical();
      try {
        refs.geometry.truck.T_B_C = conv::fromTransformMsg(
            tf_buffer_.lookupTransform(base_frame_, optical_frame_, ros::Time(0)).transform);
      } catch (const std::exception& e) {
        ROS_WARN("evaluator: no %s -> %s (%s): the truck reference assumes the camera at %s",
                 base_frame_.c_str(), optical_frame_.c_str(), e.what(), base_frame_.c_str());
      }
    }
    RunEvaluationOptions options;
    options.latency_scan = latency_scan_;
    std::string table, ate_part;
    try {
      const RunEvaluation run = evaluateRun(Trajectory(est_.begin(), est_.end()), refs, options);
      table = formatRunEvaluation(run);
      ate_part = " " + formatSummaryFields(run);
    } catch (const std::exception& e) {
      table = std::string("no evaluation: ") + e.what();
      ate_part = " ate_rmse_m=nan max_err_deg=nan,nan,nan max_err_mm=nan,nan,nan";
    }
    std::printf("%s\n", table.c_str());
    if (!table_path_.empty()) {
      std::ofstream f(table_path_);
      f << table << "\n" << ate_part.substr(1) << "\n";
      if (!f) ROS_ERROR("evaluator: cannot write ~table_path %s", table_path_.c_str());
    }
    std::printf(
        "summary: frames=%zu tracked=%d dropped=%zu rejected=%d%s ms_per_frame=%.2f "
        "latency_ms=%.1f%s\n",
        est_.size(), tracked_, static_cast<std::size_t>(dropped_) + missing, rejected_,
        ate_part.c_str(), median(frame_ms), median(latency_ms_), saved.c_str());
    std::fflush(stdout);
  }

  ros::NodeHandle nh_, pnh_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  std::string reference_topic_, map_frame_, odom_frame_, trajectory_path_, map_path_, table_path_;
  std::string base_frame_, optical_frame_;
  int latency_scan_ = 8;
  std::map<double, TrackSensorSample> track_;
  std::map<double, GimbalSensorSample> gimbal_;
  std::map<double, TruckRcSample> truck_;
  double end_timeout_s_ = 3.0;
  bool exit_at_end_ = true, done_ = false;
  std::mutex mutex_;
  std::map<double, Eigen::Isometry3d> gt_;
  std::map<double, double> reduce_ms_;
  std::vector<StampedPose> est_;
  std::vector<double> register_ms_, latency_ms_;
  int tracked_ = 0, rejected_ = 0;
  std::uint32_t dropped_ = 0;
  ros::WallTime last_input_;
  nav_msgs::Path path_, gt_path_;
  ros::Publisher errors_pub_, gt_path_pub_, path_pub_;
  ros::Subscriber status_sub_, stats_sub_, ref_sub_, track_sub_, car_sub_, truck_sub_;
  ros::WallTimer timer_;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "evaluator");
  try {
    Evaluator e;
    ros::AsyncSpinner spinner(2);
    spinner.start();
    ros::waitForShutdown();
  } catch (const std::exception& e) {
    ROS_FATAL("evaluator: %s", e.what());
    return 1;
  }
  return 0;
}
