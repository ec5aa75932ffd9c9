// depth_track/registration: owns the tracker state (the cell odometry stage). `cells` in; out: tf
// odom -> base_link (through the static base_link -> camera transform from tf, waited for and
// never assumed), `odom` (nav_msgs/Odometry: child_frame_id, twist, the odometry's covariance
// with the motion prior's variance along directions the view did not fix), `path` (capped),
// `status` (rig_msgs/TrackingStatus per frame). Optional motion prior from tf (~guess_frame). While
// LOST, relocalises against the map's ray cast at the held pose: the fusion nodelet's map when it
// runs in this manager, else its ~render_depth service (another process or machine; answers waited
// for at most ~render_timeout). Services: ~reset, ~reset_to_pose, ~save_trajectory (TUM, odom and
// map poses), ~pause, ~resume. With tracker/auto_noise the odometry starts with the settings of
// pca_reduce's noise calibration (`cells/noise`), which pca_reduce sends before the first cells:
// the first frame waits for it.
#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <nav_msgs/Path.h>
#include <nodelet/nodelet.h>
#include <rig_msgs/NoiseCalibration.h>
#include <rig_msgs/RenderDepth.h>
#include <rig_msgs/ResetToPose.h>
#include <rig_msgs/SaveFile.h>
#include <rig_msgs/TrackingStatus.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>
#include <pluginlib/class_list_macros.hpp>

#include <condition_variable>
#include <deque>
#include <filesystem>
#include <sstream>

#include "depth_track/core/cell_odometry.hpp"
#include "depth_track/core/cell_reducer.hpp"
#include "depth_track/core/imu_prior.hpp"
#include "depth_track/core/map/mapper_params.hpp"
#include "depth_track/core/noise_model.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/core/tum_io.hpp"
#include "depth_track/ros/conversions.hpp"
#include "depth_track/ros/params.hpp"
#include "graph_common.hpp"
#include "graph_diagnostics.hpp"
#include "graph_reconfigure.hpp"

namespace depth_track {
namespace graph {

class RegistrationNodelet : public nodelet::Nodelet {
 public:
  ~RegistrationNodelet() override {
    if (queue_) queue_->stop();
  }

 private:
  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    rosparams::ParamReader r(pnh, "registration");
    const Mode mode = parseMode(r.getString("mode"));
    mode_ = mode;
    odom_frame_ = r.getString("odom_frame");
    base_frame_ = r.getString("base_frame");
    map_frame_ = r.getString("map_frame");
    guess_frame_ = r.getString("guess_frame");
    guess_child_frame_ = r.getString("guess_child_frame");
    if (guess_child_frame_.empty()) guess_child_frame_ = base_frame_;
    guess_timeout_s_ = r.getDouble("guess_timeout");
    use_imu_ = r.getBool("imu");
    // ~imu_<name>: the filter's table (imu_prior.hpp), checked by its validate().
    imu_config_ = r.table<ImuPriorConfig>(
        pnh, imuPriorParams(), ImuPriorConfig{},
        [](const ImuPriorConfig& c) { return c.validate(); }, "imu_");
    imu_timeout_s_ = r.getDouble("imu_timeout");
    static_tf_timeout_s_ = r.getDouble("static_tf_timeout");
    publish_tf_ = r.getBool("publish_tf");
    path_length_ = r.getInt("path_length");
    lost_pos_var_ = r.getDouble("lost_position_var");
    lost_rot_var_ = r.getDouble("lost_rotation_var");
    relocalise_ = r.getBool("relocalise");
    relocalise_every_ = r.getInt("relocalise_every");
    const std::string render_service = r.getString("render_service");
    render_timeout_s_ = r.getDouble("render_timeout");
    trajectory_path_ = r.getString("trajectory_path");
    FrameQueueOptions queue_options;
    queue_options.live_depth = r.getInt("live_queue");
    const std::string mount_text = r.getString("camera_mount");
    const std::string mount_frame = r.getString("camera_frame");
    std::optional<Eigen::Isometry3d> mount;
    if (!mount_text.empty()) {
      std::istringstream in(mount_text);
      double v[7];
      bool ok = true;
      for (double& x : v) ok = ok && static_cast<bool>(in >> x);
      geometry_msgs::Pose p;
      p.position.x = v[0], p.position.y = v[1], p.position.z = v[2];
      p.orientation.x = v[3], p.orientation.y = v[4], p.orientation.z = v[5],
      p.orientation.w = v[6];
      try {
        if (!ok) throw std::invalid_argument("needs 7 numbers");
        mount = conv::fromPoseMsg(p);
      } catch (const std::exception& e) {
        r.problem(pnh.resolveName("camera_mount") + " = '" + mount_text +
                  "': 'x y z qx qy qz qw' (m, unit quaternion) expected: " + e.what());
      }
    }
    config_ = r.table<TrackerConfig>(
        ros::NodeHandle(nh, "tracker"), trackerParams(), TrackerConfig{},
        [](const TrackerConfig& c) {
          return c.validate(PinholeIntrinsics{640, 480, 500, 500, 319.5, 239.5});
        });
    // The ray-cast range of a relocalisation is the mapper's (its virtual images).
    mapper_config_ = readMapperTable(r, nh);
    r.finish();
    ctx_ = graphContext(nh.getNamespace());
    render_call_ =
        std::make_unique<TimedServiceCall<rig_msgs::RenderDepth>>(nh.resolveName(render_service));
    diag_.start(nh, pnh, getName(), readDiagnosticThresholds(nh), {true, true, true, true});
    method_name_ = toString(config_.registration.method);
    fm_from_start_ = config_.registration.method == RegistrationMethod::kCellSearch;
    diag_.add("tracking state",
              [this](diagnostic_updater::DiagnosticStatusWrapper& d) { stateTask(d); });
    reconf_.bindTable("registration", "tracker", trackerParams(),
                      [](TrackerConfig& c) -> TrackerConfig& { return c; });
    reconf_.start(pnh, "registration", config_, TrackerConfig{}, [this](const TrackerConfig& c) {
      auto p = c.validate(PinholeIntrinsics{640, 480, 500, 500, 319.5, 239.5});
      if (c.registration.method == RegistrationMethod::kCellSearch && !fm_from_start_ &&
          !cells_have_fm_)
        p.push_back(
            "cell_search needs the cells' FM (Foerstner-Moonen) terms, which pca_reduce does not "
            "compute now (start the graph with method:=cell_search, or pca_reduce/fm_terms true)");
      return p;
    });

