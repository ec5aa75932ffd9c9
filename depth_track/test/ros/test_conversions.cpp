// The graph's one conversions header and its parameter tables, without a roscore: depth encodings,
// camera_info, the cell cloud round trip (bit for bit, so the graph registers exactly what the
// offline tools register), the pose covariance from the normal equations, and config/tracking.yaml
// against the tables it documents.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <set>

#include "depth_track/core/cells.hpp"
#include "depth_track/core/map/mapper_params.hpp"
#include "depth_track/core/registration.hpp"
#include "depth_track/core/se3.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/sim/scene.hpp"
#include "depth_track/core/tracker_params.hpp"
#include "depth_track/ros/conversions.hpp"
#include "depth_track/ros/params.hpp"

using namespace depth_track;

namespace {

sensor_msgs::Image image16(int w, int h, const std::vector<std::uint16_t>& v) {
  sensor_msgs::Image m;
  m.width = w, m.height = h, m.encoding = "16UC1", m.step = 2 * w;
  m.data.resize(v.size() * 2);
  std::memcpy(m.data.data(), v.data(), m.data.size());
  return m;
}
sensor_msgs::Image image32(int w, int h, const std::vector<float>& v) {
  sensor_msgs::Image m;
  m.width = w, m.height = h, m.encoding = "32FC1", m.step = 4 * w;
  m.data.resize(v.size() * 4);
  std::memcpy(m.data.data(), v.data(), m.data.size());
  return m;
}
std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

/// A rendered chair-room frame with L515 noise, as the rig's bags carry it.
DepthImage chairFrame(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C) {
  const auto scene = sim::chairRoomScene();
  const DepthRange range;
  const auto clean = sim::renderDepth(scene, K, T_W_C, range);
  return sim::applyNoise(clean, sim::NoiseConfig::forModel(sim::parseNoiseModel("l515")), 7, range);
}

}  // namespace

TEST(Conversions, DepthEncodingsGiveMetres) {
  const DepthRange range{0.1, 10.0};
  // 16UC1 in L515 units (0.25 mm): 4000 units = 1 m; 0 = no return, 65535 beyond range.
  const auto d16 = conv::depthFromMsg(image16(3, 1, {4000, 0, 65535}), 0.00025, range);
  EXPECT_FLOAT_EQ(d16.data[0], 1.0f);
  EXPECT_EQ(d16.data[1], 0.0f);
  EXPECT_EQ(d16.data[2], 0.0f);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  const auto d32 = conv::depthFromMsg(image32(4, 1, {1.0f, nan, inf, 0.0f}), 1.0, range);
  EXPECT_EQ(d32.data, (std::vector<float>{1.0f, 0.0f, 0.0f, 0.0f}));
  // mono16 is the same as 16UC1 (ROS drivers use both names).
  auto mono = image16(1, 1, {1500});
  mono.encoding = "mono16";
  EXPECT_FLOAT_EQ(conv::depthFromMsg(mono, 0.001, range).data[0], 1.5f);
}

TEST(Conversions, Depth32FromTheGraphRoundTripsExactly) {
  // ingest publishes 32FC1 with NaN for "no return"; pca_reduce reads it back: same floats.
  DepthImage d(4, 2);
  d.data = {0.6f, 0.0f, 1.2345678f, 3.999f, 0.0f, 2.5f, 0.53f, 1.0f};
  std_msgs::Header h;
  const auto msg = conv::depthToMsg(d, h);
  EXPECT_EQ(msg->encoding, "32FC1");
  EXPECT_TRUE(std::isnan(reinterpret_cast<const float*>(msg->data.data())[1]));
  EXPECT_EQ(conv::depthFromMsg(*msg, 1.0, DepthRange{}).data, d.data);
}

