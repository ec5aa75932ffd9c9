// camera_check's measuring core on rendered frames of a known camera: a 0.6 m disc in front of a
// wall at the distances of the thesis's table 4.2, rendered with a focal constant that differs
// from the nominal one the measurement is given (so CAM_K must come from the outline), a depth
// scale error, and the L515 / D435 noise models.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "depth_track/core/camera_check.hpp"
#include "depth_track/core/depth_correction.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

using namespace depth_track;
using namespace depth_track::sim;

namespace {

const std::vector<double> kThesisDistances = {0.56, 0.6, 0.76, 1.2,  1.47, 1.77,
                                              2.0,  2.2, 2.47, 2.75, 3.0};
constexpr double kDiameter = 0.6;
constexpr double kWallGap = 0.6;  // wall behind the target's face, m

/// A camera `distance_m` in front of the calibration target's face (or of the wall alone),
/// looking at it square on.
Eigen::Isometry3d cameraAt(double distance_m) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = rotationBodyFromOptical();
  T.translation() = Eigen::Vector3d(-distance_m, 0.0, 1.0);
  return T;
}

/// `frames` noisy frames of the set-up seen by a camera whose true focal constant is true_k_px.
SegmentFrames recordSegment(double distance_m, bool disc, const NoiseConfig& noise, int frames,
                            double true_k_px, std::uint64_t seed) {
  const PinholeIntrinsics K = PinholeIntrinsics::isotropic(640, 480, true_k_px);
  const DepthRange range;
  const RenderedDepth clean = renderDepthWithIncidence(
      calibrationTargetScene(kDiameter, kWallGap, disc), K, cameraAt(distance_m), range);
  SegmentFrames seg;
  seg.label = std::to_string(distance_m).substr(0, 4) + " m";
  seg.reference_distance_m = distance_m;
  for (int f = 0; f < frames; ++f)
    seg.frames.push_back(
        applyNoise(clean.depth, noise, frameSeed(seed, f), range, &clean.cos_incidence));
  return seg;
}

struct Measured {
  std::vector<SegmentResult> segments;
  CameraCheckFit fit;
};

Measured measureAll(const std::vector<double>& distances, bool disc, const NoiseConfig& noise,
                    double true_k_px, const CameraCheckConfig& cfg, int frames = 30) {
  Measured run;
  const PinholeIntrinsics nominal = l515Intrinsics();
  std::uint64_t seed = 11;
  for (double d : distances)
    run.segments.push_back(
        measureSegment(recordSegment(d, disc, noise, frames, true_k_px, seed++), nominal, cfg));
  run.fit = fitCameraModel(run.segments, cfg);
  std::printf("%s", formatCameraCheckTable(run.segments, run.fit, cfg).c_str());
  return run;
}

/// 12-88 % width of the edge spread the renderer's lateral blur produces: each pixel near an
/// edge reports the depth of a neighbour offset by round(sigma g) pixels (clamped) along u and v,
/// so across the outline's directions the offset along the normal has the variance of one
/// rounded, clamped Gaussian; for a near-Gaussian spread the width is 2 x 1.175 sd.
double expectedEdgeSpread(const NoiseConfig& c) {
  const double sigma = c.lateral_fwhm_px / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  auto Phi = [](double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); };
  double var = 0.0;
  for (int k = -c.max_jitter_px; k <= c.max_jitter_px; ++k) {
    const double lo = k == -c.max_jitter_px ? 0.0 : Phi((k - 0.5) / sigma);
    const double hi = k == c.max_jitter_px ? 1.0 : Phi((k + 0.5) / sigma);
    var += k * k * (hi - lo);
  }
  return 2.0 * 1.1750 * std::sqrt(var);
}

std::string tempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("dt_test_camera_check_" + name)).string();
}

}  // namespace