    if (mount) {  // the launch file's mount, for everyone on /tf_static
      geometry_msgs::TransformStamped t;
      t.header.stamp = ros::Time::now();
      t.header.frame_id = base_frame_;
      t.child_frame_id = mount_frame;
      t.transform = conv::toTransformMsg(*mount);
      static_tf_pub_.sendTransform(t);
    }
    tf_buffer_ = std::make_unique<tf2_ros::Buffer>(ros::Duration(30.0));
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_, nh);
    odom_pub_ = nh.advertise<nav_msgs::Odometry>("odom", 50);
    path_pub_ = nh.advertise<nav_msgs::Path>("path", 2);
    status_pub_ = nh.advertise<rig_msgs::TrackingStatus>("status", 50);
    reset_srv_ = pnh.advertiseService("reset", &RegistrationNodelet::onReset, this);
    reset_pose_srv_ =
        pnh.advertiseService("reset_to_pose", &RegistrationNodelet::onResetToPose, this);
    save_srv_ = pnh.advertiseService("save_trajectory", &RegistrationNodelet::onSave, this);
    pause_srv_ = pnh.advertiseService("pause", &RegistrationNodelet::onPause, this);
    resume_srv_ = pnh.advertiseService("resume", &RegistrationNodelet::onResume, this);
    queue_ = std::make_unique<FrameQueue<sensor_msgs::PointCloud2ConstPtr>>(
        mode, 100000, [this](const sensor_msgs::PointCloud2ConstPtr& m) { process(m); },
        queue_options);
    info_sub_ = nh.subscribe("depth/camera_info", 5, &RegistrationNodelet::onInfo, this);
    cells_sub_ = nh.subscribe("cells", 50, &RegistrationNodelet::onCells, this);
    if (config_.auto_noise)
      noise_sub_ = nh.subscribe("cells/noise", 1, &RegistrationNodelet::onNoise, this);
    if (use_imu_)
      imu_sub_ = nh.subscribe("imu", 2000, &RegistrationNodelet::onImu, this,
                              ros::TransportHints().tcpNoDelay());
    NODELET_INFO("registration: %s, %s -> %s, method %s%s",
                 mode == Mode::kReplay ? "replay" : "live", odom_frame_.c_str(),
                 base_frame_.c_str(), toString(config_.registration.method).c_str(),
                 !guess_frame_.empty()
                     ? (", prior from tf " + guess_frame_ + " -> " + guess_child_frame_).c_str()
                 : use_imu_ ? (", prior from the IMU on " + imu_sub_.getTopic()).c_str()
                            : "");
  }

  void onInfo(const sensor_msgs::CameraInfoConstPtr& info) {
    std::lock_guard<std::mutex> lock(info_mutex_);
    info_ = info;
  }
  /// IMU readings, buffered until the frame they reach is tracked.
  void onImu(const sensor_msgs::ImuConstPtr& m) {
    const ImuSample s = conv::imuSampleFromMsg(*m);
    std::lock_guard<std::mutex> lock(imu_mutex_);
    if (imu_frame_.empty()) imu_frame_ = m->header.frame_id;
    imu_last_stamp_s_ = s.stamp_s;
    imu_buffer_.push_back(s);
    if (imu_buffer_.size() > 20000) imu_buffer_.pop_front();  // 100 s at 200 Hz: nobody reads
  }

  void onCells(const sensor_msgs::PointCloud2ConstPtr& m) {
    diag_.input();
    queue_->push(m);
  }

