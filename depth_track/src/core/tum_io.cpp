#include "depth_track/core/tum_io.hpp"

#include "depth_track/core/png16.hpp"

#include <sys/stat.h>
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <memory>
#include <numeric>
#include <sstream>

#include <Eigen/SVD>

namespace depth_track {
namespace {

struct FileCloser {
  void operator()(std::FILE* f) const {
    if (f != nullptr) std::fclose(f);
  }
};
using FilePtr = std::unique_ptr<std::FILE, FileCloser>;

// ---- text parsing
// ---------------------------------------------------------------------------------
std::string where(const std::string& path, int line) {
  return path + ":" + std::to_string(line) + ": ";
}

// Splits on whitespace and commas.
std::vector<std::string> tokens(const std::string& line) {
  std::vector<std::string> out;
  std::string cur;
  for (char c : line) {
    if (c == ' ' || c == '\t' || c == ',' || c == '\r' || c == '\n') {
      if (!cur.empty()) out.push_back(cur);
      cur.clear();
    } else {
      cur.push_back(c);
    }
  }
  if (!cur.empty()) out.push_back(cur);
  return out;
}

bool isCommentOrBlank(const std::string& line) {
  const auto first = line.find_first_not_of(" \t\r\n");
  return first == std::string::npos || line[first] == '#';
}

// Parses a whole token as a finite double.
bool parseFinite(const std::string& token, double* value) {
  errno = 0;
  char* end = nullptr;
  *value = std::strtod(token.c_str(), &end);
  return end != token.c_str() && *end == '\0' && errno != ERANGE && std::isfinite(*value);
}

bool fileExists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode);
}

std::string folderOf(const std::string& path) {
  const auto slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

std::ifstream openText(const std::string& path, const char* what) {
  std::ifstream in(path);
  if (!in)
    throw FileFormatError(path + ": cannot open " + what + " (" + std::strerror(errno) + ")");
  return in;
}

// The number rows of a small text file (comments and blank lines skipped), each with its line
// number. Every field must be a finite number.
struct NumberRow {
  int line_no = 0;
  std::vector<double> values;
};
std::vector<NumberRow> readNumberRows(const std::string& path, const char* what) {
  std::ifstream in = openText(path, what);
  std::vector<NumberRow> rows;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (isCommentOrBlank(line)) continue;
    NumberRow row;
    row.line_no = line_no;
    for (const std::string& t : tokens(line)) {
      double v = 0.0;
      if (!parseFinite(t, &v))
        throw FileFormatError(where(path, line_no) + "'" + t + "' is not a finite number");
      row.values.push_back(v);
    }
    rows.push_back(std::move(row));
  }
  return rows;
}

// Requires `rows` x `cols` numbers; the message names the file's layout.
void requireShape(const std::vector<NumberRow>& rows, std::size_t n_rows, std::size_t n_cols,
                  const std::string& path, const std::string& layout) {
  for (const NumberRow& r : rows)
    if (r.values.size() != n_cols)
      throw FileFormatError(where(path, r.line_no) + "expected " + std::to_string(n_cols) +
                            " numbers (" + layout + "), got " + std::to_string(r.values.size()));
  if (rows.size() != n_rows)
    throw FileFormatError(path + ": expected " + std::to_string(n_rows) + " row" +
                          (n_rows == 1 ? "" : "s") + " (" + layout + "), got " +
                          std::to_string(rows.size()));
}

PinholeIntrinsics intrinsicsOf(double fx, double fy, double cx, double cy) {
  PinholeIntrinsics k;
  k.width = k.height = 0;  // the caller takes the size from the frames
  k.fx = fx, k.fy = fy, k.cx = cx, k.cy = cy;
  return k;
}

void requirePositiveFocal(const PinholeIntrinsics& k, const std::string& path) {
  if (!(k.fx > 0.0 && k.fy > 0.0))
    throw FileFormatError(path + ": focal lengths must be positive (fx " + std::to_string(k.fx) +
                          ", fy " + std::to_string(k.fy) + ")");
}

