// tum_to_bag: turns a recorded sequence folder (TUM RGB-D: depth.txt, depth/*.png, groundtruth.txt;
// or 7-Scenes: frame-*.depth.png, frame-*.pose.txt) into a bag with the topic layout of the
// scenario bags (tools/ros/tum_bag.hpp), so a recorded sequence is replayed and evaluated like a
// rig run. Offline: no roscore, no wall clock; the depth PNGs go into the bag as they are (16UC1 in
// the folder's units, the unit recorded as depth_scale_m), but for a layout's own "no return"
// value (7-Scenes: 65535), which becomes 0 (REP 118).
//
//   tum_to_bag DIR OUT.bag [--camera fr1|fr2|fr3 | --fx F --fy F --cx C --cy C] [--depth-scale S]
//              [--compression none|lz4|bz2] [--max-frames N] [--no-ground-truth] [--overwrite]
//
// The bag is written next to OUT.bag as OUT.bag.part and renamed when complete: a failure leaves
// neither a half-written bag nor a damaged earlier one.
#include <rosbag/bag.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include "../sequence_intrinsics.hpp"
#include "depth_track/core/servotrack_kinematics.hpp"
#include "depth_track/core/tum_io.hpp"
#include "tum_bag.hpp"

namespace fs = std::filesystem;
using namespace depth_track;

namespace {

constexpr const char* kCaller = "/tum_to_bag";

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string fmt(double v) {
  std::ostringstream s;
  s.precision(10);
  s << v;
  return s.str();
}


// Fails unless stamps increase strictly: a reader pairs frames and poses by time.
template <class Items, class StampOf, class Describe>
void requireIncreasing(const Items& items, StampOf stamp_of, Describe describe) {
  for (std::size_t i = 1; i < items.size(); ++i)
    if (!(stamp_of(items[i]) > stamp_of(items[i - 1])))
      throw FileFormatError(describe(i) + ": stamp " + fmt(stamp_of(items[i])) +
                            " is not after the one before it (" + fmt(stamp_of(items[i - 1])) +
                            "); entries must be in time order");
}

bool hostIsBigEndian() {
  const std::uint16_t one = 1;
  unsigned char first = 0;
  std::memcpy(&first, &one, 1);
  return first == 0;
}

// Removes the partial output unless the bag was completed.
class PartialFile {
 public:
  explicit PartialFile(std::string path) : path_(std::move(path)) {}
  ~PartialFile() {
    if (!done_) {
      std::error_code ec;
      fs::remove(path_, ec);
    }
  }
  void done() { done_ = true; }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  bool done_ = false;
};

int run(int argc, char** argv) {
  CLI::App app{
      "Writes a recorded sequence folder (TUM RGB-D: depth.txt, depth/*.png, groundtruth.txt; or "
      "7-Scenes: frame-*.depth.png, frame-*.pose.txt) as a bag: "
      "/camera/image_rect (16UC1, the folder's units; connection header depth_scale_m), "
      "/camera/camera_info, /ground_truth/camera_pose (PoseStamped, frame map) and /tf_static."};
  std::string dir, out, camera, compression = "lz4";
  double fx = 0, fy = 0, cx = 0, cy = 0, depth_scale = 0.0;
  int max_frames = 0;
  bool no_gt = false, overwrite = false;
  app.add_option("DIR", dir, "sequence folder (TUM RGB-D or 7-Scenes layout)")->required();
  app.add_option("OUT", out, "bag to write")->required();
  auto* cam_opt =
      app.add_option("--camera", camera, "TUM camera: fr1 | fr2 | fr3 (the published calibration)");
  std::vector<CLI::Option*> k_opts = {app.add_option("--fx", fx, "focal length x, px"),
                                      app.add_option("--fy", fy, "focal length y, px"),
                                      app.add_option("--cx", cx, "principal point x, px"),
                                      app.add_option("--cy", cy, "principal point y, px")};
  for (auto* o : k_opts) o->excludes(cam_opt);
  auto* scale_opt = app.add_option(
      "--depth-scale", depth_scale,
      "metres per 16-bit depth unit (default: the folder's own: TUM 0.0002, 7-Scenes 0.001, or "
      "intrinsics.txt's)");
  app.add_option("--compression", compression, "none | lz4 | bz2")
      ->check(CLI::IsMember({"none", "lz4", "bz2"}))
      ->capture_default_str();
  app.add_option("--max-frames", max_frames, "write at most this many depth frames (0 = all)")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--no-ground-truth", no_gt,
               "write depth only (for a folder without ground truth)");
  app.add_flag("--overwrite", overwrite, "replace OUT if it exists");
  CLI11_PARSE(app, argc, argv);

