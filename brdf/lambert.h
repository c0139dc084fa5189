#pragma once
// Lambertian reflector: f = albedo / pi, sampled with the cosine-weighted hemisphere.

#include "brdf/common.h"

namespace mesoscan {

class LambertBrdf {
 public:
  static constexpr const char* Name() { return "lambert"; }
  // albedo: hemispherical reflectance per channel, each in [0, 1].
  explicit LambertBrdf(const Rgb& albedo = Rgb::Constant(0.5)) : albedo_(albedo) {}

  Rgb f(const Vec3& wo, const Vec3& wi) const {
    return SameHemisphereUp(wo, wi) ? Rgb(albedo_ * kInvPi) : Rgb::Zero();
  }
  std::optional<BrdfSample> Sample(const Vec3& wo, const Vec2& u) const {
    if (wo.z() <= 0) return std::nullopt;
    const Vec3 wi = SampleCosineHemisphere(u);
    const double pdf = CosineHemispherePdf(wi.z());
    if (pdf <= 0) return std::nullopt;
    return BrdfSample{wi, albedo_ * kInvPi, pdf};
  }
  double Pdf(const Vec3& wo, const Vec3& wi) const {
    return SameHemisphereUp(wo, wi) ? CosineHemispherePdf(wi.z()) : 0.0;
  }
  const Rgb& albedo() const { return albedo_; }

 private:
  Rgb albedo_;
};

}  // namespace mesoscan
