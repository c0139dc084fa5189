#pragma once
// GGX (Trowbridge-Reitz) microfacet reflection with the height-correlated Smith masking-shadowing
// term and an exact dielectric or conductor Fresnel factor (Walter et al. 2007; Heitz 2014,
// "Understanding the masking-shadowing function", eq. 99). Sampling draws visible normals (Heitz
// 2018, "Sampling the GGX distribution of visible normals").
//
// Everything is templated on the scalar T so that Ceres can fit alpha / eta / k with autodiff
// through exactly the code the renderer evaluates (COLMAP camera-model style). Only +, *, /, sqrt
// and comparisons are used on T, all of which ceres::Jet supports.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <optional>
#include <type_traits>

#include "brdf/common.h"
#include "core/error.h"

namespace mesoscan {

enum class FresnelKind { kDielectric, kConductor };

template <typename T>
using Rgb_ = Eigen::Array<T, 3, 1>;
template <typename T>
using Vec3_ = Eigen::Matrix<T, 3, 1>;

// Unpolarised Fresnel reflectance of a dielectric interface seen from the outside; eta is the
// relative index n_inside / n_outside (> 0). Total internal reflection cannot happen from outside.
template <typename T>
T FresnelDielectric(T cos_i, T eta) {
  using std::sqrt;
  const T sin2_t = (T(1) - cos_i * cos_i) / (eta * eta);
  const T cos_t = sqrt(T(1) - sin2_t);
  const T r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  const T r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
  return T(0.5) * (r_parl * r_parl + r_perp * r_perp);
}

// Unpolarised Fresnel reflectance of a conductor with complex index eta + i k, in real arithmetic
// (Born & Wolf 1999, sec. 14.4.1; the same formula as pbrt-v4's FrComplex).
template <typename T>
T FresnelConductor(T cos_i, T eta, T k) {
  using std::sqrt;
  const T c2 = cos_i * cos_i, s2 = T(1) - c2, s4 = s2 * s2;
  const T t1 = eta * eta - k * k - s2;
  const T a2pb2 = sqrt(t1 * t1 + T(4) * k * k * eta * eta);
  const T a = sqrt(T(0.5) * (a2pb2 + t1));
  const T term1 = a2pb2 + c2, term2 = T(2) * a * cos_i;
  const T rs = (term1 - term2) / (term1 + term2);
  const T term3 = a2pb2 * c2 + s4, term4 = term2 * s2;
  const T rp = rs * (term3 - term4) / (term3 + term4);
  return T(0.5) * (rs + rp);
}

template <typename T>
class GgxBrdf {
 public:
  static constexpr const char* Name() { return "ggx"; }
  // alpha: GGX roughness (RMS slope / sqrt 2), in [1e-3, 1]. Smaller is
  // sharper. eta, k: per-channel complex index of refraction. kDielectric uses
  // eta only (k ignored);
  //   kConductor uses both (e.g. gold ~ eta (0.18, 0.42, 1.37), k
  //   (3.42, 2.35, 1.77)).
  GgxBrdf(T alpha, FresnelKind kind, const Rgb_<T>& eta, const Rgb_<T>& k = Rgb_<T>::Zero())
      : alpha_(alpha), kind_(kind), eta_(eta), k_(k) {}

  static GgxBrdf Dielectric(T alpha, T eta) {
    return GgxBrdf(alpha, FresnelKind::kDielectric, Rgb_<T>::Constant(eta));
  }
  static GgxBrdf Conductor(T alpha, const Rgb_<T>& eta, const Rgb_<T>& k) {
    return GgxBrdf(alpha, FresnelKind::kConductor, eta, k);
  }

  // Throws Error(kBadInput) naming the parameter when it is out of range.
  void Check() const {
    if (!(alpha_ >= T(1e-3) && alpha_ <= T(1)))
      MESOSCAN_BAD_INPUT("ggx: alpha " << alpha_ << " outside [0.001, 1]");
    for (int c = 0; c < 3; ++c) {
      if (!(eta_[c] > T(0))) MESOSCAN_BAD_INPUT("ggx: eta must be > 0");
      if (!(k_[c] >= T(0))) MESOSCAN_BAD_INPUT("ggx: k must be >= 0");
    }
  }

