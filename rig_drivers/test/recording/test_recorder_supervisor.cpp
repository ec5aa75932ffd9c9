// RecorderSupervisor against a stand-in for rosbag record (fake_recorder.sh: the same options,
// real files, real exits and signals) on a real folder: the folder is made, a recorder that dies
// is reported by name with the bags it closed and the one it left open, restarts wait for the
// folder, a removed folder is noticed, and a Ctrl-C leaves every bag closed. Restart timing runs
// on an injected clock; only the child's own progress is waited for.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "rig_drivers/recording/recorder_supervisor.hpp"

using namespace rig_drivers;

namespace {

std::string tempDir() {
  char tmpl[] = "/tmp/rig_rec_supXXXXXX";
  const char* d = ::mkdtemp(tmpl);
  return d ? d : "/tmp";
}

std::string slurp(const std::string& path) {
  std::ifstream f(path);
  std::string s;
  std::getline(f, s);
  return s;
}

struct Probe {
  std::vector<RecorderEvent> events;
  std::vector<std::string> output;
  std::string last(int level) const {
    for (auto it = events.rbegin(); it != events.rend(); ++it)
      if (it->level == level) return it->message;
    return "";
  }
  int count(int level) const {
    int n = 0;
    for (const auto& e : events) n += e.level == level;
    return n;
  }
};

RecorderConfig fakeConfig(const std::string& dir) {
  RecorderConfig c;
  c.bag_dir = dir;
  c.bag_prefix = "rec";
  c.topics = {"/camera/image_rect", "/tf"};
  c.split_size_mb = 5;
  c.min_free_mb = 0;
  c.recorder = {RIG_SOURCE_DIR "/test/recording/fake_recorder.sh"};
  return c;
}

/// Steps the supervisor at a fixed injected time until pred() holds (the child works in real
/// time); false after 10 s of wall time.
bool stepUntil(RecorderSupervisor& s, double now_s, const std::function<bool()>& pred) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (std::chrono::steady_clock::now() < end) {
    s.step(now_s);
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return pred();
}

bool exists(const std::string& p) { return ::access(p.c_str(), F_OK) == 0; }

}  // namespace

TEST(RecorderSupervisor, MakesTheFolderRecordsAndClosesOnStop) {
  const std::string root = tempDir();
  const std::string dir = root + "/a/b/rig_bags";  // three levels missing
  ::setenv("FAKE_MODE", "record", 1);
  ::setenv("FAKE_ARGS", (root + "/args").c_str(), 1);
  Probe p;
  RecorderSupervisor s(
      fakeConfig(dir), [&](const RecorderEvent& e) { p.events.push_back(e); },
      [&](const std::string& l) { p.output.push_back(l); });
  s.step(0.0);
  ASSERT_TRUE(exists(dir)) << "the bag folder is made before the recorder starts";
  ASSERT_TRUE(stepUntil(s, 0.1, [&] { return s.status().active_bag != ""; }));
  EXPECT_EQ(s.status().state, RecorderState::kRecording);
  EXPECT_EQ(s.status().level, 0);
  EXPECT_EQ(s.status().active_bag, "rec_2024-01-02-03-04-05_0.bag.active");
  EXPECT_NE(
      s.status().summary.find("recording into " + dir + "/rec_2024-01-02-03-04-05_0.bag.active"),
      std::string::npos)
      << s.status().summary;
  EXPECT_EQ(slurp(root + "/args"),
            "--split --size=5 --lz4 --min-space=0M -o " + dir + "/rec /camera/image_rect /tf");
  EXPECT_EQ(p.count(2), 0);
  s.stop(5.0);  // Ctrl-C: the bag is closed
  EXPECT_EQ(s.status().state, RecorderState::kStopped);
  EXPECT_TRUE(exists(dir + "/rec_2024-01-02-03-04-05_0.bag"));
  EXPECT_FALSE(exists(dir + "/rec_2024-01-02-03-04-05_0.bag.active"));
  EXPECT_EQ(s.status().closed_bags, 1u);
  EXPECT_EQ(s.status().unindexed_bags, 0u);
  EXPECT_EQ(p.count(2), 0);
  std::filesystem::remove_all(root);
}

