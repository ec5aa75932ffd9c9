// Depth from the voxel map (thesis §3.14): one ray per pixel; the first run of occupied voxels
// along it gives the depth.
#if (defined(__SSE2__) || defined(_M_X64)) && !defined(DT_RAYCAST_NO_SIMD)
#define DT_RAYCAST_SSE2 1
#include <emmintrin.h>
#endif

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <type_traits>

#include "depth_track/core/map/map_raycaster.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/worker_pool.hpp"
#include "voxel_map_impl.hpp"

namespace depth_track {

using map_detail::Block;
using map_detail::Chunk;

namespace {

constexpr int kTile = 8;               // pixels per tile edge, ray order
constexpr double kRunCapVoxels = 6.0;  // longest occupied run averaged along a ray, voxels

void checkRaycastInput(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                       const DepthRange& range) {
  auto problems = K.validate();
  for (const auto& p : range.validate()) problems.push_back(p);
  if (!T_W_C.matrix().allFinite())
    problems.push_back("pose T_W_C is not finite");
  else if ((T_W_C.linear().transpose() * T_W_C.linear() - Eigen::Matrix3d::Identity()).norm() >
           1e-3)
    problems.push_back("pose T_W_C has no valid rotation");
  if (!problems.empty()) throw std::invalid_argument("raycast: " + joinProblems(problems));
}

// Surface depth along a pixel ray (the ray parameter is depth: d_C = (x, y, 1)). Noise makes a
// surface a shell a few voxels thick, and the first occupied voxel is its near face, biased
// towards the camera by about the noise; the depth returned is the evidence-weighted centre of
// the first run of consecutive occupied voxels, the run capped at `cap` (depth units) so that a
// ray grazing a floor does not slide along it.
struct HitDepth {
  double cap = 0.0;    // longest run averaged, depth units
  float l_occ = 0.0f;  // occupancy threshold, log-odds
  bool found = false;
  double t_first = 0.0, t_last = 0.0, sum_w = 0.0, sum_wt = 0.0;
  bool operator()(const Chunk& c, int bi, int i, double t_in, double t_out) {
    const bool occ = c.occupiedAt(bi, i);
    if (!found) {
      if (!occ) return false;
      found = true;
      t_first = t_last = t_in;
    } else if (!occ || t_in > t_last + 1e-6) {
      return true;  // the run ended (or a skipped gap)
    }
    // Weight by evidence above the threshold and by the chord length inside the run: voxels hit
    // most often lie nearest the surface.
    const double end = std::min(t_out, t_first + cap);
    const double w = (c.blocks[bi]->log_odds[i] - l_occ) * (end - t_in) + 1e-12;
    sum_w += w;
    sum_wt += w * 0.5 * (t_in + end);
    t_last = end;
    return t_last - t_first >= cap;
  }
  float depth() const { return static_cast<float>(sum_wt / sum_w); }
};

// Camera-frame projection of world boxes, for the per-pixel depth bounds.
struct Projector {
  const PinholeIntrinsics& K;
  Eigen::Matrix3d R_C_W;
  Eigen::Vector3d t_C_W;
  double zmin, zmax;
};

// Depth bounds of the axis-aligned world box [lo_W, lo_W + ext_W] in the camera frame, and the
// pixel rectangle that can see it. Returns false when the box cannot be seen in [zmin, zmax].
struct BoxView {
  double z_lo, z_hi;
  int u0, u1, v0, v1;  // inclusive pixel range
};
bool viewBox(const Projector& P, const Eigen::Vector3d& lo_W, const Eigen::Vector3d& ext_W,
             BoxView* out) {
  const PinholeIntrinsics& K = P.K;
  const Eigen::Vector3d base = P.R_C_W * lo_W + P.t_C_W;
  const Eigen::Vector3d ex = P.R_C_W.col(0) * ext_W.x(), ey = P.R_C_W.col(1) * ext_W.y(),
                        ez = P.R_C_W.col(2) * ext_W.z();
  double z_lo = std::numeric_limits<double>::infinity(), z_hi = -z_lo;
  double u_lo = z_lo, u_hi = z_hi, v_lo = z_lo, v_hi = z_hi;
  bool all_front = true;
  for (int c = 0; c < 8; ++c) {
    Eigen::Vector3d p = base;
    if (c & 1) p += ex;
    if (c & 2) p += ey;
    if (c & 4) p += ez;
    z_lo = std::min(z_lo, p.z());
    z_hi = std::max(z_hi, p.z());
    if (p.z() <= 1e-6) {
      all_front = false;
      continue;
    }
    const double iz = 1.0 / p.z();
    const double u = K.fx * p.x() * iz + K.cx, v = K.fy * p.y() * iz + K.cy;
    u_lo = std::min(u_lo, u), u_hi = std::max(u_hi, u);
    v_lo = std::min(v_lo, v), v_hi = std::max(v_hi, v);
  }
  if (z_hi < P.zmin || z_lo > P.zmax) return false;
  out->z_lo = z_lo;
  out->z_hi = z_hi;
  if (!all_front) {  // straddles the camera plane: any pixel may see it
    out->u0 = 0, out->u1 = K.width - 1, out->v0 = 0, out->v1 = K.height - 1;
    return true;
  }
  // A pixel ray meets the box only if the pixel centre lies in the hull of the projected corners;
  // a thousandth of a pixel of margin absorbs rounding.
  constexpr double kPx = 1e-3;
  if (u_hi < -kPx || v_hi < -kPx || u_lo > K.width - 1 + kPx || v_lo > K.height - 1 + kPx)
    return false;
  out->u0 = std::max(0, static_cast<int>(std::ceil(u_lo - kPx)));
  out->u1 = std::min(K.width - 1, static_cast<int>(std::floor(u_hi + kPx)));
  out->v0 = std::max(0, static_cast<int>(std::ceil(v_lo - kPx)));
  out->v1 = std::min(K.height - 1, static_cast<int>(std::floor(v_hi + kPx)));
  return out->u0 <= out->u1 && out->v0 <= out->v1;
}

// Per-pixel near depth bound: no occupied voxel on a pixel's ray lies nearer than near[p]
// (+inf: none on the ray at all).
struct PixelBounds {
  static constexpr float kMargin = 1e-4f;  // depth, m: covers float rounding (~1e-6 m)
  // Four pixels of a row side by side, all a splat reads and writes of them in one cache line.
  struct alignas(64) Group {
    float inv[3][4];  // 1 / world components of the pixel rays d_W = R_W_C (x, y, 1)
    float near[4];
  };
  int gw = 0;  // groups per row: the image width rounded up to a multiple of 4, over 4
  std::vector<Group> g;
  Eigen::Vector3d o_W;  // camera centre
  float near(int u, int v) const {
    return g[static_cast<std::size_t>(v) * gw + (u >> 2)].near[u & 3];
  }
  // Lowers near, over the pixels of rectangle `b`, to the depth at which each pixel ray enters
  // the world box [lo_W, hi_W] where it meets the box (slab test, in float with a margin).
  void add(const BoxView& b, const Eigen::Vector3d& lo_W, const Eigen::Vector3d& hi_W) {
    const float l0 = static_cast<float>(lo_W.x() - o_W.x()),
                h0 = static_cast<float>(hi_W.x() - o_W.x());
    const float l1 = static_cast<float>(lo_W.y() - o_W.y()),
                h1 = static_cast<float>(hi_W.y() - o_W.y());
    const float l2 = static_cast<float>(lo_W.z() - o_W.z()),
                h2 = static_cast<float>(hi_W.z() - o_W.z());
#ifdef DT_RAYCAST_SSE2
    const __m128 lo0 = _mm_set1_ps(l0), hi0 = _mm_set1_ps(h0), lo1 = _mm_set1_ps(l1),
                 hi1 = _mm_set1_ps(h1), lo2 = _mm_set1_ps(l2), hi2 = _mm_set1_ps(h2);
    const __m128 margin = _mm_set1_ps(kMargin), margin2 = _mm_set1_ps(2.0f * kMargin);
#endif
    for (int v = b.v0; v <= b.v1; ++v) {
      Group* row = g.data() + static_cast<std::size_t>(v) * gw;
      // Four pixels at a time (SSE2, part of x86-64), a group at a time: the test is exact for
      // any pixel, so the pixels of a group outside the rectangle lose nothing.
      for (Group* q = row + (b.u0 >> 2); q <= row + (b.u1 >> 2); ++q) {
#ifdef DT_RAYCAST_SSE2
        const __m128 i0 = _mm_load_ps(q->inv[0]), i1 = _mm_load_ps(q->inv[1]),
                     i2 = _mm_load_ps(q->inv[2]);
        const __m128 nr4 = _mm_load_ps(q->near);
        const __m128 a0 = _mm_mul_ps(lo0, i0), c0 = _mm_mul_ps(hi0, i0);
        const __m128 a1 = _mm_mul_ps(lo1, i1), c1 = _mm_mul_ps(hi1, i1);
        const __m128 a2 = _mm_mul_ps(lo2, i2), c2 = _mm_mul_ps(hi2, i2);
        const __m128 t_in =
            _mm_max_ps(_mm_max_ps(_mm_min_ps(a0, c0), _mm_min_ps(a1, c1)), _mm_min_ps(a2, c2));
        const __m128 t_out =
            _mm_min_ps(_mm_min_ps(_mm_max_ps(a0, c0), _mm_max_ps(a1, c1)), _mm_max_ps(a2, c2));
        const __m128 meets = _mm_cmple_ps(t_in, _mm_add_ps(t_out, margin2));
        const __m128 nv = _mm_min_ps(nr4, _mm_sub_ps(t_in, margin));
        _mm_store_ps(q->near, _mm_or_ps(_mm_and_ps(meets, nv), _mm_andnot_ps(meets, nr4)));
#else
        for (int k = 0; k < 4; ++k) {
          const float i0 = q->inv[0][k], i1 = q->inv[1][k], i2 = q->inv[2][k];
          const float a0 = l0 * i0, c0 = h0 * i0, a1 = l1 * i1, c1 = h1 * i1, a2 = l2 * i2,
                      c2 = h2 * i2;
          const float t_in =
              std::max(std::max(std::min(a0, c0), std::min(a1, c1)), std::min(a2, c2));
          const float t_out =
              std::min(std::min(std::max(a0, c0), std::max(a1, c1)), std::max(a2, c2));
          if (t_in <= t_out + 2.0f * kMargin) q->near[k] = std::min(q->near[k], t_in - kMargin);
        }
#endif
      }
    }
  }
};

// The camera in float, for OctantQueue.
struct OctantProjector {
  static constexpr float kPx = 1e-3f;  // as viewBox
  float fx, fy, cx, cy, zmin, zmax;
  int width, height;
  float step[3][3];  // step[a]: camera-frame offset of one voxel along world axis a
};

#ifdef DT_RAYCAST_SSE2
// viewBox for the small boxes of block octants, in float, four boxes at a time (one per lane):
// boxes are queued and their rectangles found and splatted when four are in. The corners are
// offset from the block's camera-frame corner (from double) by a few voxel steps, so they are
// off by ~1e-7 m: ~1e-4 px, within the 1e-3 px margin (a pixel it drops is missed by the box),
// and the z range test keeps 1e-4 m of margin (a box kept in vain changes nothing).
struct OctantQueue {
  int count = 0;
  alignas(16) float base[3][4];  // camera-frame lower corner, per component
  alignas(16) float n[3][4];     // extent in voxels along world x, y, z
  double lo_W[4][3], ext_W[4][3];