  // Microfacet distribution D(wm), normalised so that int D cos(theta_m) dw = 1 (Walter 2007 eq.
  // 33).
  T D(const Vec3_<T>& wm) const {
    const T a2 = alpha_ * alpha_;
    const T c2 = wm.z() * wm.z();
    const T d = c2 * (a2 - T(1)) + T(1);
    return a2 / (T(kPi) * d * d);
  }
  // Smith Lambda for GGX (Heitz 2014 eq. 72).
  T Lambda(const Vec3_<T>& w) const {
    using std::sqrt;
    const T c2 = w.z() * w.z();
    const T tan2 = (T(1) - c2) / c2;
    return (sqrt(T(1) + alpha_ * alpha_ * tan2) - T(1)) * T(0.5);
  }
  T G1(const Vec3_<T>& w) const { return T(1) / (T(1) + Lambda(w)); }
  T G(const Vec3_<T>& wo, const Vec3_<T>& wi) const {
    return T(1) / (T(1) + Lambda(wo) + Lambda(wi));
  }
  Rgb_<T> Fresnel(T cos_d) const {
    Rgb_<T> f;
    for (int c = 0; c < 3; ++c)
      f[c] = kind_ == FresnelKind::kDielectric ? FresnelDielectric(cos_d, eta_[c])
                                               : FresnelConductor(cos_d, eta_[c], k_[c]);
    return f;
  }

  // f = D G F / (4 cos_o cos_i) (Walter 2007 eq. 20); zero unless both are above the surface.
  Rgb_<T> f(const Vec3_<T>& wo, const Vec3_<T>& wi) const {
    if (!(wo.z() > T(0) && wi.z() > T(0))) return Rgb_<T>::Zero();
    Vec3_<T> wm = wo + wi;
    const T n2 = wm.squaredNorm();
    if (!(n2 > T(0))) return Rgb_<T>::Zero();
    using std::sqrt;
    wm /= sqrt(n2);
    const T cos_d = wo.dot(wm);
    return Fresnel(cos_d) * (D(wm) * G(wo, wi) / (T(4) * wo.z() * wi.z()));
  }

  // Density of visible normals, then the reflection Jacobian 1 / (4 wo.wm) (Heitz 2018 eq. 17).
  T Pdf(const Vec3_<T>& wo, const Vec3_<T>& wi) const {
    if (!(wo.z() > T(0) && wi.z() > T(0))) return T(0);
    Vec3_<T> wm = wo + wi;
    using std::sqrt;
    wm /= sqrt(wm.squaredNorm());
    const T cos_d = wo.dot(wm);
    if (!(cos_d > T(0))) return T(0);
    return G1(wo) * D(wm) / (T(4) * wo.z());
  }

  std::optional<BrdfSample> Sample(const Vec3& wo,
                                   const Vec2& u) const requires std::is_same_v<T, double> {
    if (wo.z() <= 0) return std::nullopt;
    const Vec3 wm = SampleVisibleNormal(wo, u);
    const Vec3 wi = Reflect(wo, wm);
    if (wi.z() <= 0) return std::nullopt;
    const double pdf = Pdf(wo, wi);
    if (!(pdf > 0)) return std::nullopt;
    return BrdfSample{wi, f(wo, wi), pdf};
  }

  T alpha() const { return alpha_; }
  FresnelKind kind() const { return kind_; }
  const Rgb_<T>& eta() const { return eta_; }
  const Rgb_<T>& k() const { return k_; }

 private:
  // Heitz 2018, listing 1 (isotropic alpha).
  Vec3 SampleVisibleNormal(const Vec3& wo, const Vec2& u) const {
    const Vec3 vh = Vec3(alpha_ * wo.x(), alpha_ * wo.y(), wo.z()).normalized();
    const double lensq = vh.x() * vh.x() + vh.y() * vh.y();
    const Vec3 t1 = lensq > 0 ? Vec3(-vh.y(), vh.x(), 0) / std::sqrt(lensq) : Vec3(1, 0, 0);
    const Vec3 t2 = vh.cross(t1);
    const double r = std::sqrt(u.x()), phi = 2 * kPi * u.y();
    const double p1 = r * std::cos(phi);
    double p2 = r * std::sin(phi);
    const double s = 0.5 * (1 + vh.z());
    p2 = (1 - s) * std::sqrt(std::max(0.0, 1 - p1 * p1)) + s * p2;
    const Vec3 nh = p1 * t1 + p2 * t2 + std::sqrt(std::max(0.0, 1 - p1 * p1 - p2 * p2)) * vh;
    return Vec3(alpha_ * nh.x(), alpha_ * nh.y(), std::max(1e-9, nh.z())).normalized();
  }

  T alpha_;
  FresnelKind kind_;
  Rgb_<T> eta_, k_;
};

}  // namespace mesoscan
