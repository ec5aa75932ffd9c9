// depth_track/loop_closure: every cl_step-th tracked frame (depth/image + its `status`), registers
// the frame against the virtual depth ray-cast from the graph's map at the predicted pose (the
// core's LoopCloser and its gates) and, when accepted, updates the correction map -> odom, which
// goes out on tf at a steady rate (~tf_rate), not only when it changes. Publishes the gate's
// decision and reason on `loop_closure/status` and, while someone watches, the virtual depth at
// the corrected pose on `loop_closure/virtual_depth`. Needs the fusion nodelet's map (same
// manager); with loop_closure off it publishes the identity correction.
#include <geometry_msgs/TransformStamped.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <rig_msgs/LoopClosureStatus.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>
#include <pluginlib/class_list_macros.hpp>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/map/mapper_params.hpp"
#include "depth_track/ros/conversions.hpp"
#include "depth_track/ros/params.hpp"
#include "graph_common.hpp"
#include "graph_diagnostics.hpp"
#include "graph_reconfigure.hpp"

namespace depth_track {
namespace graph {

class LoopClosureNodelet : public nodelet::Nodelet {
 public:
  ~LoopClosureNodelet() override { input_.stop(); }

 private:
  using Frame = TrackedFrame;

  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    rosparams::ParamReader r(pnh, "loop_closure");
    mode_ = parseMode(r.getString("mode"));
    map_frame_ = r.getString("map_frame");
    odom_frame_ = r.getString("odom_frame");
    const double tf_rate = r.getDouble("tf_rate");
    const int sync_queue = r.getInt("sync_queue");
    FrameQueueOptions queue_options;
    queue_options.worker_nice = r.getInt("worker_nice");  // live mode only (FrameQueue)
    wait_timeout_s_ = r.getDouble("wait_timeout");
    config_ = readMapperTable(r, nh);
    r.finish();
    ctx_ = graphContext(nh.getNamespace());
    diag_.start(nh, pnh, getName(), readDiagnosticThresholds(nh),
                {config_.loop.enabled, config_.loop.enabled, config_.loop.enabled, false});
    diag_.add("loop closure",
              [this](diagnostic_updater::DiagnosticStatusWrapper& d) { loopTask(d); });
    if (config_.loop.enabled) {  // with loop closure off there is nothing to reconfigure
      reconf_.bindTable("loop_closure", "mapper", mapperParams(),
                        [](MapperConfig& c) -> MapperConfig& { return c; });
      reconf_.start(pnh, "loop_closure", config_, MapperConfig{}, [](const MapperConfig& c) {
        return c.validate(PinholeIntrinsics{640, 480, 500, 500, 319.5, 239.5});
      });
    }
    if (config_.loop.enabled) ctx_->map.attachLoopClosure();
    status_pub_ = nh.advertise<rig_msgs::LoopClosureStatus>("loop_closure/status", 20);
    image_transport::ImageTransport it(nh);
    virtual_pub_ = it.advertise("loop_closure/virtual_depth", 1);
    if (config_.loop.enabled)
      input_.start(
          nh, mode_, sync_queue, [this](const Frame& f) { process(f); }, queue_options);
    tf_timer_ = nh.createTimer(ros::Duration(1.0 / tf_rate), [this](const ros::TimerEvent&) {
      const ros::Time now = ros::Time::now();
      if (now <= last_tf_stamp_ && now + ros::Duration(1.0) > last_tf_stamp_) return;  // no news
      last_tf_stamp_ = now;
      geometry_msgs::TransformStamped t;
      t.header.stamp = now;
      t.header.frame_id = map_frame_;
      t.child_frame_id = odom_frame_;
      t.transform = conv::toTransformMsg(ctx_->map.latestCorrection());
      tf_pub_.sendTransform(t);
    });
    NODELET_INFO("loop_closure: %s, every %d frames, %s -> %s at %.0f Hz",
                 config_.loop.enabled ? "on" : "off", config_.loop.cl_step, map_frame_.c_str(),
                 odom_frame_.c_str(), tf_rate);
  }

