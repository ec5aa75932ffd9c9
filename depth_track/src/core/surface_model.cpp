#include "depth_track/core/surface_model.hpp"

#include "depth_track/core/camera.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace depth_track {

namespace {
// 21 bits per axis around the origin: +-2^20 voxels (+-21 km at 2 cm).
constexpr std::int64_t kAxisOffset = std::int64_t{1} << 20;
constexpr std::int64_t kAxisMask = (std::int64_t{1} << 21) - 1;
// A refined cell's ray must meet the plane at more than this cosine (grazing rays move the mean
// far along the ray for a small error in the plane).
constexpr float kMinRayCos = 0.2f;
// The first table: 2^16 slots (2.4 MB).
constexpr int kFirstBits = 16;
}  // namespace

std::vector<std::string> SurfaceModelConfig::validate() const {
  std::vector<std::string> p;
  if (!(voxel_m >= 0.002 && voxel_m <= 0.5))
    p.push_back("model.voxel_m must lie in [0.002, 0.5] m");
  if (max_weight < 1 || max_weight > 60000) p.push_back("model.max_weight must lie in [1, 60000]");
  if (min_weight < 1) p.push_back("model.min_weight must be >= 1");
  if (!(max_offset_m > 0.0)) p.push_back("model.max_offset_m must be > 0 m");
  if (!(max_offset_sigmas > 0.0)) p.push_back("model.max_offset_sigmas must be > 0");
  if (!noise.valid()) p.push_back("model.noise: the depth-noise coefficients must be >= 0");
  if (!(cos_min >= -1.0 && cos_min <= 1.0)) p.push_back("model.cos_min must lie in [-1, 1]");
  if (!(keep_radius_m >= 0.0)) p.push_back("model.keep_radius_m must be >= 0 m (0 = keep all)");
  if (prune_every < 1) p.push_back("model.prune_every must be >= 1 frame");
  return p;
}

namespace {
void checkConfig(const SurfaceModelConfig& config) {
  const auto problems = config.validate();
  if (!problems.empty())
    throw std::invalid_argument("surface model config: " + joinProblems(problems));
}
}  // namespace

SurfaceModel::SurfaceModel(const SurfaceModelConfig& config) : config_(config) {
  checkConfig(config);
  inv_voxel_ = static_cast<float>(1.0 / config.voxel_m);
}

void SurfaceModel::setConfig(const SurfaceModelConfig& config) {
  checkConfig(config);
  if (config.voxel_m != config_.voxel_m)
    throw std::invalid_argument("surface model: model.voxel_m cannot change on a built model");
  config_ = config;
}

std::uint64_t SurfaceModel::keyOf(const Eigen::Vector3f& p_W) const {
  std::uint64_t key = 0;
  for (int a = 0; a < 3; ++a) {
    const auto i = static_cast<std::int64_t>(std::floor(p_W[a] * inv_voxel_)) + kAxisOffset;
    key = (key << 21) | static_cast<std::uint64_t>(i & kAxisMask);
  }
  return key;
}

void SurfaceModel::clear() {
  keys_.clear();
  slots_.clear();
  size_ = 0;
  bits_ = 0;
}

std::size_t SurfaceModel::memoryBytes() const {
  return keys_.capacity() * sizeof(std::uint64_t) + slots_.capacity() * sizeof(Voxel);
}

double SurfaceModel::bytesPerVoxel() const {
  return size_ == 0 ? 0.0 : static_cast<double>(memoryBytes()) / static_cast<double>(size_);
}

std::size_t SurfaceModel::slotOf(std::uint64_t key) const {
  // Fibonacci hashing: the top bits of the key times 2^64 / phi.
  return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ull) >> (64 - bits_));
}

const SurfaceModel::Voxel* SurfaceModel::find(std::uint64_t key) const {
  if (size_ == 0) return nullptr;
  const std::size_t mask = keys_.size() - 1;
  for (std::size_t i = slotOf(key);; i = (i + 1) & mask) {
    if (keys_[i] == key) return &slots_[i];
    if (keys_[i] == kEmpty) return nullptr;
  }
}

