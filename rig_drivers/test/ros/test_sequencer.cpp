// rostest: a mode 2 step sequence through sequencer -> track_host -> fake TrackDRV on a pty, with
// depth_camera (sim backend, triggered) rendering from a fixed true pose. Checks one depth frame
// per `frame` step, each taken with the carriage still at the commanded position; and that a
// malformed script is rejected with its line number before anything moves.
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/String.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <mutex>
#include <vector>

#include "rig_msgs/RawFrame.h"
#include "rig_msgs/TrackState.h"
#include "wait_until.hpp"

namespace {

struct Listener {
  std::mutex m;
  std::vector<sensor_msgs::Image> images;
  int infos = 0;
  std::string status;
  // Carriage position over time, by the host stamp of each TrackState. The image and the state
  // arrive on separate connections, so the latest state received when an image arrives may
  // already show the next move; the stamps say what the carriage did before the frame was taken.
  std::vector<std::pair<ros::Time, double>> states;
  int track_moves_sent = 0;
  void onImage(const sensor_msgs::Image& i) {
    std::lock_guard<std::mutex> l(m);
    images.push_back(i);
  }
  void onInfo(const sensor_msgs::CameraInfo&) {
    std::lock_guard<std::mutex> l(m);
    ++infos;
  }
  void onStatus(const std_msgs::String& s) {
    std::lock_guard<std::mutex> l(m);
    status = s.data;
  }
  void onState(const rig_msgs::TrackState& s) {
    std::lock_guard<std::mutex> l(m);
    states.emplace_back(s.header.stamp, s.track_pos_m);
  }
  void onRaw(const rig_msgs::RawFrame& r) {
    std::lock_guard<std::mutex> l(m);
    if (r.outgoing && r.bytes.size() > 5 && r.bytes[5] == 0x10) ++track_moves_sent;  // kTrackMove
  }
  // Position in the latest state stamped at or before t (-1 if none), whatever order the states
  // arrived in.
  double posAt(const ros::Time& t) const {
    double pos = -1;
    ros::Time latest;
    for (const auto& st : states)
      if (st.first <= t && st.first >= latest) latest = st.first, pos = st.second;
    return pos;
  }
  std::string getStatus() {
    std::lock_guard<std::mutex> l(m);
    return status;
  }
};

using rig_drivers::test::waitUntil;

}  // namespace

TEST(Sequencer, ModeTwoRunYieldsOneFramePerFrameStep) {
  ros::NodeHandle nh, pnh("~");
  int expected_frames = 0;
  double step_m = 0;
  pnh.param("expected_frames", expected_frames, 7);
  pnh.param("step_m", step_m, 0.010);
  // Position resolution: exact micrometres with the fake board; one motor step (0.0186 mm) with
  // the simulated TrackDRV, whose TrackPos is the stepper count.
  double pos_tol_m = 1e-6;
  pnh.param("pos_tol_m", pos_tol_m, pos_tol_m);
  Listener L;
  auto s1 = nh.subscribe("camera/image_rect", 100, &Listener::onImage, &L);
  auto s2 = nh.subscribe("camera/camera_info", 100, &Listener::onInfo, &L);
  auto s3 = nh.subscribe("sequencer/status", 10, &Listener::onStatus, &L);
  auto s4 = nh.subscribe("track_state", 100, &Listener::onState, &L);
  auto s5 = nh.subscribe("raw_frames", 1000, &Listener::onRaw, &L);
  ros::AsyncSpinner spinner(2);
  spinner.start();

  ASSERT_TRUE(waitUntil([&] { return L.getStatus().rfind("done", 0) == 0; }, 90))
      << "sequencer status: '" << L.getStatus() << "'";
  ros::WallDuration(0.5).sleep();  // nothing may follow the last frame
  std::lock_guard<std::mutex> l(L.m);
  EXPECT_EQ(L.status, "done " + std::to_string(expected_frames) + " frames");
  ASSERT_EQ(static_cast<int>(L.images.size()), expected_frames);
  EXPECT_EQ(L.infos, expected_frames);
  EXPECT_EQ(L.track_moves_sent, 5);
  for (std::size_t i = 0; i < L.images.size(); ++i) {
    const auto& im = L.images[i];
    EXPECT_EQ(im.encoding, "16UC1");
    EXPECT_EQ(im.header.frame_id, "camera_depth_optical_frame");
    ASSERT_EQ(im.data.size(), static_cast<std::size_t>(im.step) * im.height);
    // The rendered room is in view: most pixels have a return inside the L515 range.
    std::size_t valid = 0;
    const auto* px = reinterpret_cast<const std::uint16_t*>(im.data.data());
    for (std::size_t k = 0; k < im.width * im.height; ++k) valid += px[k] >= 530 && px[k] <= 4000;
    EXPECT_GT(valid, im.width * im.height / 2) << "frame " << i;
  }
  // Frame k was taken still at the commanded position: 2 frames at 0, then one per 10 mm step
  // (tolerance: the board's position resolution, see pos_tol_m). The carriage position at a
  // frame is the last state stamped at or before the frame's stamp (camera time = grab time).
  for (int i = 0; i < expected_frames; ++i) {
    const double want = i < 2 ? 0.0 : (i - 1) * step_m;
    EXPECT_NEAR(L.posAt(L.images[i].header.stamp), want, pos_tol_m) << "frame " << i;
  }
}

TEST(Sequencer, MalformedScriptIsRejectedBeforeAnythingMoves) {
  ros::NodeHandle nh, pnh("~");
  std::string bad_script;
  ASSERT_TRUE(pnh.getParam("bad_script", bad_script));
  Listener L;
  auto s5 = nh.subscribe("raw_frames", 1000, &Listener::onRaw, &L);
  ros::AsyncSpinner spinner(1);
  spinner.start();
  ros::WallDuration(0.5).sleep();
  // Run the real sequencer executable (next to this test binary) on the malformed script.
  char self[4096] = {0};
  ASSERT_GT(::readlink("/proc/self/exe", self, sizeof self - 1), 0);
  std::string dir(self);
  dir = dir.substr(0, dir.rfind('/'));
  const std::string cmd = dir + "/sequencer __name:=bad_sequencer _script:=" + bad_script +
                          " _camera_trigger_service:=/camera/depth_camera/trigger 2>&1";
  FILE* f = ::popen(cmd.c_str(), "r");
  ASSERT_NE(f, nullptr);
  std::string out;
  char buf[512];
  while (std::fgets(buf, sizeof buf, f)) out += buf;
  const int status = ::pclose(f);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 1) << out;
  EXPECT_NE(out.find("mode2_bad.txt:5:"), std::string::npos) << out;
  EXPECT_NE(out.find("nothing was moved"), std::string::npos) << out;
  ros::WallDuration(0.5).sleep();
  std::lock_guard<std::mutex> l(L.m);
  EXPECT_EQ(L.track_moves_sent, 0);
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_sequencer");
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}
