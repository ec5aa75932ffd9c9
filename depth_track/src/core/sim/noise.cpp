#include "depth_track/core/sim/noise.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "depth_track/core/yaml_section.hpp"

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

void checkFrame(const DepthImage& d) {
  if (d.width <= 0 || d.height <= 0 ||
      d.data.size() != static_cast<std::size_t>(d.width) * d.height) {
    std::ostringstream s;
    s << "depth frame " << d.width << "x" << d.height << " has " << d.data.size()
      << " values; expected width * height > 0";
    throw DepthInputError(s.str());
  }
}

/// Discontinuity test between two neighbouring depths (the config's edge rule), written without
/// branches so row loops vectorise; same arithmetic, hence the same verdict, as the plain rule
/// (NaN and non-positive depths count as "no return").
inline bool isJump(float a, float b, double jump_min_m, double jump_rel) {
  const bool pa = a > 0.0f, pb = b > 0.0f;
  const double near = std::min(a, b);
  const bool big = std::abs(static_cast<double>(a) - b) > std::max(jump_min_m, jump_rel * near);
  return (pa != pb) | (pa & pb & big);
}

bool isJump(float a, float b, const NoiseConfig& c) {
  return isJump(a, b, c.edge_jump_min_m, c.edge_jump_rel);
}

/// std::round (halves away from zero) without the libm call: truncation and the exact
/// fractional part x - trunc(x) decide the same integer for every finite x.
inline double roundHalfAway(double x) {
  if (!(std::abs(x) < 4503599627370496.0)) return std::round(x);  // already integral, or NaN
  const double t = static_cast<double>(static_cast<std::int64_t>(x));
  const double f = x - t;  // exact: t holds x's integer bits
  // Branch-free (the fraction is random, a branch would mispredict half the time); copysign
  // restores std::round's sign of a zero result.
  const double up = f >= 0.5 ? 1.0 : 0.0, down = f <= -0.5 ? 1.0 : 0.0;
  return std::copysign(t + up - down, x);
}

inline std::uint8_t plusOneSat(std::uint8_t x) {
  return static_cast<std::uint8_t>(std::min<std::uint8_t>(x, 254) + 1);
}

// Row kernels: plain loops over restrict pointers with the count passed by value, so the
// compiler vectorises them (through a captured reference the byte stores could alias the count).

/// o[u] |= s[u], u in [0, n).
inline void orRow(std::uint8_t* __restrict o, const std::uint8_t* __restrict s, int n) {
  for (int u = 0; u < n; ++u) o[u] |= s[u];
}

/// x[u] = min(x[u], p[u] + 1) saturating at 255, u in [0, n).
inline void relaxRow(std::uint8_t* __restrict x, const std::uint8_t* __restrict p, int n) {
  for (int u = 0; u < n; ++u) x[u] = std::min(x[u], plusOneSat(p[u]));
}

/// o[u] = min(o[u], s[u]), u in [0, n).
inline void minRow(std::int32_t* __restrict o, const std::int32_t* __restrict s, int n) {
  for (int u = 0; u < n; ++u) o[u] = std::min(o[u], s[u]);
}

/// o[u] = 1 where a[u] and b[u] are separated by a discontinuity, else 0, u in [0, n).
inline void jumpRow(std::uint8_t* __restrict o, const float* __restrict a,
                    const float* __restrict b, int n, double jump_min_m, double jump_rel) {
  for (int u = 0; u < n; ++u) o[u] = isJump(a[u], b[u], jump_min_m, jump_rel);
}

/// o[u] = 0 where o[u] flags a discontinuity, 255 elsewhere, u in [0, n).
inline void markRow(std::uint8_t* __restrict o, int n) {
  for (int u = 0; u < n; ++u) o[u] = o[u] ? 0 : 255;
}

/// std::round(y) for 0 <= y: adding and removing 2^52 rounds to the nearest integer (ties to
/// even, exactly, in the default rounding mode); a tie rounded down is moved up, as std::round
/// rounds halves away from zero. Beyond 2^52 every double is an integer already.
inline double roundNonNegative(double y) {
  constexpr double kTwo52 = 4503599627370496.0;
  const double t = (y + kTwo52) - kTwo52;
  const double r = t + (y - t == 0.5 ? 1.0 : 0.0);
  return y < kTwo52 ? r : y;
}

/// Final stage of a row of noisy depths (metres): depths outside [min_m, max_m] become 0, and
/// positive ones are quantised to round(z / quantum_m) * quantum_m (quantum_m 0 = none), then
/// stored as float. Branch-free so it vectorises.
inline void finishRow(float* __restrict out, const double* __restrict z, int n, double min_m,
                      double max_m, double quantum_m) {
  if (quantum_m > 0.0) {
    for (int u = 0; u < n; ++u) {
      const bool inside = (z[u] >= min_m) & (z[u] <= max_m);
      const double x = inside ? z[u] : 0.0;
      const double q = roundNonNegative(x / quantum_m) * quantum_m;
      out[u] = static_cast<float>(x > 0.0 ? q : x);
    }
  } else {
    for (int u = 0; u < n; ++u) {
      const bool inside = (z[u] >= min_m) & (z[u] <= max_m);
      out[u] = static_cast<float>(inside ? z[u] : 0.0);
    }
  }
}

