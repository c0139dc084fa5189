#pragma once
// atan2 to ~2 ulp, several times faster than glibc's correctly rounded one, and its reduced-range
// core for vector lanes (lens_shift_fit.cc's FitBlock). Shared by the lens-shift fitter and the
// phase-shift solver (which checks that the float it stores is the one std::atan2 would give).

#include <algorithm>
#include <cmath>

#include "core/numbers.h"

namespace mesoscan {

// atan(t) = t + t^3 P(t^2) for |t| <= tan(pi / 8): P interpolates (atan(s) - s) / s^3 at the 10
// Chebyshev nodes in t^2 (computed at 50 digits); the largest error of the double evaluation
// over the interval is 1.1e-16 (one rounding of atan).
constexpr double kAtanP[10] = {-0.3333333333333325,  0.19999999999898407,  -0.1428571426609662,
                               0.11111109636534361,  -0.09090852557176049, 0.0769105515839315,
                               -0.06649613695291669, 0.05736332165907643,  -0.04483334622272886,
                               0.02275052699336167};
constexpr double kTanPi8 = 0.41421356237309503;

// atan(u) for |u| <= tan(pi / 8) with the polynomial above in Estrin's scheme (short dependency
// chains; the same 1.1e-16 over the interval). T is double (FastAtan2) or a vector of doubles
// (FitBlock's lanes): one sequence of operations, so both round the same way. By reference: a
// vector passed or returned by value would change the ABI between the AVX2 clone and the default.
template <class T>
inline __attribute__((always_inline)) void AtanReduced(const T& u, T* at) {
  const T z = u * u, z2 = z * z, z4 = z2 * z2;
  const T p = ((kAtanP[0] + kAtanP[1] * z) + z2 * (kAtanP[2] + kAtanP[3] * z)) +
              z4 * (((kAtanP[4] + kAtanP[5] * z) + z2 * (kAtanP[6] + kAtanP[7] * z)) +
                    z4 * (kAtanP[8] + kAtanP[9] * z));
  *at = u + u * z * p;
}

// atan2(ay, ax) for ay, ax >= 0 from t = min / max of the two in [0, 1] (0 when both are 0):
// atan(t) through the reduced range, then reflected about the diagonal when ay > ax. The part of
// atan2 every form shares (FastAtan2, the phase-shift solver's and the lens-shift fitters'
// lanes); each forms t and applies the quadrant signs itself, as its scalar counterpart does.
template <class T>
inline __attribute__((always_inline)) void AtanOfRatio(const T& t, const T& ay, const T& ax,
                                                       T* at) {
  const auto big = t > kTanPi8;
  const T u = big ? (t - 1.0) / (t + 1.0) : t;
  AtanReduced(u, at);
  *at = big ? *at + 0.25 * kPi : *at;
  *at = ay > ax ? 0.5 * kPi - *at : *at;
}

// atan2(y, x) in [-pi, pi] to ~2 ulp (the same steps as FitBlock's lanes; glibc's atan2 is
// correctly rounded and several times slower). atan2(0, 0) = 0; NaN in, NaN out.
inline double FastAtan2(double y, double x) {
  if (std::isnan(x) || std::isnan(y)) return x + y;
  const double ay = std::abs(y), ax = std::abs(x);
  const double hi = std::max(ay, ax), lo = std::min(ay, ax);
  const double t = hi > 0.0 ? lo / hi : 0.0;
  double at;
  AtanOfRatio(t, ay, ax, &at);
  if (x < 0) at = kPi - at;
  return y < 0 ? -at : at;
}

}  // namespace mesoscan
