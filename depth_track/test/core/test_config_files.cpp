// config/*.yaml against the parameter table: the documented defaults are the code's defaults,
// every parameter is documented, and bad files are rejected naming file, line and key.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <fstream>
#include <set>

#include "depth_track/core/tracker_params.hpp"

using namespace depth_track;

namespace {
const std::string kConfigDir = std::string(DT_SOURCE_DIR) + "/../config";
}

TEST(ConfigFiles, TrackerYamlListsEveryParameterAtItsDefault) {
  const YAML::Node root = YAML::LoadFile(kConfigDir + "/tracker.yaml");
  const TrackerConfig defaults;
  std::set<std::string> seen;
  for (const auto& kv : root) {
    const std::string key = kv.first.as<std::string>();
    seen.insert(key);
    TrackerConfig from_file;
    setTrackerParam(from_file, key, kv.second.as<std::string>());
    bool known = false;
    for (const ParamSpec& p : trackerParams())
      if (p.name == key) {
        known = true;
        EXPECT_EQ(p.get(from_file), p.get(defaults))
            << key << " in tracker.yaml differs from the code's default";
      }
    EXPECT_TRUE(known) << key;
  }
  for (const ParamSpec& p : trackerParams())
    EXPECT_TRUE(seen.count(p.name)) << p.name << " is not documented";
}

TEST(ConfigFiles, OverridesLoadAndValidate) {
  TrackerConfig cfg;
  loadTrackerParamsYaml(kConfigDir + "/tum_kinect.yaml", cfg);
  EXPECT_EQ(cfg.pca.cell_size, 10);
  EXPECT_EQ(cfg.pca.normal_radius_cells, 2);
  EXPECT_TRUE(cfg.validate(PinholeIntrinsics{640, 480, 535.4, 539.2, 320.1, 247.6}).empty());
  TrackerConfig d435;
  loadTrackerParamsYaml(kConfigDir + "/d435.yaml", d435);
  EXPECT_EQ(d435.pca.cell_size, 10);
  EXPECT_EQ(d435.prefilter.type, PrefilterType::kBilateral);
  EXPECT_TRUE(d435.validate(PinholeIntrinsics{640, 480, 385.0, 385.0, 319.5, 239.5}).empty());
}

TEST(ConfigFiles, BadValuesNameFileLineAndKey) {
  const std::string path = ::testing::TempDir() + "/bad_tracker.yaml";
  std::ofstream(path) << "cell_size: 5\nmethod: icp\n";
  try {
    TrackerConfig cfg;
    loadTrackerParamsYaml(path, cfg);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("bad_tracker.yaml:2"), std::string::npos) << what;
    EXPECT_NE(what.find("icp"), std::string::npos) << what;
  }
  std::ofstream(path) << "cell_sise: 5\n";
  TrackerConfig cfg;
  EXPECT_THROW(loadTrackerParamsYaml(path, cfg), std::invalid_argument);
  EXPECT_THROW(setTrackerParam(cfg, "dist_min", "abc"), std::invalid_argument);
  EXPECT_THROW(setTrackerParam(cfg, "robust", "maybe"), std::invalid_argument);
  setTrackerParam(cfg, "robust", "off");
  EXPECT_FALSE(cfg.registration.robust);
}