  void push(const OctantProjector& P, const float base_C[3], const int n_vox[3], const double lo[3],
            const double ext[3], PixelBounds* bounds) {
    for (int k = 0; k < 3; ++k) {
      base[k][count] = base_C[k];
      n[k][count] = static_cast<float>(n_vox[k]);
      lo_W[count][k] = lo[k];
      ext_W[count][k] = ext[k];
    }
    if (++count == 4) flush(P, bounds);
  }

  void flush(const OctantProjector& P, PixelBounds* bounds) {
    if (count == 0) return;
    for (int j = count; j < 4; ++j)  // idle lanes: copies of the first box, results unused
      for (int k = 0; k < 3; ++k) base[k][j] = base[k][0], n[k][j] = n[k][0];
    // Corners (x, y) = (0, 0), (nx, 0), (0, ny), (nx, ny) at z offsets 0 and nz.
    __m128 corner[8][3];
    for (int k = 0; k < 3; ++k) {
      const __m128 b = _mm_load_ps(base[k]);
      const __m128 ex = _mm_mul_ps(_mm_load_ps(n[0]), _mm_set1_ps(P.step[0][k]));
      const __m128 ey = _mm_mul_ps(_mm_load_ps(n[1]), _mm_set1_ps(P.step[1][k]));
      const __m128 ez = _mm_mul_ps(_mm_load_ps(n[2]), _mm_set1_ps(P.step[2][k]));
      corner[0][k] = b;
      corner[1][k] = _mm_add_ps(b, ex);
      corner[2][k] = _mm_add_ps(b, ey);
      corner[3][k] = _mm_add_ps(b, _mm_add_ps(ex, ey));
      for (int c = 0; c < 4; ++c) corner[4 + c][k] = _mm_add_ps(corner[c][k], ez);
    }
    const __m128 one = _mm_set1_ps(1.0f);
    __m128 z_lo = corner[0][2], z_hi = z_lo;
    __m128 iz = _mm_div_ps(one, corner[0][2]);
    __m128 x_lo = _mm_mul_ps(corner[0][0], iz), x_hi = x_lo;
    __m128 y_lo = _mm_mul_ps(corner[0][1], iz), y_hi = y_lo;
    for (int c = 1; c < 8; ++c) {
      z_lo = _mm_min_ps(z_lo, corner[c][2]), z_hi = _mm_max_ps(z_hi, corner[c][2]);
      iz = _mm_div_ps(one, corner[c][2]);
      const __m128 x = _mm_mul_ps(corner[c][0], iz), y = _mm_mul_ps(corner[c][1], iz);
      x_lo = _mm_min_ps(x_lo, x), x_hi = _mm_max_ps(x_hi, x);
      y_lo = _mm_min_ps(y_lo, y), y_hi = _mm_max_ps(y_hi, y);
    }
    // Out of the depth range; straddling the camera plane (any pixel may see it).
    const int out_z = _mm_movemask_ps(_mm_or_ps(_mm_cmplt_ps(z_hi, _mm_set1_ps(P.zmin - 1e-4f)),
                                                _mm_cmpgt_ps(z_lo, _mm_set1_ps(P.zmax + 1e-4f))));
    const int straddle = _mm_movemask_ps(_mm_cmple_ps(z_lo, _mm_set1_ps(1e-6f)));
    const float kPx = OctantProjector::kPx;
    const __m128 u_lo = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(P.fx), x_lo), _mm_set1_ps(P.cx));
    const __m128 u_hi = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(P.fx), x_hi), _mm_set1_ps(P.cx));
    const __m128 v_lo = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(P.fy), y_lo), _mm_set1_ps(P.cy));
    const __m128 v_hi = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(P.fy), y_hi), _mm_set1_ps(P.cy));
    const __m128 neg_px = _mm_set1_ps(-kPx);
    const int off_image =
        _mm_movemask_ps(_mm_or_ps(_mm_or_ps(_mm_cmplt_ps(u_hi, neg_px), _mm_cmplt_ps(v_hi, neg_px)),
                                  _mm_or_ps(_mm_cmpgt_ps(u_lo, _mm_set1_ps(P.width - 1 + kPx)),
                                            _mm_cmpgt_ps(v_lo, _mm_set1_ps(P.height - 1 + kPx)))));
    // max(0, ceil(lo - kPx)) and min(last, floor(hi + kPx)), the clamps taken first (ceil and
    // floor are monotonic): the values are then non-negative, where floor is truncation.
    auto ceil0 = [&](__m128 lo) {
      const __m128 x = _mm_max_ps(_mm_sub_ps(lo, _mm_set1_ps(kPx)), _mm_setzero_ps());
      const __m128i t = _mm_cvttps_epi32(x);
      return _mm_sub_epi32(t, _mm_castps_si128(_mm_cmplt_ps(_mm_cvtepi32_ps(t), x)));
    };
    auto floorLast = [&](__m128 hi, int last) {
      return _mm_cvttps_epi32(
          _mm_min_ps(_mm_max_ps(_mm_add_ps(hi, _mm_set1_ps(kPx)), _mm_setzero_ps()),
                     _mm_set1_ps(static_cast<float>(last))));
    };
    alignas(16) int u0[4], u1[4], v0[4], v1[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(u0), ceil0(u_lo));
    _mm_store_si128(reinterpret_cast<__m128i*>(v0), ceil0(v_lo));
    _mm_store_si128(reinterpret_cast<__m128i*>(u1), floorLast(u_hi, P.width - 1));
    _mm_store_si128(reinterpret_cast<__m128i*>(v1), floorLast(v_hi, P.height - 1));
    for (int j = 0; j < count; ++j) {
      if ((out_z >> j) & 1) continue;
      BoxView bv;
      if ((straddle >> j) & 1) {
        bv.u0 = 0, bv.u1 = P.width - 1, bv.v0 = 0, bv.v1 = P.height - 1;
      } else {
        if ((off_image >> j) & 1) continue;
        bv.u0 = u0[j], bv.u1 = u1[j], bv.v0 = v0[j], bv.v1 = v1[j];
        if (bv.u0 > bv.u1 || bv.v0 > bv.v1) continue;
      }
      const Eigen::Vector3d lo(lo_W[j][0], lo_W[j][1], lo_W[j][2]);
      const Eigen::Vector3d ext(ext_W[j][0], ext_W[j][1], ext_W[j][2]);
      bounds->add(bv, lo, lo + ext);
    }
    count = 0;
  }
};
#endif

