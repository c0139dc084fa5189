#include "heightfield/triangulate.h"

#include <cmath>

namespace mesoscan {

Triangulator::Triangulator(const PinholeCamera& camera, const PinholeCamera& projector, char axis)
    : camera_(camera), projector_(projector), axis_(axis == 'y' ? 1 : 0) {
  proj_from_world_ = projector.world_from_device.Inverse();
  camera_centre_in_device_ = proj_from_world_ * camera_.CentreInWorld();
  projector_distorted_ = projector.HasDistortion();
  // The row v = fy y/z + cy holds no skew term; only columns need Newton for a skewed K.
  projector_skewed_ = axis_ == 0 && projector.K(0, 1) != 0.0;
}

std::optional<Vec3d> Triangulator::IntersectDevice(const Vec3d& ray_in_world,
                                                   const Vec3d& ray_in_device, double u) const {
  // The ray in projector device coordinates: p(t) = o + t d.
  const Vec3d& o = camera_centre_in_device_;
  const Vec3d& d = ray_in_device;
  const int a = axis_;
  // Pinhole (zero-skew) plane x - xn z = 0 (rows: y - yn z = 0) through the projector centre.
  double t;
  if (!PinholeT(d, u, &t)) return std::nullopt;
  if (projector_distorted_ || projector_skewed_) {
    // Newton on g(t) = column(p(t)) - u; the derivative by central differences.
    auto column = [&](double tt, double* col) {
      const Vec3d p = o + tt * d;
      double uv[2];
      if (!projector_.ProjectDevice(p.data(), uv)) return false;
      *col = uv[a];
      return true;
    };
    bool converged = false;
    for (int it = 0; it < 20; ++it) {
      double g0;
      if (!column(t, &g0)) return std::nullopt;
      g0 -= u;
      if (std::abs(g0) < 1e-10) {
        converged = true;
        break;
      }
      const double h = 1e-7 * std::max(1e-3, std::abs(t));
      double gp, gm;
      if (!column(t + h, &gp) || !column(t - h, &gm)) return std::nullopt;
      const double slope = (gp - gm) / (2 * h);
      if (!(std::abs(slope) > 0)) return std::nullopt;
      const double step = g0 / slope;
      t -= step;
      if (std::abs(step) < 1e-13 * std::max(1.0, std::abs(t))) {
        converged = true;
        break;
      }
    }
    if (!converged) return std::nullopt;
  }
  if (!(t > 0) || !std::isfinite(t)) return std::nullopt;
  const Vec3d p = o + t * d;
  if (!(p.z() > 0)) return std::nullopt;
  return camera_.CentreInWorld() + t * ray_in_world;
}

}  // namespace mesoscan