TEST(RecorderSupervisor, ARecorderThatDiesIsReportedByNameAndStartedAgain) {
  const std::string dir = tempDir();
  ::setenv("FAKE_MODE", "die", 1);
  ::unsetenv("FAKE_ARGS");
  Probe p;
  RecorderConfig c = fakeConfig(dir);
  c.restart_period_s = 5.0;
  RecorderSupervisor s(
      c, [&](const RecorderEvent& e) { p.events.push_back(e); },
      [&](const std::string& l) { p.output.push_back(l); });
  ASSERT_TRUE(stepUntil(s, 0.0, [&] { return p.count(2) == 1; }));
  const std::string m = p.last(2);
  EXPECT_NE(m.find("recording into " + dir + " stopped"), std::string::npos) << m;
  EXPECT_NE(m.find("killed by signal 6"), std::string::npos) << m;
  // The first error line is the cause; the ones after it follow from it.
  EXPECT_NE(m.find("(Aborted): Problem writing data to disk;"), std::string::npos) << m;
  EXPECT_NE(m.find("2 bags closed and readable in " + dir), std::string::npos) << m;
  EXPECT_NE(m.find("rec_2024-01-02-03-04-05_2.bag.active was left open and is not indexed"),
            std::string::npos)
      << m;
  EXPECT_NE(m.find("rosbag reindex " + dir + "/rec_2024-01-02-03-04-05_2.bag.active"),
            std::string::npos)
      << m;
  // The recorder's own lines reach the log as they were written.
  ASSERT_FALSE(p.output.empty());
  EXPECT_NE(p.output.back().find("\033[31m[ERROR]"), std::string::npos);
  const RecorderStatus st = s.status();
  EXPECT_EQ(st.state, RecorderState::kWaiting);
  EXPECT_EQ(st.level, 2);
  EXPECT_EQ(st.closed_bags, 2u);
  EXPECT_EQ(st.unindexed_bags, 1u);
  EXPECT_EQ(
      st.summary.rfind("not recording into " + dir + ": the recorder was killed by signal 6", 0),
      0u)
      << st.summary;

  // It closed bags, so the next start is one restart period later.
  s.step(4.9);
  EXPECT_EQ(s.status().starts, 1u);
  // The next one stops at once, closing nothing: the wait doubles, 5 s, then 10 s.
  ::setenv("FAKE_MODE", "refuse", 1);
  s.step(5.0);
  EXPECT_EQ(s.status().starts, 2u);
  ASSERT_TRUE(stepUntil(s, 5.0, [&] { return s.status().state == RecorderState::kWaiting; }));
  EXPECT_NE(p.last(2).find("exited with status 1: Error writing: Error writing to file"),
            std::string::npos)
      << p.last(2);
  // The bag it could not write a message into is removed; the one named before is not again.
  EXPECT_NE(p.last(2).find("removed rec_2024-01-02-03-04-05_0.bag.active (no message in it)"),
            std::string::npos)
      << p.last(2);
  EXPECT_EQ(p.last(2).find("_2.bag.active"), std::string::npos) << p.last(2);
  EXPECT_FALSE(exists(dir + "/rec_2024-01-02-03-04-05_0.bag.active"));
  EXPECT_TRUE(exists(dir + "/rec_2024-01-02-03-04-05_2.bag.active"));
  EXPECT_NE(p.last(2).find("starting it again in 5 s"), std::string::npos) << p.last(2);
  s.step(9.9);
  EXPECT_EQ(s.status().starts, 2u);
  s.step(10.0);
  EXPECT_EQ(s.status().starts, 3u);
  ASSERT_TRUE(stepUntil(s, 10.0, [&] { return s.status().state == RecorderState::kWaiting; }));
  EXPECT_NE(p.last(2).find("starting it again in 10 s"), std::string::npos) << p.last(2);
  s.step(19.9);
  EXPECT_EQ(s.status().starts, 3u);
  s.step(20.0);
  EXPECT_EQ(s.status().starts, 4u);
  s.stop(5.0);
  std::filesystem::remove_all(dir);
}