#ifdef DT_RAYCAST_SSE2
using Boxes = OctantQueue;
#else
struct Boxes {};  // the plain build splats each box at once (viewBox)
#endif

// Splats the occupied voxels of block `bi` of chunk `c` into the bounds, as the tight boxes of its
// occupied voxels in each of its eight 4x4x4-voxel octants (with SSE2 through `queue`, which the
// caller flushes at the end). The block's lower corner: block_lo_W in the world, block_lo_C in the
// camera frame (for the queue).
void splatBlock([[maybe_unused]] const Projector& P, [[maybe_unused]] const OctantProjector& OP,
                [[maybe_unused]] Boxes& queue, const Chunk& c, int bi,
                const Eigen::Vector3d& block_lo_W, [[maybe_unused]] const float block_lo_C[3],
                double s, PixelBounds* bounds) {
  const auto& occ = c.occ[bi];  // word z holds bits x | y << 3
  for (int oz = 0; oz < 2; ++oz)
    for (int oy = 0; oy < 2; ++oy)
      for (int ox = 0; ox < 2; ++ox) {
        const std::uint64_t quad = std::uint64_t{0x0F0F0F0F} << (4 * ox + 32 * oy);
        // The octant's four z words; its z, y and x extents without branches.
        const std::uint64_t w0 = occ[4 * oz] & quad, w1 = occ[4 * oz + 1] & quad,
                            w2 = occ[4 * oz + 2] & quad, w3 = occ[4 * oz + 3] & quad;
        const std::uint64_t xy = w0 | w1 | w2 | w3;
        if (!xy) continue;
        const unsigned zs = unsigned{w0 != 0} | unsigned{w1 != 0} << 1 | unsigned{w2 != 0} << 2 |
                            unsigned{w3 != 0} << 3;
        const int z_lo = 4 * oz + __builtin_ctz(zs), z_hi = 4 * oz + 31 - __builtin_clz(zs);
        constexpr std::uint64_t k7F = 0x7F7F7F7F7F7F7F7Full, k80 = 0x8080808080808080ull;
        const std::uint64_t rows = (((xy & k7F) + k7F) | xy) & k80;  // bit 7 of each non-zero row
        const int y_lo = __builtin_ctzll(rows) >> 3, y_hi = (63 - __builtin_clzll(rows)) >> 3;
        std::uint64_t xr = xy | xy >> 32;  // x bits over all rows
        xr |= xr >> 16;
        xr |= xr >> 8;
        const unsigned xs = static_cast<unsigned>(xr & 0xFFu);
        const int x_lo = __builtin_ctz(xs), x_hi = 31 - __builtin_clz(xs);
        const int n[3] = {x_hi - x_lo + 1, y_hi - y_lo + 1, z_hi - z_lo + 1};
        const int first[3] = {x_lo, y_lo, z_lo};
        double lo[3], ext[3];
        for (int k = 0; k < 3; ++k) lo[k] = block_lo_W[k] + first[k] * s, ext[k] = n[k] * s;
#ifdef DT_RAYCAST_SSE2
        float base_C[3];
        for (int k = 0; k < 3; ++k)
          base_C[k] =
              block_lo_C[k] + x_lo * OP.step[0][k] + y_lo * OP.step[1][k] + z_lo * OP.step[2][k];
        queue.push(OP, base_C, n, lo, ext, bounds);
#else
        BoxView bv;
        const Eigen::Vector3d lo_v(lo[0], lo[1], lo[2]), ext_v(ext[0], ext[1], ext[2]);
        if (viewBox(P, lo_v, ext_v, &bv)) bounds->add(bv, lo_v, lo_v + ext_v);
#endif
      }
}