  /// TRACKING is OK, RELOCALISING a warning, LOST (or nothing tracked yet) an error.
  void stateTask(diagnostic_updater::DiagnosticStatusWrapper& d) {
    std::lock_guard<std::mutex> lock(last_mutex_);
    d.add("method", method_name_);
    if (!last_) {
      d.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no frame yet");
      return;
    }
    const rig_msgs::TrackingStatus& s = *last_;
    const std::uint8_t level = s.state == rig_msgs::TrackingStatus::TRACKING && !s.input_rejected
                                   ? diagnostic_msgs::DiagnosticStatus::OK
                               : s.state == rig_msgs::TrackingStatus::RELOCALISING
                                   ? diagnostic_msgs::DiagnosticStatus::WARN
                                   : diagnostic_msgs::DiagnosticStatus::ERROR;
    d.summary(level, s.state_name + (s.failure.empty() ? "" : ": " + s.failure));
    d.add("state", s.state_name);
    d.add("frame", s.frame);
    d.addf("stamp (s)", "%.3f", s.header.stamp.toSec());
    d.add("cells", s.cells);
    d.add("matches", s.matches);
    d.add("fm_matches", s.fm_matches);
    d.add("iterations", s.iterations);
    d.addf("icp error (mm)", "%.3f", s.error_rms_m * 1e3);
    d.add("held directions (degenerate view)", s.degenerate_directions);
    d.add("unconfirmed directions (basin probe)", s.unconfirmed_directions);
    d.add("frames the deep returns fixed (basin_deep_floor)", deep_kept_frames_seen_);
    d.add("frames lost in a row", lost_frames_in_a_row_);
  }

  void onNoise(const rig_msgs::NoiseCalibrationConstPtr& m) {
    std::lock_guard<std::mutex> lock(noise_mutex_);
    noise_msg_ = m;
    noise_cv_.notify_all();
  }

  /// The odometry's config for its first frame: with auto_noise, the one pca_reduce calibrated
  /// (it publishes the calibration before the first cells; over separate processes it may still
  /// be on its way, hence the wait). Without it within 10 s the parameters stay as given.
  CellOdometryConfig startConfig() {
    CellOdometryConfig c = config_.odometryConfig();
    if (!config_.auto_noise) return c;
    rig_msgs::NoiseCalibrationConstPtr m;
    {
      std::unique_lock<std::mutex> lock(noise_mutex_);
      noise_cv_.wait_for(lock, std::chrono::seconds(10), [this] { return noise_msg_ != nullptr; });
      m = noise_msg_;
    }
    if (!m) {
      NODELET_ERROR(
          "registration: auto_noise is on but no calibration came on %s within 10 s "
          "(is pca_reduce running?): tracking with the parameters as given",
          noise_sub_.getTopic().c_str());
      return c;
    }
    calibration_ = conv::fromMsg(*m);
    calibration_->applyTo(&c);
    NODELET_INFO("registration: odometry starts with the noise calibration of %.3f s: %s",
                 calibration_->stamp_s, calibration_->summary.c_str());
    return c;
  }

  // ---- per frame ---------------------------------------------------------------------------

  rig_msgs::TrackingStatus newStatus(const std_msgs::Header& h) const {
    rig_msgs::TrackingStatus s;
    s.header.stamp = h.stamp;
    s.header.frame_id = odom_frame_;
    s.camera_frame = h.frame_id;
    s.method = toString(config_.registration.method);
    s.frame = frames_;
    s.epoch = epoch_;
    s.camera_pose.orientation.w = 1.0;
    return s;
  }
  void publishStatus(rig_msgs::TrackingStatus& s) {
    s.frames_rejected = rejected_;
    s.frames_dropped = ctx_->skipped_ingest + ctx_->skipped_reduce + ctx_->skipped_registration;
    status_pub_.publish(s);
    if (!s.input_rejected) {
      diag_.processed(s.ms_register);
      diag_.latency(s.latency_ms);
    }
    diag_.counts(queue_->skipped(), rejected_);
    std::lock_guard<std::mutex> lock(last_mutex_);
    last_ = s;
    lost_frames_in_a_row_ = lost_frames_;
    deep_kept_frames_seen_ = deep_kept_frames_;
  }
  void reject(const std_msgs::Header& h, const std::string& why) {
    ++rejected_;
    NODELET_ERROR_THROTTLE(1.0, "registration: frame at %.3f rejected: %s", h.stamp.toSec(),
                           why.c_str());
    rig_msgs::TrackingStatus s = rejectedStatus(h, "registration: " + why);
    s.header.frame_id = odom_frame_;
    s.method = toString(config_.registration.method);
    s.frame = frames_;
    s.epoch = epoch_;
    if (odometry_) {
      s.state = static_cast<std::uint8_t>(odometry_->state());
      s.state_name = toString(odometry_->state());
    }
    publishStatus(s);
  }

  /// base_frame -> camera from tf (static); false while it is missing, with a throttled warning.
  bool cameraMount(const std::string& camera_frame, const ros::Time& stamp) {
    if (have_mount_ && camera_frame == camera_frame_) return true;
    try {
      const auto t = tf_buffer_->lookupTransform(base_frame_, camera_frame, ros::Time(0));
      T_base_C_ = conv::fromTransformMsg(t.transform);
      camera_frame_ = camera_frame;
      have_mount_ = true;
      NODELET_INFO("registration: camera mount %s -> %s from tf: t = (%.3f, %.3f, %.3f) m",
                   base_frame_.c_str(), camera_frame.c_str(), T_base_C_.translation().x(),
                   T_base_C_.translation().y(), T_base_C_.translation().z());
      return true;
    } catch (const std::exception& e) {
      NODELET_WARN_THROTTLE(static_tf_timeout_s_,
                            "registration: waiting for the static transform %s -> %s (from "
                            "/tf_static, the robot description or the launch file's camera_mount); "
                            "frames are not tracked until it comes (%s)",
                            base_frame_.c_str(), camera_frame.c_str(), e.what());
      (void)stamp;
      return false;
    }
  }

