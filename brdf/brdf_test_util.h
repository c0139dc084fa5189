#pragma once
// Statistical checks shared by the BRDF unit tests (pbrt-v4 bsdfs_test.cpp style). Test-only.

#include <Eigen/Core>
#include <functional>
#include <random>
#include <unsupported/Eigen/SpecialFunctions>
#include <vector>

#include "brdf/common.h"

namespace mesoscan::testing {

// Sample counts: the full figures under NDEBUG, a fifth in debug / sanitizer builds (the assertions
// stay the same; the chi-square test is valid at any count).
#ifdef NDEBUG
inline constexpr int kSampleScale = 5;
#else
inline constexpr int kSampleScale = 1;
#endif

// Integral of f over [a, b]: adaptive Simpson started from `pieces` equal parts, each refined until
// its error estimate is below eps (pbrt-v3 AdaptiveSimpson).
template <typename F>
double AdaptiveSimpson(const F& f, double a, double b, double eps = 1e-7, int max_depth = 8,
                       int pieces = 4) {
  auto rec = [&](auto&& self, double a0, double b0, double fa, double fm, double fb, double whole,
                 double tol, int depth) -> double {
    const double m = 0.5 * (a0 + b0), lm = 0.5 * (a0 + m), rm = 0.5 * (m + b0);
    const double flm = f(lm), frm = f(rm);
    const double left = (m - a0) / 6 * (fa + 4 * flm + fm);
    const double right = (b0 - m) / 6 * (fm + 4 * frm + fb);
    const double delta = left + right - whole;
    if (depth <= 0 || std::abs(delta) <= 15 * tol) return left + right + delta / 15;
    return self(self, a0, m, fa, flm, fm, left, tol / 2, depth - 1) +
           self(self, m, b0, fm, frm, fb, right, tol / 2, depth - 1);
  };
  double sum = 0;
  for (int i = 0; i < pieces; ++i) {
    const double a0 = a + (b - a) * i / pieces, b0 = a + (b - a) * (i + 1) / pieces;
    const double fa = f(a0), fb = f(b0), fm = f(0.5 * (a0 + b0));
    sum +=
        rec(rec, a0, b0, fa, fm, fb, (b0 - a0) / 6 * (fa + 4 * fm + fb), eps / pieces, max_depth);
  }
  return sum;
}

struct ChiSquareResult {
  double p_value = 0;           // probability of a chi-square at least this large under H0
  double significance = 0;      // threshold the p-value must exceed
  double pdf_integral = 0;      // quadrature of Pdf over the upper hemisphere
  double success_fraction = 0;  // fraction of Sample calls that returned a direction
  int samples = 0;
  int dof = 0;
  bool sample_outside_support = false;  // a sample landed in a bin where the pdf is zero
};

// Chi-square goodness of fit of Sample against Pdf for one wo, on a theta x phi grid over the upper
// hemisphere; cells with expected count < 5 are pooled (pbrt-v4 ChiSquareTest). `tests` is the
// number of such tests in the suite (Sidak correction of the 1% level).
template <typename Model>
ChiSquareResult ChiSquareTest(const Model& m, const Vec3& wo, int samples, int tests, uint32_t seed,
                              int theta_res = 10, int phi_res = 20) {
  ChiSquareResult r;
  r.samples = samples;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::vector<double> observed(theta_res * phi_res, 0.0), expected(theta_res * phi_res, 0.0);
  int ok = 0;
  for (int i = 0; i < samples; ++i) {
    const Vec2 u(uni(rng), uni(rng));
    const auto s = m.Sample(wo, u);
    if (!s || s->wi.z() <= 0) continue;
    ++ok;
    const double theta = std::acos(std::clamp(s->wi.z(), -1.0, 1.0));
    double phi = std::atan2(s->wi.y(), s->wi.x());
    if (phi < 0) phi += 2 * kPi;
    const int ti = std::min(theta_res - 1, static_cast<int>(theta / (kPi / 2) * theta_res));
    const int pi = std::min(phi_res - 1, static_cast<int>(phi / (2 * kPi) * phi_res));
    observed[ti * phi_res + pi] += 1;
  }
  r.success_fraction = static_cast<double>(ok) / samples;
  // Expected counts: nested adaptive Simpson over each cell in (theta, phi) with the sin(theta)
  // factor (pbrt-v3 AdaptiveSimpson2D), so narrow highlights are integrated accurately.
  double integral = 0;
  for (int ti = 0; ti < theta_res; ++ti)
    for (int pi = 0; pi < phi_res; ++pi) {
      const double t0 = ti * (kPi / 2) / theta_res, t1 = (ti + 1) * (kPi / 2) / theta_res;
      const double p0 = pi * 2 * kPi / phi_res, p1 = (pi + 1) * 2 * kPi / phi_res;
      auto inner = [&](double theta) {
        const double st = std::sin(theta);
        return AdaptiveSimpson(
            [&](double phi) {
              const Vec3 wi = SphericalDirection(theta, phi);
              return wi.z() > 1e-12 ? m.Pdf(wo, wi) * st : 0.0;
            },
            p0, p1);
      };
      const double cell = AdaptiveSimpson(inner, t0, t1);
      expected[ti * phi_res + pi] = cell * samples;
      integral += cell;
    }
  r.pdf_integral = integral;
  // Pool cells with small expectation, then the chi-square statistic.
  std::vector<int> order(expected.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return expected[a] < expected[b]; });
  double pooled_exp = 0, pooled_obs = 0, chsq = 0;
  int cells = 0;
  for (int i : order) {
    if (expected[i] == 0) {
      if (observed[i] > samples * 1e-5) r.sample_outside_support = true;
      continue;
    }
    if (expected[i] < 5) {
      pooled_exp += expected[i];
      pooled_obs += observed[i];
    } else if (pooled_exp > 0 && pooled_exp < 5) {
      pooled_exp += expected[i];
      pooled_obs += observed[i];
    } else {
      const double d = observed[i] - expected[i];
      chsq += d * d / expected[i];
      ++cells;
    }
  }
  if (pooled_exp > 0) {
    const double d = pooled_obs - pooled_exp;
    chsq += d * d / pooled_exp;
    ++cells;
  }
  r.dof = cells - 1;
  Eigen::ArrayXd a(1), x(1);
  a << 0.5 * r.dof;
  x << 0.5 * chsq;
  r.p_value = r.dof > 0 ? Eigen::igammac(a, x)(0) : 1.0;
  r.significance = 1.0 - std::pow(1.0 - 0.01, 1.0 / tests);
  return r;
}

