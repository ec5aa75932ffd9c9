#include "depth_track/core/map/map_fuser.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>

#include "../simd4.hpp"
#include "carve_walk.hpp"
#include "depth_track/core/noise_model.hpp"
#include "voxel_map_impl.hpp"

namespace depth_track {

using map_detail::Block;
using map_detail::Chunk;

namespace {

// Applies a log-odds change to voxel i of block b (in chunk c); keeps the counters consistent.
inline void applyUpdate(VoxelMap::Impl& m, Chunk& c, int bi, Block& b, int i, float delta) {
  using namespace map_detail;
  float l = b.has(&map_detail::Masks::observed, i) ? b.log_odds[i] : 0.0f;
  b.set(&map_detail::Masks::observed, i);
  l = std::min(std::max(l + delta, m.l_min), m.l_max);
  b.log_odds[i] = l;
  const bool occ = l > m.l_occ;
  if (occ != b.has(&map_detail::Masks::occupied, i)) {
    if (occ) {
      b.set(&map_detail::Masks::occupied, i);
      c.occ[bi][i >> 6] |= std::uint64_t{1} << (i & 63);
      ++c.n_occ[bi];
      if (b.n_occupied++ == 0) ++c.occupied_blocks;
      ++m.occupied_count;
    } else {
      b.clear(&map_detail::Masks::occupied, i);
      c.occ[bi][i >> 6] &= ~(std::uint64_t{1} << (i & 63));
      --c.n_occ[bi];
      if (--b.n_occupied == 0) --c.occupied_blocks;
      --m.occupied_count;
    }
  }
  b.set(&map_detail::Masks::dirty, i);
  b.any_dirty = true;
}

// True when voxel i of b has not yet been updated in the current frame (and marks it).
inline bool claim(VoxelMap::Impl& m, Block& b, int i) {
  using namespace map_detail;
  if (b.touch_frame != m.frame) {
    for (auto& w : b.mask) w.touched = 0;
    b.touch_frame = m.frame;
  }
  if (b.has(&map_detail::Masks::touched, i)) return false;
  b.set(&map_detail::Masks::touched, i);
  return true;
}

// Chunk at chunk coordinate c, allocated (growing the dense index) when missing; nullptr when
// the index would exceed its size cap.
Chunk* chunkAlloc(VoxelMap::Impl& m, const Eigen::Vector3i& c) {
  if (Chunk* ch = m.chunkAt(c.x(), c.y(), c.z())) return ch;
  const bool inside = (c.array() >= m.index_lo.array()).all() &&
                      (c.array() < (m.index_lo + m.index_dims).array()).all();
  if (!inside) {
    Eigen::Vector3i lo = c.array() - 2, hi = c.array() + 3;  // slack: grow rarely
    if (!m.index.empty()) {
      lo = lo.cwiseMin(m.index_lo);
      hi = hi.cwiseMax(m.index_lo + m.index_dims);
    }
    const Eigen::Vector3i dims = hi - lo;
    const std::size_t n = static_cast<std::size_t>(dims.x()) * dims.y() * dims.z();
    if (n > map_detail::kMaxChunkIndex) return nullptr;
    std::vector<Chunk*> index(n, nullptr);
    for (const auto& ch : m.chunks) {
      const Eigen::Vector3i r = ch->coord - lo;
      index[(static_cast<std::size_t>(r.z()) * dims.y() + r.y()) * dims.x() + r.x()] = ch.get();
    }
    m.index.swap(index);
    m.index_lo = lo;
    m.index_dims = dims;
  }
  auto owned = std::make_unique<Chunk>();
  owned->coord = c;
  Chunk* ch = owned.get();
  m.chunks.push_back(std::move(owned));
  const Eigen::Vector3i r = c - m.index_lo;
  m.index[(static_cast<std::size_t>(r.z()) * m.index_dims.y() + r.y()) * m.index_dims.x() + r.x()] =
      ch;
  return ch;
}

// A voxel update resolved ahead of time, so the lines it touches can be fetched first.
struct Pending {
  Chunk* chunk;
  Block* block;
  int block_index;
  int voxel;
};

// Per-frame projection constants: pixel (u, v) with depth z is the voxel-coordinate point
// Rs (xu[u] z, yv[v] z, z) + ts.
struct FrameRays {
  const float *xu, *yv;
  Eigen::Matrix3f Rs;
  Eigen::Vector3f ts;
};

// Pass 1: one hit per voxel holding a return. Consecutive pixels often fall into one voxel; the
// last key short-cuts them. Kept out of line (as is carve()) so each loop gets the registers.
__attribute__((noinline)) void fuseHits(VoxelMap::Impl& m, const DepthImage& depth,
                                        const FrameRays& fr, float z_max, FuseStats& st) {
  const int w = depth.width, h = depth.height;
  int last[3] = {std::numeric_limits<int>::min(), 0, 0};
  Chunk* chunk = nullptr;
  Eigen::Vector3i chunk_coord(std::numeric_limits<int>::min(), 0, 0);
  std::vector<Pending> pending(w);  // at most one per pixel of a row
  std::vector<int> kx(w), ky(w), kz(w);
  const Eigen::Matrix3f& R = fr.Rs;
  const Eigen::Vector3f& t = fr.ts;
  for (int v = 0; v < h; ++v) {
    int n = 0;
    const float* row = depth.data.data() + static_cast<std::size_t>(v) * w;
    const float yv = fr.yv[v];
    if (v + 1 < h)  // the next row streams in while this one is fused
      for (int u = 0; u < w; u += 16) __builtin_prefetch(row + w + u);
    // The row's voxel keys first, in a branch-free loop the compiler vectorises (no-return
    // pixels get the camera's voxel and are skipped below).
    for (int u = 0; u < w; ++u) {
      const float z0 = row[u];
      const float z = z0 > 0.0f && z0 < std::numeric_limits<float>::infinity() ? z0 : 0.0f;
      const float px = fr.xu[u] * z, py = yv * z;
      kx[u] = map_detail::fastFloor(R(0, 0) * px + R(0, 1) * py + R(0, 2) * z + t.x());
      ky[u] = map_detail::fastFloor(R(1, 0) * px + R(1, 1) * py + R(1, 2) * z + t.y());
      kz[u] = map_detail::fastFloor(R(2, 0) * px + R(2, 1) * py + R(2, 2) * z + t.z());
    }
    for (int u = 0; u < w; ++u) {
      const float z = row[u];
      // A return is finite and positive; counted here rather than in a separate pass.
      if (!(z > 0.0f) || !(z < std::numeric_limits<float>::infinity())) continue;
      ++st.valid_pixels;
      if (z > z_max) {
        ++st.beyond_fuse_depth;
        continue;
      }
      const int x = kx[u], y = ky[u], zz = kz[u];
      if (x == last[0] && y == last[1] && zz == last[2]) {
        ++st.fused_pixels;
        continue;
      }
      if (!m.inKeyRange(x, y, zz)) {
        ++st.outside_region;
        continue;
      }
      const Eigen::Vector3i cc(x >> map_detail::kChunkShift, y >> map_detail::kChunkShift,
                               zz >> map_detail::kChunkShift);
      if (cc != chunk_coord || !chunk) {
        chunk = chunkAlloc(m, cc);
        chunk_coord = cc;
        if (!chunk) {
          ++st.outside_region;
          continue;
        }
      }
      last[0] = x, last[1] = y, last[2] = zz;
      ++st.fused_pixels;
      const int bi = map_detail::blockInChunk(x, y, zz);
      auto& slot = chunk->blocks[bi];
      if (!slot) {
        slot = std::make_unique<Block>();
        chunk->born[bi] = m.frame;
        ++m.block_count;
      }
      const int i = map_detail::voxelInBlock(x, y, zz);
      // The grid is far larger than the caches: fetch the voxel's lines while the rest of the
      // row is resolved, and update them afterwards.
      __builtin_prefetch(slot.get());
      __builtin_prefetch(&slot->mask[i >> 6]);
      __builtin_prefetch(&slot->log_odds[i]);
      pending[n++] = {chunk, slot.get(), bi, i};
    }
    for (int k = 0; k < n; ++k) {
      const Pending& p = pending[k];
      if (claim(m, *p.block, p.voxel)) {
        applyUpdate(m, *p.chunk, p.block_index, *p.block, p.voxel, m.l_hit);
        ++st.hit_updates;
      }
    }
  }
}

// Pass 2: carving along every stride-th ray in u and v (offset `phase` rotating over frames),
// through blocks that hold returns: one miss per voxel passed before (return depth - margin),
// at most one update per voxel per frame, none for voxels hit in this frame (claimed in pass 1).
// Misses all change a voxel alike, so the order in which rays claim voxels does not matter: a
// row of rays is walked first (fetching the voxels' lines), then its misses are applied.
__attribute__((noinline)) void carve(VoxelMap::Impl& m, const DepthImage& depth,
                                     const DepthImage* dropped_from, const std::uint8_t* dropped,
                                     const FrameRays& fr, const Eigen::Isometry3d& T_W_C,
                                     int stride, double margin_m, double z_max, FuseStats& st) {
  const int w = depth.width, h = depth.height;
  const int phase = static_cast<int>(m.frame % static_cast<std::uint32_t>(stride * stride));
  const int ou = phase % stride, ov = phase / stride;
  const Eigen::Vector3d o = T_W_C.translation();
  const Eigen::Matrix3d R = T_W_C.linear();
  std::vector<Pending> pending(4096);
  std::size_t n = 0;
  auto collect = [&](Chunk& c, int bi, Block& b, int i) {
    __builtin_prefetch(&b);
    __builtin_prefetch(&b.mask[i >> 6]);
    __builtin_prefetch(&b.log_odds[i]);
    if (__builtin_expect(n == pending.size(), 0)) pending.resize(2 * n);
    pending[n++] = {&c, &b, bi, i};
  };
  for (int v = ov; v < h; v += stride) {
    const float* row = depth.data.data() + static_cast<std::size_t>(v) * w;
    const std::size_t r0 = static_cast<std::size_t>(v) * w;
    for (int u = ou; u < w; u += stride) {
      // A return left out of the hits (MapFuser::fuse) still carves.
      const double z = dropped && dropped[r0 + u] ? dropped_from->data[r0 + u] : row[u];
      // As in the hit pass, only a finite positive depth is a return (a ray to +inf never ends).
      if (!(z > 0.0) || !(z < std::numeric_limits<double>::infinity()) || z > z_max) continue;
      // With d_C = (x, y, 1) the ray parameter is the depth along the optical axis.
      const Eigen::Vector3d d = R * Eigen::Vector3d(fr.xu[u], fr.yv[v], 1.0);
      const double t_end = z - margin_m / d.norm();  // margin metres along the ray
      if (t_end <= 0.0) continue;
      map_detail::walkCarve(m, o, d, t_end, collect);
      ++st.carve_rays;
    }
    for (std::size_t k = 0; k < n; ++k) {
      const Pending& p = pending[k];
      if (claim(m, *p.block, p.voxel)) {
        applyUpdate(m, *p.chunk, p.block_index, *p.block, p.voxel, m.l_miss);
        ++st.miss_updates;
      }
    }
    n = 0;
  }
}

// Frames on which the noise limit tries to measure the sensor's noise before it gives up.
constexpr int kNoiseFrames = 10;

// One frame's contribution to the noise limit (MapConfig::max_fuse_noise_voxels).
struct NoiseLimit {
  bool settled = false;  // measured (or unmeasurable for good): no further frame is measured
  double depth_m = std::numeric_limits<double>::infinity();  // infinity = no limit
  DepthNoiseModel model;  // sigma(z) when measured
  std::string summary;
};

// Measures sigma(z) on one frame and the depth where it reaches the limit. Not settled when the
// frame has too few planar cells to tell (a later frame may).
NoiseLimit measureNoiseLimit(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                             const MapConfig& config, int frame_number) {
  NoiseLimit out;
  const double limit_m = config.max_fuse_noise_voxels * config.voxel_size_m;
  char lim[96];
  std::snprintf(lim, sizeof(lim), "%.3g voxels = %.1f mm", config.max_fuse_noise_voxels,
                1e3 * limit_m);
  NoiseEstimator estimator;
  try {
    estimator.addFrame(depth, intrinsics);
  } catch (const DepthInputError& e) {
    out.settled = true;
    out.summary = std::string("depth noise not measurable (") + e.what() + "): no noise limit";
    return out;
  }
  const DepthNoiseModel noise = estimator.model();
  if (!noise.known()) {
    if (frame_number >= kNoiseFrames) {
      out.settled = true;
      out.summary = "depth noise not measured on the first " + std::to_string(kNoiseFrames) +
                    " frames (too few planar cells): no noise limit";
    }
    return out;
  }
  out.settled = true;
  out.model = noise;
  char buf[320];
  if (!(config.max_fuse_noise_voxels > 0.0)) {
    out.summary = estimator.summary() + "; no noise limit (max_fuse_noise 0)";
    return out;
  }
  const double z = noise.depthAtSigma(limit_m);
  if (z == 0.0) {
    std::snprintf(buf, sizeof(buf),
                  "%s; above the limit of %s at every depth (voxels finer than this sensor's "
                  "noise): no noise limit",
                  estimator.summary().c_str(), lim);
  } else if (!std::isfinite(z)) {
    std::snprintf(buf, sizeof(buf), "%s; never above the limit of %s: no noise limit",
                  estimator.summary().c_str(), lim);
  } else {
    out.depth_m = z;
    std::snprintf(buf, sizeof(buf),
                  "%s; above the limit of %s beyond %.2f m: deeper returns are not fused",
                  estimator.summary().c_str(), lim, z);
  }
  out.summary = buf;
  return out;
}


// Least-squares moments of inverse depth w over the pixel ray (x, y), for snapToCellPlanes.
struct Plane {
  double a = 0.0, b = 0.0, c = 0.0;  // w = a + b x + c y
};
struct Moments {
  double n = 0, sx = 0, sy = 0, sw = 0, sxx = 0, sxy = 0, syy = 0, sxw = 0, syw = 0;
  void remove(const Moments& o) {
    n -= o.n, sx -= o.sx, sy -= o.sy, sw -= o.sw;
    sxx -= o.sxx, sxy -= o.sxy, syy -= o.syy, sxw -= o.sxw, syw -= o.syw;
  }
  // The plane through the means, its slopes from the centred moments (uncentred sums in double
  // keep ~1e-10 of relative precision over a cell's rays); false when the returns are on a line.
  bool solve(Plane* p) const {
    if (n < 3.0) return false;
    const double mx = sx / n, my = sy / n, mw = sw / n;
    const double cxx = sxx - n * mx * mx, cxy = sxy - n * mx * my, cyy = syy - n * my * my;
    const double cxw = sxw - n * mx * mw, cyw = syw - n * my * mw;
    const double det = cxx * cyy - cxy * cxy;
    if (!(det > 1e-6 * cxx * cyy)) return false;
    p->b = (cyy * cxw - cxy * cyw) / det;
    p->c = (cxx * cyw - cxy * cxw) / det;
    p->a = mw - p->b * mx - p->c * my;
    return std::isfinite(p->a) && std::isfinite(p->b) && std::isfinite(p->c);
  }
};

// MapConfig::snap_cell_px: `out` is `in` with the returns of each planar cell moved onto the
// cell's fitted plane. In the camera frame a plane n.p = d holds the points z (x, y, 1) with
// 1/z = (n_x x + n_y y + n_z) / d, so inverse depth w = 1/z is fitted linearly in the pixel ray
// (x, y); a return's distance from the plane in depth is z^2 (w - w_fit) to first order, judged
// against sigma(z) at the cell's mean depth. Returns only up to z_fit take part (deeper ones are
// not fused anyway; z_fit lies beyond the fuse depth z_fuse so that the cut falls on the cells'
// planes). With `dropped` (MapConfig::drop_unplaced), the returns up to z_fuse of a cell with too
// few returns to place its plane to half a voxel are zeroed in `out`, marked there and counted in
// `unplaced` (finer cells are not tried: they hold fewer still); those beyond it stay as they
// were, and the hit pass counts them as beyond the fuse depth. With q_sigmas > 0
// (MapConfig::snap_step_sigmas), where sigma exceeds a voxel, a cell is one plane only if the
// mean residual of its inliers in each of its four quarters, four column bands and four row
// bands lies within q_sigmas standard errors (sigma / sqrt(n)) of the plane: a corner or step
// under a noise of several centimetres passes the RMS test but leaves some of them off the
// plane. Returns the number snapped.
int snapToCellPlanes(const DepthImage& in, const float* xu, const float* yv, int cell,
                     double voxel_m, double q_sigmas, const DepthNoiseModel& noise, float z_fit,
                     float z_fuse, DepthImage& out, std::uint8_t* dropped, int& unplaced) {
  constexpr double kInlierSigmas = 3.0;  // a return within this of the plane is on it
  constexpr double kPlanarRms = 1.5;     // a cell is planar when its inliers' RMS is within this
  const int w = in.width, h = in.height;
  out.width = w;
  out.height = h;
  out.data = in.data;
  int snapped = 0;
  // A cell's pixels are read a row of four at a time (simd4 vectors); sums are kept per lane in
  // float, over rays centred on the cell's (x, y), and added up in double.
  using simd4::V4f;
  using simd4::V4i;
  // A return is positive and finite (as in the hit pass), and up to z_fit.
  const V4f zero = simd4::splat(0.0f), one = simd4::splat(1.0f),
            zmax4 = simd4::splat(std::min(z_fit, std::numeric_limits<float>::max()));
  struct LaneMoments {
    V4f n{}, sx{}, sy{}, sw{}, sxx{}, sxy{}, syy{}, sxw{}, syw{};
    // m: 1 for a return, 0 for none; iz: inverse depth, 0 where m is.
    void add(V4f m, V4f x, V4f y, V4f iz) {
      const V4f mx = m * x, my = m * y;
      n += m, sx += mx, sy += my, sw += iz;
      sxx += mx * x, sxy += mx * y, syy += my * y, sxw += x * iz, syw += y * iz;
    }
    Moments total() const {
      Moments t;
      for (int k = 0; k < 4; ++k) {
        t.n += n[k], t.sx += sx[k], t.sy += sy[k], t.sw += sw[k], t.sxx += sxx[k];
        t.sxy += sxy[k], t.syy += syy[k], t.sxw += sxw[k], t.syw += syw[k];
      }
      return t;
    }
  };
  // Four pixels of `row` from column u (u1: the cell's end): depth (1 where no return), 1/0 for
  // a return, inverse depth (0 where no return), centred ray x.
  auto lanes = [&](const float* row, int u, int u1, V4f xc, V4f& z, V4f& m, V4f& iz, V4f& x) {
    z = simd4::load4OrZero(row, u, u1);
    x = simd4::load4OrZero(xu, u, u1) - xc;  // (beyond u1 -xc: finite, and z = 0 there)
    const V4i ok = (z > zero) & (z <= zmax4);  // false for NaN
    m = ok ? one : zero;
    z = ok ? z : one;
    iz = m / z;
  };
  // Puts back the returns of the cell [u0, u1) x [v0, v1) as measured.
  auto restore = [&](int u0, int v0, int u1, int v1) {
    for (int v = v0; v < v1; ++v) {
      const std::size_t r = static_cast<std::size_t>(v) * w;
      std::copy(in.data.begin() + r + u0, in.data.begin() + r + u1, out.data.begin() + r + u0);
    }
  };
  // Snaps the cell [u0, u0 + size) x [v0, v0 + size) when it is planar; false when it is not.
  auto snapCell = [&](int u0, int v0, int size) {
    const int u1 = std::min(w, u0 + size), v1 = std::min(h, v0 + size);
    const int min_valid = std::max(6, size * size / 4);
    const float xc1 = 0.5f * (xu[u0] + xu[u1 - 1]), yc = 0.5f * (yv[v0] + yv[v1 - 1]);
    const V4f xc = simd4::splat(xc1);
    V4f z, m, iz, x;
    LaneMoments lm;
    V4f zsum = zero;
    for (int v = v0; v < v1; ++v) {
      const float* row = in.data.data() + static_cast<std::size_t>(v) * w;
      const V4f y = simd4::splat(yv[v] - yc);
      for (int u = u0; u < u1; u += 4) {
        lanes(row, u, u1, xc, z, m, iz, x);
        lm.add(m, x, y, iz);
        zsum += m * z;
      }
    }
    const Moments all = lm.total();
    const double n = all.n;
    if (n == 0) return false;
    const double sigma =
        noise.sigmaAt((double{zsum[0]} + zsum[1] + zsum[2] + zsum[3]) / n);
    if (dropped && sigma > 0.0 && n < 4.0 * (sigma / voxel_m) * (sigma / voxel_m)) {
      // Too few returns to place the cell's plane to half a voxel: fused as measured or at a
      // plane this uncertain they would mark voxels off the surface. Left out of the hits.
      for (int v = v0; v < v1; ++v) {
        const std::size_t r = static_cast<std::size_t>(v) * w;
        for (int u = u0; u < u1; ++u) {
          const float zr = in.data[r + u];
          if (zr > 0.0f && zr < std::numeric_limits<float>::infinity() && zr <= z_fuse) {
            out.data[r + u] = 0.0f;
            dropped[r + u] = 1;
            ++unplaced;
          }
        }
      }
      return true;
    }
    if (n < min_valid || !(sigma > 0.0)) return false;
    const V4f gate = simd4::splat(static_cast<float>(kInlierSigmas * sigma)), neg_gate = -gate;
    // Fit w = a + b x + c y, judge every return against the plane, and fit again without the
    // returns more than kInlierSigmas off it (another surface in the cell, or a stray return):
    // their moments are taken off the totals. Each judging pass writes the cell's output, which
    // is taken back when the cell is not one plane.
    Moments fit = all;
    double n_in = 0.0, ss = 0.0;
    bool written = false, planar = false;
    // The quarters' and bands' test only where the noise exceeds a voxel: under it, a step the
    // RMS test passes (up to about 2 sigma) is snapped at most a voxel off either surface.
    const bool steps = q_sigmas > 0.0 && sigma > voxel_m;
    for (int pass = 0; pass < 2; ++pass) {
      Plane pl;
      if (!fit.solve(&pl)) {
        planar = false;
        break;
      }
      const V4f a = simd4::splat(static_cast<float>(pl.a)),
                b = simd4::splat(static_cast<float>(pl.b)),
                c = simd4::splat(static_cast<float>(pl.c));
      LaneMoments off;
      V4f in_n = zero, in_ss = zero;
      // For the step test: inliers and their residual sums per column (lane k of chunk
      // (u - u0) / 4) of the cell's upper and lower half, and per row. The quarters, column bands
      // and row bands are sums of these. Only the cell's own entries are cleared (a 4 px cell, an
      // L515's usual, uses one chunk and four rows); rows beyond the frame's edge stay empty.
      V4f col_n[2][8], col_e[2][8];
      double row_n[32], row_e[32];
      if (steps) {
        for (int i = 0; i < (size + 3) / 4; ++i)
          col_n[0][i] = col_n[1][i] = col_e[0][i] = col_e[1][i] = zero;
        for (int i = 0; i < size; ++i) row_n[i] = 0.0, row_e[i] = 0.0;
      }
      const int vc = v0 + size / 2;
      for (int v = v0; v < v1; ++v) {
        const float* row = in.data.data() + static_cast<std::size_t>(v) * w;
        const V4f y = simd4::splat(yv[v] - yc);
        float* dst = out.data.data() + static_cast<std::size_t>(v) * w;
        const int half = v < vc ? 0 : 1;
        V4f rn = zero, re = zero;
        for (int u = u0; u < u1; u += 4) {
          lanes(row, u, u1, xc, z, m, iz, x);
          const V4f f = a + b * x + c * y;
          const V4f e = (iz - f) * z * z;
          const V4i ok = (m > zero) & (e <= gate) & (e >= neg_gate) & (f > zero);
          const V4f on = ok ? one : zero, off_m = m - on;
          in_n += on;
          in_ss += on * e * e;
          if (steps) {  // loop-invariant: the compiler keeps two loops
            const V4f oe = on * e;
            col_n[half][(u - u0) >> 2] += on, col_e[half][(u - u0) >> 2] += oe;
            rn += on, re += oe;
          }
          off.add(off_m, x, y, off_m * iz);
          // 1 / f only where f > 0 (ok); the other lanes keep the frame's value.
          const V4f snapped_z = ok ? one / (ok ? f : one) : simd4::load4OrZero(row, u, u1);
          simd4::store4(dst, u, u1, snapped_z);
        }
        if (steps) {
          row_n[v - v0] = double{rn[0]} + rn[1] + rn[2] + rn[3];
          row_e[v - v0] = double{re[0]} + re[1] + re[2] + re[3];
        }
      }
      written = true;
      n_in = double{in_n[0]} + in_n[1] + in_n[2] + in_n[3];
      ss = double{in_ss[0]} + in_ss[1] + in_ss[2] + in_ss[3];
      planar = n_in >= min_valid && 2.0 * n_in >= n;
      // The step test: the inliers of each quarter, each column band and each row band on
      // average on the plane. A corner leaves quarters off it; a straight step through the cell,
      // which the plane's tilt takes up so that the quarters' means stay near it, leaves the
      // bands beside the step off it.
      if (planar && steps) {
        const auto offPlane = [&](double bn, double be) {
          return bn >= 2.0 && std::abs(be / bn) > q_sigmas * sigma / std::sqrt(bn);
        };
        // Sums over columns [i0, i1) of the halves h0..h1.
        const auto columns = [&](int i0, int i1, int h0, int h1, double& cn, double& ce) {
          cn = ce = 0.0;
          for (int hh = h0; hh <= h1; ++hh)
            for (int i = i0; i < i1; ++i)
              cn += col_n[hh][i >> 2][i & 3], ce += col_e[hh][i >> 2][i & 3];
        };
        double cn, ce;
        for (int q = 0; q < 4 && planar; ++q) {  // quarters
          const int hh = q >> 1, i0 = (q & 1) * (size / 2);
          columns(i0, i0 + size / 2, hh, hh, cn, ce);
          planar = !offPlane(cn, ce);
        }
        const int bw = std::max(1, size / 4);
        for (int band = 0; band < 4 && planar; ++band) {  // column and row bands
          columns(band * bw, (band + 1) * bw, 0, 1, cn, ce);
          double rn = 0.0, re = 0.0;
          for (int i = band * bw; i < (band + 1) * bw; ++i) rn += row_n[i], re += row_e[i];
          planar = !offPlane(cn, ce) && !offPlane(rn, re);
        }
      }
      if (!planar || n_in == n) break;  // none left out: a second fit would be the same
      fit = all;
      fit.remove(off.total());
    }
    if (!planar || ss > kPlanarRms * kPlanarRms * sigma * sigma * n_in) {
      if (written) restore(u0, v0, u1, v1);
      return false;
    }
    snapped += static_cast<int>(n_in);
    return true;
  };
  // Cell sizes: a cell is fitted at the smallest size whose plane is known to half a voxel (the
  // plane's offset error sigma / sqrt(n) <= voxel / 2 needs n >= 4 (sigma / voxel)^2 returns), so
  // that quiet or near returns are fitted on small cells, which follow curved surfaces and reach
  // edges, and noisy far ones on large cells, which average their noise. A cell that is not one
  // plane (an edge, a crease, a small object) is tried again as four quarters, down to kMinCell
  // pixels. Returns and their depth sums per kMinCell block first, so that a cell's count and
  // mean depth come without reading its pixels.
  constexpr int kMinCell = 4;
  const int bw = (w + kMinCell - 1) / kMinCell, bh = (h + kMinCell - 1) / kMinCell;
  static_assert(kMinCell == 4, "a block row is one simd4 vector");
  std::vector<float> bn(static_cast<std::size_t>(bw) * bh, 0.0f), bz(bn.size(), 0.0f);
  std::vector<V4f> lane_n(bw), lane_z(bw);  // one block row's per-lane sums
  for (int by = 0; by < bh; ++by) {
    std::fill(lane_n.begin(), lane_n.end(), zero);
    std::fill(lane_z.begin(), lane_z.end(), zero);
    for (int v = by * kMinCell; v < std::min(h, (by + 1) * kMinCell); ++v) {
      const float* row = in.data.data() + static_cast<std::size_t>(v) * w;
      for (int bx = 0; bx < bw; ++bx) {
        const V4f z = simd4::load4OrZero(row, bx * kMinCell, w);
        const V4i ok = (z > zero) & (z <= zmax4);
        lane_n[bx] += ok ? one : zero;
        lane_z[bx] += ok ? z : zero;
      }
    }
    for (int bx = 0; bx < bw; ++bx) {
      const V4f& ln = lane_n[bx];
      const V4f& lz = lane_z[bx];
      bn[static_cast<std::size_t>(by) * bw + bx] = ln[0] + ln[1] + ln[2] + ln[3];
      bz[static_cast<std::size_t>(by) * bw + bx] = lz[0] + lz[1] + lz[2] + lz[3];
    }
  }
  const double inv_voxel = 1.0 / voxel_m;
  auto snapTree = [&](auto& self, int u0, int v0, int size) -> void {
    if (u0 >= w || v0 >= h) return;
    const int half = size / 2;
    if (half >= kMinCell) {
      double n = 0.0, zsum = 0.0;
      for (int by = v0 / kMinCell; by < std::min(bh, (v0 + size) / kMinCell); ++by)
        for (int bx = u0 / kMinCell; bx < std::min(bw, (u0 + size) / kMinCell); ++bx) {
          n += bn[static_cast<std::size_t>(by) * bw + bx];
          zsum += bz[static_cast<std::size_t>(by) * bw + bx];
        }
      if (n == 0) return;
      const double r = noise.sigmaAt(zsum / n) * inv_voxel;
      const bool quarters_suffice = n >= 16.0 * r * r;  // n / 4 >= 4 (sigma / voxel)^2
      if (quarters_suffice || !snapCell(u0, v0, size))
        for (int q = 0; q < 4; ++q) self(self, u0 + (q & 1) * half, v0 + (q >> 1) * half, half);
      return;
    }
    snapCell(u0, v0, size);
  };
  for (int v0 = 0; v0 < h; v0 += cell)
    for (int u0 = 0; u0 < w; u0 += cell) snapTree(snapTree, u0, v0, cell);
  return snapped;
}

// MapConfig::edge_margin_px: zeroes in `out` (a copy of `in`) the returns on the near side of a
// depth edge: those with a return within `margin` pixels (chessboard) that lies deeper by more
// than jump z (and, once the noise is known, by more than kEdgeSigmas sigma(z), so that noise
// alone never reads as an edge). Stereo edge fattening and the spot's lateral spread put such
// returns off the foreground's true outline, in free space beside it; the far side's returns are
// kept (a return taken from the background lies on it). `mask` (w x h) gets 1 where a return was
// dropped and 0 everywhere else. Only returns up to z_fit are judged (the snap's depth). Returns
// the number dropped up to the fuse depth z_fuse; those dropped beyond it are counted in `beyond`.
// The window's maximum is separable: rows first, then columns.
int dropNearSideOfEdges(const DepthImage& in, int margin, double jump, const DepthNoiseModel& noise,
                        float z_fit, float z_fuse, std::vector<float>& row_max, DepthImage& out,
                        std::uint8_t* mask, int& beyond) {
  constexpr double kEdgeSigmas = 6.0;
  const int w = in.width, h = in.height;
  out.width = w;
  out.height = h;
  out.data.resize(in.data.size());  // every pixel is written below
  row_max.resize(static_cast<std::size_t>(w) * h);
  std::vector<float> padded(static_cast<std::size_t>(w + 2 * margin), 0.0f);
  // Rows: the deepest return within +-margin columns (no return = 0; NaN and inf are none).
  for (int v = 0; v < h; ++v) {
    const float* row = in.data.data() + static_cast<std::size_t>(v) * w;
    for (int u = 0; u < w; ++u) {
      const float z = row[u];
      padded[u + margin] = z > 0.0f && z < std::numeric_limits<float>::infinity() ? z : 0.0f;
    }
    float* dst = row_max.data() + static_cast<std::size_t>(v) * w;
    std::copy(padded.begin(), padded.begin() + w, dst);
    for (int k = 1; k <= 2 * margin; ++k) {
      const float* src = padded.data() + k;
      for (int u = 0; u < w; ++u) dst[u] = std::max(dst[u], src[u]);
    }
  }
  // Columns: the deepest of the rows' maxima within +-margin rows, then the test.
  std::vector<float> win(w);
  const float jump_f = static_cast<float>(jump);
  const bool with_noise = noise.known();
  const float q0 = static_cast<float>(kEdgeSigmas * noise.const_m),
              q1 = static_cast<float>(kEdgeSigmas * noise.linear),
              q2 = static_cast<float>(kEdgeSigmas * noise.quad_per_m);
  int dropped = 0;
  for (int v = 0; v < h; ++v) {
    const int v0 = std::max(0, v - margin), v1 = std::min(h - 1, v + margin);
    std::copy(row_max.begin() + static_cast<std::size_t>(v0) * w,
              row_max.begin() + static_cast<std::size_t>(v0 + 1) * w, win.begin());
    for (int vv = v0 + 1; vv <= v1; ++vv) {
      const float* src = row_max.data() + static_cast<std::size_t>(vv) * w;
      for (int u = 0; u < w; ++u) win[u] = std::max(win[u], src[u]);
    }
    const float* row = in.data.data() + static_cast<std::size_t>(v) * w;
    float* dst = out.data.data() + static_cast<std::size_t>(v) * w;
    std::uint8_t* mrow = mask + static_cast<std::size_t>(v) * w;
    // Four pixels at a time. A return is positive and finite; one deeper than the fuse depth
    // is not fused anyway (both comparisons are false for NaN).
    using simd4::V4f;
    using simd4::V4i;
    const V4f zero = simd4::splat(0.0f), jump4 = simd4::splat(jump_f),
              zlim = simd4::splat(std::min(z_fit, std::numeric_limits<float>::max())),
              zfuse = simd4::splat(std::min(z_fuse, std::numeric_limits<float>::max())),
              c0 = simd4::splat(with_noise ? q0 : 0.0f), c1 = simd4::splat(with_noise ? q1 : 0.0f),
              c2 = simd4::splat(with_noise ? q2 : 0.0f);
    V4i count = {0, 0, 0, 0}, count_beyond = {0, 0, 0, 0};
    for (int u = 0; u < w; u += 4) {
      const V4f z = simd4::load4OrZero(row, u, w), m = simd4::load4OrZero(win.data(), u, w);
      const V4f by_noise = c0 + z * (c1 + z * c2), by_jump = jump4 * z;
      const V4f thr = by_noise > by_jump ? by_noise : by_jump;
      const V4i drop = (z > zero) & (z <= zlim) & (m - z > thr);
      simd4::store4(dst, u, w, drop ? zero : z);
      const V4i within = drop & (z <= zfuse);
      count -= within;  // -1 per dropped lane
      count_beyond -= drop ^ within;
      for (int k = 0; k < 4 && u + k < w; ++k) mrow[u + k] = drop[k] ? 1 : 0;
    }
    dropped += count[0] + count[1] + count[2] + count[3];
    beyond += count_beyond[0] + count_beyond[1] + count_beyond[2] + count_beyond[3];
  }
  return dropped;
}

}  // namespace

MapFuser::MapFuser(VoxelMap& map, const PinholeIntrinsics& intrinsics)
    : map_(map), intrinsics_(intrinsics) {
  const auto kp = intrinsics.validate();
  if (!kp.empty()) throw std::invalid_argument("fuse: camera intrinsics: " + joinProblems(kp));
  ray_x_.resize(intrinsics.width);
  ray_y_.resize(intrinsics.height);
  for (int u = 0; u < intrinsics.width; ++u)
    ray_x_[u] = static_cast<float>((u - intrinsics.cx) / intrinsics.fx);
  for (int v = 0; v < intrinsics.height; ++v)
    ray_y_[v] = static_cast<float>((v - intrinsics.cy) / intrinsics.fy);
}

FuseStats MapFuser::fuse(const DepthImage& depth, const Eigen::Isometry3d& T_W_C) {
  const auto t_call = std::chrono::steady_clock::now();
  // Every check comes before the first write, so a throw leaves the map as it was.
  if (depth.empty()) throw DepthInputError("fuse: depth frame is empty (0x0 pixels)");
  checkFrameSize(depth, intrinsics_);
  map_detail::checkPose(T_W_C, "fuse");
  FuseStats st;

  VoxelMap::Impl& m = *map_.impl_;
  const MapConfig& config = map_.config();
  // The noise limit is measured on the map's first frames, before the write lock (the
  // measurement reads only the frame, and readers need not wait for it).
  std::optional<NoiseLimit> noise;
  if (config.max_fuse_noise_voxels > 0.0 || config.snap_cell_px > 0) {
    int frames = 0;
    {
      const map_detail::ReadLock lock(m.mutex);
      frames = m.noise_settled ? -1 : m.noise_frames;
    }
    if (frames >= 0) {
      const auto t_noise = std::chrono::steady_clock::now();
      noise = measureNoiseLimit(depth, intrinsics_, config, frames + 1);
      st.ms_noise = msSince(t_noise);
    }
  }
  const map_detail::WriteLock lock(m.mutex);
  const auto t_start = std::chrono::steady_clock::now();
  st.ms_lock_wait =
      std::chrono::duration<double, std::milli>(t_start - t_call).count() - st.ms_noise;
  const std::uint32_t frame_before = m.frame;
  ++m.frame;
  if (m.frame == 0) ++m.frame;  // 0 marks "never touched"
  FrameRays fr;
  fr.xu = ray_x_.data();
  fr.yv = ray_y_.data();
  // Voxel coordinates directly: q = (R p_C + t) / s.
  fr.Rs = (T_W_C.linear() * m.inv_s).cast<float>();
  fr.ts = (T_W_C.translation() * m.inv_s).cast<float>();

  // Another fuser of this map may have settled the limit since the read above.
  const bool settles = noise && noise->settled && !m.noise_settled;
  const double noise_depth = settles ? noise->depth_m : m.noise_depth_m;
  const double z_max = std::min(config.max_fuse_depth_m > 0.0
                                    ? config.max_fuse_depth_m
                                    : std::numeric_limits<double>::infinity(),
                                noise_depth);
  st.fuse_depth_limit_m = std::isfinite(z_max) ? z_max : 0.0;
  const DepthNoiseModel& noise_model = settles ? noise->model : m.noise_model;
  // The limit cuts the snapped depth, not the return: a cell near it is fitted with the returns
  // up to kCutTailSigmas sigma beyond it, and its returns are fused where the cell's plane lies
  // within it. Cut return by return, only the returns that noise pulled nearer would be fused
  // at the limit's depth, a surface drawn towards the camera by about sigma there and never
  // carved (the rays beyond the limit do not carve).
  constexpr double kCutTailSigmas = 3.0;
  // Returns left out of the hits (the near side of a depth edge, cells whose plane cannot be
  // placed) are zeroed in the fused image and marked in dropped_; their rays still carve.
  const bool edges = config.edge_margin_px > 0;
  const bool snap = config.snap_cell_px > 0 && noise_model.known();
  const double z_fit =
      snap && std::isfinite(z_max) ? z_max + kCutTailSigmas * noise_model.sigmaAt(z_max) : z_max;
  const bool unplaced = snap && config.drop_unplaced;
  const bool drops = edges || unplaced;
  // The edge pass writes every entry of the mask; without it the snap only marks its drops.
  if (edges)
    dropped_.resize(depth.data.size());
  else if (drops)
    dropped_.assign(depth.data.size(), 0);
  int edge_beyond = 0;  // near-side returns beyond the fuse depth: counted as beyond it
  if (edges)
    st.edge_dropped = dropNearSideOfEdges(depth, config.edge_margin_px, config.edge_jump,
                                          noise_model, static_cast<float>(z_fit),
                                          static_cast<float>(z_max), edge_scratch_, edged_,
                                          dropped_.data(), edge_beyond);
  const DepthImage& kept = edges ? edged_ : depth;
  if (snap)
    st.snapped_pixels = snapToCellPlanes(
        kept, ray_x_.data(), ray_y_.data(), config.snap_cell_px, config.voxel_size_m,
        config.snap_step_sigmas, noise_model, static_cast<float>(z_fit),
        static_cast<float>(z_max), snapped_, unplaced ? dropped_.data() : nullptr,
        st.unplaced_dropped);
  const DepthImage& fused = snap ? snapped_ : kept;
  fuseHits(m, fused, fr, static_cast<float>(z_max), st);
  // Still returns of the frame.
  st.valid_pixels += st.edge_dropped + st.unplaced_dropped + edge_beyond;
  st.beyond_fuse_depth += edge_beyond;
  if (st.valid_pixels == 0) {
    // Nothing was written (voxels and chunks are only touched for returns): undo the frame count.
    m.frame = frame_before;
    throw DepthInputError("fuse: depth frame has no valid return");
  }
  if (noise && !m.noise_settled) {
    ++m.noise_frames;
    if (settles) {
      m.noise_settled = true;
      m.noise_depth_m = noise->depth_m;
      m.noise_model = noise->model;
    }
    if (!noise->summary.empty()) m.noise_summary = noise->summary;
  }
  if (config.model == UpdateModel::kProbabilistic)
    carve(m, fused, drops ? &depth : nullptr, drops ? dropped_.data() : nullptr, fr, T_W_C,
          config.carve_stride_px, config.carve_margin_m, z_max, st);
  ++map_.frames_fused_;
  st.ms = msSince(t_start);
  timing_.add(st.ms);
  return st;
}

}  // namespace depth_track
