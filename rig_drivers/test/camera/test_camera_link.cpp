// CameraLink (the camera node's device layer) against a fake camera that is missing at the start,
// appears, disappears mid-stream and comes back, on an injected clock: every open attempt, loss,
// reconnect and missing frame is counted exactly. And the V4L2 source on paths that are not a
// camera: the reason names the device and what was tried.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "rig_drivers/camera/camera_link.hpp"
#include "rig_drivers/camera/v4l2_source.hpp"

using namespace rig_drivers;

namespace {

constexpr double kRateHz = 30.0;
constexpr std::int64_t kEpochNs = 1700000000LL * 1000000000LL;

/// A camera on an injected clock: when present, it exposes frame k at k / 30 s of its own clock,
/// also while nobody reads it (a real camera keeps its clock), and delivers the newest one.
/// The link is stepped at 64 Hz (faster than the frames; binary-exact times, so every retry falls
/// on a known step).
struct FakeCamera {
  bool present = false;
  bool silent = false;  ///< present but delivering nothing (a hung USB stream)
  bool ends_after = false;
  int opens = 0, closes = 0;
  double now_s = 0.0;
  long last_index = -1;
};

class FakeSource : public DepthSource {
 public:
  explicit FakeSource(FakeCamera* cam) : cam_(cam) {}
  std::string device() const override { return "/dev/fake_video7"; }
  bool open(std::string* why) override {
    ++cam_->opens;
    if (!cam_->present) {
      *why = "cannot open /dev/fake_video7: No such file or directory";
      return false;
    }
    return true;
  }
  void close() override { ++cam_->closes; }
  GrabStatus grab(DepthFrame* out, std::string* why) override {
    if (!cam_->present) {
      *why = "VIDIOC_DQBUF: No such device";
      return GrabStatus::kLost;
    }
    if (cam_->ends_after) {
      *why = "end of the sequence";
      return GrabStatus::kEnded;
    }
    const long k = static_cast<long>(std::floor(cam_->now_s * kRateHz + 1e-9));
    if (cam_->silent || k == cam_->last_index) {
      *why = "no frame within 1 s";
      return GrabStatus::kNoFrame;
    }
    cam_->last_index = k;
    out->depth = depth_track::DepthImage(4, 3, 1.0f);
    out->stamp_ns = kEpochNs + k * 1000000000LL / 30;
    return GrabStatus::kFrame;
  }
  depth_track::PinholeIntrinsics intrinsics() const override { return {}; }

 private:
  FakeCamera* cam_;
};

struct LinkRun {
  FakeCamera cam;
  std::vector<CameraEvent> events;
  std::unique_ptr<CameraLink> link;
  std::vector<std::int64_t> stamps;
  long step = 0;
  explicit LinkRun(CameraLinkConfig c = {}) {
    link = std::make_unique<CameraLink>(c, std::make_unique<FakeSource>(&cam),
                                        [this](const CameraEvent& e) { events.push_back(e); });
  }
  /// Steps the link every 1/64 s until t_end.
  void runUntil(double t_end) {
    while (step < std::lround(t_end * 64)) {
      cam.now_s = static_cast<double>(++step) / 64.0;
      DepthFrame f;
      if (link->step(cam.now_s, &f)) stamps.push_back(f.stamp_ns);
    }
  }
  int count(CameraEvent::Type t) const {
    int n = 0;
    for (const auto& e : events) n += e.type == t;
    return n;
  }
};

}  // namespace

TEST(CameraLink, WaitsForAMissingDeviceThenStreams) {
  LinkRun r;
  r.runUntil(3.0);  // no camera for 3 s: an attempt every 0.5 s, one message
  EXPECT_EQ(r.link->state(), CameraState::kWaiting);
  EXPECT_EQ(r.link->stats().failed_opens, 6u);  // at 1/64, 0.5+1/64, ... 2.5+1/64 s
  EXPECT_EQ(r.cam.opens, 6);
  ASSERT_EQ(r.events.size(), 1u);
  EXPECT_EQ(r.events[0].type, CameraEvent::kWaiting);
  EXPECT_NE(r.events[0].message.find("waiting for /dev/fake_video7"), std::string::npos);
  EXPECT_NE(r.events[0].message.find("No such file or directory"), std::string::npos);
  EXPECT_NE(r.events[0].message.find("retrying every 0.5 s"), std::string::npos);
  EXPECT_NE(r.link->status().find("waiting for /dev/fake_video7: cannot open"), std::string::npos);
  EXPECT_TRUE(r.stamps.empty());

  r.cam.present = true;  // plugged in at 3 s: opened at the next attempt (3.0 + 1/64 s)
  r.runUntil(5.0);
  EXPECT_EQ(r.link->state(), CameraState::kStreaming);
  EXPECT_EQ(r.count(CameraEvent::kOpened), 1);
  // Every frame of the camera from the open on, once each, in order.
  ASSERT_FALSE(r.stamps.empty());
  for (std::size_t i = 1; i < r.stamps.size(); ++i)
    EXPECT_EQ(std::lround((r.stamps[i] - r.stamps[i - 1]) * 1e-9 * kRateHz), 1) << i;
  // Frames 90 (3.0 s, the newest when the device opened) to 150 (5.0 s).
  EXPECT_EQ(r.stamps.size(), 61u);
  EXPECT_EQ(r.link->stats().frames, 61u);
  EXPECT_EQ(r.link->stats().losses, 0u);
  EXPECT_EQ(r.link->stats().gap_frames, 0u);
  EXPECT_NE(r.link->status().find("streaming from /dev/fake_video7, 61 frames"), std::string::npos);
}