TEST(Conversions, BadImagesAreNamed) {
  const DepthRange range;
  auto rgb = image16(2, 2, {1, 2, 3, 4});
  rgb.encoding = "rgb8";
  EXPECT_NE(errorOf([&] { conv::depthFromMsg(rgb, 0.001, range); }).find("rgb8"),
            std::string::npos);
  auto be = image16(2, 2, {1, 2, 3, 4});
  be.is_bigendian = 1;
  EXPECT_NE(errorOf([&] { conv::depthFromMsg(be, 0.001, range); }).find("big-endian"),
            std::string::npos);
  auto short_step = image16(2, 2, {1, 2, 3, 4});
  short_step.step = 3;
  EXPECT_NE(errorOf([&] { conv::depthFromMsg(short_step, 0.001, range); }).find("step"),
            std::string::npos);
  auto truncated = image16(2, 2, {1, 2, 3, 4});
  truncated.data.resize(5);
  EXPECT_NE(errorOf([&] { conv::depthFromMsg(truncated, 0.001, range); }).find("holds 5 B"),
            std::string::npos);
  EXPECT_NE(errorOf([&] { conv::depthFromMsg(image16(2, 2, {1, 2, 3, 4}), 0.0, range); }), "");
}

TEST(Conversions, CameraInfoToIntrinsics) {
  sensor_msgs::CameraInfo ci;
  ci.width = 640, ci.height = 480;
  ci.K = {458, 0, 320, 0, 459, 240, 0, 0, 1};
  const PinholeIntrinsics k = conv::intrinsicsFromCameraInfo(ci);  // P zero: K is used
  EXPECT_EQ(k.width, 640);
  EXPECT_DOUBLE_EQ(k.fy, 459.0);
  ci.P = {400, 0, 321, 0, 0, 401, 241, 0, 0, 0, 1, 0};  // rectified projection wins
  const PinholeIntrinsics p = conv::intrinsicsFromCameraInfo(ci);
  EXPECT_DOUBLE_EQ(p.fx, 400.0);
  EXPECT_DOUBLE_EQ(p.cy, 241.0);
  sensor_msgs::CameraInfo zero;
  zero.width = 640, zero.height = 480;
  EXPECT_NE(errorOf([&] { conv::intrinsicsFromCameraInfo(zero); }).find("uncalibrated"),
            std::string::npos);
  sensor_msgs::CameraInfo nosize = ci;
  nosize.width = 0;
  EXPECT_NE(errorOf([&] { conv::intrinsicsFromCameraInfo(nosize); }).find("image size"),
            std::string::npos);
  sensor_msgs::CameraInfo binned = ci;
  binned.binning_x = 2;
  EXPECT_NE(errorOf([&] { conv::intrinsicsFromCameraInfo(binned); }).find("binning"),
            std::string::npos);
  EXPECT_NE(errorOf([&] {
              conv::checkImageMatchesInfo(image16(2, 2, {1, 2, 3, 4}), k);
            }).find("camera_info says 640x480"),
            std::string::npos);
}

