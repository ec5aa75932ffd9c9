// tum_to_bag: the TUM fr3/teddy folder written as a bag and read back through the rosbag API
// (frames, stamps, intrinsics, depth against the PNGs, ground truth, static frames), and every kind
// of bad input refused with a message naming what is wrong, leaving no bag behind and an existing
// one untouched. Runs the tool itself; no roscore.
// The teddy bag tracked by evaluate_bag and its ATE checked against shared/tools/eval_traj.py:
// test_evaluate_bag (EvaluateBagTum).
#include <geometry_msgs/PoseStamped.h>
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sys/wait.h>
#include <tf2_msgs/TFMessage.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "depth_track/core/tum_io.hpp"
#include "../shared_data.hpp"
#include "tool_test.hpp"
#include "tum_bag.hpp"

#ifndef TUM_TO_BAG
#error "TUM_TO_BAG must name the tum_to_bag executable"
#endif

namespace fs = std::filesystem;
using namespace depth_track;

namespace {

using tool_test::TmpDir;
using tool_test::ToolRun;

ToolRun runTool(const std::string& args, const std::string& log_dir) {
  return tool_test::runTool(TUM_TO_BAG, args, log_dir);
}

std::vector<std::string> lines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> out;
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

void writeLines(const std::string& path, const std::vector<std::string>& ls) {
  std::ofstream out(path);
  for (const auto& l : ls) out << l << "\n";
}

// A small TUM folder: the first n teddy frames (copied PNGs), teddy's list header and its ground
// truth, which tests then spoil one way or another.
struct SmallFolder {
  std::string dir;
  std::vector<std::string> depth_lines;  ///< depth.txt as written, header included
  SmallFolder(const std::string& root, const std::string& teddy, int n)
      : dir(root + "/rgbd_dataset_freiburg3_small") {
    fs::create_directories(dir + "/depth");
    int frames = 0;
    for (const std::string& l : lines(teddy + "/depth.txt")) {
      if (l.empty() || l[0] == '#') {
        depth_lines.push_back(l);
        continue;
      }
      if (frames++ == n) break;
      const std::string rel = l.substr(l.find(' ') + 1);
      fs::copy_file(teddy + "/" + rel, dir + "/" + rel);
      depth_lines.push_back(l);
    }
    writeLines(dir + "/depth.txt", depth_lines);
    fs::copy_file(teddy + "/groundtruth.txt", dir + "/groundtruth.txt");
  }
  std::string framePath(int i) const {  // i-th listed image (0-based)
    int k = 0;
    for (const auto& l : depth_lines)
      if (!l.empty() && l[0] != '#' && k++ == i) return dir + "/" + l.substr(l.find(' ') + 1);
    return "";
  }
};

// A refused run: non-zero exit, the message names the problem, no bag and no partial file left.
void expectRefused(const ToolRun& r, const std::string& out, const std::string& message_part) {
  EXPECT_NE(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find(message_part), std::string::npos)
      << "expected '" << message_part << "' in: " << r.output;
  EXPECT_FALSE(fs::exists(out)) << out;
  EXPECT_FALSE(fs::exists(out + ".part")) << out << ".part";
}

// Runs the tool on folder `f` with `args`, writing <tmp>/x.bag, and expects a refusal.
void expectFolderRefused(const SmallFolder& f, const TmpDir& tmp, const std::string& message_part,
                         const std::string& args = "--camera fr3") {
  const std::string out = tmp.path + "/x.bag";
  expectRefused(runTool(f.dir + " " + out + " " + args, tmp.path), out, message_part);
}

template <class M>
std::vector<boost::shared_ptr<M>> readTopic(const std::string& bag_path, const std::string& topic,
                                            std::vector<ros::M_string>* headers = nullptr) {
  rosbag::Bag bag(bag_path, rosbag::bagmode::Read);
  rosbag::View view(bag, rosbag::TopicQuery(topic));
  std::vector<boost::shared_ptr<M>> out;
  for (const rosbag::MessageInstance& m : view) {
    auto p = m.instantiate<M>();
    EXPECT_TRUE(p) << topic << " holds a " << m.getDataType();
    if (!p) continue;
    out.push_back(p);
    if (headers) headers->push_back(*m.getConnectionHeader());
  }
  return out;
}

}  // namespace

