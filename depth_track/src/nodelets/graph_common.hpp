#pragma once
// What the tracking graph's nodelets share, ROS side only: the frame queue that gives replay its
// order and live mode its freshness, the clock/stamp guard, the input watchdog, and the
// in-process registry through which nodelets of one manager share the map and their counters.
#include <image_transport/image_transport.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/map/map_fuser.hpp"
#include "depth_track/core/map/map_raycaster.hpp"
#include "depth_track/core/map/mapper.hpp"
#include "depth_track/core/map/mapper_params.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/ros/params.hpp"

namespace depth_track {
namespace graph {

enum class Mode { kLive, kReplay };
inline Mode parseMode(const std::string& s) { return s == "replay" ? Mode::kReplay : Mode::kLive; }

/// How a FrameQueue's live mode waits and how its worker shares the cores.
struct FrameQueueOptions {
  /// Live mode: items that may wait while the worker is busy; a newer item beyond them drops
  /// the oldest waiting one (counted as skipped). 1 keeps only the freshest; 2 absorbs one
  /// frame that overruns its period (or two frames delivered at once) without a skip, and
  /// still never lets a backlog grow.
  std::size_t live_depth = 1;
  /// Live mode: nice value of the worker thread (0 = the process's; higher yields the cores to
  /// threads of lower values, e.g. the map's work to the tracking chain). Linux nice is per
  /// thread. Replay ignores it: there every stage takes every frame in order, so a priority
  /// would only slow the replay down.
  int worker_nice = 0;
};

/// Hands messages from a subscriber callback to one worker thread. Replay: every item, in
/// order (up to `capacity`; beyond it the oldest is dropped and counted, which a replay at a
/// sustainable rate never reaches). Live: at most `live_depth` items wait, oldest first; an item
/// pushed out before the worker took it is counted as skipped. The worker runs `process`, which
/// must not throw (the nodelets catch everything inside it).
template <class T>
class FrameQueue {
 public:
  FrameQueue(Mode mode, std::size_t capacity, std::function<void(const T&)> process,
             FrameQueueOptions options = {})
      : mode_(mode),
        capacity_(mode == Mode::kLive ? std::max<std::size_t>(options.live_depth, 1) : capacity),
        nice_(mode == Mode::kLive ? options.worker_nice : 0),
        process_(std::move(process)) {
    worker_ = std::thread([this] { run(); });
  }
  ~FrameQueue() { stop(); }
  FrameQueue(const FrameQueue&) = delete;
  FrameQueue& operator=(const FrameQueue&) = delete;

  void push(const T& item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (items_.size() >= capacity_) {
        items_.pop_front();
        ++(mode_ == Mode::kLive ? skipped_ : overflowed_);
      }
      items_.push_back(item);
    }
    cv_.notify_one();
  }
  /// Drops everything waiting (a reset); the item being processed finishes.
  void clear() {
    std::lock_guard<std::mutex> lock(mutex_);
    items_.clear();
  }
  /// Blocks until nothing waits and the worker is idle (tests, shutdown).
  void stop() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stopping_) return;
      stopping_ = true;
    }
    cv_.notify_all();
    if (worker_.joinable()) worker_.join();
  }
  std::uint64_t skipped() const { return skipped_; }
  std::uint64_t overflowed() const { return overflowed_; }
  std::size_t waiting() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size();
  }
  /// The worker's nice value as the kernel reports it (tests; -100 before the worker started).
  int workerNice() const { return worker_nice_seen_; }

 private:
  void run() {
    if (nice_ != 0) {
      // setpriority on a thread id changes that thread alone (Linux); failing to lower the
      // priority only costs speed, so it is reported and the worker runs on.
      const auto tid = static_cast<id_t>(::syscall(SYS_gettid));
      if (::setpriority(PRIO_PROCESS, tid, nice_) != 0)
        ROS_WARN("frame queue: could not set the worker's nice value to %d (errno %d)", nice_,
                 errno);
    }
    errno = 0;
    worker_nice_seen_ = ::getpriority(PRIO_PROCESS, static_cast<id_t>(::syscall(SYS_gettid)));
    for (;;) {
      T item;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        cv_.wait(lock, [this] { return stopping_ || !items_.empty(); });
        if (stopping_) return;
        item = items_.front();
        items_.pop_front();
      }
      process_(item);
    }
  }

  Mode mode_;
  std::size_t capacity_;  ///< replay: the overflow bound; live: live_depth
  int nice_;
  std::atomic<int> worker_nice_seen_{-100};
  std::function<void(const T&)> process_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<T> items_;
  bool stopping_ = false;
  std::atomic<std::uint64_t> skipped_{0}, overflowed_{0};
  std::thread worker_;
};