/// Dilates a 0/1 mask by a (2r+1)^2 square clipped at the image border: out = 1 where any mask
/// pixel lies within chessboard distance r. Separable (rows, then columns).
std::vector<std::uint8_t> dilateSquare(const std::vector<std::uint8_t>& mask, int w, int h, int r) {
  std::vector<std::uint8_t> rows(mask.size(), 0), out(mask.size(), 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& rr) {
    for (int v = rr.begin(); v < rr.end(); ++v) {
      const std::uint8_t* s = &mask[static_cast<std::size_t>(v) * w];
      std::uint8_t* o = &rows[static_cast<std::size_t>(v) * w];
      for (int du = -r; du <= r; ++du) {
        const int lo = std::max(0, -du), hi = std::min(w, w - du);
        if (hi > lo) orRow(o + lo, s + lo + du, hi - lo);
      }
    }
  });
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& rr) {
    for (int v = rr.begin(); v < rr.end(); ++v)
      for (int vv = std::max(0, v - r); vv <= std::min(h - 1, v + r); ++vv)
        orRow(&out[static_cast<std::size_t>(v) * w], &rows[static_cast<std::size_t>(vv) * w], w);
  });
  return out;
}

/// Order-preserving integer key of a depth for "nearest valid return" minima: the bit pattern
/// of a positive float (which orders like the float), INT32_MAX (a NaN pattern, above every
/// positive float) for no return.
inline std::int32_t depthKey(float q) {
  std::int32_t k;
  std::memcpy(&k, &q, sizeof k);
  return q > 0.0f ? k : std::numeric_limits<std::int32_t>::max();
}

inline float keyDepth(std::int32_t k) {
  if (k == std::numeric_limits<std::int32_t>::max()) return 0.0f;
  float q;
  std::memcpy(&q, &k, sizeof q);
  return q;
}

/// k[u] = depthKey(q[u]), u in [0, n).
inline void keyRow(std::int32_t* __restrict k, const float* __restrict q, int n) {
  for (int u = 0; u < n; ++u) k[u] = depthKey(q[u]);
}

/// Per pixel, the key of the nearest (smallest positive) depth among its row neighbours within
/// r pixels, clipped at the image border.
std::vector<std::int32_t> rowMinKeys(const DepthImage& d, int r) {
  const int w = d.width, h = d.height;
  std::vector<std::int32_t> out(d.data.size(), std::numeric_limits<std::int32_t>::max());
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& rr) {
    std::vector<std::int32_t> keys(w);
    for (int v = rr.begin(); v < rr.end(); ++v) {
      const float* s = &d.data[static_cast<std::size_t>(v) * w];
      keyRow(keys.data(), s, w);
      std::int32_t* o = &out[static_cast<std::size_t>(v) * w];
      for (int du = -r; du <= r; ++du) {
        const int lo = std::max(0, -du), hi = std::min(w, w - du);
        if (hi > lo) minRow(o + lo, keys.data() + lo + du, hi - lo);
      }
    }
  });
  return out;
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
  if (!(std::isfinite(depth_offset_m) && std::abs(depth_offset_m) <= 0.2))
    p.push_back("depth_offset_m must be within +-0.2 m");
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

