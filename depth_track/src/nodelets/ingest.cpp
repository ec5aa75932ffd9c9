// depth_track/ingest: image_rect + camera_info (paired by stamp) -> depth in metres through the
// core's one conversion, range limits and the prefilter stage -> depth/image (32FC1) +
// depth/camera_info, and depth/false_colour while someone watches it. Bad input becomes a
// throttled error and a rejection entry on `status`; nothing escapes a callback.
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <pluginlib/class_list_macros.hpp>

#include <memory>

#include "depth_track/core/depth_correction.hpp"
#include "depth_track/core/prefilter_stage.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/core/worker_pool.hpp"
#include "depth_track/ros/conversions.hpp"
#include "depth_track/ros/params.hpp"
#include "graph_common.hpp"
#include "graph_diagnostics.hpp"
#include "graph_reconfigure.hpp"

namespace depth_track {
namespace graph {

class IngestNodelet : public nodelet::Nodelet {
 public:
  ~IngestNodelet() override {
    if (queue_) queue_->stop();
  }

 private:
  struct Runtime {  // what dynamic_reconfigure may change
    TrackerConfig tracker;
    DepthRange range;
  };
  struct Frame {
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CameraInfoConstPtr info;  ///< null = none with this stamp (missing camera_info)
  };

  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    rosparams::ParamReader r(pnh, "ingest");
    const Mode mode = parseMode(r.getString("mode"));
    depth_scale_m_ = r.getDouble("depth_scale");
    range_.min_m = r.getDouble("d_min");
    range_.max_m = r.getDouble("d_max");
    band_m_ = r.getDouble("false_colour_band");
    const double timeout_s = r.getDouble("input_timeout");
    const int threads = r.getInt("threads");
    const int replay_queue = r.getInt("replay_queue");
    FrameQueueOptions queue_options;
    queue_options.live_depth = r.getInt("live_queue");
    const std::string transport = r.getString("image_transport");
    const std::string correction_file = r.getString("depth_correction");
    if (!correction_file.empty()) {
      try {
        correction_ = loadDepthCorrectionYaml(correction_file);
      } catch (const std::invalid_argument& e) {
        r.problem(pnh.resolveName("depth_correction") + ": " + e.what());
      }
    }
    for (const auto& p : range_.validate()) r.problem(pnh.resolveName("d_min") + "/d_max: " + p);
    config_ =
        r.table<TrackerConfig>(ros::NodeHandle(nh, "tracker"), trackerParams(), TrackerConfig{},
                               [](const TrackerConfig& c) { return c.validate(nominalK()); });
    r.finish();  // throws: the manager reports the message and the nodelet does not start
    diag_.start(nh, pnh, getName(), readDiagnosticThresholds(nh), {});
    reconf_.bindNodeParam("ingest", "d_min", [](Runtime& s) -> double& { return s.range.min_m; });
    reconf_.bindNodeParam("ingest", "d_max", [](Runtime& s) -> double& { return s.range.max_m; });
    reconf_.bindTable("ingest", "tracker", trackerParams(),
                      [](Runtime& s) -> TrackerConfig& { return s.tracker; });
    reconf_.start(pnh, "ingest", {config_, range_}, {TrackerConfig{}, DepthRange{}},
                  [](const Runtime& s) {
                    auto p = s.range.validate();
                    for (const auto& q : s.tracker.validate(nominalK())) p.push_back(q);
                    return p;
                  });
    pool_ = std::make_shared<WorkerPool>(threads);
    ctx_ = graphContext(nh.getNamespace());

    image_transport::ImageTransport it(nh);
    depth_pub_ = it.advertiseCamera("depth/image", 5);
    colour_pub_ = it.advertise("depth/false_colour", 1);
    status_pub_ = nh.advertise<rig_msgs::TrackingStatus>("status", 50);
    queue_ = std::make_unique<FrameQueue<Frame>>(
        mode, replay_queue, [this](const Frame& f) { process(f); }, queue_options);
    // Resolved first: this image_transport appends "/compressedDepth" to the name as given, and
    // the remapping of image_rect would not reach the transport's subtopic.
    image_sub_ =
        it.subscribe(nh.resolveName("image_rect"), 50, &IngestNodelet::onImage, this,
                     image_transport::TransportHints(transport, ros::TransportHints(), pnh));
    info_sub_ = nh.subscribe("camera_info", 50, &IngestNodelet::onInfo, this);
    watchdog_.start(nh, "ingest", {image_sub_.getTopic(), info_sub_.getTopic()}, timeout_s);
    NODELET_INFO(
        "ingest: %s on %s (%s) + %s, depth_scale %g m/unit, range %.2f..%.2f m, prefilter %s",
        mode == Mode::kReplay ? "replay" : "live", image_sub_.getTopic().c_str(), transport.c_str(),
        info_sub_.getTopic().c_str(), depth_scale_m_, range_.min_m, range_.max_m,
        toString(config_.prefilter.type).c_str());
  }

  static PinholeIntrinsics nominalK() {
    return PinholeIntrinsics{640, 480, 500, 500, 319.5, 239.5};
  }