/// Decides what a frame's stamp means: the clock jumped back (a looped bag: reset the graph),
/// the stamp does not increase (reject the frame), or it is the next frame.
class StampGuard {
 public:
  enum class Verdict { kNext, kReset, kReject };
  Verdict check(const ros::Time& stamp) {
    const ros::Time now = ros::Time::now();
    Verdict v = Verdict::kNext;
    if (have_ && now + ros::Duration(0.5) < last_now_) {
      v = Verdict::kReset;
    } else if (have_ && stamp <= last_stamp_) {
      // A bag restarted without --clock shows only as a stamp far in the past.
      v = stamp + ros::Duration(1.0) < last_stamp_ && now < last_now_ + ros::Duration(2.0) &&
                  ros::Time::isSimTime()
              ? Verdict::kReset
              : Verdict::kReject;
      if (v == Verdict::kReject) return v;
    }
    have_ = true;
    last_stamp_ = stamp;
    last_now_ = now;
    return v;
  }
  void clear() { have_ = false; }
  const ros::Time& lastStamp() const { return last_stamp_; }

 private:
  bool have_ = false;
  ros::Time last_stamp_, last_now_;
};

/// Warns once per `timeout_s` of wall time without input, naming the resolved topics.
class InputWatchdog {
 public:
  void start(ros::NodeHandle& nh, const std::string& who, std::vector<std::string> topics,
             double timeout_s) {
    who_ = who;
    topics_ = std::move(topics);
    timeout_s_ = timeout_s;
    last_ = ros::WallTime::now();
    timer_ =
        nh.createWallTimer(ros::WallDuration(timeout_s / 2), [this](const ros::WallTimerEvent&) {
          const double idle = (ros::WallTime::now() - last_).toSec();
          if (idle < timeout_s_) return;
          std::string list;
          for (const auto& t : topics_) list += (list.empty() ? "" : ", ") + t;
          ROS_WARN("%s: no input for %.0f s on %s (is the camera / bag running and remapped?)",
                   who_.c_str(), idle, list.c_str());
          last_ = ros::WallTime::now();
        });
  }
  void kick() { last_ = ros::WallTime::now(); }

 private:
  std::string who_;
  std::vector<std::string> topics_;
  double timeout_s_ = 5.0;
  ros::WallTime last_;
  ros::WallTimer timer_;
};