// The L515-like camera: sigma 1.5 mm + 1.1 mm/m z, 2.4 px lateral blur, edge drop-outs, 0.25 mm
// units, reading 0.63 % long (the thesis's table 4.2 fit), true focal constant 461 px where the
// nominal intrinsics say 458. Every figure is recovered within the tolerances: sigma 10 %
// at each distance (its estimate from ~1e5 face pixels x 30 frames is good to < 1 %), bias 0.1 %
// of depth (the plane's mean over 1e5 pixels is good to microns), CAM_K 0.5 % (the outline is
// located to ~0.1 px on 100-500 px diameters).
TEST(CameraCheck, L515LikeCameraRecovered) {
  NoiseConfig noise = NoiseConfig::forModel(NoiseModel::kL515);
  noise.depth_scale_bias = 0.0063;
  const double true_k = 461.0;
  CameraCheckConfig cfg;
  cfg.target_diameter_m = kDiameter;
  cfg.depth_unit_m = nativeDepthScale(NoiseModel::kL515);
  const Measured run = measureAll(kThesisDistances, true, noise, true_k, cfg);
  const double spread = expectedEdgeSpread(noise);
  for (const SegmentResult& r : run.segments) {
    SCOPED_TRACE(r.label);
    const double d = r.reference_distance_m;
    ASSERT_TRUE(r.target_found) << r.target_note;
    EXPECT_NEAR(r.camera_depth_m, 1.0063 * d, 0.001 * d);
    EXPECT_NEAR(r.error_pct, 0.63, 0.1);
    const double sigma = noise.sigmaAt(r.camera_depth_m);
    EXPECT_NEAR(r.sigma_spatial_m, sigma, 0.1 * sigma);
    EXPECT_NEAR(r.sigma_temporal_m, sigma, 0.1 * sigma);
    // Random drop-outs only on the face (0.1 %): the edge band is left out of it.
    EXPECT_NEAR(r.dropout_share, noise.random_dropout_prob, 0.001);
    EXPECT_LT(r.tilt_deg, 0.5);
    EXPECT_NEAR(r.cam_k_px, true_k, 0.005 * true_k);
    // The camera's depth and the nominal 458 px: the diameter reads 0.63 % + 461/458 - 1 long.
    EXPECT_NEAR(r.diameter_est_m, kDiameter * 1.0063 * true_k / 458.0, 0.005 * kDiameter);
    EXPECT_NEAR(r.edge_spread_px, spread, 0.1 * spread);
    EXPECT_GT(r.edge_asymmetry, 0.67);
    EXPECT_LT(r.edge_asymmetry, 1.5);
  }
  const CameraCheckFit& f = run.fit;
  ASSERT_TRUE(f.depth_fitted);
  EXPECT_NEAR(f.depth_scale, 1.0063, 0.001);
  EXPECT_NEAR(f.depth_offset_m, 0.0, 0.001);
  EXPECT_EQ(f.sigma_terms, 3);
  for (double z : kThesisDistances) {
    const double fitted = f.sigma_const_m + f.sigma_linear * z + f.sigma_quad_per_m * z * z;
    EXPECT_NEAR(fitted, noise.sigmaAt(z), 0.1 * noise.sigmaAt(z)) << z << " m";
  }
  ASSERT_TRUE(f.focal_fitted);
  EXPECT_NEAR(f.cam_k_px, true_k, 0.005 * true_k);
  // A symmetric blur leaves the 50 % point on the true outline.
  EXPECT_NEAR(f.edge_offset_px, 0.0, 0.25);
  EXPECT_TRUE(f.edge_symmetric);
  EXPECT_NEAR(f.edge_spread_px, spread, 0.1 * spread);
  EXPECT_NEAR(f.edge_spread_mm_per_m, 1e3 * spread / 458.0, 0.1e3 * spread / 458.0);
}

