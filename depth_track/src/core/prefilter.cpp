#include "depth_track/core/prefilter.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace depth_track {

PrefilterType parsePrefilterType(const std::string& name) {
  if (name == "none" || name == "0") return PrefilterType::kNone;
  if (name == "bilateral" || name == "1") return PrefilterType::kBilateral;
  if (name == "crop" || name == "2") return PrefilterType::kCrop;
  throw std::invalid_argument("unknown prefilter type '" + name +
                              "' (expected none, bilateral or crop)");
}

std::string toString(PrefilterType type) {
  switch (type) {
    case PrefilterType::kNone:
      return "none";
    case PrefilterType::kBilateral:
      return "bilateral";
    case PrefilterType::kCrop:
      return "crop";
  }
  return "unknown";
}

BilateralMode parseBilateralMode(const std::string& name) {
  if (name == "full") return BilateralMode::kFull;
  if (name == "separable") return BilateralMode::kSeparable;
  throw std::invalid_argument("unknown bilateral mode '" + name + "' (expected full or separable)");
}

std::string toString(BilateralMode mode) {
  return mode == BilateralMode::kFull ? "full" : "separable";
}

std::vector<std::string> PrefilterConfig::validate() const {
  std::vector<std::string> problems;
  if (type == PrefilterType::kBilateral) {
    if (kernel_size_px < 3 || kernel_size_px > 101 || kernel_size_px % 2 == 0) {
      problems.push_back("kernel_size_px " + std::to_string(kernel_size_px) +
                         " must be odd and within 3..101");
    }
    if (!(std::isfinite(spatial_sigma_px) && spatial_sigma_px > 0.0))
      problems.push_back("spatial_sigma_px must be a positive number of pixels");
    if (!(std::isfinite(depth_sigma_m) && depth_sigma_m > 0.0))
      problems.push_back("depth_sigma_m must be a positive number of metres");
    if (!(std::isfinite(depth_cutoff_sigmas) && depth_cutoff_sigmas > 0.0 &&
          depth_cutoff_sigmas <= 5.0))
      problems.push_back("depth_cutoff_sigmas must lie in (0, 5]");
  }
  if (type == PrefilterType::kCrop) {
    if (crop_x_px < 0 || crop_y_px < 0) problems.push_back("crop_x_px and crop_y_px must be >= 0");
    if (crop_width_px < 1 || crop_height_px < 1)
      problems.push_back("crop_width_px and crop_height_px must be >= 1 pixel");
  }
  return problems;
}

std::vector<std::string> PrefilterConfig::validate(int width, int height) const {
  std::vector<std::string> problems = validate();
  if (type == PrefilterType::kCrop && (static_cast<long>(crop_x_px) + crop_width_px > width ||
                                       static_cast<long>(crop_y_px) + crop_height_px > height)) {
    std::ostringstream s;
    s << "crop rectangle " << crop_width_px << "x" << crop_height_px << " at (" << crop_x_px << ", "
      << crop_y_px << ") does not fit a " << width << "x" << height << " frame";
    problems.push_back(s.str());
  }
  return problems;
}

