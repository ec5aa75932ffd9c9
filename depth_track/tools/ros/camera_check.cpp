// camera_check: characterises a depth camera from recordings of a target at known distances (the
// thesis's §4.1 tests): depth bias against laser-measured distances, temporal and spatial noise,
// drop-outs, the focal constant CAM_K from a round target's diameter, lateral resolution from the
// spread of its outline; then fits the renderer's noise model and a depth correction and writes
// them as YAML (core: depth_track/core/camera_check.hpp; docs/camera_check.md).
//
//   camera_check INPUT [INPUT ...] [--distances D1,D2,...] [--diameter M] [--out FILE.yaml]
//                [--plots DIR] [--segment T0:T1 ...] [--depth-topic T] [--info-topic T]
//                [--depth-scale S] [--fx F --fy F --cx C --cy C | --camera fr1|fr2|fr3]
//
// INPUT: a bag with a depth image topic (16UC1 or 32FC1) and camera_info (read with the rosbag
// API: no roscore), or a TUM-layout folder (depth.txt + 16-bit PNGs; intrinsics by option). Each
// input is split into the periods in which the camera stood still (or into --segment ranges);
// --distances gives the laser-measured distance of each segment in order. Offline, no wall clock.
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sys/wait.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "depth_track/core/camera_check.hpp"
#include "depth_track/core/sim/noise.hpp"
#include "depth_track/core/tum_cameras.hpp"
#include "depth_track/core/tum_io.hpp"
#include "depth_track/ros/conversions.hpp"
#include "tum_bag.hpp"

#ifndef DT_SCRIPTS_DIR
#define DT_SCRIPTS_DIR ""
#endif

namespace fs = std::filesystem;
using namespace depth_track;

