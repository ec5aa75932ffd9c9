#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "depth_track/core/angles.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

using namespace depth_track;
using namespace depth_track::sim;

namespace {
constexpr double kPoseTol = 1e-9;  // poses are computed in closed form (double rounding only)

double fractionValid(const DepthImage& d) {
  return static_cast<double>(d.countValid()) / static_cast<double>(d.data.size());
}
}  // namespace

TEST(RenderedRuns, UnknownNameListsKnownRuns) {
  try {
    makeRun("xtest9");
    FAIL() << "unknown run accepted";
  } catch (const std::invalid_argument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("xtest9"), std::string::npos) << msg;
    for (const auto& k : knownRuns()) EXPECT_NE(msg.find(k), std::string::npos) << msg;
  }
}

TEST(RenderedRuns, XTest1ChairStepsOneMetreTowardsTheChair) {
  const RenderedRun run = makeRun("xtest1_05_chair");
  ASSERT_EQ(run.size(), 103u);
  ASSERT_EQ(run.T_W_C.size(), run.size());
  ASSERT_EQ(run.rig.size(), run.size());
  EXPECT_TRUE(run.on_track);
  EXPECT_EQ(run.intrinsics.width, 640);
  EXPECT_EQ(run.intrinsics.fx, 458.0);
  EXPECT_EQ(run.intrinsics.cx, 320.0);
  for (std::size_t i = 1; i < run.size(); ++i)
    EXPECT_NEAR(run.stamps_s[i] - run.stamps_s[i - 1], 1.0 / 30.0, 1e-12);
  for (std::size_t i = 1; i < 3; ++i) EXPECT_TRUE(run.T_W_C[i].isApprox(run.T_W_C[0], kPoseTol));
  for (std::size_t i = 3; i < run.size(); ++i) {
    const Eigen::Vector3d step = run.T_W_C[i].translation() - run.T_W_C[i - 1].translation();
    EXPECT_NEAR((step - Eigen::Vector3d(0.010, 0, 0)).norm(), 0.0, kPoseTol) << i;
    EXPECT_NEAR((run.T_W_C[i].linear() - run.T_W_C[0].linear()).norm(), 0.0, kPoseTol);
  }
  EXPECT_NEAR(run.rig.back().track_pos_m, 1.0, 1e-12);

  // Start: back wall 3.2 m ahead (a wall pixel above the furniture), chair back 2.16 m ahead
  // (a pixel on the chair's top rail, 0.11 m above the camera at 2.16 m).
  const DepthImage first = run.renderFrame(0, NoiseConfig::forModel(NoiseModel::kNone), 0);
  EXPECT_NEAR(first.at(320, 60), 3.2, 1e-5);
  const int v_rail = static_cast<int>(std::lround(240 - 458.0 * 0.11 / 2.14));
  EXPECT_NEAR(first.at(320, v_rail), 2.14, 1e-5);
  EXPECT_GT(fractionValid(first), 0.97);
  const DepthImage last =
      run.renderFrame(run.size() - 1, NoiseConfig::forModel(NoiseModel::kNone), 0);
  EXPECT_NEAR(last.at(320, 60), 2.2, 1e-5);
  EXPECT_GT(fractionValid(last), 0.97);
}

TEST(RenderedRuns, ChairStillNeverMoves) {
  const RenderedRun run = makeRun("chair_still");
  ASSERT_EQ(run.size(), 90u);
  const RenderedRun xtest = makeRun("xtest1_05_chair");
  for (const auto& T : run.T_W_C) EXPECT_TRUE(T.isApprox(xtest.T_W_C.front(), kPoseTol));
  EXPECT_NEAR(run.stamps_s.back(), 89.0 / 30.0, 1e-12);
}

TEST(RenderedRuns, Rt3PitchSinusoidAndTravel) {
  const RenderedRun run = makeRun("rt3");
  ASSERT_EQ(run.size(), 750u);
  double max_pitch = -1.0, min_pitch = 1.0;
  for (const auto& s : run.rig) {
    max_pitch = std::max(max_pitch, s.pitch_rad);
    min_pitch = std::min(min_pitch, s.pitch_rad);
    EXPECT_EQ(s.yaw_rad, 0.0);
  }
  // 30 Hz samples of a 12.6 s period: the peak is sampled within 1/60 s, cos error < 0.02 %.
  EXPECT_NEAR(max_pitch, 20.0 * kDegToRad, 0.01 * kDegToRad);
  EXPECT_NEAR(min_pitch, -20.0 * kDegToRad, 0.01 * kDegToRad);
  // Quarter period (3.15 s = frame 94.5): near the positive peak, camera nose up.
  EXPECT_GT(run.rig[95].pitch_rad, 19.9 * kDegToRad);
  EXPECT_GT(run.T_W_C[95].linear().col(2).z(), std::sin(19.9 * kDegToRad));
  EXPECT_NEAR(run.rig.back().track_pos_m, 0.042 * 749.0 / 30.0, 1e-12);
  // Even fully pitched the camera sees mostly surfaces within range.
  for (std::size_t i : {std::size_t{95}, std::size_t{284}, std::size_t{749}}) {
    const DepthImage d = run.renderFrame(i, NoiseConfig::forModel(NoiseModel::kNone), 0);
    EXPECT_GT(fractionValid(d), 0.8) << "frame " << i;
  }
}