  // ---- everything the user gave, checked before anything is read or written
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw UsageError(dir + ": " + (fs::exists(dir, ec) ? "not a folder" : "no such folder"));
  DepthSequence seq = readDepthSequence(dir);
  const IntrinsicsFlags flags{
      fx, fy, cx, cy,
      static_cast<int>(std::count_if(k_opts.begin(), k_opts.end(),
                                     [](const CLI::Option* o) { return o->count() > 0; }))};
  PinholeIntrinsics K;
  try {
    K = chooseIntrinsics(seq, dir, camera, flags).K;
  } catch (const std::invalid_argument& e) {
    throw UsageError(e.what());
  }
  if (scale_opt->count() == 0) depth_scale = seq.depth_scale_m;
  if (!(depth_scale > 0.0 && depth_scale <= 1.0))
    throw UsageError(
        "--depth-scale " + fmt(depth_scale) +
        ": expected metres per unit in (0, 1]; a value above 1 looks like units per metre (TUM: "
        "0.0002 = 1/5000)");
  if (fs::exists(out, ec) && !overwrite)
    throw UsageError(out + " exists; not overwritten (--overwrite replaces it)");
  const fs::path out_dir = fs::absolute(out).parent_path();
  if (!fs::is_directory(out_dir, ec))
    throw UsageError(out_dir.string() + ": no such folder for OUT");

  // ---- the folder: frame list, ground truth, image size (errors name file and line)
  std::vector<TumFrame>& frames = seq.frames;
  if (frames.empty()) throw FileFormatError(seq.frames_source + " lists no frames");
  requireIncreasing(
      frames, [](const TumFrame& f) { return f.stamp_s; },
      [&](std::size_t i) {
        return seq.frames_source + ": frame " + std::to_string(i + 1) + " (" +
               fs::path(frames[i].path).filename().string() + ")";
      });
  const bool cut = max_frames > 0 && static_cast<std::size_t>(max_frames) < frames.size();
  if (cut) frames.resize(max_frames);

  Trajectory gt;
  if (!no_gt) {
    if (seq.ground_truth.empty())
      throw FileFormatError(
          (seq.layout == "7-Scenes" ? dir + "/frame-*.pose.txt: none found"
                                    : dir + "/groundtruth.txt: missing") +
          " (the folder's ground truth; --no-ground-truth writes a bag of depth only, "
          "which can be tracked but not scored)");
    gt = std::move(seq.ground_truth);
    requireIncreasing(
        gt, [](const StampedPose& p) { return p.stamp_s; },
        [&](std::size_t i) { return seq.ground_truth_source + ": pose " + std::to_string(i + 1); });
    if (cut) {  // a cut sequence keeps the ground truth that can still pair with its frames
      const double t_end = frames.back().stamp_s + 0.02;
      gt.erase(std::find_if(gt.begin(), gt.end(),
                            [&](const StampedPose& p) { return p.stamp_s > t_end; }),
               gt.end());
    }
  }
  {
    int w = 0, h = 0;
    readPng16(frames.front().path, &w, &h);
    K.width = w, K.height = h;
  }
  const auto k_problems = K.validate();
  if (!k_problems.empty()) throw UsageError("intrinsics: " + joinProblems(k_problems));

  // ---- the bag, in time order: tf_static, then depth frames and poses merged by stamp
  PartialFile part(out + ".part");
  rosbag::Bag bag;
  bag.open(part.path(), rosbag::bagmode::Write);
  if (compression == "lz4") bag.setCompression(rosbag::compression::LZ4);
  if (compression == "bz2") bag.setCompression(rosbag::compression::BZ2);

