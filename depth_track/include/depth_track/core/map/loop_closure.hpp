#pragma once
/// Loop closure against the map (thesis §2.15, §3.13, fig. 3.28): ray-cast a virtual depth image
/// from the voxel map at the predicted pose, reduce it to cells, register the current frame's
/// cells onto them and correct the pose, with gates that reject a correction the map cannot
/// support. ROS-free core.
#include <Eigen/Geometry>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/cells.hpp"
#include "depth_track/core/map/map_raycaster.hpp"
#include "depth_track/core/map/voxel_map.hpp"
#include "depth_track/core/registration.hpp"
#include "depth_track/core/running_stats.hpp"
#include "depth_track/core/surface_model.hpp"

namespace depth_track {

/// What a loop-closure attempt registers the current frame against.
enum class LoopReference {
  kRaycast,  ///< a virtual depth image ray-cast from the occupancy map (thesis)
  kSurface,  ///< the loop closer's own mean-surface layer of the frames fused long enough ago
};
LoopReference parseLoopReference(const std::string& name);
std::string toString(LoopReference reference);

/// Configuration of the loop-closure step (thesis fig. 5.1 names in brackets).
struct LoopClosureConfig {
  bool enabled = false;  ///< (ClosedLoop)
  int cl_step = 10;      ///< attempt on every n-th frame (CLStep)
  /// Reduction of both the virtual image and the current frame (one grid, so cells pair one to
  /// one). Edge-spanning cells are kept out as in tracking; 10 px cells average the 5 mm voxel
  /// staircase of the virtual surface over ~4 voxels at 2 m.
  PcaConfig pca = [] {
    PcaConfig p;
    p.cell_size = 10;
    p.min_valid_fraction = 0.9;
    return p;
  }();
  /// 1 = ray-cast the virtual image at full resolution; 2 = at half resolution (intrinsics
  /// scaled by 1/2 about pixel centres), with the current frame averaged over 2x2 pixels and
  /// both reduced with cells of pca.cell_size / 2 px, so a cell covers the same view (4x fewer
  /// rays; corrections agree with full resolution, see test_loop_closure). The default: a
  /// 320x240 cast takes ~12 ms against ~38 ms at 640x480, and the tracker runs in
  /// test_loop_closure end with the same or lower errors than at full resolution.
  int raycast_downsample = 2;
  RegistrationConfig registration;  ///< method and pair gates of the correcting registration
  /// The model is the map without blocks first seen in the last min_model_age_frames fused
  /// frames: registering against what the last frames just fused only echoes their pose (and
  /// feeds the map's own bias back into the pose, the thesis's accelerated drift); loop closure
  /// needs the older, consolidated part of the map.
  int min_model_age_frames = 60;
  /// Corrections smaller than this are below what the map resolves; they are not applied.
  double deadband_m = 0.005;
  double deadband_deg = 0.1;
  /// Gate 1, sparse model: share of pixels of the virtual image with a return, and its cells.
  /// Half the view: a model covering only one side of the image (the edge of what was mapped
  /// long enough ago) constrains the rotation about the optical axis poorly, and its
  /// corrections add more error than they remove (measured on the rendered Room3 run).
  double min_model_fraction = 0.5;
  int min_model_cells = 200;
  /// Cells whose surface is seen at grazing incidence (|cos| between the cell's normal and its
  /// viewing ray below this; 0.3 = 72.5 deg) are left out of both images. A ray grazing a voxel
  /// surface crosses its shell of occupied voxels over a long stretch, so the virtual depth
  /// there is smeared along the ray; on a floor seen from a truck this tilted the corrections
  /// in pitch and roll. 0 keeps every cell.
  double min_incidence_cos = 0.3;
  /// Gate 1b, degenerate view: the smallest eigenvalue of the mean normal scatter
  /// (1/n) sum n n^T of the model's cells. Below it one translation direction is barely
  /// constrained (a single wall, a floor and a wall), and the registration slides along it.
  double min_normal_spread = 0.03;
  /// Gate 2, too few matches: pairs used in the final iteration.
  int min_matches = 100;
  /// Gate 3, implausible correction: drift between two attempts is millimetres, so a larger
  /// jump is a mismatch with the map.
  double max_correction_m = 0.05;
  double max_correction_deg = 3.0;
  double max_error_rms_m = 0.015;  ///< residual RMS above this = poor fit, metres
  /// What the frame is registered against (see LoopReference). With kSurface every fused frame
  /// is reduced to cells (observe()) and, once min_model_age_frames old, averaged into `surface`:
  /// a mean-surface layer in the map frame, whose planes average the sensor's noise where the
  /// occupancy map's ray cast returns the near side of a shell of stray hits.
  LoopReference reference = LoopReference::kSurface;
  /// The layer (kSurface): 1 cm voxels (the tracker's), kept whole (no radius); a cell within
  /// 3 cm of a plane takes it (the reach of a correction per round), and one observation makes a
  /// voxel's plane usable: the frames are reduced at half resolution, and most 1 cm voxels see a
  /// cell mean in only some of them (with the tracker's 3, 20-33 % of a rendered rt3 frame's
  /// cells found a plane against 96 % with 1; docs/mapping.md has the sweep).
  SurfaceModelConfig surface = [] {
    SurfaceModelConfig c;
    c.keep_radius_m = 0.0;
    c.max_offset_m = 0.03;
    c.min_weight = 1;
    return c;
  }();
  /// kSurface: registrations against the layer, its planes taken again at the corrected pose.
  int surface_rounds = 2;
  /// kSurface: the first round searches this far along each cell's normal for the layer's plane
  /// (metres; 0 = the layer's own reach, about a voxel and a half), the later rounds as usual.
  /// The default is the correction gate (max_correction_m): the drift an attempt may remove.
  double surface_reach_m = 0.05;
  /// kSurface: start the layer's rounds from the ray cast's correction when that passes its
  /// gates (the cast reaches drift beyond the layer's offset gate; the layer then removes the
  /// cast's bias), else from the prediction.
  bool surface_after_raycast = false;

