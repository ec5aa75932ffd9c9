#pragma once
// The graph's diagnostics (diagnostic_updater on /diagnostics), shared by the five nodelets so
// each adds only what is its own: input rate (FrequencyStatus against the camera's rate),
// processing time, frames dropped / rejected and, for the registration, stamp-to-publish
// latency; every nodelet adds its state task (tracking state, map size, last correction). The
// thresholds are the `diagnostics` block of config/tracking.yaml (one table, params.cpp).
// Updates run on a wall timer: on a bag's clock, which stops with the bag, a ROS timer would
// stop reporting exactly when the input stops.
#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/update_functions.h>
#include <ros/ros.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "depth_track/core/running_stats.hpp"
#include "depth_track/ros/params.hpp"

namespace depth_track {
namespace graph {

/// WARN / ERROR thresholds of the diagnostics (units in the names).
struct DiagnosticThresholds {
  double period_s = 1.0;
  double expected_rate_hz = 30.0;
  double rate_tolerance = 0.2;
  int rate_window = 5;
  double time_warn_ms = 33.0, time_error_ms = 100.0;
  double latency_warn_ms = 30.0, latency_error_ms = 100.0;
  double drop_error_fraction = 0.5;
  int loop_reject_warn = 10;
};

/// The `diagnostics` block under the graph's namespace, validated (throws ParamError).
inline DiagnosticThresholds readDiagnosticThresholds(const ros::NodeHandle& nh) {
  rosparams::ParamReader r(ros::NodeHandle(nh, "diagnostics"), "diagnostics");
  DiagnosticThresholds t;
  t.period_s = r.getDouble("period");
  t.expected_rate_hz = r.getDouble("expected_rate");
  t.rate_tolerance = r.getDouble("rate_tolerance");
  t.rate_window = r.getInt("rate_window");
  t.time_warn_ms = r.getDouble("time_warn");
  t.time_error_ms = r.getDouble("time_error");
  t.latency_warn_ms = r.getDouble("latency_warn");
  t.latency_error_ms = r.getDouble("latency_error");
  t.drop_error_fraction = r.getDouble("drop_error_fraction");
  t.loop_reject_warn = r.getInt("loop_reject_warn");
  if (t.time_error_ms < t.time_warn_ms)
    r.problem(nh.resolveName("diagnostics/time_error") + " must not be below time_warn");
  if (t.latency_error_ms < t.latency_warn_ms)
    r.problem(nh.resolveName("diagnostics/latency_error") + " must not be below latency_warn");
  r.finish();
  return t;
}

/// One nodelet's diagnostic updater with the common tasks. Thread-safe: the frame callbacks
/// report from any thread, the updater runs on its own wall timer.
class StageDiagnostics {
 public:
  struct Options {
    bool rate = true;      ///< input rate (FrequencyStatus)
    bool time = true;      ///< processing time per frame
    bool drops = true;     ///< frames dropped (live mode) and rejected
    bool latency = false;  ///< stamp-to-publish latency
  };

  /// `name` is the nodelet's (getName()); status names become "<name>: <task>".
  void start(ros::NodeHandle& nh, ros::NodeHandle& pnh, const std::string& name,
             const DiagnosticThresholds& t, Options o) {
    t_ = t;
    min_rate_ = max_rate_ = t.expected_rate_hz;
    updater_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, name);
    updater_->setHardwareID("depth_track graph " + nh.getNamespace());
    if (o.rate) {
      rate_ = std::make_unique<diagnostic_updater::FrequencyStatus>(
          diagnostic_updater::FrequencyStatusParam(&min_rate_, &max_rate_, t.rate_tolerance,
                                                   t.rate_window),
          "input rate");
      updater_->add(*rate_);
    }
    if (o.time)
      updater_->add("processing time",
                    [this](diagnostic_updater::DiagnosticStatusWrapper& s) { timeTask(s); });
    if (o.drops)
      updater_->add("frames dropped",
                    [this](diagnostic_updater::DiagnosticStatusWrapper& s) { dropTask(s); });
    if (o.latency)
      updater_->add("latency",
                    [this](diagnostic_updater::DiagnosticStatusWrapper& s) { latencyTask(s); });
    timer_ = nh.createWallTimer(ros::WallDuration(t.period_s),
                                [this](const ros::WallTimerEvent&) { updater_->force_update(); });
  }

  /// A frame arrived.
  void input() {
    if (rate_) rate_->tick();
    std::lock_guard<std::mutex> lock(mutex_);
    ++inputs_;
  }
  /// One frame's processing took `ms` of wall time.
  void processed(double ms) {
    std::lock_guard<std::mutex> lock(mutex_);
    times_ms_.add(ms);
  }
  /// One frame's stamp-to-publish latency.
  void latency(double ms) {
    std::lock_guard<std::mutex> lock(mutex_);
    latencies_ms_.add(ms);
  }
  /// Running totals of frames skipped (live mode) and rejected (bad input).
  void counts(std::uint64_t dropped, std::uint64_t rejected) {
    std::lock_guard<std::mutex> lock(mutex_);
    dropped_ = dropped;
    rejected_ = rejected;
  }
  /// Adds a nodelet-specific task, run on each update.
  template <class F>
  void add(const std::string& task, F&& f) {
    updater_->add(task, std::forward<F>(f));
  }
  const DiagnosticThresholds& thresholds() const { return t_; }

