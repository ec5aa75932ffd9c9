// Equivalence of the optimised noise pass (applyNoise, edgeDistance) with a plain serial
// reference kept here: the straightforward per-pixel implementation the optimised code replaced
// (commit "test_render_noise_equivalence"). The noise is a deterministic function of (frame,
// config, seed), so the optimised output must be bit-identical, not merely statistically alike.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <vector>

#include "depth_track/core/depth_image.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/sim/render.hpp"
#include "depth_track/core/sim/rendered_run.hpp"

using namespace depth_track;
using namespace depth_track::sim;

namespace {

// ---- reference: one pixel at a time, every draw recomputed, no tables, no threads ----------

std::uint64_t refMix64(std::uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

enum RefStream : std::uint64_t {
  kJitterU = 0,
  kJitterU2,
  kJitterV,
  kJitterV2,
  kGauss1,
  kGauss2,
  kEdgeDrop,
  kBleed,
  kSpeckle,
  kRandomDrop,
  kGrazing,
  kNumStreams
};

double refUniform(std::uint64_t seed, std::size_t idx, RefStream s) {
  const std::uint64_t counter = static_cast<std::uint64_t>(idx) * kNumStreams + s;
  const std::uint64_t h = refMix64(seed + counter * 0x9E3779B97F4A7C15ull);
  return (static_cast<double>(h >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

double refGaussian(std::uint64_t seed, std::size_t idx, RefStream a, RefStream b) {
  const double u1 = refUniform(seed, idx, a), u2 = refUniform(seed, idx, b);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

double refPairedGaussian(std::uint64_t seed, std::size_t idx) {
  const std::size_t pair = idx >> 1;
  const double u1 = refUniform(seed, pair, kGauss1), u2 = refUniform(seed, pair, kGauss2);
  const double r = std::sqrt(-2.0 * std::log(u1));
  return (idx & 1) ? r * std::sin(2.0 * M_PI * u2) : r * std::cos(2.0 * M_PI * u2);
}

bool refIsJump(float a, float b, const NoiseConfig& c) {
  if ((a > 0.0f) != (b > 0.0f)) return true;
  if (a <= 0.0f) return false;
  const double near = std::min(a, b);
  return std::abs(static_cast<double>(a) - b) > std::max(c.edge_jump_min_m, c.edge_jump_rel * near);
}

std::vector<std::uint8_t> refEdgeDistance(const DepthImage& depth, const NoiseConfig& c) {
  const int w = depth.width, h = depth.height;
  std::vector<std::uint8_t> d(static_cast<std::size_t>(w) * h, 255);
  auto at = [&](int u, int v) -> std::uint8_t& { return d[static_cast<std::size_t>(v) * w + u]; };
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const float z = depth.at(u, v);
      if ((u > 0 && refIsJump(z, depth.at(u - 1, v), c)) ||
          (u + 1 < w && refIsJump(z, depth.at(u + 1, v), c)) ||
          (v > 0 && refIsJump(z, depth.at(u, v - 1), c)) ||
          (v + 1 < h && refIsJump(z, depth.at(u, v + 1), c)))
        at(u, v) = 0;
    }
  auto relax = [](std::uint8_t& x, std::uint8_t n) {
    if (n < 255 && n + 1 < x) x = static_cast<std::uint8_t>(n + 1);
  };
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      std::uint8_t& x = at(u, v);
      if (u > 0) relax(x, at(u - 1, v));
      if (v > 0) {
        relax(x, at(u, v - 1));
        if (u > 0) relax(x, at(u - 1, v - 1));
        if (u + 1 < w) relax(x, at(u + 1, v - 1));
      }
    }
  for (int v = h - 1; v >= 0; --v)
    for (int u = w - 1; u >= 0; --u) {
      std::uint8_t& x = at(u, v);
      if (u + 1 < w) relax(x, at(u + 1, v));
      if (v + 1 < h) {
        relax(x, at(u, v + 1));
        if (u + 1 < w) relax(x, at(u + 1, v + 1));
        if (u > 0) relax(x, at(u - 1, v + 1));
      }
    }
  return d;
}

/// The noise pass exactly as first written (valid config and frame assumed; the tests below
/// check the error paths of applyNoise separately).
DepthImage refApplyNoise(const DepthImage& clean, const NoiseConfig& c, std::uint64_t seed,
                         const DepthRange& range, const std::vector<float>* cos_incidence) {
  if (c.model == NoiseModel::kNone && c.sigmaAt(1.0) == 0.0 && c.lateral_fwhm_px == 0.0 &&
      c.edge_dropout_prob == 0.0 && c.edge_bleed_prob == 0.0 && c.speckle_prob == 0.0 &&
      c.random_dropout_prob == 0.0 && c.grazing_dropout_prob == 0.0 && c.quantum_m == 0.0 &&
      c.depth_scale_bias == 0.0) {
    DepthImage out = clean;
    for (float& z : out.data)
      if (!(z >= range.min_m && z <= range.max_m)) z = 0.0f;
    return out;
  }
  const int w = clean.width, h = clean.height;
  const std::size_t n = static_cast<std::size_t>(w) * h;
  seed = refMix64(seed ^ 0x5DEECE66Dull);
  const std::vector<std::uint8_t> edge = refEdgeDistance(clean, c);
  std::vector<std::uint8_t> speckle_seed;
  if (c.speckle_prob > 0.0) {
    speckle_seed.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i)
      speckle_seed[i] = refUniform(seed, i, kSpeckle) < c.speckle_prob ? 1 : 0;
  }
  const double jitter_sigma = c.lateral_fwhm_px / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  const int jmax = c.max_jitter_px;
  const int band = c.edge_band_px;
  DepthImage out(w, h);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * w + u;
      const int e = edge[i];
      double z = clean.data[i];
      if (jitter_sigma > 0.0 && e <= jmax) {
        auto offset = [&](RefStream a, RefStream b) {
          const double o = std::round(jitter_sigma * refGaussian(seed, i, a, b));
          return static_cast<int>(
              std::clamp(o, -static_cast<double>(jmax), static_cast<double>(jmax)));
        };
        const int su = std::clamp(u + offset(kJitterU, kJitterU2), 0, w - 1);
        const int sv = std::clamp(v + offset(kJitterV, kJitterV2), 0, h - 1);
        z = clean.at(su, sv);
      }
      if (c.edge_bleed_prob > 0.0 && e <= band && refUniform(seed, i, kBleed) < c.edge_bleed_prob) {
        float fg = 0.0f;
        for (int dv = -band; dv <= band; ++dv)
          for (int du = -band; du <= band; ++du) {
            const int uu = u + du, vv = v + dv;
            if (uu < 0 || vv < 0 || uu >= w || vv >= h) continue;
            const float q = clean.at(uu, vv);
            if (q > 0.0f && (fg == 0.0f || q < fg)) fg = q;
          }
        if (fg > 0.0f && (z <= 0.0 || refIsJump(static_cast<float>(z), fg, c))) z = fg;
      }
      if (c.edge_dropout_prob > 0.0 && e <= band) {
        const double p = c.edge_dropout_prob * (1.0 - static_cast<double>(e) / (band + 1));
        if (refUniform(seed, i, kEdgeDrop) < p) z = 0.0;
      }
      if (cos_incidence && c.grazing_dropout_prob > 0.0 && z > 0.0) {
        const double ci = (*cos_incidence)[i];
        if (ci < c.grazing_cos &&
            refUniform(seed, i, kGrazing) < c.grazing_dropout_prob * (1.0 - ci / c.grazing_cos))
          z = 0.0;
      }
      z *= 1.0 + c.depth_scale_bias;
      if (z > 0.0) {
        const double sigma = c.sigmaAt(z);
        if (sigma > 0.0) z += sigma * refPairedGaussian(seed, i);
      }
      if (!speckle_seed.empty() && z > 0.0) {
        const int rr = c.speckle_radius_px;
        for (int dv = -rr; dv <= rr && z > 0.0; ++dv)
          for (int du = -rr; du <= rr; ++du) {
            const int uu = u + du, vv = v + dv;
            if (uu < 0 || vv < 0 || uu >= w || vv >= h) continue;
            if (speckle_seed[static_cast<std::size_t>(vv) * w + uu]) {
              z = 0.0;
              break;
            }
          }
      }
      if (c.random_dropout_prob > 0.0 && refUniform(seed, i, kRandomDrop) < c.random_dropout_prob)
        z = 0.0;
      if (!(z >= range.min_m && z <= range.max_m)) z = 0.0;
      if (z > 0.0 && c.quantum_m > 0.0) z = std::round(z / c.quantum_m) * c.quantum_m;
      out.data[i] = static_cast<float>(z);
    }
  return out;
}

// ---- test frames -------------------------------------------------------------------------------

/// A rendered frame plus its incidence, with extra holes punched in: scattered single pixels,
/// short runs and a block (no-return areas with edges of every orientation).
struct Frame {
  const char* name;
  RenderedDepth r;
};

void punchHoles(RenderedDepth& r, std::uint64_t salt) {
  const int w = r.depth.width, h = r.depth.height;
  for (int k = 0; k < 400; ++k) {
    const std::uint64_t x = refMix64(salt + k);
    const int u = static_cast<int>(x % w), v = static_cast<int>((x >> 20) % h);
    const int len = 1 + static_cast<int>((x >> 40) % 6);
    for (int du = 0; du < len && u + du < w; ++du) {
      r.depth.at(u + du, v) = 0.0f;
      r.cos_incidence[static_cast<std::size_t>(v) * w + u + du] = 0.0f;
    }
  }
  for (int v = h / 3; v < h / 3 + 17 && v < h; ++v)
    for (int u = w / 2; u < w / 2 + 23 && u < w; ++u) {
      r.depth.at(u, v) = 0.0f;
      r.cos_incidence[static_cast<std::size_t>(v) * w + u] = 0.0f;
    }
}

const std::vector<Frame>& frames() {
  static const std::vector<Frame> f = [] {
    std::vector<Frame> out;
    // Chair room from the track start: furniture silhouettes, floor at grazing incidence.
    out.push_back(
        {"chair", renderDepthWithIncidence(chairRoomScene(), l515Intrinsics(),
                                           cameraPoseOnTrack(0.0, 0.0, 0.0), DepthRange{})});
    // Same view cut at 2.5 m (far surfaces become holes) and with punched holes.
    RenderedDepth cut =
        renderDepthWithIncidence(chairRoomScene(), l515Intrinsics(),
                                 cameraPoseOnTrack(0.3, 0.17, -0.09), DepthRange{0.3, 2.5});
    punchHoles(cut, 77);
    out.push_back({"chair_cut_holes", cut});
    // Furnished room mid-run.
    const RenderedRun room = makeRun("room3");
    out.push_back({"room3", renderDepthWithIncidence(room.scene, room.intrinsics,
                                                     room.T_W_C[room.size() / 2], room.range)});
    // A small odd-sized frame (borders on every side, odd pixel count: an unpaired last pixel).
    RenderedDepth small;
    small.depth = DepthImage(37, 23);
    small.cos_incidence.assign(37 * 23, 0.0f);
    for (int v = 0; v < 23; ++v)
      for (int u = 0; u < 37; ++u) {
        const bool fg = (u - 18) * (u - 18) + (v - 11) * (v - 11) < 40;
        small.depth.at(u, v) = fg ? 0.8f + 0.01f * u : 2.0f + 0.02f * v;
        small.cos_incidence[static_cast<std::size_t>(v) * 37 + u] =
            static_cast<float>((u * 7 + v * 3) % 23) / 22.0f;
      }
    punchHoles(small, 5);
    out.push_back({"small_odd", small});
    return out;
  }();
  return f;
}

/// Configs: the three presets plus variants that reach paths the presets do not (every effect
/// at once, zero bands and radii, a scale bias, no quantisation, noise under model "none").
std::vector<std::pair<const char*, NoiseConfig>> configs() {
  std::vector<std::pair<const char*, NoiseConfig>> c;
  c.push_back({"none", NoiseConfig::forModel(NoiseModel::kNone)});
  c.push_back({"l515", NoiseConfig::forModel(NoiseModel::kL515)});
  c.push_back({"d435", NoiseConfig::forModel(NoiseModel::kD435)});
  NoiseConfig all = NoiseConfig::forModel(NoiseModel::kD435);
  all.sigma_const_m = 0.002;
  all.sigma_linear = 0.001;
  all.edge_bleed_prob = 0.8;
  all.speckle_prob = 0.01;
  all.speckle_radius_px = 3;
  all.random_dropout_prob = 0.05;
  all.grazing_cos = 0.5;
  all.grazing_dropout_prob = 0.7;
  all.depth_scale_bias = 0.0063;
  all.quantum_m = 0.0;
  all.max_jitter_px = 6;
  all.edge_band_px = 7;
  c.push_back({"everything", all});
  NoiseConfig zero = NoiseConfig::forModel(NoiseModel::kD435);
  zero.edge_band_px = 0;
  zero.speckle_radius_px = 0;
  zero.max_jitter_px = 0;
  c.push_back({"zero_bands", zero});
  NoiseConfig plain;  // model "none" but with Gaussian noise only
  plain.sigma_const_m = 0.003;
  c.push_back({"none_gauss", plain});
  NoiseConfig jitter_only;
  jitter_only.lateral_fwhm_px = 5.0;
  jitter_only.max_jitter_px = 16;
  jitter_only.edge_jump_min_m = 0.0;
  jitter_only.edge_jump_rel = 0.01;
  c.push_back({"jitter_only", jitter_only});
  return c;
}

/// Index of the first pixel whose bits differ, or -1.
long firstDifference(const DepthImage& a, const DepthImage& b) {
  for (std::size_t i = 0; i < a.data.size(); ++i)
    if (std::memcmp(&a.data[i], &b.data[i], sizeof(float)) != 0) return static_cast<long>(i);
  return -1;
}

}  // namespace

// The optimised pass must reproduce the reference bit for bit: every preset and variant, several
// seeds, frames with edges and holes, with and without the incidence buffer.
TEST(RenderNoiseEquivalence, ApplyNoiseBitIdentical) {
  const std::uint64_t seeds[] = {0, 42, 0xFFFFFFFFFFFFFFFFull};
  std::size_t compared = 0, changed = 0;
  for (const Frame& f : frames())
    for (const auto& [cname, c] : configs()) {
      ASSERT_TRUE(c.validate().empty()) << cname;
      for (std::uint64_t seed : seeds)
        for (bool with_incidence : {false, true}) {
          const std::vector<float>* inc = with_incidence ? &f.r.cos_incidence : nullptr;
          const DepthRange range{0.2, 6.0};
          const DepthImage fast = applyNoise(f.r.depth, c, seed, range, inc);
          const DepthImage ref = refApplyNoise(f.r.depth, c, seed, range, inc);
          ASSERT_EQ(fast.width, ref.width);
          ASSERT_EQ(fast.height, ref.height);
          const long d = firstDifference(fast, ref);
          ASSERT_EQ(d, -1) << f.name << " / " << cname << " seed " << seed
                           << (with_incidence ? " with" : " without") << " incidence: pixel ("
                           << d % f.r.depth.width << ", " << d / f.r.depth.width << ") "
                           << fast.data[d] << " vs reference " << ref.data[d];
          ++compared;
          for (std::size_t i = 0; i < ref.data.size(); ++i)
            changed += ref.data[i] != f.r.depth.data[i];
        }
    }
  // The comparison means something only if the noise actually changed pixels.
  EXPECT_GT(changed, 1000000u);
  std::printf("%zu noisy frames bit-identical to the reference (%zu pixels changed by noise)\n",
              compared, changed);
}

TEST(RenderNoiseEquivalence, EdgeDistanceIdentical) {
  std::vector<DepthImage> images;
  for (const Frame& f : frames()) images.push_back(f.r.depth);
  // No edge at all (everything 255), and distances beyond the 255 cap along a long strip.
  images.push_back(DepthImage(300, 4, 1.0f));
  DepthImage strip(700, 3, 1.5f);
  strip.at(0, 1) = 0.0f;
  images.push_back(strip);
  DepthImage column(2, 600, 1.5f);
  column.at(1, 599) = 3.0f;
  images.push_back(column);
  images.push_back(DepthImage(1, 1, 1.0f));
  for (const auto& [cname, c] : configs())
    for (std::size_t k = 0; k < images.size(); ++k) {
      const std::vector<std::uint8_t> fast = edgeDistance(images[k], c);
      const std::vector<std::uint8_t> ref = refEdgeDistance(images[k], c);
      ASSERT_EQ(fast.size(), ref.size());
      for (std::size_t i = 0; i < ref.size(); ++i)
        ASSERT_EQ(static_cast<int>(fast[i]), static_cast<int>(ref[i]))
            << cname << " image " << k << " pixel " << i;
    }
  // The capped strip really reaches the cap, and the first frame really has edges.
  const std::vector<std::uint8_t> s = edgeDistance(strip, configs()[1].second);
  EXPECT_EQ(s.back(), 255);
  EXPECT_EQ(s[2 * 700 + 300], 255);
  EXPECT_EQ(s[700 + 200], 199);
  const std::vector<std::uint8_t> e = edgeDistance(images[0], configs()[1].second);
  EXPECT_GT(std::count(e.begin(), e.end(), 0), 1000);
}
