// depth_track/fusion: fuses each tracked full-resolution frame (depth/image + its `status`, paired
// by stamp) into the graph's voxel map at T_map_camera = (map -> odom of that frame, decided by
// the loop closure) * T_odom_camera. Lost and rejected frames are not fused (they would poison
// the map). Publishes, rate-limited, `map/voxels` (PointCloud2 of occupied voxel centres, map
// frame) and `map/markers` (MarkerArray, one CUBE_LIST per 0.5 m tile, only the tiles that
// changed: unlike a full rebuild per insert, the cost follows what changed). Services:
// ~save_map (OctoMap .bt), ~clear_map, ~render_depth (rig_msgs/RenderDepth: the map's virtual
// depth at a pose, cast by the core's ray caster; how a registration in another process
// relocalises; answered on a thread of its own, so a wait for the map never stalls the frames).
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <rig_msgs/RenderDepth.h>
#include <rig_msgs/SaveFile.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_srvs/Trigger.h>
#include <visualization_msgs/MarkerArray.h>
#include <pluginlib/class_list_macros.hpp>

#include <unordered_map>

#include "depth_track/core/map/mapper_params.hpp"
#include "depth_track/ros/conversions.hpp"
#include "depth_track/ros/params.hpp"
#include "graph_common.hpp"
#include "graph_diagnostics.hpp"

namespace depth_track {
namespace graph {

class FusionNodelet : public nodelet::Nodelet {
 public:
  ~FusionNodelet() override {
    if (render_spinner_) render_spinner_->stop();
    input_.stop();
  }

 private:
  using Frame = TrackedFrame;

  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    rosparams::ParamReader r(pnh, "fusion");
    mode_ = parseMode(r.getString("mode"));
    map_frame_ = r.getString("map_frame");
    odom_frame_ = r.getString("odom_frame");
    publish_period_s_ = r.getDouble("publish_period");
    const int sync_queue = r.getInt("sync_queue");
    FrameQueueOptions queue_options;
    queue_options.worker_nice = r.getInt("worker_nice");  // live mode only (FrameQueue)
    map_path_ = r.getString("map_path");
    config_ = readMapperTable(r, nh);
    r.finish();
    ctx_ = graphContext(nh.getNamespace());
    ctx_->map.attachFusion();
    diag_.start(nh, pnh, getName(), readDiagnosticThresholds(nh), {});
    diag_.add("map", [this](diagnostic_updater::DiagnosticStatusWrapper& d) { mapTask(d); });
    voxels_pub_ = nh.advertise<sensor_msgs::PointCloud2>("map/voxels", 1, true);
    markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>("map/markers", 10, true);
    save_srv_ = pnh.advertiseService("save_map", &FusionNodelet::onSave, this);
    clear_srv_ = pnh.advertiseService("clear_map", &FusionNodelet::onClear, this);
    // render_depth may wait for the map to catch up (replay): its own queue and thread, so the
    // frames it waits for still come in through the nodelet's callbacks.
    ros::AdvertiseServiceOptions render_opts;
    render_opts.init<rig_msgs::RenderDepth>(
        "render_depth",
        [this](rig_msgs::RenderDepth::Request& req, rig_msgs::RenderDepth::Response& res) {
          return onRender(req, res);
        });
    render_opts.callback_queue = &render_queue_;
    render_srv_ = pnh.advertiseService(render_opts);
    render_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &render_queue_);
    render_spinner_->start();
    input_.start(
        nh, mode_, sync_queue, [this](const Frame& f) { process(f); }, queue_options);
    publish_timer_ = nh.createWallTimer(ros::WallDuration(std::max(publish_period_s_, 0.05)),
                                        [this](const ros::WallTimerEvent&) { publishMap(); });
    NODELET_INFO("fusion: %s, voxel %.4f m, region %s, carving %s",
                 mode_ == Mode::kReplay ? "replay" : "live", config_.map.voxel_size_m,
                 mapRegionText(config_.map).c_str(),
                 config_.map.model == UpdateModel::kProbabilistic ? "on" : "off");
  }

  void process(const Frame& f) {
    diag_.input();
    const auto t0 = std::chrono::steady_clock::now();
    fuseFrame(f);
    diag_.processed(msSince(t0));
    diag_.counts(input_.skipped(), 0);
  }