TEST(RenderedRuns, RealTimeTableCases) {
  struct Case {
    const char* name;
    std::size_t frames;
    double speed_mps, pitch_deg, yaw_deg;
  };
  for (const Case& c : {Case{"rt1", 360, 0.095, 0, 0}, Case{"rt2", 360, 0.095, 0, 10},
                        Case{"rt4", 750, 0.042, 0, 0}, Case{"rt5", 360, 0.095, 0, 15},
                        Case{"rt6", 360, 0.095, 15, 0}}) {
    const RenderedRun run = makeRun(c.name);
    ASSERT_EQ(run.size(), c.frames) << c.name;
    double pmax = 0, ymax = 0;
    for (const auto& s : run.rig) {
      pmax = std::max(pmax, std::abs(s.pitch_rad));
      ymax = std::max(ymax, std::abs(s.yaw_rad));
    }
    // Slow sinusoids (1/12 or 1/24 Hz) sampled at 30 Hz reach their peak within 0.1 %.
    EXPECT_NEAR(pmax, c.pitch_deg * kDegToRad, 0.001 * c.pitch_deg * kDegToRad + 1e-12) << c.name;
    EXPECT_NEAR(ymax, c.yaw_deg * kDegToRad, 0.001 * c.yaw_deg * kDegToRad + 1e-12) << c.name;
    // Every table 5.4 run covers about a metre of track.
    const double travel = run.rig.back().track_pos_m - run.rig.front().track_pos_m;
    EXPECT_NEAR(travel, c.speed_mps * (c.frames - 1) / 30.0, 1e-12) << c.name;
    EXPECT_GT(travel, 1.0) << c.name;
  }
}

TEST(RenderedRuns, Room3CirclesTwiceAndSeesTheRoom) {
  const RenderedRun run = makeRun("room3");
  EXPECT_FALSE(run.on_track);
  ASSERT_GT(run.size(), 800u);
  // Two full laps: back at the start pose (the last frame is within one frame period of it).
  const double step = 0.30 / 30.0;
  EXPECT_LT((run.T_W_C.back().translation() - run.T_W_C.front().translation()).norm(), step);
  // The path is a circle of radius 0.7 m about the origin (camera 0.12 m ahead of the truck
  // point, so sqrt(0.7^2 + 0.12^2) from the centre), at constant height.
  const double r_cam = std::hypot(0.7, 0.12);
  for (const auto& T : run.T_W_C) {
    EXPECT_NEAR(T.translation().head<2>().norm(), r_cam, 1e-9);
    EXPECT_NEAR(T.translation().z(), 0.35, 1e-12);
    EXPECT_NEAR(T.linear().col(1).z(), -1.0, 1e-12);  // level camera: image down = world down
  }
  for (std::size_t i = 0; i < run.size(); i += 110) {
    const DepthImage d = run.renderFrame(i, NoiseConfig::forModel(NoiseModel::kNone), 0);
    EXPECT_GT(fractionValid(d), 0.9) << "frame " << i;
  }
}

TEST(RenderedRuns, TruckStraightRuns) {
  const RenderedRun chair3 = makeRun("chair3");
  ASSERT_EQ(chair3.size(), 3u + 150u);
  const Eigen::Vector3d start = chair3.T_W_C.front().translation();
  EXPECT_NEAR(2.16 - start.x(), 2.5, 1e-12);  // chair back 2.5 m ahead of the camera
  EXPECT_NEAR((chair3.T_W_C.back().translation() - start - Eigen::Vector3d(1.5, 0, 0)).norm(), 0.0,
              1e-9);
  const RenderedRun hall1 = makeRun("hall1");
  EXPECT_NEAR(hall1.T_W_C.back().translation().x() - hall1.T_W_C.front().translation().x(), 8.0,
              0.30 / 30.0);
  const DepthImage d = hall1.renderFrame(400, NoiseConfig::forModel(NoiseModel::kNone), 0);
  EXPECT_GT(fractionValid(d), 0.5);  // the far end of a long hall is beyond the 4 m range
}

