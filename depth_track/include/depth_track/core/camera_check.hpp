#pragma once
/// Camera characterisation from recorded depth frames of a target (thesis §4.1): depth bias
/// against laser-measured distances, temporal and spatial noise, drop-outs, the focal constant
/// (CAM_K) from a round target's diameter in pixels, and the lateral resolution from the spread
/// of the target's outline; then the noise model sigma(z) = a + b z + c z^2 and a depth-scale
/// correction fitted over all distances. ROS-free core; the `camera_check` tool is its front end.
///
/// Geometry: depths are z along the optical axis (metres); pixel (u, v) as in PinholeIntrinsics.
/// A plane is fitted in inverse depth, 1/z = g + a x + b y with x = (u - cx) / fx and
/// y = (v - cy) / fy, which is exact for any plane; its depth "on the axis" is 1/g, the distance a
/// laser along the optical axis measures to a target square to the camera.
#include <cstddef>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

namespace depth_track {

/// Thrown for input camera_check cannot measure (no planar region, a segment without frames,
/// frames of the wrong size...); the message names the segment and what was wrong.
class CameraCheckError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// How targets are found and measured.
struct CameraCheckConfig {
  /// Diameter of the round target, metres; 0 = none (a flat wall): the focal check is skipped.
  double target_diameter_m = 0.0;
  /// Pixel the target is looked for at; NaN = the principal point.
  double seed_u_px = std::numeric_limits<double>::quiet_NaN();
  double seed_v_px = std::numeric_limits<double>::quiet_NaN();
  int seed_radius_px = 6;  ///< half side of the seed window whose plane starts the region
  /// Face pixels within this chessboard distance of the target's outline are left out of the
  /// face statistics (edge drop-outs and lateral blur live there), pixels.
  int interior_margin_px = 5;
  int wall_window_px = 60;  ///< without a bounded target: half side of the central window, px
  int edge_window_px = 10;  ///< the edge spread is sampled within +- this distance of the outline
  int edge_sectors = 72;    ///< angular sectors in which the outline is located separately
  /// A return belongs to the target's face when it lies within this many single-frame sigmas of
  /// the face's plane (at least 2 mm plus two depth units).
  double face_tolerance_sigmas = 5.0;
  /// Depth unit of the input (16UC1 scale), metres; 0 = unknown or float. Its quantisation
  /// variance (unit^2 / 12) is removed from the noise model's sigma, which the renderer quantises
  /// again.
  double depth_unit_m = 0.0;

