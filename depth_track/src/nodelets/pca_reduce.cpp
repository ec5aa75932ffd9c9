// depth_track/pca_reduce: depth/image + depth/camera_info -> the cell reducer stage -> `cells`
// (organised PointCloud2 in the optical frame, conversions.hpp) and `cells/stats`
// (rig_msgs/ReductionStats: total / retained / pruned by reason, ms). With tracker/auto_noise the
// first frame with depth is measured by the core's calibrateNoise (as the offline Tracker does),
// the reducer takes its settings and `cells/noise` (rig_msgs/NoiseCalibration, latched) carries
// them to registration before that frame's cells.
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <rig_msgs/NoiseCalibration.h>
#include <rig_msgs/ReductionStats.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <visualization_msgs/Marker.h>
#include <pluginlib/class_list_macros.hpp>

#include "depth_track/core/cell_reducer.hpp"
#include "depth_track/core/noise_model.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/core/worker_pool.hpp"
#include "depth_track/ros/conversions.hpp"
#include "depth_track/ros/params.hpp"
#include "graph_common.hpp"
#include "graph_diagnostics.hpp"

namespace depth_track {
namespace graph {

class PcaReduceNodelet : public nodelet::Nodelet {
 public:
  ~PcaReduceNodelet() override {
    if (queue_) queue_->stop();
  }

 private:
  struct Frame {
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CameraInfoConstPtr info;
  };

  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    rosparams::ParamReader r(getPrivateNodeHandle(), "pca_reduce");
    const Mode mode = parseMode(r.getString("mode"));
    const int threads = r.getInt("threads");
    fm_terms_ = r.getBool("fm_terms");
    FrameQueueOptions queue_options;
    queue_options.live_depth = r.getInt("live_queue");
    config_ = r.table<TrackerConfig>(
        ros::NodeHandle(nh, "tracker"), trackerParams(), TrackerConfig{},
        [](const TrackerConfig& c) {
          return c.validate(PinholeIntrinsics{640, 480, 500, 500, 319.5, 239.5});
        });
    r.finish();
    diag_.start(nh, getPrivateNodeHandle(), getName(), readDiagnosticThresholds(nh), {});
    pool_ = std::make_shared<WorkerPool>(threads);
    ctx_ = graphContext(nh.getNamespace());
    cells_pub_ = nh.advertise<sensor_msgs::PointCloud2>("cells", 5);
    stats_pub_ = nh.advertise<rig_msgs::ReductionStats>("cells/stats", 5);
    normals_pub_ = nh.advertise<visualization_msgs::Marker>("cells/normals", 1);
    status_pub_ = nh.advertise<rig_msgs::TrackingStatus>("status", 50);
    noise_pub_ = nh.advertise<rig_msgs::NoiseCalibration>("cells/noise", 1, true);
    queue_ = std::make_unique<FrameQueue<Frame>>(
        mode, 100000, [this](const Frame& f) { process(f); }, queue_options);
    image_transport::ImageTransport it(nh);
    sub_ = it.subscribeCamera("depth/image", 50, &PcaReduceNodelet::onFrame, this);
  }

  void onFrame(const sensor_msgs::ImageConstPtr& image,
               const sensor_msgs::CameraInfoConstPtr& info) {
    diag_.input();
    queue_->push({image, info});
  }