TEST(CameraLink, ReconnectsAfterUnplugAndCountsTheGap) {
  LinkRun r;
  r.cam.present = true;
  r.runUntil(2.0);
  const std::size_t before = r.stamps.size();
  const std::int64_t last_before = r.stamps.back();
  r.cam.present = false;  // unplugged at 2 s
  r.runUntil(3.3);
  EXPECT_EQ(r.link->state(), CameraState::kLost);
  EXPECT_EQ(r.count(CameraEvent::kLost), 1);
  EXPECT_NE(r.link->status().find("to come back"), std::string::npos);
  r.cam.present = true;  // plugged in again at 3.3 s
  r.runUntil(5.0);
  EXPECT_EQ(r.link->state(), CameraState::kStreaming);
  EXPECT_EQ(r.link->stats().losses, 1u);
  EXPECT_EQ(r.link->stats().reconnects, 1u);
  EXPECT_EQ(r.count(CameraEvent::kOpened), 2);
  ASSERT_EQ(r.count(CameraEvent::kResumed), 1);
  ASSERT_GT(r.stamps.size(), before);
  // The gap is the stamps' own: every frame between the last before and the first after is missing.
  const std::int64_t first_after = r.stamps[before];
  const long missing = std::lround((first_after - last_before) * 1e-9 * kRateHz) - 1;
  // Lost at the step after 2 s (2.016 s), attempts every 0.5 s: 2.516 and 3.016 s find nothing,
  // 3.516 s opens: frames 61..104 (2.033 .. 3.467 s) are missing.
  EXPECT_EQ(last_before, kEpochNs + 60 * 1000000000LL / 30);
  EXPECT_EQ(missing, 44);
  EXPECT_EQ(r.link->stats().gap_frames, static_cast<std::uint64_t>(missing));
  EXPECT_NEAR(r.link->stats().last_gap_s, (first_after - last_before) * 1e-9, 1e-9);
  // Frames after the gap arrive every 1/30 s again, none twice.
  for (std::size_t i = before + 1; i < r.stamps.size(); ++i)
    EXPECT_EQ(std::lround((r.stamps[i] - r.stamps[i - 1]) * 1e-9 * kRateHz), 1);
  EXPECT_EQ(
      r.stamps.size() + static_cast<std::size_t>(missing),
      static_cast<std::size_t>(std::lround((r.stamps.back() - r.stamps.front()) * 1e-9 * 30)) + 1)
      << "delivered + missing = every frame the camera exposed from the first to the last";
}

TEST(CameraLink, ASilentDeviceIsLostAfterTheStaleTimeout) {
  CameraLinkConfig c;
  c.stale_timeout_s = 1.0;
  LinkRun r(c);
  r.cam.present = true;
  r.runUntil(1.0);
  r.cam.silent = true;
  r.runUntil(1.9);
  EXPECT_EQ(r.link->state(), CameraState::kStreaming);  // 0.9 s without a frame: not yet
  r.runUntil(2.2);
  EXPECT_EQ(r.link->state(), CameraState::kLost);
  ASSERT_EQ(r.count(CameraEvent::kLost), 1);
  EXPECT_NE(r.events.back().message.find("no frame for"), std::string::npos);
  EXPECT_EQ(r.cam.closes, 1);
  r.cam.silent = false;  // the stream comes back: reopened, the gap counted
  r.runUntil(3.5);
  EXPECT_EQ(r.link->state(), CameraState::kStreaming);
  EXPECT_EQ(r.link->stats().reconnects, 1u);
  EXPECT_GT(r.link->stats().gap_frames, 30u);
}