  /// Attempts, the last gate decision and its reason, the correction map -> odom; WARN after
  /// diagnostics/loop_reject_warn rejected attempts in a row (drift goes uncorrected).
  void loopTask(diagnostic_updater::DiagnosticStatusWrapper& d) {
    const Eigen::Isometry3d X = ctx_->map.latestCorrection();
    std::lock_guard<std::mutex> lock(diag_mutex_);
    if (!config_.loop.enabled)
      d.summary(diagnostic_msgs::DiagnosticStatus::OK, "off (map -> odom stays identity)");
    else if (attempts_ == 0)
      d.summary(diagnostic_msgs::DiagnosticStatus::OK, "no attempt yet");
    else if (rejected_in_a_row_ >= diag_.thresholds().loop_reject_warn)
      d.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "%d attempts in a row rejected: %s",
                 rejected_in_a_row_, last_reason_.c_str());
    else
      d.summary(diagnostic_msgs::DiagnosticStatus::OK,
                (last_accepted_ ? "accepted: " : "rejected: ") + last_reason_);
    d.add("every n frames", config_.loop.cl_step);
    d.add("reference", toString(config_.loop.reference));
    d.add("attempts", attempts_);
    d.add("accepted", accepted_);
    d.add("rejected in a row", rejected_in_a_row_);
    d.add("last reason", last_reason_);
    d.addf("last correction (mm)", "%.2f", last_correction_m_ * 1e3);
    d.addf("last correction (deg)", "%.3f", last_correction_deg_);
    d.addf("map -> odom (mm)", "%.2f", X.translation().norm() * 1e3);
    d.addf("map -> odom (deg)", "%.3f", Eigen::AngleAxisd(X.rotation()).angle() * kRadToDeg);
  }

  void process(const Frame& f) {
    diag_.input();
    const auto t0 = std::chrono::steady_clock::now();
    closeFrame(f);
    diag_.processed(msSince(t0));
    diag_.counts(input_.skipped(), 0);
  }

  void closeFrame(const Frame& f) {
    if (auto c = reconf_.takePending()) {  // between frames
      std::lock_guard<std::mutex> lock(diag_mutex_);
      config_ = *c;
      closer_.reset();  // built with the old gates and range
      caster_.reset();
    }
    const double stamp = f.image->header.stamp.toSec();
    if (!ctx_->map.adopt(f.status->epoch)) return;  // from before a reset
    Eigen::Isometry3d X = ctx_->map.latestCorrection();
    try {
      if (stamp < last_stamp_) {  // time jumped back: the graph was reset
        frames_ = 0;
        std::lock_guard<std::mutex> lock(diag_mutex_);
        attempts_ = accepted_ = 0;
        rejected_in_a_row_ = 0;
      }
      const double prev = last_stamp_;
      last_stamp_ = stamp;
      ++frames_;
      const bool attempt = f.status->tracked && frames_ % config_.loop.cl_step == 0;
      // The surface layer (cl_reference surface) takes every tracked frame at its map pose.
      const bool observe = f.status->tracked && config_.loop.reference == LoopReference::kSurface;
      std::optional<DepthImage> depth;
      Eigen::Isometry3d T_odom_C = Eigen::Isometry3d::Identity();
      PinholeIntrinsics K;
      const auto closerOver = [&](const std::shared_ptr<VoxelMap>& map) -> LoopCloser& {
        return closer_.over(map, K, [&](const VoxelMap& m) {
          return std::make_unique<LoopCloser>(m, K, config_.range, config_.loop);
        });
      };
      if (attempt || observe) {
        T_odom_C = conv::fromPoseMsg(f.status->camera_pose);
        K = conv::intrinsicsFromCameraInfo(*f.info);
        depth = conv::depthFromMsg(*f.image, 1.0, DepthRange{0.0, 1e9});
      }
      if (attempt) {
        // The offline order: this frame's attempt sees the map fused up to the previous frame.
        if (mode_ == Mode::kReplay && prev >= 0.0 && !ctx_->map.waitFused(prev, wait_timeout_s_))
          NODELET_WARN("loop_closure: the map did not catch up with frame %.3f within %.0f s", prev,
                       wait_timeout_s_);
        const std::shared_ptr<VoxelMap> map = ctx_->map.map();
        std::optional<LoopClosureResult> res;
        if (map && map->occupiedCount() > 0)
          res = closerOver(map).attempt(*depth, stamp, T_odom_C, X);
        if (res) {
          {
            std::lock_guard<std::mutex> lock(diag_mutex_);
            ++attempts_;
            if (res->accepted) ++accepted_;
            X = res->correction.T_M_O;  // the one it started from when rejected
            rejected_in_a_row_ = res->accepted ? 0 : rejected_in_a_row_ + 1;
            last_accepted_ = res->accepted;
            last_reason_ = res->reason;
            last_correction_m_ = res->correction_m;
            last_correction_deg_ = res->correction_deg;
          }
          publishStatus(f, *res);
          if (virtual_pub_.getNumSubscribers() > 0) {
            const DepthImage virt =
                caster_
                    .over(map, K,
                          [&](const VoxelMap& m) {
                            return std::make_unique<MapRayCaster>(m, K, config_.range);
                          })
                    .cast(X * T_odom_C);
            if (!virt.empty()) {
              std_msgs::Header h = f.image->header;
              virtual_pub_.publish(conv::depthToMsg(virt, h));
            }
          }
        }
      }
      if (observe) {
        // After the decision, at the pose fusion uses, as Mapper::process observes after fusing;
        // the map is made here if fusion has not made it yet (the same parameters and first pose),
        // so the layer takes the same frames as offline whatever the nodelets' order.
        const Eigen::Isometry3d T_map_C = X * T_odom_C;
        closerOver(ctx_->map.ensureMap(K, config_, T_map_C)).observe(*depth, T_map_C);
      }
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(1.0, "loop_closure: frame at %.3f: %s", stamp, e.what());
    }
    ctx_->map.decide(stamp, X);  // every frame gets a decision, so fusion never waits in vain
  }