TEST(TumToBag, TeddyReadsBackAsWritten) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  const std::string bag = tmp.path + "/teddy.bag";
  const ToolRun r = runTool(teddy + " " + bag + " --camera fr3", tmp.path);
  ASSERT_EQ(r.rc, 0) << r.output;

  const std::vector<TumFrame> frames = readTumFrameList(teddy + "/depth.txt");
  const Trajectory gt = readTumTrajectory(teddy + "/groundtruth.txt");
  ASSERT_EQ(frames.size(), 200u);

  // Depth: one 16UC1 image per listed frame, at its stamp, in list order.
  std::vector<ros::M_string> image_headers, info_headers;
  const auto images = readTopic<sensor_msgs::Image>(bag, tum_bag::kDepthTopic, &image_headers);
  ASSERT_EQ(images.size(), frames.size());
  std::vector<double> stamps;
  for (std::size_t i = 0; i < images.size(); ++i) {
    const sensor_msgs::Image& im = *images[i];
    // ros::Time holds nanoseconds; TUM stamps have 6 decimals.
    EXPECT_NEAR(im.header.stamp.toSec(), frames[i].stamp_s, 1e-6) << i;
    EXPECT_EQ(im.encoding, "16UC1");
    EXPECT_EQ(im.width, 640u);
    EXPECT_EQ(im.height, 480u);
    EXPECT_EQ(im.step, 1280u);
    EXPECT_EQ(im.header.frame_id, tum_bag::kOpticalFrame);
    stamps.push_back(im.header.stamp.toSec());
  }
  // The depth unit is recorded on the topic's connection, and a pixel read through it gives the
  // metres the core reads from the PNG.
  ASSERT_FALSE(image_headers.empty());
  const auto scale = tum_bag::depthScaleOf(image_headers.front());
  ASSERT_TRUE(scale.has_value());
  EXPECT_DOUBLE_EQ(*scale, 0.0002);
  const DepthRange any{0.01, 60.0};
  for (std::size_t i : {std::size_t{0}, std::size_t{99}, std::size_t{199}}) {
    int w = 0, h = 0;
    const std::vector<std::uint16_t> png = readPng16(frames[i].path, &w, &h);
    ASSERT_EQ(images[i]->data.size(), png.size() * 2);
    EXPECT_EQ(std::memcmp(images[i]->data.data(), png.data(), images[i]->data.size()), 0)
        << "frame " << i << " differs from " << frames[i].path;
    const DepthImage metres = loadTumDepth(frames[i].path, 0.0002, any);
    std::uint16_t raw = 0;
    const std::size_t at = (240 * 640 + 320) * 2;
    std::memcpy(&raw, images[i]->data.data() + at, 2);
    ASSERT_GT(raw, 0) << "centre pixel of frame " << i << " has no depth";
    EXPECT_NEAR(raw * *scale, metres.at(320, 240), 1e-6);
    EXPECT_GT(raw * *scale, 0.5);  // teddy's median depth is about 2.1 m
    EXPECT_LT(raw * *scale, 5.0);
  }

  // camera_info: the published fr3 calibration at every frame's stamp, same depth unit field.
  const auto infos = readTopic<sensor_msgs::CameraInfo>(bag, tum_bag::kInfoTopic, &info_headers);
  ASSERT_EQ(infos.size(), frames.size());
  for (std::size_t i = 0; i < infos.size(); ++i) {
    EXPECT_EQ(infos[i]->header.stamp, images[i]->header.stamp) << i;
    const PinholeIntrinsics k = conv::intrinsicsFromCameraInfo(*infos[i]);
    EXPECT_EQ(k.width, 640);
    EXPECT_EQ(k.height, 480);
    EXPECT_DOUBLE_EQ(k.fx, 535.4);
    EXPECT_DOUBLE_EQ(k.fy, 539.2);
    EXPECT_DOUBLE_EQ(k.cx, 320.1);
    EXPECT_DOUBLE_EQ(k.cy, 247.6);
    for (double d : infos[i]->D) EXPECT_EQ(d, 0.0);
  }
  EXPECT_EQ(tum_bag::depthScaleOf(info_headers.front()), scale);

  // Ground truth: every pose of groundtruth.txt (100 Hz, it runs on 1 s past the last frame).
  const auto poses = readTopic<geometry_msgs::PoseStamped>(bag, tum_bag::kGroundTruthTopic);
  ASSERT_EQ(poses.size(), gt.size());
  std::vector<double> gt_stamps;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(poses[i]->header.frame_id, tum_bag::kMapFrame);
    EXPECT_NEAR(poses[i]->header.stamp.toSec(), gt[i].stamp_s, 1e-6);
    const Eigen::Isometry3d T = conv::fromPoseMsg(poses[i]->pose);
    EXPECT_LT((T.translation() - gt[i].T_W_C.translation()).norm(), 1e-12) << i;
    EXPECT_LT((T.linear() - gt[i].T_W_C.linear()).norm(), 1e-9) << i;
    gt_stamps.push_back(poses[i]->header.stamp.toSec());
  }
  // The dataset's README: 196 of the 200 frames have a ground-truth pose within 20 ms.
  EXPECT_EQ(associateStamps(stamps, gt_stamps).size(), 196u);

  // Static frames: base_link = camera_link (hand-held), optical z forward = body x.
  std::vector<ros::M_string> tf_headers;
  const auto tfs = readTopic<tf2_msgs::TFMessage>(bag, tum_bag::kTfStaticTopic, &tf_headers);
  ASSERT_EQ(tfs.size(), 1u);
  EXPECT_EQ(tf_headers.front()["latching"], "1");
  ASSERT_EQ(tfs.front()->transforms.size(), 2u);
  const auto& a = tfs.front()->transforms[0];
  const auto& b = tfs.front()->transforms[1];
  EXPECT_EQ(a.header.frame_id, "base_link");
  EXPECT_EQ(a.child_frame_id, "camera_link");
  EXPECT_EQ(b.header.frame_id, "camera_link");
  EXPECT_EQ(b.child_frame_id, tum_bag::kOpticalFrame);
  const auto& q = b.transform.rotation;
  const Eigen::Matrix3d R_L_O = Eigen::Quaterniond(q.w, q.x, q.y, q.z).toRotationMatrix();
  EXPECT_LT((R_L_O * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitX()).norm(), 1e-12);
  EXPECT_LT((R_L_O * Eigen::Vector3d::UnitX() + Eigen::Vector3d::UnitY()).norm(), 1e-12);
  EXPECT_LT((R_L_O * Eigen::Vector3d::UnitY() + Eigen::Vector3d::UnitZ()).norm(), 1e-12);
}