  /// The IMU prior's guess for the frame at `stamp` (camera frame `camera_frame`): readings up
  /// to the stamp handed over (waiting up to imu_timeout for one at or after it), the prior
  /// built once the IMU's mount is in tf. Problems go to the log, throttled; the frame then
  /// takes the constant-velocity guess.
  std::optional<ImuMotionPrior::Guess> imuPrior(const ros::Time& stamp,
                                                const std::string& camera_frame) {
    const double t = stamp.toSec();
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(imu_timeout_s_);
    std::deque<ImuSample> take;
    std::string frame;
    for (;;) {
      {
        std::lock_guard<std::mutex> lock(imu_mutex_);
        frame = imu_frame_;
        // A reading at or after the stamp has come; or none for a second (an unplugged IMU, or
        // none yet): the frame goes on at once.
        if (imu_last_stamp_s_ >= t || imu_last_stamp_s_ < t - 1.0 ||
            ros::WallTime::now() >= deadline) {
          while (!imu_buffer_.empty() && imu_buffer_.front().stamp_s <= t) {
            take.push_back(imu_buffer_.front());
            imu_buffer_.pop_front();
          }
          break;
        }
      }
      ros::WallDuration(0.002).sleep();
    }
    if (frame.empty()) {
      NODELET_WARN_THROTTLE(5.0, "registration: ~imu is on but no reading came on %s",
                            imu_sub_.getTopic().c_str());
      return std::nullopt;
    }
    if (!imu_) {
      try {
        const auto tf = tf_buffer_->lookupTransform(camera_frame, frame, ros::Time(0));
        ImuPriorConfig c = imu_config_;
        c.T_C_I = conv::fromTransformMsg(tf.transform);
        imu_.emplace(c);
        NODELET_INFO("registration: IMU %s at (%.3f, %.3f, %.3f) m in %s", frame.c_str(),
                     c.T_C_I.translation().x(), c.T_C_I.translation().y(),
                     c.T_C_I.translation().z(), camera_frame.c_str());
      } catch (const std::exception& e) {
        NODELET_WARN_THROTTLE(5.0,
                              "registration: waiting for the IMU's mount %s -> %s in tf (%s); "
                              "constant velocity meanwhile",
                              camera_frame.c_str(), frame.c_str(), e.what());
        return std::nullopt;
      }
    }
    for (const ImuSample& s : take) {
      try {
        imu_->add(s);
      } catch (const std::exception& e) {
        NODELET_WARN_THROTTLE(5.0, "registration: IMU reading left out: %s", e.what());
      }
    }
    return imu_->guess(t);
  }

  std::optional<Eigen::Isometry3d> prior(const ros::Time& stamp) {
    if (guess_frame_.empty()) return std::nullopt;
    try {
      // Waited for in wall time: tf2's own timeout runs on the bag's clock, which stops with it.
      const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(guess_timeout_s_);
      while (!tf_buffer_->canTransform(guess_frame_, guess_child_frame_, stamp) &&
             ros::WallTime::now() < deadline)
        ros::WallDuration(0.002).sleep();
      const auto t = tf_buffer_->lookupTransform(guess_frame_, guess_child_frame_, stamp);
      const Eigen::Isometry3d T_g_base = conv::fromTransformMsg(t.transform);
      std::optional<Eigen::Isometry3d> out;
      if (have_guess_)  // camera motion T_Cprev_Ccur = T_C_base T_base_prev_cur T_base_C
        out = T_base_C_.inverse() * (T_g_base_prev_.inverse() * T_g_base) * T_base_C_;
      T_g_base_prev_ = T_g_base;
      have_guess_ = true;
      return out;
    } catch (const std::exception& e) {
      NODELET_WARN_THROTTLE(5.0,
                            "registration: no motion prior from tf %s -> %s at %.3f (%s); "
                            "constant velocity instead",
                            guess_frame_.c_str(), guess_child_frame_.c_str(), stamp.toSec(),
                            e.what());
      have_guess_ = false;
      return std::nullopt;
    }
  }