namespace {

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

/// Depths are taken as the camera delivers them: only no-return values (0, NaN, Inf) are dropped.
const DepthRange kWideRange{0.01, 100.0};

/// One recording: its frames by stamp, loaded on demand (a recording can be far larger than
/// memory; a segment is loaded, measured and dropped).
class Recording {
 public:
  virtual ~Recording() = default;
  std::string name;
  PinholeIntrinsics intrinsics;
  double depth_unit_m = 0.0;   ///< 16-bit unit, 0 for float depth
  std::vector<double> stamps;  ///< seconds
  std::vector<double> centre;  ///< central depth of every frame (for still periods), m
  /// The frames with these indices (ascending), in order.
  virtual std::vector<DepthImage> load(const std::vector<std::size_t>& which) = 0;
};

class BagRecording : public Recording {
 public:
  BagRecording(const std::string& path, std::string depth_topic, std::string info_topic,
               double depth_scale_option) {
    name = path;
    try {
      bag_.open(path, rosbag::bagmode::Read);
    } catch (const rosbag::BagException& e) {
      throw UsageError(path + ": cannot read the bag (" + e.what() + ")");
    }
    // The depth and camera_info topics: as given, or the only ones of their type.
    std::vector<std::string> images, infos;
    rosbag::View all(bag_);
    std::map<std::string, std::string> types;
    for (const rosbag::ConnectionInfo* c : all.getConnections()) {
      types[c->topic] = c->datatype;
      if (c->datatype == "sensor_msgs/Image" &&
          std::find(images.begin(), images.end(), c->topic) == images.end())
        images.push_back(c->topic);
      if (c->datatype == "sensor_msgs/CameraInfo" &&
          std::find(infos.begin(), infos.end(), c->topic) == infos.end())
        infos.push_back(c->topic);
    }
    auto list = [](const std::vector<std::string>& v) {
      std::string s;
      for (const auto& t : v) s += (s.empty() ? "" : ", ") + t;
      return s.empty() ? std::string("none") : s;
    };
    if (depth_topic.empty()) {
      if (std::find(images.begin(), images.end(), tum_bag::kDepthTopic) != images.end())
        depth_topic = tum_bag::kDepthTopic;
      else if (images.size() == 1)
        depth_topic = images.front();
      else
        throw UsageError(path + ": " +
                         (images.empty() ? std::string("holds no sensor_msgs/Image topic")
                                         : "holds several image topics (" + list(images) +
                                               "): choose one with --depth-topic"));
    } else if (!types.count(depth_topic) || types[depth_topic] != "sensor_msgs/Image") {
      throw UsageError(path + ": --depth-topic " + depth_topic +
                       (types.count(depth_topic) ? " is a " + types[depth_topic]
                                                 : std::string(" is not in the bag")) +
                       " (image topics: " + list(images) + ")");
    }
    if (info_topic.empty()) {
      const std::string sibling =
          depth_topic.substr(0, depth_topic.find_last_of('/') + 1) + "camera_info";
      if (std::find(infos.begin(), infos.end(), sibling) != infos.end())
        info_topic = sibling;
      else if (infos.size() == 1)
        info_topic = infos.front();
      else
        throw UsageError(path + ": " +
                         (infos.empty()
                              ? std::string("holds no sensor_msgs/CameraInfo topic (needed for "
                                            "the intrinsics)")
                              : "holds several camera_info topics (" + list(infos) +
                                    "): choose one with --info-topic"));
    } else if (!types.count(info_topic) || types[info_topic] != "sensor_msgs/CameraInfo") {
      throw UsageError(path + ": --info-topic " + info_topic + " is not a CameraInfo topic (" +
                       list(infos) + ")");
    }
    depth_topic_ = depth_topic;

    {
      rosbag::View info_view(bag_, rosbag::TopicQuery(info_topic));
      for (const rosbag::MessageInstance& m : info_view) {
        const auto ci = m.instantiate<sensor_msgs::CameraInfo>();
        if (!ci) continue;
        try {
          intrinsics = conv::intrinsicsFromCameraInfo(*ci);
        } catch (const DepthInputError& e) {
          throw DepthInputError(path + ": " + info_topic + ": " + e.what());
        }
        have_info_ = true;
        break;
      }
      if (!have_info_) throw UsageError(path + ": " + info_topic + " holds no message");
    }

    // Pass 1: stamps, central depths, and the encoding and unit checked once on every frame.
    rosbag::View view(bag_, rosbag::TopicQuery(depth_topic_));
    std::optional<double> recorded_scale;
    for (const rosbag::ConnectionInfo* c : view.getConnections())
      if (c->header)
        if (const auto s = tum_bag::depthScaleOf(*c->header)) recorded_scale = *s;
    scale_ = depth_scale_option > 0.0 ? depth_scale_option : recorded_scale.value_or(0.001);
    std::size_t index = 0;
    for (const rosbag::MessageInstance& m : view) {
      const auto img = m.instantiate<sensor_msgs::Image>();
      if (!img) continue;
      const std::string where = path + ": " + depth_topic_ + " message " + std::to_string(index);
      if (index == 0) {
        float_ = img->encoding == "32FC1";
        if (!float_ && !recorded_scale && !(depth_scale_option > 0.0))
          std::fprintf(stderr,
                       "camera_check: %s: no depth unit recorded for %s (%s): assuming 1 mm per "
                       "unit (REP 118); --depth-scale overrides\n",
                       path.c_str(), depth_topic_.c_str(), img->encoding.c_str());
      }
      const DepthImage d = decode(*img, where);
      stamps.push_back(img->header.stamp.isZero() ? m.getTime().toSec()
                                                  : img->header.stamp.toSec());
      centre.push_back(centralDepth(d, intrinsics));
      ++index;
    }
    if (stamps.empty()) throw UsageError(path + ": " + depth_topic_ + " holds no image");
    depth_unit_m = float_ ? 0.0 : scale_;
  }

  std::vector<DepthImage> load(const std::vector<std::size_t>& which) override {
    std::vector<DepthImage> out;
    std::size_t index = 0, next = 0;
    rosbag::View view(bag_, rosbag::TopicQuery(depth_topic_));
    for (const rosbag::MessageInstance& m : view) {
      if (next == which.size()) break;
      if (index++ != which[next]) continue;
      ++next;
      const auto img = m.instantiate<sensor_msgs::Image>();
      out.push_back(
          decode(*img, name + ": " + depth_topic_ + " message " + std::to_string(index - 1)));
    }
    return out;
  }