TEST(CameraLink, StaleTimeoutOffAndMaintainOnlyForATriggeredCamera) {
  CameraLinkConfig c;
  c.stale_timeout_s = 0.0;
  LinkRun r(c);
  for (int i = 1; i <= 64; ++i) EXPECT_FALSE(r.link->step(i / 64.0, nullptr));  // no device
  EXPECT_EQ(r.link->stats().failed_opens, 2u);
  r.cam.present = true;
  EXPECT_FALSE(r.link->step(1.6, nullptr));  // opened, nothing grabbed
  EXPECT_EQ(r.cam.last_index, -1);
  EXPECT_EQ(r.link->state(), CameraState::kStreaming);
  r.cam.silent = true;
  DepthFrame f;
  for (int i = 0; i < 600; ++i) EXPECT_FALSE(r.link->step(2.0 + i, &f));  // 10 min idle
  EXPECT_EQ(r.link->state(), CameraState::kStreaming);
}

TEST(CameraLink, AnEndedSourceStopsAndSaysSo) {
  LinkRun r;
  r.cam.present = true;
  r.runUntil(0.5);
  r.cam.ends_after = true;
  r.runUntil(1.0);
  EXPECT_EQ(r.link->state(), CameraState::kEnded);
  ASSERT_EQ(r.count(CameraEvent::kEnded), 1);
  EXPECT_NE(r.link->status().find("end of the sequence"), std::string::npos);
  const int opens = r.cam.opens;
  r.runUntil(2.0);
  EXPECT_EQ(r.cam.opens, opens);  // not reopened
}

TEST(CameraLink, ANewReasonIsReportedOnceEach) {
  struct Flaky : DepthSource {
    int n = 0;
    std::string device() const override { return "/dev/video3"; }
    bool open(std::string* why) override {
      ++n;
      if (n > 4) throw std::runtime_error("driver threw");
      *why = n <= 2 ? "No such file or directory" : "Device or resource busy";
      return false;
    }
    void close() override {}
    GrabStatus grab(DepthFrame*, std::string*) override { return GrabStatus::kNoFrame; }
    depth_track::PinholeIntrinsics intrinsics() const override { return {}; }
  };
  std::vector<std::string> msgs;
  CameraLink link({}, std::make_unique<Flaky>(),
                  [&](const CameraEvent& e) { msgs.push_back(e.message); });
  for (int i = 0; i < 6; ++i) link.step(i * 0.5, nullptr);
  ASSERT_EQ(msgs.size(), 3u);  // missing, busy, threw
  EXPECT_NE(msgs[1].find("busy"), std::string::npos);
  EXPECT_NE(msgs[2].find("driver threw"), std::string::npos);
  EXPECT_EQ(link.stats().failed_opens, 6u);
}

TEST(CameraLink, ConfigReportsEveryProblem) {
  CameraLinkConfig c;
  c.retry_period_s = 0;
  c.stale_timeout_s = 0.01;
  c.rate_hz = -1;
  EXPECT_EQ(c.validate().size(), 3u);
  EXPECT_THROW(CameraLink(c, nullptr, nullptr), std::invalid_argument);
  EXPECT_TRUE(CameraLinkConfig{}.validate().empty());
}

TEST(V4l2Source, AMissingDeviceIsNamedAndWaitedFor) {
  depth_track::PinholeIntrinsics K;
  K.width = 640;
  K.height = 480;
  CameraLinkConfig c;
  std::vector<std::string> msgs;
  CameraLink link(c,
                  std::make_unique<V4l2Source>("/tmp/rig_no_such_dir/video0", K, 0.00025,
                                               depth_track::DepthRange{}),
                  [&](const CameraEvent& e) { msgs.push_back(e.message); });
  DepthFrame f;
  EXPECT_FALSE(link.step(0.0, &f));
  EXPECT_FALSE(link.step(0.6, &f));
  ASSERT_EQ(msgs.size(), 1u);
  EXPECT_NE(msgs[0].find("waiting for /tmp/rig_no_such_dir/video0: cannot open "
                         "/tmp/rig_no_such_dir/video0: No such file or directory"),
            std::string::npos)
      << msgs[0];
  EXPECT_EQ(link.stats().failed_opens, 2u);
}

TEST(V4l2Source, ADeviceThatIsNotACameraIsNamed) {
  depth_track::PinholeIntrinsics K;
  V4l2Source s("/dev/null", K, 0.001, depth_track::DepthRange{});
  std::string why;
  EXPECT_FALSE(s.open(&why));
  EXPECT_NE(why.find("/dev/null is not a V4L2 device"), std::string::npos) << why;
  DepthFrame f;
  EXPECT_EQ(s.grab(&f, &why), GrabStatus::kLost);  // closed after the failed open
}
