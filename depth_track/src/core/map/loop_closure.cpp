#include "depth_track/core/map/loop_closure.hpp"
#include "depth_track/core/angles.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

#include "depth_track/core/se3.hpp"

namespace depth_track {

namespace {
// Leaves out cells whose surface is seen at grazing incidence: |cos| of the angle between the
// cell's normal and its viewing ray below min_cos. Rebuilds the grid lookup to match.
void dropGrazingCells(CellCloud& c, double min_cos) {
  if (min_cos <= 0.0) return;
  std::vector<Cell> kept;
  kept.reserve(c.cells.size());
  std::fill(c.grid_index.begin(), c.grid_index.end(), -1);
  for (const Cell& cell : c.cells) {
    const float r = cell.mean_C.norm();
    if (!(r > 0.0f) || std::abs(cell.normal_C.dot(cell.mean_C)) < min_cos * r) continue;
    c.grid_index[static_cast<std::size_t>(cell.gy) * c.grid_w + cell.gx] =
        static_cast<int>(kept.size());
    kept.push_back(cell);
  }
  c.cells.swap(kept);
}
// Keeps the cells flagged in `keep`, rebuilding the grid lookup.
void keepFlagged(CellCloud& c, const std::vector<std::uint8_t>& keep) {
  std::vector<Cell> kept;
  kept.reserve(c.cells.size());
  std::fill(c.grid_index.begin(), c.grid_index.end(), -1);
  for (std::size_t i = 0; i < c.cells.size(); ++i) {
    if (!keep[i]) continue;
    const Cell& cell = c.cells[i];
    c.grid_index[static_cast<std::size_t>(cell.gy) * c.grid_w + cell.gx] =
        static_cast<int>(kept.size());
    kept.push_back(cell);
  }
  c.cells.swap(kept);
}
}  // namespace

LoopReference parseLoopReference(const std::string& name) {
  if (name == "raycast") return LoopReference::kRaycast;
  if (name == "surface") return LoopReference::kSurface;
  throw std::invalid_argument("unknown loop-closure reference '" + name +
                              "' (expected raycast or surface)");
}
std::string toString(LoopReference reference) {
  return reference == LoopReference::kSurface ? "surface" : "raycast";
}

PinholeIntrinsics downsampledIntrinsics(const PinholeIntrinsics& K, int factor) {
  if (factor < 1 || K.width % factor != 0 || K.height % factor != 0)
    throw std::invalid_argument("downsampledIntrinsics: " + std::to_string(K.width) + "x" +
                                std::to_string(K.height) + " is not divisible by factor " +
                                std::to_string(factor));
  PinholeIntrinsics out = K;
  out.width = K.width / factor;
  out.height = K.height / factor;
  out.fx = K.fx / factor;
  out.fy = K.fy / factor;
  // Pixel u' covers full-resolution pixels factor*u' .. factor*u' + factor - 1, whose centres
  // average to factor*u' + (factor - 1)/2.
  out.cx = (K.cx + 0.5) / factor - 0.5;
  out.cy = (K.cy + 0.5) / factor - 0.5;
  return out;
}

DepthImage downsampleDepth(const DepthImage& depth, int factor) {
  if (factor < 1 || depth.width % factor != 0 || depth.height % factor != 0)
    throw std::invalid_argument("downsampleDepth: " + std::to_string(depth.width) + "x" +
                                std::to_string(depth.height) + " is not divisible by factor " +
                                std::to_string(factor));
  const int w = depth.width / factor, h = depth.height / factor;
  DepthImage out(w, h, 0.0f);
  const float inv_n = 1.0f / static_cast<float>(factor * factor);
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      float sum = 0.0f;
      bool complete = true;
      for (int j = 0; j < factor && complete; ++j) {
        for (int i = 0; i < factor; ++i) {
          const float z = depth.at(u * factor + i, v * factor + j);
          if (!(z > 0.0f) || !std::isfinite(z)) {
            complete = false;
            break;
          }
          sum += z;
        }
      }
      if (complete) out.at(u, v) = sum * inv_n;
    }
  }
  return out;
}

