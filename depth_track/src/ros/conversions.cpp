#include "depth_track/ros/conversions.hpp"

#include <sensor_msgs/image_encodings.h>

#include <Eigen/Eigenvalues>
#include <boost/make_shared.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

namespace depth_track {
namespace conv {

namespace {
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
}

DepthImage depthFromMsg(const sensor_msgs::Image& image, double depth_scale_m,
                        const DepthRange& range) {
  const DepthEncoding enc = parseDepthEncoding(image.encoding);
  const std::size_t bytes_per_px = enc == DepthEncoding::kU16 ? 2 : 4;
  if (image.is_bigendian)
    throw DepthInputError("depth image is big-endian (" + image.encoding +
                          "); only little-endian images are handled");
  if (image.width == 0 || image.height == 0)
    throw DepthInputError("depth image is empty (" + std::to_string(image.width) + "x" +
                          std::to_string(image.height) + ")");
  if (image.step < image.width * bytes_per_px)
    throw DepthInputError("depth image step " + std::to_string(image.step) + " B is less than " +
                          std::to_string(image.width) + " px x " + std::to_string(bytes_per_px) +
                          " B (" + image.encoding + ")");
  if (image.data.size() != static_cast<std::size_t>(image.step) * image.height)
    throw DepthInputError("depth image holds " + std::to_string(image.data.size()) +
                          " B, expected height " + std::to_string(image.height) + " x step " +
                          std::to_string(image.step));
  return depthFromRaw(image.data.data(), static_cast<int>(image.width),
                      static_cast<int>(image.height), image.step, enc, depth_scale_m, range);
}

sensor_msgs::ImagePtr depthToMsg(const DepthImage& depth, const std_msgs::Header& header) {
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->width = depth.width;
  msg->height = depth.height;
  msg->encoding = sensor_msgs::image_encodings::TYPE_32FC1;
  msg->is_bigendian = 0;
  msg->step = depth.width * 4;
  msg->data.resize(depth.data.size() * 4);
  float* out = reinterpret_cast<float*>(msg->data.data());
  for (std::size_t i = 0; i < depth.data.size(); ++i)
    out[i] = depth.data[i] > 0.0f ? depth.data[i] : kNaN;
  return msg;
}

sensor_msgs::ImagePtr falseColourDepth(const DepthImage& depth, const std_msgs::Header& header,
                                       double band_m) {
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->width = depth.width;
  msg->height = depth.height;
  msg->encoding = sensor_msgs::image_encodings::RGB8;
  msg->step = depth.width * 3;
  msg->data.assign(static_cast<std::size_t>(msg->step) * depth.height, 0);
  const double inv_band = 1.0 / band_m;
  for (std::size_t i = 0; i < depth.data.size(); ++i) {
    const float d = depth.data[i];
    if (!(d > 0.0f)) continue;
    // Hue cycles once per six bands so that neighbouring bands always differ in colour.
    const double h = std::fmod(d * inv_band, 6.0);
    const int sector = static_cast<int>(h);
    const double f = h - sector;
    const auto up = static_cast<std::uint8_t>(255.0 * f),
               down = static_cast<std::uint8_t>(255.0 * (1.0 - f));
    std::uint8_t r = 0, g = 0, b = 0;
    switch (sector) {
      case 0:
        r = 255, g = up;
        break;
      case 1:
        r = down, g = 255;
        break;
      case 2:
        g = 255, b = up;
        break;
      case 3:
        g = down, b = 255;
        break;
      case 4:
        r = up, b = 255;
        break;
      default:
        r = 255, b = down;
        break;
    }
    std::uint8_t* px = &msg->data[i * 3];
    px[0] = r, px[1] = g, px[2] = b;
  }
  return msg;
}

PinholeIntrinsics intrinsicsFromCameraInfo(const sensor_msgs::CameraInfo& info) {
  if (info.width == 0 || info.height == 0)
    throw DepthInputError("camera_info has no image size (" + std::to_string(info.width) + "x" +
                          std::to_string(info.height) + ")");
  if (info.binning_x > 1 || info.binning_y > 1)
    throw DepthInputError("camera_info has binning " + std::to_string(info.binning_x) + "x" +
                          std::to_string(info.binning_y) + ", which is not handled");
  if (info.roi.width != 0 && (info.roi.width != info.width || info.roi.height != info.height))
    throw DepthInputError("camera_info has a region of interest, which is not handled");
  PinholeIntrinsics k;
  k.width = static_cast<int>(info.width);
  k.height = static_cast<int>(info.height);
  const bool have_p = info.P[0] != 0.0 && info.P[5] != 0.0;
  k.fx = have_p ? info.P[0] : info.K[0];
  k.fy = have_p ? info.P[5] : info.K[4];
  k.cx = have_p ? info.P[2] : info.K[2];
  k.cy = have_p ? info.P[6] : info.K[5];
  if (k.fx == 0.0 || k.fy == 0.0)
    throw DepthInputError("camera_info is uncalibrated (focal lengths are zero)");
  const auto problems = k.validate();
  if (!problems.empty())
    throw DepthInputError("camera_info intrinsics are invalid: " + joinProblems(problems));
  return k;
}

void checkImageMatchesInfo(const sensor_msgs::Image& image, const PinholeIntrinsics& k) {
  if (static_cast<int>(image.width) != k.width || static_cast<int>(image.height) != k.height)
    throw DepthInputError("depth image is " + std::to_string(image.width) + "x" +
                          std::to_string(image.height) + " but camera_info says " +
                          std::to_string(k.width) + "x" + std::to_string(k.height));
}

// ---- cells
// ---------------------------------------------------------------------------------------

namespace {

/// One cell as laid out in the cloud: 22 floats then 3 int32, no padding.
struct CellPoint {
  float x, y, z;
  float normal_x, normal_y, normal_z;
  float curvature;
  float cov[6];  // xx xy xz yy yz zz
  float eig[3];
  float isq[6];  // xx xy xz yy yz zz
  std::int32_t col, row, n_valid;
};
static_assert(sizeof(CellPoint) == 25 * 4, "CellPoint must be packed");

struct FieldDef {
  const char* name;
  std::uint8_t datatype;
};

const std::vector<FieldDef>& fieldDefs() {
  using F = sensor_msgs::PointField;
  static const std::vector<FieldDef> defs = {
      {"x", F::FLOAT32},         {"y", F::FLOAT32},        {"z", F::FLOAT32},
      {"normal_x", F::FLOAT32},  {"normal_y", F::FLOAT32}, {"normal_z", F::FLOAT32},
      {"curvature", F::FLOAT32}, {"cov_xx", F::FLOAT32},   {"cov_xy", F::FLOAT32},
      {"cov_xz", F::FLOAT32},    {"cov_yy", F::FLOAT32},   {"cov_yz", F::FLOAT32},
      {"cov_zz", F::FLOAT32},    {"eig0", F::FLOAT32},     {"eig1", F::FLOAT32},
      {"eig2", F::FLOAT32},      {"isq_xx", F::FLOAT32},   {"isq_xy", F::FLOAT32},
      {"isq_xz", F::FLOAT32},    {"isq_yy", F::FLOAT32},   {"isq_yz", F::FLOAT32},
      {"isq_zz", F::FLOAT32},    {"col", F::INT32},        {"row", F::INT32},
      {"n_valid", F::INT32}};
  return defs;
}

void packSym(const Eigen::Matrix3f& m, float* out) {
  out[0] = m(0, 0), out[1] = m(0, 1), out[2] = m(0, 2);
  out[3] = m(1, 1), out[4] = m(1, 2), out[5] = m(2, 2);
}
Eigen::Matrix3f unpackSym(const float* in) {
  Eigen::Matrix3f m;
  m << in[0], in[1], in[2], in[1], in[3], in[4], in[2], in[4], in[5];
  return m;
}

}  // namespace

sensor_msgs::PointCloud2Ptr cellsToCloud(const CellCloud& cells, const std_msgs::Header& header) {
  auto msg = boost::make_shared<sensor_msgs::PointCloud2>();
  msg->header = header;
  msg->width = cells.grid_w;
  msg->height = cells.grid_h;
  std::uint32_t offset = 0;
  for (const FieldDef& f : fieldDefs()) {
    sensor_msgs::PointField pf;
    pf.name = f.name;
    pf.offset = offset;
    pf.datatype = f.datatype;
    pf.count = 1;
    msg->fields.push_back(pf);
    offset += 4;
  }
  msg->is_bigendian = false;
  msg->point_step = sizeof(CellPoint);
  msg->row_step = msg->point_step * msg->width;
  msg->is_dense = false;
  const std::size_t n = static_cast<std::size_t>(cells.grid_w) * cells.grid_h;
  msg->data.resize(n * sizeof(CellPoint));
  auto* pts = reinterpret_cast<CellPoint*>(msg->data.data());
  for (std::size_t i = 0; i < n; ++i) {
    CellPoint& p = pts[i];
    std::fill(reinterpret_cast<float*>(&p), reinterpret_cast<float*>(&p) + 22, kNaN);
    p.col = static_cast<std::int32_t>(i % cells.grid_w);
    p.row = static_cast<std::int32_t>(i / cells.grid_w);
    p.n_valid = 0;
  }
  for (const Cell& c : cells.cells) {
    CellPoint& p = pts[static_cast<std::size_t>(c.gy) * cells.grid_w + c.gx];
    p.x = c.mean_C.x(), p.y = c.mean_C.y(), p.z = c.mean_C.z();
    p.normal_x = c.normal_C.x(), p.normal_y = c.normal_C.y(), p.normal_z = c.normal_C.z();
    // Reduced without them (the tracker's reduction): solved here from the covariance, so the
    // published fields mean the same either way.
    const CellSpectrum sp = cells.has_spectra
                                ? CellSpectrum{c.eigenvalues, c.surface_variation, c.det}
                                : spectrumOf(c.cov);
    p.curvature = sp.surface_variation;
    packSym(c.cov, p.cov);
    p.eig[0] = sp.eigenvalues(0), p.eig[1] = sp.eigenvalues(1), p.eig[2] = sp.eigenvalues(2);
    packSym(c.cov_inv_sqrt, p.isq);
    p.n_valid = c.n_valid;
  }
  return msg;
}

std::shared_ptr<CellCloud> cellsFromCloud(const sensor_msgs::PointCloud2& msg, int image_width,
                                          int image_height) {
  const auto& defs = fieldDefs();
  if (msg.fields.size() != defs.size() || msg.point_step != sizeof(CellPoint))
    throw DepthInputError("cell cloud has " + std::to_string(msg.fields.size()) + " fields of " +
                          std::to_string(msg.point_step) + " B per point; expected the " +
                          std::to_string(defs.size()) + " cell fields of depth_track's pca_reduce");
  for (std::size_t i = 0; i < defs.size(); ++i)
    if (msg.fields[i].name != defs[i].name || msg.fields[i].offset != 4 * i ||
        msg.fields[i].datatype != defs[i].datatype || msg.fields[i].count != 1)
      throw DepthInputError("cell cloud field " + std::to_string(i) + " is '" + msg.fields[i].name +
                            "', expected '" + defs[i].name + "'");
  if (msg.is_bigendian) throw DepthInputError("cell cloud is big-endian");
  if (msg.width == 0 || msg.height == 0 || image_width % static_cast<int>(msg.width) != 0 ||
      image_width / static_cast<int>(msg.width) * static_cast<int>(msg.height) != image_height)
    throw DepthInputError("cell grid " + std::to_string(msg.width) + "x" +
                          std::to_string(msg.height) + " does not tile a " +
                          std::to_string(image_width) + "x" + std::to_string(image_height) +
                          " image");
  const std::size_t n = static_cast<std::size_t>(msg.width) * msg.height;
  if (msg.row_step != msg.width * msg.point_step || msg.data.size() != n * sizeof(CellPoint))
    throw DepthInputError("cell cloud holds " + std::to_string(msg.data.size()) + " B, expected " +
                          std::to_string(n * sizeof(CellPoint)));
  auto cloud = std::make_shared<CellCloud>();
  cloud->cell_size = image_width / static_cast<int>(msg.width);
  cloud->grid_w = static_cast<int>(msg.width);
  cloud->grid_h = static_cast<int>(msg.height);
  cloud->grid_index.assign(n, -1);
  // The core stages report per-frame results at the cloud's stamp (FrameStatus::stamp_s) and in
  // its frame, and the odometry's motion prior reads the stamps (velocity over a window of frames).
  cloud->stamp_s = msg.header.stamp.toSec();
  cloud->frame_id = msg.header.frame_id;
  const auto* pts = reinterpret_cast<const CellPoint*>(msg.data.data());
  // Sized once: growing the vector cell by cell cost 1.8 % of the graph's CPU (perf, RT3).
  cloud->cells.reserve(static_cast<std::size_t>(
      std::count_if(pts, pts + n, [](const CellPoint& p) { return p.n_valid > 0; })));
  for (std::size_t i = 0; i < n; ++i) {
    const CellPoint& p = pts[i];
    if (p.n_valid <= 0) continue;
    if (!(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z) &&
          std::isfinite(p.normal_x) && std::isfinite(p.normal_y) && std::isfinite(p.normal_z)))
      throw DepthInputError("cell cloud point " + std::to_string(i) +
                            " has n_valid > 0 but non-finite geometry");
    Cell c;
    c.gx = static_cast<int>(i % msg.width);
    c.gy = static_cast<int>(i / msg.width);
    c.n_valid = p.n_valid;
    c.mean_C = Eigen::Vector3f(p.x, p.y, p.z);
    c.normal_C = Eigen::Vector3f(p.normal_x, p.normal_y, p.normal_z);
    c.surface_variation = p.curvature;
    c.cov = unpackSym(p.cov);
    c.eigenvalues = Eigen::Vector3f(p.eig[0], p.eig[1], p.eig[2]);
    c.eigenvectors.setZero();
    c.cov_inv_sqrt = unpackSym(p.isq);
    c.det = c.cov.determinant();
    cloud->grid_index[i] = static_cast<int>(cloud->cells.size());
    cloud->cells.push_back(c);
  }
  cloud->stats.total = static_cast<int>(n);
  cloud->stats.retained = static_cast<int>(cloud->cells.size());
  return cloud;
}

rig_msgs::NoiseCalibration toMsg(const NoiseCalibration& c, const std_msgs::Header& header) {
  rig_msgs::NoiseCalibration m;
  m.header = header;
  m.measured = c.measured;
  m.summary = c.summary;
  m.noise_sigma_const_m = c.noise.const_m;
  m.noise_sigma_quad_per_m = c.noise.quad_per_m;
  m.z_ref_m = c.z_ref_m;
  m.footprint_noise = c.adaptation.footprint_noise;
  m.normal_radius_cells = c.adaptation.normal_radius_cells;
  m.normal_merge_dist_m = c.adaptation.normal_merge_dist_m;
  m.min_valid_fraction = c.adaptation.min_valid_fraction;
  m.cos_min = c.adaptation.cos_min;
  m.huber_delta_m = c.adaptation.huber_delta_m;
  m.max_error_rms_m = c.adaptation.max_error_rms_m;
  return m;
}

NoiseCalibration fromMsg(const rig_msgs::NoiseCalibration& m) {
  NoiseCalibration c;
  c.stamp_s = m.header.stamp.toSec();
  c.measured = m.measured;
  c.summary = m.summary;
  if (!m.measured) return c;
  c.noise.const_m = m.noise_sigma_const_m;
  c.noise.quad_per_m = m.noise_sigma_quad_per_m;
  c.z_ref_m = m.z_ref_m;
  c.adaptation.footprint_noise = m.footprint_noise;
  c.adaptation.normal_radius_cells = m.normal_radius_cells;
  c.adaptation.normal_merge_dist_m = m.normal_merge_dist_m;
  c.adaptation.min_valid_fraction = m.min_valid_fraction;
  c.adaptation.cos_min = m.cos_min;
  c.adaptation.huber_delta_m = m.huber_delta_m;
  c.adaptation.max_error_rms_m = m.max_error_rms_m;
  const double values[] = {c.noise.const_m,
                           c.noise.quad_per_m,
                           c.adaptation.normal_merge_dist_m,
                           c.adaptation.min_valid_fraction,
                           c.adaptation.cos_min,
                           c.adaptation.huber_delta_m,
                           c.adaptation.max_error_rms_m};
  for (double v : values)
    if (!std::isfinite(v) || v < 0.0)
      throw DepthInputError("noise calibration holds a non-finite or negative value");
  if (!c.noise.known() || c.adaptation.cos_min > 1.0 || c.adaptation.min_valid_fraction > 1.0)
    throw DepthInputError(
        "noise calibration: measured, but no noise (both sigma terms 0), cos_min or "
        "min_valid_fraction above 1");
  return c;
}

// ---- poses
// ---------------------------------------------------------------------------------------

geometry_msgs::Pose toPoseMsg(const Eigen::Isometry3d& T) {
  geometry_msgs::Pose p;
  p.position.x = T.translation().x();
  p.position.y = T.translation().y();
  p.position.z = T.translation().z();
  Eigen::Quaterniond q(T.rotation());
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  p.orientation.x = q.x();
  p.orientation.y = q.y();
  p.orientation.z = q.z();
  p.orientation.w = q.w();
  return p;
}

geometry_msgs::Transform toTransformMsg(const Eigen::Isometry3d& T) {
  const geometry_msgs::Pose p = toPoseMsg(T);
  geometry_msgs::Transform t;
  t.translation.x = p.position.x;
  t.translation.y = p.position.y;
  t.translation.z = p.position.z;
  t.rotation = p.orientation;
  return t;
}

namespace {
Eigen::Isometry3d fromParts(double x, double y, double z, double qx, double qy, double qz,
                            double qw, const char* what) {
  const double v[7] = {x, y, z, qx, qy, qz, qw};
  for (double d : v)
    if (!std::isfinite(d))
      throw std::invalid_argument(std::string(what) + " has a non-finite entry");
  const Eigen::Quaterniond q(qw, qx, qy, qz);
  if (!(q.norm() >= 0.9 && q.norm() <= 1.1))
    throw std::invalid_argument(std::string(what) + " has a quaternion of norm " +
                                std::to_string(q.norm()) + " (not a rotation)");
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}
}  // namespace

ImuSample imuSampleFromMsg(const sensor_msgs::Imu& m) {
  ImuSample s;
  s.stamp_s = m.header.stamp.toSec();
  s.gyro_rad_s = Eigen::Vector3d(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z);
  s.accel_m_s2 =
      Eigen::Vector3d(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z);
  return s;
}

Eigen::Isometry3d fromPoseMsg(const geometry_msgs::Pose& p) {
  return fromParts(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                   p.orientation.z, p.orientation.w, "pose");
}

Eigen::Isometry3d fromTransformMsg(const geometry_msgs::Transform& t) {
  return fromParts(t.translation.x, t.translation.y, t.translation.z, t.rotation.x, t.rotation.y,
                   t.rotation.z, t.rotation.w, "transform");
}

std::array<double, 36> poseCovariance(const Matrix6d& H, double sigma_m,
                                      const Eigen::Isometry3d& T_P_ref,
                                      const Eigen::Vector3d& p_P_body, double unconstrained_var) {
  // Pseudo-inverse through the eigen decomposition: a degenerate view (one wall) leaves a
  // direction without information, which must show as a large variance, not as a NaN.
  Eigen::SelfAdjointEigenSolver<Matrix6d> es(0.5 * (H + H.transpose()));
  const Eigen::Matrix<double, 6, 1> ev = es.eigenvalues();
  const double floor = std::max(ev.maxCoeff(), 0.0) * 1e-9;
  Eigen::Matrix<double, 6, 1> inv;
  for (int i = 0; i < 6; ++i)
    inv(i) = ev(i) > floor && ev(i) > 0.0 ? sigma_m * sigma_m / ev(i) : unconstrained_var;
  const Matrix6d cov_ref = es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
  // [omega; v] about the reference origin is [omega; u] about a pivot at that origin.
  return poseCovarianceOfIncrement(cov_ref, T_P_ref.rotation(), T_P_ref.translation(), p_P_body);
}

std::array<double, 36> poseCovarianceOfIncrement(const Matrix6d& cov_ref, const Eigen::Matrix3d& R,
                                                 const Eigen::Vector3d& c_P,
                                                 const Eigen::Vector3d& p_P_body) {
  // [omega; u] in the reference frame -> (position of the body, rotation) in the parent frame:
  // omega_P = R omega, the pivot moves by R u, and the body origin p by R u + omega_P x (p - c).
  auto skew = [](const Eigen::Vector3d& a) {
    Eigen::Matrix3d s;
    s << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
    return s;
  };
  Matrix6d M = Matrix6d::Zero();  // rows: x y z rx ry rz; columns: omega u
  M.block<3, 3>(0, 0) = (skew(c_P) - skew(p_P_body)) * R;
  M.block<3, 3>(0, 3) = R;
  M.block<3, 3>(3, 0) = R;
  const Matrix6d cov = M * cov_ref * M.transpose();
  std::array<double, 36> out{};
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) out[r * 6 + c] = cov(r, c);
  return out;
}

std::array<double, 36> diagonalCovariance(double var_pos_m2, double var_rot_rad2) {
  std::array<double, 36> out{};
  for (int i = 0; i < 3; ++i) out[i * 7] = var_pos_m2;
  for (int i = 3; i < 6; ++i) out[i * 7] = var_rot_rad2;
  return out;
}

}  // namespace conv
}  // namespace depth_track