  void publishStatus(const Frame& f, const LoopClosureResult& r) {
    rig_msgs::LoopClosureStatus s;
    s.header.stamp = f.image->header.stamp;
    s.header.frame_id = map_frame_;
    s.accepted = r.accepted;
    s.reason = r.reason;
    s.correction_m = r.correction_m;
    s.correction_deg = r.correction_deg;
    s.model_fraction = r.model_fraction;
    s.normal_spread = r.normal_spread;
    s.model_cells = r.model_cells;
    s.current_cells = r.current_cells;
    s.matches = r.matches;
    s.error_rms_m = r.error_rms_m;
    s.ms_raycast = r.ms_raycast;
    s.ms_reduce = r.ms_reduce;
    s.ms_register = r.ms_register;
    s.attempts = attempts_;
    s.accepted_total = accepted_;
    status_pub_.publish(s);
  }

  Mode mode_ = Mode::kLive;
  std::string map_frame_, odom_frame_;
  double wait_timeout_s_ = 10.0;
  MapperConfig config_;
  std::shared_ptr<GraphContext> ctx_;
  double last_stamp_ = -1.0;
  std::uint64_t frames_ = 0;
  std::mutex diag_mutex_;  // the attempt counters and the last decision, read by loopTask
  std::uint32_t attempts_ = 0, accepted_ = 0;
  int rejected_in_a_row_ = 0;
  bool last_accepted_ = false;
  std::string last_reason_;
  double last_correction_m_ = 0.0, last_correction_deg_ = 0.0;
  MapStage<LoopCloser> closer_;    // the loop-closure worker's only
  MapStage<MapRayCaster> caster_;  // the virtual depth it publishes (full resolution)
  StageDiagnostics diag_;
  RuntimeParams<MapperConfig> reconf_;
  ros::Publisher status_pub_;
  image_transport::Publisher virtual_pub_;
  tf2_ros::TransformBroadcaster tf_pub_;
  ros::Timer tf_timer_;
  ros::Time last_tf_stamp_;
  TrackedFrameInput input_;
};

}  // namespace graph
}  // namespace depth_track

PLUGINLIB_EXPORT_CLASS(depth_track::graph::LoopClosureNodelet, nodelet::Nodelet)