// One pixel ray P(t) = O + t D in voxel units (t is depth).
struct Ray {
  double O[3], D[3], invD[3];
  bool pos[3];
};

// The first run of occupied voxels met by a ray: the voxels (block, bit index) and their chords
// [t[k], t[k + 1]] along the ray.
struct Run {
  static constexpr int kMax = 16;  // a run of at most 6 voxel lengths crosses at most 14 voxels
  const Block* block[kMax];
  int lin[kMax];
  double t[kMax + 1];
  int n = 0;
  // Evidence-weighted centre of the run (HitDepth::depth()); 0 for no run.
  float depth(float l_occ) const {
    if (n == 0) return 0.0f;
    double sum_w = 0.0, sum_wt = 0.0;
    for (int k = 0; k < n; ++k) {
      const double w = (block[k]->log_odds[lin[k]] - l_occ) * (t[k + 1] - t[k]) + 1e-12;
      sum_w += w;
      sum_wt += w * 0.5 * (t[k] + t[k + 1]);
    }
    return static_cast<float>(sum_wt / sum_w);
  }
};

// The run HitDepth would average along the ray for t in [t, t1): marches voxel by voxel through
// blocks with an occupied voxel (born by born_max), skipping chunks and blocks without one whole,
// to the first occupied voxel, and on to the end of its run. The voxels Impl::walk<true, true>
// visits (raycastReference; up to ties within kEps at voxel edges) and the same arithmetic,
// restructured for speed: integer stepping with the voxel's bit index kept in the block, the
// block's occupancy words at hand, chunk crossings looked up in place, and the run's evidence read
// later (Run::depth). run.n = 0: no hit.
template <class Map>
void castRay(const Map& m, const Ray& r, double t, double t1, double cap, std::uint32_t born_max,
             Run& run) {
  constexpr double kEps = 1e-9;  // as Impl::walk
  const double inf = std::numeric_limits<double>::infinity();
  const int dir[3] = {r.pos[0] ? 1 : -1, r.pos[1] ? 1 : -1, r.pos[2] ? 1 : -1};
  const int dlin[3] = {dir[0], 8 * dir[1], 64 * dir[2]};  // voxel bit index step per axis
  const double t_step[3] = {std::abs(r.invD[0]), std::abs(r.invD[1]), std::abs(r.invD[2])};
  int& n = run.n;
  n = 0;
  double t_first = 0.0;
  while (t < t1) {
    int q[3] = {map_detail::fastFloor(r.O[0] + t * r.D[0]),
                map_detail::fastFloor(r.O[1] + t * r.D[1]),
                map_detail::fastFloor(r.O[2] + t * r.D[2])};
    const Chunk* c = m.chunkAt(q[0] >> map_detail::kChunkShift, q[1] >> map_detail::kChunkShift,
                               q[2] >> map_detail::kChunkShift);
    int shift = 0, bi = 0;
    if (!c || c->occupied_blocks == 0) {
      shift = map_detail::kChunkShift;
    } else {
      bi = map_detail::blockInChunk(q[0], q[1], q[2]);
      if (c->n_occ[bi] == 0 || c->born[bi] > born_max) shift = map_detail::kBlockShift;
    }
    if (shift != 0) {
      if (n > 0) return;  // the run ended
      double t_exit = inf;
      for (int a = 0; a < 3; ++a) {
        const int lo = (q[a] >> shift) << shift;
        const double bound = r.pos[a] ? lo + (1 << shift) : lo;
        t_exit = std::min(t_exit, (bound - r.O[a]) * r.invD[a]);
      }
      t = std::max(t_exit, t) + kEps;
      continue;
    }
    // Inside a block with an occupied voxel; on into neighbouring ones of the same chunk. The
    // per-axis state lives in scalars (one copy of the step per axis) to stay in registers.
    double tn0 = ((r.pos[0] ? q[0] + 1 : q[0]) - r.O[0]) * r.invD[0];
    double tn1 = ((r.pos[1] ? q[1] + 1 : q[1]) - r.O[1]) * r.invD[1];
    double tn2 = ((r.pos[2] ? q[2] + 1 : q[2]) - r.O[2]) * r.invD[2];
    // Voxel steps left along each axis before leaving the block.
    int left0 = r.pos[0] ? 7 - (q[0] & 7) : (q[0] & 7);
    int left1 = r.pos[1] ? 7 - (q[1] & 7) : (q[1] & 7);
    int left2 = r.pos[2] ? 7 - (q[2] & 7) : (q[2] & 7);
    const std::uint64_t* occ = c->occ[bi].data();
    int lin = map_detail::voxelInBlock(q[0], q[1], q[2]);
    enum { kGoOn, kDone, kEmptyBlock, kEmptyChunk };
    // Visits the current voxel, which the ray leaves at `te` along axis A, and steps to the next.
    auto step = [&](auto axis, double& tn, int& left) {
      constexpr int A = decltype(axis)::value;
      const double te = std::max(tn, t);
      // A voxel the ray only grazes at an edge or corner (chord under kEps) does not count: the
      // reference march, stepping kEps past each exit, steps over it.
      const bool o = (occ[lin >> 6] >> (lin & 63)) & 1u;
      if (te - t > kEps) {
        if (n == 0) {
          if (o) {
            t_first = t;
            run.t[0] = t;
          }
        } else if (!o) {
          return kDone;
        }
        if (o) {
          const double end = std::min(std::min(te, t1), t_first + cap);
          const Block* b = c->blocks[bi].get();
          __builtin_prefetch(&b->log_odds[lin]);  // read by Run::depth once the run is known
          run.block[n] = b;
          run.lin[n] = lin;
          run.t[++n] = end;
          if (end - t_first >= cap || n == Run::kMax) return kDone;
        }
      }
      t = te;
      if (t >= t1) return kDone;
      q[A] += dir[A];
      tn += t_step[A];
      if (left-- > 0) {
        lin += dlin[A];
        return kGoOn;
      }
      // Into the next block along the axis.
      left = 7;
      lin -= 7 * dlin[A];
      if ((q[A] & 63) == (r.pos[A] ? 0 : 63)) {  // into the next chunk
        c = m.chunkAt(q[0] >> map_detail::kChunkShift, q[1] >> map_detail::kChunkShift,
                      q[2] >> map_detail::kChunkShift);
        if (!c || c->occupied_blocks == 0) return kEmptyChunk;
        bi = map_detail::blockInChunk(q[0], q[1], q[2]);
      } else {
        bi += dir[A] << (3 * A);
      }
      if (c->n_occ[bi] == 0 || c->born[bi] > born_max) return kEmptyBlock;
      occ = c->occ[bi].data();
      return kGoOn;
    };
    int status;
    do {
      if (tn0 < tn1 && tn0 < tn2)
        status = step(std::integral_constant<int, 0>(), tn0, left0);
      else if (tn1 < tn2)
        status = step(std::integral_constant<int, 1>(), tn1, left1);
      else
        status = step(std::integral_constant<int, 2>(), tn2, left2);
    } while (status == kGoOn);
    if (status == kDone) return;
    if (n > 0) return;  // the run ended
    // Skip the empty block or chunk q lies in at once.
    const int skip = status == kEmptyBlock ? map_detail::kBlockShift : map_detail::kChunkShift;
    double t_exit = inf;
    for (int a = 0; a < 3; ++a) {
      const int lo = (q[a] >> skip) << skip;
      const double bound = r.pos[a] ? lo + (1 << skip) : lo;
      t_exit = std::min(t_exit, (bound - r.O[a]) * r.invD[a]);
    }
    t = std::max(t_exit, t);
    t += kEps;
  }
}

}  // namespace