namespace {

// exp(-t) for 0 <= t <= 12.5 without a library call, so the tap loop below vectorises:
// exp(-t) = exp(-t/128)^128, the inner exponential by its cubic Taylor polynomial (truncation
// < 4e-6 relative for t/128 <= 0.1), then 7 squarings. Relative error < 1e-3 over the range
// (< 2e-5 for t <= 4.5, the 3-sigma default).
inline float expNegApprox(float t) {
  const float s = t * (1.0f / 128.0f);
  float e = 1.0f - s * (1.0f - s * (0.5f - s * (1.0f / 6.0f)));
  e *= e;
  e *= e;
  e *= e;
  e *= e;
  e *= e;
  e *= e;
  e *= e;
  return e;
}

// A usable depth: positive and finite (frames from depthFromRaw hold 0 for anything else, but a
// hand-made frame may carry NaN or Inf; they count as "no return" here too).
inline bool isDepth(float d) { return d > 0.0f && d < std::numeric_limits<float>::infinity(); }

// Copies a frame into a buffer with a border of rx columns / ry rows. Missing pixels and the
// border hold a stand-in depth further from every real depth of the frame than the range cutoff
// (cutoff_m), so its range weight is cut off and the tap loop needs no separate validity test;
// its weight is exactly 0, so it never reaches the sums.
std::vector<float> padForFilter(const DepthImage& in, int rx, int ry, double cutoff_m,
                                std::ptrdiff_t* stride) {
  float max_depth = 0.0f;
  for (float d : in.data)
    if (std::isfinite(d)) max_depth = std::max(max_depth, d);
  const float far = static_cast<float>(2.0 * max_depth + 4.0 * cutoff_m + 1.0e4);
  *stride = in.width + 2 * rx;
  std::vector<float> p(static_cast<std::size_t>(*stride) * (in.height + 2 * ry), far);
  for (int v = 0; v < in.height; ++v) {
    const float* src = in.data.data() + static_cast<std::size_t>(v) * in.width;
    float* dst = p.data() + static_cast<std::size_t>(v + ry) * *stride + rx;
    for (int u = 0; u < in.width; ++u) dst[u] = isDepth(src[u]) ? src[u] : far;
  }
  return p;
}

// ---- each pair of pixels evaluated once ---------------------------------------------------------
// The bilateral weight of a pixel pair is symmetric (spatial Gaussian of the offset, range
// Gaussian of the depth difference), so a pass visits only half of the kernel's offsets (dy > 0,
// or dy = 0 and dx > 0) and adds each weight to both pixels of the pair: half the exponentials of
// the direct form. Each loop runs along a row, so it vectorises without reassociating any sum.
// Rows are processed in fixed bands of kBandRows; a band also accumulates into the ry rows below
// it, and the bands' sums are merged in band order, so the result does not depend on the thread
// count.
constexpr int kBandRows = 32;

// Pairs of pixels in two different rows: centre row `c` and neighbour row `nb` (already offset
// by dx). Adds each pair's weight to both rows' accumulators.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void pairRowsDistinct(const float* __restrict c, const float* __restrict nb, int width, float ws,
                      float inv_2sd2, float t_cut, float* __restrict num_c,
                      float* __restrict den_c, float* __restrict num_n, float* __restrict den_n) {
  for (int x = 0; x < width; ++x) {
    const float a = c[x], b = nb[x];
    const float dz = b - a;
    const float t = dz * dz * inv_2sd2;
    const float keep = static_cast<float>(t <= t_cut);
    const float w = ws * expNegApprox(t < t_cut ? t : t_cut) * keep;
    num_c[x] += w * b;
    den_c[x] += w;
    num_n[x] += w * a;
    den_n[x] += w;
  }
}

// Pairs (x, x + dx) within one row: the two ends share one accumulator row, so the weights go
// through a scratch buffer and each direction is its own (vectorisable) loop.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void pairRowSame(const float* __restrict c, int width, int dx, float ws, float inv_2sd2,
                 float t_cut, float* __restrict w_buf, float* __restrict num,
                 float* __restrict den) {
  for (int x = 0; x < width; ++x) {
    const float dz = c[x + dx] - c[x];
    const float t = dz * dz * inv_2sd2;
    const float keep = static_cast<float>(t <= t_cut);
    w_buf[x] = ws * expNegApprox(t < t_cut ? t : t_cut) * keep;
  }
  for (int x = 0; x < width; ++x) {
    num[x] += w_buf[x] * c[x + dx];
    den[x] += w_buf[x];
  }
  for (int x = 0; x < width; ++x) {
    num[x + dx] += w_buf[x] * c[x];
    den[x + dx] += w_buf[x];
  }
}

