// Depth from the voxel map (thesis §3.14): one ray per pixel, first occupied voxel wins.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "depth_track/core/map/voxel_map.hpp"
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
  // A pixel sees the box only if its centre lies in the hull of the projected corners; one pixel
  // of margin absorbs rounding.
  if (u_hi < -1.0 || v_hi < -1.0 || u_lo > K.width || v_lo > K.height) return false;
  out->u0 = std::max(0, static_cast<int>(std::ceil(u_lo)) - 1);
  out->u1 = std::min(K.width - 1, static_cast<int>(std::floor(u_hi)) + 1);
  out->v0 = std::max(0, static_cast<int>(std::ceil(v_lo)) - 1);
  out->v1 = std::min(K.height - 1, static_cast<int>(std::floor(v_hi)) + 1);
  return out->u0 <= out->u1 && out->v0 <= out->v1;
}

// Per-pixel depth bounds: no occupied voxel on a pixel's ray lies nearer than near[p] or farther
// than far[p] (near = +inf: none at all).
struct PixelBounds {
  int w = 0;
  std::vector<float> near, far;
  void add(const BoxView& b) {
    // Rounded outwards to float so the bounds stay conservative.
    const float zl = std::nextafter(static_cast<float>(b.z_lo), -1.0f);
    const float zh = std::nextafter(static_cast<float>(b.z_hi), 1e30f);
    for (int v = b.v0; v <= b.v1; ++v) {
      float* nr = near.data() + static_cast<std::size_t>(v) * w;
      float* fr = far.data() + static_cast<std::size_t>(v) * w;
      for (int u = b.u0; u <= b.u1; ++u) {
        nr[u] = std::min(nr[u], zl);
        fr[u] = std::max(fr[u], zh);
      }
    }
  }
};

// Splats the occupied voxels of block `bi` of chunk `c` into the bounds, as the tight boxes of its
// occupied voxels in each of its eight 4x4x4-voxel octants.
void splatBlock(const Projector& P, const Chunk& c, int bi, const Eigen::Vector3d& block_lo_W,
                double s, PixelBounds* bounds) {
  const auto& occ = c.occ[bi];  // word z holds bits x | y << 3
  for (int oz = 0; oz < 2; ++oz)
    for (int oy = 0; oy < 2; ++oy)
      for (int ox = 0; ox < 2; ++ox) {
        const std::uint64_t quad = std::uint64_t{0x0F0F0F0F} << (4 * ox + 32 * oy);
        int z_lo = 8, z_hi = -1;
        std::uint64_t xy = 0;
        for (int z = 4 * oz; z < 4 * oz + 4; ++z) {
          const std::uint64_t b = occ[z] & quad;
          if (!b) continue;
          xy |= b;
          z_lo = std::min(z_lo, z);
          z_hi = z;
        }
        if (!xy) continue;
        std::uint32_t xs = 0;  // x bits over all rows
        int y_lo = 8, y_hi = -1;
        for (int y = 0; y < 8; ++y) {
          const std::uint32_t row = static_cast<std::uint32_t>(xy >> (8 * y)) & 0xFFu;
          if (!row) continue;
          xs |= row;
          y_lo = std::min(y_lo, y);
          y_hi = y;
        }
        const int x_lo = __builtin_ctz(xs), x_hi = 31 - __builtin_clz(xs);
        BoxView bv;
        const Eigen::Vector3d lo = block_lo_W + Eigen::Vector3d(x_lo, y_lo, z_lo) * s;
        const Eigen::Vector3d ext =
            Eigen::Vector3d(x_hi - x_lo + 1, y_hi - y_lo + 1, z_hi - z_lo + 1) * s;
        if (viewBox(P, lo, ext, &bv)) bounds->add(bv);
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
  static constexpr int kMax = 32;  // a run of at most 6 voxel lengths crosses at most 14 voxels
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

// HitDepth along the ray for t in [t, t1): marches voxel by voxel through blocks with an occupied
// voxel (born by born_max), skipping chunks and blocks without one whole, to the first occupied
// voxel, then averages its run. The same voxels and the same arithmetic as HitDepth fed by
// Impl::walk, restructured for speed: integer stepping with the voxel's bit index kept in the
// block, the block's occupancy words at hand, and the run's evidence read after the run is known.
// Returns 0 when there is no hit.
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
    // Inside a block with an occupied voxel; on into neighbouring ones of the same chunk.
    double t_next[3];
    int left[3];  // voxel steps left along each axis before leaving the block
    for (int a = 0; a < 3; ++a) {
      t_next[a] = ((r.pos[a] ? q[a] + 1 : q[a]) - r.O[a]) * r.invD[a];
      left[a] = r.pos[a] ? 7 - (q[a] & 7) : (q[a] & 7);
    }
    const std::uint64_t* occ = c->occ[bi].data();
    int lin = map_detail::voxelInBlock(q[0], q[1], q[2]);
    bool next_chunk = false;
    while (true) {
      const int a =
          t_next[0] < t_next[1] ? (t_next[0] < t_next[2] ? 0 : 2) : (t_next[1] < t_next[2] ? 1 : 2);
      const double te = std::max(t_next[a], t);
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
          return;
        }
        if (o) {
          const double end = std::min(std::min(te, t1), t_first + cap);
          const Block* b = c->blocks[bi].get();
          __builtin_prefetch(&b->log_odds[lin]);  // read by Run::depth once the run is known
          run.block[n] = b;
          run.lin[n] = lin;
          run.t[++n] = end;
          if (end - t_first >= cap || n == Run::kMax) return;
        }
      }
      t = te;
      if (t >= t1) return;
      q[a] += dir[a];
      t_next[a] += t_step[a];
      if (left[a]-- > 0) {
        lin += dlin[a];
        continue;
      }
      // Into the next block along axis a.
      left[a] = 7;
      lin -= 7 * dlin[a];
      if ((q[a] & 63) == (r.pos[a] ? 0 : 63)) {
        next_chunk = true;
        break;
      }
      bi += dir[a] << (3 * a);
      if (c->n_occ[bi] == 0 || c->born[bi] > born_max) break;
      occ = c->occ[bi].data();
    }
    if (n > 0 && !next_chunk) return;  // the run met an empty block
    t += kEps;
  }
}

}  // namespace

