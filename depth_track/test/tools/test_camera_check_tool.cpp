// camera_check the tool: a bag of a known camera (rendered L515-like frames of the calibration
// target at three stations with the camera moving between them, 16UC1 in 0.25 mm units recorded
// in the connection header, camera_info) is split into its still periods and measured; the YAML
// it writes holds the camera's bias, noise and CAM_K; the plots are written. A TUM-layout folder
// is read too, and bad input (wrong encoding, a segment without frames, distances that do not
// match the segments, no intrinsics) is refused with a message naming it. Runs the tool itself;
// no roscore.
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tum_io.hpp"
#include "tool_test.hpp"
#include "tum_bag.hpp"

#ifndef CAMERA_CHECK
#error "CAMERA_CHECK must name the camera_check executable"
#endif

namespace fs = std::filesystem;
using namespace depth_track;
using namespace depth_track::sim;

namespace {

constexpr double kTrueK = 460.0;  // in camera_info too: the tool must read it from there
constexpr double kBias = 0.005;
const std::vector<double> kStations = {0.8, 1.5, 2.5};

using tool_test::TmpDir;
using tool_test::ToolRun;

ToolRun runTool(const std::string& args, const std::string& log_dir) {
  return tool_test::runTool(CAMERA_CHECK, args, log_dir);
}

PinholeIntrinsics camera() { return PinholeIntrinsics::isotropic(640, 480, kTrueK); }

NoiseConfig noise() {
  NoiseConfig c = NoiseConfig::forModel(NoiseModel::kL515);
  c.depth_scale_bias = kBias;
  return c;
}

/// Camera pose `d` in front of the target's face.
Eigen::Isometry3d cameraAt(double d) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = rotationBodyFromOptical();
  T.translation() = Eigen::Vector3d(-d, 0.0, 1.0);
  return T;
}

/// The camera's distance at each frame: 1.5 s still at every station, 0.5 s moving between.
std::vector<double> schedule() {
  std::vector<double> d;
  for (std::size_t k = 0; k < kStations.size(); ++k) {
    if (k > 0)
      for (int i = 1; i <= 15; ++i)
        d.push_back(kStations[k - 1] + (kStations[k] - kStations[k - 1]) * i / 16.0);
    for (int i = 0; i < 45; ++i) d.push_back(kStations[k]);
  }
  return d;
}

sensor_msgs::Image imageMsg(const RawDepth16& raw, const ros::Time& t, std::uint32_t seq) {
  sensor_msgs::Image img;
  img.header.stamp = t;
  img.header.seq = seq;
  img.header.frame_id = tum_bag::kOpticalFrame;
  img.width = raw.width;
  img.height = raw.height;
  img.encoding = "16UC1";
  img.step = 2 * raw.width;
  img.data.resize(raw.data.size() * 2);
  std::memcpy(img.data.data(), raw.data.data(), img.data.size());
  return img;
}

/// A bag of the schedule; `encoding` replaces the image encoding (for the bad-input case).
void writeBag(const std::string& path, const std::string& encoding = "16UC1") {
  const Scene scene = calibrationTargetScene();
  const double unit = nativeDepthScale(NoiseModel::kL515);
  rosbag::Bag bag(path, rosbag::bagmode::Write);
  const std::map<std::string, std::string> scale = {{tum_bag::kDepthScaleKey, "0.00025"}};
  const auto image_hdr = tum_bag::connectionHeader<sensor_msgs::Image>("/test", scale);
  const auto info_hdr = tum_bag::connectionHeader<sensor_msgs::CameraInfo>("/test", scale);
  const std::vector<double> d = schedule();
  const DepthRange range;
  for (std::size_t i = 0; i < d.size(); ++i) {
    const ros::Time t(1700000000.0 + i / 30.0);
    const RenderedDepth clean = renderDepthWithIncidence(scene, camera(), cameraAt(d[i]), range);
    const DepthImage noisy =
        applyNoise(clean.depth, noise(), frameSeed(7, i), range, &clean.cos_incidence);
    sensor_msgs::Image img = imageMsg(toRaw16(noisy, unit), t, i);
    img.encoding = encoding;
    bag.write(tum_bag::kDepthTopic, t, img, image_hdr);
    bag.write(tum_bag::kInfoTopic, t, tum_bag::cameraInfoMsg(camera(), t, tum_bag::kOpticalFrame),
              info_hdr);
  }
  bag.close();
}

}  // namespace

