// Scenario files: every committed scenario parses and matches the thesis; malformed ones name
// file, line and field.
#include <gtest/gtest.h>

#include <string>

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
  ASSERT_EQ(files.size(), 10u);  // XTest1_05_Chair, RT1..RT6, Chair3, Room3, Hall1
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