  /// The map's size and how often it goes out; WARN while tracked frames leave it empty.
  void mapTask(diagnostic_updater::DiagnosticStatusWrapper& d) {
    const auto map = ctx_->map.map();
    const std::size_t voxels = map ? map->occupiedCount() : 0;
    const double since = ros::WallTime::now().toSec() - last_publish_wall_s_;
    // A surface needs hits from hitsToOccupy() frames (two at the default threshold).
    const int needed = map ? std::max(1, map->config().hitsToOccupy()) : 1;
    if (fused_ >= static_cast<std::uint64_t>(needed) && voxels == 0)
      d.summaryf(diagnostic_msgs::DiagnosticStatus::WARN,
                 "%llu frames were fused but the map is empty (range / region?; a voxel is "
                 "occupied after hits in %d frames)",
                 static_cast<unsigned long long>(fused_.load()), needed);
    else
      d.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "%zu occupied voxels", voxels);
    d.add("occupied voxels", voxels);
    d.add("frames fused", fused_.load());
    d.add("frames not fused (not tracked)", not_fused_.load());
    d.add("publications", publications_.load());
    d.addf("fuse depth limit (m, 0 = none)", "%.2f", fuse_depth_limit_m_.load());
    d.addf("returns within the fuse depth fused at their cell's plane (last frame, %)", "%.1f",
           snapped_percent_.load());
    d.addf("returns left out of the hits: near side of a depth edge (last frame, %)", "%.1f",
           edge_percent_.load());
    d.addf("returns left out of the hits: cells too small to place (last frame, %)", "%.1f",
           unplaced_percent_.load());
    d.addf("since last publication (s)", "%.1f", last_publish_wall_s_ > 0 ? since : -1.0);
  }

  void fuseFrame(const Frame& f) {
    const double stamp = f.image->header.stamp.toSec();
    if (!ctx_->map.adopt(f.status->epoch)) return;  // from before a reset: not this map's
    try {
      if (stamp < last_stamp_) {  // time jumped back: the registration resets the map too
        map_changed_ = true;
        tiles_.clear();
      }
      last_stamp_ = stamp;
      const auto X =
          ctx_->map.correctionFor(stamp, mode_ == Mode::kReplay && config_.loop.enabled, 30.0);
      if (!f.status->tracked) {
        ++not_fused_;
        ctx_->map.fused(stamp);
        return;
      }
      if (!X) throw std::runtime_error("no map -> odom decision for this frame within 30 s");
      const Eigen::Isometry3d T_map_C = *X * conv::fromPoseMsg(f.status->camera_pose);
      const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(*f.info);
      const DepthImage depth = conv::depthFromMsg(*f.image, 1.0, DepthRange{0.0, 1e9});
      const auto map = ctx_->map.ensureMap(K, config_, T_map_C);
      MapFuser& fuser =
          fuser_.over(map, K, [&](VoxelMap& m) { return std::make_unique<MapFuser>(m, K); });
      const FuseStats fs = fuser.fuse(depth, T_map_C);
      fuse_depth_limit_m_ = fs.fuse_depth_limit_m;
      const int considered = fs.returnsWithinFuseDepth();
      const auto percent = [&](int k) { return considered > 0 ? 100.0 * k / considered : 0.0; };
      snapped_percent_ = percent(fs.snapped_pixels);
      edge_percent_ = percent(fs.edge_dropped);
      unplaced_percent_ = percent(fs.unplaced_dropped);
      // The noise limit (max_fuse_noise) is measured on the map's first frames (ms_noise > 0):
      // say once what it measured and what it leaves out.
      if (fs.ms_noise > 0.0) {
        const std::string noise_limit = map->fuseNoiseSummary();
        if (noise_limit != logged_noise_limit_) {
          logged_noise_limit_ = noise_limit;
          NODELET_INFO("fusion: depth noise %s", noise_limit.c_str());
        }
      }
      if (config_.flush_every > 0 && map->framesFused() % config_.flush_every == 0) map->flush();
      ++fused_;
      map_changed_ = true;
    } catch (const std::exception& e) {
      NODELET_ERROR_THROTTLE(1.0, "fusion: frame at %.3f not fused: %s", stamp, e.what());
    }
    ctx_->map.fused(stamp);
  }

  /// Occupied voxels as a cloud and as per-tile cube lists; only changed tiles are re-sent.
  void publishMap() {
    if (!map_changed_.exchange(false)) return;
    const bool want_cloud = voxels_pub_.getNumSubscribers() > 0;
    const bool want_markers = markers_pub_.getNumSubscribers() > 0;
    if (!want_cloud && !want_markers) {
      map_changed_ = true;  // publish once someone subscribes
      return;
    }
    std::vector<Eigen::Vector3f> centres;
    double voxel = config_.map.voxel_size_m;
    if (const auto map = ctx_->map.map()) {
      voxel = map->config().voxel_size_m;
      map->forEachOccupied(
          [&](const VoxelKey& k) { centres.push_back(map->centerOf(k).cast<float>()); });
    }
    ros::Time now = ros::Time::now();
    if (want_cloud) {
      sensor_msgs::PointCloud2 c;
      c.header.stamp = now;
      c.header.frame_id = map_frame_;
      c.height = 1;
      c.width = centres.size();
      for (int i = 0; i < 3; ++i) {
        sensor_msgs::PointField pf;
        pf.name = std::string(1, "xyz"[i]);
        pf.offset = 4 * i;
        pf.datatype = sensor_msgs::PointField::FLOAT32;
        pf.count = 1;
        c.fields.push_back(pf);
      }
      c.point_step = 12;
      c.row_step = 12 * c.width;
      c.is_dense = true;
      c.data.resize(c.row_step);
      std::memcpy(c.data.data(), centres.data(), c.data.size());
      voxels_pub_.publish(c);
    }
    ++publications_;
    last_publish_wall_s_ = ros::WallTime::now().toSec();
    if (want_markers) {
      const double tile = 0.5;
      std::unordered_map<std::int64_t, std::vector<Eigen::Vector3f>> by_tile;
      for (const auto& p : centres) {
        const std::int64_t tx = static_cast<std::int64_t>(std::floor(p.x() / tile)) & 0xFFFFF;
        const std::int64_t ty = static_cast<std::int64_t>(std::floor(p.y() / tile)) & 0xFFFFF;
        const std::int64_t tz = static_cast<std::int64_t>(std::floor(p.z() / tile)) & 0xFFFFF;
        by_tile[(tx << 40) | (ty << 20) | tz].push_back(p);
      }
      visualization_msgs::MarkerArray arr;
      std::unordered_map<std::int64_t, std::pair<std::size_t, int>> now_tiles;
      for (auto& [key, pts] : by_tile) {
        const int id = tileId(key);
        now_tiles[key] = {pts.size(), id};
        auto old = tiles_.find(key);
        if (old != tiles_.end() && old->second.first == pts.size()) continue;  // unchanged
        visualization_msgs::Marker m;
        m.header.stamp = now;
        m.header.frame_id = map_frame_;
        m.ns = "occupied_voxels";
        m.id = id;
        m.type = visualization_msgs::Marker::CUBE_LIST;
        m.action = visualization_msgs::Marker::ADD;
        m.pose.orientation.w = 1.0;
        m.scale.x = m.scale.y = m.scale.z = voxel;
        m.points.reserve(pts.size());
        m.colors.reserve(pts.size());
        for (const auto& p : pts) {
          geometry_msgs::Point q;
          q.x = p.x(), q.y = p.y(), q.z = p.z();
          m.points.push_back(q);
          // Colour by height (octomap_server's habit), cycling every 2 m.
          const double h = std::fmod(std::fmod(p.z(), 2.0) + 2.0, 2.0) / 2.0;
          std_msgs::ColorRGBA col;
          col.r = static_cast<float>(std::clamp(std::abs(h * 6 - 3) - 1, 0.0, 1.0));
          col.g = static_cast<float>(std::clamp(2 - std::abs(h * 6 - 2), 0.0, 1.0));
          col.b = static_cast<float>(std::clamp(2 - std::abs(h * 6 - 4), 0.0, 1.0));
          col.a = 1.0f;
          m.colors.push_back(col);
        }
        arr.markers.push_back(std::move(m));
      }
      for (const auto& [key, v] : tiles_)
        if (!now_tiles.count(key)) {
          visualization_msgs::Marker m;
          m.header.frame_id = map_frame_;
          m.ns = "occupied_voxels";
          m.id = v.second;
          m.action = visualization_msgs::Marker::DELETE;
          arr.markers.push_back(m);
        }
      tiles_ = std::move(now_tiles);
      if (!arr.markers.empty()) markers_pub_.publish(arr);
    }
  }
  int tileId(std::int64_t key) {
    auto it = tile_ids_.find(key);
    if (it != tile_ids_.end()) return it->second;
    const int id = static_cast<int>(tile_ids_.size());
    tile_ids_[key] = id;
    return id;
  }

  bool onSave(rig_msgs::SaveFile::Request& req, rig_msgs::SaveFile::Response& res) {
    res.path = req.path.empty() ? map_path_ : req.path;
    try {
      const auto map = ctx_->map.map();
      if (!map) throw std::runtime_error("the map is empty (no frame fused yet)");
      map->save(res.path);
      const std::size_t n = map->occupiedCount();
      res.success = true;
      res.message = "map of " + std::to_string(n) + " occupied voxels -> " + res.path;
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("save_map failed: ") + e.what();
    }
    NODELET_INFO("fusion: %s", res.message.c_str());
    return true;
  }
  /// The virtual depth at the requested pose (map or odom frame), after waiting up to wait_s
  /// for the map to hold every frame up to fused_upto. Every failure is an answer naming it.
  bool onRender(rig_msgs::RenderDepth::Request& req, rig_msgs::RenderDepth::Response& res) {
    res.success = false;
    try {
      // A microsecond below: the stamp went double -> ros::Time -> double on its way here.
      const double upto = req.fused_upto.toSec() - 1e-6;
      std::string late;
      if (req.wait_s > 0.0 && upto > 0.0 && !ctx_->map.waitFused(upto, std::min(req.wait_s, 60.0)))
        late = " (the map had not caught up with " + std::to_string(upto) + " s after " +
               std::to_string(req.wait_s) + " s)";
      Eigen::Isometry3d T_map_C = conv::fromPoseMsg(req.pose);
      if (req.header.frame_id == odom_frame_) {
        T_map_C = ctx_->map.correctionFor(req.header.stamp.toSec(), false, 0.0)
                      .value_or(Eigen::Isometry3d::Identity()) *
                  T_map_C;
      } else if (req.header.frame_id != map_frame_) {
        throw std::invalid_argument("pose in frame '" + req.header.frame_id + "'; expected '" +
                                    map_frame_ + "' or '" + odom_frame_ + "'");
      }
      const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(req.camera_info);
      const std::shared_ptr<VoxelMap> map = ctx_->map.map();
      res.occupied_voxels = map ? map->occupiedCount() : 0;
      if (res.occupied_voxels == 0) throw std::runtime_error("the map is empty" + late);
      const DepthImage virt =
          render_caster_
              .over(map, K,
                    [&](const VoxelMap& m) {
                      return std::make_unique<MapRayCaster>(m, K, config_.range);
                    })
              .cast(T_map_C);
      std_msgs::Header h = req.header;
      h.frame_id = req.camera_info.header.frame_id;
      res.depth = *conv::depthToMsg(virt, h);
      res.map_pose = conv::toPoseMsg(T_map_C);
      res.success = true;
      res.message = "cast " + std::to_string(K.width) + "x" + std::to_string(K.height) + ", " +
                    std::to_string(virt.countValid()) + " returns from " +
                    std::to_string(res.occupied_voxels) + " occupied voxels" + late;
    } catch (const std::exception& e) {
      res.message = std::string("render_depth: ") + e.what();
      NODELET_WARN_THROTTLE(1.0, "fusion: %s", res.message.c_str());
    }
    return true;
  }

  bool onClear(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    ctx_->map.clear(ctx_->map.epoch());
    map_changed_ = true;
    res.success = true;
    res.message = "map cleared; the next tracked frame starts a new one";
    NODELET_INFO("fusion: %s", res.message.c_str());
    return true;
  }

  Mode mode_ = Mode::kLive;
  std::string map_frame_, odom_frame_, map_path_;
  double publish_period_s_ = 1.0;
  MapperConfig config_;
  std::atomic<double> fuse_depth_limit_m_{0.0};  ///< the last fused frame's (FuseStats)
  std::atomic<double> snapped_percent_{0.0};     ///< share of its returns snapped (FuseStats)
  std::atomic<double> edge_percent_{0.0};      ///< ... left out: near side of a depth edge
  std::atomic<double> unplaced_percent_{0.0};  ///< ... left out: cells too small to place
  std::string logged_noise_limit_;               ///< the noise limit's summary as last logged
  std::shared_ptr<GraphContext> ctx_;
  double last_stamp_ = -1.0;
  std::atomic<std::uint64_t> fused_{0}, not_fused_{0}, publications_{0};
  std::atomic<double> last_publish_wall_s_{0.0};
  MapStage<MapFuser> fuser_;              // the fusion worker's only
  MapStage<MapRayCaster> render_caster_;  // the render_depth thread's only
  ros::CallbackQueue render_queue_;
  std::unique_ptr<ros::AsyncSpinner> render_spinner_;
  ros::ServiceServer render_srv_;
  StageDiagnostics diag_;
  std::atomic<bool> map_changed_{false};
  std::unordered_map<std::int64_t, std::pair<std::size_t, int>> tiles_;  // key -> (voxels, id)
  std::unordered_map<std::int64_t, int> tile_ids_;
  ros::Publisher voxels_pub_, markers_pub_;
  ros::ServiceServer save_srv_, clear_srv_;
  ros::WallTimer publish_timer_;
  TrackedFrameInput input_;
};

}  // namespace graph
}  // namespace depth_track

PLUGINLIB_EXPORT_CLASS(depth_track::graph::FusionNodelet, nodelet::Nodelet)