  void process(const sensor_msgs::PointCloud2ConstPtr& m) {
    ctx_->skipped_registration = queue_->skipped();
    const std_msgs::Header& h = m->header;
    std::lock_guard<std::mutex> lock(state_mutex_);
    try {
      if (auto c = reconf_.takePending()) applyConfig(*c);  // between frames, never within one
      switch (guard_.check(h.stamp)) {
        case StampGuard::Verdict::kReject:
          reject(h, "stamp " + std::to_string(h.stamp.toSec()) + " s does not increase (last " +
                        std::to_string(guard_.lastStamp().toSec()) + " s)");
          return;
        case StampGuard::Verdict::kReset:
          NODELET_WARN(
              "registration: time jumped back to %.3f s (a looped or restarted bag): the "
              "graph resets (tracking, path, map)",
              h.stamp.toSec());
          // The camera mount is static and stays; tf2's listener clears the rest itself.
          resetLocked(std::nullopt);
          guard_.check(h.stamp);
          break;
        case StampGuard::Verdict::kNext:
          break;
      }
      if (paused_) return;
      sensor_msgs::CameraInfoConstPtr info;
      {
        std::lock_guard<std::mutex> l(info_mutex_);
        info = info_;
      }
      if (!info) {
        reject(h, "no camera_info yet on " + info_sub_.getTopic());
        return;
      }
      const PinholeIntrinsics K = conv::intrinsicsFromCameraInfo(*info);
      if (!cameraMount(h.frame_id, h.stamp)) {
        reject(h, "waiting for tf " + base_frame_ + " -> " + h.frame_id);
        return;
      }
      const std::shared_ptr<const CellCloud> cells = conv::cellsFromCloud(*m, K.width, K.height);
      cells_have_fm_ = !cells->cells.empty() && !cells->cells.front().cov_inv_sqrt.isZero();
      if (!odometry_ || K.width != K_.width || K.height != K_.height) {
        K_ = K;
        odometry_ = std::make_unique<CellOdometry>(K, startConfig(), T_base_C_);
        // Ray-cast images are reduced like the camera's frames (the calibrated pooling).
        PcaConfig pca = config_.reducerConfig();
        if (calibration_) calibration_->applyTo(&pca);
        relocaliser_ = std::make_unique<CellReducer>(K, pca);
      }
      ++frames_;
      const double prev_stamp = prev_stamp_;
      prev_stamp_ = h.stamp.toSec();
      const auto t0 = std::chrono::steady_clock::now();
      auto guess = prior(h.stamp);
      std::optional<InertialHold> hold;
      if (!guess && use_imu_ && guess_frame_.empty())
        if (const auto g = imuPrior(h.stamp, h.frame_id)) {
          guess = g->T_Cprev_Ccur;
          hold = g->hold;
        }
      FrameStatus st = odometry_->track(cells, guess, hold);
      rig_msgs::TrackingStatus s = newStatus(h);
      s.prior_used = guess.has_value();
      if (!st.tracked) {
        ++lost_frames_;
        if (relocalise_ && lost_frames_ % relocalise_every_ == 0) {
          const double now_stamp = prev_stamp_;
          prev_stamp_ = prev_stamp;  // the frame before this one must be in the map
          tryRelocalise(h, *info, &st);
          prev_stamp_ = now_stamp;
        }
      } else {
        lost_frames_ = 0;
      }
      const double ms_register =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (imu_) {
        try {
          imu_->update(h.stamp.toSec(), odometry_->pose(), trackedPoseCovariance(st));
          if (!imu_->started())
            NODELET_WARN_THROTTLE(5.0, "registration: the IMU prior has not started: %s",
                                  imu_->reason().c_str());
        } catch (const std::exception& e) {
          NODELET_WARN_THROTTLE(5.0, "registration: IMU prior: %s", e.what());
        }
      }
      publishFrame(h, st, ms_register, s);
    } catch (const std::exception& e) {
      reject(h, e.what());
    }
  }

  /// A reconfigured tracker table: the odometry keeps pose, velocity and keyframe.
  /// auto_noise's calibration stays for the parameters the request left as they were.
  void applyConfig(const TrackerConfig& c) {
    CellOdometryConfig oc = c.odometryConfig();
    if (calibration_) calibration_->applyToUnchanged(config_.odometryConfig(), &oc);
    if (odometry_) odometry_->setConfig(oc);
    if (relocaliser_ && c.registration.method != config_.registration.method) {
      PcaConfig pca = c.reducerConfig();
      if (calibration_) calibration_->applyTo(&pca);  // no reduction parameter is reconfigurable
      relocaliser_ = std::make_unique<CellReducer>(K_, pca);
    }
    config_ = c;
    std::lock_guard<std::mutex> lock(last_mutex_);
    method_name_ = toString(c.registration.method);
  }

  /// Registers the lost frame onto the map ray-cast at the held pose (wider search).
  void tryRelocalise(const std_msgs::Header& h, const sensor_msgs::CameraInfo& info,
                     FrameStatus* st) {
    const Eigen::Isometry3d T_odom_C = odometry_->pose();
    std::string why;
    const DepthImage virt =
        ctx_->map.fusionAttached() ? castHere(T_odom_C, &why) : castRemote(h, info, T_odom_C, &why);
    if (virt.empty()) {  // the status shows it (publishFrame takes st's failure)
      st->failure += "; relocalisation: no map to relocalise against: " + why;
      return;
    }
    const auto ref = relocaliser_->reduce(virt, h.stamp.toSec(), h.frame_id);
    const RelocalisationResult rr = odometry_->relocalise(*ref, T_odom_C, T_odom_C);
    if (rr.accepted) {
      NODELET_INFO("registration: relocalised against the map at %.3f s (%s)", h.stamp.toSec(),
                   rr.reason.c_str());
      st->tracked = true;
      st->T_W_C = rr.T_W_C;
      st->matches = rr.registration.matches;
      st->error_rms_m = rr.registration.error_rms_m;
      st->normal_matrix = rr.registration.normal_matrix;
      st->covariance = Matrix6d::Zero();  // the failed frame's; the normal matrix decides
      st->degenerate_directions = 0;
      st->T_W_Cref = T_odom_C;
      st->failure = "relocalised: " + rr.reason;
    } else {
      st->failure += "; relocalisation: " + rr.reason;
    }
    st->state = odometry_->state();
  }