  void onImage(const sensor_msgs::ImageConstPtr& image) {
    watchdog_.kick();
    diag_.input();
    std::lock_guard<std::mutex> lock(pair_mutex_);
    if (auto p = pairs_.addA(image->header.stamp, image)) paired(*p);
    // An image that waited through 10 newer ones without its camera_info never gets one.
    while (pairs_.unpairedA() > reported_unpaired_) {
      ++reported_unpaired_;
      queue_->push({nullptr, nullptr});
    }
  }
  void onInfo(const sensor_msgs::CameraInfoConstPtr& info) {
    std::lock_guard<std::mutex> lock(pair_mutex_);
    if (auto p = pairs_.addB(info->header.stamp, info)) paired(*p);
  }
  void paired(const std::pair<sensor_msgs::ImageConstPtr, sensor_msgs::CameraInfoConstPtr>& p) {
    // Images older than this pair will not get their camera_info any more.
    for (const auto& img : pairs_.takeOlderA(p.first->header.stamp)) queue_->push({img, nullptr});
    queue_->push({p.first, p.second});
  }

  void reject(const std_msgs::Header& h, const std::string& why) {
    ++rejected_;
    NODELET_ERROR_THROTTLE(1.0, "ingest: frame at %.3f rejected: %s", h.stamp.toSec(), why.c_str());
    rig_msgs::TrackingStatus s = rejectedStatus(h, "ingest: " + why);
    s.frames_rejected = rejected_;
    status_pub_.publish(s);
  }

  void process(const Frame& f) {
    const auto t0 = std::chrono::steady_clock::now();
    processFrame(f);
    diag_.processed(msSince(t0));
    diag_.counts(queue_->skipped(), rejected_);
  }
  void processFrame(const Frame& f) {
    ctx_->skipped_ingest = queue_->skipped();
    if (auto s = reconf_.takePending()) {  // between frames: the prefilter is rebuilt below
      config_ = s->tracker;
      range_ = s->range;
      prefilter_.reset();
    }
    if (!f.image || !f.info) {
      std_msgs::Header h;
      if (f.image)
        h = f.image->header;
      else
        h.stamp = ros::Time::now();
      reject(h, "an image came without camera_info of the same stamp on " + info_sub_.getTopic() +
                    " (missing camera_info)");
      return;
    }
    const std_msgs::Header& h = f.image->header;
    try {
      switch (guard_.check(h.stamp)) {
        case StampGuard::Verdict::kReject:
          reject(h, "stamp " + std::to_string(h.stamp.toSec()) + " s does not increase (last " +
                        std::to_string(guard_.lastStamp().toSec()) + " s)");
          return;
        case StampGuard::Verdict::kReset:  // registration logs the jump; a new camera may follow
          prefilter_.reset();
          break;
        case StampGuard::Verdict::kNext:
          break;
      }
      const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(*f.info);
      conv::checkImageMatchesInfo(*f.image, K);
      if (!prefilter_ || K.width != K_.width || K.height != K_.height) {
        prefilter_ = std::make_unique<PrefilterStage>(K, config_.prefilter, pool_);
        K_ = K;
      }
      DepthImage depth = conv::depthFromMsg(*f.image, depth_scale_m_, range_);
      applyDepthCorrection(depth, correction_);
      // A covered lens or a view beyond range is a frame, not bad input: the tracker flags it
      // LOST (its status says why) and relocalises when the view returns.
      if (depth.countValid() == 0)
        NODELET_WARN_THROTTLE(1.0,
                              "ingest: frame at %.3f has no valid depth (every pixel 0, NaN, "
                              "Inf or outside %.2f..%.2f m)",
                              h.stamp.toSec(), range_.min_m, range_.max_m);
      if (!prefilter_->passthrough()) {
        const auto t0 = std::chrono::steady_clock::now();
        depth = prefilter_->apply(depth);
        ctx_->times.setPrefilter(h.stamp.toSec(), msSince(t0));
      }
      depth_pub_.publish(conv::depthToMsg(depth, h), f.info);
      if (colour_pub_.getNumSubscribers() > 0)
        colour_pub_.publish(conv::falseColourDepth(depth, h, band_m_));
    } catch (const std::exception& e) {
      reject(h, e.what());
    }
  }

  double depth_scale_m_ = 0.001, band_m_ = 0.05;
  DepthRange range_;
  DepthCorrection correction_;  ///< camera_check's measured depth response (identity = none)
  TrackerConfig config_;
  std::shared_ptr<WorkerPool> pool_;
  std::shared_ptr<GraphContext> ctx_;
  std::unique_ptr<PrefilterStage> prefilter_;
  PinholeIntrinsics K_;
  StampGuard guard_;
  std::uint32_t rejected_ = 0;
  std::mutex pair_mutex_;
  StampPairer<sensor_msgs::ImageConstPtr, sensor_msgs::CameraInfoConstPtr> pairs_{10};
  std::uint64_t reported_unpaired_ = 0;
  image_transport::Subscriber image_sub_;
  ros::Subscriber info_sub_;
  image_transport::CameraPublisher depth_pub_;
  image_transport::Publisher colour_pub_;
  ros::Publisher status_pub_;
  InputWatchdog watchdog_;
  StageDiagnostics diag_;
  RuntimeParams<Runtime> reconf_;
  std::unique_ptr<FrameQueue<Frame>> queue_;
};

}  // namespace graph
}  // namespace depth_track

PLUGINLIB_EXPORT_CLASS(depth_track::graph::IngestNodelet, nodelet::Nodelet)