// A 7-Scenes pose file: a 4x4 camera-to-world matrix. Its rotation, written with a few digits,
// is put back on SO(3) (nearest rotation); one further than 1e-3 from a rotation is refused.
Eigen::Isometry3d readPoseMatrix(const std::string& path) {
  const std::vector<NumberRow> rows = readNumberRows(path, "pose");
  requireShape(rows, 4, 4, path, "a 4x4 camera-to-world matrix");
  Eigen::Matrix4d M;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) M(r, c) = rows[r].values[c];
  if ((M.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 1e-6)
    throw FileFormatError(where(path, rows[3].line_no) + "last row must be 0 0 0 1");
  const Eigen::Matrix3d A = M.topLeftCorner<3, 3>();
  const double off = (A.transpose() * A - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (!(off <= 1e-3) || A.determinant() <= 0.0) {
    std::ostringstream s;
    s << path << ": the upper-left 3x3 is not a rotation (|R^T R - I| = " << off
      << ", det = " << A.determinant() << ")";
    throw FileFormatError(s.str());
  }
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = svd.matrixU() * svd.matrixV().transpose();
  T.translation() = M.topRightCorner<3, 1>();
  return T;
}

DepthSequence readTumSequence(const std::string& dir) {
  DepthSequence seq;
  seq.layout = "TUM RGB-D";
  seq.frames_source = dir + "/depth.txt";
  seq.frames = readTumFrameList(seq.frames_source);
  seq.depth_scale_m = 1.0 / 5000.0;
  const std::string k_path = dir + "/intrinsics.txt";
  if (fileExists(k_path)) {
    const std::vector<NumberRow> rows = readNumberRows(k_path, "intrinsics");
    requireShape(rows, 1, 5, k_path, "'fx fy cx cy units_per_metre'");
    const std::vector<double>& v = rows.front().values;
    seq.intrinsics = intrinsicsOf(v[0], v[1], v[2], v[3]);
    requirePositiveFocal(*seq.intrinsics, k_path);
    if (!(v[4] >= 1.0))
      throw FileFormatError(where(k_path, rows.front().line_no) + "units per metre " +
                            std::to_string(v[4]) + ": expected at least 1 (TUM 5000, mm 1000)");
    seq.depth_scale_m = 1.0 / v[4];
    seq.intrinsics_source = k_path;
  }
  const std::string gt_path = dir + "/groundtruth.txt";
  if (fileExists(gt_path)) {
    seq.ground_truth = readTumTrajectory(gt_path);
    seq.ground_truth_source = gt_path;
  }
  return seq;
}

DepthSequence readSevenScenesSequence(const std::string& dir,
                                      const std::vector<std::string>& depth_pngs) {
  DepthSequence seq;
  seq.layout = "7-Scenes";
  seq.depth_scale_m = 0.001;
  seq.no_return_raw = 65535;
  seq.frames_source = dir + "/frame-*.depth.png";
  for (std::size_t i = 0; i < depth_pngs.size(); ++i)
    seq.frames.push_back({static_cast<double>(i) / 30.0, depth_pngs[i]});
  const std::string k_path = dir + "/camera-intrinsics.txt";
  if (fileExists(k_path)) {
    const std::vector<NumberRow> rows = readNumberRows(k_path, "intrinsics");
    requireShape(rows, 3, 3, k_path, "a 3x3 camera matrix K");
    seq.intrinsics = intrinsicsOf(rows[0].values[0], rows[1].values[1], rows[0].values[2],
                                  rows[1].values[2]);
    requirePositiveFocal(*seq.intrinsics, k_path);
    seq.intrinsics_source = k_path;
  } else {
    seq.intrinsics = intrinsicsOf(585.0, 585.0, 320.0, 240.0);
    seq.intrinsics_source = "the 7-Scenes published depth calibration (no " + k_path + ")";
  }
  // Ground truth: every frame's pose file, or none at all.
  const std::string suffix = ".depth.png";
  std::size_t with_pose = 0;
  std::string first_missing;
  std::vector<std::string> pose_paths;
  for (const std::string& png : depth_pngs) {
    pose_paths.push_back(png.substr(0, png.size() - suffix.size()) + ".pose.txt");
    if (fileExists(pose_paths.back()))
      ++with_pose;
    else if (first_missing.empty())
      first_missing = pose_paths.back();
  }
  if (with_pose > 0 && with_pose < pose_paths.size())
    throw FileFormatError(first_missing + ": missing (" + std::to_string(with_pose) + " of " +
                          std::to_string(pose_paths.size()) +
                          " frames have a pose file; the ground truth needs every frame's)");
  if (with_pose > 0) {
    for (std::size_t i = 0; i < pose_paths.size(); ++i)
      seq.ground_truth.push_back({seq.frames[i].stamp_s, readPoseMatrix(pose_paths[i])});
    seq.ground_truth_source = dir + "/frame-*.pose.txt";
  }
  return seq;
}

// The sorted 7-Scenes depth images of `dir` (empty when there are none).
std::vector<std::string> sevenScenesDepthImages(const std::string& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    const std::string suffix = ".depth.png";
    if (name.rfind("frame-", 0) == 0 && name.size() > suffix.size() &&
        name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0 &&
        e.is_regular_file(ec))
      out.push_back(e.path().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

std::vector<std::uint16_t> readPng16(const std::string& path, int* width, int* height) {
  FilePtr file(std::fopen(path.c_str(), "rb"));
  if (!file) throw FileFormatError(path + ": cannot open PNG (" + std::strerror(errno) + ")");
  std::vector<std::uint8_t> bytes;
  std::uint8_t chunk[1 << 16];
  std::size_t n = 0;
  while ((n = std::fread(chunk, 1, sizeof(chunk), file.get())) > 0)
    bytes.insert(bytes.end(), chunk, chunk + n);
  if (std::ferror(file.get()))
    throw FileFormatError(path + ": cannot read PNG (" + std::strerror(errno) + ")");
  try {
    Png16Image image = decodePng16(bytes.data(), bytes.size());
    *width = image.width;
    *height = image.height;
    return std::move(image.pixels);
  } catch (const Png16Error& e) {
    throw FileFormatError(path + ": " + e.what());
  }
}

void writePng16(const std::string& path, const std::vector<std::uint16_t>& data, int width,
                int height) {
  std::vector<std::uint8_t> bytes;
  try {
    bytes = encodePng16(data.data(), data.size(), width, height);
  } catch (const Png16Error& e) {
    throw FileFormatError(path + ": " + e.what());
  }
  FilePtr file(std::fopen(path.c_str(), "wb"));
  if (!file) throw FileFormatError(path + ": cannot create PNG (" + std::strerror(errno) + ")");
  if (std::fwrite(bytes.data(), 1, bytes.size(), file.get()) != bytes.size() ||
      std::fflush(file.get()) != 0)
    throw FileFormatError(path + ": PNG write failed (" + std::strerror(errno) + ")");
}

std::vector<TumFrame> readTumFrameList(const std::string& list_path) {
  std::ifstream in = openText(list_path, "frame list");
  const std::string folder = folderOf(list_path);
  std::vector<TumFrame> frames;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (isCommentOrBlank(line)) continue;
    const auto t = tokens(line);
    TumFrame f;
    if (t.size() != 2 || !parseFinite(t[0], &f.stamp_s))
      throw FileFormatError(where(list_path, line_no) + "expected 'timestamp path', got '" + line +
                            "'");
    f.path = (!t[1].empty() && t[1][0] == '/') ? t[1] : folder + "/" + t[1];
    if (!fileExists(f.path))
      throw FileFormatError(where(list_path, line_no) + "listed image " + f.path +
                            " does not exist");
    frames.push_back(std::move(f));
  }
  return frames;
}

DepthImage loadTumDepth(const std::string& png_path, double depth_scale_m,
                        const DepthRange& range) {
  int w = 0, h = 0;
  const std::vector<std::uint16_t> raw = readPng16(png_path, &w, &h);
  try {
    return depthFromRaw(raw.data(), w, h, 2 * static_cast<std::size_t>(w), DepthEncoding::kU16,
                        depth_scale_m, range);
  } catch (const DepthInputError& e) {
    throw DepthInputError(png_path + ": " + e.what());
  }
}

void saveTumDepth(const std::string& png_path, const DepthImage& depth, double depth_scale_m) {
  if (!(std::isfinite(depth_scale_m) && depth_scale_m > 0.0))
    throw FileFormatError(png_path + ": depth scale must be a positive number of metres per unit");
  if (depth.data.size() != static_cast<std::size_t>(depth.width) * depth.height)
    throw FileFormatError(png_path + ": depth frame buffer does not match its size");
  std::vector<std::uint16_t> raw(depth.data.size());
  for (std::size_t i = 0; i < raw.size(); ++i) {
    const double d = depth.data[i];
    const double units = std::round(d / depth_scale_m);
    if (!std::isfinite(d) || d < 0.0 || units > 65535.0) {
      std::ostringstream s;
      s << png_path << ": depth " << d << " m at pixel (" << i % depth.width << ", "
        << i / depth.width << ") does not fit 16 bits at " << depth_scale_m << " m per unit";
      throw FileFormatError(s.str());
    }
    raw[i] = static_cast<std::uint16_t>(units);
  }
  writePng16(png_path, raw, depth.width, depth.height);
}

Trajectory readTumTrajectory(const std::string& path) {
  std::ifstream in = openText(path, "trajectory");
  Trajectory out;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (isCommentOrBlank(line)) continue;
    const auto t = tokens(line);
    if (t.size() != 8) {
      throw FileFormatError(where(path, line_no) +
                            "expected 8 fields 't tx ty tz qx qy qz qw', got " +
                            std::to_string(t.size()));
    }
    double v[8];
    for (int i = 0; i < 8; ++i) {
      if (!parseFinite(t[i], &v[i]))
        throw FileFormatError(where(path, line_no) + "field " + std::to_string(i + 1) + " '" +
                              t[i] + "' is not a finite number");
    }
    const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
    if (!(q.norm() > 1e-6))
      throw FileFormatError(where(path, line_no) + "quaternion has zero length");
    StampedPose p;
    p.stamp_s = v[0];
    p.T_W_C.linear() = q.normalized().toRotationMatrix();
    p.T_W_C.translation() = Eigen::Vector3d(v[1], v[2], v[3]);
    out.push_back(p);
  }
  return out;
}

void writeTumTrajectory(const std::string& path, const Trajectory& trajectory,
                        const std::string& comment) {
  std::ofstream out(path);
  if (!out)
    throw FileFormatError(path + ": cannot create trajectory (" + std::strerror(errno) + ")");
  if (!comment.empty()) out << "# " << comment << "\n";
  out << "# timestamp tx ty tz qx qy qz qw (camera-to-world T_W_C, metres)\n";
  for (std::size_t i = 0; i < trajectory.size(); ++i) {
    const StampedPose& p = trajectory[i];
    if (!std::isfinite(p.stamp_s) || !p.T_W_C.matrix().allFinite())
      throw FileFormatError(path + ": pose " + std::to_string(i) + " is not finite");
    Eigen::Quaterniond q(p.T_W_C.rotation());
    if (q.w() < 0.0) q.coeffs() *= -1.0;
    const Eigen::Vector3d t = p.T_W_C.translation();
    out << std::fixed << std::setprecision(6) << p.stamp_s << ' ' << t.x() << ' ' << t.y() << ' '
        << t.z() << std::setprecision(9) << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' '
        << q.w() << '\n';
  }
  out.flush();
  if (!out) throw FileFormatError(path + ": trajectory write failed");
}

std::vector<std::pair<std::size_t, std::size_t>> associateStamps(
    const std::vector<double>& query_s, const std::vector<double>& reference_s, double max_gap_s) {
  std::vector<std::size_t> order(reference_s.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return reference_s[a] < reference_s[b]; });
  std::vector<double> sorted(order.size());
  for (std::size_t i = 0; i < order.size(); ++i) sorted[i] = reference_s[order[i]];

  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (std::size_t q = 0; q < query_s.size(); ++q) {
    const double t = query_s[q];
    if (!std::isfinite(t) || sorted.empty()) continue;
    const std::size_t hi = static_cast<std::size_t>(
        std::lower_bound(sorted.begin(), sorted.end(), t) - sorted.begin());
    std::size_t best = sorted.size();
    double best_gap = 0.0;
    for (std::size_t cand = hi == 0 ? 0 : hi - 1; cand <= hi && cand < sorted.size(); ++cand) {
      const double gap = std::abs(sorted[cand] - t);
      if (best == sorted.size() || gap < best_gap) {
        best = cand;
        best_gap = gap;
      }
    }
    if (best < sorted.size() && best_gap <= max_gap_s) pairs.emplace_back(q, order[best]);
  }
  return pairs;
}

