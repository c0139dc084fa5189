#include "brdf/brdf.h"

#include <gtest/gtest.h>

#include <set>
#include <utility>

#include "brdf/brdf_test_util.h"

namespace mesoscan {
namespace {
using testing::ChiSquareTest;
using testing::kSampleScale;
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

// White furnace for every analytic model, roughness extremes included (GGX alpha 0.001 and 1, an
// ideal conductor), at every elevation of FurnaceElevationsDeg() (0 to 89.5 deg): per channel,
// albedo <= 1 + z SE, where albedo is the plain Monte-Carlo estimate with the model's own sampling
// (n i.i.d. samples), SE its standard error sd / sqrt(n) and z the one-sided normal quantile of a
// 1% family-wise false-alarm rate over all comparisons of this test (Bonferroni: z = 4.3 for
// ~2000 comparisons). Single-scattering GGX loses energy, so every true albedo is <= 1.
TEST(Brdf, WhiteFurnaceAlbedoAtMostOneForEveryWo) {
  auto models = AnalyticModels();
  models.emplace_back("ggx_dielectric_0.001", Brdf(GgxBrdf<double>::Dielectric(1e-3, 1.5)));
  models.emplace_back("ggx_dielectric_1", Brdf(GgxBrdf<double>::Dielectric(1.0, 1.5)));
  models.emplace_back("ggx_conductor_0.001",
                      Brdf(GgxBrdf<double>::Conductor(1e-3, kGoldEta, kGoldK)));
  models.emplace_back("ggx_conductor_1", Brdf(GgxBrdf<double>::Conductor(1.0, kGoldEta, kGoldK)));
  models.emplace_back("ggx_ideal_conductor_1", Brdf(GgxBrdf<double>::Conductor(
                                                   1.0, Rgb::Constant(1.0), Rgb::Constant(1e4))));
  models.emplace_back(
      "ggx_ideal_conductor_0.001",
      Brdf(GgxBrdf<double>::Conductor(1e-3, Rgb::Constant(1.0), Rgb::Constant(1e4))));
  const std::vector<double> thetas = testing::FurnaceElevationsDeg();
  const int checks = static_cast<int>(models.size() * thetas.size() * 3);
  const double z = testing::NormalUpperQuantile(0.01 / checks);
  const int n = 1000 * kSampleScale;
  uint32_t seed = 500;
  for (const auto& [name, brdf] : models) {
    const auto r = testing::SweepFurnace(brdf, thetas, n, seed);
    seed += 1000;
    EXPECT_LE(r.worst_z, z) << name << ": albedo " << r.worst_albedo << " +- " << r.worst_se
                            << " at theta_o " << r.worst_theta_deg;
    std::printf("%-26s max albedo %.4f (SE %.4f) at theta_o %.2f, max (albedo-1)/SE %.2f <= %.2f\n",
                name.c_str(), r.worst_albedo, r.worst_se, r.worst_theta_deg, r.worst_z, z);
  }
  // A white Lambertian reflector is exactly 1 at every wo (the estimator is constant, SE 0).
  const auto white = testing::EstimateAlbedo(LambertBrdf(Rgb::Ones()),
                                             SphericalDirection(89.5 * kPi / 180, 0.0), 64, 1);
  EXPECT_NEAR(white.albedo[0], 1.0, 1e-12);
  EXPECT_NEAR(white.standard_error[0], 0.0, 1e-9);
}

// The furnace check can fail: a smooth ideal conductor (albedo ~0.99 up to ~60 deg) made 2% too
// bright is caught, with the same n and z as above.
TEST(Brdf, WhiteFurnaceCatchesTwoPercentExcess) {
  struct TooBright {
    GgxBrdf<double> ggx = GgxBrdf<double>::Conductor(0.05, Rgb::Constant(1.0), Rgb::Constant(1e4));
    std::optional<BrdfSample> Sample(const Vec3& wo, const Vec2& u) const {
      auto s = ggx.Sample(wo, u);
      if (s) s->f *= 1.02;
      return s;
    }
  };
  const auto r =
      testing::SweepFurnace(TooBright(), testing::FurnaceElevationsDeg(), 1000 * kSampleScale, 77);
  const double z = testing::NormalUpperQuantile(0.01 / (11 * 62 * 3));
  EXPECT_GT(r.worst_z, z) << r.worst_albedo << " +- " << r.worst_se;
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

// The model type behind a variant alternative (measured tables are held by shared_ptr).
template <typename T>
struct ModelOf {
  using type = T;
};
template <typename T>
struct ModelOf<std::shared_ptr<const T>> {
  using type = T;
};

TEST(Brdf, EveryModelNamesItself) {
  std::set<std::string> names;
  [&]<size_t... I>(std::index_sequence<I...>) {
    (names.insert(ModelOf<std::variant_alternative_t<I, Brdf::Model>>::type::Name()), ...);
  }
  (std::make_index_sequence<std::variant_size_v<Brdf::Model>>());
  EXPECT_EQ(names.size(), std::variant_size_v<Brdf::Model>) << "two models share a name";
  EXPECT_EQ(names.count(""), 0u);
  const Brdf lambert(LambertBrdf(Rgb(0.5, 0.5, 0.5)));
  const Brdf ggx(GgxBrdf<double>::Dielectric(0.3, 1.5));
  EXPECT_EQ(std::string(lambert.Name()), "lambert");
  EXPECT_EQ(std::string(ggx.Name()), "ggx");
  EXPECT_TRUE(lambert.Is<LambertBrdf>());
  EXPECT_FALSE(ggx.Is<LambertBrdf>());
  EXPECT_TRUE(ggx.Is<GgxBrdf<double>>());
  EXPECT_FALSE(ggx.Is<MerlBrdf>());
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