NoiseConfig loadNoiseModelYaml(const std::string& path) {
  const std::string section = "noise_model";
  const auto entries = readYamlSection(path, section);
  NoiseConfig c;
  for (const auto& [key, value] : entries)
    if (key == "base") {
      try {
        c = NoiseConfig::forModel(parseNoiseModel(value.text));
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(yamlProblem(path, section, key, value.line, e.what()));
      }
    }
  // Every settable field once, by its name in the struct.
  struct Field {
    const char* name;
    double* real;
    int* integer;
  };
  const Field fields[] = {
      {"sigma_const_m", &c.sigma_const_m, nullptr},
      {"sigma_linear", &c.sigma_linear, nullptr},
      {"sigma_quad_per_m", &c.sigma_quad_per_m, nullptr},
      {"lateral_fwhm_px", &c.lateral_fwhm_px, nullptr},
      {"max_jitter_px", nullptr, &c.max_jitter_px},
      {"edge_jump_min_m", &c.edge_jump_min_m, nullptr},
      {"edge_jump_rel", &c.edge_jump_rel, nullptr},
      {"edge_band_px", nullptr, &c.edge_band_px},
      {"edge_dropout_prob", &c.edge_dropout_prob, nullptr},
      {"edge_bleed_prob", &c.edge_bleed_prob, nullptr},
      {"speckle_prob", &c.speckle_prob, nullptr},
      {"speckle_radius_px", nullptr, &c.speckle_radius_px},
      {"random_dropout_prob", &c.random_dropout_prob, nullptr},
      {"grazing_cos", &c.grazing_cos, nullptr},
      {"grazing_dropout_prob", &c.grazing_dropout_prob, nullptr},
      {"quantum_m", &c.quantum_m, nullptr},
      {"depth_scale_bias", &c.depth_scale_bias, nullptr},
      {"depth_offset_m", &c.depth_offset_m, nullptr},
  };
  for (const auto& [key, value] : entries) {
    if (key == "base") continue;
    const Field* f = nullptr;
    for (const Field& cand : fields)
      if (key == cand.name) f = &cand;
    if (!f) {
      std::string known = "base";
      for (const Field& cand : fields) known += std::string(", ") + cand.name;
      throw std::invalid_argument(
          yamlProblem(path, section, key, value.line, "unknown key (known: " + known + ")"));
    }
    const double v = yamlNumber(path, section, key, value);
    if (f->real) {
      *f->real = v;
    } else {
      if (v != std::floor(v) || std::abs(v) > 1e6)
        throw std::invalid_argument(yamlProblem(path, section, key, value.line,
                                                "must be a whole number (got " + value.text + ")"));
      *f->integer = static_cast<int>(v);
    }
  }
  const auto problems = c.validate();
  if (!problems.empty())
    throw std::invalid_argument(path + ": " + section + ": " + joinProblems(problems));
  return c;
}