TEST(CameraCheckTool, BagOfStationsMeasured) {
  TmpDir tmp;
  const std::string bag = tmp.path + "/calib.bag", yaml = tmp.path + "/cam.yaml";
  writeBag(bag);
  const ToolRun r = runTool(bag + " --distances 0.8,1.5,2.5 --diameter 0.6 --out " + yaml +
                                " --plots " + tmp.path + "/plots",
                            tmp.path);
  std::printf("%s", r.output.c_str());
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("camera_check: 3 segments"), std::string::npos);
  EXPECT_NE(r.output.find("CAM_K = "), std::string::npos);

  const YAML::Node doc = YAML::LoadFile(yaml);
  const YAML::Node segs = doc["camera_check"]["segments"];
  ASSERT_EQ(segs.size(), 3u);
  const NoiseConfig n = noise();
  for (std::size_t k = 0; k < 3; ++k) {
    SCOPED_TRACE(k);
    const YAML::Node s = segs[k];
    EXPECT_TRUE(s["target_found"].as<bool>()) << s["target_note"].as<std::string>();
    // Still frames only: 1.5 s stations less 0.2 s trimmed at each end, 45 frames at most.
    EXPECT_GE(s["frames"].as<int>(), 30);
    EXPECT_LE(s["frames"].as<int>(), 45);
    EXPECT_NEAR(s["error_pct"].as<double>(), 100.0 * kBias, 0.1);
    const double z = s["camera_depth_m"].as<double>();
    EXPECT_NEAR(s["sigma_spatial_m"].as<double>(), n.sigmaAt(z), 0.1 * n.sigmaAt(z));
    EXPECT_NEAR(s["cam_k_px"].as<double>(), kTrueK, 0.005 * kTrueK);
  }
  const YAML::Node fit = doc["camera_check"]["fit"];
  EXPECT_NEAR(fit["depth_scale"].as<double>(), 1.0 + kBias, 0.001);
  EXPECT_NEAR(fit["cam_k_px"].as<double>(), kTrueK, 0.005 * kTrueK);
  EXPECT_NEAR(doc["noise_model"]["depth_scale_bias"].as<double>(), kBias, 0.001);
  EXPECT_EQ(doc["noise_model"]["base"].as<std::string>(), "l515");
  EXPECT_NEAR(doc["noise_model"]["quantum_m"].as<double>(), 0.00025, 1e-12);
  EXPECT_NEAR(doc["depth_correction"]["scale"].as<double>(), 1.0 + kBias, 0.001);
  for (const char* png : {"sigma_vs_distance.png", "bias_vs_distance.png", "focal_vs_distance.png",
                          "edge_spread.png"}) {
    const fs::path p = fs::path(tmp.path) / "plots" / png;
    EXPECT_TRUE(fs::exists(p)) << p;
    if (fs::exists(p)) {
      EXPECT_GT(fs::file_size(p), 10000u) << p;
    }
  }

  if (const char* keep = std::getenv("DT_CAMERA_CHECK_KEEP"))  // to look at the plots
    fs::copy(tmp.path, keep, fs::copy_options::recursive | fs::copy_options::overwrite_existing);

  // Explicit ranges instead of still periods; a range outside the recording is named.
  const ToolRun ranges =
      runTool(bag + " --segment 0.2:1.3 --segment 2.2:3.3 --distances 0.8,1.5", tmp.path);
  EXPECT_EQ(ranges.rc, 0) << ranges.output;
  const ToolRun empty = runTool(bag + " --segment 50:60", tmp.path);
  EXPECT_EQ(empty.rc, 2);
  EXPECT_NE(empty.output.find("--segment 50:60: no frames in this time range"), std::string::npos)
      << empty.output;
  const ToolRun count = runTool(bag + " --distances 0.8,1.5", tmp.path);
  EXPECT_EQ(count.rc, 2);
  EXPECT_NE(count.output.find("--distances gives 2 distances for the 3 segments found"),
            std::string::npos)
      << count.output;
}