  /// The map of the fusion nodelet in this manager, cast at the held pose.
  DepthImage castHere(const Eigen::Isometry3d& T_odom_C, std::string* why) {
    // Replay: the offline order, the map holds every frame before this one (fusion runs behind).
    if (mode_ == Mode::kReplay && prev_stamp_ > 0.0 &&
        !ctx_->map.waitFused(prev_stamp_, kReplayMapWait_s))
      NODELET_WARN(
          "registration: the map did not catch up with frame %.3f within %.0f s; "
          "relocalising against what it holds",
          prev_stamp_, kReplayMapWait_s);
    const Eigen::Isometry3d T_map_odom = ctx_->map.latestCorrection();
    const std::shared_ptr<VoxelMap> map = ctx_->map.map();
    if (!map || map->occupiedCount() == 0) {
      *why = "the map is empty";
      return DepthImage();
    }
    return reloc_caster_
        .over(map, K_,
              [&](const VoxelMap& m) {
                return std::make_unique<MapRayCaster>(m, K_, mapper_config_.range);
              })
        .cast(T_map_odom * T_odom_C);
  }

  /// The map of a fusion nodelet in another process, cast there (its ~render_depth) at the held
  /// pose in the odom frame, which it turns into the map frame with its own correction.
  DepthImage castRemote(const std_msgs::Header& h, const sensor_msgs::CameraInfo& info,
                        const Eigen::Isometry3d& T_odom_C, std::string* why) {
    rig_msgs::RenderDepth::Request req;
    req.header.stamp = h.stamp;
    req.header.frame_id = odom_frame_;
    req.pose = conv::toPoseMsg(T_odom_C);
    req.camera_info = info;
    if (mode_ == Mode::kReplay && prev_stamp_ > 0.0) {  // the offline order, as castHere
      req.fused_upto = ros::Time(prev_stamp_);
      req.wait_s = kReplayMapWait_s;
    }
    const auto res = render_call_->call(req, req.wait_s + render_timeout_s_, why);
    if (!res) return DepthImage();
    if (!res->success) {
      *why = res->message;
      return DepthImage();
    }
    if (res->message.find("caught up") != std::string::npos)
      NODELET_WARN("registration: %s", res->message.c_str());
    return conv::depthFromMsg(res->depth, 1.0, DepthRange{0.0, 1e9});
  }

  void publishFrame(const std_msgs::Header& h, const FrameStatus& st, double ms_register,
                    rig_msgs::TrackingStatus& s) {
    const Eigen::Isometry3d T_odom_C = st.T_W_C;
    const Eigen::Isometry3d T_odom_base = T_odom_C * T_base_C_.inverse();
    // Odometry: pose, twist in the body frame from the last frame's motion, covariance.
    nav_msgs::Odometry odom;
    odom.header.stamp = h.stamp;
    odom.header.frame_id = odom_frame_;
    odom.child_frame_id = base_frame_;
    odom.pose.pose = conv::toPoseMsg(T_odom_base);
    // The odometry's own covariance (the motion prior's variance along held directions) when
    // its registration decided the pose; a relocalised frame's from its normal matrix.
    const bool registered = st.tracked && st.matches > 0;
    const std::array<double, 36> cov =
        registered && !st.covariance.isZero()
            ? conv::poseCovarianceOfIncrement(st.covariance, st.T_W_Cref.rotation(),
                                              T_odom_C.translation(), T_odom_base.translation())
        : registered ? conv::poseCovariance(st.normal_matrix, std::max(st.error_rms_m, 1e-4),
                                            st.T_W_Cref, T_odom_base.translation())
                     : conv::diagonalCovariance(lost_pos_var_, lost_rot_var_);
    std::copy(cov.begin(), cov.end(), odom.pose.covariance.begin());
    if (have_last_ && h.stamp > last_stamp_) {
      const double dt = (h.stamp - last_stamp_).toSec();
      const Eigen::Isometry3d d = last_T_odom_base_.inverse() * T_odom_base;
      const Eigen::AngleAxisd aa(d.rotation());
      const Eigen::Vector3d w = aa.angle() * aa.axis() / dt, v = d.translation() / dt;
      odom.twist.twist.linear.x = v.x(), odom.twist.twist.linear.y = v.y(),
      odom.twist.twist.linear.z = v.z();
      odom.twist.twist.angular.x = w.x(), odom.twist.twist.angular.y = w.y(),
      odom.twist.twist.angular.z = w.z();
      for (int i = 0; i < 36; ++i)
        odom.twist.covariance[i] = 2.0 * odom.pose.covariance[i] / (dt * dt);
    }
    last_T_odom_base_ = T_odom_base;
    last_stamp_ = h.stamp;
    have_last_ = true;
    if (publish_tf_) {
      geometry_msgs::TransformStamped t;
      t.header = odom.header;
      t.child_frame_id = base_frame_;
      t.transform = conv::toTransformMsg(T_odom_base);
      tf_pub_.sendTransform(t);
    }
    odom_pub_.publish(odom);
    // Path and trajectory.
    geometry_msgs::PoseStamped ps;
    ps.header = odom.header;
    ps.pose = odom.pose.pose;
    path_.header = odom.header;
    path_.poses.push_back(ps);
    while (static_cast<int>(path_.poses.size()) > path_length_)
      path_.poses.erase(path_.poses.begin());
    if (path_pub_.getNumSubscribers() > 0) path_pub_.publish(path_);
    trajectory_.push_back({h.stamp.toSec(), T_odom_C});
    if (trajectory_.size() > 200000) trajectory_.pop_front();
    // Status.
    s.state = static_cast<std::uint8_t>(st.state);
    s.state_name = toString(st.state);
    s.tracked = st.tracked;
    s.failure = st.failure;
    s.new_keyframe = st.new_keyframe;
    s.camera_pose = conv::toPoseMsg(T_odom_C);
    s.cells = st.cells;
    s.candidates = st.candidates;
    s.matches = st.matches;
    s.fm_matches = st.fm_matches;
    s.iterations = st.iterations;
    s.error_rms_m = st.error_rms_m;
    s.degenerate_directions = st.degenerate_directions;
    s.weakest_information = st.weakest_information;
    s.unconfirmed_directions = st.unconfirmed_directions;
    deep_kept_frames_ += st.basin_deep_kept;
    s.ms_register = ms_register;
    const auto front = ctx_->times.get(h.stamp.toSec());
    s.ms_prefilter = front.first;
    s.ms_reduce = front.second;
    s.latency_ms = (ros::Time::now() - h.stamp).toSec() * 1e3;
    publishStatus(s);
  }

