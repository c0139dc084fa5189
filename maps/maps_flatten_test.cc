#include "maps/maps_flatten.h"

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "core/numbers.h"

namespace mesoscan {
namespace {

// A weave-like texture (zero mean over whole periods): wavelengths 0.5-0.9 mm, 30 um.
double Texture(double u, double v) {
  return 20e-6 * std::sin(2 * kPi * u / 0.6e-3) * std::sin(2 * kPi * v / 0.5e-3) +
         10e-6 * std::cos(2 * kPi * (u - 0.5 * v) / 0.9e-3 + 0.4);
}

// A tilted (1.5 deg), bent (0.3 mm sag over 24 mm) sample with the texture; 480 x 400 px of
// 50 um. Returns the texture alone in *texture.
HeightField TiltedBent(ImageF* texture, bool holes) {
  HeightField hf;
  hf.pixel_size = 50e-6;
  hf.z = ImageF(480, 400, 1);
  *texture = ImageF(480, 400, 1);
  for (int y = 0; y < 400; ++y)
    for (int x = 0; x < 480; ++x) {
      const double u = x * hf.pixel_size, v = y * hf.pixel_size;
      const double t = Texture(u, v);
      (*texture)(x, y) = static_cast<float>(t);
      const double shape = 2e-3 + std::tan(1.5 * kPi / 180) * (u - 0.01) + 0.004 * v -
                           0.3e-3 * std::pow((u - 0.012) / 0.012, 2) +
                           0.1e-3 * std::pow((v - 0.01) / 0.01, 2);
      hf.z(x, y) = static_cast<float>(shape + t);
      if (holes && (x - 300) * (x - 300) + (y - 120) * (y - 120) < 400) hf.z(x, y) = NAN;
    }
  return hf;
}

// RMS of (recovered - truth) relative to RMS of truth, both with their means removed.
double RelativeRms(const ImageF& got, const ImageF& truth) {
  double mg = 0, mt = 0;
  int64_t n = 0;
  for (size_t p = 0; p < got.pixels(); ++p)
    if (std::isfinite(got.data()[p])) mg += got.data()[p], mt += truth.data()[p], ++n;
  mg /= n, mt /= n;
  double e2 = 0, t2 = 0;
  for (size_t p = 0; p < got.pixels(); ++p) {
    if (!std::isfinite(got.data()[p])) continue;
    e2 += std::pow((got.data()[p] - mg) - (truth.data()[p] - mt), 2);
    t2 += std::pow(truth.data()[p] - mt, 2);
  }
  return std::sqrt(e2 / t2);
}

TEST(MapsFlatten, PolynomialRecoversTheTextureWithinOnePercent) {
  ImageF texture;
  const HeightField hf = TiltedBent(&texture, /*holes=*/true);
  const FlattenResult r = Flatten(hf, ImageU8(), ParseFlatten("poly:2"));
  const double rel = RelativeRms(r.field.z, texture);
  std::cout << "poly:2 texture error " << rel * 100 << "% RMS; " << r.description << "\n";
  EXPECT_LT(rel, 0.01);
  // Nothing lost: flattened + removed = input.
  for (size_t p = 0; p < hf.z.pixels(); ++p) {
    if (std::isfinite(hf.z.data()[p])) {
      ASSERT_NEAR(r.field.z.data()[p] + r.removed.data()[p], hf.z.data()[p], 1e-9);
    }
  }
  EXPECT_TRUE(std::isnan(r.field.z(300, 120)));
  for (float v : r.removed.data()) ASSERT_TRUE(std::isfinite(v));
}

TEST(MapsFlatten, HighpassRecoversTheTextureWithinOnePercent) {
  ImageF texture;
  const HeightField hf = TiltedBent(&texture, /*holes=*/true);
  const FlattenResult r = Flatten(hf, ImageU8(), ParseFlatten("highpass:8"));
  const double rel = RelativeRms(r.field.z, texture);
  std::cout << "highpass:8 texture error " << rel * 100 << "% RMS; " << r.description << "\n";
  EXPECT_LT(rel, 0.01);
}

TEST(MapsFlatten, RobustPlaneIgnoresOutliersAndRecoversTheTilt) {
  ImageF texture;
  HeightField hf = TiltedBent(&texture, false);
  // A plane only (no bend) with 5% of the pixels as 1 mm spikes (dust, mixed pixels).
  for (int y = 0; y < hf.height(); ++y)
    for (int x = 0; x < hf.width(); ++x) {
      const double u = x * hf.pixel_size, v = y * hf.pixel_size;
      hf.z(x, y) = static_cast<float>(1e-3 + 0.03 * u - 0.01 * v + texture(x, y) +
                                      ((x * 7 + y * 13) % 20 == 0 ? 1e-3 : 0.0));
    }
  const FlattenResult r = Flatten(hf, ImageU8(), ParseFlatten("plane"));
  ImageF clean(hf.width(), hf.height(), 1, NAN);
  for (int y = 0; y < hf.height(); ++y)
    for (int x = 0; x < hf.width(); ++x)
      if ((x * 7 + y * 13) % 20 != 0) clean(x, y) = r.field.z(x, y);
  const double rel = RelativeRms(clean, texture);
  std::cout << "robust plane with 5% spikes: texture error " << rel * 100 << "% RMS\n";
  EXPECT_LT(rel, 0.01);
}

TEST(MapsFlatten, Parse) {
  EXPECT_EQ(ParseFlatten("plane").method, FlattenMethod::kPlane);
  EXPECT_EQ(ParseFlatten("poly:3").poly_degree, 3);
  EXPECT_NEAR(ParseFlatten("highpass:2.5").highpass_wavelength_m, 2.5e-3, 1e-12);
  EXPECT_THROW(ParseFlatten("poly:9"), Error);
  EXPECT_THROW(ParseFlatten("poly:x"), Error);
  EXPECT_THROW(ParseFlatten("highpass:-1"), Error);
  EXPECT_THROW(ParseFlatten("tilt"), Error);
}

}  // namespace
}  // namespace mesoscan
