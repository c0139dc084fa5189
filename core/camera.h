#pragma once
// The OpenCV pinhole camera with 5-coefficient distortion [k1, k2, p1, p2, k3], templated on the
// scalar so Ceres autodiff differentiates the same code (COLMAP's camera models). Used for both
// camera and projector. Pixel (0,0) has its centre at (0.0, 0.0).

#include <array>
#include <cmath>

#include "core/transform.h"

namespace mesoscan {

struct PinholeCamera {
  int width = 0, height = 0;           // pixels
  Mat3d K = Mat3d::Identity();         // [[fx, s, cx], [0, fy, cy], [0, 0, 1]], pixels
  std::array<double, 5> distortion{};  // k1, k2, p1, p2, k3 (OpenCV order)
  Rigid3d world_from_device;           // device (x right, y down, z forward) -> world

  bool HasDistortion() const {
    for (double d : distortion)
      if (d != 0.0) return true;
    return false;
  }

  // Normalised image coordinates (x/z, y/z) -> distorted normalised coordinates. The
  // coefficients d may be a scalar type of their own (Ceres jets in calibration).
  template <typename D, typename T>
  static void Distort(const D* d, const T& x, const T& y, T* xd, T* yd) {
    const T r2 = x * x + y * y;
    const T radial = T(1) + r2 * (T(d[0]) + r2 * (T(d[1]) + r2 * T(d[4])));
    *xd = x * radial + (T(2) * T(d[2])) * x * y + T(d[3]) * (r2 + T(2) * x * x);
    *yd = y * radial + T(d[2]) * (r2 + T(2) * y * y) + (T(2) * T(d[3])) * x * y;
  }

  // Point in device coordinates -> pixel. Returns false if behind the device (z <= 0).
  template <typename T>
  bool ProjectDevice(const T* p, T* uv) const {
    if (!(p[2] > T(0))) return false;
    const T x = p[0] / p[2], y = p[1] / p[2];
    T xd, yd;
    Distort(distortion.data(), x, y, &xd, &yd);
    uv[0] = T(K(0, 0)) * xd + T(K(0, 1)) * yd + T(K(0, 2));
    uv[1] = T(K(1, 1)) * yd + T(K(1, 2));
    return true;
  }

  // The same model with every parameter of type T (calibration's bundle adjustment: Ceres
  // autodiff differentiates this code): intrinsics {fx, fy, cx, cy} (zero skew), distortion
  // {k1, k2, p1, p2, k3}, p a point in device coordinates. Returns false behind the device.
  template <typename T>
  static bool ProjectWithParams(const T* intrinsics, const T* distortion, const T* p, T* uv) {
    if (!(p[2] > T(0))) return false;
    const T x = p[0] / p[2], y = p[1] / p[2];
    T xd, yd;
    Distort(distortion, x, y, &xd, &yd);
    uv[0] = intrinsics[0] * xd + intrinsics[2];
    uv[1] = intrinsics[1] * yd + intrinsics[3];
    return true;
  }

  bool Project(const Vec3d& point_in_world, Vec2d* uv) const {
    const Vec3d p = world_from_device.Inverse() * point_in_world;
    return ProjectDevice(p.data(), uv->data());
  }

  // Pixel -> undistorted normalised coordinates (x/z, y/z), by Newton iteration on the
  // distortion model (exact to ~1e-12 for any realistic lens; OpenCV's undistortPoints uses a
  // fixed-point iteration that stops earlier).
  Vec2d UndistortNormalized(const Vec2d& uv) const;

  // Pixel -> unit ray direction in world coordinates; origin is CentreInWorld().
  Vec3d RayDirectionInWorld(const Vec2d& uv) const {
    const Vec2d n = UndistortNormalized(uv);
    return (world_from_device.rotation * Vec3d(n.x(), n.y(), 1.0)).normalized();
  }
  Vec3d CentreInWorld() const { return world_from_device.translation; }
};

}  // namespace mesoscan