 private:
  DepthImage decode(const sensor_msgs::Image& img, const std::string& where) const {
    try {
      if ((img.encoding == "32FC1") != float_)
        throw DepthInputError("encoding changes to " + img.encoding + " within the topic");
      conv::checkImageMatchesInfo(img, intrinsics);
      return conv::depthFromMsg(img, scale_, kWideRange);
    } catch (const DepthInputError& e) {
      throw DepthInputError(where + ": " + e.what());
    }
  }

  rosbag::Bag bag_;
  std::string depth_topic_;
  bool have_info_ = false;
  bool float_ = false;
  double scale_ = 0.001;
};

class TumRecording : public Recording {
 public:
  TumRecording(const std::string& dir, const PinholeIntrinsics& K, double scale) {
    name = dir;
    scale_ = scale;
    depth_unit_m = scale;
    frames_ = readTumFrameList(dir + "/depth.txt");
    if (frames_.empty()) throw UsageError(dir + "/depth.txt lists no frames");
    int w = 0, h = 0;
    readPng16(frames_.front().path, &w, &h);
    intrinsics = K;
    intrinsics.width = w, intrinsics.height = h;
    const auto problems = intrinsics.validate();
    if (!problems.empty()) throw UsageError(dir + ": intrinsics: " + joinProblems(problems));
    for (const TumFrame& f : frames_) {
      stamps.push_back(f.stamp_s);
      centre.push_back(centralDepth(frame(f.path), intrinsics));
    }
  }

  std::vector<DepthImage> load(const std::vector<std::size_t>& which) override {
    std::vector<DepthImage> out;
    for (std::size_t i : which) out.push_back(frame(frames_[i].path));
    return out;
  }

 private:
  DepthImage frame(const std::string& png) const {
    DepthImage d = loadTumDepth(png, scale_, kWideRange);
    if (d.width != intrinsics.width || d.height != intrinsics.height)
      throw FileFormatError(png + ": " + std::to_string(d.width) + "x" + std::to_string(d.height) +
                            " image, the first frame is " + std::to_string(intrinsics.width) + "x" +
                            std::to_string(intrinsics.height));
    return d;
  }

  std::vector<TumFrame> frames_;
  double scale_ = kTumDepthScaleM;
};

/// A segment to measure: which recording, which frames.
struct Plan {
  Recording* rec = nullptr;
  std::string label;
  std::size_t first = 0, last = 0;  ///< frame indices, inclusive
  double t0 = 0.0, t1 = 0.0;        ///< seconds from the recording's first frame
  double centre_m = 0.0;            ///< median central depth
};

std::vector<double> parseList(const std::string& text, const std::string& option) {
  std::vector<double> out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    char* end = nullptr;
    const double v = std::strtod(item.c_str(), &end);
    if (item.empty() || *end != '\0' || !(v > 0.0) || !std::isfinite(v))
      throw UsageError(option + ": '" + item + "' is not a positive distance in metres");
    out.push_back(v);
  }
  return out;
}

std::string describe(const std::vector<Plan>& plans) {
  std::ostringstream o;
  for (const Plan& p : plans)
    o << "  " << p.label << ": " << p.rec->name << " t " << fmt("%.2f", p.t0) << "-"
      << fmt("%.2f", p.t1) << " s, frames " << p.first << "-" << p.last << ", central depth "
      << fmt("%.3f", p.centre_m) << " m\n";
  return o.str();
}

