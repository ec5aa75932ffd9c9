#pragma once
/// Rig simulator scenarios (config/scenarios/*.yaml): what the rig does during one recorded run.
/// ROS-free.
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace rig_drivers {

/// Thrown for a scenario that cannot be used; the message names the file, the line (1-based,
/// when known) and the field, e.g. "RT1.yaml:7: track.duration_s: must be > 0 (got -3)".
class ScenarioError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// kTripod: no rig boards, the camera alone on a tripod (the camera calibration runs of thesis
/// §4.1.3).
enum class RigKind { kServoTrack, kServoTruck, kTripod };
enum class ServoAxis { kNone, kPitch, kYaw };

/// ServoTrack run: the carriage on the track with the pitch/yaw gimbal.
struct TrackScenario {
  int mode = 1;                   ///< 1 = continuous at 30 Hz, 2 = step sequence
  double start_position_m = 0.0;  ///< carriage position along the track at the start, m
  // mode 1 (thesis table 5.4)
  double set_speed_mm_s = 200.0;      ///< speed demanded of TrackDRV, mm/s
  double achieved_speed_mm_s = 95.0;  ///< speed the stepper actually reached, mm/s (simulated)
  double duration_s = 12.0;           ///< run time, s
  int frames = 360;                   ///< camera frames recorded (duration x frame rate)
  ServoAxis servo_axis = ServoAxis::kNone;  ///< gimbal axis driven by the sine input
  double amplitude_deg = 0.0;               ///< sine amplitude of the servo demand, degrees
  double frequency_hz = 0.0;                ///< sine frequency of the servo demand, Hz
  // mode 2 (step sequence)
  int still_frames = 3;           ///< frames taken before the first step
  int steps = 100;                ///< number of track steps, one frame after each
  double step_mm = 10.0;          ///< length of one step, mm
  double step_speed_mm_s = 60.0;  ///< cruise speed during a step, mm/s
  double settle_s = 0.4;          ///< wait after a step before the frame is taken, s
};

/// One segment of the RC inputs of a ServoTruck run (held constant over the segment).
struct TruckSegment {
  double duration_s = 0.0;  ///< s
  double throttle = 0.0;  ///< RC CH3 speed/direction, normalised -1 (full reverse) .. 1 (full fwd)
  double steering = 0.0;  ///< RC CH2 steering, normalised -1 (full left) .. 1 (full right)
};

/// ServoTruck run: RC inputs over time, starting at a pose on the floor.
struct TruckScenario {
  double start_x_m = 0.0;          ///< start position on the floor plane (world x), m
  double start_y_m = 0.0;          ///< start position on the floor plane (world y), m
  double start_heading_deg = 0.0;  ///< heading, degrees counter-clockwise from world +x
  std::vector<TruckSegment> segments;
  double duration() const;  ///< sum of the segment durations, s
};

/// Tripod run (camera calibration, thesis §4.1.3 and table 4.2): the camera stands still on the
/// calibration target's axis at each distance in turn and is carried to the next one in between,
/// recording throughout. The distance is from the camera to the target's face, along the view.
struct TripodScenario {
  std::vector<double> distances_m;  ///< stations, in the order visited, m
  double hold_s = 2.0;              ///< still time at each station, s
  double move_s = 0.5;              ///< carrying time between stations (camera moving), s
  double duration() const;          ///< whole run, s
  /// Camera distance to the target's face at time t_s from the start of the run (smooth moves
  /// between stations: no jump in speed at either end), m.
  double distanceAt(double t_s) const;
};

/// A complete scenario. Defaults are those of the ServoTrack runs of the thesis.
struct Scenario {
  std::string name;         ///< e.g. "RT1"; the bag is <name>.bag
  std::string description;  ///< one line, free text
  RigKind rig = RigKind::kServoTrack;
  std::string scene = "chair_room";  ///< chair_room | furnished_room | hall | calibration_target
  std::string noise = "l515";        ///< depth noise model: l515 | d435 | none
  double frame_rate_hz = 30.0;       ///< camera frame rate, Hz
  std::uint64_t seed = 1;            ///< seed of every random draw of the run
  TrackScenario track;
  TruckScenario truck;
  TripodScenario tripod;

  /// Every problem with this scenario (empty = valid); each names its field.
  std::vector<std::string> validate() const;
  /// Camera frames the run yields (mode 2: still_frames + steps).
  int frameCount() const;
  /// Length of the run in seconds (mode 2: an estimate from step time and settling).
  double durationS() const;
};

/// Parses a scenario from YAML text; `source` names the file in error messages. Throws
/// ScenarioError naming source, line and field for bad syntax, unknown or mistyped fields and
/// values that do not validate. Thread-safe.
Scenario parseScenario(const std::string& yaml_text, const std::string& source);

/// Reads and parses a scenario file (see parseScenario). Throws ScenarioError if unreadable.
Scenario loadScenario(const std::string& path);

/// All scenario files (*.yaml) in a folder, sorted by name. Throws ScenarioError if unreadable.
std::vector<std::string> listScenarioFiles(const std::string& folder);

const char* toString(RigKind rig);
const char* toString(ServoAxis axis);

}  // namespace rig_drivers