namespace {

// The ray cast of VoxelMap::raycast and MapRayCaster::cast; the caller holds the read lock.
DepthImage castImage(const VoxelMap::Impl& m, const PinholeIntrinsics& K,
                     const Eigen::Isometry3d& T_W_C, const DepthRange& range,
                     const WorkerPool& pool, int min_age_frames, PixelBounds& bounds) {
  const int w = K.width, h = K.height;
  DepthImage out(w, h, 0.0f);
  if (m.occupied_count == 0) return out;
  if (static_cast<std::uint32_t>(min_age_frames) >= m.frame) return out;
  const std::uint32_t born_max = m.frame - static_cast<std::uint32_t>(min_age_frames);

  // Per-pixel near depth bounds from the occupied voxels of each visible block: the tight box of
  // the occupied voxels in each block octant, and the depth at which each pixel ray enters it. A
  // ray meets no occupied voxel before entering the nearest such box, and none at all if it
  // meets no box. (A far bound from the box exits would stop the few rays that pass boxes
  // without a hit sooner, but costs more to splat than it saves.) The buffers are the caller's
  // scratch kept between calls (fresh image-sized buffers cost page faults each call).
  const int gw = (w + 3) / 4;
  bounds.gw = gw;
  bounds.g.resize(static_cast<std::size_t>(gw) * h);
  bounds.o_W = T_W_C.translation();
  {
    // The ray components in double, then the reciprocal in float: relative error ~1e-7 even for
    // rays nearly parallel to an axis plane.
    const Eigen::Matrix3d& R_W_C = T_W_C.linear();
    for (int a = 0; a < 3; ++a) {
      for (int v = 0; v < h; ++v) {
        const double base = R_W_C(a, 1) * (v - K.cy) / K.fy + R_W_C(a, 2);
        const double step = R_W_C(a, 0) / K.fx;
        const double first = base - step * K.cx;
        PixelBounds::Group* row = bounds.g.data() + static_cast<std::size_t>(v) * gw;
#ifdef DT_RAYCAST_SSE2
        // The same arithmetic four pixels at a time (whole groups); d = 0 -> 1e-30 as
        // below.
        const __m128d first2 = _mm_set1_pd(first), step2 = _mm_set1_pd(step);
        const __m128 tiny = _mm_set1_ps(1e-30f), one = _mm_set1_ps(1.0f);
        const __m128 far = _mm_set1_ps(std::numeric_limits<float>::infinity());
        for (int u = 0; u < 4 * gw; u += 4) {
          const __m128d u01 = _mm_set_pd(u + 1, u), u23 = _mm_set_pd(u + 3, u + 2);
          const __m128 d = _mm_movelh_ps(_mm_cvtpd_ps(_mm_add_pd(first2, _mm_mul_pd(step2, u01))),
                                         _mm_cvtpd_ps(_mm_add_pd(first2, _mm_mul_pd(step2, u23))));
          const __m128 zero = _mm_cmpeq_ps(d, _mm_setzero_ps());
          _mm_store_ps(row[u >> 2].inv[a],
                       _mm_div_ps(one, _mm_or_ps(_mm_andnot_ps(zero, d), _mm_and_ps(zero, tiny))));
          if (a == 0) _mm_store_ps(row[u >> 2].near, far);
        }
#else
        for (int u = 0; u < 4 * gw; ++u) {
          const float d = static_cast<float>(first + step * u);
          row[u >> 2].inv[a][u & 3] =
              1.0f / (d == 0.0f ? 1e-30f : d);  // no 0 * inf in the slab test
          row[u >> 2].near[u & 3] = std::numeric_limits<float>::infinity();
        }
#endif
      }
    }
  }
  const Eigen::Isometry3d T_C_W = T_W_C.inverse();
  const Projector P{K, T_C_W.linear(), T_C_W.translation(), range.min_m, range.max_m};
  const double chunk_m = 64 * m.s, block_m = 8 * m.s;
  // Blocks are culled by their bounding sphere against the view frustum (one pixel of margin),
  // their octant boxes then by viewBox.
  struct Frustum {
    double r, zmin, zmax;
    Eigen::Vector2d n[4];  // side plane normals through the camera centre, (x or y, z) components
    bool mayMeet(const Eigen::Vector3d& c) const {
      if (c.z() + r < zmin || c.z() - r > zmax) return false;
      return n[0].x() * c.x() + n[0].y() * c.z() >= -r &&
             n[1].x() * c.x() + n[1].y() * c.z() >= -r &&
             n[2].x() * c.y() + n[2].y() * c.z() >= -r && n[3].x() * c.y() + n[3].y() * c.z() >= -r;
    }
  } frustum;
  frustum.r = 0.5 * std::sqrt(3.0) * block_m;
  frustum.zmin = range.min_m;
  frustum.zmax = range.max_m;
  frustum.n[0] = Eigen::Vector2d(1.0, -(-1.0 - K.cx) / K.fx).normalized();  // u >= -1
  frustum.n[1] = Eigen::Vector2d(-1.0, (w - K.cx) / K.fx).normalized();     // u <= w
  frustum.n[2] = Eigen::Vector2d(1.0, -(-1.0 - K.cy) / K.fy).normalized();  // v >= -1
  frustum.n[3] = Eigen::Vector2d(-1.0, (h - K.cy) / K.fy).normalized();     // v <= h
  // Camera-frame centre of a block from its camera-frame lower corner: lo_C + this.
  const Eigen::Vector3d c_C_half = P.R_C_W * Eigen::Vector3d::Constant(0.5 * block_m);
  OctantProjector OP;
  OP.fx = static_cast<float>(K.fx), OP.fy = static_cast<float>(K.fy);
  OP.cx = static_cast<float>(K.cx), OP.cy = static_cast<float>(K.cy);
  OP.zmin = static_cast<float>(range.min_m), OP.zmax = static_cast<float>(range.max_m);
  OP.width = w, OP.height = h;
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k < 3; ++k) OP.step[a][k] = static_cast<float>(P.R_C_W(k, a) * m.s);
  // Per chunk: its blocks with an occupied voxel old enough (without a branch per block), those
  // that may be seen (their occupancy lines fetched meanwhile, all at once), then their splats.
  int cand[map_detail::kChunkBlocks], seen[map_detail::kChunkBlocks];
  Boxes queue;
  float seen_lo_C[map_detail::kChunkBlocks][3];
  for (const auto& ch : m.chunks) {
    if (ch->occupied_blocks == 0) continue;
    BoxView cv;
    const Eigen::Vector3d chunk_lo = ch->coord.cast<double>() * chunk_m;
    if (!viewBox(P, chunk_lo, Eigen::Vector3d::Constant(chunk_m), &cv)) continue;
    int n_cand = 0, n_seen = 0;
    for (int b8 = 0; b8 < map_detail::kChunkBlocks; b8 += 8) {
#ifdef DT_RAYCAST_SSE2
      // Most blocks of a chunk hold no occupied voxel: eight counts checked at once.
      const __m128i counts = _mm_loadu_si128(reinterpret_cast<const __m128i*>(&ch->n_occ[b8]));
      if (_mm_movemask_epi8(_mm_cmpeq_epi16(counts, _mm_setzero_si128())) == 0xFFFF) continue;
#endif
      for (int bi = b8; bi < b8 + 8; ++bi) {
        cand[n_cand] = bi;
        n_cand += (ch->n_occ[bi] != 0) & (ch->born[bi] <= born_max);
      }
    }
    for (int k = 0; k < n_cand; ++k) {
      const int bi = cand[k];
      const Eigen::Vector3d lo =
          chunk_lo + Eigen::Vector3d(bi & 7, (bi >> 3) & 7, bi >> 6) * block_m;
      const Eigen::Vector3d lo_C = P.R_C_W * lo + P.t_C_W;
      if (!frustum.mayMeet(lo_C + c_C_half)) continue;
      __builtin_prefetch(ch->occ[bi].data());
      for (int a = 0; a < 3; ++a) seen_lo_C[n_seen][a] = static_cast<float>(lo_C[a]);
      seen[n_seen++] = bi;
    }
    for (int k = 0; k < n_seen; ++k) {
      const int bi = seen[k];
      const Eigen::Vector3d lo =
          chunk_lo + Eigen::Vector3d(bi & 7, (bi >> 3) & 7, bi >> 6) * block_m;
      splatBlock(P, OP, queue, *ch, bi, lo, seen_lo_C[k], m.s, &bounds);
    }
  }
#ifdef DT_RAYCAST_SSE2
  queue.flush(OP, &bounds);
#endif

