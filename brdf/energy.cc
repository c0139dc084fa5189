#include "brdf/energy.h"

#include <algorithm>
#include <cstdio>

#include "core/error.h"
#include "core/parallel.h"

namespace mesoscan {
namespace {

constexpr double kDeg = 180 / kPi;
// Grid angles at most this far above the horizon are evaluated just above it (the albedo of a
// direction in the surface plane is a limit).
constexpr double kMaxEvalTheta = 89.95 / kDeg;
// Screening estimates (16^2 stratified importance samples, within ~2% on the shared files) above
// this get the accurate quadrature: n = 96, whose worst error against a 384^2 grid over 0..90 deg
// on the seven shared RGL files is 0.24% (cc_ibiza_sunset; 128^2: 0.17%). Everything else is
// far enough below 1 that its exact value does not matter for the clamp.
constexpr double kRefineAbove = 0.95;
constexpr int kFineN = 96;
// A clamped model is scaled to this albedo, not 1: the margin covers the fine estimate's error
// (<= 0.24%, above) and the linear interpolation of the scale between grid points, so the albedo
// stays <= 1 between grid points too (satin_rosaline after the clamp: <= 0.9992 every 0.2 deg
// from 70 to 89.9 deg with a 384^2 quadrature, at target 0.998 and n = 128).
constexpr double kTarget = 0.997;

}  // namespace

Rgb HalfVectorAlbedo(const std::function<Rgb(const Vec3& wo, const Vec3& wi)>& f, const Vec3& wo,
                     int n) {
  Rgb sum = Rgb::Zero();
  const double phi_o = std::atan2(wo.y(), wo.x());
  for (int j = 0; j < n; ++j) {
    const double phi_m = (2 * (j + 0.5) / n - 1) * kPi + phi_o;
    for (int i = 0; i < n; ++i) {
      const double u = (i + 0.5) / n, theta_m = u * u * (kPi / 2);
      const Vec3 wm = SphericalDirection(theta_m, phi_m);
      const double wo_dot_wm = wo.dot(wm);
      if (wo_dot_wm <= 0) continue;
      const Vec3 wi = Reflect(wo, wm);
      if (wi.z() <= 0) continue;
      // dwi = |d wi / d wm| |d wm / du| du = 4 (wo.wm) * 2 pi^2 u sin(theta_m) du.
      const double jacobian = 4 * wo_dot_wm * 2 * kPi * kPi * u * std::sin(theta_m);
      sum += f(wo, wi) * (wi.z() * jacobian);
    }
  }
  return sum / (static_cast<double>(n) * n);
}

EnergyClamp BuildEnergyClamp(std::vector<double> theta, std::vector<bool> is_slice,
                             const std::function<Rgb(double theta)>& screen_at,
                             const std::function<Rgb(double theta, int n)>& albedo_at) {
  MESOSCAN_CHECK(!theta.empty() && theta.size() == is_slice.size());
  for (size_t i = 0; i + 1 < theta.size(); ++i) MESOSCAN_CHECK(theta[i + 1] > theta[i]);
  EnergyClamp e;
  e.theta = std::move(theta);
  e.is_slice = std::move(is_slice);
  const size_t n = e.theta.size();
  e.albedo.assign(n, Rgb::Zero());
  e.scale.assign(n, Rgb::Ones());
  ParallelFor(static_cast<int64_t>(n), [&](int64_t i) {
    const double t = std::min(e.theta[i], kMaxEvalTheta);
    Rgb a = screen_at(t);
    if (a.maxCoeff() > kRefineAbove) a = albedo_at(t, kFineN);
    e.albedo[i] = a;
  });
  for (size_t i = 0; i < n; ++i)
    if ((e.albedo[i] > 1).any()) e.exceeds = e.active = true;
  if (!e.exceeds) return e;
  for (size_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c)
      if (e.albedo[i][c] > kTarget) e.scale[i][c] = kTarget / e.albedo[i][c];
  return e;
}

Rgb EnergyClamp::Scale(double theta_o) const {
  if (!active) return Rgb::Ones();
  if (theta_o <= theta.front()) return scale.front();
  if (theta_o >= theta.back()) return scale.back();
  const size_t i = std::upper_bound(theta.begin(), theta.end(), theta_o) - theta.begin() - 1;
  const double w = (theta_o - theta[i]) / (theta[i + 1] - theta[i]);
  return (1 - w) * scale[i] + w * scale[i + 1];
}

double EnergyClamp::MaxAlbedo(double* theta_deg, int* channel) const {
  double best = 0;
  for (size_t i = 0; i < albedo.size(); ++i)
    for (int c = 0; c < 3; ++c)
      if (albedo[i][c] > best) {
        best = albedo[i][c];
        if (theta_deg) *theta_deg = theta[i] * kDeg;
        if (channel) *channel = c;
      }
  return best;
}

int EnergyClamp::Slices() const {
  return static_cast<int>(std::count(is_slice.begin(), is_slice.end(), true));
}

int EnergyClamp::SlicesClamped() const {
  int n = 0;
  for (size_t i = 0; i < albedo.size(); ++i) n += is_slice[i] && (albedo[i] > 1).any();
  return n;
}

std::string EnergyClamp::Summary() const {
  double deg = 0;
  int ch = 0;
  const double max = MaxAlbedo(&deg, &ch);
  static const char* kChannel[3] = {"R", "G", "B"};
  char buf[256];
  if (!exceeds) {
    std::snprintf(buf, sizeof(buf), "energy conserving: max albedo %.3f at %.1f deg (%s), no clamp",
                  max, deg, kChannel[ch]);
    return buf;
  }
  double lo = 1e9, hi = -1;
  for (size_t i = 0; i < theta.size(); ++i)
    if ((scale[i] < 1).any()) {
      lo = std::min(lo, theta[i] * kDeg);
      hi = std::max(hi, theta[i] * kDeg);
    }
  if (!active) {
    std::snprintf(buf, sizeof(buf),
                  "NOT energy-conserving (not clamped): %d of %d %s exceed 1 (theta_o "
                  "%.1f-%.1f deg), max albedo %.3f at %.1f deg (%s)",
                  SlicesClamped(), Slices(), slice_noun.c_str(), lo, hi, max, deg, kChannel[ch]);
    return buf;
  }
  Rgb after = Rgb::Zero();
  for (size_t i = 0; i < albedo.size(); ++i) after = after.max(albedo[i] * scale[i]);
  std::snprintf(buf, sizeof(buf),
                "energy clamped: %d of %d %s (theta_o %.1f-%.1f deg scaled), max "
                "albedo before %.3f at %.1f deg (%s), after %.3f",
                SlicesClamped(), Slices(), slice_noun.c_str(), lo, hi, max, deg, kChannel[ch],
                after.maxCoeff());
  return buf;
}

}  // namespace mesoscan