TEST(RecorderSupervisor, AFolderThatCannotBeMadeIsNamedAndWaitedFor) {
  const std::string root = tempDir();
  const std::string blocker = root + "/not_a_folder";
  std::ofstream(blocker) << "x";
  ::setenv("FAKE_MODE", "record", 1);
  Probe p;
  RecorderConfig c = fakeConfig(blocker + "/rig_bags");
  c.restart_period_s = 1.0;
  RecorderSupervisor s(
      c, [&](const RecorderEvent& e) { p.events.push_back(e); }, nullptr);
  for (int i = 0; i < 10; ++i) s.step(i * 0.5);  // 4.5 s: five attempts, one message
  ASSERT_EQ(p.count(2), 1);
  EXPECT_NE(p.last(2).find("not recording: cannot create the bag folder " + blocker +
                           "/rig_bags: " + blocker),
            std::string::npos)
      << p.last(2);
  EXPECT_NE(p.last(2).find("trying again every 1 s"), std::string::npos) << p.last(2);
  EXPECT_EQ(s.status().level, 2);
  EXPECT_EQ(s.status().starts, 0u);
  ::unlink(blocker.c_str());  // the obstacle goes: recording starts at the next attempt
  s.step(5.0);
  EXPECT_EQ(s.status().starts, 1u);
  EXPECT_EQ(s.status().state, RecorderState::kRecording);
  s.stop(5.0);
  std::filesystem::remove_all(root);
}

TEST(RecorderSupervisor, NoRecorderBelowTheReserve) {
  const std::string dir = tempDir();
  Probe p;
  RecorderConfig c = fakeConfig(dir);
  c.min_free_mb = 1048576;  // 1 TB free asked for
  RecorderSupervisor s(
      c, [&](const RecorderEvent& e) { p.events.push_back(e); }, nullptr);
  s.step(0.0);
  EXPECT_EQ(s.status().starts, 0u);
  ASSERT_EQ(p.count(2), 1);
  EXPECT_NE(
      p.last(2).find("free on the file system of " + dir + ", below the reserve of 1048576 MiB"),
      std::string::npos)
      << p.last(2);
  std::filesystem::remove_all(dir);
}

TEST(RecorderSupervisor, ARemovedFolderIsNoticedAndMadeAgain) {
  const std::string root = tempDir(), dir = root + "/bags";
  ::setenv("FAKE_MODE", "record", 1);
  Probe p;
  RecorderConfig c = fakeConfig(dir);
  c.restart_period_s = 1.0;
  RecorderSupervisor s(
      c, [&](const RecorderEvent& e) { p.events.push_back(e); }, nullptr);
  ASSERT_TRUE(stepUntil(s, 0.0, [&] { return s.status().active_bag != ""; }));
  const std::string active = dir + "/rec_2024-01-02-03-04-05_0.bag.active";
  ASSERT_EQ(::unlink(active.c_str()), 0);
  ASSERT_EQ(::rmdir(dir.c_str()), 0);
  ASSERT_TRUE(stepUntil(s, 2.0, [&] { return s.status().state == RecorderState::kWaiting; }));
  EXPECT_NE(p.last(2).find("the bag folder " + dir + " was removed while recording"),
            std::string::npos)
      << p.last(2);
  s.step(3.5);  // restart due: the folder is made again and the recorder runs in it
  EXPECT_TRUE(exists(dir));
  EXPECT_EQ(s.status().starts, 2u);
  EXPECT_EQ(s.status().state, RecorderState::kRecording);
  s.stop(5.0);
  std::filesystem::remove_all(root);
}

TEST(RecorderSupervisor, ConfigReportsEveryProblemAndTheCommandLine) {
  RecorderConfig c;
  c.bag_dir = "relative/bags";
  c.bag_prefix = "a/b";
  c.split_size_mb = 0;
  c.compression = "zip";
  c.min_free_mb = -1;
  c.restart_period_s = 0;
  c.max_restart_period_s = -1;
  c.check_period_s = 0;
  c.recorder.clear();
  EXPECT_EQ(c.validate().size(), 10u);  // and no topics
  EXPECT_THROW(RecorderSupervisor(c, nullptr, nullptr), std::invalid_argument);
  RecorderConfig d;
  d.bag_dir = "/data/bags";
  d.bag_prefix = "servotrack";
  d.topics = {"/tf", "/tf_static"};
  d.compression = "none";
  EXPECT_TRUE(d.validate().empty());
  const std::vector<std::string> want = {"rosrun",      "rosbag",
                                         "record",      "--split",
                                         "--size=1024", "--min-space=1024M",
                                         "-o",          "/data/bags/servotrack",
                                         "/tf",         "/tf_static"};
  EXPECT_EQ(recordCommand(d), want);
}