TEST(TumToBag, MaxFramesKeepsTheGroundTruthThatCanPair) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 12);
  const std::string bag = tmp.path + "/cut.bag";
  const ToolRun r = runTool(f.dir + " " + bag + " --camera fr3 --max-frames 10", tmp.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const auto images = readTopic<sensor_msgs::Image>(bag, tum_bag::kDepthTopic);
  ASSERT_EQ(images.size(), 10u);
  const auto poses = readTopic<geometry_msgs::PoseStamped>(bag, tum_bag::kGroundTruthTopic);
  ASSERT_FALSE(poses.empty());
  const double last = images.back()->header.stamp.toSec();
  EXPECT_LE(poses.back()->header.stamp.toSec(), last + 0.02);
  // 100 Hz ground truth: the next pose after the cut would lie within 10 ms of it.
  EXPECT_GT(poses.back()->header.stamp.toSec(), last + 0.02 - 0.011);
}

TEST(TumToBag, RefusesAMissingFolder) {
  TmpDir tmp;
  const std::string out = tmp.path + "/x.bag";
  expectRefused(runTool(tmp.path + "/nowhere " + out + " --camera fr3", tmp.path), out,
                "nowhere: no such folder");
}

TEST(TumToBag, RefusesAFolderWithoutFrameList) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  fs::remove(f.dir + "/depth.txt");
  expectFolderRefused(f, tmp, "not a depth sequence: no depth.txt");
}

TEST(TumToBag, NamesTheMalformedFrameListLine) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  auto ls = f.depth_lines;  // 3 header lines, then frames on lines 4..6
  ls.insert(ls.begin() + 4, "1341841873.3 depth/a.png extra");
  writeLines(f.dir + "/depth.txt", ls);
  expectFolderRefused(f, tmp, "depth.txt:5: expected 'timestamp path'");
}

TEST(TumToBag, NamesAListedImageThatIsMissing) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  fs::remove(f.framePath(2));
  expectFolderRefused(f, tmp, "depth.txt:6: listed image");
}

TEST(TumToBag, NamesTheMalformedGroundTruthLine) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  auto ls = lines(f.dir + "/groundtruth.txt");
  ls[5] = "1341841873.4451 -2.17 0.68 1.48 -0.26 0.79 -0.51";  // 7 fields on line 6
  writeLines(f.dir + "/groundtruth.txt", ls);
  expectFolderRefused(f, tmp, "groundtruth.txt:6: expected 8 fields");
}

