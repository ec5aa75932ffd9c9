#pragma once
/// Mode 2 step scripts (config/sequences/*.txt): parsing and validation before anything moves.
///
/// Format: one step per line; '#' starts a comment; blank lines are ignored; keywords carry their
/// unit in the name:
///   move_mm D        move the carriage by D millimetres (+ = away from the far sensor)
///   goto_mm P        move the carriage to P millimetres from the far sensor (absolute)
///   speed_mm_s V     profile speed for the following moves (mm/s, 0 = board default)
///   pitch_deg A      gimbal pitch demand (deg, absolute)
///   yaw_deg A        gimbal yaw demand (deg, absolute)
///   wait_ms T        settle without moving (ms)
///   frame            take one depth frame once the rig is still
///   repeat N ... end_repeat   the enclosed lines N times (may nest)
#include <cstddef>
#include <stdexcept>
#include <string>
#include <vector>

namespace rig_drivers {

/// A malformed script; line() is the 1-based line of the first problem (0 = whole file).
class StepScriptError : public std::runtime_error {
 public:
  StepScriptError(const std::string& what, int line) : std::runtime_error(what), line_(line) {}
  int line() const { return line_; }

 private:
  int line_;
};

/// Physical limits a script is checked against (defaults: ServoTrack, thesis ch. 4 / app. B).
struct StepLimits {
  double track_length_mm = 1200.0;  ///< usable carriage travel from the far sensor (mm)
  double max_speed_mm_s = 200.0;    ///< highest profile speed a script may request (mm/s)
  double max_pitch_deg = 30.0;      ///< gimbal pitch range is +-this (deg)
  double max_yaw_deg = 45.0;        ///< gimbal yaw range is +-this (deg)
  double max_wait_ms = 60000.0;     ///< longest single wait (ms)
  std::size_t max_steps = 100000;   ///< after expanding repeats
  /// Every problem with these limits (empty = valid).
  std::vector<std::string> validate() const;
};

enum class StepKind { kMove, kGoto, kSpeed, kPitch, kYaw, kWait, kFrame };

/// One expanded step. `value` is in the unit of its keyword (mm, mm/s, deg, ms; unused for frame).
struct Step {
  StepKind kind = StepKind::kFrame;
  double value = 0.0;
  int line = 0;  ///< source line (for messages while running)
};

struct StepScript {
  std::string name;  ///< file name or label used in messages
  std::vector<Step> steps;
  /// Number of frame steps (= depth frames a run of this script records).
  std::size_t frameCount() const;
  /// Number of steps that move the rig (move/goto/pitch/yaw).
  std::size_t motionCount() const;
};

/// Keyword of a step kind ("move_mm", ...).
const char* stepKeyword(StepKind kind);

/// Parses and validates a whole script; throws StepScriptError "name:line: problem" on the first
/// malformed line, so nothing is sent for a bad script. Pure, thread-safe.
StepScript parseStepScript(const std::string& text, const std::string& name,
                           const StepLimits& limits = StepLimits());

/// Reads and parses a script file; throws StepScriptError (line 0) when the file cannot be read.
StepScript loadStepScript(const std::string& path, const StepLimits& limits = StepLimits());

}  // namespace rig_drivers
