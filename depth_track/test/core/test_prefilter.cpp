#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

#include "depth_track/core/prefilter.hpp"
#include "depth_track/core/tum_io.hpp"
#include "../shared_data.hpp"

using namespace depth_track;

namespace {

// Plane at depth z0 (or a vertical step: z_left for u < step_u, z_right beyond) plus i.i.d.
// Gaussian noise of sigma_m.
DepthImage noisyScene(int w, int h, double z_left, double z_right, int step_u, double sigma_m,
                      unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, sigma_m);
  DepthImage d(w, h);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u)
      d.at(u, v) = static_cast<float>((u < step_u ? z_left : z_right) + noise(rng));
  return d;
}

PrefilterConfig bilateral(int ksz, double ss_px, double sd_m) {
  PrefilterConfig c;
  c.type = PrefilterType::kBilateral;
  c.kernel_size_px = ksz;
  c.spatial_sigma_px = ss_px;
  c.depth_sigma_m = sd_m;
  return c;
}

// Noise left after a weighted mean of i.i.d. samples: sigma * sqrt(sum w^2) / sum w, for the
// spatial weights of a square kernel (the range weights are ~1 on a plane whose noise is far
// below the depth sigma).
double smoothedSigma(double sigma_m, int ksz, double ss_px, bool one_dimensional = false) {
  const int r = ksz / 2;
  double s1 = 0.0, s2 = 0.0;
  for (int dy = one_dimensional ? 0 : -r; dy <= (one_dimensional ? 0 : r); ++dy)
    for (int dx = -r; dx <= r; ++dx) {
      const double w = std::exp(-(dx * dx + dy * dy) / (2.0 * ss_px * ss_px));
      s1 += w;
      s2 += w * w;
    }
  return sigma_m * std::sqrt(s2) / s1;
}

struct Stats {
  double mean = 0.0, stddev = 0.0;
  int n = 0;
};

Stats statsOf(const DepthImage& d, int u0, int u1, int v0, int v1) {
  Stats s;
  double sum = 0.0, sum2 = 0.0;
  for (int v = v0; v < v1; ++v)
    for (int u = u0; u < u1; ++u) {
      sum += d.at(u, v);
      sum2 += static_cast<double>(d.at(u, v)) * d.at(u, v);
      ++s.n;
    }
  s.mean = sum / s.n;
  s.stddev = std::sqrt(std::max(0.0, sum2 / s.n - s.mean * s.mean));
  return s;
}

// The bilateral filter written out directly (std::exp, bounds checks, no cutoff tricks beyond the
// configured one): the reference the optimised path must match.
DepthImage referenceBilateral(const DepthImage& in, const PrefilterConfig& c, int rx, int ry) {
  DepthImage out(in.width, in.height);
  for (int v = 0; v < in.height; ++v)
    for (int u = 0; u < in.width; ++u) {
      const double zc = in.at(u, v);
      if (zc <= 0.0) continue;
      double num = 0.0, den = 0.0;
      for (int dy = -ry; dy <= ry; ++dy)
        for (int dx = -rx; dx <= rx; ++dx) {
          const int x = u + dx, y = v + dy;
          if (x < 0 || y < 0 || x >= in.width || y >= in.height) continue;
          const double z = in.at(x, y);
          if (z <= 0.0) continue;
          const double dz = z - zc;
          if (std::abs(dz) > c.depth_cutoff_sigmas * c.depth_sigma_m) continue;
          const double w =
              std::exp(-(dx * dx + dy * dy) / (2.0 * c.spatial_sigma_px * c.spatial_sigma_px)) *
              std::exp(-dz * dz / (2.0 * c.depth_sigma_m * c.depth_sigma_m));
          num += w * z;
          den += w;
        }
      out.at(u, v) = static_cast<float>(num / den);
    }
  return out;
}

DepthImage referenceBilateral(const DepthImage& in, const PrefilterConfig& c) {
  const int r = c.kernel_size_px / 2;
  if (c.bilateral_mode == BilateralMode::kSeparable)
    return referenceBilateral(referenceBilateral(in, c, r, 0), c, 0, r);
  return referenceBilateral(in, c, r, r);
}

}  // namespace