int runPlots(const std::string& script, const std::string& yaml, const std::string& dir,
             const std::string& csv) {
  std::fflush(stdout);  // our lines before the script's
  const std::string cmd =
      "/usr/bin/python3 '" + script + "' '" + yaml + "' '" + dir + "' --edge-csv '" + csv + "'";
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

int run(int argc, char** argv) {
  CLI::App app{
      "Characterise a depth camera from recordings of a target (a round disc of known diameter "
      "in front of a wall, or a flat wall) at laser-measured distances: depth bias, noise, "
      "drop-outs, CAM_K, lateral resolution; writes the fitted noise model and depth correction "
      "as YAML."};
  std::vector<std::string> inputs;
  std::string distances_text, out_path, plots_dir, depth_topic, info_topic, camera;
  std::string base_model = "l515";
  std::vector<std::string> segment_texts;
  double diameter = 0.0, depth_scale = 0.0, min_still_s = 1.0, trim_s = 0.2;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  int max_frames = 150;
  CameraCheckConfig cfg;
  app.add_option("INPUT", inputs, "bag(s) or TUM-layout folder(s)")->required();
  app.add_option("--distances", distances_text,
                 "laser-measured distance of each segment along the optical axis, m, in order "
                 "(comma-separated)");
  app.add_option("--diameter", diameter,
                 "round target's diameter, m (none: flat wall, no focal check)");
  app.add_option("--out", out_path, "write the report (noise model, depth correction) here (YAML)");
  app.add_option("--plots", plots_dir, "write PNG plots into this folder (matplotlib)");
  app.add_option("--segment", segment_texts,
                 "T0:T1 seconds from the recording's first frame (repeatable; one INPUT); "
                 "default: the periods the camera stood still");
  app.add_option("--min-still", min_still_s, "shortest still period, s")->capture_default_str();
  app.add_option("--trim", trim_s, "frames this close to a still period's ends are left out, s")
      ->capture_default_str();
  app.add_option("--max-frames", max_frames, "frames measured per segment (evenly spread)")
      ->capture_default_str();
  app.add_option("--depth-topic", depth_topic,
                 "depth image topic (default: /camera/image_rect or the only image topic)");
  app.add_option("--info-topic", info_topic,
                 "camera_info topic (default: next to the depth topic)");
  app.add_option("--depth-scale", depth_scale,
                 "metres per 16-bit unit (default: the bag's depth_scale_m, else 0.001 (REP 118); "
                 "TUM folders 0.0002)");
  auto* cam_opt = app.add_option("--camera", camera, "TUM folder intrinsics: fr1 | fr2 | fr3");
  std::vector<CLI::Option*> k_opts = {
      app.add_option("--fx", fx, "TUM folder: focal length x, px"),
      app.add_option("--fy", fy, "TUM folder: focal length y, px"),
      app.add_option("--cx", cx, "TUM folder: principal point x, px"),
      app.add_option("--cy", cy, "TUM folder: principal point y, px")};
  for (auto* o : k_opts) o->excludes(cam_opt);
  app.add_option("--seed-u", cfg.seed_u_px, "column the target is looked for at (default: cx)");
  app.add_option("--seed-v", cfg.seed_v_px, "row the target is looked for at (default: cy)");
  app.add_option("--base-model", base_model,
                 "noise preset the written model takes unmeasured effects from: l515 | d435 | none")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  // ---- options checked before anything is read
  sim::parseNoiseModel(base_model);  // names the accepted presets when wrong
  if (!(diameter >= 0.0 && diameter < 10.0)) throw UsageError("--diameter must be in [0, 10) m");
  if (max_frames < 2) throw UsageError("--max-frames must be >= 2");
  if (!(min_still_s > 0.0)) throw UsageError("--min-still must be > 0 s");
  if (!(trim_s >= 0.0)) throw UsageError("--trim must be >= 0 s");
  if (!segment_texts.empty() && inputs.size() != 1)
    throw UsageError("--segment ranges apply to one INPUT (" + std::to_string(inputs.size()) +
                     " given)");
  const std::vector<double> distances =
      distances_text.empty() ? std::vector<double>{} : parseList(distances_text, "--distances");
  cfg.target_diameter_m = diameter;
  if (!out_path.empty() && fs::is_directory(out_path))
    throw UsageError("--out " + out_path + " is a folder; give a file name");
  const int k_given = static_cast<int>(std::count_if(
      k_opts.begin(), k_opts.end(), [](const CLI::Option* o) { return o->count() > 0; }));
  if (k_given != 0 && k_given != 4) throw UsageError("--fx --fy --cx --cy go together");

  // ---- recordings
  std::vector<std::unique_ptr<Recording>> recs;
  for (const std::string& in : inputs) {
    std::error_code ec;
    if (fs::is_directory(in, ec)) {
      PinholeIntrinsics K;
      if (!camera.empty()) {
        const auto k = tumIntrinsics(camera);
        if (!k) throw UsageError("--camera '" + camera + "': expected fr1, fr2 or fr3");
        K = *k;
      } else if (k_given == 4) {
        K.fx = fx, K.fy = fy, K.cx = cx, K.cy = cy;
      } else {
        throw UsageError(in +
                         " is a TUM-layout folder: give its intrinsics (--fx --fy --cx --cy, "
                         "or --camera fr1|fr2|fr3)");
      }
      recs.push_back(
          std::make_unique<TumRecording>(in, K, depth_scale > 0.0 ? depth_scale : kTumDepthScaleM));
    } else if (fs::is_regular_file(in, ec)) {
      recs.push_back(std::make_unique<BagRecording>(in, depth_topic, info_topic, depth_scale));
    } else {
      throw UsageError(in + ": no such bag or folder");
    }
  }

  // ---- segments: the given ranges, or each recording's still periods
  std::vector<Plan> plans;
  for (auto& rec : recs) {
    const double t_first = rec->stamps.front();
    const double t_last = rec->stamps.back() - t_first;
    if (!segment_texts.empty()) {
      for (const std::string& s : segment_texts) {
        const auto colon = s.find(':');
        char* e1 = nullptr;
        char* e2 = nullptr;
        const double a = colon == std::string::npos ? NAN : std::strtod(s.c_str(), &e1);
        const double b = colon == std::string::npos ? NAN : std::strtod(s.c_str() + colon + 1, &e2);
        if (colon == std::string::npos || e1 != s.c_str() + colon || *e2 != '\0' || !(b > a))
          throw UsageError("--segment '" + s + "': expected T0:T1 with T0 < T1 (seconds)");
        Plan p;
        p.rec = rec.get();
        p.label = "seg " + std::to_string(plans.size() + 1);
        p.t0 = a, p.t1 = b;
        bool any = false;
        std::vector<double> c;
        for (std::size_t i = 0; i < rec->stamps.size(); ++i) {
          const double t = rec->stamps[i] - t_first;
          if (t < a || t > b) continue;
          if (!any) p.first = i;
          p.last = i;
          any = true;
          if (rec->centre[i] > 0.0) c.push_back(rec->centre[i]);
        }
        if (!any)
          throw UsageError("--segment " + s + ": no frames in this time range (" + rec->name +
                           " spans 0-" + fmt("%.2f", t_last) + " s)");
        std::sort(c.begin(), c.end());
        p.centre_m = c.empty() ? 0.0 : c[c.size() / 2];
        plans.push_back(p);
      }
      continue;
    }
    const std::vector<StillPeriod> still = findStillPeriods(rec->stamps, rec->centre, min_still_s);
    if (still.empty()) {
      double lo = 1e9, hi = 0.0;
      for (double c : rec->centre)
        if (c > 0.0) lo = std::min(lo, c), hi = std::max(hi, c);
      throw UsageError(rec->name + ": no still period of " + fmt("%.1f", min_still_s) +
                       " s or more (the central depth " +
                       (hi > 0.0 ? "ranges " + fmt("%.3f", lo) + "-" + fmt("%.3f", hi) + " m"
                                 : std::string("has no return in any frame")) +
                       "); give --segment ranges or a shorter --min-still");
    }
    for (const StillPeriod& sp : still) {
      Plan p;
      p.rec = rec.get();
      p.label = "seg " + std::to_string(plans.size() + 1);
      p.first = sp.first, p.last = sp.last;
      // Settling at the ends: drop trim_s at each end unless that leaves too little.
      while (p.first < p.last && rec->stamps[p.first] - rec->stamps[sp.first] < trim_s &&
             rec->stamps[sp.last] - rec->stamps[p.first] > 2 * trim_s)
        ++p.first;
      while (p.last > p.first && rec->stamps[sp.last] - rec->stamps[p.last] < trim_s &&
             rec->stamps[p.last] - rec->stamps[p.first] > trim_s)
        --p.last;
      p.t0 = rec->stamps[p.first] - t_first, p.t1 = rec->stamps[p.last] - t_first;
      p.centre_m = sp.depth_m;
      plans.push_back(p);
    }
  }
  if (!distances.empty() && distances.size() != plans.size())
    throw UsageError("--distances gives " + std::to_string(distances.size()) +
                     " distances for the " + std::to_string(plans.size()) + " segments found:\n" +
                     describe(plans) +
                     "(adjust --distances, --min-still or give --segment ranges)");
  std::printf("camera_check: %zu segments\n%s", plans.size(), describe(plans).c_str());

  // ---- measure segment by segment (only one segment's frames in memory)
  std::vector<SegmentResult> results;
  double unit = 0.0;
  for (const auto& rec : recs) unit = std::max(unit, rec->depth_unit_m);
  cfg.depth_unit_m = unit;
  for (std::size_t k = 0; k < plans.size(); ++k) {
    const Plan& p = plans[k];
    std::vector<std::size_t> which;
    const std::size_t n = p.last - p.first + 1;
    const std::size_t take = std::min<std::size_t>(n, max_frames);
    for (std::size_t j = 0; j < take; ++j) which.push_back(p.first + j * n / take);
    SegmentFrames seg;
    seg.label = p.label;
    seg.t_start_s = p.t0, seg.t_end_s = p.t1;
    if (!distances.empty()) seg.reference_distance_m = distances[k];
    seg.frames = p.rec->load(which);
    try {
      results.push_back(measureSegment(seg, p.rec->intrinsics, cfg));
    } catch (const CameraCheckError& e) {
      throw CameraCheckError(p.rec->name + ": " + e.what());
    }
  }
  const CameraCheckFit fit = fitCameraModel(results, cfg);
  std::printf("%s", formatCameraCheckTable(results, fit, cfg).c_str());

  // ---- files
  CameraCheckReport rep;
  for (const auto& rec : recs) rep.source += (rep.source.empty() ? "" : ", ") + rec->name;
  rep.intrinsics = recs.front()->intrinsics;
  rep.config = cfg;
  rep.segments = results;
  rep.fit = fit;
  rep.base_model = base_model;
  for (sim::NoiseModel m : {sim::NoiseModel::kL515, sim::NoiseModel::kD435}) {
    const sim::NoiseConfig c = sim::NoiseConfig::forModel(m);
    rep.reference_models.push_back(
        {sim::noiseModelName(m), c.sigma_const_m, c.sigma_linear, c.sigma_quad_per_m});
  }
  std::string yaml = out_path;
  if (!plots_dir.empty()) {
    std::error_code ec;
    fs::create_directories(plots_dir, ec);
    if (!fs::is_directory(plots_dir)) throw UsageError("--plots " + plots_dir + ": cannot create");
    if (yaml.empty()) yaml = (fs::path(plots_dir) / "camera_check.yaml").string();
  }
  if (!yaml.empty()) {
    writeCameraCheckYaml(yaml, rep);
    std::printf("camera_check: report written to %s\n", yaml.c_str());
  }
  if (!plots_dir.empty()) {
    const std::string csv = (fs::path(plots_dir) / "edge_spread.csv").string();
    writeEdgeSpreadCsv(csv, results);
    const char* env = std::getenv("DT_CAMERA_CHECK_PLOT");
    const std::string script = env ? env : std::string(DT_SCRIPTS_DIR) + "/camera_check_plot.py";
    const int rc = runPlots(script, yaml, plots_dir, csv);
    if (rc != 0)
      throw std::runtime_error("the plot script " + script + " failed (exit " + std::to_string(rc) +
                               "); the report " + yaml + " is kept");
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const UsageError& e) {
    std::fprintf(stderr, "camera_check: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "camera_check: %s\n", e.what());
    return 1;
  }
}