template <class Keep>
void SurfaceModel::rehash(int bits, Keep keep) {
  std::vector<std::uint64_t> keys = std::move(keys_);
  std::vector<Voxel> slots = std::move(slots_);
  bits_ = bits;
  keys_.assign(std::size_t{1} << bits_, kEmpty);
  slots_.assign(std::size_t{1} << bits_, Voxel{});
  size_ = 0;
  const std::size_t mask = keys_.size() - 1;
  for (std::size_t j = 0; j < keys.size(); ++j) {
    if (keys[j] == kEmpty || !keep(slots[j])) continue;
    std::size_t i = slotOf(keys[j]);
    while (keys_[i] != kEmpty) i = (i + 1) & mask;
    keys_[i] = keys[j];
    slots_[i] = slots[j];
    ++size_;
  }
}

void SurfaceModel::grow() {
  rehash(bits_ == 0 ? kFirstBits : bits_ + 1, [](const Voxel&) { return true; });
}

std::size_t SurfaceModel::prune(const Eigen::Vector3d& centre_W, double radius_m) {
  if (size_ == 0) return 0;
  const Eigen::Vector3f c = centre_W.cast<float>();
  const float r2 = static_cast<float>(radius_m * radius_m);
  const auto inside = [&](const Voxel& v) {
    return (Eigen::Vector3f(v.mean[0], v.mean[1], v.mean[2]) - c).squaredNorm() <= r2;
  };
  std::size_t kept = 0;
  for (std::size_t j = 0; j < keys_.size(); ++j) kept += keys_[j] != kEmpty && inside(slots_[j]);
  const std::size_t dropped = size_ - kept;
  if (dropped == 0) return 0;
  // The smallest table (from 2^kFirstBits) that holds what is kept below 70 % load.
  int bits = kFirstBits;
  while (10 * kept > 7 * (std::size_t{1} << bits)) ++bits;
  rehash(bits, inside);
  keys_.shrink_to_fit();
  slots_.shrink_to_fit();
  return dropped;
}

void SurfaceModel::prefetchSlot(std::uint64_t key) const {
  const std::size_t i = slotOf(key);
  __builtin_prefetch(&keys_[i]);
  __builtin_prefetch(&slots_[i]);
}

SurfaceModel::Voxel& SurfaceModel::findOrInsert(std::uint64_t key) {
  if (10 * (size_ + 1) > 7 * keys_.size()) grow();  // load factor at most 0.7
  const std::size_t mask = keys_.size() - 1;
  std::size_t i = slotOf(key);
  for (; keys_[i] != kEmpty; i = (i + 1) & mask)
    if (keys_[i] == key) return slots_[i];
  keys_[i] = key;
  ++size_;
  return slots_[i];
}

