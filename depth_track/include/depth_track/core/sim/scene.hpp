#pragma once
/// Analytic scenes for the synthetic depth renderer (ROS-free, library depth_track_sim).
/// World frame W follows REP 103: x forward, y left, z up, floor at z = 0. Units: metres.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <string>
#include <vector>

namespace depth_track {
namespace sim {

/// Shape of a primitive, described in its own frame P.
enum class Shape {
  kRectangle,  ///< plane z = 0, |x| <= hx, |y| <= hy (both sides visible)
  kBox,        ///< solid box |x| <= hx, |y| <= hy, |z| <= hz
  kCylinder,   ///< solid capped cylinder, axis z, radius hx (= hy), |z| <= hz
  kSphere,     ///< solid sphere, radius hx (= hy = hz), centred at P's origin
};

/// One primitive: shape, pose T_W_P and half extents (see Shape for their meaning), metres.
struct Primitive {
  Shape shape = Shape::kBox;
  Eigen::Isometry3d T_W_P = Eigen::Isometry3d::Identity();
  Eigen::Vector3d half_extents = Eigen::Vector3d::Zero();
  std::string label;  ///< what it is ("chair leg"), for messages and debugging
};

/// Ray hit in a primitive's frame: parameter t along the ray (p = o + t d).
/// Returns the smallest t in [t_min, t_max] where the ray enters the surface, or nullopt.
/// For solids a ray starting inside does not hit (a camera never sits inside furniture).
/// Thread-safe.
std::optional<double> intersectLocal(const Primitive& prim, const Eigen::Vector3d& o_P,
                                     const Eigen::Vector3d& d_P, double t_min, double t_max);

/// Outward unit normal, in the primitive's frame, of the surface point p_P (a point returned by
/// intersectLocal; for a rectangle the +z side). Thread-safe.
Eigen::Vector3d surfaceNormalLocal(const Primitive& prim, const Eigen::Vector3d& p_P);

/// Unsigned distance from a world point p_W to the primitive's surface, metres. Thread-safe.
double distanceToSurface(const Primitive& prim, const Eigen::Vector3d& p_W);

/// A collection of primitives in the world frame.
struct Scene {
  std::string name;
  std::vector<Primitive> primitives;

  /// Unsigned distance from p_W to the nearest primitive's surface, metres (infinity for an
  /// empty scene). Thread-safe.
  double distanceTo(const Eigen::Vector3d& p_W) const;

  /// Axis-aligned rectangle in a wall/floor: centre c_W, unit normal n_W (any direction), and
  /// half sizes; `up_W` fixes the in-plane orientation (x of P ~ up_W x n_W).
  void addRectangle(const Eigen::Vector3d& c_W, const Eigen::Vector3d& n_W, double half_w_m,
                    double half_h_m, const std::string& label,
                    const Eigen::Vector3d& up_W = Eigen::Vector3d::UnitZ());
  /// Box spanning [min_W, max_W] (axis-aligned in W).
  void addBoxAabb(const Eigen::Vector3d& min_W, const Eigen::Vector3d& max_W,
                  const std::string& label);
  /// Box with centre c_W, yaw about z (rad) and half extents.
  void addBox(const Eigen::Vector3d& c_W, double yaw_rad, const Eigen::Vector3d& half_m,
              const std::string& label);
  /// Capped cylinder between the axis end points a_W and b_W with radius r_m.
  void addCylinder(const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W, double r_m,
                   const std::string& label);
  /// Sphere with centre c_W and radius r_m.
  void addSphere(const Eigen::Vector3d& c_W, double r_m, const std::string& label);

  /// Every problem (non-finite pose, non-positive sizes), naming the primitive; empty = valid.
  std::vector<std::string> validate() const;
};

/// The thesis's chair-in-a-room (XTest1_05_Chair, ch. 5.1-5.3): camera start at (0, 0, 0.80)
/// looking along +x; back wall at x = 3.2 m; chair with thin legs and back bars facing the
/// camera about 2.1-2.5 m ahead; table, radiator 0.1 m off the back wall, beach ball, shelves,
/// side walls, floor and ceiling.
Scene chairRoomScene();

/// Furnished living room (ServoTruck Room3): 5.6 m x 4.6 m, 2.5 m high, centred on the W
/// origin with an empty central area for a truck circling it; furniture along all walls.
Scene furnishedRoomScene();

/// Hallway (ServoTruck Hall1): 1.6 m wide, 2.4 m high, running along +x from x = -1 m to
/// x = 14 m, with doors recessed 0.12 m into the walls (leaf, reveals, soffit, architraves),
/// radiators, a cabinet, a bench, a console table and a shoe rack along the walls.
Scene hallwayScene();

/// Camera calibration set-up (thesis §4.1.3, table 4.2): a round target of `diameter_m` (a disc
/// 20 mm thick on a post behind it, so nothing but the disc lies in front of its outline) with its
/// face centred at (0, 0, 1.0) facing -x, a wall `wall_gap_m` behind the face, and the floor. A
/// camera at (-d, 0, 1.0) looking along +x sees the face at depth d. Without the target the wall
/// stands at x = 0 (the flat-wall test).
Scene calibrationTargetScene(double diameter_m = 0.6, double wall_gap_m = 0.6,
                             bool with_target = true);

/// Degenerate-view room (run wall_slide): 5 m x 4 m, 2.5 m high, centred on the W origin; on
/// the +y wall a 1.2 m wide, 0.45 m deep, 2.2 m tall cabinet and a 3 cm deep picture, whose
/// fronts are parallel to the wall; furniture with faces in every direction on the +x side.
Scene wallCabinetScene();

}  // namespace sim
}  // namespace depth_track
