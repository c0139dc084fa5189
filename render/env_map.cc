#include "render/env_map.h"

#include <algorithm>
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
  // Sampling density: piecewise constant over the texels, proportional to luminance x the
  // texel's solid angle (the sin(theta) integral over its row), matching the nearest-texel
  // radiance exactly, so NEE's weight Le / pdf is constant within a texel. (The bilinear warp
  // used before spread a small bright light's density into its dark neighbours: 2x the noise
  // of Cycles on studio.exr.) Texels without light get no density; BRDF sampling covers them
  // through MIS.
  e.row_cdf_.assign(h + 1, 0.0);
  e.col_cdf_.assign(static_cast<size_t>(h) * (w + 1), 0.0);
  for (int y = 0; y < h; ++y) {
    const double solid = std::cos(static_cast<double>(y) / h * kPi) - std::cos((y + 1.0) / h * kPi);
    double* cdf = &e.col_cdf_[static_cast<size_t>(y) * (w + 1)];
    for (int x = 0; x < w; ++x) {
      const Rgb c(e.rgb_(x, y, 0), e.rgb_(x, y, 1), e.rgb_(x, y, 2));
      cdf[x + 1] = cdf[x] + std::max(0.0, Luminance(c)) * solid;
    }
    e.row_cdf_[y + 1] = e.row_cdf_[y] + cdf[w];
  }
  if (!(e.row_cdf_[h] > 0)) MESOSCAN_BAD_INPUT("environment map: no light (all pixels are zero)");
  return e;
}

EnvironmentMap EnvironmentMap::Load(const std::filesystem::path& path, double scale) {
  const ImageF im = ReadImage(path);
  if (im.channels() < 3)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path),
                          "environment map: expected RGB channels, got " << im.channels());
  // Radiance is finite and >= 0: a NaN or negative texel is a damaged or foreign file, named.
  // Negatives within 1e-3 of the brightest texel are the ringing of a filtered or resampled map
  // (Blender's studio.exr holds -3e-6 against a peak of 118) and are read as 0.
  float peak = 0;
  for (const float v : im.data())
    if (std::isfinite(v)) peak = std::max(peak, v);
  const float floor = -1e-3f * peak;
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < im.height(); ++y)
      for (int x = 0; x < im.width(); ++x) {
        const float v = im(x, y, c);
        if (!(std::isfinite(v) && v >= floor))
          MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "environment map: texel ("
                                                           << x << ", " << y << ") channel " << c
                                                           << " is " << v
                                                           << ", expected a finite radiance >= 0");
      }
  try {
    return FromImage(im, scale);
  } catch (const Error& e) {
    // FromImage's refusals are about this file's pixels.
    if (e.kind() != ErrorKind::kBadInput || !e.file().empty()) throw;
    throw e.At(ErrorSite::File(path));
  }
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
          std::filesystem::path("/usr/share/blender/datafiles/studiolights/world") /
          (name + ".exr");
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
  const int w = rgb_.width(), h = rgb_.height();
  const double total = row_cdf_[h];
  // Row, then column within the row; the remainders of u place the point inside the texel
  // (keeping the sampler's stratification).
  const double ty = u.y() * total;
  int y =
      static_cast<int>(std::upper_bound(row_cdf_.begin(), row_cdf_.end(), ty) - row_cdf_.begin()) -
      1;
  y = std::clamp(y, 0, h - 1);
  while (y > 0 && !(row_cdf_[y + 1] > row_cdf_[y])) --y;
  const double row_mass = row_cdf_[y + 1] - row_cdf_[y];
  if (!(row_mass > 0)) return std::nullopt;
  const double fy = std::clamp((ty - row_cdf_[y]) / row_mass, 0.0, 1.0);
  const double* cdf = &col_cdf_[static_cast<size_t>(y) * (w + 1)];
  const double tx = u.x() * cdf[w];
  int x = static_cast<int>(std::upper_bound(cdf, cdf + w + 1, tx) - cdf) - 1;
  x = std::clamp(x, 0, w - 1);
  while (x > 0 && !(cdf[x + 1] > cdf[x])) --x;
  const double texel_mass = cdf[x + 1] - cdf[x];
  if (!(texel_mass > 0)) return std::nullopt;
  const double fx = std::clamp((tx - cdf[x]) / texel_mass, 0.0, 1.0);
  const Vec2 uv((x + fx) / w, (y + fy) / h);
  const double sin_theta = std::sin(uv.y() * kPi);
  if (!(sin_theta > 0)) return std::nullopt;
  // Uniform in (u, v) inside the texel: pdf_uv = P(texel) * w * h; per solid angle divide by
  // the Jacobian 2 pi^2 sin(theta).
  const double pdf = texel_mass / total * w * h / (kTwoPi * kPi * sin_theta);
  return EnvSample{FromMap(UvToDirection(uv)), Rgb(rgb_(x, y, 0), rgb_(x, y, 1), rgb_(x, y, 2)),
                   pdf};
}

Rgb EnvironmentMap::LeAndPdf(const Vec3& w, double* pdf) const {
  if (constant_) {
    *pdf = 0.0;
    return constant_radiance_;
  }
  const Vec2 uv = DirectionToUv(ToMap(w));
  const int wd = rgb_.width(), ht = rgb_.height();
  const int x = std::clamp(static_cast<int>(uv.x() * wd), 0, wd - 1);
  const int y = std::clamp(static_cast<int>(uv.y() * ht), 0, ht - 1);
  const double sin_theta = std::sin(uv.y() * kPi);
  const double* cdf = &col_cdf_[static_cast<size_t>(y) * (wd + 1)];
  *pdf = sin_theta > 0 ? (cdf[x + 1] - cdf[x]) / row_cdf_[ht] * wd * ht / (kTwoPi * kPi * sin_theta)
                       : 0.0;
  return Rgb(rgb_(x, y, 0), rgb_(x, y, 1), rgb_(x, y, 2));
}

Rgb EnvironmentMap::UpperHemisphereIrradiance() const {
  if (constant_) return kPi * constant_radiance_;
  const int w = rgb_.width(), h = rgb_.height();
  Rgb e = Rgb::Zero();
  for (int y = 0; y < h; ++y) {
    const double t0 = static_cast<double>(y) / h * kPi;
    if (t0 >= 0.5 * kPi) break;
    const double t1 = std::min((y + 1.0) / h * kPi, 0.5 * kPi);
    const double s0 = std::sin(t0), s1 = std::sin(t1);
    const double weight = (kTwoPi / w) * 0.5 * (s1 * s1 - s0 * s0);
    Rgb row = Rgb::Zero();
    for (int x = 0; x < w; ++x) row += Rgb(rgb_(x, y, 0), rgb_(x, y, 1), rgb_(x, y, 2));
    e += weight * row;
  }
  return e;
}

double EnvironmentMap::Pdf(const Vec3& w) const {
  if (constant_) return 0.0;
  const Vec2 uv = DirectionToUv(ToMap(w));
  const int wd = rgb_.width(), ht = rgb_.height();
  const int x = std::clamp(static_cast<int>(uv.x() * wd), 0, wd - 1);
  const int y = std::clamp(static_cast<int>(uv.y() * ht), 0, ht - 1);
  const double sin_theta = std::sin(uv.y() * kPi);
  if (!(sin_theta > 0)) return 0.0;
  const double* cdf = &col_cdf_[static_cast<size_t>(y) * (wd + 1)];
  return (cdf[x + 1] - cdf[x]) / row_cdf_[ht] * wd * ht / (kTwoPi * kPi * sin_theta);
}

}  // namespace mesoscan
