#include "depth_track/core/sim/scene.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "depth_track/core/se3.hpp"

namespace depth_track {
namespace sim {

namespace {

constexpr double kParallelEps = 1e-15;

/// Orthonormal frame whose z axis is `z` (unit); x is chosen perpendicular to `hint` when possible.
Eigen::Matrix3d frameFromZ(const Eigen::Vector3d& z, const Eigen::Vector3d& hint) {
  Eigen::Vector3d x = hint.cross(z);
  if (x.norm() < 1e-9) x = Eigen::Vector3d::UnitX().cross(z);
  if (x.norm() < 1e-9) x = Eigen::Vector3d::UnitY().cross(z);
  x.normalize();
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(1) = z.cross(x);
  R.col(2) = z;
  return R;
}

std::optional<double> accept(double t, double t_min, double t_max) {
  if (t >= t_min && t <= t_max) return t;
  return std::nullopt;
}

}  // namespace

std::optional<double> intersectLocal(const Primitive& prim, const Eigen::Vector3d& o,
                                     const Eigen::Vector3d& d, double t_min, double t_max) {
  const Eigen::Vector3d& h = prim.half_extents;
  switch (prim.shape) {
    case Shape::kRectangle: {
      if (std::abs(d.z()) < kParallelEps) return std::nullopt;
      const double t = -o.z() / d.z();
      if (!(t >= t_min && t <= t_max)) return std::nullopt;
      const double x = o.x() + t * d.x(), y = o.y() + t * d.y();
      if (std::abs(x) <= h.x() && std::abs(y) <= h.y()) return t;
      return std::nullopt;
    }
    case Shape::kBox: {
      double t0 = -std::numeric_limits<double>::infinity();
      double t1 = std::numeric_limits<double>::infinity();
      for (int i = 0; i < 3; ++i) {
        if (std::abs(d[i]) < kParallelEps) {
          if (std::abs(o[i]) > h[i]) return std::nullopt;
          continue;
        }
        const double inv = 1.0 / d[i];
        double ta = (-h[i] - o[i]) * inv, tb = (h[i] - o[i]) * inv;
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tb);
        if (t0 > t1) return std::nullopt;
      }
      return accept(t0, t_min, t_max);  // t0 < t_min: starts inside or the box is behind
    }
    case Shape::kCylinder: {
      const double r = h.x(), hz = h.z();
      double best = std::numeric_limits<double>::infinity();
      const double a = d.x() * d.x() + d.y() * d.y();
      if (a > kParallelEps) {
        const double b = o.x() * d.x() + o.y() * d.y();
        const double c = o.x() * o.x() + o.y() * o.y() - r * r;
        const double disc = b * b - a * c;
        if (disc >= 0.0) {
          const double t = (-b - std::sqrt(disc)) / a;  // entry through the mantle
          const double z = o.z() + t * d.z();
          if (t >= t_min && t <= t_max && std::abs(z) <= hz) best = t;
        }
      }
      if (std::abs(d.z()) > kParallelEps) {
        const double zc = d.z() > 0.0 ? -hz : hz;  // the cap facing the ray
        const double t = (zc - o.z()) / d.z();
        if (t >= t_min && t <= t_max && t < best) {
          const double x = o.x() + t * d.x(), y = o.y() + t * d.y();
          if (x * x + y * y <= r * r) best = t;
        }
      }
      if (std::isfinite(best)) return best;
      return std::nullopt;
    }
    case Shape::kSphere: {
      const double r = h.x();
      const double a = d.squaredNorm();
      const double b = o.dot(d);
      const double c = o.squaredNorm() - r * r;
      const double disc = b * b - a * c;
      if (disc < 0.0 || a < kParallelEps) return std::nullopt;
      return accept((-b - std::sqrt(disc)) / a, t_min, t_max);
    }
  }
  return std::nullopt;
}

Eigen::Vector3d surfaceNormalLocal(const Primitive& prim, const Eigen::Vector3d& p) {
  const Eigen::Vector3d& h = prim.half_extents;
  switch (prim.shape) {
    case Shape::kRectangle:
      return Eigen::Vector3d::UnitZ();
    case Shape::kBox: {
      // The face the point lies on is the one it is closest to.
      int axis = 0;
      double best = -std::numeric_limits<double>::infinity();
      for (int i = 0; i < 3; ++i) {
        const double d = std::abs(p[i]) - h[i];
        if (d > best) {
          best = d;
          axis = i;
        }
      }
      Eigen::Vector3d n = Eigen::Vector3d::Zero();
      n[axis] = p[axis] >= 0.0 ? 1.0 : -1.0;
      return n;
    }
    case Shape::kCylinder: {
      const double radial = p.head<2>().norm();
      if (std::abs(p.z()) - h.z() > radial - h.x() || radial < 1e-12)
        return Eigen::Vector3d(0.0, 0.0, p.z() >= 0.0 ? 1.0 : -1.0);
      return Eigen::Vector3d(p.x() / radial, p.y() / radial, 0.0);
    }
    case Shape::kSphere: {
      const double r = p.norm();
      return r > 0.0 ? Eigen::Vector3d(p / r) : Eigen::Vector3d::UnitZ();
    }
  }
  return Eigen::Vector3d::UnitZ();
}

double Scene::distanceTo(const Eigen::Vector3d& p_W) const {
  double d = std::numeric_limits<double>::infinity();
  for (const Primitive& prim : primitives) d = std::min(d, distanceToSurface(prim, p_W));
  return d;
}

double distanceToSurface(const Primitive& prim, const Eigen::Vector3d& p_W) {
  const Eigen::Vector3d p = prim.T_W_P.inverse() * p_W;
  const Eigen::Vector3d& h = prim.half_extents;
  switch (prim.shape) {
    case Shape::kRectangle: {
      const Eigen::Vector3d q(std::max(std::abs(p.x()) - h.x(), 0.0),
                              std::max(std::abs(p.y()) - h.y(), 0.0), p.z());
      return q.norm();
    }
    case Shape::kBox: {
      const Eigen::Vector3d q = p.cwiseAbs() - h;
      const double outside = q.cwiseMax(0.0).norm();
      const double inside = std::min(q.maxCoeff(), 0.0);
      return std::abs(outside + inside);
    }
    case Shape::kCylinder: {
      const Eigen::Vector2d q(p.head<2>().norm() - h.x(), std::abs(p.z()) - h.z());
      const double sdf = std::min(q.maxCoeff(), 0.0) + q.cwiseMax(0.0).norm();
      return std::abs(sdf);
    }
    case Shape::kSphere:
      return std::abs(p.norm() - h.x());
  }
  return std::numeric_limits<double>::infinity();
}

void Scene::addRectangle(const Eigen::Vector3d& c_W, const Eigen::Vector3d& n_W, double half_w_m,
                         double half_h_m, const std::string& label, const Eigen::Vector3d& up_W) {
  Primitive p;
  p.shape = Shape::kRectangle;
  p.T_W_P.linear() = frameFromZ(n_W.normalized(), up_W);
  p.T_W_P.translation() = c_W;
  p.half_extents = Eigen::Vector3d(half_w_m, half_h_m, 0.0);
  p.label = label;
  primitives.push_back(p);
}

void Scene::addBoxAabb(const Eigen::Vector3d& min_W, const Eigen::Vector3d& max_W,
                       const std::string& label) {
  Primitive p;
  p.shape = Shape::kBox;
  p.T_W_P.translation() = 0.5 * (min_W + max_W);
  p.half_extents = 0.5 * (max_W - min_W);
  p.label = label;
  primitives.push_back(p);
}

void Scene::addBox(const Eigen::Vector3d& c_W, double yaw_rad, const Eigen::Vector3d& half_m,
                   const std::string& label) {
  Primitive p;
  p.shape = Shape::kBox;
  p.T_W_P.linear() = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  p.T_W_P.translation() = c_W;
  p.half_extents = half_m;
  p.label = label;
  primitives.push_back(p);
}

void Scene::addCylinder(const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W, double r_m,
                        const std::string& label) {
  Primitive p;
  p.shape = Shape::kCylinder;
  const Eigen::Vector3d axis = b_W - a_W;
  const double len = axis.norm();
  p.T_W_P.linear() = frameFromZ(len > 0.0 ? Eigen::Vector3d(axis / len) : Eigen::Vector3d::UnitZ(),
                                Eigen::Vector3d::UnitZ());
  p.T_W_P.translation() = 0.5 * (a_W + b_W);
  p.half_extents = Eigen::Vector3d(r_m, r_m, 0.5 * len);
  p.label = label;
  primitives.push_back(p);
}

void Scene::addSphere(const Eigen::Vector3d& c_W, double r_m, const std::string& label) {
  Primitive p;
  p.shape = Shape::kSphere;
  p.T_W_P.translation() = c_W;
  p.half_extents = Eigen::Vector3d::Constant(r_m);
  p.label = label;
  primitives.push_back(p);
}

std::vector<std::string> Scene::validate() const {
  std::vector<std::string> problems;
  if (primitives.empty()) problems.push_back("scene '" + name + "' has no primitives");
  for (std::size_t i = 0; i < primitives.size(); ++i) {
    const Primitive& p = primitives[i];
    std::ostringstream who;
    who << "primitive " << i << " ('" << p.label << "')";
    if (!p.T_W_P.matrix().allFinite())
      problems.push_back(who.str() + " has a non-finite pose");
    else if (!isRigid(p.T_W_P))
      problems.push_back(who.str() + " has a pose that is not a rigid rotation");
    const Eigen::Vector3d& h = p.half_extents;
    const bool flat = p.shape == Shape::kRectangle;
    if (!h.allFinite() || h.x() <= 0.0 || h.y() <= 0.0 || (!flat && h.z() <= 0.0))
      problems.push_back(who.str() + " needs positive finite half extents (metres)");
    if ((p.shape == Shape::kCylinder && h.x() != h.y()) ||
        (p.shape == Shape::kSphere && (h.x() != h.y() || h.x() != h.z())))
      problems.push_back(who.str() + " has unequal radii");
  }
  return problems;
}

// ---------------------------------------------------------------------------------------------
// Scenes. Dimensions are those of ordinary furniture; comments give the reasoning where the
// thesis fixes a number.

namespace {

using V = Eigen::Vector3d;

/// Axis-aligned room shell: floor, ceiling and four walls (inward normals).
void addRoomShell(Scene& s, double x0, double x1, double y0, double y1, double height) {
  const double cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
  const double hx = 0.5 * (x1 - x0), hy = 0.5 * (y1 - y0), hz = 0.5 * height;
  s.addRectangle(V(cx, cy, 0.0), V::UnitZ(), hy, hx, "floor", V::UnitX());
  s.addRectangle(V(cx, cy, height), -V::UnitZ(), hy, hx, "ceiling", V::UnitX());
  s.addRectangle(V(x1, cy, hz), -V::UnitX(), hy, hz, "wall +x");
  s.addRectangle(V(x0, cy, hz), V::UnitX(), hy, hz, "wall -x");
  s.addRectangle(V(cx, y1, hz), -V::UnitY(), hx, hz, "wall +y");
  s.addRectangle(V(cx, y0, hz), V::UnitY(), hx, hz, "wall -y");
}

/// Four-legged table: top [x0,x1] x [y0,y1] at height top_z, square legs of side leg_m.
void addTable(Scene& s, double x0, double x1, double y0, double y1, double top_z, double leg_m,
              const std::string& label) {
  s.addBoxAabb(V(x0, y0, top_z - 0.03), V(x1, y1, top_z), label + " top");
  const double in = 0.03;
  for (double x : {x0 + in, x1 - in - leg_m})
    for (double y : {y0 + in, y1 - in - leg_m})
      s.addBoxAabb(V(x, y, 0.0), V(x + leg_m, y + leg_m, top_z - 0.03), label + " leg");
}

/// Radiator of vertical columns standing gap_m off a wall whose inner face is at x = wall_x
/// (facing -x when facing = -1, +x when facing = +1), spanning y in [y0, y1].
void addRadiatorX(Scene& s, double wall_x, int facing, double gap_m, double y0, double y1,
                  int columns, const std::string& label) {
  const double depth = 0.08;
  const double back = wall_x + facing * gap_m;
  const double front = back + facing * depth;
  const double pitch = (y1 - y0) / columns;
  for (int i = 0; i < columns; ++i) {
    const double ya = y0 + i * pitch + 0.15 * pitch, yb = y0 + (i + 1) * pitch - 0.15 * pitch;
    s.addBoxAabb(V(std::min(back, front), ya, 0.15), V(std::max(back, front), yb, 0.75),
                 label + " column");
  }
  // Manifold pipe along the bottom, feeding the columns.
  s.addCylinder(V(back + facing * 0.5 * depth, y0 - 0.05, 0.12),
                V(back + facing * 0.5 * depth, y1 + 0.05, 0.12), 0.015, label + " pipe");
}

/// Same along a wall at y = wall_y (facing -y / +y), spanning x in [x0, x1].
void addRadiatorY(Scene& s, double wall_y, int facing, double gap_m, double x0, double x1,
                  int columns, const std::string& label) {
  const double depth = 0.08;
  const double back = wall_y + facing * gap_m;
  const double front = back + facing * depth;
  const double pitch = (x1 - x0) / columns;
  for (int i = 0; i < columns; ++i) {
    const double xa = x0 + i * pitch + 0.15 * pitch, xb = x0 + (i + 1) * pitch - 0.15 * pitch;
    s.addBoxAabb(V(xa, std::min(back, front), 0.15), V(xb, std::max(back, front), 0.75),
                 label + " column");
  }
}

/// Bookcase against a wall: outer box [lo, hi]; open towards `open_axis` sign (+-1 in x or y).
void addBookcase(Scene& s, const V& lo, const V& hi, int shelves, bool open_along_x,
                 const std::string& label) {
  const double t = 0.02;
  if (open_along_x) {  // sides are at y = lo.y / hi.y
    s.addBoxAabb(V(lo.x(), lo.y(), lo.z()), V(hi.x(), lo.y() + t, hi.z()), label + " side");
    s.addBoxAabb(V(lo.x(), hi.y() - t, lo.z()), V(hi.x(), hi.y(), hi.z()), label + " side");
  } else {  // sides at x = lo.x / hi.x
    s.addBoxAabb(V(lo.x(), lo.y(), lo.z()), V(lo.x() + t, hi.y(), hi.z()), label + " side");
    s.addBoxAabb(V(hi.x() - t, lo.y(), lo.z()), V(hi.x(), hi.y(), hi.z()), label + " side");
  }
  for (int i = 0; i <= shelves; ++i) {
    const double z = lo.z() + 0.05 + i * (hi.z() - lo.z() - 0.05 - t) / shelves;
    s.addBoxAabb(V(lo.x(), lo.y(), z), V(hi.x(), hi.y(), z + t), label + " shelf");
  }
}

/// Simple dining chair at (x, y) (seat centre), rotated by yaw (rad), with its back on the -x
/// side of its own frame.
void addSimpleChair(Scene& s, double x, double y, double yaw, const std::string& label) {
  const Eigen::Isometry3d T = Eigen::Translation3d(x, y, 0.0) * Eigen::AngleAxisd(yaw, V::UnitZ());
  auto at = [&](double lx, double ly, double lz) { return T * V(lx, ly, lz); };
  const double hs = 0.2;
  for (double lx : {-hs, hs})
    for (double ly : {-hs, hs})
      s.addCylinder(at(lx, ly, 0.0), at(lx, ly, 0.44), 0.015, label + " leg");
  s.addBox(at(0, 0, 0.455), yaw, V(0.22, 0.22, 0.015), label + " seat");
  s.addBox(at(-hs, 0, 0.7), yaw, V(0.015, 0.22, 0.18), label + " back");
}

}  // namespace

Scene chairRoomScene() {
  Scene s;
  s.name = "chair_room";
  // Room: the camera starts at (0, 0, 0.80) looking along +x; the back wall is 3.2 m ahead
  // (thesis fig. 5.11/5.13 context). Side walls are close enough to be seen near the back wall,
  // so yaw and sway are observed by more than one plane.
  addRoomShell(s, -1.5, 3.2, -1.8, 1.7, 2.5);
  s.addBoxAabb(V(3.185, -1.8, 0.0), V(3.2, 1.7, 0.10), "skirting board");

  // Chair with its back towards the camera (the back's horizontal bars face the camera,
  // thesis fig. 5.20). Rear legs continue up as the back posts.
  const double xb = 2.16, xf = 2.54, yl = 0.2, r_leg = 0.015;
  for (double y : {-yl, yl}) {
    s.addCylinder(V(xb, y, 0.0), V(xb, y, 0.93), r_leg, "chair back post");
    s.addCylinder(V(xf, y, 0.0), V(xf, y, 0.43), r_leg, "chair front leg");
    s.addCylinder(V(xb, y, 0.16), V(xf, y, 0.16), 0.009, "chair side stretcher");
  }
  s.addCylinder(V(xf, -yl, 0.2), V(xf, yl, 0.2), 0.009, "chair front stretcher");
  s.addBoxAabb(V(xb - 0.02, -0.22, 0.43), V(xf + 0.02, 0.22, 0.455), "chair seat");
  for (double z : {0.57, 0.68, 0.79})
    s.addBoxAabb(V(xb - 0.01, -yl, z), V(xb + 0.01, yl, z + 0.035), "chair back bar");
  s.addBoxAabb(V(xb - 0.02, -yl - 0.02, 0.88), V(xb + 0.02, yl + 0.02, 0.94), "chair top rail");

  // Table on the left, partly behind the chair.
  addTable(s, 2.35, 3.05, 0.55, 1.55, 0.73, 0.045, "table");
  s.addCylinder(V(2.8, 1.25, 0.73), V(2.8, 1.25, 0.95), 0.05, "table lamp stem");
  s.addSphere(V(2.8, 1.25, 1.05), 0.11, "table lamp shade");

  // Radiator 0.1 m off the back wall, to the right of the chair.
  addRadiatorX(s, 3.2, -1, 0.10, -1.25, -0.45, 8, "radiator");

  // Beach ball on the floor, front right (thesis fig. 5.3/5.4).
  s.addSphere(V(1.95, -0.75, 0.25), 0.25, "beach ball");

  // Bookcase on the right wall and a shelf with a vase above the radiator.
  addBookcase(s, V(1.1, -1.8, 0.0), V(1.9, -1.5, 1.8), 4, false, "bookcase");
  s.addBoxAabb(V(2.95, -1.35, 1.25), V(3.2, -0.35, 1.28), "wall shelf");
  s.addCylinder(V(3.07, -1.05, 1.28), V(3.07, -1.05, 1.50), 0.06, "vase");
  s.addBoxAabb(V(3.0, -0.75, 1.28), V(3.14, -0.45, 1.46), "box on shelf");
  s.addBoxAabb(V(3.17, 0.1, 1.3), V(3.2, 0.75, 1.75), "picture frame");
  return s;
}

Scene furnishedRoomScene() {
  Scene s;
  s.name = "furnished_room";
  addRoomShell(s, -2.8, 2.8, -2.3, 2.3, 2.5);
  // Sofa along +y wall.
  s.addBoxAabb(V(-1.2, 1.45, 0.0), V(1.0, 2.3, 0.42), "sofa base");
  s.addBoxAabb(V(-1.2, 2.05, 0.42), V(1.0, 2.3, 0.85), "sofa back");
  s.addBoxAabb(V(-1.2, 1.45, 0.42), V(-1.0, 2.05, 0.62), "sofa arm");
  s.addBoxAabb(V(0.8, 1.45, 0.42), V(1.0, 2.05, 0.62), "sofa arm");
  s.addBox(V(-0.5, 1.75, 0.52), 0.3, V(0.2, 0.06, 0.16), "cushion");
  // Bookcase along -x wall.
  addBookcase(s, V(-2.8, -1.5, 0.0), V(-2.45, -0.3, 1.9), 5, true, "bookcase");
  // TV on a stand against +x wall.
  s.addBoxAabb(V(2.35, -0.8, 0.0), V(2.8, 0.6, 0.5), "tv stand");
  s.addBoxAabb(V(2.5, -0.55, 0.75), V(2.56, 0.55, 1.4), "tv");
  s.addBoxAabb(V(2.45, -0.15, 0.5), V(2.6, 0.15, 0.75), "tv foot");
  // Armchair in the (-x, +y) corner, turned 45 degrees.
  s.addBox(V(-2.1, 1.6, 0.22), -M_PI / 4, V(0.4, 0.4, 0.22), "armchair base");
  s.addBox(V(-2.35, 1.85, 0.6), -M_PI / 4, V(0.12, 0.4, 0.25), "armchair back");
  // Dining corner (+x, -y): table and two chairs.
  addTable(s, 1.3, 2.3, -2.2, -1.4, 0.74, 0.05, "dining table");
  addSimpleChair(s, 1.55, -1.2, -M_PI / 2, "dining chair");
  addSimpleChair(s, 2.05, -1.2, -M_PI / 2, "dining chair");
  // Radiator under the window on the -y wall, window sill above it.
  addRadiatorY(s, -2.3, +1, 0.06, -1.2, -0.2, 6, "radiator");
  s.addBoxAabb(V(-1.3, -2.3, 0.9), V(-0.1, -2.12, 0.93), "window sill");
  // Door frame on the -x wall near the +y corner... placed at y in [0.3, 1.2].
  s.addBoxAabb(V(-2.8, 0.3, 0.0), V(-2.72, 0.38, 2.05), "door frame");
  s.addBoxAabb(V(-2.8, 1.12, 0.0), V(-2.72, 1.2, 2.05), "door frame");
  s.addBoxAabb(V(-2.8, 0.3, 2.05), V(-2.72, 1.2, 2.13), "door frame");
  // Pieces whose side faces pin down sliding along the two long walls.
  s.addBoxAabb(V(0.1, -2.3, 0.0), V(0.9, -1.85, 0.85), "chest of drawers");
  s.addBoxAabb(V(1.15, 1.8, 0.0), V(1.5, 2.2, 0.55), "side table");
  s.addCylinder(V(1.32, 2.0, 0.55), V(1.32, 2.0, 0.75), 0.05, "table lamp stem");
  s.addCylinder(V(1.32, 2.0, 0.75), V(1.32, 2.0, 0.95), 0.13, "table lamp shade");
  s.addCylinder(V(-1.45, 2.0, 0.0), V(-1.45, 2.0, 1.5), 0.015, "floor lamp pole");
  s.addCylinder(V(-1.45, 2.0, 1.5), V(-1.45, 2.0, 1.8), 0.18, "floor lamp shade");
  // Odds and ends on the floor.
  s.addCylinder(V(-1.7, -1.9, 0.0), V(-1.7, -1.9, 0.35), 0.14, "waste bin");
  s.addCylinder(V(2.3, 1.9, 0.0), V(2.3, 1.9, 0.3), 0.16, "plant pot");
  s.addSphere(V(2.3, 1.9, 0.6), 0.3, "plant");
  s.addSphere(V(-1.5, 1.1, 0.2), 0.2, "ball");
  s.addBoxAabb(V(-0.3, -2.3, 1.3), V(0.5, -2.27, 1.8), "picture");
  return s;
}

Scene wallCabinetScene() {
  Scene s;
  s.name = "wall_cabinet";
  addRoomShell(s, -2.5, 2.5, -2.0, 2.0, 2.5);
  // The +y wall: a tall cabinet whose front is parallel to it, and a shallow picture beside it.
  // Seen square on from the middle of the room (floor, ceiling and the cabinet's top out of
  // view), every surface in view shares one normal: only the outlines tell where along the wall
  // and at which height the camera is.
  s.addBoxAabb(V(-0.6, 1.55, 0.0), V(0.6, 2.0, 2.2), "cabinet");
  s.addBoxAabb(V(-1.3, 1.97, 1.1), V(-0.8, 2.0, 1.5), "picture");
  // The +x side: furniture with faces in every direction.
  addBookcase(s, V(2.15, -1.2, 0.0), V(2.5, 0.0, 1.9), 5, true, "bookcase");
  addSimpleChair(s, 1.6, 0.8, M_PI, "chair");
  s.addBox(V(1.9, -1.6, 0.25), 0.4, V(0.25, 0.2, 0.25), "box");
  s.addCylinder(V(2.1, 1.5, 0.0), V(2.1, 1.5, 0.9), 0.2, "column");
  s.addSphere(V(1.5, -0.4, 0.15), 0.15, "ball");
  return s;
}

namespace {

/// A wall along x at y = wall_y whose face points along `facing` (+1: +y, -1: -y), from x0 to
/// x1, with door openings [x, x + door_w_m] recessed `recess_m` into the wall: leaf, both
/// reveals and the soffit are modelled, so each door adds faces across the corridor axis.
void addWallWithDoors(Scene& s, double wall_y, int facing, double x0, double x1, double height,
                      std::vector<double> doors, const std::string& label) {
  const double door_w = 0.85, door_h = 2.05, recess = 0.12;
  const V n(0.0, facing, 0.0);
  const double back_y = wall_y - facing * recess;  // the leaf sits behind the wall face
  std::sort(doors.begin(), doors.end());
  auto wallPiece = [&](double xa, double xb, double za, double zb) {
    if (xb - xa < 1e-6 || zb - za < 1e-6) return;
    s.addRectangle(V(0.5 * (xa + xb), wall_y, 0.5 * (za + zb)), n, 0.5 * (xb - xa), 0.5 * (zb - za),
                   label);
  };
  double x = x0;
  for (double d : doors) {
    wallPiece(x, d, 0.0, height);
    const double skirt_lo = std::min(wall_y, wall_y + facing * 0.015);
    if (d - x > 0.01)
      s.addBoxAabb(V(x, skirt_lo, 0.0), V(d, skirt_lo + 0.015, 0.1), label + " skirting board");
    wallPiece(d, d + door_w, door_h, height);  // above the door
    const double yc = 0.5 * (wall_y + back_y);
    s.addRectangle(V(d + 0.5 * door_w, back_y, 0.5 * door_h), n, 0.5 * door_w, 0.5 * door_h,
                   label + " door leaf");
    s.addRectangle(V(d, yc, 0.5 * door_h), V::UnitX(), 0.5 * recess, 0.5 * door_h,
                   label + " door reveal");
    s.addRectangle(V(d + door_w, yc, 0.5 * door_h), -V::UnitX(), 0.5 * recess, 0.5 * door_h,
                   label + " door reveal");
    s.addRectangle(V(d + 0.5 * door_w, yc, door_h), -V::UnitZ(), 0.5 * recess, 0.5 * door_w,
                   label + " door soffit", V::UnitX());
    // Architrave proud of the wall around the opening.
    const double ylo = std::min(wall_y, wall_y + facing * 0.025);
    const double yhi = ylo + 0.025;
    s.addBoxAabb(V(d - 0.07, ylo, 0.0), V(d, yhi, door_h + 0.07), label + " door frame");
    s.addBoxAabb(V(d + door_w, ylo, 0.0), V(d + door_w + 0.07, yhi, door_h + 0.07),
                 label + " door frame");
    s.addBoxAabb(V(d, ylo, door_h), V(d + door_w, yhi, door_h + 0.07), label + " door frame");
    x = d + door_w;
  }
  wallPiece(x, x1, 0.0, height);
  const double skirt_lo = std::min(wall_y, wall_y + facing * 0.015);
  s.addBoxAabb(V(x, skirt_lo, 0.0), V(x1, skirt_lo + 0.015, 0.1), label + " skirting board");
}

}  // namespace

Scene hallwayScene() {
  Scene s;
  s.name = "hallway";
  const double x0 = -1.0, x1 = 14.0, y0 = -0.8, y1 = 0.8, height = 2.4;
  const double cx = 0.5 * (x0 + x1), hx = 0.5 * (x1 - x0), hy = 0.5 * (y1 - y0);
  s.addRectangle(V(cx, 0.0, 0.0), V::UnitZ(), hy, hx, "floor", V::UnitX());
  s.addRectangle(V(cx, 0.0, height), -V::UnitZ(), hy, hx, "ceiling", V::UnitX());
  s.addRectangle(V(x1, 0.0, 0.5 * height), -V::UnitX(), hy, 0.5 * height, "end wall");
  s.addRectangle(V(x0, 0.0, 0.5 * height), V::UnitX(), hy, 0.5 * height, "front door wall");
  // Doors recessed into both long walls, on alternating sides.
  addWallWithDoors(s, y1, -1, x0, x1, height, {2.0, 8.5}, "left wall");
  addWallWithDoors(s, y0, +1, x0, x1, height, {5.0, 11.0}, "right wall");
  addRadiatorY(s, y1, -1, 0.05, 3.4, 4.4, 5, "radiator");
  addRadiatorY(s, y0, +1, 0.05, 9.2, 10.2, 5, "radiator");
  s.addBoxAabb(V(6.3, y0, 0.0), V(7.2, y0 + 0.4, 0.9), "cabinet");
  addTable(s, 2.2, 3.0, y0 + 0.02, y0 + 0.37, 0.8, 0.035, "console table");
  s.addBoxAabb(V(5.8, y1 - 0.35, 0.0), V(7.0, y1, 0.45), "bench");
  s.addBoxAabb(V(0.5, y1 - 0.3, 0.05), V(1.3, y1, 0.07), "shoe rack shelf");
  s.addBoxAabb(V(0.5, y1 - 0.3, 0.3), V(1.3, y1, 0.32), "shoe rack shelf");
  for (int i = 0; i < 4; ++i) {
    const double x = 0.5 + 0.25 * i;
    s.addCylinder(V(x, y1, 1.7), V(x, y1 - 0.1, 1.7), 0.012, "coat hook");
  }
  s.addBoxAabb(V(3.5, y0, 1.4), V(4.1, y0 + 0.02, 1.9), "picture");
  s.addBoxAabb(V(10.0, y1 - 0.02, 1.35), V(10.6, y1, 1.85), "picture");
  for (double x : {1.5, 6.0, 10.5})
    s.addCylinder(V(x, 0.0, 2.4), V(x, 0.0, 2.32), 0.15, "ceiling light");
  s.addCylinder(V(11.8, 0.55, 0.0), V(11.8, 0.55, 0.3), 0.14, "plant pot");
  s.addSphere(V(11.8, 0.55, 0.6), 0.28, "plant");
  s.addSphere(V(12.5, -0.3, 0.18), 0.18, "ball");
  return s;
}

Scene calibrationTargetScene(double diameter_m, double wall_gap_m, bool with_target) {
  Scene s;
  s.name = "calibration_target";
  const double wall_x = with_target ? wall_gap_m : 0.0;
  // Wide enough for the view from 4 m away; the floor runs from behind such a camera to the wall.
  s.addRectangle(V(wall_x, 0.0, 1.5), -V::UnitX(), 6.0, 3.0, "wall");
  s.addRectangle(V(0.5 * (wall_x - 5.0), 0.0, 0.0), V::UnitZ(), 6.0, 0.5 * (wall_x + 5.0), "floor",
                 V::UnitX());
  if (with_target) {
    s.addCylinder(V(0.0, 0.0, 1.0), V(0.02, 0.0, 1.0), 0.5 * diameter_m, "target disc");
    s.addCylinder(V(0.1, 0.0, 0.0), V(0.1, 0.0, 1.0), 0.02, "target post");
  }
  return s;
}

}  // namespace sim
}  // namespace depth_track