  const Eigen::Matrix3d R = T_W_C.linear();
  const Eigen::Vector3d O = T_W_C.translation() * m.inv_s;
  const double run_cap_m = kRunCapVoxels * m.s;
  const double inf = std::numeric_limits<double>::infinity();
  // Camera-frame ray components per column and row (as raycastReference computes them).
  std::vector<double> ray_x(w), ray_y(h);
  for (int u = 0; u < w; ++u) ray_x[u] = (u - K.cx) / K.fx;
  for (int v = 0; v < h; ++v) ray_y[v] = (v - K.cy) / K.fy;
  // Marches pixel (u, v) into `run` (n = 0: no hit).
  auto march = [&](int u, int v, Run& run) {
    run.n = 0;
    const float tn = bounds.near(u, v);
    if (tn == std::numeric_limits<float>::infinity()) return;
    const double t0 = std::max(range.min_m, static_cast<double>(tn));
    const double t1 = range.max_m;
    if (t0 >= t1) return;
    const Eigen::Vector3d d = R * Eigen::Vector3d(ray_x[u], ray_y[v], 1.0);
    Ray ray;
    for (int a = 0; a < 3; ++a) {
      ray.O[a] = O[a];
      ray.D[a] = d[a] * m.inv_s;
      ray.invD[a] = ray.D[a] != 0.0 ? 1.0 / ray.D[a] : inf;
      ray.pos[a] = ray.D[a] >= 0.0;
    }
    castRay(m, ray, t0, t1, run_cap_m / d.norm(), born_max, run);
  };
  // Pixels in square tiles: neighbouring rays meet the same blocks, which then stay in cache. The
  // 64 runs of a tile are marched first and averaged after, so that the evidence they read
  // (prefetched during the march) has arrived by then.
  auto band = [&](int ty) {
    Run runs[kTile * kTile];
    const int v0 = ty * kTile, v_end = std::min(h, v0 + kTile);
    for (int u0 = 0; u0 < w; u0 += kTile) {
      const int u_end = std::min(w, u0 + kTile);
      for (int v = v0; v < v_end; ++v)
        for (int u = u0; u < u_end; ++u) march(u, v, runs[(v - v0) * kTile + u - u0]);
      for (int v = v0; v < v_end; ++v) {
        float* dst = out.data.data() + static_cast<std::size_t>(v) * w;
        for (int u = u0; u < u_end; ++u) dst[u] = runs[(v - v0) * kTile + u - u0].depth(m.l_occ);
      }
    }
  };
  const int bands = (h + kTile - 1) / kTile;
  pool.parallelFor(0, bands, 1, [&](int b, int e) {
    for (int ty = b; ty < e; ++ty) band(ty);
  });
  return out;
}

}  // namespace

