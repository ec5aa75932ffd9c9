#pragma once
/// The intrinsics a recorded sequence folder is read with, chosen one way for the tools that read
/// such folders (track_sequence, tum_to_bag): --camera fr1|fr2|fr3 (TUM's published
/// calibrations), or all four of --fx --fy --cx --cy, or else the folder's own intrinsics file
/// (DepthSequence::intrinsics). Header-only, ROS-free.
#include <stdexcept>
#include <string>

#include "depth_track/core/tum_cameras.hpp"
#include "depth_track/core/tum_io.hpp"

namespace depth_track {

/// The four values of --fx --fy --cx --cy and how many of them were given.
struct IntrinsicsFlags {
  double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
  int given = 0;
};

struct ChosenIntrinsics {
  PinholeIntrinsics K;  ///< image size 0 x 0: the caller takes it from the frames
  std::string source;   ///< where K came from, for the tools' first line
};

/// Throws std::invalid_argument for an unknown --camera, some but not all of --fx --fy --cx
/// --cy, or none given for a folder without an intrinsics file (naming the camera the folder
/// points at, when it does).
inline ChosenIntrinsics chooseIntrinsics(const DepthSequence& seq, const std::string& dir,
                                         const std::string& camera, const IntrinsicsFlags& f) {
  ChosenIntrinsics c;
  if (!camera.empty()) {
    const auto k = tumIntrinsics(camera);
    if (!k) throw std::invalid_argument("--camera '" + camera + "': expected fr1, fr2 or fr3");
    c.K = *k;
    c.source = "--camera " + camera;
  } else if (f.given == 4) {
    c.K.fx = f.fx, c.K.fy = f.fy, c.K.cx = f.cx, c.K.cy = f.cy;
    c.source = "--fx --fy --cx --cy";
  } else if (f.given == 0 && seq.intrinsics) {
    c.K = *seq.intrinsics;
    c.source = seq.intrinsics_source;
  } else {
    const std::string hint = folderCameraHint(dir);
    throw std::invalid_argument(
        std::string(f.given == 0 ? "no intrinsics (" + dir + ", " + seq.layout +
                                       ", has no intrinsics file): "
                                 : "--fx --fy --cx --cy go together: ") +
        "give --camera fr1|fr2|fr3 or all of --fx --fy --cx --cy" +
        (hint.empty() ? ""
                      : " (" + dir + " looks like a " + hint + " sequence: --camera " + hint +
                            ")"));
  }
  c.K.width = c.K.height = 0;
  return c;
}

}  // namespace depth_track