  // ---- services ----------------------------------------------------------------------------

  void resetLocked(const std::optional<Eigen::Isometry3d>& T_odom_base) {
    if (odometry_) {
      if (T_odom_base)
        odometry_->reset(*T_odom_base * T_base_C_);
      else
        odometry_->reset();
    }
    if (!T_odom_base) ctx_->map.clear(++epoch_);  // a new start: the old map does not apply
    path_.poses.clear();
    trajectory_.clear();
    imu_.reset();  // starts again from the next still window
    frames_ = 0;
    lost_frames_ = 0;
    prev_stamp_ = -1.0;
    have_last_ = false;
    have_guess_ = false;
    guard_.clear();
  }
  bool onReset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    std::lock_guard<std::mutex> lock(state_mutex_);
    queue_->clear();
    resetLocked(std::nullopt);
    res.success = true;
    res.message = "tracking, path, trajectory and map reset; next frame starts at the origin";
    NODELET_INFO("registration: %s", res.message.c_str());
    return true;
  }
  bool onResetToPose(rig_msgs::ResetToPose::Request& req, rig_msgs::ResetToPose::Response& res) {
    std::lock_guard<std::mutex> lock(state_mutex_);
    try {
      const Eigen::Isometry3d T = conv::fromPoseMsg(req.pose);
      if (!have_mount_) throw std::runtime_error("the camera mount is not known yet (no tf)");
      if (!odometry_) throw std::runtime_error("no frame was tracked yet");
      resetLocked(T);
      res.success = true;
      res.message = "tracking restarts at the given pose of " + base_frame_ + " in " + odom_frame_;
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("reset_to_pose refused: ") + e.what();
    }
    NODELET_INFO("registration: %s", res.message.c_str());
    return true;
  }
  bool onSave(rig_msgs::SaveFile::Request& req, rig_msgs::SaveFile::Response& res) {
    Trajectory odom;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      res.path = req.path.empty() ? trajectory_path_ : req.path;
      odom.assign(trajectory_.begin(), trajectory_.end());
    }
    // In replay the loop closure may still be deciding the last frames (it runs behind the
    // odometry): their map poses wait for its decision on the last one, without holding the
    // odometry's state.
    if (mode_ == Mode::kReplay && !odom.empty() &&
        !ctx_->map.correctionFor(odom.back().stamp_s, true, kSaveWaitS))
      NODELET_WARN(
          "registration: save_trajectory: loop closure did not decide the frame at %.3f within "
          "%.0f s; the last frames' map poses use the decision before it",
          odom.back().stamp_s, kSaveWaitS);
    try {
      Trajectory map;
      for (const auto& p : odom) {
        const auto X = ctx_->map.correctionFor(p.stamp_s, false, 0.0);
        map.push_back({p.stamp_s, X.value_or(Eigen::Isometry3d::Identity()) * p.T_W_C});
      }
      writeTumTrajectory(res.path, odom,
                         "depth_track registration: T_" + odom_frame_ + "_" + camera_frame_);
      const std::filesystem::path p(res.path);
      const std::string map_path =
          (p.parent_path() / (p.stem().string() + "_map" + p.extension().string())).string();
      writeTumTrajectory(map_path, map,
                         "depth_track registration: T_" + map_frame_ + "_" + camera_frame_);
      res.success = true;
      res.message = std::to_string(odom.size()) + " poses of " + camera_frame_ + " in " +
                    odom_frame_ + " -> " + res.path + ", in " + map_frame_ + " -> " + map_path;
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("save_trajectory failed: ") + e.what();
    }
    NODELET_INFO("registration: %s", res.message.c_str());
    return true;
  }
  bool onPause(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    paused_ = true;
    res.success = true;
    res.message = "paused: frames are ignored until ~resume";
    return true;
  }
  bool onResume(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    paused_ = false;
    res.success = true;
    res.message = "resumed";
    return true;
  }

  Mode mode_ = Mode::kLive;
  static constexpr double kSaveWaitS = 10.0;  ///< save_trajectory's wait for loop closure, s
  double prev_stamp_ = -1.0;  ///< stamp of the last frame tracked or lost (not rejected)
  std::string odom_frame_, base_frame_, map_frame_, guess_frame_, guess_child_frame_, camera_frame_,
      trajectory_path_;
  double guess_timeout_s_ = 0.05, static_tf_timeout_s_ = 2.0, lost_pos_var_ = 1.0,
         lost_rot_var_ = 0.1;
  bool publish_tf_ = true, relocalise_ = true;
  int path_length_ = 2000, relocalise_every_ = 3;
  /// Replay: how long a relocalisation waits for the map to hold every earlier frame.
  static constexpr double kReplayMapWait_s = 10.0;
  double render_timeout_s_ = 0.5;
  std::unique_ptr<TimedServiceCall<rig_msgs::RenderDepth>> render_call_;
  TrackerConfig config_;
  MapperConfig mapper_config_;
  std::shared_ptr<GraphContext> ctx_;

  std::mutex state_mutex_;  // odometry, path, trajectory (worker thread vs services)
  std::unique_ptr<CellOdometry> odometry_;
  std::unique_ptr<CellReducer> relocaliser_;
  MapStage<MapRayCaster> reloc_caster_;  // the virtual view of a relocalisation (same manager)
  PinholeIntrinsics K_;
  Eigen::Isometry3d T_base_C_ = Eigen::Isometry3d::Identity();
  bool have_mount_ = false;
  Eigen::Isometry3d T_g_base_prev_ = Eigen::Isometry3d::Identity();
  bool have_guess_ = false;
  // ~imu: the camera's IMU as motion prior (built once its mount is in tf).
  bool use_imu_ = false;
  ImuPriorConfig imu_config_;
  double imu_timeout_s_ = 0.05;
  ros::Subscriber imu_sub_;
  std::mutex imu_mutex_;
  std::string imu_frame_;
  std::deque<ImuSample> imu_buffer_;
  double imu_last_stamp_s_ = -1e300;  // the latest reading's stamp (the buffer is emptied)
  std::optional<ImuMotionPrior> imu_;
  StampGuard guard_;
  std::atomic<bool> paused_{false};
  std::uint32_t frames_ = 0, rejected_ = 0, epoch_ = 0;
  int lost_frames_ = 0;
  Eigen::Isometry3d last_T_odom_base_ = Eigen::Isometry3d::Identity();
  ros::Time last_stamp_;
  bool have_last_ = false;
  nav_msgs::Path path_;
  std::deque<StampedPose> trajectory_;

  std::mutex info_mutex_;
  sensor_msgs::CameraInfoConstPtr info_;
  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  tf2_ros::TransformBroadcaster tf_pub_;
  tf2_ros::StaticTransformBroadcaster static_tf_pub_;
  ros::Subscriber info_sub_, cells_sub_, noise_sub_;
  std::mutex noise_mutex_;
  std::condition_variable noise_cv_;
  rig_msgs::NoiseCalibrationConstPtr noise_msg_;  ///< the latest from cells/noise
  std::optional<NoiseCalibration> calibration_;   ///< the one the odometry started with
  ros::Publisher odom_pub_, path_pub_, status_pub_;
  ros::ServiceServer reset_srv_, reset_pose_srv_, save_srv_, pause_srv_, resume_srv_;
  std::mutex last_mutex_;  // the diagnostics' view of the last frame
  std::optional<rig_msgs::TrackingStatus> last_;
  std::string method_name_;
  int lost_frames_in_a_row_ = 0;
  long deep_kept_frames_seen_ = 0;  ///< deep_kept_frames_ as of last_ (under last_mutex_)
  long deep_kept_frames_ = 0;       ///< frames FrameStatus::basin_deep_kept, since the start
  std::atomic<bool> cells_have_fm_{false};  ///< the last cells carry the FM terms (cell_search)
  bool fm_from_start_ = false;  ///< started as cell_search: pca_reduce computes the FM terms
  StageDiagnostics diag_;
  RuntimeParams<TrackerConfig> reconf_;
  std::unique_ptr<FrameQueue<sensor_msgs::PointCloud2ConstPtr>> queue_;
};

}  // namespace graph
}  // namespace depth_track

PLUGINLIB_EXPORT_CLASS(depth_track::graph::RegistrationNodelet, nodelet::Nodelet)