TEST(Prefilter, ParseNamesAndThesisCodes) {
  EXPECT_EQ(parsePrefilterType("none"), PrefilterType::kNone);
  EXPECT_EQ(parsePrefilterType("bilateral"), PrefilterType::kBilateral);
  EXPECT_EQ(parsePrefilterType("crop"), PrefilterType::kCrop);
  EXPECT_EQ(parsePrefilterType("1"), PrefilterType::kBilateral);
  EXPECT_EQ(toString(PrefilterType::kCrop), "crop");
  try {
    parsePrefilterType("median");
    ADD_FAILURE() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'median'"), std::string::npos);
  }
  EXPECT_EQ(parseBilateralMode("separable"), BilateralMode::kSeparable);
  EXPECT_EQ(parseBilateralMode(toString(BilateralMode::kFull)), BilateralMode::kFull);
  EXPECT_THROW(parseBilateralMode("fast"), std::invalid_argument);
}

TEST(Prefilter, ValidateReportsEveryProblem) {
  PrefilterConfig c = bilateral(30, -1.0, 0.0);
  c.depth_cutoff_sigmas = 9.0;
  EXPECT_EQ(c.validate().size(), 4u);
  PrefilterConfig thesis;  // fig. 5.1 defaults
  thesis.type = PrefilterType::kBilateral;
  EXPECT_TRUE(thesis.validate().empty());
  EXPECT_EQ(thesis.kernel_size_px, 31);
  EXPECT_DOUBLE_EQ(thesis.spatial_sigma_px, 15.0);
  // Depth_Const 200 raw L515 units of 0.25 mm.
  EXPECT_DOUBLE_EQ(thesis.depth_sigma_m, depthSigmaFromRawUnits(200.0, 0.00025));

  PrefilterConfig crop;
  crop.type = PrefilterType::kCrop;
  EXPECT_EQ(crop.validate().size(), 1u);  // zero-size rectangle
  crop.crop_x_px = 600;
  crop.crop_width_px = 100;
  crop.crop_height_px = 10;
  EXPECT_TRUE(crop.validate().empty());
  const auto p = crop.validate(640, 480);
  ASSERT_EQ(p.size(), 1u);
  EXPECT_NE(p[0].find("640x480"), std::string::npos);
  EXPECT_THROW(applyPrefilter(DepthImage(640, 480, 1.0f), crop), std::invalid_argument);
  EXPECT_THROW(applyPrefilter(DepthImage(64, 48, 1.0f), bilateral(4, 3.0, 0.05)),
               std::invalid_argument);
}

TEST(Prefilter, NoneCopiesAndCropZeroesOutside) {
  const DepthImage d = noisyScene(40, 30, 1.0, 1.0, 40, 0.01, 1);
  PrefilterConfig none;
  EXPECT_EQ(applyPrefilter(d, none).data, d.data);
  PrefilterConfig crop;
  crop.type = PrefilterType::kCrop;
  crop.crop_x_px = 5;
  crop.crop_y_px = 7;
  crop.crop_width_px = 20;
  crop.crop_height_px = 10;
  const DepthImage c = applyPrefilter(d, crop);
  for (int v = 0; v < d.height; ++v)
    for (int u = 0; u < d.width; ++u) {
      const bool inside = u >= 5 && u < 25 && v >= 7 && v < 17;
      EXPECT_EQ(c.at(u, v), inside ? d.at(u, v) : 0.0f) << u << "," << v;
    }
  EXPECT_EQ(c.countValid(), 200u);
}

// Noise model of the bilateral filter on a noisy plane (noise sigma_n << depth sigma sd): the
// range weight of a neighbour is a Gaussian of its depth around the centre's noisy depth, so the
// weighted mean is the spatial mean shrunk by (1 - a) plus a share a of the centre's own noise,
// a = sigma_n^2 / (sigma_n^2 + sd^2) (the mean of a Gaussian times a Gaussian). Predicted output
// noise: sqrt(((1 - a) s_spatial)^2 + (a sigma_n)^2).
double bilateralNoiseModel(double sigma_n, double sd, int ksz, double ss_px) {
  const double a = sigma_n * sigma_n / (sigma_n * sigma_n + sd * sd);
  const double s = smoothedSigma(sigma_n, ksz, ss_px);
  return std::sqrt((1 - a) * (1 - a) * s * s + a * a * sigma_n * sigma_n);
}