// A bilateral pass with a (2 ry + 1) x (2 rx + 1) kernel by the pair-symmetric scheme above:
// the full kernel (rx = ry = r) or one 1-D pass of the separable form (ry = 0 or rx = 0).
DepthImage bilateralPass(const DepthImage& in, int rx, int ry, const PrefilterConfig& c,
                         const WorkerPool& pool) {
  const int W = in.width, H = in.height;
  std::ptrdiff_t ps = 0;
  const std::vector<float> padded =
      padForFilter(in, rx, ry, c.depth_cutoff_sigmas * c.depth_sigma_m, &ps);
  const int kw = 2 * rx + 1, kh = 2 * ry + 1;
  std::vector<float> spatial(static_cast<std::size_t>(kw) * kh);
  const double inv_2ss2 = 1.0 / (2.0 * c.spatial_sigma_px * c.spatial_sigma_px);
  for (int dy = -ry; dy <= ry; ++dy)
    for (int dx = -rx; dx <= rx; ++dx)
      spatial[(dy + ry) * kw + dx + rx] =
          static_cast<float>(std::exp(-(dx * dx + dy * dy) * inv_2ss2));
  const float inv_2sd2 = static_cast<float>(1.0 / (2.0 * c.depth_sigma_m * c.depth_sigma_m));
  const float t_cut = static_cast<float>(0.5 * c.depth_cutoff_sigmas * c.depth_cutoff_sigmas);

  const int n_bands = (H + kBandRows - 1) / kBandRows;
  const std::ptrdiff_t as = W + 2 * rx;  // accumulator row stride (columns -rx .. W + rx)
  std::vector<std::vector<float>> band_num(n_bands), band_den(n_bands);
  auto run_band = [&](int b) {
    const int y0 = b * kBandRows, y1 = std::min(H, y0 + kBandRows);
    std::vector<float>& num = band_num[b];
    std::vector<float>& den = band_den[b];
    num.assign(static_cast<std::size_t>(y1 - y0 + ry) * as, 0.0f);
    den.assign(num.size(), 0.0f);
    std::vector<float> w_buf(W);
    for (int y = y0; y < y1; ++y) {
      const float* crow = padded.data() + (y + ry) * ps + rx;
      float* num_c = num.data() + (y - y0) * as + rx;
      float* den_c = den.data() + (y - y0) * as + rx;
      for (int dx = 1; dx <= rx; ++dx)
        pairRowSame(crow, W, dx, spatial[ry * kw + dx + rx], inv_2sd2, t_cut, w_buf.data(), num_c,
                    den_c);
      for (int dy = 1; dy <= ry; ++dy)
        for (int dx = -rx; dx <= rx; ++dx)
          pairRowsDistinct(crow, padded.data() + (y + ry + dy) * ps + rx + dx, W,
                           spatial[(dy + ry) * kw + dx + rx], inv_2sd2, t_cut, num_c, den_c,
                           num.data() + (y - y0 + dy) * as + rx + dx,
                           den.data() + (y - y0 + dy) * as + rx + dx);
    }
  };
  pool.parallelFor(0, n_bands, 1, [&](int b0, int b1) {
    for (int b = b0; b < b1; ++b) run_band(b);
  });

  // Merge in band order; columns outside the image and rows below it only ever received weight
  // 0 (their partners are the far stand-in) and are dropped.
  std::vector<float> num(static_cast<std::size_t>(W) * H, 0.0f), den(num.size(), 0.0f);
  for (int b = 0; b < n_bands; ++b) {
    const int y0 = b * kBandRows;
    const int rows = std::min(H, y0 + kBandRows) - y0 + ry;
    for (int ay = 0; ay < rows && y0 + ay < H; ++ay) {
      const float* bn = band_num[b].data() + ay * as + rx;
      const float* bd = band_den[b].data() + ay * as + rx;
      float* gn = num.data() + static_cast<std::size_t>(y0 + ay) * W;
      float* gd = den.data() + static_cast<std::size_t>(y0 + ay) * W;
      for (int x = 0; x < W; ++x) {
        gn[x] += bn[x];
        gd[x] += bd[x];
      }
    }
  }
  // Add the centre tap (weight 1) last; invalid centres stay invalid.
  DepthImage out(W, H);
  for (std::size_t i = 0; i < out.data.size(); ++i) {
    const float z = in.data[i];
    out.data[i] = isDepth(z) ? (num[i] + z) / (den[i] + 1.0f) : 0.0f;
  }
  return out;
}

}  // namespace

DepthImage applyPrefilter(const DepthImage& depth, const PrefilterConfig& config, int threads) {
  return applyPrefilter(depth, config, WorkerPool(std::max(1, threads)));
}

DepthImage applyPrefilter(const DepthImage& depth, const PrefilterConfig& config,
                          const WorkerPool& pool) {
  const auto problems = config.validate(depth.width, depth.height);
  if (!problems.empty())
    throw std::invalid_argument("invalid prefilter config: " + joinProblems(problems));
  if (depth.data.size() != static_cast<std::size_t>(depth.width) * depth.height)
    throw DepthInputError("depth frame buffer size does not match its width x height");

  switch (config.type) {
    case PrefilterType::kNone:
      return depth;
    case PrefilterType::kCrop: {
      DepthImage out(depth.width, depth.height);
      for (int v = config.crop_y_px; v < config.crop_y_px + config.crop_height_px; ++v)
        for (int u = config.crop_x_px; u < config.crop_x_px + config.crop_width_px; ++u)
          out.at(u, v) = depth.at(u, v);
      return out;
    }
    case PrefilterType::kBilateral: {
      if (depth.empty()) return depth;
      const int r = config.kernel_size_px / 2;
      if (config.bilateral_mode == BilateralMode::kFull)
        return bilateralPass(depth, r, r, config, pool);
      return bilateralPass(bilateralPass(depth, r, 0, config, pool), 0, r, config, pool);
    }
  }
  return depth;
}

}  // namespace depth_track
