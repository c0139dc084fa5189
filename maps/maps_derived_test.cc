#include "maps/maps_derived.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/numbers.h"

namespace mesoscan {
namespace {

HeightField Grid(int w, int h, double p) {
  HeightField hf;
  hf.pixel_size = p;
  hf.z = ImageF(w, h, 1, 0.0f);
  return hf;
}

TEST(MapsDerived, AoIsOneOnAPlaneAndMatchesAVGroove) {
  HeightField hf = Grid(201, 201, 10e-6);
  // A tilted plane is open too: the horizon never rises above the mount's horizontal... only on
  // the down-slope side, so use a flat plane for AO = 1.
  AoOptions o;
  o.radius_m = 0.5e-3;
  const ImageF flat = AmbientOcclusion(hf, o, false);
  EXPECT_NEAR(flat(100, 100), 1.0, 1e-6);
  // V-groove along y, walls at 30 degrees: at its bottom the horizon is 30 degrees across the
  // groove (|cos phi| of it along azimuth phi): AO = mean_phi 1 / (1 + (tan 30 |cos phi|)^2).
  const double t = std::tan(30 * kPi / 180);
  for (int y = 0; y < hf.height(); ++y)
    for (int x = 0; x < hf.width(); ++x)
      hf.z(x, y) = static_cast<float>(std::abs(x - 100) * hf.pixel_size * t);
  const ImageF groove = AmbientOcclusion(hf, o, false);
  double expect = 0;
  for (int d = 0; d < o.directions; ++d) {
    const double c = std::cos(2 * kPi * (d + 0.5) / o.directions) * t;
    expect += 1.0 / (1.0 + c * c);
  }
  expect /= o.directions;
  EXPECT_NEAR(groove(100, 100), expect, 1e-3);
  EXPECT_LT(groove(100, 100), 0.9);
  // Periodic: a tile's AO wraps (a groove at the edge occludes like one in the middle).
  HeightField g2 = Grid(64, 64, 10e-6);
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x)
      g2.z(x, y) = static_cast<float>(std::abs(((x + 32) % 64) - 32) * 10e-6 * t);
  const ImageF wrapped = AmbientOcclusion(g2, o, true);
  EXPECT_NEAR(wrapped(0, 10), wrapped(0, 40), 1e-6);
  EXPECT_LT(wrapped(0, 10), 0.95);
}

TEST(MapsDerived, MeanCurvatureOfASphere) {
  const double radius = 5e-3;
  HeightField hf = Grid(201, 201, 10e-6);
  for (int y = 0; y < 201; ++y)
    for (int x = 0; x < 201; ++x) {
      const double dx = (x - 100) * 10e-6, dy = (y - 100) * 10e-6;
      hf.z(x, y) =
          static_cast<float>(std::sqrt(radius * radius - dx * dx - dy * dy) - radius + 1e-3);
    }
  const ImageF k = MeanCurvature(hf, 0.0, false);
  // float32 heights of ~1 mm: second differences carry ~1e-10 m / (1e-5 m)^2 = 1 /m of noise.
  EXPECT_NEAR(k(100, 100), 1.0 / radius, 0.02 / radius);
  EXPECT_NEAR(k(150, 60), 1.0 / radius, 0.02 / radius);
}

TEST(MapsDerived, NormalsAndProjectorIrradiance) {
  HeightField hf = Grid(101, 101, 1e-4);
  hf.x0 = -5e-3, hf.y0 = 5e-3;
  const ImageF n = NormalsOf(hf, false);
  EXPECT_NEAR(n(50, 50, 2), 1.0, 1e-6);
  // A light 0.2 m above the centre: irradiance ~ cos / r^2 = d / r^3.
  const ImageF e = ProjectorIrradiance(hf, n, Vec3d(0, 0, 0.2));
  const double d = 0.2, x = 5e-3;
  const double ratio = (d / std::pow(d * d + x * x, 1.5)) / (1 / (d * d));
  EXPECT_NEAR(e(100, 50) / e(50, 50), ratio, 1e-5);
  // Tilt a normal away from the light: less light.
  HeightField tilted = hf;
  for (int y = 0; y < 101; ++y)
    for (int x2 = 0; x2 < 101; ++x2) tilted.z(x2, y) = static_cast<float>(0.2 * x2 * 1e-4);
  const ImageF et = ProjectorIrradiance(tilted, NormalsOf(tilted, false), Vec3d(-0.2, 0, 0.2));
  EXPECT_TRUE(std::isfinite(et(50, 50)));
}

}  // namespace
}  // namespace mesoscan