TEST(CameraCheckTool, BadInputNamed) {
  TmpDir tmp;
  const std::string bag = tmp.path + "/rgb.bag";
  writeBag(bag, "rgb8");
  const ToolRun enc = runTool(bag, tmp.path);
  EXPECT_EQ(enc.rc, 1);
  EXPECT_NE(enc.output.find("/camera/image_rect message 0: unsupported depth encoding 'rgb8'"),
            std::string::npos)
      << enc.output;

  const ToolRun missing = runTool(tmp.path + "/nothing.bag", tmp.path);
  EXPECT_EQ(missing.rc, 2);
  EXPECT_NE(missing.output.find("no such bag or folder"), std::string::npos) << missing.output;

  // A TUM folder needs intrinsics; a camera looking at nothing has no still depth.
  const std::string dir = tmp.path + "/tum";
  fs::create_directories(dir + "/depth");
  std::ofstream list(dir + "/depth.txt");
  for (int i = 0; i < 40; ++i) {
    const std::string name = "depth/" + std::to_string(i) + ".png";
    saveTumDepth(dir + "/" + name, DepthImage(640, 480, 0.0f), 0.0002);
    list << i / 30.0 << " " << name << "\n";
  }
  list.close();
  const ToolRun no_k = runTool(dir, tmp.path);
  EXPECT_EQ(no_k.rc, 2);
  EXPECT_NE(no_k.output.find("give its intrinsics"), std::string::npos) << no_k.output;
  const ToolRun blank = runTool(dir + " --fx 460 --fy 460 --cx 320 --cy 240", tmp.path);
  EXPECT_EQ(blank.rc, 2);
  EXPECT_NE(blank.output.find("has no return in any frame"), std::string::npos) << blank.output;
  const ToolRun planar =
      runTool(dir + " --fx 460 --fy 460 --cx 320 --cy 240 --segment 0:1", tmp.path);
  EXPECT_EQ(planar.rc, 1);
  EXPECT_NE(planar.output.find("no planar region at pixel (320, 240)"), std::string::npos)
      << planar.output;
}

// A TUM-layout folder of a wall (the flat-wall test): bias and noise, focal check skipped.
TEST(CameraCheckTool, TumFolderOfAWall) {
  TmpDir tmp;
  const std::string dir = tmp.path + "/wall";
  fs::create_directories(dir + "/depth");
  std::ofstream list(dir + "/depth.txt");
  const Scene wall = calibrationTargetScene(0.6, 0.6, false);
  const DepthRange range;
  const RenderedDepth clean = renderDepthWithIncidence(wall, camera(), cameraAt(1.5), range);
  for (int i = 0; i < 40; ++i) {
    const std::string name = "depth/" + std::to_string(i) + ".png";
    saveTumDepth(dir + "/" + name,
                 applyNoise(clean.depth, noise(), frameSeed(3, i), range, &clean.cos_incidence),
                 0.0002);
    list << 100.0 + i / 30.0 << " " << name << "\n";
  }
  list.close();
  const ToolRun r = runTool(
      dir + " --fx 460 --fy 460 --cx 320 --cy 240 --distances 1.5 --out " + tmp.path + "/wall.yaml",
      tmp.path);
  std::printf("%s", r.output.c_str());
  ASSERT_EQ(r.rc, 0) << r.output;
  EXPECT_NE(r.output.find("focal check skipped: no target diameter given"), std::string::npos);
  const YAML::Node s = YAML::LoadFile(tmp.path + "/wall.yaml")["camera_check"]["segments"][0];
  EXPECT_NEAR(s["error_pct"].as<double>(), 100.0 * kBias, 0.1);
  const double z = s["camera_depth_m"].as<double>();
  // TUM units are 0.2 mm: their quantisation adds 0.06 mm in quadrature, 2 % of sigma here.
  EXPECT_NEAR(s["sigma_spatial_m"].as<double>(), noise().sigmaAt(z), 0.1 * noise().sigmaAt(z));
}
