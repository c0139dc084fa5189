#pragma once
// The closed set of BRDF models the renderer samples, behind one value type (pbrt-v4's
// TaggedPointer idea with std::variant): dispatch is a switch per call, no virtual call, and a Brdf
// is cheap to copy (measured tables are shared, immutable).
//
//   Brdf b = LoadBrdf("paper.bsdf");  // or Brdf(LambertBrdf(...)), Brdf(GgxBrdf<double>(...))
//   Rgb f = b.f(wo, wi);               // local frame, z = normal, no cosine
//   if (auto s = b.Sample(wo, u)) L += s->f * s->wi.z() / s->pdf * Li(s->wi);

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>
#include <variant>

#include "brdf/common.h"
#include "brdf/ggx.h"
#include "brdf/lambert.h"
#include "brdf/merl.h"
#include "brdf/rgl.h"

namespace mesoscan {

class Brdf {
 public:
  using Model = std::variant<LambertBrdf, GgxBrdf<double>, std::shared_ptr<const MerlBrdf>,
                             std::shared_ptr<const RglBrdf>>;

  Brdf(LambertBrdf m) : model_(std::move(m)) {}
  Brdf(GgxBrdf<double> m) : model_(std::move(m)) {}
  Brdf(std::shared_ptr<const MerlBrdf> m) : model_(std::move(m)) {
    MESOSCAN_CHECK(Get<MerlBrdf>());
  }
  Brdf(std::shared_ptr<const RglBrdf> m) : model_(std::move(m)) { MESOSCAN_CHECK(Get<RglBrdf>()); }

  Rgb f(const Vec3& wo, const Vec3& wi) const {
    return std::visit([&](const auto& m) { return Deref(m).f(wo, wi); }, model_);
  }
  std::optional<BrdfSample> Sample(const Vec3& wo, const Vec2& u) const {
    return std::visit([&](const auto& m) { return Deref(m).Sample(wo, u); }, model_);
  }
  double Pdf(const Vec3& wo, const Vec3& wi) const {
    return std::visit([&](const auto& m) { return Deref(m).Pdf(wo, wi); }, model_);
  }

  // The model's own name (each model's static Name(): "lambert", "ggx", "merl", "rgl").
  const char* Name() const {
    return std::visit([](const auto& m) { return std::decay_t<decltype(Deref(m))>::Name(); },
                      model_);
  }
  // True if the model is a T (LambertBrdf, GgxBrdf<double>, MerlBrdf, RglBrdf).
  template <typename T>
  bool Is() const {
    if constexpr (kHeldByValue<T>)
      return std::holds_alternative<T>(model_);
    else
      return Get<T>() != nullptr;
  }
  const Model& model() const { return model_; }
  // The measured table, or nullptr when the model is another kind.
  template <typename T>
  const T* Get() const {
    if (auto p = std::get_if<std::shared_ptr<const T>>(&model_)) return p->get();
    return nullptr;
  }

 private:
  // True if T is an alternative of Model itself (the analytic models; tables are shared_ptrs).
  template <typename T, typename V>
  struct Holds;
  template <typename T, typename... Ts>
  struct Holds<T, std::variant<Ts...>> : std::bool_constant<(std::is_same_v<T, Ts> || ...)> {};
  template <typename T>
  static constexpr bool kHeldByValue = Holds<T, Model>::value;

  template <typename T>
  static const T& Deref(const T& m) {
    return m;
  }
  template <typename T>
  static const T& Deref(const std::shared_ptr<const T>& m) {
    return *m;
  }

  Model model_;
};

// Loads a measured BRDF by content: "tensor_file" magic -> RGL .bsdf, else a MERL .binary. Throws
// Error(kBadInput) naming the file.
Brdf LoadBrdf(const std::filesystem::path& path, const MerlOptions& merl_options = {});

// Directional albedo rho(wo) = int f(wo, wi) cos(theta_i) dwi per channel, estimated with the
// model's own importance sampling on a fixed stratified grid of n x n samples (deterministic).
Rgb DirectionalAlbedo(const Brdf& brdf, const Vec3& wo, int n = 64);

struct BrdfInfo {
  std::string format;       // "RGL tensor_file (Dupuy & Jakob 2018)", "MERL binary", ...
  std::string description;  // the file's own description, if any
  std::string resolution;   // human-readable table sizes
  // Directional albedo over incident elevations 0..85 degrees (step 5), per channel.
  Rgb albedo_min, albedo_max;
  double albedo_min_theta_deg = 0,
         albedo_max_theta_deg = 0;  // where the luminance extremes are
  // Measured models: EnergyClamp::Summary() ("energy clamped: 2 of 8 incident slices ...");
  // analytic models: empty.
  std::string energy;
};
BrdfInfo DescribeBrdf(const Brdf& brdf);

}  // namespace mesoscan