TEST(Prefilter, BilateralReducesPlaneNoiseAsPredicted) {
  const double sigma_n = 0.01;  // 1 cm noise, below the 5 cm depth sigma
  {
    // Small kernel: many independent patches in the frame, so the sample std is tight (~3 %).
    const DepthImage d = noisyScene(200, 150, 2.0, 2.0, 200, sigma_n, 2);
    const DepthImage f = applyPrefilter(d, bilateral(9, 3.0, 0.05), 2);
    const Stats before = statsOf(d, 4, 196, 4, 146);
    const Stats after = statsOf(f, 4, 196, 4, 146);
    EXPECT_NEAR(before.stddev, sigma_n, 0.05 * sigma_n);
    const double expected = bilateralNoiseModel(sigma_n, 0.05, 9, 3.0);  // ~1.2 mm
    EXPECT_NEAR(after.stddev, expected, 0.15 * expected);
    EXPECT_NEAR(after.mean, 2.0, 3.0 * sigma_n / std::sqrt(after.n));
    EXPECT_EQ(f.countValid(), d.countValid());
  }
  {
    // The thesis's kernel (Ksz 31, 15 px): smoothing correlates outputs over ~15 px, so a
    // 160x120 frame holds only ~50 independent patches; pool three frames (~10 % scatter).
    double var = 0.0;
    for (unsigned seed : {11u, 12u, 13u}) {
      const DepthImage d = noisyScene(160, 120, 2.0, 2.0, 160, sigma_n, seed);
      const DepthImage f = applyPrefilter(d, bilateral(31, 15.0, 0.05), 2);
      const Stats after = statsOf(f, 15, 145, 15, 105);
      var += after.stddev * after.stddev / 3.0;
    }
    const double expected = bilateralNoiseModel(sigma_n, 0.05, 31, 15.0);  // ~0.5 mm
    EXPECT_NEAR(std::sqrt(var), expected, 0.25 * expected);
  }
}

TEST(Prefilter, BilateralKeepsAStepEdge) {
  // A 0.5 m step is 10 depth sigmas: beyond the 3-sigma cutoff nothing crosses it.
  const double sigma_n = 0.005;
  const DepthImage d = noisyScene(120, 60, 1.5, 2.0, 60, sigma_n, 3);
  for (const BilateralMode mode : {BilateralMode::kFull, BilateralMode::kSeparable}) {
    PrefilterConfig c = bilateral(31, 15.0, 0.05);
    c.bilateral_mode = mode;
    const DepthImage f = applyPrefilter(d, c);
    // Next to the edge a pixel averages only its own side (about half a kernel): noise left is
    // below sigma_n / 10, far below any leak across a 0.5 m step.
    for (int v = 15; v < 45; ++v) {
      EXPECT_NEAR(f.at(59, v), 1.5, 0.1 * sigma_n * 3) << "row " << v;
      EXPECT_NEAR(f.at(60, v), 2.0, 0.1 * sigma_n * 3) << "row " << v;
    }
  }
}

TEST(Prefilter, HolesAreNeitherUsedNorFilled) {
  DepthImage d = noisyScene(80, 60, 1.2, 1.2, 80, 0.005, 4);
  for (int v = 20; v < 40; ++v)
    for (int u = 30; u < 50; ++u) d.at(u, v) = 0.0f;
  d.at(5, 5) = 0.0f;
  const DepthImage f = applyPrefilter(d, bilateral(15, 5.0, 0.05));
  EXPECT_EQ(f.countValid(), d.countValid());
  EXPECT_EQ(f.at(40, 30), 0.0f);
  EXPECT_EQ(f.at(5, 5), 0.0f);
  // Pixels bordering the hole are not pulled towards 0.
  for (int v = 20; v < 40; ++v) {
    EXPECT_NEAR(f.at(29, v), 1.2, 0.005);
    EXPECT_NEAR(f.at(50, v), 1.2, 0.005);
  }
}

TEST(Prefilter, NanAndInfCountAsHoles) {
  DepthImage d(12, 10, 1.0f);
  d.at(3, 3) = std::numeric_limits<float>::quiet_NaN();
  d.at(7, 5) = std::numeric_limits<float>::infinity();
  d.at(8, 5) = -2.0f;
  for (const BilateralMode mode : {BilateralMode::kFull, BilateralMode::kSeparable}) {
    PrefilterConfig c = bilateral(7, 2.0, 0.05);
    c.bilateral_mode = mode;
    const DepthImage f = applyPrefilter(d, c);
    EXPECT_EQ(f.at(3, 3), 0.0f);
    EXPECT_EQ(f.at(7, 5), 0.0f);
    EXPECT_EQ(f.at(8, 5), 0.0f);
    for (int v = 0; v < 10; ++v)
      for (int u = 0; u < 12; ++u)
        if (f.at(u, v) != 0.0f) {
          EXPECT_NEAR(f.at(u, v), 1.0f, 1e-6f) << u << "," << v;
        }
    EXPECT_EQ(f.countValid(), 117u);
  }
}