TEST(TumToBag, MissingGroundTruthNeedsConsent) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  fs::remove(f.dir + "/groundtruth.txt");
  expectFolderRefused(f, tmp, "groundtruth.txt: missing");
  const std::string out = tmp.path + "/x.bag";
  const ToolRun r = runTool(f.dir + " " + out + " --camera fr3 --no-ground-truth", tmp.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_EQ(readTopic<sensor_msgs::Image>(out, tum_bag::kDepthTopic).size(), 3u);
  EXPECT_TRUE(readTopic<geometry_msgs::PoseStamped>(out, tum_bag::kGroundTruthTopic).empty());
}

TEST(TumToBag, NamesAnUnreadablePng) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 4);
  const std::string bad = f.framePath(2);
  writeLines(bad, {"not an image"});
  expectFolderRefused(f, tmp, bad + ": not a PNG file");

  // A PNG cut short: libpng's complaint, with the file's name.
  const std::string good = f.framePath(1);
  std::ifstream in(good, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), {});
  std::ofstream(bad, std::ios::binary).write(bytes.data(), bytes.size() / 2);
  expectFolderRefused(f, tmp, bad + ": corrupt PNG");
}

TEST(TumToBag, NamesAFrameOfAnotherSize) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  writePng16(f.framePath(1), std::vector<std::uint16_t>(320 * 240, 10000), 320, 240);
  expectFolderRefused(f, tmp, f.framePath(1) + ": 320x240 image, the first frame is 640x480");
}

TEST(TumToBag, RefusesStampsOutOfOrder) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  auto ls = f.depth_lines;
  std::swap(ls[4], ls[5]);
  writeLines(f.dir + "/depth.txt", ls);
  expectFolderRefused(f, tmp, "depth.txt: frame 3");
}

TEST(TumToBag, AsksForIntrinsicsAndSuggestsTheCamera) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 2);
  expectFolderRefused(f, tmp, "--camera fr3", "");
  expectFolderRefused(f, tmp, "--fx --fy --cx --cy go together", "--fx 500 --fy 500");
  expectFolderRefused(f, tmp, "--camera 'fr4': expected fr1, fr2 or fr3", "--camera fr4");
  expectFolderRefused(f, tmp, "looks like units per metre", "--camera fr3 --depth-scale 5000");
  const std::string out = tmp.path + "/x.bag";
  // Explicit intrinsics are taken as given.
  const ToolRun r = runTool(f.dir + " " + out + " --fx 500 --fy 501 --cx 300 --cy 200", tmp.path);
  ASSERT_EQ(r.rc, 0) << r.output;
  const auto infos = readTopic<sensor_msgs::CameraInfo>(out, tum_bag::kInfoTopic);
  ASSERT_EQ(infos.size(), 2u);
  EXPECT_DOUBLE_EQ(conv::intrinsicsFromCameraInfo(*infos[0]).fy, 501.0);
  EXPECT_DOUBLE_EQ(conv::intrinsicsFromCameraInfo(*infos[0]).cy, 200.0);
}

TEST(TumToBag, KeepsAnExistingBag) {
  DT_TEDDY_OR_SKIP(teddy);
  TmpDir tmp;
  SmallFolder f(tmp.path, teddy, 3);
  const std::string out = tmp.path + "/x.bag";
  writeLines(out, {"an earlier recording"});
  const ToolRun r = runTool(f.dir + " " + out + " --camera fr3", tmp.path);
  EXPECT_EQ(r.rc, 2) << r.output;
  EXPECT_NE(r.output.find("exists; not overwritten"), std::string::npos) << r.output;
  EXPECT_EQ(lines(out), std::vector<std::string>{"an earlier recording"});

  // --overwrite that fails half-way (frame 3 unreadable) still leaves the earlier bag whole.
  writeLines(f.framePath(2), {"garbage"});
  const ToolRun failed = runTool(f.dir + " " + out + " --camera fr3 --overwrite", tmp.path);
  EXPECT_EQ(failed.rc, 1) << failed.output;
  EXPECT_EQ(lines(out), std::vector<std::string>{"an earlier recording"});
  EXPECT_FALSE(fs::exists(out + ".part"));

  fs::copy_file(f.framePath(0), f.framePath(2), fs::copy_options::overwrite_existing);
  const ToolRun ok = runTool(f.dir + " " + out + " --camera fr3 --overwrite", tmp.path);
  ASSERT_EQ(ok.rc, 0) << ok.output;
  EXPECT_EQ(readTopic<sensor_msgs::Image>(out, tum_bag::kDepthTopic).size(), 3u);
}
