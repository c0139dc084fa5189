#pragma once
// Environment lighting for the preview renderer: an equirectangular (lat-long) HDR map in the
// z-up world, importance-sampled texel by texel (piecewise constant density proportional to
// luminance x solid angle, matching the nearest-texel radiance), or a constant radiance that
// is not importance-sampled.
//
// Direction <-> image, Blender's world convention (so Blender's studio lights look the same):
//   u = 0.5 - atan2(y, x) / (2 pi), row v = theta / pi with theta the angle from +z (v = 0 is
//   the zenith, the top row of the image).

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "brdf/common.h"
#include "core/image.h"

namespace mesoscan {

struct EnvSample {
  Vec3 wi;     // world direction towards the light
  Rgb Le;      // radiance arriving from wi, W/(m^2 sr) in the map's units
  double pdf;  // per unit solid angle, > 0
};

class EnvironmentMap {
 public:
  // Uniform radiance from every direction.
  static EnvironmentMap Constant(const Rgb& radiance);
  // From an RGB lat-long image (>= 2x2, 3 channels, linear). Negative values (lossy EXR
  // compression) are clamped to 0. `scale` multiplies the radiance.
  static EnvironmentMap FromImage(const ImageF& rgb, double scale = 1.0);
  // Reads an EXR/HDR lat-long map; throws Error naming the file.
  static EnvironmentMap Load(const std::filesystem::path& path, double scale = 1.0);
  // A procedural clear sky with a sun: a smooth zenith-to-horizon gradient, a dim ground, and a
  // small bright sun disk at (sun_elevation_deg, sun_azimuth_deg from +x towards +y). Generated
  // by the project itself, so the demo needs no downloaded asset. width x width/2 pixels.
  static EnvironmentMap Sky(double sun_elevation_deg = 25.0, double sun_azimuth_deg = 200.0,
                            int width = 512);

  // Rotates the environment about +z by `degrees` (counter-clockwise seen from above): the light
  // that came from azimuth phi comes from phi + degrees. For turntables and light placement.
  void SetRotation(double degrees);
  double rotation_deg() const { return rotation_deg_; }

  // A named environment from Blender's studio lights (Debian package blender-data):
  // /usr/share/blender/datafiles/studiolights/world/NAME.exr (studio, forest, city, courtyard,
  // interior, night, sunrise, sunset). Empty if the name is unknown or the package is missing.
  static std::filesystem::path NamedPath(const std::string& name);
  static std::vector<std::string> NamedEnvironments();

  bool is_constant() const { return constant_; }
  // Radiance arriving from world direction w (unit).
  Rgb Le(const Vec3& w) const;
  // Importance-samples a direction (not available for a constant map: returns nullopt, the
  // renderer then relies on BRDF sampling alone).
  std::optional<EnvSample> Sample(const Vec2& u) const;
  // Solid-angle density of Sample() at w; 0 for a constant map.
  double Pdf(const Vec3& w) const;
  // Le(w) and Pdf(w) from one direction-to-texel conversion (one atan2/acos instead of two).
  Rgb LeAndPdf(const Vec3& w, double* pdf) const;
  // Irradiance on an upward-facing horizontal surface from the upper hemisphere,
  // E = int_{z > 0} Le(w) cos(theta) dw per channel, exact for the nearest-texel radiance Le()
  // returns (each texel's cos-weighted solid angle is integrated in closed form:
  // dphi (sin^2 theta1 - sin^2 theta0) / 2, the horizon row clipped at theta = pi/2). Invariant
  // under SetRotation. pi * L for a constant map. The renderer's control variate on the mount.
  Rgb UpperHemisphereIrradiance() const;
  const ImageF& image() const { return rgb_; }

 private:
  Rgb Lookup(double u, double v) const;
  Vec3 ToMap(const Vec3& w) const;    // world -> map frame (undo the rotation)
  Vec3 FromMap(const Vec3& w) const;  // map frame -> world
  double rotation_deg_ = 0, cos_rot_ = 1, sin_rot_ = 0;
  bool constant_ = true;
  Rgb constant_radiance_ = Rgb::Zero();
  ImageF rgb_;
  std::vector<double> row_cdf_;  // h + 1: cumulative mass of the rows
  std::vector<double> col_cdf_;  // h x (w + 1): cumulative mass within each row
};

}  // namespace mesoscan