// The D435-like camera: sigma 4.8 mm/m^2 z^2 (43 mm at 3 m), 1 mm units, speckle, and stereo edge
// bleeding that fattens the target by a few pixels; reading 0.4 % short, true K 455 px. The
// per-distance CAM_K of the thesis's method is biased by the fattening (most at the far
// distances, where the disc is smallest); the fit over distances separates the constant pixel
// offset from the 1/z geometry and recovers K within 0.5 %.
TEST(CameraCheck, D435LikeCameraRecovered) {
  NoiseConfig noise = NoiseConfig::forModel(NoiseModel::kD435);
  noise.depth_scale_bias = -0.004;
  const double true_k = 455.0;
  CameraCheckConfig cfg;
  cfg.target_diameter_m = kDiameter;
  cfg.depth_unit_m = nativeDepthScale(NoiseModel::kD435);
  const Measured run = measureAll(kThesisDistances, true, noise, true_k, cfg);
  const CameraCheckFit& f = run.fit;
  ASSERT_TRUE(f.focal_fitted);
  EXPECT_NEAR(f.cam_k_px, true_k, 0.005 * true_k);
  // Bleeding reaches up to edge_band_px (4) beyond the outline with probability 0.5.
  EXPECT_GT(f.edge_offset_px, 1.0);
  EXPECT_LT(f.edge_offset_px, noise.edge_band_px + 2.0);
  EXPECT_FALSE(f.edge_symmetric);
  for (const SegmentResult& r : run.segments) {
    SCOPED_TRACE(r.label);
    const double d = r.reference_distance_m;
    ASSERT_TRUE(r.target_found) << r.target_note;
    EXPECT_NEAR(r.camera_depth_m, 0.996 * d, 0.001 * d);
    EXPECT_NEAR(r.error_pct, -0.4, 0.1);
    // The measured spread holds the 1 mm quantisation (q^2 / 12) on top of the model's sigma.
    const double sigma = std::sqrt(std::pow(noise.sigmaAt(r.camera_depth_m), 2) + 1e-6 / 12.0);
    EXPECT_NEAR(r.sigma_spatial_m, sigma, 0.1 * sigma);
    EXPECT_NEAR(r.sigma_temporal_m, sigma, 0.1 * sigma);
    EXPECT_NEAR(edgeCorrectedCamK(r, f, cfg), true_k, 0.005 * true_k);
    if (d >= 2.0) {
      EXPECT_GT(r.cam_k_px, 1.01 * true_k) << "fattening should show at " << d << " m";
    }
  }
  for (double z : kThesisDistances) {
    const double fitted = f.sigma_const_m + f.sigma_linear * z + f.sigma_quad_per_m * z * z;
    EXPECT_NEAR(fitted, noise.sigmaAt(z), 0.1 * noise.sigmaAt(z)) << z << " m";
  }
  EXPECT_NEAR(f.depth_scale, 0.996, 0.001);
}

// A flat wall and no diameter: depth bias and noise are measured on the central window, and the
// report says why the focal check was skipped. With a diameter but no disc, it says none was found.
TEST(CameraCheck, WallGivesBiasAndNoiseAndSkipsFocalCheck) {
  NoiseConfig noise = NoiseConfig::forModel(NoiseModel::kL515);
  noise.depth_scale_bias = 0.0063;
  CameraCheckConfig cfg;
  const Measured run = measureAll({1.0, 2.0, 3.0}, false, noise, 458.0, cfg, 10);
  for (const SegmentResult& r : run.segments) {
    SCOPED_TRACE(r.label);
    EXPECT_FALSE(r.target_found);
    EXPECT_NE(r.target_note.find("wall"), std::string::npos) << r.target_note;
    EXPECT_NEAR(r.error_pct, 0.63, 0.1);
    const double sigma = noise.sigmaAt(r.camera_depth_m);
    EXPECT_NEAR(r.sigma_spatial_m, sigma, 0.1 * sigma);
    EXPECT_NEAR(r.sigma_temporal_m, sigma, 0.1 * sigma);
    EXPECT_TRUE(std::isnan(r.cam_k_px));
    EXPECT_TRUE(std::isnan(r.edge_spread_px));
    EXPECT_EQ(r.face_pixels, 121 * 121);
  }
  EXPECT_FALSE(run.fit.focal_fitted);
  bool said = false;
  for (const std::string& n : run.fit.notes)
    said |= n.find("focal check skipped: no target diameter given") != std::string::npos;
  EXPECT_TRUE(said);
  EXPECT_NEAR(run.fit.depth_scale, 1.0063, 0.001);
  EXPECT_NE(formatCameraCheckTable(run.segments, run.fit, cfg).find("focal check skipped"),
            std::string::npos);

  cfg.target_diameter_m = kDiameter;
  const Measured with_d = measureAll({1.5}, false, noise, 458.0, cfg, 4);
  EXPECT_FALSE(with_d.fit.focal_fitted);
  said = false;
  for (const std::string& n : with_d.fit.notes)
    said |= n.find("no round target found") != std::string::npos;
  EXPECT_TRUE(said);
}