TEST(Conversions, CellCloudRoundTripIsBitExact) {
  const PinholeIntrinsics K = sim::l515Intrinsics();
  Eigen::Isometry3d T_W_C = sim::makeRun("xtest1_05_chair").T_W_C.front();
  PcaConfig pca;  // Cell Search's configuration: inverse square roots filled too
  const CellCloud cells = reduceToCells(chairFrame(K, T_W_C), K, pca);
  ASSERT_GT(cells.cells.size(), 5000u);
  std_msgs::Header h;
  h.frame_id = "camera_depth_optical_frame";
  h.stamp = ros::Time(1700000001, 673000000);
  const auto msg = conv::cellsToCloud(cells, h);
  EXPECT_EQ(msg->width, static_cast<unsigned>(cells.grid_w));
  EXPECT_EQ(msg->height, static_cast<unsigned>(cells.grid_h));
  const auto back = conv::cellsFromCloud(*msg, K.width, K.height);
  // The header's stamp and frame reach the core's cloud (the stages report results at it).
  EXPECT_EQ(back->stamp_s, h.stamp.toSec());
  EXPECT_EQ(back->frame_id, h.frame_id);
  EXPECT_EQ(back->cell_size, cells.cell_size);
  EXPECT_EQ(back->grid_index, cells.grid_index);
  ASSERT_EQ(back->cells.size(), cells.cells.size());
  for (std::size_t i = 0; i < cells.cells.size(); ++i) {
    const Cell &a = cells.cells[i], &b = back->cells[i];
    ASSERT_EQ(a.gx, b.gx);
    ASSERT_EQ(a.gy, b.gy);
    ASSERT_EQ(a.n_valid, b.n_valid);
    ASSERT_TRUE(a.mean_C == b.mean_C) << i;
    ASSERT_TRUE(a.normal_C == b.normal_C) << i;
    ASSERT_TRUE(a.cov == b.cov) << i;
    ASSERT_TRUE(a.eigenvalues == b.eigenvalues) << i;
    ASSERT_TRUE(a.cov_inv_sqrt == b.cov_inv_sqrt) << i;
    ASSERT_EQ(a.surface_variation, b.surface_variation);
  }
  // What it is for: the next frame registers onto the cells that went through the message
  // exactly as onto the original ones, with every registration method.
  const Eigen::Isometry3d T_W_C1 = sim::makeRun("xtest1_05_chair").T_W_C[8];
  const CellCloud next = reduceToCells(chairFrame(K, T_W_C1), K, pca);
  for (auto method : {RegistrationMethod::kPointToPlane, RegistrationMethod::kCellSearch,
                      RegistrationMethod::kPointToPoint}) {
    RegistrationConfig rc;
    rc.method = method;
    const auto r0 = registerCells(cells, next, K, Eigen::Isometry3d::Identity(), rc);
    const auto r1 = registerCells(*back, next, K, Eigen::Isometry3d::Identity(), rc);
    EXPECT_EQ(r0.matches, r1.matches);
    EXPECT_TRUE(r0.T_ref_cur.matrix() == r1.T_ref_cur.matrix()) << toString(method);
  }
}

TEST(Conversions, CellsReducedWithoutSpectraArePublishedWithThem) {
  // The tracker's reduction leaves eigenvalues and surface variation out; the published cloud
  // solves them from the covariance, so rviz and other readers see the same fields.
  const PinholeIntrinsics K = sim::l515Intrinsics();
  const Eigen::Isometry3d T_W_C = sim::makeRun("xtest1_05_chair").T_W_C.front();
  PcaConfig with;
  with.compute_inv_sqrt = false;
  PcaConfig without = with;
  without.cell_spectra = false;
  const DepthImage depth = chairFrame(K, T_W_C);
  const CellCloud a = reduceToCells(depth, K, with), b = reduceToCells(depth, K, without);
  ASSERT_FALSE(b.has_spectra);
  std_msgs::Header h;
  h.frame_id = "camera_depth_optical_frame";
  const auto from_a = conv::cellsFromCloud(*conv::cellsToCloud(a, h), K.width, K.height);
  const auto from_b = conv::cellsFromCloud(*conv::cellsToCloud(b, h), K.width, K.height);
  EXPECT_TRUE(from_b->has_spectra);
  ASSERT_EQ(from_a->cells.size(), from_b->cells.size());
  ASSERT_GT(from_a->cells.size(), 5000u);
  int curved = 0;
  for (std::size_t i = 0; i < from_a->cells.size(); ++i) {
    const Cell &x = from_a->cells[i], &y = from_b->cells[i];
    // From the float covariance rather than the double one: equal to float precision of the
    // largest eigenvalue.
    ASSERT_LT((x.eigenvalues - y.eigenvalues).norm(), 1e-5f * x.eigenvalues(2)) << i;
    // lambda0 from a float covariance is good to ~1e-7 lambda2, so the curvature to ~1e-6 of
    // its own scale (values here run from ~1e-5 on the planes up).
    ASSERT_NEAR(x.surface_variation, y.surface_variation, 1e-6f) << i;
    ASSERT_GT(y.eigenvalues(2), 0.0f) << i;
    curved += y.surface_variation > 1e-4f;
  }
  EXPECT_GT(curved, 100);  // the curvature field carries values, not zeros
}