/// The map of one graph, shared by the fusion nodelet (the writer, through a MapFuser), the
/// loop-closure nodelet and the registration's relocalisation (readers, through MapRayCaster /
/// LoopCloser) when they run in one nodelet manager; plus the map -> odom correction the loop
/// closure decides per frame. The VoxelMap guards itself (one writer or many readers, a waiting
/// writer first): the session adds no lock around it, only a short one around the pointer, so a
/// reader keeps the map it took alive while clear() starts a new one. In replay mode the two
/// mapping nodelets hand frames to each other through it in the offline order: the loop closure
/// of frame k reads the map fused up to frame k-1, and frame k is fused at the pose it decided.
class MapSession {
 public:
  /// The map, built on the first frame (its intrinsics and start pose place the region).
  std::shared_ptr<VoxelMap> ensureMap(const PinholeIntrinsics& K, const MapperConfig& config,
                                      const Eigen::Isometry3d& T_map_C0) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!map_) {
      auto map = std::make_shared<VoxelMap>(config.map);
      map->placeRegion(T_map_C0);
      intrinsics_ = K;
      map_ = std::move(map);
    }
    return map_;
  }
  /// The current map, or null before the first fused frame (and after clear()).
  std::shared_ptr<VoxelMap> map() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return map_;
  }
  /// The intrinsics of the camera whose first frame built the map.
  PinholeIntrinsics intrinsics() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return intrinsics_;
  }
  /// In this process, the fusion nodelet writes the map (else relocalisation asks over ROS).
  void attachFusion() { fusion_attached_ = true; }
  bool fusionAttached() const { return fusion_attached_; }
  /// Forgets the map and every correction (reset, clear_map, a jump back in time); frames of
  /// earlier epochs that are still on their way must be dropped (see current()). A reader still
  /// holding the old map finishes on it.
  void clear(std::uint32_t epoch) {
    epoch_ = epoch;
    forget();
  }
  /// For a frame of `epoch`: true when it belongs to the map. A newer epoch (the registration
  /// reset in another process, where it could not clear this session) clears the map and is
  /// adopted; an older one (a frame from before a reset, still on its way) gives false.
  bool adopt(std::uint32_t epoch) {
    std::uint32_t cur = epoch_;
    while (epoch > cur)
      if (epoch_.compare_exchange_weak(cur, epoch)) {
        forget();
        return true;
      }
    return epoch == epoch_;
  }

  /// True for frames of the epoch the map belongs to.
  bool current(std::uint32_t epoch) const { return epoch == epoch_; }
  std::uint32_t epoch() const { return epoch_; }

 private:
  void forget() {
    std::lock_guard<std::mutex> lock(mutex_);
    map_.reset();
    decisions_.clear();
    T_map_odom_ = Eigen::Isometry3d::Identity();
    fused_upto_ = -1.0;
    ++generation_;
    cv_.notify_all();
  }

 public:
  // ---- corrections (loop closure -> everyone) ----
  void attachLoopClosure() { loop_attached_ = true; }
  bool loopAttached() const { return loop_attached_; }
  /// The loop closure's decision for the frame at stamp_s: map -> odom from then on.
  void decide(double stamp_s, const Eigen::Isometry3d& T_map_odom) {
    std::lock_guard<std::mutex> lock(mutex_);
    decisions_[stamp_s] = T_map_odom;
    while (decisions_.size() > 4096) decisions_.erase(decisions_.begin());
    T_map_odom_ = T_map_odom;
    cv_.notify_all();
  }
  /// map -> odom for the frame at stamp_s; in replay waits (up to timeout_s) until the loop
  /// closure has decided that frame. nullopt on timeout or a reset meanwhile.
  std::optional<Eigen::Isometry3d> correctionFor(double stamp_s, bool wait, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    const auto gen = generation_;
    auto ready = [&] {
      return generation_ != gen || (!decisions_.empty() && decisions_.rbegin()->first >= stamp_s);
    };
    if (wait && loop_attached_ &&
        !cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), ready))
      return std::nullopt;
    if (generation_ != gen) return std::nullopt;
    auto it = decisions_.upper_bound(stamp_s);
    if (it == decisions_.begin()) return T_map_odom_;
    return std::prev(it)->second;
  }
  Eigen::Isometry3d latestCorrection() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return T_map_odom_;
  }

  // ---- fusion progress (fusion -> loop closure) ----
  void fused(double stamp_s) {
    std::lock_guard<std::mutex> lock(mutex_);
    fused_upto_ = std::max(fused_upto_, stamp_s);
    cv_.notify_all();
  }
  /// Waits until every frame up to stamp_s was fused (or skipped); false on timeout.
  bool waitFused(double stamp_s, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    const auto gen = generation_;
    return cv_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                        [&] { return generation_ != gen || fused_upto_ >= stamp_s; });
  }

 private:
  mutable std::mutex mutex_;  // the pointer, the decisions and the fusion progress
  std::condition_variable cv_;
  std::shared_ptr<VoxelMap> map_;
  PinholeIntrinsics intrinsics_;
  std::map<double, Eigen::Isometry3d> decisions_;
  Eigen::Isometry3d T_map_odom_ = Eigen::Isometry3d::Identity();
  double fused_upto_ = -1.0;
  std::uint64_t generation_ = 0;
  std::atomic<bool> loop_attached_{false}, fusion_attached_{false};
  std::atomic<std::uint32_t> epoch_{0};
};