std::vector<std::string> LoopClosureConfig::validate(const PinholeIntrinsics& intrinsics) const {
  std::vector<std::string> p;
  if (cl_step < 1) p.push_back("cl_step must be >= 1 frame");
  if (raycast_downsample != 1 && raycast_downsample != 2) {
    p.push_back("raycast_downsample must be 1 or 2");
  } else if (raycast_downsample == 2) {
    if (pca.cell_size % 2 != 0)
      p.push_back("pca.cell_size must be even with raycast_downsample = 2");
    if (intrinsics.width % 2 != 0 || intrinsics.height % 2 != 0)
      p.push_back("image width and height must be even with raycast_downsample = 2");
  }
  for (const auto& s : pca.validate(intrinsics.width, intrinsics.height)) p.push_back("pca: " + s);
  for (const auto& s : registration.validate()) p.push_back("registration: " + s);
  if (!(min_model_fraction >= 0.0 && min_model_fraction <= 1.0))
    p.push_back("min_model_fraction must lie in [0, 1]");
  if (min_model_cells < 1) p.push_back("min_model_cells must be >= 1");
  if (!(min_incidence_cos >= 0.0 && min_incidence_cos < 1.0))
    p.push_back("min_incidence_cos must lie in [0, 1)");
  if (!(min_normal_spread >= 0.0 && min_normal_spread <= 1.0 / 3.0))
    p.push_back("min_normal_spread must lie in [0, 1/3]");
  if (min_matches < 1) p.push_back("min_matches must be >= 1");
  if (!(max_correction_m > 0.0)) p.push_back("max_correction_m must be > 0 m");
  if (!(max_correction_deg > 0.0)) p.push_back("max_correction_deg must be > 0 deg");
  if (!(max_error_rms_m > 0.0)) p.push_back("max_error_rms_m must be > 0 m");
  if (min_model_age_frames < 0) p.push_back("min_model_age_frames must be >= 0");
  if (reference == LoopReference::kSurface) {
    if (surface_rounds < 1) p.push_back("surface_rounds must be >= 1");
    if (!(surface_reach_m >= 0.0)) p.push_back("surface_reach_m must be >= 0 m");
    for (const auto& s : surface.validate()) p.push_back("surface: " + s);
  }
  if (!(deadband_m >= 0.0) || !(deadband_deg >= 0.0))
    p.push_back("deadband_m and deadband_deg must be >= 0");
  return p;
}

namespace {
const LoopClosureConfig& checked(const PinholeIntrinsics& intrinsics,
                                 const LoopClosureConfig& config) {
  const auto problems = config.validate(intrinsics);
  if (!problems.empty())
    throw std::invalid_argument("loop closure config: " + joinProblems(problems));
  return config;
}
}  // namespace

LoopCloser::LoopCloser(const VoxelMap& map, const PinholeIntrinsics& intrinsics,
                       const DepthRange& range, const LoopClosureConfig& config)
    : intrinsics_(intrinsics),
      cast_intrinsics_(checked(intrinsics, config).raycast_downsample == 1
                           ? intrinsics
                           : downsampledIntrinsics(intrinsics, config.raycast_downsample)),
      config_(config),
      caster_(map, cast_intrinsics_, range) {
  if (config_.reference == LoopReference::kSurface)
    layer_ = std::make_unique<SurfaceModel>(config_.surface);
}

LoopClosureResult closeLoop(const VoxelMap& map, const DepthImage& current,
                            const PinholeIntrinsics& intrinsics, const DepthRange& range,
                            const Eigen::Isometry3d& T_W_C_pred, const LoopClosureConfig& config) {
  if (config.reference != LoopReference::kRaycast)
    throw std::invalid_argument(
        "closeLoop: needs reference raycast (a one-shot closer has observed no frames for a "
        "surface layer; use LoopCloser::observe and attempt)");
  return LoopCloser(map, intrinsics, range, config).attempt(current, 0.0, T_W_C_pred);
}

PcaConfig LoopCloser::castPca() const {
  PcaConfig pca = config_.pca;
  pca.cell_size /= config_.raycast_downsample;  // the same cells on the halved image
  return pca;
}

CellCloud LoopCloser::reduceFrame(const DepthImage& current) const {
  const int f = config_.raycast_downsample;
  CellCloud cur = f == 1 ? reduceToCells(current, cast_intrinsics_, castPca())
                         : reduceToCells(downsampleDepth(current, f), cast_intrinsics_, castPca());
  dropGrazingCells(cur, config_.min_incidence_cos);
  return cur;
}

void LoopCloser::observe(const DepthImage& depth, const Eigen::Isometry3d& T_W_C) {
  if (!layer_) return;
  checkFrameSize(depth, intrinsics_);
  if (!T_W_C.matrix().allFinite())
    throw std::invalid_argument("loop closure: observed pose T_W_C is not finite");
  const auto t0 = std::chrono::steady_clock::now();
  const CellCloud cells = reduceFrame(depth);
  PendingFrame f;
  f.T_W_C = T_W_C;
  f.means.reserve(cells.cells.size());
  f.normals.reserve(cells.cells.size());
  for (const Cell& c : cells.cells) {
    f.means.push_back(c.mean_C);
    f.normals.push_back(c.normal_C);
  }
  pending_.push_back(std::move(f));
  // A frame joins the layer once it is as old as the ray cast's model (min_model_age_frames):
  // registering against what the last frames just added would only echo their poses.
  while (static_cast<int>(pending_.size()) > config_.min_model_age_frames) {
    const PendingFrame& old = pending_.front();
    scratch_.cells.resize(old.means.size());
    for (std::size_t i = 0; i < old.means.size(); ++i) {
      scratch_.cells[i].mean_C = old.means[i];
      scratch_.cells[i].normal_C = old.normals[i];
    }
    layer_->integrate(scratch_, old.T_W_C);
    pending_.pop_front();
  }
  observe_timing_.add(msSince(t0));
}