// White-furnace check of one model: the directional albedo rho_c(wo) = E[f_c cos(theta_i) / pdf]
// estimated by plain Monte Carlo with the model's own importance sampling (i.i.d. uniform u from
// a fixed seed; a failed Sample() counts as 0), with its standard error from the sample variance,
// SE = sd / sqrt(n). This estimator shares nothing with the load-time albedo quadrature of the
// energy clamp (brdf/energy.h: midpoint rule over the half vector on f alone).
struct FurnaceEstimate {
  Rgb albedo = Rgb::Zero();
  Rgb standard_error = Rgb::Zero();
};
template <typename Model>
FurnaceEstimate EstimateAlbedo(const Model& m, const Vec3& wo, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  Rgb sum = Rgb::Zero(), sum2 = Rgb::Zero();
  for (int i = 0; i < n; ++i) {
    const Vec2 u(uni(rng), uni(rng));
    if (const auto s = m.Sample(wo, u)) {
      const Rgb w = s->f * s->wi.z() / s->pdf;
      sum += w;
      sum2 += w * w;
    }
  }
  FurnaceEstimate e;
  e.albedo = sum / n;
  const Rgb var = ((sum2 - sum * sum / n) / (n - 1)).max(0.0);
  e.standard_error = (var / n).sqrt();
  return e;
}

// One-sided standard-normal quantile z with P(Z > z) = p (bisection on erfc; p in (0, 0.5]).
inline double NormalUpperQuantile(double p) {
  double lo = 0, hi = 40;
  for (int i = 0; i < 200; ++i) {
    const double mid = 0.5 * (lo + hi);
    (0.5 * std::erfc(mid / std::sqrt(2.0)) > p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

// The outgoing elevations every furnace test visits: 0 to 89.5 degrees in 1.5-degree steps,
// offset by 0.25 so that most fall between the RGL files' incident slices and between the energy
// clamp's grid points, plus exactly 0 and 89.5.
inline std::vector<double> FurnaceElevationsDeg() {
  std::vector<double> d = {0.0};
  for (double t = 0.25; t < 89.5; t += 1.5) d.push_back(t);
  d.push_back(89.5);
  return d;
}

// Result of a white-furnace sweep of one model: the largest excess (albedo - 1) / SE and where.
struct FurnaceSweep {
  double worst_albedo = 0, worst_theta_deg = 0, worst_se = 0;
  double worst_z = -1e300;  // max over angles and channels of (albedo - 1) / SE
  int checks = 0;           // angle x channel comparisons made
};
template <typename Model>
FurnaceSweep SweepFurnace(const Model& m, const std::vector<double>& thetas_deg, int n,
                          uint32_t seed, double phi = 0.3) {
  FurnaceSweep r;
  for (double deg : thetas_deg) {
    const auto e = EstimateAlbedo(m, SphericalDirection(deg * kPi / 180, phi), n, seed++);
    for (int c = 0; c < 3; ++c) {
      ++r.checks;
      // SE 0 (a constant estimator, e.g. white Lambert): compare against rounding only.
      const double z = (e.albedo[c] - 1) / std::max(e.standard_error[c], 1e-12);
      if (e.albedo[c] > r.worst_albedo) {
        r.worst_albedo = e.albedo[c];
        r.worst_theta_deg = deg;
        r.worst_se = e.standard_error[c];
      }
      r.worst_z = std::max(r.worst_z, z);
    }
  }
  return r;
}

// Random direction in the upper hemisphere with cos(theta) >= min_cos.
inline Vec3 RandomUpperDirection(std::mt19937& rng, double min_cos = 0.0) {
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double z = min_cos + (1 - min_cos) * uni(rng);
  const double phi = 2 * kPi * uni(rng);
  const double r = std::sqrt(std::max(0.0, 1 - z * z));
  return Vec3(r * std::cos(phi), r * std::sin(phi), z);
}

}  // namespace mesoscan::testing
