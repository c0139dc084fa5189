#include "render/env_map.h"

#include <cmath>

#include "core/error.h"
#include "core/image_io.h"

namespace mesoscan {

namespace {
constexpr double kTwoPi = 2.0 * kPi;

// Direction -> (u, v) in [0,1]^2 (see header) and back.
Vec2 DirectionToUv(const Vec3& w) {
  double u = 0.5 - std::atan2(w.y(), w.x()) / kTwoPi;
  if (u < 0) u += 1;
  if (u >= 1) u -= 1;
  const double v = Elevation(w) / kPi;
  return {u, std::clamp(v, 0.0, 1.0)};
}
Vec3 UvToDirection(const Vec2& uv) {
  return SphericalDirection(uv.y() * kPi, (0.5 - uv.x()) * kTwoPi);
}
}  // namespace

EnvironmentMap EnvironmentMap::Constant(const Rgb& radiance) {
  EnvironmentMap e;
  e.constant_ = true;
  e.constant_radiance_ = radiance.max(0.0);
  return e;
}

EnvironmentMap EnvironmentMap::FromImage(const ImageF& rgb, double scale) {
  if (rgb.width() < 2 || rgb.height() < 2 || rgb.channels() < 3)
    MESOSCAN_BAD_INPUT("environment map: expected an RGB lat-long image of at least 2x2, got "
                       << rgb.width() << "x" << rgb.height() << "x" << rgb.channels());
  EnvironmentMap e;
  e.constant_ = false;
  const int w = rgb.width(), h = rgb.height();
  e.rgb_ = ImageF(w, h, 3);
  double total = 0;
  for (int c = 0; c < 3; ++c)
    for (size_t i = 0; i < rgb.pixels(); ++i) {
      float v = rgb.channel(c)[i];
      v = std::isfinite(v) ? std::max(0.0f, v) * static_cast<float>(scale) : 0.0f;
      e.rgb_.channel(c)[i] = v;
      total += v;
    }
  if (!(total > 0)) MESOSCAN_BAD_INPUT("environment map: no light (all pixels are zero)");
  // Sampling density at the pixel centres (the warp's nodes), luminance x sin(theta), with a
  // small floor so every direction that has light keeps a positive density.
  std::vector<double> density(static_cast<size_t>(w) * h);
  double mean = 0;
  for (int y = 0; y < h; ++y) {
    const double s = std::sin((y + 0.5) / h * kPi);
    for (int x = 0; x < w; ++x) {
      const Rgb c(e.rgb_(x, y, 0), e.rgb_(x, y, 1), e.rgb_(x, y, 2));
      density[static_cast<size_t>(y) * w + x] = Luminance(c) * s;
      mean += density[static_cast<size_t>(y) * w + x];
    }
  }
  mean /= density.size();
  for (double& d : density) d += 1e-3 * mean;
  e.warp_ = Warp2D(w, h, std::move(density), {}, /*sampling=*/true, "environment map");
  return e;
}

EnvironmentMap EnvironmentMap::Load(const std::filesystem::path& path, double scale) {
  const ImageF im = ReadImage(path);
  if (im.channels() < 3)
    MESOSCAN_BAD_INPUT(path.string() << ": environment map: expected RGB channels, got "
                                     << im.channels());
  return FromImage(im, scale);
}

EnvironmentMap EnvironmentMap::Sky(double sun_elevation_deg, double sun_azimuth_deg, int width) {
  const int w = std::max(8, width), h = w / 2;
  ImageF im(w, h, 3);
  const double se = sun_elevation_deg * kPi / 180, sa = sun_azimuth_deg * kPi / 180;
  const Vec3 sun = SphericalDirection(0.5 * kPi - se, sa);
  // Sun: 0.53 degrees across would be a single texel at preview sizes; a 2-degree disk keeps it
  // resolvable while staying a hard, directional light (grazing light shows relief).
  const double sun_cos = std::cos(2.0 * kPi / 180);
  const Rgb zenith(0.25, 0.45, 0.95), horizon(0.85, 0.9, 1.0), ground(0.18, 0.16, 0.14);
  const Rgb sun_radiance(4000.0, 3700.0, 3200.0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const Vec3 d = UvToDirection({(x + 0.5) / w, (y + 0.5) / h});
      Rgb c;
      if (d.z() >= 0) {
        const double t = std::pow(1.0 - d.z(), 3.0);
        c = (1 - t) * zenith + t * horizon;
        // Brighter sky around the sun (a simple forward-scattering glow).
        c += Rgb(1.0, 0.9, 0.7) * 2.0 * std::pow(std::max(0.0, d.dot(sun)), 16.0);
        if (d.dot(sun) >= sun_cos) c += sun_radiance;
      } else {
        c = ground;
      }
      for (int k = 0; k < 3; ++k) im(x, y, k) = static_cast<float>(c[k]);
    }
  }
  return FromImage(im);
}