TEST(Prefilter, HolesStayOutForAnyDepthSigma) {
  // Holes are skipped by value (a stand-in depth beyond the range cutoff), so even a depth sigma
  // of 5 km, whose 15 km cutoff takes in every real depth, must not let a hole into the mean: a
  // flat 2 m surface next to a column of holes stays at 2 m (float rounding only).
  DepthImage d(9, 9, 2.0f);
  for (int v = 0; v < 9; ++v) d.at(4, v) = 0.0f;
  for (const double sd : {0.05, 5000.0}) {
    const DepthImage f = applyPrefilter(d, bilateral(9, 3.0, sd));
    for (int v = 0; v < 9; ++v)
      for (int u = 0; u < 9; ++u) EXPECT_NEAR(f.at(u, v), d.at(u, v), 1e-6) << u << "," << v;
  }
}

TEST(Prefilter, OptimisedFullKernelMatchesTheDirectFormula) {
  // Steps of 2 cm (inside the cutoff, partly weighted), 30 cm (outside), holes and borders.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> noise(-0.01, 0.01);
  DepthImage d(64, 48);
  for (int v = 0; v < 48; ++v)
    for (int u = 0; u < 64; ++u) {
      double z = 1.0 + (u > 20 ? 0.02 : 0.0) + (v > 30 ? 0.3 : 0.0) + noise(rng);
      if ((u * 7 + v * 3) % 23 == 0) z = 0.0;
      d.at(u, v) = static_cast<float>(z);
    }
  PrefilterConfig c = bilateral(11, 4.0, 0.02);
  c.depth_cutoff_sigmas = 5.0;  // the widest allowed: worst case of the exp approximation
  const DepthImage ref = referenceBilateral(d, c);
  const DepthImage f1 = applyPrefilter(d, c, 1);
  const DepthImage f2 = applyPrefilter(d, c, 2);
  EXPECT_EQ(f1.data, f2.data);  // rows are independent: any thread count gives the same bits
  double max_diff = 0.0;
  for (std::size_t i = 0; i < d.data.size(); ++i) {
    EXPECT_EQ(f1.data[i] > 0.0f, d.data[i] > 0.0f);
    max_diff = std::max(max_diff, std::abs(static_cast<double>(f1.data[i]) - ref.data[i]));
  }
  // Weight error of the exp approximation < 1e-3 relative, times the 0.1 m spread of depths
  // inside the cutoff, bounds the output error by 1e-4 m; float rounding adds ~1e-6 m.
  EXPECT_LT(max_diff, 1e-4);
  std::printf("full kernel vs direct formula: max |diff| = %.2e m\n", max_diff);
}

TEST(Prefilter, FullKernelWiderThanARowBandMatchesTheDirectFormula) {
  // The full kernel works in bands of 32 rows, each spilling r rows into the next: a kernel
  // radius larger than a band and a height that is not a multiple of it must change nothing.
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> noise(-0.02, 0.02);
  DepthImage d(50, 37);
  for (int v = 0; v < d.height; ++v)
    for (int u = 0; u < d.width; ++u)
      d.at(u, v) = (u + 2 * v) % 17 == 0 ? 0.0f : static_cast<float>(1.5 + 0.001 * v + noise(rng));
  const PrefilterConfig c = bilateral(75, 20.0, 0.03);
  const DepthImage ref = referenceBilateral(d, c);
  const DepthImage f = applyPrefilter(d, c, 2);
  double max_diff = 0.0;
  for (std::size_t i = 0; i < d.data.size(); ++i)
    max_diff = std::max(max_diff, std::abs(static_cast<double>(f.data[i]) - ref.data[i]));
  EXPECT_LT(max_diff, 1e-4);  // same bound as above: exp approximation x depth spread
}