std::size_t LoopCloser::pendingBytes() const {
  std::size_t bytes = 0;
  for (const PendingFrame& f : pending_)
    bytes += (f.means.capacity() + f.normals.capacity()) * sizeof(Eigen::Vector3f);
  return bytes;
}

std::string LoopCloser::castModel(const Eigen::Isometry3d& T_W_C, LoopClosureResult& r,
                                  CellCloud& model) {
  auto t0 = std::chrono::steady_clock::now();
  const DepthImage virt = caster_.cast(T_W_C, config_.min_model_age_frames);
  r.ms_raycast += msSince(t0);
  r.model_fraction = static_cast<double>(virt.countValid()) / virt.data.size();
  std::ostringstream why;
  if (r.model_fraction < config_.min_model_fraction) {
    why << "model too sparse: virtual image has returns on " << 100.0 * r.model_fraction
        << " % of pixels (< " << 100.0 * config_.min_model_fraction << " %)";
    return why.str();
  }
  t0 = std::chrono::steady_clock::now();
  model = reduceToCells(virt, cast_intrinsics_, castPca());
  dropGrazingCells(model, config_.min_incidence_cos);
  r.ms_reduce += msSince(t0);
  r.model_cells = static_cast<int>(model.cells.size());
  if (r.model_cells < config_.min_model_cells) {
    why << "model too sparse: " << r.model_cells << " cells in the virtual image (< "
        << config_.min_model_cells << ")";
  }
  return why.str();
}

std::string LoopCloser::layerModel(const CellCloud& cur, const Eigen::Isometry3d& T_W_C,
                                   bool final_round, double reach_m, LoopClosureResult& r,
                                   CellCloud& model) const {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::uint8_t> took;
  ModelRefineStats st;
  model = layer_->refine(cur, T_W_C, &st, &took, reach_m);
  keepFlagged(model, took);
  r.ms_reduce += msSince(t0);
  r.model_fraction = cur.cells.empty() ? 0.0 : static_cast<double>(st.refined) / cur.cells.size();
  r.model_cells = static_cast<int>(model.cells.size());
  std::ostringstream why;
  if (final_round && r.model_fraction < config_.min_model_fraction) {
    why << "model too sparse: the surface layer holds " << 100.0 * r.model_fraction
        << " % of the frame's cells (< " << 100.0 * config_.min_model_fraction << " %)";
  } else if (r.model_cells < config_.min_model_cells) {
    why << "model too sparse: " << r.model_cells << " cells in the surface layer (< "
        << config_.min_model_cells << ")";
  }
  return why.str();
}

std::string LoopCloser::registerOnto(const CellCloud& model, const CellCloud& cur,
                                     LoopClosureResult& r, RegistrationResult& res) const {
  std::ostringstream why;
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const Cell& c : model.cells) {
    const Eigen::Vector3d n = c.normal_C.cast<double>();
    scatter += n * n.transpose();
  }
  scatter /= static_cast<double>(model.cells.size());
  r.normal_spread = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter).eigenvalues()(0);
  if (r.normal_spread < config_.min_normal_spread) {
    why << "degenerate view: normal spread " << r.normal_spread << " (< "
        << config_.min_normal_spread << "), a translation along the surfaces is unconstrained";
    return why.str();
  }
  const auto t0 = std::chrono::steady_clock::now();
  RegistrationConfig reg = config_.registration;
  reg.min_matches = std::min(reg.min_matches, config_.min_matches);
  // The guess is the odometry's pose, whose error against the map is the drift this step is
  // there to remove (up to the correction gate), not the tracker's per-frame motion prior: weighed
  // against that (2 mm), each correction stopped short and closed only part of the drift. The
  // directions the model does not fix at all still keep the odometry's pose.
  reg.degeneracy.prior_sigma_m = std::max(config_.max_correction_m, reg.degeneracy.prior_sigma_m);
  res = registerCells(model, cur, cast_intrinsics_, Eigen::Isometry3d::Identity(), reg);
  r.ms_register += msSince(t0);
  r.matches = res.matches;
  r.error_rms_m = res.error_rms_m;
  if (res.matches < config_.min_matches) {
    why << "too few matches: " << res.matches << " cell pairs (< " << config_.min_matches << ")";
  } else if (!res.failure.empty()) {
    why << "registration failed: " << res.failure;
  } else if (!res.T_ref_cur.matrix().allFinite()) {
    why << "registration gave a non-finite correction";
  }
  return why.str();
}