  // A bag cannot hold time 0, where a 7-Scenes folder's stamps (i / 30 s) begin: such a run is
  // written 1 s later, frames and ground truth alike (said on the last line).
  double shift_s = 0.0;
  if ((gt.empty() ? frames.front().stamp_s
                  : std::min(frames.front().stamp_s, gt.front().stamp_s)) < 1.0) {
    shift_s = 1.0;
    for (TumFrame& f : frames) f.stamp_s += shift_s;
    for (StampedPose& p : gt) p.stamp_s += shift_s;
  }
  const double t0 =
      gt.empty() ? frames.front().stamp_s : std::min(frames.front().stamp_s, gt.front().stamp_s);
  {
    tf2_msgs::TFMessage st;
    Eigen::Isometry3d T_L_O = Eigen::Isometry3d::Identity();
    T_L_O.linear() = rotationBodyFromOptical();
    // A hand-held camera: base_link is the camera body itself.
    st.transforms = {
        tum_bag::transformStamped(ros::Time(t0), "base_link", "camera_link",
                                  Eigen::Isometry3d::Identity()),
        tum_bag::transformStamped(ros::Time(t0), "camera_link", tum_bag::kOpticalFrame, T_L_O)};
    auto hdr = tum_bag::connectionHeader<tf2_msgs::TFMessage>(kCaller, {{"latching", "1"}});
    bag.write(tum_bag::kTfStaticTopic, ros::Time(t0), st, hdr);
  }
  const std::map<std::string, std::string> scale_field = {
      {tum_bag::kDepthScaleKey, fmt(depth_scale)}};
  const auto image_hdr = tum_bag::connectionHeader<sensor_msgs::Image>(kCaller, scale_field);
  const auto info_hdr = tum_bag::connectionHeader<sensor_msgs::CameraInfo>(kCaller, scale_field);
  const auto pose_hdr = tum_bag::connectionHeader<geometry_msgs::PoseStamped>(kCaller, {});

  std::size_t fi = 0, gi = 0;
  while (fi < frames.size() || gi < gt.size()) {
    if (gi < gt.size() && (fi == frames.size() || gt[gi].stamp_s < frames[fi].stamp_s)) {
      const ros::Time t(gt[gi].stamp_s);
      geometry_msgs::PoseStamped pose;
      pose.header.stamp = t;
      pose.header.frame_id = tum_bag::kMapFrame;
      pose.header.seq = static_cast<uint32_t>(gi);
      pose.pose = conv::toPoseMsg(gt[gi++].T_W_C);
      bag.write(tum_bag::kGroundTruthTopic, t, pose, pose_hdr);
      continue;
    }
    const TumFrame& f = frames[fi];
    int w = 0, h = 0;
    const std::vector<std::uint16_t> raw = readSequenceDepthRaw(seq, fi, &w, &h);
    if (w != K.width || h != K.height)
      throw FileFormatError(f.path + ": " + std::to_string(w) + "x" + std::to_string(h) +
                            " image, the first frame is " + std::to_string(K.width) + "x" +
                            std::to_string(K.height));
    const ros::Time t(f.stamp_s);
    sensor_msgs::Image img;
    img.header.stamp = t;
    img.header.seq = static_cast<uint32_t>(fi);
    img.header.frame_id = tum_bag::kOpticalFrame;
    img.width = w;
    img.height = h;
    img.encoding = "16UC1";
    img.is_bigendian = hostIsBigEndian() ? 1 : 0;  // readPng16 gives host byte order
    img.step = 2 * w;
    img.data.resize(raw.size() * 2);
    std::memcpy(img.data.data(), raw.data(), img.data.size());
    bag.write(tum_bag::kDepthTopic, t, img, image_hdr);
    auto info = tum_bag::cameraInfoMsg(K, t, tum_bag::kOpticalFrame);
    info.header.seq = img.header.seq;
    bag.write(tum_bag::kInfoTopic, t, info, info_hdr);
    ++fi;
  }
  bag.close();
  fs::rename(part.path(), out);
  part.done();

  std::vector<double> frame_s, gt_s;
  for (const auto& f : frames) frame_s.push_back(f.stamp_s);
  for (const auto& p : gt) gt_s.push_back(p.stamp_s);
  const std::size_t paired = gt.empty() ? 0 : associateStamps(frame_s, gt_s).size();
  std::printf(
      "tum_to_bag: %zu depth frames %dx%d (fx=%g fy=%g cx=%g cy=%g, %g m per unit), %zu "
      "ground-truth "
      "poses (%zu of %zu frames have one within 20 ms) -> %s (%.1f MB)%s\n",
      frames.size(), K.width, K.height, K.fx, K.fy, K.cx, K.cy, depth_scale, gt.size(), paired,
      frames.size(), out.c_str(), static_cast<double>(fs::file_size(out)) / 1e6,
      shift_s > 0.0 ? "; stamps written 1 s later than the folder's (a bag cannot hold time 0)"
                    : "");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << "tum_to_bag: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "tum_to_bag: " << e.what() << "\n";
    return 1;
  }
}
