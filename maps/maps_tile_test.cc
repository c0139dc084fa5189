#include "maps/maps_tile.h"

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>

#include "maps/maps_flatten.h"

namespace mesoscan {
namespace {

// A stationary random texture (the flattened surface the tiler gets): white noise blurred with
// sigma 1.5 px, 20 um RMS, 560 x 520 px of 25 um.
HeightField RandomSurface(unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g(0.0f, 1.0f);
  HeightField hf;
  hf.pixel_size = 25e-6;
  hf.z = ImageF(560, 520, 1);
  for (float& v : hf.z.data()) v = g(rng);
  hf.z = NormalisedGaussianBlur(hf.z, 1.5);
  double s2 = 0;
  for (float v : hf.z.data()) s2 += v * v;
  const double scale = 20e-6 / std::sqrt(s2 / hf.z.pixels());
  for (int y = 0; y < hf.height(); ++y)
    for (int x = 0; x < hf.width(); ++x) hf.z(x, y) = static_cast<float>(hf.z(x, y) * scale);
  return hf;
}

// The tile's seam gradient RMS matches its interior's within 10% (three textures), where the
// plain crop's seam is many times its interior. Sampling spread: a seam holds 400 differences
// with a correlation length of ~3 px, so its RMS scatters by ~1/sqrt(2 * 400/3) = 6% (1 sigma)
// around the interior's; the x and y seams are pooled (4% spread), each alone is held to 20%.
TEST(MapsTile, BlendSeamGradientsMatchTheInterior) {
  for (unsigned seed : {1u, 2u, 3u}) {
    const HeightField hf = RandomSurface(seed);
    TileOptions o;
    o.size_m = 10e-3;  // 400 px
    const TileResult t = MakeTile(hf, ImageF(), ImageU8(), o);
    std::cout << t.BriefReport() << "\n";
    EXPECT_EQ(t.size_px, 400);
    const SeamStats& s = t.seams_after;
    const double pooled =
        std::sqrt((s.seam_rms_x * s.seam_rms_x + s.seam_rms_y * s.seam_rms_y) /
                  (s.interior_rms_x * s.interior_rms_x + s.interior_rms_y * s.interior_rms_y));
    EXPECT_NEAR(pooled, 1.0, 0.10);
    EXPECT_NEAR(s.ratio_x(), 1.0, 0.20);
    EXPECT_NEAR(s.ratio_y(), 1.0, 0.20);
    EXPECT_GT(t.seams_before.ratio_x(), 2.0);
    // Height statistics kept: the tile's RMS within 10% of the source square's.
    double m = 0, s2 = 0, ms = 0, ss2 = 0;
    const int n = t.size_px;
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) m += t.field.z(x, y), ms += hf.z(t.src_x + x, t.src_y + y);
    m /= n * n, ms /= n * n;
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x)
        s2 += std::pow(t.field.z(x, y) - m, 2),
            ss2 += std::pow(hf.z(t.src_x + x, t.src_y + y) - ms, 2);
    EXPECT_NEAR(std::sqrt(s2 / ss2), 1.0, 0.10);
  }
}

TEST(MapsTile, MirrorIsContinuousAndAvoidsHoles) {
  HeightField hf = RandomSurface(4);
  // Holes on the left half: the tile must come from the right.
  for (int y = 0; y < hf.height(); ++y)
    for (int x = 0; x < 200; x += 7) hf.z(x, y) = NAN;
  TileOptions o;
  o.size_m = 4e-3;
  o.method = TileMethod::kMirror;
  const TileResult t = MakeTile(hf, ImageF(), ImageU8(), o);
  EXPECT_EQ(t.size_px, 160);
  EXPECT_GE(t.src_x, 197);                            // right of the last hole column (196)
  EXPECT_NEAR(t.seams_after.seam_rms_x, 0.0, 1e-12);  // mirrored: no step, a crease
  for (float v : t.field.z.data()) ASSERT_TRUE(std::isfinite(v));
  o.size_m = 50e-3;
  EXPECT_THROW(MakeTile(hf, ImageF(), ImageU8(), o), Error);
  EXPECT_THROW(ParseTileMethod("wrap"), Error);
}

}  // namespace
}  // namespace mesoscan