/// A core map stage (MapFuser, MapRayCaster, LoopCloser) over the session's current map. The
/// stages hold their map by reference, so this keeps the map alive as long as its stage and
/// builds a new stage when the session starts a new map or the camera changes. Not thread-safe
/// (one per thread, like the stages).
template <class Stage>
class MapStage {
 public:
  /// The stage over `map` for camera K, built with make(map) when either changed.
  template <class Make>
  Stage& over(const std::shared_ptr<VoxelMap>& map, const PinholeIntrinsics& K, Make&& make) {
    if (!stage_ || map != map_ || K.width != K_.width || K.height != K_.height || K.fx != K_.fx ||
        K.fy != K_.fy || K.cx != K_.cx || K.cy != K_.cy) {
      stage_.reset();
      map_ = map;
      K_ = K;
      stage_ = make(*map_);
    }
    return *stage_;
  }
  /// Drops the stage (its config changed): the next over() builds a new one.
  void reset() {
    stage_.reset();
    map_.reset();
  }

 private:
  std::shared_ptr<VoxelMap> map_;  // declared before stage_: outlives it
  PinholeIntrinsics K_;
  std::unique_ptr<Stage> stage_;
};

/// A ROS service called on a thread of its own, so the caller waits at most a timeout for the
/// answer (roscpp's call has none: a slow or vanished server would stall a frame worker for as
/// long as the connection lives). One call at a time: while one that timed out is still out, the
/// next is refused rather than queued behind it. Thread-safe.
template <class Srv>
class TimedServiceCall {
 public:
  explicit TimedServiceCall(std::string service) : service_(std::move(service)) {}
  const std::string& service() const { return service_; }
  /// The answer within timeout_s, or nullopt with *why naming what went wrong.
  std::optional<typename Srv::Response> call(const typename Srv::Request& req, double timeout_s,
                                             std::string* why) {
    auto state = std::make_shared<State>();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (busy_ && !busy_->done) {
        *why = service_ + ": the previous call is still out";
        return std::nullopt;
      }
      busy_ = state;
    }
    // The thread owns the state: a call that outlives the wait (or this object) ends on its own.
    std::thread([state, req, name = service_] {
      Srv srv;
      srv.request = req;
      const bool ok = ros::service::call(name, srv);
      std::lock_guard<std::mutex> lock(state->mutex);
      state->ok = ok;
      state->response = srv.response;
      state->done = true;
      state->cv.notify_all();
    }).detach();
    std::unique_lock<std::mutex> lock(state->mutex);
    if (!state->cv.wait_for(lock, std::chrono::duration<double>(timeout_s),
                            [&] { return state->done.load(); })) {
      char s[32];
      std::snprintf(s, sizeof(s), "%g", timeout_s);
      *why = service_ + ": no answer within " + s + " s";
      return std::nullopt;
    }
    if (!state->ok) {
      *why = service_ + ": call failed (is the node that offers it running?)";
      return std::nullopt;
    }
    return state->response;
  }

 private:
  struct State {
    std::mutex mutex;
    std::condition_variable cv;
    std::atomic<bool> done{false};
    bool ok = false;
    typename Srv::Response response;
  };
  std::string service_;
  std::mutex mutex_;
  std::shared_ptr<State> busy_;
};