TEST(Conversions, BadCellCloudsAreNamed) {
  CellCloud c;
  c.cell_size = 5, c.grid_w = 4, c.grid_h = 3;
  c.grid_index.assign(12, -1);
  std_msgs::Header h;
  auto msg = conv::cellsToCloud(c, h);
  EXPECT_NE(errorOf([&] { conv::cellsFromCloud(*msg, 21, 15); }).find("does not tile"),
            std::string::npos);
  EXPECT_NO_THROW(conv::cellsFromCloud(*msg, 20, 15));
  msg->fields[3].name = "nx";
  EXPECT_NE(errorOf([&] { conv::cellsFromCloud(*msg, 20, 15); }).find("'nx'"), std::string::npos);
  auto cut = conv::cellsToCloud(c, h);
  cut->data.resize(100);
  EXPECT_NE(errorOf([&] { conv::cellsFromCloud(*cut, 20, 15); }).find("holds 100 B"),
            std::string::npos);
}

TEST(Conversions, CorruptPosesAreRejected) {
  geometry_msgs::Pose p;
  p.orientation.w = 1.0;
  p.position.x = 1.5;
  EXPECT_NEAR(conv::fromPoseMsg(p).translation().x(), 1.5, 0);
  geometry_msgs::Pose zero_q = p;
  zero_q.orientation.w = 0.0;
  EXPECT_NE(errorOf([&] { conv::fromPoseMsg(zero_q); }).find("quaternion"), std::string::npos);
  geometry_msgs::Pose nan = p;
  nan.position.y = std::nan("");
  EXPECT_NE(errorOf([&] { conv::fromPoseMsg(nan); }).find("non-finite"), std::string::npos);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = expSO3(Eigen::Vector3d(0.3, -0.2, 1.1));
  T.translation() = Eigen::Vector3d(1, 2, 3);
  EXPECT_TRUE(conv::fromTransformMsg(conv::toTransformMsg(T)).isApprox(T, 1e-12));
}

TEST(Conversions, PoseCovarianceMatchesSampledPerturbations) {
  // Sample increments [omega; v] with covariance sigma^2 H^-1 in the reference frame, apply them
  // as the registration does (on the left of T_ref_body), and measure the body's position and
  // rotation in the parent frame: their covariance must be the converted one.
  Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Random();
  const Eigen::Matrix<double, 6, 6> H =
      A * A.transpose() * 1e4 + 1e3 * Eigen::Matrix<double, 6, 6>::Identity();
  const double sigma = 0.004;
  Eigen::Isometry3d T_P_ref = Eigen::Isometry3d::Identity();
  T_P_ref.linear() = expSO3(Eigen::Vector3d(0.4, 0.1, -0.7));
  T_P_ref.translation() = Eigen::Vector3d(0.8, -1.2, 0.5);
  Eigen::Isometry3d T_ref_body = Eigen::Isometry3d::Identity();
  T_ref_body.linear() = expSO3(Eigen::Vector3d(-0.2, 0.3, 0.1));
  T_ref_body.translation() = Eigen::Vector3d(0.3, 0.1, 1.0);
  const Eigen::Isometry3d T_P_body = T_P_ref * T_ref_body;
  const auto cov = conv::poseCovariance(H, sigma, T_P_ref, T_P_body.translation());

  const Eigen::Matrix<double, 6, 6> cov_ref = sigma * sigma * H.inverse();
  const Eigen::Matrix<double, 6, 6> L = cov_ref.llt().matrixL();
  std::mt19937 rng(3);
  std::normal_distribution<double> n01;
  const int n = 20000;
  Eigen::Matrix<double, 6, 6> emp = Eigen::Matrix<double, 6, 6>::Zero();
  for (int i = 0; i < n; ++i) {
    Vector6d z;
    for (int k = 0; k < 6; ++k) z(k) = n01(rng);
    const Vector6d xi = L * z;
    const Eigen::Isometry3d T = T_P_ref * expIncrement(xi) * T_ref_body;
    Vector6d d;
    d.head<3>() = T.translation() - T_P_body.translation();
    const Eigen::AngleAxisd aa(T.rotation() * T_P_body.rotation().transpose());
    d.tail<3>() = aa.angle() * aa.axis();
    emp += d * d.transpose() / n;
  }
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) {
      // Sampling error of a covariance entry: sqrt((s_rr s_cc + s_rc^2) / n), 5 of them.
      const double tol = 5.0 * std::sqrt((emp(r, r) * emp(c, c) + emp(r, c) * emp(r, c)) / n);
      EXPECT_NEAR(cov[r * 6 + c], emp(r, c), tol) << r << "," << c;
    }
  // A direction the scene does not constrain shows as a large variance, not as a NaN.
  Eigen::Matrix<double, 6, 6> flat = H;
  flat.row(3).setZero();
  flat.col(3).setZero();
  const auto cov_flat = conv::poseCovariance(flat, sigma, Eigen::Isometry3d::Identity(),
                                             Eigen::Vector3d::Zero(), 1e3);
  EXPECT_NEAR(cov_flat[0], 1e3, 1.0);  // v_x unconstrained -> x
  for (double v : cov_flat) EXPECT_TRUE(std::isfinite(v));
}

