#pragma once
// Energy conservation ("white furnace") of measured BRDFs: the directional albedo
//   rho_c(wo) = int f_c(wo, wi) cos(theta_i) dwi
// must not exceed 1 for any wo and channel c. Measured data need not obey it: the RGL file
// satin_rosaline_rgb.bsdf reflects up to 1.156 of the incident light at theta_o = 85 deg (its
// grazing slices are fitted/extrapolated, not measured; a plain (theta, phi) quadrature of the raw
// tables gives the same figure, so it is the data, not our sampling). A renderer that bounces
// light off such a surface creates energy.
//
// EnergyClamp holds, on a grid of outgoing elevations, the albedo the file has (the original
// figures, for `mesoscan brdf info`) and the per-channel factor min(1, 0.997 / rho) the model
// applies, linear in theta between grid points (0.997: a margin for the estimate's own error and
// the interpolation, see energy.cc); a file whose albedo stays <= 1 is left untouched. The grid
// contains the file's own incident slices plus points between them, because interpolating between
// two slices can give more albedo than either slice has (satin: 1.09 at the 78.7 and 90 deg
// slices, 1.156 at 85 deg between them).

#include <functional>
#include <string>
#include <vector>

#include "brdf/common.h"

namespace mesoscan {

struct EnergyClamp {
  std::vector<double> theta;   // outgoing elevations (radians), ascending
  std::vector<Rgb> albedo;     // estimated directional albedo per channel, before the clamp
  std::vector<Rgb> scale;      // per channel min(1, 0.997 / albedo) where some albedo > 1, else 1
  std::vector<bool> is_slice;  // grid point is one of the file's own incident slices
  std::string slice_noun = "incident slices";  // what Summary() calls them
  bool exceeds = false;                        // some albedo > 1
  bool active = false;  // the scale is applied (exceeds, unless the caller opted out)

  // Factor at an elevation (radians): linear between grid points, constant beyond the ends;
  // exactly 1 when the clamp is inactive.
  Rgb Scale(double theta_o) const;
  // Largest albedo before the clamp over the grid and channels, where it is.
  double MaxAlbedo(double* theta_deg = nullptr, int* channel = nullptr) const;
  int Slices() const;         // the file's incident slices on the grid
  int SlicesClamped() const;  // ... whose albedo exceeds 1 in some channel
  // One line for `brdf info` / the load warning, e.g. "energy clamped: 2 of 8 incident slices
  // (theta_o 75.0-90.0 deg scaled), max albedo before 1.155 at 85.8 deg (R), after 0.997" or
  // "energy conserving: max albedo 0.995 at 68.0 deg (B), no clamp", or "NOT energy-conserving (not
  // clamped): ..." when the clamp exceeds but is inactive.
  std::string Summary() const;
};

// Deterministic estimate of rho(wo) per channel from f alone (no importance sampling): the
// midpoint rule on an n x n grid over the half vector in the parameterisation of Dupuy & Jakob 2018
// (u_theta = sqrt(2 theta_m / pi), u_phi = phi_m / 2 pi around wo), which resolves highlights
// near the mirror direction. Against a 384^2 grid on the shared RGL files: 0.84% worst at n = 48,
// 0.17% at n = 128.
Rgb HalfVectorAlbedo(const std::function<Rgb(const Vec3& wo, const Vec3& wi)>& f, const Vec3& wo,
                     int n);

// Builds the clamp (in parallel over theta): a cheap screen `screen_at(theta)` (e.g. 16^2
// stratified importance samples of the unclamped model), replaced by `albedo_at(theta, 96)`
// (HalfVectorAlbedo of the unclamped model) wherever a channel of the screen exceeds 0.95.
EnergyClamp BuildEnergyClamp(std::vector<double> theta, std::vector<bool> is_slice,
                             const std::function<Rgb(double theta)>& screen_at,
                             const std::function<Rgb(double theta, int n)>& albedo_at);
// Stratified importance-sampling estimate with n x n samples (the screen of BuildEnergyClamp).
template <typename Model>
Rgb StratifiedAlbedo(const Model& m, const Vec3& wo, int n) {
  Rgb sum = Rgb::Zero();
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      if (auto s = m.Sample(wo, Vec2((i + 0.5) / n, (j + 0.5) / n)))
        sum += s->f * s->wi.z() / s->pdf;
  return sum / (static_cast<double>(n) * n);
}

}  // namespace mesoscan