  /// Every problem (non-positive sizes, negative diameter, ...); empty = valid.
  std::vector<std::string> validate() const;
};

/// The frames of one still period of the camera in front of the target.
struct SegmentFrames {
  std::string label;  ///< names the segment in the table and in messages
  /// Laser-measured distance from the camera to the target's face along the optical axis,
  /// metres; NaN = not measured (no bias for this segment).
  double reference_distance_m = std::numeric_limits<double>::quiet_NaN();
  double t_start_s = 0.0, t_end_s = 0.0;  ///< time span of the frames (for the report)
  std::vector<DepthImage> frames;         ///< metres, 0 = no return
};

/// One sample of a segment's edge-spread function: share of returns on the target's face at
/// signed distance s from the outline (outward positive).
struct EdgeSpreadBin {
  double s_px = 0.0;
  double face_share = 0.0;  ///< returns on the face / all returns, in this bin
  double returns = 0.0;     ///< returns counted in the bin (pixels x frames)
};

/// What measureSegment finds for one segment. Fields that could not be measured are NaN.
struct SegmentResult {
  std::string label;
  double t_start_s = 0.0, t_end_s = 0.0;
  int frames = 0;
  double reference_distance_m = std::numeric_limits<double>::quiet_NaN();
  double camera_depth_m = 0.0;     ///< mean over frames of the face plane's depth on the axis
  double camera_depth_sd_m = 0.0;  ///< frame-to-frame standard deviation of that depth
  double error_pct = std::numeric_limits<double>::quiet_NaN();  ///< (camera - reference) / ref
  double sigma_temporal_m = std::numeric_limits<double>::quiet_NaN();  ///< per-pixel sd over time
  double sigma_spatial_m = 0.0;  ///< sd of one frame's depths about its plane (RMS over frames)
  double dropout_share = 0.0;    ///< share of face pixel-frames without a return
  double tilt_deg = 0.0;         ///< angle between the face's normal and the optical axis
  int face_pixels = 0;           ///< pixels of the measured face
  bool target_found = false;     ///< a bounded round target was found (else: a wall)
  std::string target_note;       ///< why not, or what was found
  // ---- outline of a found target (NaN without one)
  double centre_u_px = std::numeric_limits<double>::quiet_NaN();
  double centre_v_px = std::numeric_limits<double>::quiet_NaN();
  double diameter_px = std::numeric_limits<double>::quiet_NaN();  ///< in columns (fx pixels)
  double outline_coverage_deg = 0.0;  ///< angle of the outline that was located
  double outline_rms_px = std::numeric_limits<double>::quiet_NaN();  ///< scatter about the circle
  /// CAM_K as the thesis's table 4.2: diameter_px * distance / diameter (reference distance if
  /// given, else the camera depth); NaN without a target diameter.
  double cam_k_px = std::numeric_limits<double>::quiet_NaN();
  /// The diameter the camera's depth and its nominal focal length imply, and its error.
  double diameter_est_m = std::numeric_limits<double>::quiet_NaN();
  double diameter_error_pct = std::numeric_limits<double>::quiet_NaN();
  /// Lateral resolution: distance between the 88 % and 12 % points of the edge-spread function
  /// (the FWHM of the line spread for a Gaussian blur), pixels and mm per metre of depth.
  double edge_spread_px = std::numeric_limits<double>::quiet_NaN();
  double edge_spread_mm_per_m = std::numeric_limits<double>::quiet_NaN();
  /// Inner (88 % -> 50 %) over outer (50 % -> 12 %) half width: 1 for a symmetric blur, far from
  /// 1 when one side bleeds (stereo fattening) or erodes; NaN for an edge sharper than 0.5 px.
  double edge_asymmetry = std::numeric_limits<double>::quiet_NaN();
  std::vector<EdgeSpreadBin> edge_spread;  ///< the measured function, for plots
};

/// Measures one segment: finds the planar region around the seed pixel (the round target's face
/// bounded by its depth step, or a wall), fits its plane per frame, and reports depth, noise,
/// drop-outs and, for a bounded target, its outline (diameter, CAM_K, edge spread).
/// Throws CameraCheckError naming the segment for no frames, frames whose size differs from the
/// intrinsics or from each other, or no planar region at the seed; std::invalid_argument for a
/// bad config or intrinsics. Thread-safe.
SegmentResult measureSegment(const SegmentFrames& segment, const PinholeIntrinsics& intrinsics,
                             const CameraCheckConfig& config);

/// Fits over all segments (fields NaN / flags false when not enough data).
struct CameraCheckFit {
  /// sigma(z) = const + linear z + quad z^2 (non-negative coefficients, fitted to the spatial
  /// sigma less the quantisation of depth_unit_m, relative errors weighted equally).
  int sigma_terms = 0;  ///< distances allow 1 (const), 2 (+ linear) or 3 terms
  double sigma_const_m = 0.0, sigma_linear = 0.0, sigma_quad_per_m = 0.0;
  double sigma_rms_rel = std::numeric_limits<double>::quiet_NaN();  ///< RMS relative residual
  /// Depth response: camera = scale * reference + offset (needs two or more reference distances;
  /// with one, scale only).
  bool depth_fitted = false;
  double depth_scale = 1.0, depth_offset_m = 0.0;
  double depth_rms_m = std::numeric_limits<double>::quiet_NaN();
  /// Focal constant from the outline diameters: diameter_px = K D / z + 2 edge_offset_px, so an
  /// edge widened (or eroded) by a constant number of pixels does not bias K. One distance:
  /// K from that diameter, edge offset assumed 0.
  bool focal_fitted = false;
  double cam_k_px = std::numeric_limits<double>::quiet_NaN();
  double cam_k_se_px = std::numeric_limits<double>::quiet_NaN();  ///< standard error
  double edge_offset_px = std::numeric_limits<double>::quiet_NaN();
  /// Mean lateral resolution over the segments with a target.
  double edge_spread_px = std::numeric_limits<double>::quiet_NaN();
  double edge_spread_mm_per_m = std::numeric_limits<double>::quiet_NaN();
  bool edge_symmetric = false;     ///< every measured edge has asymmetry within 0.67..1.5
  std::vector<std::string> notes;  ///< what was skipped and why
};

/// Fits the noise model, depth response and focal constant over the segments. Thread-safe.
CameraCheckFit fitCameraModel(const std::vector<SegmentResult>& segments,
                              const CameraCheckConfig& config);

/// The per-segment CAM_K corrected for the fitted edge offset (NaN without a fit or target).
double edgeCorrectedCamK(const SegmentResult& segment, const CameraCheckFit& fit,
                         const CameraCheckConfig& config);

/// The segments as a table in the layout of the thesis's table 4.2 (plus noise, drop-out and
/// edge columns), then the fits, as printable text.
std::string formatCameraCheckTable(const std::vector<SegmentResult>& segments,
                                   const CameraCheckFit& fit, const CameraCheckConfig& config);

/// A noise model drawn for comparison in the plots (coefficients of sigma(z)).
struct ReferenceSigmaModel {
  std::string name;
  double const_m = 0.0, linear = 0.0, quad_per_m = 0.0;
};

/// Everything camera_check writes.
struct CameraCheckReport {
  std::string source;  ///< the input(s), for the file header
  PinholeIntrinsics intrinsics;
  CameraCheckConfig config;
  std::vector<SegmentResult> segments;
  CameraCheckFit fit;
  /// Noise preset the written noise model takes its unmeasured effects from (l515 | d435 | none).
  std::string base_model = "l515";
  std::vector<ReferenceSigmaModel> reference_models;
};

/// Writes the report as YAML: `camera_check:` (inputs, segments, fits), `noise_model:` (loadable
/// by sim::loadNoiseModelYaml: render_sequence --noise-model, the rig simulator's depth camera)
/// and, when the depth response was fitted, `depth_correction:` (loadDepthCorrectionYaml). The
/// file is written through PATH.part and renamed. Throws std::runtime_error naming the path.
void writeCameraCheckYaml(const std::string& path, const CameraCheckReport& report);

/// Writes every segment's edge-spread function as CSV (segment,s_px,face_share,returns) for the
/// plot script. Throws std::runtime_error naming the path.
void writeEdgeSpreadCsv(const std::string& path, const std::vector<SegmentResult>& segments);

/// The camera's depth at the image centre: median of the valid depths within radius_px
/// (chessboard) of the principal point, metres; 0 when none. Thread-safe.
double centralDepth(const DepthImage& depth, const PinholeIntrinsics& intrinsics,
                    int radius_px = 10);

/// A run of frames during which the camera stood still.
struct StillPeriod {
  std::size_t first = 0, last = 0;  ///< frame indices, inclusive
  double depth_m = 0.0;             ///< median central depth over the run
};

/// Splits a recording into still periods from each frame's central depth (centralDepth): a run
/// ends when two consecutive frames leave its median by more than max(tolerance_rel * depth,
/// tolerance_m) (one stray frame is skipped); runs shorter than min_duration_s (stamps, seconds)
/// are motion and dropped, as are frames without a central depth. Thread-safe.
std::vector<StillPeriod> findStillPeriods(const std::vector<double>& stamps_s,
                                          const std::vector<double>& centre_depth_m,
                                          double min_duration_s = 1.0, double tolerance_rel = 0.005,
                                          double tolerance_m = 0.003);

}  // namespace depth_track