std::string LoopCloser::plausible(const Eigen::Isometry3d& correction, LoopClosureResult& r) const {
  r.correction_m = correction.translation().norm();
  r.correction_deg = rotationAngle(correction) * kRadToDeg;
  std::ostringstream why;
  if (r.correction_m > config_.max_correction_m || r.correction_deg > config_.max_correction_deg) {
    why << "correction too large: " << 1000.0 * r.correction_m << " mm, " << r.correction_deg
        << " deg (bounds " << 1000.0 * config_.max_correction_m << " mm, "
        << config_.max_correction_deg << " deg)";
  } else if (r.error_rms_m > config_.max_error_rms_m) {
    why << "poor fit: residual RMS " << 1000.0 * r.error_rms_m << " mm (> "
        << 1000.0 * config_.max_error_rms_m << " mm)";
  }
  return why.str();
}

LoopClosureResult LoopCloser::attempt(const DepthImage& current, double stamp_s,
                                      const Eigen::Isometry3d& T_O_C,
                                      const Eigen::Isometry3d& T_M_O) {
  const auto t_attempt = std::chrono::steady_clock::now();
  if (!T_O_C.matrix().allFinite())
    throw std::invalid_argument("loop closure: predicted pose T_O_C is not finite");
  if (!T_M_O.matrix().allFinite())
    throw std::invalid_argument("loop closure: map -> odom correction T_M_O is not finite");
  checkFrameSize(current, intrinsics_);
  const Eigen::Isometry3d T_W_C_pred = T_M_O * T_O_C;

  LoopClosureResult r;
  r.T_W_C = T_W_C_pred;
  r.correction = {stamp_s, T_M_O};
  // Every exit below is a verdict with a reason; the attempt's time is taken on the way out.
  struct Timer {
    RunningStats& stats;
    std::chrono::steady_clock::time_point t0;
    ~Timer() { stats.add(msSince(t0)); }
  } timer{timing_, t_attempt};
  auto t0 = std::chrono::steady_clock::now();
  const CellCloud cur = reduceFrame(current);
  r.ms_reduce = msSince(t0);
  r.current_cells = static_cast<int>(cur.cells.size());

  // The correction maps the current camera into the model's camera at the prediction.
  Eigen::Isometry3d correction = Eigen::Isometry3d::Identity();
  std::string why;
  if (!layer_ || config_.surface_after_raycast) {
    CellCloud model;
    RegistrationResult res;
    why = castModel(T_W_C_pred, r, model);
    if (why.empty()) why = registerOnto(model, cur, r, res);
    if (why.empty()) why = plausible(res.T_ref_cur, r);
    if (why.empty()) correction = res.T_ref_cur;
    if (!why.empty() && !layer_) {
      r.reason = why;
      return r;
    }
  }
  if (layer_) {
    // The layer's planes are taken again at the corrected pose on each round: the pairs follow
    // the correction, within the layer's offset gate of the plane. The coverage gate is taken at
    // the last round's pose (a prediction a few millimetres off already loses the far cells'
    // planes: the layer's reach along a normal is about a voxel and a half).
    for (int round = 0; round < config_.surface_rounds; ++round) {
      CellCloud model;
      RegistrationResult res;
      why = layerModel(cur, T_W_C_pred * correction, round + 1 == config_.surface_rounds,
                       round == 0 ? config_.surface_reach_m : 0.0, r, model);
      if (why.empty()) why = registerOnto(model, cur, r, res);
      if (!why.empty()) {
        r.reason = why;
        return r;
      }
      correction = correction * res.T_ref_cur;
    }
    why = plausible(correction, r);
    if (!why.empty()) {
      r.reason = why;
      return r;
    }
  }
  if (r.correction_m < config_.deadband_m && r.correction_deg < config_.deadband_deg) {
    std::ostringstream o;
    o << "correction below the map's resolution: " << 1000.0 * r.correction_m << " mm, "
      << r.correction_deg << " deg (dead band " << 1000.0 * config_.deadband_m << " mm, "
      << config_.deadband_deg << " deg); not applied";
    r.reason = o.str();
    return r;
  }
  r.T_W_C = orthonormalized(T_W_C_pred * correction);
  r.correction.T_M_O = orthonormalized(r.T_W_C * T_O_C.inverse());
  r.accepted = true;
  std::ostringstream o;
  o << "accepted: " << 1000.0 * r.correction_m << " mm, " << r.correction_deg << " deg, "
    << r.matches << " pairs, residual " << 1000.0 * r.error_rms_m << " mm";
  r.reason = o.str();
  return r;
}

}  // namespace depth_track