// The odometry's covariance is over [omega; u] about the camera centre c (FrameStatus): the
// same uncertainty written about the reference origin, [omega; v] with v = u - omega x c, must
// give the same ROS covariance through the normal-matrix path checked above by sampling.
TEST(Conversions, IncrementCovarianceAboutTheCameraCentreMatchesTheNormalMatrixPath) {
  Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Random();
  const Eigen::Matrix<double, 6, 6> cov_u =
      1e-6 * (A * A.transpose() + Eigen::Matrix<double, 6, 6>::Identity());
  Eigen::Isometry3d T_P_ref = Eigen::Isometry3d::Identity();
  T_P_ref.linear() = expSO3(Eigen::Vector3d(0.4, 0.1, -0.7));
  T_P_ref.translation() = Eigen::Vector3d(0.8, -1.2, 0.5);
  const Eigen::Vector3d c_ref(0.3, 0.1, 1.0), p_P(1.5, -0.4, 0.9);
  Eigen::Matrix3d cx;
  cx << 0, -c_ref.z(), c_ref.y(), c_ref.z(), 0, -c_ref.x(), -c_ref.y(), c_ref.x(), 0;
  Eigen::Matrix<double, 6, 6> B = Eigen::Matrix<double, 6, 6>::Identity();
  B.block<3, 3>(3, 0) = cx;  // v = u + c x omega
  const Eigen::Matrix<double, 6, 6> cov_v = B * cov_u * B.transpose();
  const auto a = conv::poseCovarianceOfIncrement(cov_u, T_P_ref.rotation(), T_P_ref * c_ref, p_P);
  const auto b = conv::poseCovariance(cov_v.inverse(), 1.0, T_P_ref, p_P);
  for (int i = 0; i < 36; ++i) EXPECT_NEAR(a[i], b[i], 1e-9 * (1.0 + std::abs(b[i]))) << i;
}

// ---- config/tracking.yaml against the tables ---------------------------------------------------

namespace {

const std::string kConfig = std::string(DT_SOURCE_DIR) + "/../config/tracking.yaml";

/// The comment on each key's line, per section.
std::map<std::string, std::map<std::string, std::string>> commentsOf(const std::string& path) {
  std::map<std::string, std::map<std::string, std::string>> out;
  std::ifstream in(path);
  std::string line, section;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    const auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    const auto hash = line.find('#');
    const std::string comment = hash == std::string::npos ? "" : line.substr(hash + 1);
    if (line[0] != ' ') {
      section = line.substr(0, colon);
      continue;
    }
    const auto first = line.find_first_not_of(' ');
    out[section][line.substr(first, colon - first)] = comment;
  }
  return out;
}