// A camera that reads a constant 5 mm long: the response fit finds the offset, not a scale.
TEST(CameraCheck, DepthOffsetIsFittedApartFromScale) {
  NoiseConfig noise = NoiseConfig::forModel(NoiseModel::kL515);
  noise.depth_offset_m = 0.005;
  CameraCheckConfig cfg;
  const Measured run = measureAll({1.0, 2.0, 3.0}, false, noise, 458.0, cfg, 4);
  EXPECT_NEAR(run.fit.depth_scale, 1.0, 0.0005);
  EXPECT_NEAR(run.fit.depth_offset_m, 0.005, 0.0005);
}

// The written YAML loads back as a noise model (base preset + measured fields) and as a depth
// correction; frames corrected with it measure unbiased.
TEST(CameraCheck, YamlLoadsAsNoiseModelAndDepthCorrection) {
  NoiseConfig noise = NoiseConfig::forModel(NoiseModel::kL515);
  noise.depth_scale_bias = 0.0063;
  CameraCheckConfig cfg;
  cfg.target_diameter_m = kDiameter;
  cfg.depth_unit_m = 0.00025;
  const Measured run = measureAll({0.76, 1.47, 2.2, 3.0}, true, noise, 458.0, cfg, 10);
  CameraCheckReport rep;
  rep.source = "rendered \"test\" frames";
  rep.intrinsics = l515Intrinsics();
  rep.config = cfg;
  rep.segments = run.segments;
  rep.fit = run.fit;
  rep.base_model = "l515";
  const std::string path = tempPath("report.yaml");
  writeCameraCheckYaml(path, rep);
  EXPECT_FALSE(std::filesystem::exists(path + ".part"));

  const NoiseConfig loaded = loadNoiseModelYaml(path);
  EXPECT_EQ(loaded.model, NoiseModel::kL515);
  EXPECT_NEAR(loaded.sigma_const_m, run.fit.sigma_const_m, 1e-9);
  EXPECT_NEAR(loaded.sigma_linear, run.fit.sigma_linear, 1e-9);
  EXPECT_NEAR(loaded.sigma_quad_per_m, run.fit.sigma_quad_per_m, 1e-9);
  EXPECT_NEAR(loaded.depth_scale_bias, run.fit.depth_scale - 1.0, 1e-9);
  EXPECT_NEAR(loaded.quantum_m, 0.00025, 1e-12);
  // Unmeasured effects stay the preset's; the measured blur comes back close to the preset's.
  EXPECT_EQ(loaded.edge_dropout_prob, noise.edge_dropout_prob);
  EXPECT_NEAR(loaded.lateral_fwhm_px, noise.lateral_fwhm_px, 0.15 * noise.lateral_fwhm_px);
  for (double z : {0.76, 3.0})
    EXPECT_NEAR(loaded.sigmaAt(z), noise.sigmaAt(z), 0.1 * noise.sigmaAt(z));

  const DepthCorrection corr = loadDepthCorrectionYaml(path);
  EXPECT_NEAR(corr.scale, run.fit.depth_scale, 1e-9);
  EXPECT_NEAR(corr.offset_m, run.fit.depth_offset_m, 1e-9);
  SegmentFrames seg = recordSegment(2.0, true, noise, 5, 458.0, 99);
  for (DepthImage& f : seg.frames) applyDepthCorrection(f, corr);
  const SegmentResult corrected = measureSegment(seg, l515Intrinsics(), cfg);
  EXPECT_NEAR(corrected.error_pct, 0.0, 0.1);
  std::filesystem::remove(path);
}