void SurfaceModel::integrate(const CellCloud& cells, const Eigen::Isometry3d& T_W_C) {
  const Eigen::Matrix3f R = T_W_C.rotation().cast<float>();
  const Eigen::Vector3f t = T_W_C.translation().cast<float>();
  // The frame's cells grouped by voxel first: a voxel gains one observation per frame, the mean
  // of that frame's cells in it, however many cells its footprint holds.
  frame_cells_.clear();
  for (const Cell& c : cells.cells) {
    const Eigen::Vector3f p = R * c.mean_C + t;
    const Eigen::Vector3f n = R * c.normal_C;
    if (p.allFinite() && n.allFinite()) frame_cells_.push_back({keyOf(p), p, n});
  }
  // Grouped without sorting (a sort of the ~8000 samples cost about 0.3 ms of fr1/xyz's 4.7 ms
  // frame): a per-frame table maps each key to its first sample, which sums the rest, and the
  // groups are compacted to the front in the order first seen.
  {
    std::size_t cap = 16;
    while (cap < 2 * frame_cells_.size()) cap <<= 1;
    group_slot_.assign(cap, -1);
    group_count_.assign(frame_cells_.size(), 0);
    std::size_t m = 0;
    for (std::size_t i = 0; i < frame_cells_.size(); ++i) {
      const std::uint64_t k = frame_cells_[i].key;
      std::size_t h = (k * 0x9E3779B97F4A7C15ull) >> 40;
      for (;; ++h) {
        std::int32_t& s = group_slot_[h & (cap - 1)];
        if (s < 0) {
          s = static_cast<std::int32_t>(m);
          frame_cells_[m] = frame_cells_[i];
          group_count_[m] = 1;
          ++m;
          break;
        }
        if (frame_cells_[s].key == k) {
          frame_cells_[s].p += frame_cells_[i].p;
          frame_cells_[s].n += frame_cells_[i].n;
          ++group_count_[s];
          break;
        }
      }
    }
    frame_cells_.resize(m);
  }
  // Grow before the loop (at most one new voxel per sample), so the slots prefetched below stay
  // where they are: the table is far larger than the cache, and each voxel is a random access.
  while (10 * (size_ + frame_cells_.size()) > 7 * keys_.size()) grow();
  constexpr std::size_t kAhead = 16;  // samples
  for (std::size_t j = 0; j < std::min(kAhead, frame_cells_.size()); ++j)
    prefetchSlot(frame_cells_[j].key);
  for (std::size_t i = 0; i < frame_cells_.size(); ++i) {
    if (i + kAhead < frame_cells_.size()) prefetchSlot(frame_cells_[i + kAhead].key);
    const std::uint64_t key = frame_cells_[i].key;
    const float count = static_cast<float>(group_count_[i]);
    Eigen::Vector3f p = frame_cells_[i].p / count, n = frame_cells_[i].n / count;
    Voxel& v = findOrInsert(key);
    if (v.weight > 0 && n[0] * v.normal[0] + n[1] * v.normal[1] + n[2] * v.normal[2] <= 0.f)
      continue;  // the other side of a thin surface: not this voxel's plane
    const int w = std::min<int>(v.weight + 1, config_.max_weight);
    const float a = 1.f / static_cast<float>(w);
    for (int k = 0; k < 3; ++k) {
      v.mean[k] += a * (p[k] - v.mean[k]);
      v.normal[k] += a * (n[k] - v.normal[k]);
    }
    v.weight = static_cast<std::uint16_t>(w);
  }
}