  /// Every problem at once (empty = valid).
  std::vector<std::string> validate(const PinholeIntrinsics& intrinsics) const;
};

/// The map -> odom correction (REP 105): T_M_O maps poses of the odometry frame, in which the
/// tracker runs undisturbed, into the map frame. Stamped with the time of the frame it was
/// computed for: the mapper may run frames behind the tracker, and the correction stays valid
/// for the odometry poses after that frame (until the next one).
struct MapCorrection {
  double stamp_s = 0.0;
  Eigen::Isometry3d T_M_O = Eigen::Isometry3d::Identity();
};

/// Outcome of one attempt.
struct LoopClosureResult {
  bool accepted = false;
  std::string reason;  ///< "accepted: <size>" or why the correction was rejected
  Eigen::Isometry3d T_W_C =
      Eigen::Isometry3d::Identity();  ///< corrected pose (= input if rejected)
  double correction_m = 0.0;          ///< translation of the correction, metres
  double correction_deg = 0.0;        ///< rotation of the correction, degrees
  double model_fraction = 0.0;        ///< share of virtual pixels with a return
  double normal_spread = 0.0;         ///< smallest eigenvalue of the model's mean normal scatter
  int model_cells = 0, current_cells = 0, matches = 0;
  double error_rms_m = 0.0;
  double ms_raycast = 0.0, ms_reduce = 0.0, ms_register = 0.0;
  /// T_M_O after the attempt: T_W_C T_O_C^-1 when accepted, the correction it started from
  /// when rejected; stamped with the attempt's frame.
  MapCorrection correction;
};

/// The loop-closure stage: built once for a map, a camera and a config (its ray caster keeps
/// its scratch between attempts), it corrects the map -> odom transform against the map.
/// Thread-safe against a MapFuser writing the map on another thread (the cast holds the map's
/// read lock); not thread-safe itself (one instance per thread).
class LoopCloser {
 public:
  /// `map` must outlive the stage. Throws std::invalid_argument listing every problem of the
  /// config, intrinsics or range.
  LoopCloser(const VoxelMap& map, const PinholeIntrinsics& intrinsics, const DepthRange& range,
             const LoopClosureConfig& config);

  /// One attempt for the full-resolution frame `current` (metres) seen at stamp_s from T_O_C in
  /// the odometry frame, with T_M_O the correction in force: the virtual view is cast at the
  /// prediction T_M_O T_O_C, and an accepted registration gives T_W_C (map frame) and the new
  /// correction T_M_O' = T_W_C T_O_C^-1 stamped stamp_s. Gates and errors as closeLoop().
  LoopClosureResult attempt(const DepthImage& current, double stamp_s,
                            const Eigen::Isometry3d& T_O_C,
                            const Eigen::Isometry3d& T_M_O = Eigen::Isometry3d::Identity());