TEST(CameraCheck, LoadersNameFileLineAndKey) {
  const std::string path = tempPath("bad.yaml");
  auto write = [&](const std::string& text) { std::ofstream(path) << text; };
  auto message = [&](auto load) {
    try {
      load(path);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  write("noise_model:\n  base: l515\n  sigma_lineer: 0.001\n");
  EXPECT_NE(message(loadNoiseModelYaml).find(path + ":3: noise_model.sigma_lineer: unknown key"),
            std::string::npos)
      << message(loadNoiseModelYaml);
  write("noise_model:\n  base: kinect\n");
  EXPECT_NE(message(loadNoiseModelYaml).find(":2: noise_model.base: unknown noise model 'kinect'"),
            std::string::npos);
  write("noise_model:\n  sigma_const_m: 2mm\n");
  EXPECT_NE(message(loadNoiseModelYaml).find(":2: noise_model.sigma_const_m: cannot read '2mm'"),
            std::string::npos);
  write("noise_model:\n  sigma_const_m: -0.001\n  edge_band_px: 2.5\n");
  EXPECT_NE(message(loadNoiseModelYaml).find("edge_band_px: must be a whole number"),
            std::string::npos);
  write("noise_model:\n  sigma_const_m: -0.001\n");
  EXPECT_NE(message(loadNoiseModelYaml).find("sigma_const_m must be >= 0"), std::string::npos);
  write("camera_check: {}\n");
  EXPECT_NE(message(loadNoiseModelYaml).find("no 'noise_model:' section"), std::string::npos);
  EXPECT_NE(message(loadDepthCorrectionYaml).find("no 'depth_correction:' section"),
            std::string::npos);
  write("depth_correction:\n  scale: 1.5\n");
  EXPECT_NE(message(loadDepthCorrectionYaml).find("scale must be in 0.8..1.2"), std::string::npos);
  write("depth_correction:\n  scale: 1.01\n  ofset_m: 0.001\n");
  EXPECT_NE(message(loadDepthCorrectionYaml).find(":3: depth_correction.ofset_m: unknown key"),
            std::string::npos);
  std::filesystem::remove(path);
  EXPECT_NE(message(loadDepthCorrectionYaml).find("cannot open"), std::string::npos);
}

TEST(CameraCheck, BadInputIsNamed) {
  const PinholeIntrinsics K = l515Intrinsics();
  const CameraCheckConfig cfg;
  auto message = [&](const SegmentFrames& seg) {
    try {
      measureSegment(seg, K, cfg);
    } catch (const CameraCheckError& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  SegmentFrames seg;
  seg.label = "3.0 m";
  EXPECT_NE(message(seg).find("segment '3.0 m' has no frames"), std::string::npos);

  seg.frames.assign(3, DepthImage(640, 480, 0.0f));
  EXPECT_NE(message(seg).find("no planar region at pixel (320, 240)"), std::string::npos);
  EXPECT_NE(message(seg).find("return a depth"), std::string::npos) << message(seg);

  // Depths scattered at random between 1 and 3 m: returns, but no plane.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> z(1.0f, 3.0f);
  for (DepthImage& f : seg.frames)
    for (float& d : f.data) d = z(rng);
  EXPECT_NE(message(seg).find("do not lie on a plane"), std::string::npos) << message(seg);

  seg.frames.push_back(DepthImage(320, 240, 1.0f));
  EXPECT_NE(message(seg).find("frame 3 is 320x240 px"), std::string::npos) << message(seg);
}

// Still periods: three stations with ramps between them and a stray frame inside one.
TEST(CameraCheck, StillPeriodsSplitAtMotion) {
  std::vector<double> t, d;
  auto add = [&](double z) {
    t.push_back(t.size() / 30.0);
    d.push_back(z);
  };
  auto ramp = [&](double from, double to, int n) {  // n frames strictly between the stations
    for (int i = 1; i <= n; ++i) add(from + (to - from) * i / (n + 1.0));
  };
  std::vector<std::size_t> first, last;
  first.push_back(t.size());
  for (int i = 0; i < 60; ++i) add(0.6 + 0.0003 * std::sin(i));
  last.push_back(t.size() - 1);
  ramp(0.6, 1.2, 20);  // 0.6 m in 0.7 s
  first.push_back(t.size());
  for (int i = 0; i < 90; ++i) add(i == 40 ? 1.5 : 1.2);  // one stray frame
  last.push_back(t.size() - 1);
  ramp(1.2, 2.0, 30);
  first.push_back(t.size());
  for (int i = 0; i < 45; ++i) add(2.0);
  last.push_back(t.size() - 1);
  const std::vector<StillPeriod> p = findStillPeriods(t, d, 1.0);
  ASSERT_EQ(p.size(), 3u);
  for (std::size_t k = 0; k < 3; ++k) {
    EXPECT_EQ(p[k].first, first[k]) << k;
    EXPECT_EQ(p[k].last, last[k]) << k;
  }
  EXPECT_NEAR(p[1].depth_m, 1.2, 1e-9);
  // A station shorter than the minimum is motion.
  EXPECT_EQ(findStillPeriods(t, d, 1.6).size(), 2u);
}