DepthImage VoxelMap::raycast(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                             const DepthRange& range, int threads, int min_age_frames) const {
  checkRaycastInput(K, T_W_C, range);
  if (min_age_frames < 0) throw std::invalid_argument("raycast: min_age_frames must be >= 0");
  // Per-thread scratch, passed by reference so the pool's workers use this thread's buffers.
  thread_local PixelBounds scratch;
  const map_detail::ReadLock lock(impl_->mutex);
  return castImage(*impl_, K, T_W_C, range, WorkerPool(std::max(1, threads)), min_age_frames,
                   scratch);
}

struct MapRayCaster::Scratch {
  PixelBounds bounds;
};

MapRayCaster::MapRayCaster(const VoxelMap& map, const PinholeIntrinsics& intrinsics,
                           const DepthRange& range, std::shared_ptr<const WorkerPool> pool)
    : map_(&map),
      intrinsics_(intrinsics),
      range_(range),
      pool_(pool ? std::move(pool) : std::make_shared<const WorkerPool>(1)),
      scratch_(std::make_unique<Scratch>()) {
  checkRaycastInput(intrinsics, Eigen::Isometry3d::Identity(), range);
}

MapRayCaster::~MapRayCaster() = default;
MapRayCaster::MapRayCaster(MapRayCaster&&) noexcept = default;