DepthImage VoxelMap::raycast(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                             const DepthRange& range, int threads, int min_age_frames) const {
  checkRaycastInput(K, T_W_C, range);
  if (min_age_frames < 0) throw std::invalid_argument("raycast: min_age_frames must be >= 0");
  const Impl& m = *impl_;
  const int w = K.width, h = K.height;
  DepthImage out(w, h, 0.0f);
  if (m.occupied_count == 0) return out;
  if (static_cast<std::uint32_t>(min_age_frames) >= m.frame) return out;
  const std::uint32_t born_max = m.frame - static_cast<std::uint32_t>(min_age_frames);

  // Per-pixel near/far depth bounds from the occupied voxels of each visible block (the tight box
  // of the occupied voxels in each block octant, projected): a ray meets no occupied voxel
  // before the nearest such box over its pixel or after the farthest one.
  PixelBounds bounds;
  bounds.w = w;
  bounds.near.assign(static_cast<std::size_t>(w) * h, std::numeric_limits<float>::infinity());
  bounds.far.assign(bounds.near.size(), 0.0f);
  const Eigen::Isometry3d T_C_W = T_W_C.inverse();
  const Projector P{K, T_C_W.linear(), T_C_W.translation(), range.min_m, range.max_m};
  const double chunk_m = 64 * m.s, block_m = 8 * m.s;
  for (const auto& ch : m.chunks) {
    if (ch->occupied_blocks == 0) continue;
    BoxView cv;
    const Eigen::Vector3d chunk_lo = ch->coord.cast<double>() * chunk_m;
    if (!viewBox(P, chunk_lo, Eigen::Vector3d::Constant(chunk_m), &cv)) continue;
    for (int bi = 0; bi < map_detail::kChunkBlocks; ++bi) {
      if (ch->n_occ[bi] == 0 || ch->born[bi] > born_max) continue;
      BoxView bv;
      const Eigen::Vector3d lo =
          chunk_lo + Eigen::Vector3d(bi & 7, (bi >> 3) & 7, bi >> 6) * block_m;
      if (!viewBox(P, lo, Eigen::Vector3d::Constant(block_m), &bv)) continue;
      splatBlock(P, *ch, bi, lo, m.s, &bounds);
    }
  }

  const Eigen::Matrix3d R = T_W_C.linear();
  const Eigen::Vector3d O = T_W_C.translation() * m.inv_s;
  const double run_cap_m = kRunCapVoxels * m.s;
  const double inf = std::numeric_limits<double>::infinity();
  // Marches pixel (u, v) into `run` (n = 0: no hit).
  auto march = [&](int u, int v, Run& run) {
    run.n = 0;
    const std::size_t p = static_cast<std::size_t>(v) * w + u;
    const float tn = bounds.near[p];
    if (tn == std::numeric_limits<float>::infinity()) return;
    const double t0 = std::max(range.min_m, static_cast<double>(tn));
    const double t1 = std::min(range.max_m, static_cast<double>(bounds.far[p]) + 1e-6);
    if (t0 >= t1) return;
    const Eigen::Vector3d d = R * Eigen::Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
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
  // runs of a tile row are marched first and averaged after, so that the evidence they read
  // (prefetched during the march) has arrived by then.
  auto band = [&](int ty) {
    Run runs[kTile];
    const int v_end = std::min(h, (ty + 1) * kTile);
    for (int u0 = 0; u0 < w; u0 += kTile) {
      const int u_end = std::min(w, u0 + kTile);
      for (int v = ty * kTile; v < v_end; ++v) {
        for (int u = u0; u < u_end; ++u) march(u, v, runs[u - u0]);
        float* dst = out.data.data() + static_cast<std::size_t>(v) * w;
        for (int u = u0; u < u_end; ++u) dst[u] = runs[u - u0].depth(m.l_occ);
      }
    }
  };
  const int bands = (h + kTile - 1) / kTile;
  if (threads > 1) {
    tbb::task_arena arena(threads);
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<int>(0, bands), [&](const tbb::blocked_range<int>& r) {
        for (int ty = r.begin(); ty < r.end(); ++ty) band(ty);
      });
    });
  } else {
    for (int ty = 0; ty < bands; ++ty) band(ty);
  }
  return out;
}

DepthImage VoxelMap::raycastReference(const PinholeIntrinsics& K, const Eigen::Isometry3d& T_W_C,
                                      const DepthRange& range) const {
  checkRaycastInput(K, T_W_C, range);
  const Impl& m = *impl_;
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
