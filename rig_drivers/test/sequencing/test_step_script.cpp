#include <gtest/gtest.h>

#include <string>

#include "rig_drivers/sequencing/step_script.hpp"

using namespace rig_drivers;

namespace {
int errorLine(const std::string& text) {
  try {
    parseStepScript(text, "t.txt");
  } catch (const StepScriptError& e) {
    return e.line();
  }
  return -1;
}
std::string errorText(const std::string& text) {
  try {
    parseStepScript(text, "t.txt");
  } catch (const StepScriptError& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST(StepScript, ParsesStepsUnitsCommentsAndRepeats) {
  const auto s = parseStepScript(
      "# header\n\nspeed_mm_s 50\npitch_deg -5.5  # tilt down\nframe\nrepeat 3\n move_mm 10\n"
      " wait_ms 200\n frame\nend_repeat\ngoto_mm 0\n",
      "t.txt");
  ASSERT_EQ(s.steps.size(), 2u + 1u + 3u * 3u + 1u);
  EXPECT_EQ(s.steps[0].kind, StepKind::kSpeed);
  EXPECT_DOUBLE_EQ(s.steps[0].value, 50.0);
  EXPECT_EQ(s.steps[1].kind, StepKind::kPitch);
  EXPECT_DOUBLE_EQ(s.steps[1].value, -5.5);
  EXPECT_EQ(s.steps[1].line, 4);
  EXPECT_EQ(s.steps[3].kind, StepKind::kMove);
  EXPECT_EQ(s.steps[3].line, 7);
  EXPECT_EQ(s.steps[6].line, 7);  // repeated body keeps its source line
  EXPECT_EQ(s.frameCount(), 4u);
  EXPECT_EQ(s.motionCount(), 1u + 3u + 1u);
  EXPECT_EQ(s.steps.back().kind, StepKind::kGoto);
}

TEST(StepScript, NestedRepeatsMultiply) {
  const auto s =
      parseStepScript("repeat 2\nrepeat 3\nframe\nend_repeat\nmove_mm 1\nend_repeat\n", "n");
  EXPECT_EQ(s.frameCount(), 6u);
  EXPECT_EQ(s.motionCount(), 2u);
}

TEST(StepScript, MalformedLinesAreRejectedWithTheirLineNumber) {
  EXPECT_EQ(errorLine("frame\nmove 10\n"), 2);                 // unknown keyword
  EXPECT_EQ(errorLine("frame\n\n# c\nmove_mm\n"), 4);          // missing value
  EXPECT_EQ(errorLine("move_mm 10cm\n"), 1);                   // unit not in the keyword
  EXPECT_EQ(errorLine("move_mm 1 2\n"), 1);                    // extra argument
  EXPECT_EQ(errorLine("frame 3\n"), 1);                        // frame takes none
  EXPECT_EQ(errorLine("move_mm nan\n"), 1);                    // not finite
  EXPECT_EQ(errorLine("frame\npitch_deg 31\n"), 2);            // beyond +-30 deg
  EXPECT_EQ(errorLine("yaw_deg -46\n"), 1);                    // beyond +-45 deg
  EXPECT_EQ(errorLine("goto_mm 1300\n"), 1);                   // beyond the track
  EXPECT_EQ(errorLine("goto_mm -1\n"), 1);                     // before the far sensor
  EXPECT_EQ(errorLine("move_mm 2000\n"), 1);                   // longer than the track
  EXPECT_EQ(errorLine("wait_ms -5\n"), 1);                     // negative wait
  EXPECT_EQ(errorLine("speed_mm_s 500\n"), 1);                 // too fast
  EXPECT_EQ(errorLine("frame\nrepeat 2\nframe\n"), 2);         // never closed
  EXPECT_EQ(errorLine("frame\nend_repeat\n"), 2);              // unmatched end
  EXPECT_EQ(errorLine("repeat 0\nframe\nend_repeat\n"), 1);    // bad count
  EXPECT_EQ(errorLine("repeat 2.5\nframe\nend_repeat\n"), 1);  // bad count
  EXPECT_EQ(errorLine("repeat 2\nend_repeat\n"), 2);           // empty block
  EXPECT_EQ(errorLine("# only a comment\n"), 0);               // no steps at all
  const std::string msg = errorText("frame\nframe\nmove 10\n");
  EXPECT_NE(msg.find("t.txt:3:"), std::string::npos) << msg;
  EXPECT_NE(msg.find("move_mm"), std::string::npos) << msg;  // suggests the valid keywords
}

TEST(StepScript, ExpansionIsBounded) {
  StepLimits lim;
  lim.max_steps = 1000;
  EXPECT_THROW(
      parseStepScript("repeat 1000\nrepeat 1000\nframe\nend_repeat\nend_repeat\n", "b", lim),
      StepScriptError);
}

TEST(StepScript, MissingFileNamesThePath) {
  try {
    loadStepScript("/nonexistent/seq.txt");
    FAIL();
  } catch (const StepScriptError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/seq.txt"), std::string::npos);
    EXPECT_EQ(e.line(), 0);
  }
}

TEST(StepScript, ShippedChairSequenceIsThreeStillFramesThenHundredStepsOfTenMm) {
  const auto s =
      loadStepScript(std::string(RIG_SOURCE_DIR) + "/../config/sequences/xtest1_05_chair.txt");
  EXPECT_EQ(s.frameCount(), 103u);
  double travel_mm = 0;
  int moves = 0;
  std::size_t frames_before_first_move = 0;
  for (const auto& st : s.steps) {
    if (st.kind == StepKind::kMove) {
      EXPECT_DOUBLE_EQ(st.value, 10.0);
      travel_mm += st.value;
      ++moves;
    }
    if (st.kind == StepKind::kFrame && moves == 0) ++frames_before_first_move;
  }
  EXPECT_EQ(moves, 100);
  EXPECT_DOUBLE_EQ(travel_mm, 1000.0);
  EXPECT_EQ(frames_before_first_move, 3u);
  // Every move is followed by exactly one frame before the next move.
  int frames_since_move = -1;
  for (const auto& st : s.steps) {
    if (st.kind == StepKind::kMove) {
      if (frames_since_move >= 0) {
        EXPECT_EQ(frames_since_move, 1);
      }
      frames_since_move = 0;
    } else if (st.kind == StepKind::kFrame && frames_since_move >= 0) {
      ++frames_since_move;
    }
  }
  EXPECT_EQ(frames_since_move, 1);
}
