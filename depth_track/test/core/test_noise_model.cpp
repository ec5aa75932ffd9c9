// The depth noise measured from the frames themselves (NoiseEstimator: plane-fit residuals of
// probe cells against depth) on rendered L515- and D435-class frames of known noise, and the
// tracker settings that follow from it (adaptToNoise): the L515's are the defaults, so
// auto_noise leaves its runs as they are; a noisier sensor gets wider pooling and gates.
#include <gtest/gtest.h>

#include <cmath>

#include "depth_track/core/noise_model.hpp"
#include "depth_track/core/sim/rendered_run.hpp"
#include "depth_track/core/tracker.hpp"

using namespace depth_track;

namespace {

DepthNoiseModel estimate(sim::NoiseModel model, std::size_t frame, DepthImage* first = nullptr) {
  const sim::RenderedRun run = sim::makeRun("room3");
  NoiseEstimator est;
  const DepthImage img = run.renderFrame(frame, sim::NoiseConfig::forModel(model), 1);
  est.addFrame(img, run.intrinsics);
  std::printf("%s frame %zu: %s\n", sim::noiseModelName(model).c_str(), frame,
              est.summary().c_str());
  if (first) *first = img;
  return est.model();
}

}  // namespace

// The estimate against the rendered model's sigma at 1.5 and 2.5 m (where the room's surfaces
// are). Lateral jitter and the stereo model's correlated noise make plane residuals differ
// from the per-pixel sigma (measured: 1.04-1.22 times it on both sensors); the bound, -20 % to
// +40 %, is far tighter than the 7x between the two sensors at 2.5 m, but it is no calibration
// (camera_check is that).
TEST(NoiseEstimator, RecoversTheRenderedSensorsNoiseWithinAFactor) {
  for (const sim::NoiseModel m : {sim::NoiseModel::kL515, sim::NoiseModel::kD435}) {
    const sim::NoiseConfig truth = sim::NoiseConfig::forModel(m);
    const DepthNoiseModel est = estimate(m, 0);
    ASSERT_TRUE(est.known()) << sim::noiseModelName(m);
    for (const double z : {1.5, 2.5}) {
      const double ratio = est.sigmaAt(z) / truth.sigmaAt(z);
      EXPECT_GT(ratio, 0.8) << sim::noiseModelName(m) << " at " << z << " m";
      EXPECT_LT(ratio, 1.4) << sim::noiseModelName(m) << " at " << z << " m";
    }
  }
  const double l515 = estimate(sim::NoiseModel::kL515, 0).sigmaAt(2.5);
  const double d435 = estimate(sim::NoiseModel::kD435, 0).sigmaAt(2.5);
  EXPECT_GT(d435, 3.0 * l515);
}

// Hall1's first frame (L515 noise, seed 1): at 2.5-2.75 m most of the cells that face the camera
// lie on one column across the corridor's far corner, whose residual is geometry (6 mm with no
// noise at all). Counted, they read the sensor at 17.5 mm at 3 m (the renderer's: 4.8 mm) and the
// depth-noise weighting then discounts the far hallway 60-fold. The neighbourhood test leaves
// them out.
TEST(NoiseEstimator, CellsAcrossCreasesDoNotCount) {
  const sim::RenderedRun run = sim::makeRun("hall1");
  const sim::NoiseConfig truth = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  const DepthImage img = run.renderFrame(0, truth, 1);
  NoiseEstimator with_test;
  with_test.addFrame(img, run.intrinsics);
  std::printf("hall1 frame 0: %s\n", with_test.summary().c_str());
  NoiseEstimatorConfig off;
  off.planar_tolerance = 0.0;
  NoiseEstimator without(off);
  without.addFrame(img, run.intrinsics);
  std::printf("hall1 frame 0, no neighbourhood test: %s\n", without.summary().c_str());
  for (const double z : {1.5, 2.5}) {
    const double ratio = with_test.model().sigmaAt(z) / truth.sigmaAt(z);
    EXPECT_GT(ratio, 0.7) << "at " << z << " m";
    EXPECT_LT(ratio, 1.4) << "at " << z << " m";
  }
  // What the test is for: without it the crease column doubles the far estimate.
  EXPECT_GT(without.model().sigmaAt(2.5) / truth.sigmaAt(2.5), 2.0);
  EXPECT_LT(with_test.cells(), without.cells());
}

TEST(NoiseEstimator, RejectsABadNeighbourhoodTolerance) {
  NoiseEstimatorConfig c;
  c.planar_tolerance = -1.0;
  EXPECT_THROW(NoiseEstimator{c}, std::invalid_argument);
}

TEST(NoiseEstimator, EmptyOrFlatFramesGiveNoModel) {
  NoiseEstimator est;
  EXPECT_FALSE(est.model().known());
  const PinholeIntrinsics K = PinholeIntrinsics::isotropic(640, 480, 458.0);
  est.addFrame(DepthImage(640, 480), K);  // no returns at all
  EXPECT_FALSE(est.model().known());
  EXPECT_EQ(est.cells(), 0);
  EXPECT_THROW(est.addFrame(DepthImage(320, 240), K), std::exception);
}

// The L515's noise (kappa well below 1 pixel footprint) gives exactly the default settings;
// D435 noise at 2.5 m pools normals wider and opens the gates.
TEST(NoiseAdaptation, DefaultsForTheL515WiderForTheD435) {
  const TrackerConfig defaults;
  const sim::NoiseConfig l515 = sim::NoiseConfig::forModel(sim::NoiseModel::kL515);
  const sim::NoiseConfig d435 = sim::NoiseConfig::forModel(sim::NoiseModel::kD435);
  const DepthNoiseModel nl{l515.sigma_const_m, l515.sigma_linear, l515.sigma_quad_per_m};
  const DepthNoiseModel nd{d435.sigma_const_m, d435.sigma_linear, d435.sigma_quad_per_m};
  const NoiseAdaptation a = adaptToNoise(nl, 458.0, 5, 3.0, 0.05);
  EXPECT_LT(a.footprint_noise, 1.0);
  EXPECT_EQ(a.normal_radius_cells, defaults.pca.normal_radius_cells);
  EXPECT_EQ(a.normal_merge_dist_m, defaults.pca.normal_merge_dist_m);
  EXPECT_EQ(a.cos_min, defaults.registration.match.cos_min);
  EXPECT_EQ(a.huber_delta_m, defaults.registration.huber_delta_m);
  EXPECT_EQ(a.max_error_rms_m, defaults.max_error_rms_m);
  EXPECT_EQ(a.min_valid_fraction, defaults.pca.min_valid_fraction);
  const NoiseAdaptation b = adaptToNoise(nd, 385.0, 5, 2.5, 0.5);
  EXPECT_GT(b.footprint_noise, 3.0);
  EXPECT_GT(b.normal_radius_cells, a.normal_radius_cells);
  EXPECT_LT(b.cos_min, a.cos_min);
  EXPECT_GT(b.max_error_rms_m, a.max_error_rms_m);
  EXPECT_LT(b.min_valid_fraction, 1.0);
  // Unknown noise: the defaults.
  const NoiseAdaptation c = adaptToNoise(DepthNoiseModel{}, 458.0, 5, 3.0, 0.0);
  EXPECT_EQ(c.normal_radius_cells, defaults.pca.normal_radius_cells);
}