  void process(const Frame& f) {
    ctx_->skipped_reduce = queue_->skipped();
    const std_msgs::Header& h = f.image->header;
    try {
      const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(*f.info);
      if (!reducer_ || K.width != K_.width || K.height != K_.height || K.fx != K_.fx ||
          K.fy != K_.fy || K.cx != K_.cx || K.cy != K_.cy) {
        reducer_ = std::make_unique<CellReducer>(K, reducerConfig(), pool_);
        K_ = K;
      }
      const DepthImage depth = conv::depthFromMsg(*f.image, 1.0, DepthRange{0.0, 1e9});
      // The Tracker's rule: once, on the first frame with depth, before any cells go out.
      if (config_.auto_noise && !calibrated_ && depth.countValid() > 0) {
        const NoiseCalibration c = calibrateNoise(depth, K, config_.pca.cell_size, h.stamp.toSec());
        c.applyTo(&config_.pca);
        reducer_ = std::make_unique<CellReducer>(K, config_.reducerConfig(), pool_);
        calibrated_ = true;
        noise_pub_.publish(conv::toMsg(c, h));
        NODELET_INFO("pca_reduce: auto_noise on the frame at %.3f: %s", h.stamp.toSec(),
                     c.summary.c_str());
      }
      const auto t0 = std::chrono::steady_clock::now();
      const std::shared_ptr<const CellCloud> cells =
          reducer_->reduce(depth, h.stamp.toSec(), h.frame_id);
      const double ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      ctx_->times.setReduce(h.stamp.toSec(), ms);
      diag_.processed(ms);
      cells_pub_.publish(conv::cellsToCloud(*cells, h));
      rig_msgs::ReductionStats s;
      s.header = h;
      s.cell_size_px = cells->cell_size;
      s.grid_width = cells->grid_w;
      s.grid_height = cells->grid_h;
      s.total = cells->stats.total;
      s.retained = cells->stats.retained;
      s.pruned_invalid = cells->stats.pruned_invalid;
      s.pruned_degenerate = cells->stats.pruned_degenerate;
      s.pruned_edge = cells->stats.pruned_edge;
      s.ms_reduce = ms;
      stats_pub_.publish(s);
      if (normals_pub_.getNumSubscribers() > 0) publishNormals(*cells, h);
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(1.0, "pca_reduce: frame at %.3f rejected: %s", h.stamp.toSec(),
                             e.what());
      rig_msgs::TrackingStatus s = rejectedStatus(h, std::string("pca_reduce: ") + e.what());
      status_pub_.publish(s);
      ++rejected_;
    }
    diag_.counts(queue_->skipped(), rejected_);
  }

  /// Each cell's normal as a 3 cm line from its mean vertex (rviz cannot draw them from a cloud).
  void publishNormals(const CellCloud& cells, const std_msgs::Header& h) {
    visualization_msgs::Marker m;
    m.header = h;
    m.ns = "cell_normals";
    m.type = visualization_msgs::Marker::LINE_LIST;
    m.pose.orientation.w = 1.0;
    m.scale.x = 0.002;
    m.color.r = 1.0f, m.color.g = 0.9f, m.color.b = 0.2f, m.color.a = 1.0f;
    m.points.reserve(2 * cells.cells.size());
    for (const Cell& c : cells.cells) {
      geometry_msgs::Point a, b;
      a.x = c.mean_C.x(), a.y = c.mean_C.y(), a.z = c.mean_C.z();
      b.x = a.x + 0.03 * c.normal_C.x(), b.y = a.y + 0.03 * c.normal_C.y(),
      b.z = a.z + 0.03 * c.normal_C.z();
      m.points.push_back(a);
      m.points.push_back(b);
    }
    normals_pub_.publish(m);
  }

  /// The reduction: the FM metric's terms also when the method does not need them (~fm_terms),
  /// so that the registration can be switched to cell_search at runtime.
  PcaConfig reducerConfig() const {
    PcaConfig p = config_.reducerConfig();
    p.compute_inv_sqrt = p.compute_inv_sqrt || fm_terms_;
    return p;
  }

  TrackerConfig config_;
  bool fm_terms_ = false;
  bool calibrated_ = false;  ///< auto_noise measured (once per start, like the Tracker)
  std::shared_ptr<WorkerPool> pool_;
  std::shared_ptr<GraphContext> ctx_;
  std::unique_ptr<CellReducer> reducer_;
  PinholeIntrinsics K_;
  image_transport::CameraSubscriber sub_;
  ros::Publisher cells_pub_, stats_pub_, status_pub_, normals_pub_, noise_pub_;
  std::uint64_t rejected_ = 0;
  StageDiagnostics diag_;
  std::unique_ptr<FrameQueue<Frame>> queue_;
};

}  // namespace graph
}  // namespace depth_track

PLUGINLIB_EXPORT_CLASS(depth_track::graph::PcaReduceNodelet, nodelet::Nodelet)
