#pragma once
// Triangulation of a camera pixel with a decoded projector column: the camera ray (distortion
// removed, core/camera.h UndistortNormalized) intersected with the projector's surface of constant
// column u. Without projector distortion that surface is the plane through the projector centre
// containing the undistorted column (closed form); with distortion the column is a curve, so the
// point on the camera ray whose projection has column u is found by a 1-D Newton iteration
// started from the pinhole solution. With axis 'y' (horizontal fringes) the decoded coordinate
// is the projector row v and the surfaces are those of constant row; "column" and "u" below then
// mean row and v.

#include <cmath>
#include <optional>

#include "core/camera.h"

namespace mesoscan {

class Triangulator {
 public:
  // axis: 'x' (u is a projector column) or 'y' (u is a projector row).
  Triangulator(const PinholeCamera& camera, const PinholeCamera& projector, char axis = 'x');

  // Unit ray direction in world coordinates of camera pixel (x, y) (full-image pixel
  // coordinates, pixel centres at integers). The ray starts at camera.CentreInWorld().
  Vec3d CameraRay(double x, double y) const { return camera_.RayDirectionInWorld({x, y}); }

  // The world point on the ray (origin = camera centre, unit `ray_in_world`) whose projection
  // into the projector has column `u` (projector pixels). nullopt if the ray is parallel to the
  // column's surface, the point lies behind the camera or the projector, or Newton fails.
  std::optional<Vec3d> Intersect(const Vec3d& ray_in_world, double u) const {
    return IntersectDevice(ray_in_world, DeviceDirection(ray_in_world), u);
  }

  // The same in two steps, for several columns on one ray (triangulation and its dZ/du): the
  // ray's direction in projector device coordinates, then the intersection given it.
  Vec3d DeviceDirection(const Vec3d& ray_in_world) const {
    return proj_from_world_.rotation * ray_in_world;
  }
  std::optional<Vec3d> IntersectDevice(const Vec3d& ray_in_world, const Vec3d& ray_in_device,
                                       double u) const;

  // True if the column surfaces are planes (no projector distortion, no skew on the decoded
  // axis): IntersectDevice is then the closed form PinholeT, which per-pixel loops may call
  // inline (stage_triangulate.cc).
  bool closed_form() const { return !projector_distorted_ && !projector_skewed_; }
  // The ray parameter t of the closed form (the point is CentreInWorld() + t ray_in_world and
  // lies in front of the projector where t > 0 and z_device(t) > 0), IntersectDevice's
  // arithmetic in the same order. false where the ray is parallel to the plane.
  bool PinholeT(const Vec3d& ray_in_device, double u, double* t) const {
    const Vec3d& o = camera_centre_in_device_;
    const Vec3d& d = ray_in_device;
    const int a = axis_;
    const double xn = (u - projector_.K(a, 2)) / projector_.K(a, a);
    const double den = d[a] - xn * d.z();
    if (std::abs(den) < 1e-12) return false;
    *t = (xn * o.z() - o[a]) / den;
    return true;
  }
  // z of the point at t in projector device coordinates (IntersectDevice's test p.z() > 0).
  double DeviceZ(const Vec3d& ray_in_device, double t) const {
    return camera_centre_in_device_.z() + t * ray_in_device.z();
  }

  // CameraRay + Intersect.
  std::optional<Vec3d> Triangulate(double x, double y, double u) const {
    return Intersect(CameraRay(x, y), u);
  }

  const PinholeCamera& camera() const { return camera_; }
  const PinholeCamera& projector() const { return projector_; }

 private:
  PinholeCamera camera_, projector_;
  Rigid3d proj_from_world_;
  Vec3d camera_centre_in_device_;  // the rays' origin in projector device coordinates
  bool projector_distorted_ = false;
  bool projector_skewed_ = false;
  int axis_ = 0;  // 0: columns (x), 1: rows (y)
};

}  // namespace mesoscan
