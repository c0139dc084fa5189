#include "brdf/brdf.h"

#include <gtest/gtest.h>

#include "brdf/brdf_test_util.h"

namespace mesoscan {
namespace {
using testing::ChiSquareTest;
using testing::kSampleScale;
using testing::MaxDirectionalAlbedo;
using testing::RandomUpperDirection;

// Gold, from pbrt-v4's Au spectrum integrated to sRGB primaries (approximate).
const Rgb kGoldEta(0.143, 0.374, 1.442), kGoldK(3.983, 2.385, 1.603);

std::vector<std::pair<std::string, Brdf>> AnalyticModels() {
  return {
      {"lambert", Brdf(LambertBrdf(Rgb(0.9, 0.5, 0.1)))},
      {"ggx_dielectric_0.3", Brdf(GgxBrdf<double>::Dielectric(0.3, 1.5))},
      {"ggx_dielectric_0.05", Brdf(GgxBrdf<double>::Dielectric(0.05, 1.5))},
      {"ggx_conductor_0.2", Brdf(GgxBrdf<double>::Conductor(0.2, kGoldEta, kGoldK))},
      {"ggx_conductor_0.8", Brdf(GgxBrdf<double>::Conductor(0.8, kGoldEta, kGoldK))},
  };
}

TEST(Brdf, ChiSquareSamplingMatchesPdf) {
  const auto models = AnalyticModels();
  const std::vector<double> thetas = {5, 40, 75};
  const int tests = static_cast<int>(models.size() * thetas.size());
  uint32_t seed = 1;
  for (const auto& [name, brdf] : models)
    for (double deg : thetas) {
      const Vec3 wo = SphericalDirection(deg * kPi / 180, 0.4);
      const auto r = ChiSquareTest(brdf, wo, 40000 * kSampleScale, tests, seed++);
      EXPECT_GT(r.p_value, r.significance) << name << " theta_o " << deg << " dof " << r.dof;
      EXPECT_FALSE(r.sample_outside_support) << name << " theta_o " << deg;
      // Sampled mass that stays above the horizon equals the pdf's integral there (binomial noise
      // of the success fraction, 5 sigma, plus quadrature error).
      const double sigma =
          std::sqrt(r.success_fraction * (1 - r.success_fraction) / r.samples) + 1e-3;
      EXPECT_NEAR(r.pdf_integral, r.success_fraction, 5 * sigma) << name << " theta_o " << deg;
      EXPECT_LE(r.pdf_integral, 1.0 + 2e-3) << name;
    }
}

TEST(Brdf, LambertPdfIntegratesToOne) {
  const LambertBrdf lambert(Rgb::Constant(0.5));
  const auto r = ChiSquareTest(lambert, SphericalDirection(0.7, 0.0), 1000, 1, 7);
  EXPECT_NEAR(r.pdf_integral, 1.0, 1e-4);
  EXPECT_EQ(r.success_fraction, 1.0);
}

TEST(Brdf, WhiteFurnaceAlbedoAtMostOne) {
  for (const auto& [name, brdf] : AnalyticModels()) {
    double worst_deg = 0;
    const double a = MaxDirectionalAlbedo(brdf, 48, &worst_deg);
    // Stratified importance sampling of a bounded integrand: error well under 1%.
    EXPECT_LE(a, 1.0 + 1e-2) << name << " at theta_o " << worst_deg;
  }
  // A white Lambertian reflector is exactly 1.
  const double white = MaxDirectionalAlbedo(LambertBrdf(Rgb::Ones()), 16);
  EXPECT_NEAR(white, 1.0, 1e-9);
}

TEST(Brdf, GgxConductorWithIdealMetalIsNearlyLossless) {
  // A perfect mirror-like conductor (huge k) on a smooth surface reflects nearly everything at
  // normal incidence: single-scattering GGX loses < 2% at alpha 0.05 (Heitz 2016 fig. 2).
  const GgxBrdf<double> ggx =
      GgxBrdf<double>::Conductor(0.05, Rgb::Constant(1.0), Rgb::Constant(1e4));
  Rgb sum = Rgb::Zero();
  const int n = 64;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      if (auto s = ggx.Sample(Vec3(0, 0, 1), Vec2((i + 0.5) / n, (j + 0.5) / n)))
        sum += s->f * s->wi.z() / s->pdf;
  EXPECT_GT(sum[0] / (n * n), 0.98);
  EXPECT_LE(sum[0] / (n * n), 1.0 + 1e-6);
}

TEST(Brdf, Reciprocity) {
  std::mt19937 rng(3);
  for (const auto& [name, brdf] : AnalyticModels())
    for (int i = 0; i < 2000; ++i) {
      const Vec3 a = RandomUpperDirection(rng), b = RandomUpperDirection(rng);
      const Rgb fab = brdf.f(a, b), fba = brdf.f(b, a);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(fab[c], fba[c], 1e-9 * (1 + fab[c])) << name;
    }
}

TEST(Brdf, FresnelLimits) {
  // Normal incidence: ((eta - 1) / (eta + 1))^2 = 0.04 for glass; grazing: 1.
  EXPECT_NEAR(FresnelDielectric(1.0, 1.5), 0.04, 1e-12);
  EXPECT_NEAR(FresnelDielectric(1e-9, 1.5), 1.0, 1e-6);
  // Conductor at normal incidence: ((n-1)^2 + k^2) / ((n+1)^2 + k^2).
  const double n = 0.2, k = 3.0;
  EXPECT_NEAR(FresnelConductor(1.0, n, k),
              ((n - 1) * (n - 1) + k * k) / ((n + 1) * (n + 1) + k * k), 1e-12);
  // With k = 0 the conductor formula is the dielectric one.
  for (double c : {0.1, 0.5, 0.9})
    EXPECT_NEAR(FresnelConductor(c, 1.5, 0.0), FresnelDielectric(c, 1.5), 1e-12);
}

TEST(Brdf, GgxCheckRejectsBadParameters) {
  EXPECT_THROW(GgxBrdf<double>::Dielectric(0.0, 1.5).Check(), Error);
  EXPECT_THROW(GgxBrdf<double>::Dielectric(0.3, -1.0).Check(), Error);
  EXPECT_NO_THROW(GgxBrdf<double>::Dielectric(0.3, 1.5).Check());
}

TEST(Brdf, BelowHorizonIsZero) {
  for (const auto& [name, brdf] : AnalyticModels()) {
    const Vec3 up(0, 0.6, 0.8), down(0, 0.6, -0.8);
    EXPECT_EQ(brdf.f(up, down).maxCoeff(), 0.0) << name;
    EXPECT_EQ(brdf.Pdf(down, up), 0.0) << name;
    EXPECT_FALSE(brdf.Sample(down, Vec2(0.3, 0.3)).has_value()) << name;
  }
}

}  // namespace
}  // namespace mesoscan
