#pragma once
/// Depth-frame and trajectory files: 16-bit PNG depth images, TUM RGB-D frame lists
/// (`depth.txt`) and TUM trajectories (`t tx ty tz qx qy qz qw`, camera-to-world T_W_C).
/// ROS-free core. All functions are thread-safe (no shared state).
#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

namespace depth_track {

/// Thrown for a file that is missing, unreadable or malformed. The message names the file and,
/// for text files, the 1-based line number ("groundtruth.txt:12: ...").
class FileFormatError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Reads a 16-bit single-channel (grayscale) PNG; returns width*height values, row-major, in
/// host byte order. Throws FileFormatError naming the file for a missing file, a non-PNG, or
/// any other bit depth / colour type (which it names). Thread-safe.
std::vector<std::uint16_t> readPng16(const std::string& path, int* width, int* height);

/// Writes width*height 16-bit values (row-major) as a 16-bit grayscale PNG. Throws
/// FileFormatError when the size does not match or the file cannot be written. Thread-safe.
void writePng16(const std::string& path, const std::vector<std::uint16_t>& data, int width,
                int height);

/// One entry of a TUM frame list.
struct TumFrame {
  double stamp_s = 0.0;  ///< capture time, seconds
  std::string path;      ///< absolute (or list-relative resolved) path of the image file
};

/// Parses a TUM frame list (`depth.txt`: `timestamp relative/path` per line, `#` comments, blank
/// lines ignored). Paths are resolved against the list's folder. Throws FileFormatError naming
/// the list and line for a malformed line or a listed image that does not exist. Thread-safe.
std::vector<TumFrame> readTumFrameList(const std::string& list_path);

/// Loads one 16-bit depth PNG as metres through depthFromRaw: value * depth_scale_m (TUM: 1/5000
/// m per unit), 0 and readings outside `range` become 0 (no return). Throws FileFormatError /
/// DepthInputError naming the file. Thread-safe.
DepthImage loadTumDepth(const std::string& png_path, double depth_scale_m, const DepthRange& range);

/// Writes a depth frame (metres) as a 16-bit PNG in units of depth_scale_m (rounded; 0 stays 0).
/// Throws FileFormatError for a depth that does not fit in 16 bits or a non-finite value.
void saveTumDepth(const std::string& png_path, const DepthImage& depth, double depth_scale_m);

/// A time-stamped camera pose: T_W_C maps camera-frame points into the world.
struct StampedPose {
  double stamp_s = 0.0;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
};
using Trajectory = std::vector<StampedPose>;

/// Reads a TUM trajectory (`t tx ty tz qx qy qz qw` per line, metres, camera-to-world; `#`
/// comments and blank lines ignored; commas accepted as separators). The quaternion is
/// normalised. Throws FileFormatError naming file and line for a malformed line (field count,
/// non-number, non-finite value, zero quaternion). Thread-safe.
Trajectory readTumTrajectory(const std::string& path);

/// Writes a TUM trajectory (stamps with 6 decimals, metres with 6, quaternion with 9, qw >= 0).
/// Throws FileFormatError when the file cannot be written or a pose is not finite.
void writeTumTrajectory(const std::string& path, const Trajectory& trajectory,
                        const std::string& comment = "");

/// Nearest-stamp association: for each query stamp, the index of the nearest reference stamp
/// if it is at most max_gap_s away (TUM uses 0.02 s). Reference stamps may be in any order; a
/// reference entry may serve several queries (as in the TUM tools). Returns (query index,
/// reference index) pairs in query order. Thread-safe.
std::vector<std::pair<std::size_t, std::size_t>> associateStamps(
    const std::vector<double>& query_s, const std::vector<double>& reference_s,
    double max_gap_s = 0.02);

/// A recorded depth sequence, read from a folder in one of two layouts:
/// - TUM RGB-D: `depth.txt` (stamp, PNG path), `groundtruth.txt` (optional), 5000 units per metre.
///   An optional `intrinsics.txt` holding "fx fy cx cy units_per_metre" gives the camera and the
///   unit (a layout other datasets are often converted to).
/// - 7-Scenes: `frame-NNNNNN.depth.png` (millimetres, 65535 = no return) with
///   `frame-NNNNNN.pose.txt` (4x4 camera-to-world), in the folder or its `data/` subfolder. The
///   frames carry no stamps: frame i (in file-name order) is stamped i / 30 s, the Kinect's rate.
///   Intrinsics from `camera-intrinsics.txt` (3x3 K) when present, otherwise the dataset's
///   published depth calibration (fx = fy = 585, cx = 320, cy = 240).
struct DepthSequence {
  std::string layout;                           ///< "TUM RGB-D" or "7-Scenes"
  std::vector<TumFrame> frames;                 ///< in time order
  std::string frames_source;                    ///< DIR/depth.txt or DIR/frame-*.depth.png
  double depth_scale_m = 0.0;                   ///< metres per PNG unit
  /// A raw value the layout uses for "no return" besides 0 (7-Scenes: 65535); 0 = none.
  std::uint16_t no_return_raw = 0;
  std::optional<PinholeIntrinsics> intrinsics;  ///< from the folder (image size 0x0), if known
  std::string intrinsics_source;                ///< where `intrinsics` came from
  Trajectory ground_truth;                      ///< camera-to-world; empty when the folder has none
  std::string ground_truth_source;              ///< file (TUM) or "frame-*.pose.txt" (7-Scenes)
};

/// Frame i's raw 16-bit depth (row-major, width x height) with the layout's own "no return"
/// value (DepthSequence::no_return_raw) set to 0, the one meaning of no return everywhere else
/// (REP 118). Throws FileFormatError naming the file. Thread-safe.
std::vector<std::uint16_t> readSequenceDepthRaw(const DepthSequence& seq, std::size_t i,
                                                int* width, int* height);

/// Frame i in metres (readSequenceDepthRaw, then depthFromRaw at `depth_scale_m` over `range`).
/// Throws FileFormatError / DepthInputError naming the file. Thread-safe.
DepthImage loadSequenceDepth(const DepthSequence& seq, std::size_t i, double depth_scale_m,
                             const DepthRange& range);

/// Reads a sequence folder (either layout above). Throws FileFormatError naming the file (and
/// line) for a malformed list, intrinsics or pose file, a 7-Scenes frame without its pose file,
/// a pose that is not a rigid transform, or a folder in neither layout. Thread-safe.
DepthSequence readDepthSequence(const std::string& dir);

/// Estimated and ground-truth poses paired by stamp (equal lengths, estimate order).
struct AssociatedTrajectories {
  std::vector<double> stamps_s;  ///< the estimate's stamps
  std::vector<Eigen::Isometry3d> est_T_W_C;
  std::vector<Eigen::Isometry3d> gt_T_W_C;
};
/// Pairs an estimated trajectory with ground truth by nearest stamp (within max_gap_s); poses
/// with non-finite entries are dropped. `est` and `gt` of the result have equal length.
AssociatedTrajectories associateTrajectories(const Trajectory& est, const Trajectory& gt,
                                             double max_gap_s = 0.02);

}  // namespace depth_track