template <class Config>
void expectSectionAtDefaults(const YAML::Node& section, const std::string& name,
                             const std::vector<BasicParamSpec<Config>>& table,
                             const std::map<std::string, std::string>& comments) {
  const Config defaults;
  std::set<std::string> seen;
  ASSERT_TRUE(section.IsMap()) << name;
  for (const auto& kv : section) {
    const std::string key = kv.first.as<std::string>();
    seen.insert(key);
    const BasicParamSpec<Config>* spec = nullptr;
    for (const auto& p : table)
      if (p.name == key) spec = &p;
    ASSERT_NE(spec, nullptr) << name << "/" << key << " is not a parameter";
    Config from_file;
    spec->set(from_file, kv.second.as<std::string>());
    EXPECT_EQ(spec->get(from_file), spec->get(defaults))
        << name << "/" << key << " in tracking.yaml differs from the code's default";
    const std::string comment = comments.count(key) ? comments.at(key) : "";
    EXPECT_GT(comment.size(), 10u) << name << "/" << key << " has no meaning documented";
    if (!spec->unit.empty()) {
      EXPECT_NE(comment.find("[" + spec->unit + "]"), std::string::npos)
          << name << "/" << key << ": unit [" << spec->unit << "] not documented";
    }
  }
  for (const auto& p : table)
    EXPECT_TRUE(seen.count(p.name)) << name << "/" << p.name << " missing";
}

}  // namespace

TEST(TrackingYaml, StageTablesDocumentedAtTheirDefaults) {
  const YAML::Node root = YAML::LoadFile(kConfig);
  const auto comments = commentsOf(kConfig);
  expectSectionAtDefaults(root["tracker"], "tracker", trackerParams(), comments.at("tracker"));
  expectSectionAtDefaults(root["mapper"], "mapper", mapperParams(), comments.at("mapper"));
}

TEST(TrackingYaml, NodeletParametersDocumentedAtTheirDefaults) {
  const YAML::Node root = YAML::LoadFile(kConfig);
  const auto comments = commentsOf(kConfig);
  std::set<std::string> sections = {"tracker", "mapper"};
  for (const std::string& node : rosparams::nodeNames()) {
    sections.insert(node);
    const YAML::Node sec = root[node];
    ASSERT_TRUE(sec && sec.IsMap()) << node << " section missing";
    std::set<std::string> seen;
    for (const auto& kv : sec) {
      const std::string key = kv.first.as<std::string>();
      seen.insert(key);
      const rosparams::NodeParamSpec* spec = nullptr;
      for (const auto& p : rosparams::nodeParams())
        if (p.node == node && p.name == key) spec = &p;
      ASSERT_NE(spec, nullptr) << node << "/" << key << " is not a parameter";
      const std::string v = kv.second.as<std::string>();
      if (spec->type == 'd' || spec->type == 'i') {
        EXPECT_DOUBLE_EQ(param_text::toDouble(key, v),
                         param_text::toDouble(key, spec->default_text))
            << node << "/" << key;
      } else if (spec->type == 'b') {
        EXPECT_EQ(param_text::toBool(key, v), param_text::toBool(key, spec->default_text)) << key;
      } else {
        EXPECT_EQ(v, spec->default_text) << node << "/" << key;
      }
      const std::string comment = comments.at(node).count(key) ? comments.at(node).at(key) : "";
      EXPECT_GT(comment.size(), 10u) << node << "/" << key << " has no meaning documented";
      if (!spec->unit.empty()) {
        EXPECT_NE(comment.find("[" + spec->unit + "]"), std::string::npos)
            << node << "/" << key << ": unit [" << spec->unit << "] not documented";
      }
    }
    for (const auto& p : rosparams::nodeParams())
      if (p.node == node) {
        EXPECT_TRUE(seen.count(p.name)) << node << "/" << p.name << " missing";
      }
  }
  for (const auto& kv : root)
    EXPECT_TRUE(sections.count(kv.first.as<std::string>())) << kv.first.as<std::string>();
}

