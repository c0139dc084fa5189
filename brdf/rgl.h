#pragma once
// Measured BRDFs of the RGL EPFL material database (Dupuy & Jakob 2018, "An Adaptive
// Parameterization for Efficient Material Acquisition and Rendering"), read from their
// "tensor_file" .bsdf files (RGB variants).
//
// The file tabulates, per incident direction (theta_i, phi_i), the BRDF on a grid that is warped by
// the visible-normal distribution (vndf) and by luminance, so sampling is two exact 2-D warps
// (luminance, then vndf) and evaluation is the inverse vndf warp plus a bilinear lookup. The stored
// values include the cosine of the sampled direction (checked by the white-furnace test in
// rgl_test.cc), so f() divides it out. The file's theta_i/phi_i describe our wo (the fixed
// direction); our wi is the direction the tables sample.
//
// Energy: some files reflect more light than they receive at grazing wo (satin_rosaline_rgb: up to
// 1.156). Load() estimates the directional albedo at every incident slice and between slices and,
// where a channel exceeds 1, scales f (and sampled values) at that elevation down to albedo 1
// (brdf/energy.h); energy() keeps the original figures, and one warning line names the file.

#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "brdf/common.h"
#include "brdf/energy.h"
#include "brdf/warp2d.h"

namespace mesoscan {

class RglBrdf {
 public:
  static constexpr const char* Name() { return "rgl"; }
  // Reads and validates a tensor file; throws Error(kBadInput) naming the file and the field
  // (missing, wrong type or shape, truncated data, non-finite or negative densities). Spectral
  // files (fields "spectra"/"wavelengths" instead of "rgb") are refused. energy_clamp = false keeps
  // the file's values as they are (for inspecting the raw data; energy() is still filled in).
  static std::shared_ptr<const RglBrdf> Load(const std::filesystem::path& path,
                                             bool energy_clamp = true);

  Rgb f(const Vec3& wo, const Vec3& wi) const;
  std::optional<BrdfSample> Sample(const Vec3& wo, const Vec2& u) const;
  double Pdf(const Vec3& wo, const Vec3& wi) const;

  const std::string& description() const { return description_; }
  bool isotropic() const { return isotropic_; }
  int theta_i_count() const { return theta_i_count_; }
  int phi_i_count() const { return phi_i_count_; }
  int vndf_resolution() const { return vndf_.width(); }  // vndf grid is square in practice
  int rgb_resolution() const { return rgb_[0].width(); }
  // Albedo per incident elevation before the clamp, and the clamp applied (inactive when the file
  // conserves energy or Load was asked not to clamp).
  const EnergyClamp& energy() const { return energy_; }

 private:
  RglBrdf() = default;
  // The part of eval/pdf shared by both: folds the directions by the file's symmetry and maps the
  // half vector into the unit square.
  struct Query {
    Vec3 wo, wi, wm;
    Vec2 u_wo, u_wm;
    double params[2];
  };
  std::optional<Query> MakeQuery(const Vec3& wo, const Vec3& wi) const;
  Rgb Value(const Vec2& sample, const Vec2& u_wm, const Vec2& u_wo, const double* params) const;

  std::string description_;
  bool isotropic_ = true;
  bool jacobian_ = false;
  int reduction_ = 1;
  int theta_i_count_ = 0, phi_i_count_ = 0;
  Warp2D ndf_, sigma_, vndf_, luminance_;
  Warp2D rgb_[3];
  EnergyClamp energy_;
};

}  // namespace mesoscan