AssociatedTrajectories associateTrajectories(const Trajectory& est, const Trajectory& gt,
                                             double max_gap_s) {
  std::vector<double> est_s(est.size()), gt_s(gt.size());
  for (std::size_t i = 0; i < est.size(); ++i) est_s[i] = est[i].stamp_s;
  for (std::size_t i = 0; i < gt.size(); ++i) gt_s[i] = gt[i].stamp_s;
  AssociatedTrajectories out;
  for (const auto& [ie, ig] : associateStamps(est_s, gt_s, max_gap_s)) {
    if (!est[ie].T_W_C.matrix().allFinite() || !gt[ig].T_W_C.matrix().allFinite()) continue;
    out.stamps_s.push_back(est[ie].stamp_s);
    out.est_T_W_C.push_back(est[ie].T_W_C);
    out.gt_T_W_C.push_back(gt[ig].T_W_C);
  }
  return out;
}

DepthSequence readDepthSequence(const std::string& dir) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec))
    throw FileFormatError(dir + ": " +
                          (std::filesystem::exists(dir, ec) ? "not a folder" : "no such folder"));
  if (fileExists(dir + "/depth.txt")) return readTumSequence(dir);
  for (const std::string& d : {dir, dir + "/data"}) {
    const std::vector<std::string> pngs = sevenScenesDepthImages(d);
    if (!pngs.empty()) return readSevenScenesSequence(d, pngs);
  }
  throw FileFormatError(dir +
                        ": not a depth sequence: no depth.txt (TUM RGB-D) and no "
                        "frame-*.depth.png here or in data/ (7-Scenes)");
}

std::vector<std::uint16_t> readSequenceDepthRaw(const DepthSequence& seq, std::size_t i,
                                                int* width, int* height) {
  if (i >= seq.frames.size())
    throw std::out_of_range("readSequenceDepthRaw: frame " + std::to_string(i) + " of " +
                            std::to_string(seq.frames.size()));
  std::vector<std::uint16_t> raw = readPng16(seq.frames[i].path, width, height);
  if (seq.no_return_raw != 0) std::replace(raw.begin(), raw.end(), seq.no_return_raw, std::uint16_t{0});
  return raw;
}

DepthImage loadSequenceDepth(const DepthSequence& seq, std::size_t i, double depth_scale_m,
                             const DepthRange& range) {
  int w = 0, h = 0;
  const std::vector<std::uint16_t> raw = readSequenceDepthRaw(seq, i, &w, &h);
  try {
    return depthFromRaw(raw.data(), w, h, 2 * static_cast<std::size_t>(w), DepthEncoding::kU16,
                        depth_scale_m, range);
  } catch (const DepthInputError& e) {
    throw DepthInputError(seq.frames[i].path + ": " + e.what());
  }
}

}  // namespace depth_track