namespace {

/// The stage table's validate() on the defaults with one parameter set to `text`.
template <class Config, class Validate>
std::vector<std::string> problemsWith(const std::vector<BasicParamSpec<Config>>& table,
                                      const std::string& name, const std::string& text,
                                      Validate validate) {
  Config c;
  setParam(table, c, name, text, "test");
  return validate(c);
}

template <class Config, class Validate>
void expectRangeWithinValidate(const rosparams::ReconfigurableSpec& r,
                               const std::vector<BasicParamSpec<Config>>& table,
                               Validate validate) {
  const BasicParamSpec<Config>* row = nullptr;
  for (const auto& p : table) row = p.name == r.name ? &p : row;
  ASSERT_NE(row, nullptr) << r.name << " is not in the " << r.table << " table";
  const std::string dflt = row->get(Config{});
  if (r.type == 's') {
    EXPECT_NE(std::find(r.choices.begin(), r.choices.end(), dflt), r.choices.end())
        << r.name << ": default " << dflt << " is not among the choices";
    for (const auto& c : r.choices)
      EXPECT_TRUE(problemsWith(table, r.name, c, validate).empty()) << r.name << " = " << c;
    EXPECT_THROW(problemsWith(table, r.name, "no_such_choice", validate), std::invalid_argument)
        << r.name;
    return;
  }
  const double d = param_text::toDouble(r.name, dflt);
  EXPECT_GE(d, r.min) << r.name << ": default below the reconfigure range";
  EXPECT_LE(d, r.max) << r.name << ": default above the reconfigure range";
  // Both ends of what the server offers must pass the stage's own validate().
  for (double v : {r.min, r.max}) {
    const auto p = problemsWith(table, r.name, param_text::format(v), validate);
    EXPECT_TRUE(p.empty()) << r.name << " = " << v << ": " << (p.empty() ? "" : p.front());
  }
  if (r.type == 'i') {  // the member is an int: a fraction must not pass as one
    EXPECT_THROW(problemsWith(table, r.name, "1.5", validate), std::invalid_argument) << r.name;
  }
}

}  // namespace

TEST(Reconfigure, RangesLieWithinTheStagesValidationAndHoldTheDefaults) {
  const PinholeIntrinsics K{640, 480, 500, 500, 319.5, 239.5};
  int tracker = 0, mapper = 0, node = 0;
  for (const auto& r : rosparams::reconfigurableParams()) {
    SCOPED_TRACE(r.node + "/" + r.name);
    if (r.table == "tracker") {
      ++tracker;
      expectRangeWithinValidate(r, trackerParams(),
                                [&K](const TrackerConfig& c) { return c.validate(K); });
    } else if (r.table == "mapper") {
      ++mapper;
      expectRangeWithinValidate(r, mapperParams(),
                                [&K](const MapperConfig& c) { return c.validate(K); });
    } else {
      ++node;
      const rosparams::NodeParamSpec* spec = nullptr;
      for (const auto& p : rosparams::nodeParams())
        spec = p.node == r.node && p.name == r.name ? &p : spec;
      ASSERT_NE(spec, nullptr);
      EXPECT_EQ(spec->type, 'd') << "node parameters bind as doubles";
      EXPECT_EQ(r.min, spec->min);
      EXPECT_EQ(r.max, spec->max);
    }
  }
  EXPECT_GE(tracker, 10);  // method, gates, iterations, FM gate, prefilter
  EXPECT_GE(mapper, 5);    // cl_step and the loop-closure gates
  EXPECT_EQ(node, 2);      // ingest's range limits
}