std::vector<std::uint8_t> edgeDistance(const DepthImage& depth, const NoiseConfig& c) {
  checkFrame(depth);
  const int w = depth.width, h = depth.height;
  const double jmin = c.edge_jump_min_m, jrel = c.edge_jump_rel;
  // Each 4-neighbour pair is judged once: vjump row v = jumps between rows v and v + 1.
  std::vector<std::uint8_t> vjump(static_cast<std::size_t>(w) * std::max(h - 1, 0));
  tbb::parallel_for(tbb::blocked_range<int>(0, h - 1, 16), [&](const tbb::blocked_range<int>& r) {
    for (int v = r.begin(); v < r.end(); ++v) {
      const float* a = &depth.data[static_cast<std::size_t>(v) * w];
      jumpRow(&vjump[static_cast<std::size_t>(v) * w], a, a + w, w, jmin, jrel);
    }
  });
  std::vector<std::uint8_t> d(static_cast<std::size_t>(w) * h);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 16), [&](const tbb::blocked_range<int>& r) {
    std::vector<std::uint8_t> hjump(w, 0);  // hjump[u]: jump between u and u + 1
    for (int v = r.begin(); v < r.end(); ++v) {
      const float* z = &depth.data[static_cast<std::size_t>(v) * w];
      std::uint8_t* o = &d[static_cast<std::size_t>(v) * w];
      std::fill(o, o + w, 0);
      if (w > 1) {
        jumpRow(hjump.data(), z, z + 1, w - 1, jmin, jrel);
        orRow(o, hjump.data(), w - 1);
        orRow(o + 1, hjump.data(), w - 1);
      }
      if (v > 0) orRow(o, &vjump[static_cast<std::size_t>(v - 1) * w], w);
      if (v + 1 < h) orRow(o, &vjump[static_cast<std::size_t>(v) * w], w);
      markRow(o, w);
    }
  });
  // Two-pass chessboard distance transform (8-neighbour chamfer, exact for this metric). Every
  // step is x = min(x, neighbour + 1) saturating at 255, so the order of the steps inside a pass
  // does not matter as long as each row is final before the next one reads it: the three
  // neighbours of the previous row are applied to the whole row at once (vectorised), then the
  // in-row sweep.
  for (int v = 0; v < h; ++v) {
    std::uint8_t* x = &d[static_cast<std::size_t>(v) * w];
    if (v > 0) {
      const std::uint8_t* p = x - w;
      relaxRow(x, p, w);
      relaxRow(x + 1, p, w - 1);
      relaxRow(x, p + 1, w - 1);
    }
    for (int u = 1; u < w; ++u) x[u] = std::min(x[u], plusOneSat(x[u - 1]));
  }
  for (int v = h - 1; v >= 0; --v) {
    std::uint8_t* x = &d[static_cast<std::size_t>(v) * w];
    if (v + 1 < h) {
      const std::uint8_t* p = x + w;
      relaxRow(x, p, w);
      relaxRow(x + 1, p, w - 1);
      relaxRow(x, p + 1, w - 1);
    }
    for (int u = w - 2; u >= 0; --u) x[u] = std::min(x[u], plusOneSat(x[u + 1]));
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
      c.depth_scale_bias == 0.0 && c.depth_offset_m == 0.0) {
    DepthImage out = clean;
    for (float& z : out.data)
      if (!(z >= range.min_m && z <= range.max_m)) z = 0.0f;
    return out;
  }

  const int w = clean.width, h = clean.height;
  const std::size_t n = static_cast<std::size_t>(w) * h;
  seed = mix64(seed ^ 0x5DEECE66Dull);  // decorrelates neighbouring user seeds
  const std::vector<std::uint8_t> edge = edgeDistance(clean, c);
  const double jitter_sigma = c.lateral_fwhm_px / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  const int jmax = c.max_jitter_px;
  const int band = c.edge_band_px;

  // Speckle: a pixel is lost when a blob seed lies within speckle_radius_px (chessboard), i.e.
  // the seed mask dilated by the blob square (instead of scanning the square at every pixel).
  std::vector<std::uint8_t> speckle;
  if (c.speckle_prob > 0.0) {
    std::vector<std::uint8_t> seeds(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t i = r.begin(); i < r.end(); ++i)
                          seeds[i] = uniform(seed, i, kSpeckle) < c.speckle_prob ? 1 : 0;
                      });
    speckle = dilateSquare(seeds, w, h, c.speckle_radius_px);
  }
  // Edge bleeding needs the nearest return in the band square around a pixel: minima along rows
  // here (whole frame, vectorised), along the column only at the pixels that bleed.
  std::vector<std::int32_t> row_min;
  if (c.edge_bleed_prob > 0.0) row_min = rowMinKeys(clean, band);

  DepthImage out(w, h);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    // The Gaussian depth noise of pixels 2k and 2k+1 shares one Box-Muller pair: its radius and
    // angle are computed once and kept for the partner (which may start the next row).
    std::size_t cached_pair = static_cast<std::size_t>(-1);
    double radius = 0.0, cos_a = 0.0, sin_a = 0.0;
    std::vector<double> row(w);  // noisy depths of the row before clipping and quantisation
    for (int v = r.begin(); v < r.end(); ++v) {
      for (int u = 0; u < w; ++u) {
        const std::size_t i = static_cast<std::size_t>(v) * w + u;
        const int e = edge[i];
        double z = clean.data[i];

        // Lateral resolution: on a smooth surface the spot average is the centre depth, so only
        // pixels within reach of an edge report a neighbour's depth (ragged, eroded edges).
        if (jitter_sigma > 0.0 && e <= jmax) {
          auto offset = [&](Stream a, Stream b) {
            const double o = roundHalfAway(jitter_sigma * gaussian(seed, i, a, b));
            return static_cast<int>(
                std::clamp(o, -static_cast<double>(jmax), static_cast<double>(jmax)));
          };
          const int su = std::clamp(u + offset(kJitterU, kJitterU2), 0, w - 1);
          const int sv = std::clamp(v + offset(kJitterV, kJitterV2), 0, h - 1);
          z = clean.at(su, sv);
        }

        // Stereo edge fattening: the background near an edge takes the foreground depth.
        if (c.edge_bleed_prob > 0.0 && e <= band && uniform(seed, i, kBleed) < c.edge_bleed_prob) {
          std::int32_t key = std::numeric_limits<std::int32_t>::max();
          for (int vv = std::max(0, v - band); vv <= std::min(h - 1, v + band); ++vv)
            key = std::min(key, row_min[static_cast<std::size_t>(vv) * w + u]);
          const float fg = keyDepth(key);
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
        if (z > 0.0) z += c.depth_offset_m;
        if (z > 0.0) {
          const double sigma = c.sigmaAt(z);
          if (sigma > 0.0) {
            // Box-Muller on the uniforms of pair i / 2: cos to the even pixel, sin to the odd.
            const std::size_t pair = i >> 1;
            if (pair != cached_pair) {
              cached_pair = pair;
              const double u1 = uniform(seed, pair, kGauss1), u2 = uniform(seed, pair, kGauss2);
              radius = std::sqrt(-2.0 * std::log(u1));
              // Both at once (one sincos call); unused when the partner has no return.
              const double angle = 2.0 * M_PI * u2;
              ::sincos(angle, &sin_a, &cos_a);
            }
            const double g = radius * ((i & 1) ? sin_a : cos_a);
            z += sigma * g;
          }
        }

        if (!speckle.empty() && speckle[i] && z > 0.0) z = 0.0;
        if (c.random_dropout_prob > 0.0 && uniform(seed, i, kRandomDrop) < c.random_dropout_prob)
          z = 0.0;

        row[u] = z;
      }
      finishRow(&out.data[static_cast<std::size_t>(v) * w], row.data(), w, range.min_m, range.max_m,
                c.quantum_m);
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
