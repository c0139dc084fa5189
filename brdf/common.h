#pragma once
// Shared vocabulary of the BRDF models (pbrt-v4 bxdfs.h conventions).
//
// Every direction lives in the local shading frame: z is the surface normal, both directions point
// away from the surface and are unit length. wo is the fixed direction (towards the camera or the
// previous path vertex), wi is the one a model samples. f(wo, wi) is the BRDF value in 1/sr per RGB
// channel, *without* the cosine factor; a renderer weights a sample by f * |cos(wi)| / pdf.

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>

#include "core/fast_atan.h"
#include "core/numbers.h"  // kPi

namespace mesoscan {

using Vec3 = Eigen::Vector3d;
using Vec2 = Eigen::Vector2d;
using Rgb = Eigen::Array3d;

inline constexpr double kInvPi = 1.0 / std::numbers::pi;

// One importance sample: the sampled direction, the BRDF value there and the solid-angle pdf.
struct BrdfSample {
  Vec3 wi;
  Rgb f;       // BRDF value (no cosine), 1/sr
  double pdf;  // density of wi per unit solid angle, > 0
};

// Rec. 709 luminance of a linear RGB triple.
inline double Luminance(const Rgb& c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

inline Vec3 Reflect(const Vec3& w, const Vec3& n) { return 2.0 * w.dot(n) * n - w; }

inline bool SameHemisphereUp(const Vec3& wo, const Vec3& wi) { return wo.z() > 0 && wi.z() > 0; }

// Unit vector from spherical angles (theta from +z, phi from +x towards +y).
inline Vec3 SphericalDirection(double theta, double phi) {
  const double s = std::sin(theta);
  return Vec3(s * std::cos(phi), s * std::sin(phi), std::cos(theta));
}

// Numerically stable polar angle of a unit vector (accurate near the pole, unlike acos):
// atan2(|xy|, z) by FastAtan2 (~2 ulp; glibc's asin here was ~2% of the demo's render).
inline double Elevation(const Vec3& d) {
  return FastAtan2(std::sqrt(d.x() * d.x() + d.y() * d.y()), d.z());
}

// Cosine-weighted hemisphere sampling (Malley's method over a concentric disk, pbrt-v4).
inline Vec3 SampleCosineHemisphere(const Vec2& u) {
  const double ox = 2 * u.x() - 1, oy = 2 * u.y() - 1;
  double r = 0, theta = 0;
  if (ox != 0 || oy != 0) {
    if (std::abs(ox) > std::abs(oy)) {
      r = ox;
      theta = 0.25 * kPi * (oy / ox);
    } else {
      r = oy;
      theta = 0.5 * kPi - 0.25 * kPi * (ox / oy);
    }
  }
  const double x = r * std::cos(theta), y = r * std::sin(theta);
  return Vec3(x, y, std::sqrt(std::max(0.0, 1 - x * x - y * y)));
}
inline double CosineHemispherePdf(double cos_theta) { return std::max(0.0, cos_theta) * kInvPi; }

}  // namespace mesoscan