CellCloud SurfaceModel::refine(const CellCloud& cells, const Eigen::Isometry3d& T_W_C,
                               ModelRefineStats* stats,
                               std::vector<std::uint8_t>* took_model, double reach_m) const {
  CellCloud out = cells;
  if (took_model) took_model->assign(cells.cells.size(), 0);
  ModelRefineStats s;
  s.cells = static_cast<int>(cells.cells.size());
  const Eigen::Matrix3f R = T_W_C.rotation().cast<float>();
  const Eigen::Vector3f t = T_W_C.translation().cast<float>();
  const Eigen::Matrix3f Rt = R.transpose();
  const float cos_min = static_cast<float>(config_.cos_min);
  const float max_offset = static_cast<float>(config_.max_offset_m);
  const float k_sigma = static_cast<float>(config_.max_offset_sigmas);
  const bool noise_known = config_.noise.known();
  const float voxel = static_cast<float>(config_.voxel_m);
  const int reach_steps =
      reach_m > 0.0 ? static_cast<int>(std::ceil(reach_m / config_.voxel_m)) : 0;
  const float reach = static_cast<float>(reach_m);
  double sum_sq = 0.0;
  for (std::size_t i = 0; i < out.cells.size(); ++i) {
    Cell& c = out.cells[i];
    const Eigen::Vector3f p = R * c.mean_C + t;
    const Eigen::Vector3f n_cell = R * c.normal_C;
    const float z = c.mean_C.z();
    float gate =
        noise_known ? std::min(max_offset, k_sigma * static_cast<float>(config_.noise.sigmaAt(z)))
                    : max_offset;
    Eigen::Vector3f q = p;  // where along the normal the averaging is centred
    if (reach_steps > 0) {
      // The nearest agreeing plane within reach along the normal, stepping outwards.
      bool found_plane = false, seen_any = false;
      for (int j = 0; j <= reach_steps && !found_plane; ++j) {
        for (const int sgn : {1, -1}) {
          if (j == 0 && sgn < 0) continue;
          const Eigen::Vector3f pj = p + static_cast<float>(sgn * j) * voxel * n_cell;
          const Voxel* v = find(keyOf(pj));
          if (!v || v->weight < config_.min_weight) continue;
          seen_any = true;
          const Eigen::Vector3f n_v(v->normal[0], v->normal[1], v->normal[2]);
          const float len = n_v.norm();
          if (!(len > 0.5f)) continue;
          const Eigen::Vector3f m_v(v->mean[0], v->mean[1], v->mean[2]);
          if ((n_v / len).dot(n_cell) < cos_min || std::abs((n_v / len).dot(p - m_v)) > reach)
            continue;
          q = pj;
          found_plane = true;
          break;
        }
      }
      if (!found_plane) {
        ++(seen_any ? s.rejected : s.no_model);
        continue;
      }
      gate = std::max(gate, reach);
    }
    // The voxel the cell lies in and its neighbours along the cell's normal: a surface near a
    // voxel face splits its observations between the two layers by the sign of their noise,
    // and one layer alone would keep the cell on its own side. Voxels whose plane agrees with
    // the cell are averaged, weighted by their observations.
    const std::uint64_t keys[3] = {keyOf(q), keyOf(q + voxel * n_cell), keyOf(q - voxel * n_cell)};
    Eigen::Vector3f m_sum = Eigen::Vector3f::Zero(), n_sum = Eigen::Vector3f::Zero();
    float w_sum = 0.f;
    bool seen = false;
    for (int k = 0; k < 3; ++k) {
      if ((k == 1 && keys[1] == keys[0]) || (k == 2 && (keys[2] == keys[0] || keys[2] == keys[1])))
        continue;
      const Voxel* found = find(keys[k]);
      if (!found || found->weight < config_.min_weight) continue;
      seen = true;
      const Voxel& v = *found;
      const Eigen::Vector3f n_v(v.normal[0], v.normal[1], v.normal[2]);
      const float len = n_v.norm();
      // Normals that disagree among themselves average to a short vector: no plane there.
      if (!(len > 0.5f)) continue;
      const Eigen::Vector3f n_unit = n_v / len;
      const Eigen::Vector3f m_v(v.mean[0], v.mean[1], v.mean[2]);
      if (n_unit.dot(n_cell) < cos_min || std::abs(n_unit.dot(p - m_v)) > gate) continue;
      const float w = static_cast<float>(v.weight);
      m_sum += w * m_v;
      n_sum += w * n_unit;
      w_sum += w;
    }
    if (!(w_sum > 0.f)) {
      ++(seen ? s.rejected : s.no_model);
      continue;
    }
    const Eigen::Vector3f n = Rt * n_sum.normalized();
    const Eigen::Vector3f m = Rt * (m_sum / w_sum - t);
    const float offset = n.dot(c.mean_C - m);
    const float denom = n.dot(c.mean_C);
    if (std::abs(offset) > gate || std::abs(denom) < kMinRayCos * c.mean_C.norm()) {
      ++s.rejected;
      continue;
    }
    c.mean_C *= n.dot(m) / denom;
    c.normal_C = n;
    if (took_model) (*took_model)[i] = 1;
    ++s.refined;
    sum_sq += static_cast<double>(offset) * offset;
  }
  if (s.refined > 0) s.rms_offset_m = std::sqrt(sum_sq / s.refined);
  if (stats) *stats = s;
  return out;
}

}  // namespace depth_track