/// Wall times of the front stages per frame stamp, so that the registration's status can report
/// every stage of the frame (in one manager; separate processes report zeros).
class StageTimes {
 public:
  void setPrefilter(double stamp_s, double ms) { set(stamp_s, 0, ms); }
  void setReduce(double stamp_s, double ms) { set(stamp_s, 1, ms); }
  /// (prefilter ms, reduce ms) of the frame, zeros when unknown.
  std::pair<double, double> get(double stamp_s) const {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = times_.find(stamp_s);
    return it == times_.end() ? std::make_pair(0.0, 0.0) : it->second;
  }

 private:
  void set(double stamp_s, int which, double ms) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto& t = times_[stamp_s];
    (which == 0 ? t.first : t.second) = ms;
    while (times_.size() > 512) times_.erase(times_.begin());
  }
  mutable std::mutex mutex_;
  std::map<double, std::pair<double, double>> times_;
};

/// Per-graph shared state, keyed by the nodelets' namespace (one graph per namespace).
struct GraphContext {
  StageTimes times;
  MapSession map;
  /// Live mode: frames each stage skipped because it was still busy with an older one.
  std::atomic<std::uint64_t> skipped_ingest{0}, skipped_reduce{0}, skipped_registration{0};
};

/// Pairs messages of two streams that carry the same stamp (a depth frame and its camera_info,
/// a depth frame and its tracking status), whichever comes first; at most `capacity` unpaired
/// ones of each stream wait (the oldest goes first). Not thread-safe (one subscriber queue).
template <class A, class B>
class StampPairer {
 public:
  explicit StampPairer(std::size_t capacity) : capacity_(capacity) {}
  /// Adds an A; returns its partner when one is waiting.
  std::optional<std::pair<A, B>> addA(const ros::Time& t, const A& a) {
    return add(t, a, as_, bs_, [](const A& x, const B& y) { return std::make_pair(x, y); });
  }
  std::optional<std::pair<A, B>> addB(const ros::Time& t, const B& b) {
    return add(t, b, bs_, as_, [](const B& y, const A& x) { return std::make_pair(x, y); });
  }
  /// As which a waits longest and never found its partner (dropped on overflow).
  std::uint64_t unpairedA() const { return dropped_a_; }
  /// Removes and returns the waiting As older than t: once a pair of stamp t formed, streams
  /// that arrive in order will not bring their partners any more.
  std::vector<A> takeOlderA(const ros::Time& t) {
    std::vector<A> out;
    while (!as_.empty() && as_.front().first < t) {
      out.push_back(as_.front().second);
      as_.pop_front();
    }
    return out;
  }
  void clear() {
    as_.clear();
    bs_.clear();
  }

 private:
  template <class X, class Y, class Make>
  std::optional<std::pair<A, B>> add(const ros::Time& t, const X& x,
                                     std::deque<std::pair<ros::Time, X>>& mine,
                                     std::deque<std::pair<ros::Time, Y>>& theirs, Make make) {
    for (auto it = theirs.begin(); it != theirs.end(); ++it)
      if (it->first == t) {
        auto out = make(x, it->second);
        theirs.erase(it);
        return out;
      }
    mine.emplace_back(t, x);
    if (mine.size() > capacity_) {
      mine.pop_front();
      if constexpr (std::is_same_v<X, A>) ++dropped_a_;
    }
    return std::nullopt;
  }
  std::size_t capacity_;
  std::deque<std::pair<ros::Time, A>> as_;
  std::deque<std::pair<ros::Time, B>> bs_;
  std::uint64_t dropped_a_ = 0;
};

