#include "brdf/brdf.h"

#include <cstring>
#include <fstream>
#include <sstream>

#include "core/error.h"

namespace mesoscan {

Brdf LoadBrdf(const std::filesystem::path& path, const MerlOptions& merl_options) {
  std::error_code ec;
  const auto st = std::filesystem::status(path, ec);
  if (std::filesystem::exists(st) && !std::filesystem::is_regular_file(st))
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::File(path),
        "expected a .bsdf or .binary file, got "
            << (std::filesystem::is_directory(st) ? "a folder" : "a special file"));
  std::ifstream in(path, std::ios::binary);
  if (!in) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot open file");
  char magic[12] = {};
  in.read(magic, sizeof(magic));
  if (in.gcount() < 12 && path.extension() == ".bsdf")
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::File(path),
        "truncated RGL tensor file: " << in.gcount() << " bytes, shorter than its 12-byte header");
  if (in.gcount() == 12 && std::memcmp(magic, "tensor_file", 12) == 0)
    return Brdf(RglBrdf::Load(path, merl_options.energy_clamp));
  return Brdf(MerlBrdf::Load(path, merl_options));
}

Rgb DirectionalAlbedo(const Brdf& brdf, const Vec3& wo, int n) {
  Rgb sum = Rgb::Zero();
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const Vec2 u((i + 0.5) / n, (j + 0.5) / n);
      if (auto s = brdf.Sample(wo, u)) sum += s->f * s->wi.z() / s->pdf;
    }
  return sum / (static_cast<double>(n) * n);
}

BrdfInfo DescribeBrdf(const Brdf& brdf) {
  BrdfInfo info;
  std::ostringstream res;
  if (const auto* rgl = brdf.Get<RglBrdf>()) {
    info.format = "RGL tensor_file (Dupuy & Jakob 2018), RGB";
    info.description = rgl->description();
    res << rgl->theta_i_count() << " theta_i x " << rgl->phi_i_count() << " phi_i, vndf "
        << rgl->vndf_resolution() << "^2, rgb " << rgl->rgb_resolution() << "^2, "
        << (rgl->isotropic() ? "isotropic" : "anisotropic");
    info.energy = rgl->energy().Summary();
  } else if (const auto* merl = brdf.Get<MerlBrdf>()) {
    info.format = "MERL binary";
    res << MerlBrdf::kThetaH << " theta_h x " << MerlBrdf::kThetaD << " theta_d x "
        << MerlBrdf::kPhiD << " phi_d, isotropic";
    if (merl->invalid_entries() > 0) res << ", " << merl->invalid_entries() << " unmeasured";
    info.energy = merl->energy().Summary();
  } else {
    info.format = std::string("analytic ") + brdf.Name();
    res << "analytic";
  }
  info.resolution = res.str();
  info.albedo_min = Rgb::Constant(1e300);
  info.albedo_max = Rgb::Constant(-1e300);
  double lum_min = 1e300, lum_max = -1e300;
  // Measured models: the deterministic half-vector quadrature of the energy clamp (0.17% worst on
  // the shared RGL files at 128^2); analytic ones: their exact importance sampling (the quadrature
  // cannot resolve a GGX lobe of alpha 0.001).
  const bool measured = brdf.Get<RglBrdf>() || brdf.Get<MerlBrdf>();
  const auto f = [&brdf](const Vec3& wo, const Vec3& wi) { return brdf.f(wo, wi); };
  for (int deg = 0; deg <= 85; deg += 5) {
    const double theta = deg * kPi / 180;
    const Vec3 wo = SphericalDirection(theta, 0.0);
    const Rgb a = measured ? HalfVectorAlbedo(f, wo, 128) : DirectionalAlbedo(brdf, wo, 48);
    info.albedo_min = info.albedo_min.min(a);
    info.albedo_max = info.albedo_max.max(a);
    if (Luminance(a) < lum_min) {
      lum_min = Luminance(a);
      info.albedo_min_theta_deg = deg;
    }
    if (Luminance(a) > lum_max) {
      lum_max = Luminance(a);
      info.albedo_max_theta_deg = deg;
    }
  }
  return info;
}

}  // namespace mesoscan