TEST(Prefilter, SeparablePassesMatchTheDirectFormula) {
  std::mt19937 rng(10);
  std::uniform_real_distribution<double> noise(-0.01, 0.01);
  DepthImage d(70, 45);
  for (int v = 0; v < d.height; ++v)
    for (int u = 0; u < d.width; ++u)
      d.at(u, v) =
          (u * 5 + v) % 19 == 0
              ? 0.0f
              : static_cast<float>(2.0 + (u > 30 ? 0.05 : 0.0) + (v > 20 ? 0.4 : 0.0) + noise(rng));
  PrefilterConfig c = bilateral(15, 5.0, 0.03);
  c.bilateral_mode = BilateralMode::kSeparable;
  const DepthImage ref = referenceBilateral(d, c);
  const DepthImage f1 = applyPrefilter(d, c, 1);
  const DepthImage f2 = applyPrefilter(d, c, 2);
  EXPECT_EQ(f1.data, f2.data);
  double max_diff = 0.0;
  for (std::size_t i = 0; i < d.data.size(); ++i)
    max_diff = std::max(max_diff, std::abs(static_cast<double>(f1.data[i]) - ref.data[i]));
  EXPECT_LT(max_diff, 1e-4);  // exp approximation (< 2e-5 relative) x depth spread, two passes
}

TEST(Prefilter, SeparableApproximationSmoothsLikeTheFullKernel) {
  const double sigma_n = 0.01;
  const DepthImage d = noisyScene(160, 120, 2.0, 2.0, 160, sigma_n, 6);
  PrefilterConfig c = bilateral(31, 15.0, 0.05);
  const DepthImage full = applyPrefilter(d, c);
  c.bilateral_mode = BilateralMode::kSeparable;
  const DepthImage sep = applyPrefilter(d, c, 2);
  const Stats s = statsOf(sep, 15, 145, 15, 105);
  const Stats sf = statsOf(full, 15, 145, 15, 105);
  // Same Gaussian spatial kernel (it separates). The full kernel keeps a share a of each
  // centre's own noise (see bilateralNoiseModel); the vertical pass averages the horizontal
  // pass's share away, so the separable result is at least as smooth, and never smoother than
  // the spatial kernel alone allows.
  EXPECT_LT(s.stddev, 1.1 * sf.stddev);
  EXPECT_GT(s.stddev, 0.5 * smoothedSigma(sigma_n, 31, 15.0));
  EXPECT_LT(s.stddev, 0.1 * sigma_n);
  double max_diff = 0.0, sum2 = 0.0;
  int n = 0;
  for (int v = 15; v < 105; ++v)
    for (int u = 15; u < 145; ++u) {
      const double e = static_cast<double>(sep.at(u, v)) - full.at(u, v);
      max_diff = std::max(max_diff, std::abs(e));
      sum2 += e * e;
      ++n;
    }
  EXPECT_LT(max_diff, 0.25 * sigma_n);
  EXPECT_LT(std::sqrt(sum2 / n), 0.1 * sigma_n);
}

TEST(Prefilter, TeddyFrameStaysWithinTheDepthCutoff) {
  DT_TEDDY_OR_SKIP(teddy);
  const std::string list = teddy + "/depth.txt";
  const DepthImage d =
      loadTumDepth(readTumFrameList(list).front().path, 1.0 / 5000.0, DepthRange{0.1, 10.0});
  PrefilterConfig c;
  c.type = PrefilterType::kBilateral;  // the thesis's fig. 5.1 parameters
  const DepthImage f = applyPrefilter(d, c, 2);
  // Each output is a weighted mean of neighbours within cutoff * sigma_d of the centre, so no
  // pixel can move further than that (0.15 m): real occluding edges stay where they are.
  const double bound = c.depth_cutoff_sigmas * c.depth_sigma_m;
  std::vector<float> moved;
  for (std::size_t i = 0; i < d.data.size(); ++i) {
    ASSERT_EQ(f.data[i] > 0.0f, d.data[i] > 0.0f) << "pixel " << i;
    if (d.data[i] > 0.0f) {
      EXPECT_LE(std::abs(f.data[i] - d.data[i]), bound + 1e-5) << "pixel " << i;
      moved.push_back(std::abs(f.data[i] - d.data[i]));
    }
  }
  std::nth_element(moved.begin(), moved.begin() + moved.size() / 2, moved.end());
  // A typical pixel moves by about the sensor noise (Kinect ~1.42e-3 z^2 = 6.3 mm at 2.1 m).
  EXPECT_LT(moved[moved.size() / 2], 1.42e-3 * 2.1 * 2.1);
  std::printf("teddy frame 0, bilateral 31/15px/0.05m: median |change| %.2f mm\n",
              1e3 * moved[moved.size() / 2]);
}