/// A status entry for a frame that never reached the tracker: the stage and what was wrong.
inline rig_msgs::TrackingStatus rejectedStatus(const std_msgs::Header& image_header,
                                               const std::string& failure) {
  rig_msgs::TrackingStatus s;
  s.header = image_header;
  s.state = rig_msgs::TrackingStatus::LOST;
  s.state_name = "LOST";
  s.input_rejected = true;
  s.failure = failure;
  s.camera_frame = image_header.frame_id;
  s.camera_pose.orientation.w = 1.0;
  return s;
}

/// The mapper table (under `mapper/` of the graph's namespace), validated for a nominal camera;
/// the real intrinsics are checked with the first frame.
inline MapperConfig readMapperTable(rosparams::ParamReader& r, const ros::NodeHandle& nh) {
  const PinholeIntrinsics nominal{640, 480, 500, 500, 319.5, 239.5};
  return r.table<MapperConfig>(ros::NodeHandle(nh, "mapper"), mapperParams(), MapperConfig{},
                               [nominal](const MapperConfig& c) { return c.validate(nominal); });
}

/// A depth frame (depth/image + depth/camera_info) with the registration's status of the same
/// stamp: what the mapping nodelets work on.
struct TrackedFrame {
  sensor_msgs::ImageConstPtr image;
  sensor_msgs::CameraInfoConstPtr info;
  rig_msgs::TrackingStatusConstPtr status;
};

/// Subscribes both streams, pairs them by stamp (rejection entries of `status` have no frame
/// and are skipped) and hands the pairs to `process` on a FrameQueue worker.
class TrackedFrameInput {
 public:
  void start(ros::NodeHandle& nh, Mode mode, std::size_t sync_queue,
             std::function<void(const TrackedFrame&)> process, FrameQueueOptions options = {}) {
    pairs_ = std::make_unique<StampPairer<DepthPair, rig_msgs::TrackingStatusConstPtr>>(sync_queue);
    queue_ = std::make_unique<FrameQueue<TrackedFrame>>(mode, 100000, std::move(process), options);
    image_transport::ImageTransport it(nh);
    depth_sub_ = it.subscribeCamera("depth/image", 50, &TrackedFrameInput::onDepth, this);
    status_sub_ = nh.subscribe("status", 100, &TrackedFrameInput::onStatus, this);
  }
  void stop() {
    if (queue_) queue_->stop();
  }
  ~TrackedFrameInput() { stop(); }
  /// Live mode: pairs replaced by a newer one before the worker took them.
  std::uint64_t skipped() const { return queue_ ? queue_->skipped() : 0; }

 private:
  using DepthPair = std::pair<sensor_msgs::ImageConstPtr, sensor_msgs::CameraInfoConstPtr>;
  void onDepth(const sensor_msgs::ImageConstPtr& image,
               const sensor_msgs::CameraInfoConstPtr& info) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (auto p = pairs_->addA(image->header.stamp, {image, info}))
      queue_->push({p->first.first, p->first.second, p->second});
  }
  void onStatus(const rig_msgs::TrackingStatusConstPtr& s) {
    if (s->input_rejected) return;
    std::lock_guard<std::mutex> lock(mutex_);
    if (auto p = pairs_->addB(s->header.stamp, s))
      queue_->push({p->first.first, p->first.second, p->second});
  }
  std::mutex mutex_;
  std::unique_ptr<StampPairer<DepthPair, rig_msgs::TrackingStatusConstPtr>> pairs_;
  std::unique_ptr<FrameQueue<TrackedFrame>> queue_;
  image_transport::CameraSubscriber depth_sub_;
  ros::Subscriber status_sub_;
};

inline std::shared_ptr<GraphContext> graphContext(const std::string& ns) {
  static std::mutex mutex;
  static std::map<std::string, std::weak_ptr<GraphContext>> registry;
  std::lock_guard<std::mutex> lock(mutex);
  auto ctx = registry[ns].lock();
  if (!ctx) {
    ctx = std::make_shared<GraphContext>();
    registry[ns] = ctx;
  }
  return ctx;
}

}  // namespace graph
}  // namespace depth_track
