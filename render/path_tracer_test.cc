#include "render/path_tracer.h"

#include <gtest/gtest.h>

#include "render/env_map.h"

namespace mesoscan {
namespace {

HeightField FlatField(int n = 32, double pixel = 1e-4) {
  HeightField hf;
  hf.pixel_size = pixel;
  hf.x0 = -0.5 * (n - 1) * pixel;
  hf.y0 = 0.5 * (n - 1) * pixel;
  hf.z = ImageF(n, n, 1, 0.0f);
  return hf;
}

// Constant sky over a flat Lambert surface: every camera path returns albedo * L exactly
// (cosine sampling makes each sample's weight f cos / pdf = albedo), so the image is exact.
TEST(PathTracer, FlatLambertUnderConstantSkyIsExact) {
  RenderOptions o;
  o.width = 8;
  o.height = 6;
  o.min_spp = o.max_spp = 4;
  o.elevation_deg = 90;
  const Rgb albedo(0.2, 0.5, 0.8);
  const ImageF im = RenderHeightField(FlatField(), Brdf(LambertBrdf(albedo)),
                                      EnvironmentMap::Constant(Rgb::Constant(2.0)), o);
  // The film stores float: exact to float rounding.
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(im(4, 3, c), 2.0 * albedo[c], 1e-6);
}

// The environment's importance sampling must agree with its own Pdf() and integrate to 1.
TEST(EnvironmentMap, SamplePdfIsConsistentAndNormalised) {
  const EnvironmentMap env = EnvironmentMap::Sky(30, 45, 128);
  uint64_t s = 12345;
  auto uni = [&] {
    s = s * 6364136223846793005ULL + 1442695040888963407ULL;
    return (s >> 11) * 0x1p-53;
  };
  for (int i = 0; i < 2000; ++i) {
    const auto smp = env.Sample({uni(), uni()});
    if (!smp) continue;
    EXPECT_NEAR(env.Pdf(smp->wi) / smp->pdf, 1.0, 1e-6);
  }
  // Integral of the pdf over the sphere (midpoint rule in (theta, phi)).
  double integral = 0;
  const int nt = 400, np = 800;
  for (int i = 0; i < nt; ++i) {
    const double th = (i + 0.5) / nt * kPi;
    for (int j = 0; j < np; ++j) {
      const double ph = (j + 0.5) / np * 2 * kPi;
      integral += env.Pdf(SphericalDirection(th, ph)) * std::sin(th) * (kPi / nt) * (2 * kPi / np);
    }
  }
  EXPECT_NEAR(integral, 1.0, 0.01);
}

// A flat Lambert surface under the sky: radiance = albedo/pi * irradiance, the irradiance
// integrated numerically from the map. Checks NEE + MIS against an independent quadrature.
TEST(PathTracer, FlatLambertUnderSkyMatchesQuadrature) {
  const EnvironmentMap env = EnvironmentMap::Sky(35, 10, 128);
  double E = 0;  // luminance irradiance
  const int nt = 256, np = 512;
  for (int i = 0; i < nt; ++i) {
    const double th = (i + 0.5) / nt * 0.5 * kPi;
    for (int j = 0; j < np; ++j) {
      const double ph = (j + 0.5) / np * 2 * kPi;
      E += Luminance(env.Le(SphericalDirection(th, ph))) * std::cos(th) * std::sin(th) *
           (0.5 * kPi / nt) * (2 * kPi / np);
    }
  }
  RenderOptions o;
  o.width = 4;
  o.height = 4;
  o.min_spp = o.max_spp = 8192;
  o.elevation_deg = 90;
  o.fov_deg = 5;
  const double albedo = 0.6;
  const ImageF im = RenderHeightField(FlatField(), Brdf(LambertBrdf(Rgb::Constant(albedo))), env, o);
  // The central 2x2 pixels see only the height field (the border of the frame sees the mount).
  double mean = 0;
  for (int y = 1; y < 3; ++y)
    for (int x = 1; x < 3; ++x)
      mean += Luminance(Rgb(im(x, y, 0), im(x, y, 1), im(x, y, 2))) / 4;
  // The quadrature resolves the 2-degree sun only to ~1%: a 2% tolerance.
  EXPECT_NEAR(mean / (albedo / kPi * E), 1.0, 0.02);
}

}  // namespace
}  // namespace mesoscan
