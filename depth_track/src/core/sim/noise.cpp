#include "depth_track/core/sim/noise.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace depth_track {
namespace sim {

namespace {

/// SplitMix64 finaliser: a strong 64-bit mixer, used as a counter-based random generator.
inline std::uint64_t mix64(std::uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// Purposes of random draws; each pixel draws independently per purpose.
enum Stream : std::uint64_t {
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

/// Uniform in (0, 1) for (seed, pixel, stream): element (pixel, stream) of the SplitMix64 sequence
/// whose state starts at the mixed seed, so any draw is computed directly without order.
inline double uniform(std::uint64_t seed_mixed, std::size_t idx, Stream s) {
  const std::uint64_t counter = static_cast<std::uint64_t>(idx) * kNumStreams + s;
  const std::uint64_t h = mix64(seed_mixed + counter * 0x9E3779B97F4A7C15ull);
  return (static_cast<double>(h >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

/// Standard normal for pixel idx: Box-Muller on the uniforms of the pixel pair idx / 2, whose two
/// independent outputs (cos and sin) go to the even and the odd pixel.
inline double pairedGaussian(std::uint64_t seed, std::size_t idx) {
  const std::size_t pair = idx >> 1;
  const double u1 = uniform(seed, pair, kGauss1), u2 = uniform(seed, pair, kGauss2);
  const double r = std::sqrt(-2.0 * std::log(u1));
  return (idx & 1) ? r * std::sin(2.0 * M_PI * u2) : r * std::cos(2.0 * M_PI * u2);
}

/// Standard normal by Box-Muller from two uniform streams.
inline double gaussian(std::uint64_t seed, std::size_t idx, Stream a, Stream b) {
  const double u1 = uniform(seed, idx, a), u2 = uniform(seed, idx, b);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

bool isJump(float a, float b, const NoiseConfig& c) {
  if ((a > 0.0f) != (b > 0.0f)) return true;
  if (a <= 0.0f) return false;
  const double near = std::min(a, b);
  return std::abs(static_cast<double>(a) - b) > std::max(c.edge_jump_min_m, c.edge_jump_rel * near);
}

void checkFrame(const DepthImage& d) {
  if (d.width <= 0 || d.height <= 0 ||
      d.data.size() != static_cast<std::size_t>(d.width) * d.height) {
    std::ostringstream s;
    s << "depth frame " << d.width << "x" << d.height << " has " << d.data.size()
      << " values; expected width * height > 0";
    throw DepthInputError(s.str());
  }
}

}  // namespace

NoiseModel parseNoiseModel(const std::string& name) {
  if (name == "none") return NoiseModel::kNone;
  if (name == "l515") return NoiseModel::kL515;
  if (name == "d435") return NoiseModel::kD435;
  throw std::invalid_argument("unknown noise model '" + name + "' (known: none, l515, d435)");
}

std::string noiseModelName(NoiseModel model) {
  switch (model) {
    case NoiseModel::kNone:
      return "none";
    case NoiseModel::kL515:
      return "l515";
    case NoiseModel::kD435:
      return "d435";
  }
  return "unknown";
}

NoiseConfig NoiseConfig::forModel(NoiseModel model) {
  NoiseConfig c;
  c.model = model;
  switch (model) {
    case NoiseModel::kNone:
      break;
    case NoiseModel::kL515:
      // sigma(1 m) = 2.6 mm, sigma(3 m) = 4.8 mm, sigma(3.2 m) = 5.0 mm: "crosses 5 mm above 3 m".
      c.sigma_const_m = 0.0015;
      c.sigma_linear = 0.0011;
      // Lateral resolution about 2.4 px (thesis 4.1.4), read as the FWHM of the spot position.
      c.lateral_fwhm_px = 2.4;
      // "A solid line two pixels wide of dropout with further broken lines" along edges.
      c.edge_band_px = 2;
      c.edge_dropout_prob = 0.9;
      c.random_dropout_prob = 0.001;
      // Weak returns at grazing incidence ("dropout ... close to the ground plane"): beyond
      // 80 deg from the normal, certain drop-out approached at 90 deg.
      c.grazing_cos = 0.17;
      c.grazing_dropout_prob = 1.0;
      c.quantum_m = 0.00025;
      break;
    case NoiseModel::kD435:
      // 30 mm at 2.5 m (thesis: 24-37 mm); above the 5 mm voxel size from 1.1 m on, consistent
      // with "exceeds 5 mm at 1.5 m".
      c.sigma_quad_per_m = 0.0048;
      c.lateral_fwhm_px = 3.5;
      c.max_jitter_px = 4;
      c.edge_band_px = 4;
      c.edge_dropout_prob = 0.5;
      c.edge_bleed_prob = 0.5;  // false readings extending outwards from edges (thesis fig. 4.18)
      // About 2 % of pixels lost to speckle blobs and 0.2 % singly: a fill rate near 95 % on
      // plain surfaces once edges are counted.
      c.speckle_prob = 0.0008;
      c.speckle_radius_px = 2;
      c.random_dropout_prob = 0.002;
      c.grazing_cos = 0.17;
      c.grazing_dropout_prob = 1.0;
      c.quantum_m = 0.001;
      break;
  }
  return c;
}

std::vector<std::string> NoiseConfig::validate() const {
  std::vector<std::string> p;
  auto nonneg = [&](double v, const char* name) {
    if (!(std::isfinite(v) && v >= 0.0)) p.push_back(std::string(name) + " must be >= 0");
  };
  auto prob = [&](double v, const char* name) {
    if (!(std::isfinite(v) && v >= 0.0 && v <= 1.0))
      p.push_back(std::string(name) + " must be a probability in [0, 1]");
  };
  nonneg(sigma_const_m, "sigma_const_m");
  nonneg(sigma_linear, "sigma_linear");
  nonneg(sigma_quad_per_m, "sigma_quad_per_m");
  nonneg(lateral_fwhm_px, "lateral_fwhm_px");
  nonneg(edge_jump_min_m, "edge_jump_min_m");
  nonneg(edge_jump_rel, "edge_jump_rel");
  nonneg(quantum_m, "quantum_m");
  prob(edge_dropout_prob, "edge_dropout_prob");
  prob(edge_bleed_prob, "edge_bleed_prob");
  prob(speckle_prob, "speckle_prob");
  prob(random_dropout_prob, "random_dropout_prob");
  prob(grazing_dropout_prob, "grazing_dropout_prob");
  if (!(std::isfinite(depth_scale_bias) && std::abs(depth_scale_bias) <= 0.2))
    p.push_back("depth_scale_bias must be within +-0.2");
  if (!(std::isfinite(grazing_cos) && grazing_cos >= 0.0 && grazing_cos < 1.0))
    p.push_back("grazing_cos must be in [0, 1)");
  if (max_jitter_px < 0 || max_jitter_px > 16) p.push_back("max_jitter_px must be in [0, 16]");
  if (edge_band_px < 0 || edge_band_px > 16) p.push_back("edge_band_px must be in [0, 16]");
  if (speckle_radius_px < 0 || speckle_radius_px > 16)
    p.push_back("speckle_radius_px must be in [0, 16]");
  if (edge_jump_min_m == 0.0 && edge_jump_rel == 0.0)
    p.push_back("edge_jump_min_m and edge_jump_rel cannot both be 0 (every pixel an edge)");
  return p;
}

std::vector<std::uint8_t> edgeDistance(const DepthImage& depth, const NoiseConfig& c) {
  checkFrame(depth);
  const int w = depth.width, h = depth.height;
  std::vector<std::uint8_t> d(static_cast<std::size_t>(w) * h, 255);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& r) {
    for (int v = r.begin(); v < r.end(); ++v)
      for (int u = 0; u < w; ++u) {
        const float z = depth.at(u, v);
        if ((u > 0 && isJump(z, depth.at(u - 1, v), c)) ||
            (u + 1 < w && isJump(z, depth.at(u + 1, v), c)) ||
            (v > 0 && isJump(z, depth.at(u, v - 1), c)) ||
            (v + 1 < h && isJump(z, depth.at(u, v + 1), c)))
          d[static_cast<std::size_t>(v) * w + u] = 0;
      }
  });
  // Two-pass chessboard distance transform.
  auto at = [&](int u, int v) -> std::uint8_t& { return d[static_cast<std::size_t>(v) * w + u]; };
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

DepthImage applyNoise(const DepthImage& clean, const NoiseConfig& c, std::uint64_t seed,
                      const DepthRange& range, const std::vector<float>* cos_incidence) {
  const auto problems = c.validate();
  if (!problems.empty()) throw std::invalid_argument("NoiseConfig: " + joinProblems(problems));
  const auto range_problems = range.validate();
  if (!range_problems.empty())
    throw std::invalid_argument("DepthRange: " + joinProblems(range_problems));
  checkFrame(clean);
  if (cos_incidence && cos_incidence->size() != clean.data.size()) {
    std::ostringstream s;
    s << "incidence buffer has " << cos_incidence->size() << " values for a " << clean.width << "x"
      << clean.height << " frame";
    throw DepthInputError(s.str());
  }
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
  seed = mix64(seed ^ 0x5DEECE66Dull);  // decorrelates neighbouring user seeds
  const std::vector<std::uint8_t> edge = edgeDistance(clean, c);

  // Speckle seeds, dilated into blobs below.
  std::vector<std::uint8_t> speckle_seed;
  if (c.speckle_prob > 0.0) {
    speckle_seed.assign(n, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t i = r.begin(); i < r.end(); ++i)
                          speckle_seed[i] = uniform(seed, i, kSpeckle) < c.speckle_prob ? 1 : 0;
                      });
  }

  const double jitter_sigma = c.lateral_fwhm_px / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  const int jmax = c.max_jitter_px;
  const int band = c.edge_band_px;

  DepthImage out(w, h);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    for (int v = r.begin(); v < r.end(); ++v)
      for (int u = 0; u < w; ++u) {
        const std::size_t i = static_cast<std::size_t>(v) * w + u;
        const int e = edge[i];
        double z = clean.data[i];

        // Lateral resolution: on a smooth surface the spot average is the centre depth, so only
        // pixels within reach of an edge report a neighbour's depth (ragged, eroded edges).
        if (jitter_sigma > 0.0 && e <= jmax) {
          auto offset = [&](Stream a, Stream b) {
            const double o = std::round(jitter_sigma * gaussian(seed, i, a, b));
            return static_cast<int>(
                std::clamp(o, -static_cast<double>(jmax), static_cast<double>(jmax)));
          };
          const int su = std::clamp(u + offset(kJitterU, kJitterU2), 0, w - 1);
          const int sv = std::clamp(v + offset(kJitterV, kJitterV2), 0, h - 1);
          z = clean.at(su, sv);
        }

        // Stereo edge fattening: the background near an edge takes the foreground depth.
        if (c.edge_bleed_prob > 0.0 && e <= band && uniform(seed, i, kBleed) < c.edge_bleed_prob) {
          float fg = 0.0f;
          for (int dv = -band; dv <= band; ++dv)
            for (int du = -band; du <= band; ++du) {
              const int uu = u + du, vv = v + dv;
              if (uu < 0 || vv < 0 || uu >= w || vv >= h) continue;
              const float q = clean.at(uu, vv);
              if (q > 0.0f && (fg == 0.0f || q < fg)) fg = q;
            }
          if (fg > 0.0f && (z <= 0.0 || isJump(static_cast<float>(z), fg, c))) z = fg;
        }

        // Drop-outs along edges: certain at the edge, fading out over the band.
        if (c.edge_dropout_prob > 0.0 && e <= band) {
          const double p = c.edge_dropout_prob * (1.0 - static_cast<double>(e) / (band + 1));
          if (uniform(seed, i, kEdgeDrop) < p) z = 0.0;
        }

        // Grazing incidence, judged at the pixel's own ray (the clean surface it sees).
        if (cos_incidence && c.grazing_dropout_prob > 0.0 && z > 0.0) {
          const double ci = (*cos_incidence)[i];
          if (ci < c.grazing_cos &&
              uniform(seed, i, kGrazing) < c.grazing_dropout_prob * (1.0 - ci / c.grazing_cos))
            z = 0.0;
        }

        z *= 1.0 + c.depth_scale_bias;
        if (z > 0.0) {
          const double sigma = c.sigmaAt(z);
          if (sigma > 0.0) z += sigma * pairedGaussian(seed, i);
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
        if (c.random_dropout_prob > 0.0 && uniform(seed, i, kRandomDrop) < c.random_dropout_prob)
          z = 0.0;

        if (!(z >= range.min_m && z <= range.max_m)) z = 0.0;
        if (z > 0.0 && c.quantum_m > 0.0) z = std::round(z / c.quantum_m) * c.quantum_m;
        out.data[i] = static_cast<float>(z);
      }
  });
  return out;
}

RawDepth16 toRaw16(const DepthImage& depth, double depth_scale_m) {
  if (!(std::isfinite(depth_scale_m) && depth_scale_m > 0.0))
    throw std::invalid_argument("toRaw16: depth scale must be a positive number of metres/unit");
  checkFrame(depth);
  RawDepth16 raw;
  raw.width = depth.width;
  raw.height = depth.height;
  raw.depth_scale_m = depth_scale_m;
  raw.data.resize(depth.data.size());
  for (std::size_t i = 0; i < depth.data.size(); ++i) {
    const double z = depth.data[i];
    const double units = std::round(z / depth_scale_m);
    if (!std::isfinite(z) || z < 0.0 || units > 65535.0) {
      std::ostringstream s;
      s << "toRaw16: depth " << z << " m at pixel (" << i % depth.width << ", " << i / depth.width
        << ") does not fit 16 bits at " << depth_scale_m << " m/unit";
      throw DepthInputError(s.str());
    }
    raw.data[i] = static_cast<std::uint16_t>(units);
  }
  return raw;
}

double nativeDepthScale(NoiseModel model) {
  switch (model) {
    case NoiseModel::kL515:
      return 0.00025;
    case NoiseModel::kD435:
      return 0.001;
    case NoiseModel::kNone:
      break;
  }
  return 1.0 / 5000.0;
}

std::uint64_t frameSeed(std::uint64_t run_seed, std::uint64_t frame_index) {
  return mix64(mix64(run_seed) ^ (frame_index * 0xD1B54A32D192ED03ull + 1));
}

}  // namespace sim
}  // namespace depth_track