TEST(RenderedRuns, FramesAreReproducible) {
  const RenderedRun run = makeRun("xtest1_05_chair");
  const NoiseConfig l515 = NoiseConfig::forModel(NoiseModel::kL515);
  const DepthImage a = run.renderFrame(50, l515, 7, 1);
  const DepthImage b = run.renderFrame(50, l515, 7, 2);
  EXPECT_EQ(a.data, b.data);
  EXPECT_THROW(run.renderFrame(run.size(), l515, 7), std::out_of_range);
}

TEST(RenderedRuns, RawFramesUseTheSensorUnit) {
  const RenderedRun run = makeRun("rt1");
  const NoiseConfig l515 = NoiseConfig::forModel(NoiseModel::kL515);
  const RawDepth16 raw = run.renderFrameRaw(10, l515, 3);
  EXPECT_EQ(raw.depth_scale_m, 0.00025);
  const DepthImage metres = run.renderFrame(10, l515, 3);
  ASSERT_EQ(raw.data.size(), metres.data.size());
  for (std::size_t i = 0; i < raw.data.size(); ++i)
    ASSERT_NEAR(raw.data[i] * raw.depth_scale_m, metres.data[i], 1e-6);  // float storage only
}

TEST(RenderedRuns, BadSpecsAreNamed) {
  TrackRunSpec t;
  t.name = "bad track";
  t.duration_s = -1.0;
  t.axis = TrackRunSpec::Axis::kPitch;
  t.amplitude_deg = 90.0;
  try {
    makeTrackRun(t, chairRoomScene());
    FAIL();
  } catch (const std::invalid_argument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("bad track"), std::string::npos) << msg;
    EXPECT_NE(msg.find("duration_s"), std::string::npos) << msg;
    EXPECT_NE(msg.find("amplitude_deg"), std::string::npos) << msg;
  }
  TruckRunSpec s;
  s.name = "bad truck";
  s.camera_height_m = 0.0;
  EXPECT_EQ(s.validate().size(), 2u);  // height and no segments
  s.camera_height_m = 0.3;
  s.segments = {{0.0, 0.3, 0.0}};
  EXPECT_THROW(makeTruckRun(s, hallwayScene()), std::invalid_argument);
}

// Row scanning: in RT1 the camera moves straight at the back wall at 95 mm/s, so rows scanned
// later see the wall nearer by speed * (row time difference). Rows 20 and 200 of column 320 see
// the wall; with a 33.3 ms scan they are 12.5 ms apart: 1.19 mm. Band rendering (8 rows share a
// pose) adds at most 2 x 4 rows of scan time: +-0.05 mm.
TEST(RenderedRuns, RowScanShiftsDepthByTheMotionDuringTheScan) {
  RenderedRun run = makeRun("rt1");
  ASSERT_TRUE(run.pose_at);
  EXPECT_TRUE(run.pose_at(run.stamps_s[100]).isApprox(run.T_W_C[100], 1e-12));
  const NoiseConfig none = NoiseConfig::forModel(NoiseModel::kNone);
  const DepthImage global = run.renderFrame(100, none, 0);
  EXPECT_NEAR(global.at(320, 20), global.at(320, 200), 1e-6);
  run.scan_time_s = 1.0 / 30.0;
  const DepthImage scanned = run.renderFrame(100, none, 0);
  const double expected = 0.095 * run.scan_time_s * (180.0 / 480.0);
  EXPECT_NEAR(scanned.at(320, 20) - scanned.at(320, 200), expected, 5e-5);
  // The middle row is seen at the stamp.
  EXPECT_NEAR(scanned.at(320, 240 - 4), global.at(320, 240 - 4), 5e-5);
  // Stepped runs are at rest while a frame is captured: scanning changes nothing.
  RenderedRun xtest = makeRun("xtest1_05_chair");
  EXPECT_FALSE(xtest.pose_at);
  const DepthImage a = xtest.renderFrame(50, none, 0);
  xtest.scan_time_s = 1.0 / 30.0;
  EXPECT_EQ(a.data, xtest.renderFrame(50, none, 0).data);
  // Truck runs interpolate between frames.
  const RenderedRun room = makeRun("room3");
  ASSERT_TRUE(room.pose_at);
  EXPECT_TRUE(room.pose_at(room.stamps_s[300]).isApprox(room.T_W_C[300], 1e-9));
  const Eigen::Isometry3d mid = room.pose_at(0.5 * (room.stamps_s[300] + room.stamps_s[301]));
  // Halfway between frames the chord lies inside the circle by the sagitta s^2 / (8 r).
  const double r_cam = std::hypot(0.7, 0.12);
  const double chord = (room.T_W_C[301].translation() - room.T_W_C[300].translation()).norm();
  EXPECT_NEAR(mid.translation().head<2>().norm(), r_cam - chord * chord / (8 * r_cam), 1e-7);
}