 private:
  /// The period's statistics, leaving `samples` empty for the next period.
  RunningStats take(RunningStats& samples) {
    std::lock_guard<std::mutex> lock(mutex_);
    RunningStats v = samples;
    samples.clear();
    return v;
  }

  void timeTask(diagnostic_updater::DiagnosticStatusWrapper& s) {
    const RunningStats v = take(times_ms_);
    if (v.count() == 0) {
      s.summary(diagnostic_msgs::DiagnosticStatus::OK, "no frame processed in the last period");
      return;
    }
    const double mean = v.mean(), median = v.median(), p95 = v.p95();
    if (mean > t_.time_error_ms)
      s.summaryf(diagnostic_msgs::DiagnosticStatus::ERROR, "%.1f ms per frame (> %.0f ms)", mean,
                 t_.time_error_ms);
    else if (mean > t_.time_warn_ms)
      s.summaryf(diagnostic_msgs::DiagnosticStatus::WARN,
                 "%.1f ms per frame (> %.0f ms: live mode must skip frames)", mean,
                 t_.time_warn_ms);
    else
      s.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "%.1f ms per frame", mean);
    s.add("frames", v.count());
    s.addf("mean (ms)", "%.2f", mean);
    s.addf("median (ms)", "%.2f", median);
    s.addf("p95 (ms)", "%.2f", p95);
    s.addf("max (ms)", "%.2f", v.max());
  }

  void dropTask(diagnostic_updater::DiagnosticStatusWrapper& s) {
    std::lock_guard<std::mutex> lock(mutex_);
    const std::uint64_t dropped = dropped_ - std::min(dropped_, last_dropped_);
    const std::uint64_t rejected = rejected_ - std::min(rejected_, last_rejected_);
    const std::uint64_t inputs = inputs_ - std::min(inputs_, last_inputs_);
    last_dropped_ = dropped_, last_rejected_ = rejected_, last_inputs_ = inputs_;
    if (dropped > t_.drop_error_fraction * std::max<std::uint64_t>(inputs, 1))
      s.summaryf(diagnostic_msgs::DiagnosticStatus::ERROR,
                 "%llu of %llu frames dropped in the last period (processing too slow)",
                 static_cast<unsigned long long>(dropped), static_cast<unsigned long long>(inputs));
    else if (dropped > 0)
      s.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "%llu frames dropped in the last period",
                 static_cast<unsigned long long>(dropped));
    else if (rejected > 0)
      s.summaryf(diagnostic_msgs::DiagnosticStatus::WARN,
                 "%llu frames rejected in the last period (bad input, see the log and status)",
                 static_cast<unsigned long long>(rejected));
    else
      s.summary(diagnostic_msgs::DiagnosticStatus::OK, "none");
    s.add("dropped in period", dropped);
    s.add("rejected in period", rejected);
    s.add("dropped total", dropped_);
    s.add("rejected total", rejected_);
  }

  void latencyTask(diagnostic_updater::DiagnosticStatusWrapper& s) {
    const RunningStats v = take(latencies_ms_);
    if (v.count() == 0) {
      s.summary(diagnostic_msgs::DiagnosticStatus::OK, "no frame published in the last period");
      return;
    }
    const double median = v.median(), p95 = v.p95();
    if (median > t_.latency_error_ms)
      s.summaryf(diagnostic_msgs::DiagnosticStatus::ERROR, "median %.1f ms (> %.0f ms)", median,
                 t_.latency_error_ms);
    else if (p95 > t_.latency_warn_ms)
      s.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "p95 %.1f ms (> %.0f ms)", p95,
                 t_.latency_warn_ms);
    else
      s.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "median %.1f ms, p95 %.1f ms", median, p95);
    s.add("frames", v.count());
    s.addf("median (ms)", "%.2f", median);
    s.addf("p95 (ms)", "%.2f", p95);
    s.addf("max (ms)", "%.2f", v.max());
  }

  DiagnosticThresholds t_;
  double min_rate_ = 30.0, max_rate_ = 30.0;  // FrequencyStatus keeps pointers to these
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  std::unique_ptr<diagnostic_updater::FrequencyStatus> rate_;
  ros::WallTimer timer_;
  std::mutex mutex_;
  // Per period (cleared by each update); the window holds far more than a period's frames.
  RunningStats times_ms_, latencies_ms_;
  std::uint64_t inputs_ = 0, dropped_ = 0, rejected_ = 0;
  std::uint64_t last_inputs_ = 0, last_dropped_ = 0, last_rejected_ = 0;
};

}  // namespace graph
}  // namespace depth_track
