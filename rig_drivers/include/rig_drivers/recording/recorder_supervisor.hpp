#pragma once
/// Keeps a recorder (rosbag record) running into the rig's bag folder (ROS-free): creates the
/// folder, starts the recorder only when the folder is writable and has its reserve free, reads
/// the recorder's error lines, and when it stops on its own (disk full, folder removed, no
/// permission, a crash) says so by name, with the bags it closed and any it left unindexed (one
/// without a message in it is removed), then starts it again once the folder allows. Drivers and
/// the tracking graph never depend on it.
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "rig_drivers/recording/bag_folder.hpp"
#include "rig_drivers/recording/child_process.hpp"

namespace rig_drivers {

/// Settings of the rig's recorder (the bag_recorder node's parameters, config/drivers.yaml).
struct RecorderConfig {
  std::string bag_dir;                  ///< folder of the bags; made when missing
  std::string bag_prefix = "rig";       ///< bags are <prefix>_<date>_<n>.bag
  std::vector<std::string> topics;      ///< what to record
  int split_size_mb = 1024;             ///< a new bag after this many MiB
  std::string compression = "lz4";      ///< none | lz4 | bz2
  int min_free_mb = 1024;               ///< reserve: the recorder stops below it, restarts above it
  double restart_period_s = 5.0;        ///< first wait before starting again, s (doubles while
                                        ///< starts fail without closing a bag)
  double max_restart_period_s = 300.0;  ///< cap of that wait, s
  double check_period_s = 1.0;          ///< folder checks (removed, free space), s
  /// The recorder's command before its options (argv[0] found on PATH).
  std::vector<std::string> recorder = {"rosrun", "rosbag", "record"};
  /// Every problem with these settings (empty = valid).
  std::vector<std::string> validate() const;
};

/// The recorder's full command line for `c`.
std::vector<std::string> recordCommand(const RecorderConfig& c);

/// How the supervisor stands.
enum class RecorderState {
  kWaiting,    ///< not recording: the folder is not usable yet, or a restart is due later
  kRecording,  ///< the recorder runs
  kStopping,   ///< asked to stop
  kStopped,    ///< stopped on request
};

/// One reportable event; level 0 info, 1 warning, 2 error.
struct RecorderEvent {
  int level = 0;
  std::string message;
};

/// What diagnostics show.
struct RecorderStatus {
  RecorderState state = RecorderState::kWaiting;
  int level = 0;        ///< 0 OK, 1 WARN (little room left), 2 ERROR (not recording)
  std::string summary;  ///< one line: where it records, or why it does not
  std::string active_bag;
  std::uint64_t active_bytes = 0;
  std::size_t closed_bags = 0;  ///< closed by this supervisor's recorders
  std::uint64_t closed_bytes = 0;
  std::size_t unindexed_bags = 0;  ///< .active files left by a recorder that stopped
  std::optional<std::uint64_t> free_bytes;
  unsigned starts = 0;     ///< recorder processes started
  std::string last_error;  ///< the recorder's latest error line
};

class RecorderSupervisor {
 public:
  using EventHandler = std::function<void(const RecorderEvent& event)>;
  using OutputHandler = std::function<void(const std::string& line)>;

  /// Throws std::invalid_argument on an invalid config. Starts nothing yet.
  RecorderSupervisor(RecorderConfig config, EventHandler on_event, OutputHandler on_output);
  ~RecorderSupervisor();

  /// One step at time now_s (a monotonic clock, s): forwards the recorder's stderr lines,
  /// notices its exit and a removed folder, and (re)starts it when due. Call ~10 times a second.
  void step(double now_s);
  /// Stops the recorder with SIGINT (it closes its bag) and waits up to timeout_s for it; then
  /// SIGTERM. Returns when it is gone.
  void stop(double timeout_s);
  RecorderStatus status() const;
  const RecorderConfig& config() const { return config_; }

 private:
  void forwardOutput();
  void tryStart(double now_s);
  void onExit(int wait_status, double now_s);
  void checkFolder(double now_s);
  void report(int level, const std::string& message);

  RecorderConfig config_;
  EventHandler on_event_;
  OutputHandler on_output_;
  ChildProcess child_;
  RecorderState state_ = RecorderState::kWaiting;
  std::vector<std::string> known_before_;  ///< bags in the folder before this run (not ours)
  std::optional<FolderId> folder_;
  std::string folder_problem_;  ///< why the folder cannot be recorded into (empty = it can)
  std::string stopped_reason_;  ///< why the recorder stopped on its own (until it runs again)
  std::string first_error_;     ///< the current recorder's first error line: the cause
  std::vector<std::string> reported_open_;  ///< .active files already named in a report
  std::string removed_note_;  ///< set when the folder vanished under a running recorder
  double next_start_s_ = -1e300;
  double next_check_s_ = -1e300;
  double period_s_;
  std::size_t closed_at_start_ = 0;  ///< closed bags when the current recorder started
  unsigned starts_ = 0;
};

}  // namespace rig_drivers