DepthImage MapRayCaster::cast(const Eigen::Isometry3d& T_W_C, int min_age_frames) {
  const auto t0 = std::chrono::steady_clock::now();
  checkRaycastInput(intrinsics_, T_W_C, range_);
  if (min_age_frames < 0) throw std::invalid_argument("raycast: min_age_frames must be >= 0");
  const map_detail::ReadLock lock(map_->impl_->mutex);
  DepthImage out =
      castImage(*map_->impl_, intrinsics_, T_W_C, range_, *pool_, min_age_frames, scratch_->bounds);
  timing_.add(msSince(t0));
  return out;
}

DepthImage VoxelMap::raycastReference(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                                      const DepthRange& range) const {
  checkRaycastInput(K, T_W_C, range);
  const Impl& m = *impl_;
  const map_detail::ReadLock lock(m.mutex);
  DepthImage out(K.width, K.height, 0.0f);
  const Eigen::Vector3d o = T_W_C.translation();
  const Eigen::Matrix3d R = T_W_C.linear();
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      const Eigen::Vector3d d = R * Eigen::Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      HitDepth hit;
      hit.cap = kRunCapVoxels * m.s / d.norm();
      hit.l_occ = m.l_occ;
      m.walk<true, true>(o, d, range.min_m, range.max_m, hit);
      if (hit.found) out.at(u, v) = hit.depth();
    }
  }
  return out;
}

}  // namespace depth_track
