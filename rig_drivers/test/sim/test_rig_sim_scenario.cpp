// Scenario files: every committed scenario parses and matches the thesis; malformed ones name
// file, line and field.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "rig_drivers/sim/rig_sim_scenario.hpp"

#ifndef RIG_SOURCE_DIR
#error "RIG_SOURCE_DIR must name the rig_drivers folder"
#endif

namespace rig_drivers {
namespace {

// RIG_SOURCE_DIR is the rig_drivers package folder; scenarios live in the repository's config/.
const std::string kScenarios = std::string(RIG_SOURCE_DIR) + "/../config/scenarios";

std::string parseError(const std::string& text) {
  try {
    parseScenario(text, "bad.yaml");
  } catch (const ScenarioError& e) {
    return e.what();
  }
  return "";
}

TEST(RigSimScenario, AllCommittedScenariosParse) {
  const auto files = listScenarioFiles(kScenarios);
  // XTest1_05_Chair, RT1..RT6, Chair3, Room3, Hall1, Calibration_L515
  ASSERT_EQ(files.size(), 11u);
  for (const auto& f : files) {
    SCOPED_TRACE(f);
    const Scenario s = loadScenario(f);
    EXPECT_TRUE(s.validate().empty());
    EXPECT_EQ(f.substr(f.rfind('/') + 1), s.name + ".yaml");
  }
}

TEST(RigSimScenario, RealTimeRunsMatchTable54) {
  struct Row {
    const char* name;
    double set, achieved, duration;
    ServoAxis axis;
    double amp, freq;
    int frames;
  };
  const Row rows[] = {
      {"RT1", 200, 95, 12, ServoAxis::kNone, 0, 0, 360},
      {"RT2", 200, 95, 12, ServoAxis::kYaw, 10, 1 / 12.0, 360},
      {"RT3", 60, 42, 25, ServoAxis::kPitch, 20, 1 / 12.6, 750},
      {"RT4", 60, 42, 25, ServoAxis::kNone, 0, 0, 750},
      {"RT5", 200, 95, 12, ServoAxis::kYaw, 15, 1 / 24.0, 360},
      {"RT6", 200, 95, 12, ServoAxis::kPitch, 15, 1 / 24.0, 360},
  };
  for (const Row& r : rows) {
    SCOPED_TRACE(r.name);
    const Scenario s = loadScenario(kScenarios + "/" + r.name + ".yaml");
    EXPECT_EQ(s.rig, RigKind::kServoTrack);
    EXPECT_EQ(s.track.mode, 1);
    EXPECT_DOUBLE_EQ(s.track.set_speed_mm_s, r.set);
    EXPECT_DOUBLE_EQ(s.track.achieved_speed_mm_s, r.achieved);
    EXPECT_DOUBLE_EQ(s.track.duration_s, r.duration);
    EXPECT_EQ(s.track.servo_axis, r.axis);
    EXPECT_DOUBLE_EQ(s.track.amplitude_deg, r.amp);
    EXPECT_NEAR(s.track.frequency_hz, r.freq, 1e-9);  // written with 10 significant digits
    EXPECT_EQ(s.frameCount(), r.frames);
    // "In all cases the carriage traversed over 1 m of the track".
    EXPECT_GT(s.track.achieved_speed_mm_s * s.track.duration_s, 1000.0);
  }
}

TEST(RigSimScenario, XTestIsThreeStillFramesThenHundredTenMillimetreSteps) {
  const Scenario s = loadScenario(kScenarios + "/XTest1_05_Chair.yaml");
  EXPECT_EQ(s.track.mode, 2);
  EXPECT_EQ(s.track.still_frames, 3);
  EXPECT_EQ(s.track.steps, 100);
  EXPECT_DOUBLE_EQ(s.track.step_mm, 10.0);
  EXPECT_EQ(s.frameCount(), 103);
}

TEST(RigSimScenario, CalibrationRunStandsAtTheDistancesOfTable42) {
  const Scenario s = loadScenario(kScenarios + "/Calibration_L515.yaml");
  EXPECT_EQ(s.rig, RigKind::kTripod);
  EXPECT_EQ(s.scene, "calibration_target");
  const std::vector<double> table_4_2 = {0.56, 0.6, 0.76, 1.2,  1.47, 1.77,
                                         2.0,  2.2, 2.47, 2.75, 3.0};
  EXPECT_EQ(s.tripod.distances_m, table_4_2);
  // "A few seconds each, camera still": at least 1.5 s of frames at every distance.
  EXPECT_GE(s.tripod.hold_s * s.frame_rate_hz, 45.0);
  const double period = s.tripod.hold_s + s.tripod.move_s;
  for (std::size_t i = 0; i < table_4_2.size(); ++i) {
    SCOPED_TRACE(i);
    EXPECT_EQ(s.tripod.distanceAt(i * period), table_4_2[i]);
    EXPECT_EQ(s.tripod.distanceAt(i * period + s.tripod.hold_s), table_4_2[i]);
    if (i + 1 < table_4_2.size()) {
      const double mid = s.tripod.distanceAt(i * period + s.tripod.hold_s + 0.5 * s.tripod.move_s);
      EXPECT_NEAR(mid, 0.5 * (table_4_2[i] + table_4_2[i + 1]), 1e-12);  // smoothstep midpoint
    }
  }
  EXPECT_EQ(
      s.frameCount(),
      static_cast<int>(std::floor((11 * s.tripod.hold_s + 10 * s.tripod.move_s) * 30.0 + 1e-9)));
}

TEST(RigSimScenario, BadTripodRunsAreNamed) {
  const std::string head = "name: X\nrig: tripod\nscene: calibration_target\n";
  EXPECT_NE(parseError(head).find(": tripod: missing (needed for rig tripod)"), std::string::npos)
      << parseError(head);
  std::string e = parseError(head + "tripod:\n  distances_m: [0.6, 5.0]\n");
  EXPECT_NE(e.find("bad.yaml:5: tripod.distances_m: [1] must be 0.55..3.4 m (got 5)"),
            std::string::npos)
      << e;
  e = parseError(head + "tripod:\n  distances_m: [0.6, far]\n");
  EXPECT_NE(e.find("bad.yaml:5: tripod.distances_m[1]: cannot read 'far' as a number"),
            std::string::npos)
      << e;
  e = parseError(head + "tripod:\n  distances_m: 1.2\n");
  EXPECT_NE(e.find("tripod.distances_m: must be a list"), std::string::npos) << e;
  e = parseError(head + "tripod:\n  distances_m: [1.2]\n  hold_s: 0\n");
  EXPECT_NE(e.find("bad.yaml:6: tripod.hold_s: must be > 0"), std::string::npos) << e;
  e = parseError("name: X\nrig: tripod\nscene: chair_room\ntripod:\n  distances_m: [1.2]\n");
  EXPECT_NE(e.find("bad.yaml:3: scene: a tripod run stands before the calibration target"),
            std::string::npos)
      << e;
  e = parseError(head + "tripod:\n  distances_m: [1.2]\ntrack:\n  mode: 1\n");
  EXPECT_NE(e.find(": track: not allowed for rig tripod"), std::string::npos) << e;
  e = parseError("name: X\nrig: servotrack\ntrack:\n  mode: 1\ntripod:\n  hold_s: 1\n");
  EXPECT_NE(e.find(": tripod: not allowed for rig servotrack"), std::string::npos) << e;
}

TEST(RigSimScenario, SyntaxErrorNamesFileAndLine) {
  const std::string e = parseError("name: X\nrig: servotrack\ntrack: {mode: 1\n");
  EXPECT_NE(e.find("bad.yaml:"), std::string::npos) << e;
  EXPECT_NE(e.find("(syntax)"), std::string::npos) << e;
}

TEST(RigSimScenario, MistypedValueNamesLineAndField) {
  const std::string e =
      parseError("name: X\nrig: servotrack\ntrack:\n  mode: 1\n  duration_s: twelve\n");
  EXPECT_NE(e.find("bad.yaml:5: track.duration_s: cannot read 'twelve'"), std::string::npos) << e;
}

TEST(RigSimScenario, UnknownFieldIsNamed) {
  const std::string e = parseError("name: X\nrig: servotrack\ntrack:\n  mode: 2\n  stpes: 3\n");
  EXPECT_NE(e.find("bad.yaml:5: track.stpes: unknown field"), std::string::npos) << e;
}

TEST(RigSimScenario, OutOfRangeValueNamesLineAndField) {
  const std::string e = parseError(
      "name: X\nrig: servotrack\ntrack:\n  mode: 1\n  duration_s: 12\n  frames: 360\n"
      "  achieved_speed_mm_s: 95\n  servo_axis: pitch\n  amplitude_deg: 45\n  frequency_hz: 0.1\n");
  EXPECT_NE(e.find("bad.yaml:9: track.amplitude_deg: gimbal travel"), std::string::npos) << e;
}

TEST(RigSimScenario, FrameCountMustMatchDuration) {
  const std::string e =
      parseError("name: X\nrig: servotrack\ntrack:\n  mode: 1\n  duration_s: 12\n  frames: 300\n");
  EXPECT_NE(e.find("bad.yaml:6: track.frames"), std::string::npos) << e;
}

TEST(RigSimScenario, BadRigAndBadSegmentAreNamed) {
  EXPECT_NE(parseError("name: X\nrig: hovercraft\n").find("bad.yaml:2: rig: must be"),
            std::string::npos);
  const std::string e = parseError(
      "name: X\nrig: servotruck\ntruck:\n  segments:\n    - {duration_s: 1, throttle: 2}\n");
  EXPECT_NE(e.find("bad.yaml:5: truck.segments[0].throttle: must lie in -1..1"), std::string::npos)
      << e;
}

TEST(RigSimScenario, EmptyAndMissingFiles) {
  EXPECT_NE(parseError("").find("empty"), std::string::npos);
  EXPECT_THROW(loadScenario("/nonexistent/X.yaml"), ScenarioError);
}

}  // namespace
}  // namespace rig_drivers