Rgb EnvironmentMap::Lookup(double u, double v) const {
  const int w = rgb_.width(), h = rgb_.height();
  const int x = std::clamp(static_cast<int>(u * w), 0, w - 1);
  const int y = std::clamp(static_cast<int>(v * h), 0, h - 1);
  return Rgb(rgb_(x, y, 0), rgb_(x, y, 1), rgb_(x, y, 2));
}

void EnvironmentMap::SetRotation(double degrees) {
  if (!std::isfinite(degrees)) MESOSCAN_BAD_INPUT("environment map: rotation must be finite");
  rotation_deg_ = degrees;
  cos_rot_ = std::cos(degrees * kPi / 180);
  sin_rot_ = std::sin(degrees * kPi / 180);
}

Vec3 EnvironmentMap::ToMap(const Vec3& w) const {
  return Vec3(cos_rot_ * w.x() + sin_rot_ * w.y(), -sin_rot_ * w.x() + cos_rot_ * w.y(), w.z());
}
Vec3 EnvironmentMap::FromMap(const Vec3& w) const {
  return Vec3(cos_rot_ * w.x() - sin_rot_ * w.y(), sin_rot_ * w.x() + cos_rot_ * w.y(), w.z());
}

std::filesystem::path EnvironmentMap::NamedPath(const std::string& name) {
  for (const auto& n : NamedEnvironments())
    if (n == name) {
      const std::filesystem::path p =
          std::filesystem::path("/usr/share/blender/datafiles/studiolights/world") / (name + ".exr");
      if (std::filesystem::exists(p)) return p;
    }
  return {};
}

std::vector<std::string> EnvironmentMap::NamedEnvironments() {
  return {"studio", "forest", "city", "courtyard", "interior", "night", "sunrise", "sunset"};
}

Rgb EnvironmentMap::Le(const Vec3& w) const {
  if (constant_) return constant_radiance_;
  const Vec2 uv = DirectionToUv(ToMap(w));
  return Lookup(uv.x(), uv.y());
}

std::optional<EnvSample> EnvironmentMap::Sample(const Vec2& u) const {
  if (constant_) return std::nullopt;
  // The warp's nodes sit at the pixel centres: node i <-> u = (i + 0.5) / w. Map the warp's
  // [0,1]^2 onto that span; the thin border strips outside it are never sampled, so their light
  // is carried by BRDF sampling (MIS handles the split exactly through Pdf()).
  const auto [p, pdf_warp] = warp_.Sample(u);
  const int w = rgb_.width(), h = rgb_.height();
  const Vec2 uv((0.5 + p.x() * (w - 1)) / w, (0.5 + p.y() * (h - 1)) / h);
  const double sin_theta = std::sin(uv.y() * kPi);
  if (!(pdf_warp > 0) || !(sin_theta > 0)) return std::nullopt;
  const double jac = (static_cast<double>(w - 1) / w) * (static_cast<double>(h - 1) / h);
  const double pdf = pdf_warp / jac / (kTwoPi * kPi * sin_theta);
  return EnvSample{FromMap(UvToDirection(uv)), Lookup(uv.x(), uv.y()), pdf};
}

double EnvironmentMap::Pdf(const Vec3& w) const {
  if (constant_) return 0.0;
  const Vec2 uv = DirectionToUv(ToMap(w));
  const int wd = rgb_.width(), ht = rgb_.height();
  const Vec2 p((uv.x() * wd - 0.5) / (wd - 1), (uv.y() * ht - 0.5) / (ht - 1));
  if (p.x() < 0 || p.x() > 1 || p.y() < 0 || p.y() > 1) return 0.0;
  const double sin_theta = std::sin(uv.y() * kPi);
  if (!(sin_theta > 0)) return 0.0;
  const double jac = (static_cast<double>(wd - 1) / wd) * (static_cast<double>(ht - 1) / ht);
  return warp_.Eval(p) / jac / (kTwoPi * kPi * sin_theta);
}

}  // namespace mesoscan