  /// Every fused frame at its map-frame pose (reference kSurface: feeds the mean-surface layer
  /// once the frame is min_model_age_frames old; nothing for kRaycast).
  void observe(const DepthImage& depth, const Eigen::Isometry3d& T_W_C);

  const LoopClosureConfig& config() const { return config_; }
  /// ms per attempt (ray cast, reductions and registration).
  const RunningStats& timing() const { return timing_; }
  /// ms per observe() call (reduction of the frame, and integration of the one leaving the queue).
  const RunningStats& observeTiming() const { return observe_timing_; }
  /// The mean-surface layer (reference kSurface), else null.
  const SurfaceModel* layer() const { return layer_.get(); }
  /// Bytes of the frames waiting to join the layer (their cells).
  std::size_t pendingBytes() const;

 private:
  PinholeIntrinsics intrinsics_;       ///< the camera's
  PinholeIntrinsics cast_intrinsics_;  ///< of the virtual image (downsampled)
  LoopClosureConfig config_;
  MapRayCaster caster_;
  RunningStats timing_, observe_timing_;
  std::unique_ptr<SurfaceModel> layer_;  ///< reference kSurface
  /// Frames observed but not yet min_model_age_frames old: their cells' means and normals (all
  /// the layer reads) and map-frame poses.
  struct PendingFrame {
    std::vector<Eigen::Vector3f> means, normals;  ///< the frame's cells, camera frame
    Eigen::Isometry3d T_W_C;
  };
  std::deque<PendingFrame> pending_;
  CellCloud scratch_;  ///< a pending frame's cells as integrate() takes them

  /// The PCA config at the cast resolution (cell_size divided by raycast_downsample).
  PcaConfig castPca() const;
  /// The frame at the cast resolution, reduced with config.pca (grazing cells left out).
  CellCloud reduceFrame(const DepthImage& current) const;
  // Each stage fills its fields of `r` and returns why the attempt stops there (empty: go on).
  /// The ray cast at T_W_C reduced to cells (kRaycast's model).
  std::string castModel(const Eigen::Isometry3d& T_W_C, LoopClosureResult& r, CellCloud& model);
  /// The current cells that lie on a confident plane of the layer seen from T_W_C, moved onto it
  /// (the coverage gate on the final round only; the cell count gate on each), searching
  /// reach_m along each normal (SurfaceModel::refine).
  std::string layerModel(const CellCloud& cur, const Eigen::Isometry3d& T_W_C, bool final_round,
                         double reach_m, LoopClosureResult& r, CellCloud& model) const;
  /// The normal-spread gate, then `cur` registered onto `model` from the identity.
  std::string registerOnto(const CellCloud& model, const CellCloud& cur, LoopClosureResult& r,
                           RegistrationResult& res) const;
  /// The size and residual gates of a correction.
  std::string plausible(const Eigen::Isometry3d& correction, LoopClosureResult& r) const;
};

/// One loop-closure attempt for the current full-resolution frame `current` (metres) predicted at
/// T_W_C_pred: the virtual image is ray-cast with `intrinsics` and `range`, both images are
/// reduced with config.pca, and the current cells are registered onto the virtual ones from the
/// identity. Never throws for a poor model or fit (those are rejections with a reason); throws
/// std::invalid_argument for a bad config or pose and DepthInputError for a frame of the wrong
/// size. Thread-safe against other uses of the map. A LoopCloser built for the call; its
/// correction starts from the identity (map frame = the tracker's world). The ray-cast
/// reference only (a closer built for one call has observed no frames for a surface layer):
/// throws std::invalid_argument for config.reference kSurface.
LoopClosureResult closeLoop(const VoxelMap& map, const DepthImage& current,
                            const PinholeIntrinsics& intrinsics, const DepthRange& range,
                            const Eigen::Isometry3d& T_W_C_pred, const LoopClosureConfig& config);

/// Intrinsics of the same camera at 1/factor resolution: focal lengths divided by factor and
/// the principal point mapped with pixel centres kept (c' = (c + 0.5) / factor - 0.5).
/// Throws std::invalid_argument when width or height is not a multiple of factor.
PinholeIntrinsics downsampledIntrinsics(const PinholeIntrinsics& intrinsics, int factor);

/// Depth image averaged over factor x factor pixel blocks (metres): a block with any pixel
/// without a return gets none, so no depth is blended across an edge or a hole. Throws
/// std::invalid_argument when the size is not a multiple of factor. Thread-safe.
DepthImage downsampleDepth(const DepthImage& depth, int factor);

}  // namespace depth_track
