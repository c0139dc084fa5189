#include "render/denoise.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace mesoscan {
namespace {

// A synthetic render: radiance `truth(x, y)` plus independent Gaussian noise of `sigma` in
// each half-buffer, flat normals, constant depth, white base colour.
template <typename Truth>
RenderResult Synthetic(int w, int h, double sigma, Truth truth, uint64_t seed) {
  RenderResult r;
  r.radiance = ImageF(w, h, 3, 0.0f);
  r.half[0] = ImageF(w, h, 3, 0.0f);
  r.half[1] = ImageF(w, h, 3, 0.0f);
  r.normal = ImageF(w, h, 3, 0.0f);
  r.depth = ImageF(w, h, 1, 1.0f);
  r.albedo = ImageF(w, h, 3, 1.0f);
  r.sample_mask = ImageF(w, h, 1, 1.0f);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, sigma);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      r.normal(x, y, 2) = 1.0f;
      const double t = truth(x, y);
      for (int k = 0; k < 2; ++k) {
        const double v = t + noise(rng);
        for (int c = 0; c < 3; ++c) r.half[k](x, y, c) = static_cast<float>(v);
      }
      for (int c = 0; c < 3; ++c) r.radiance(x, y, c) = 0.5f * (r.half[0](x, y, c) + r.half[1](x, y, c));
    }
  return r;
}

double Rmse(const ImageF& im, double (*truth)(int, int), int x0, int x1) {
  double s = 0;
  int n = 0;
  for (int y = 0; y < im.height(); ++y)
    for (int x = x0; x < x1; ++x) {
      const double d = im(x, y, 1) - truth(x, y);
      s += d * d;
      ++n;
    }
  return std::sqrt(s / n);
}

double Flat(int, int) { return 1.0; }
double Step(int x, int) { return x < 32 ? 1.0 : 2.0; }

// Without noise (the two halves agree) the raw pixel always wins: the image comes back as it
// was, whatever its detail.
TEST(Denoise, NoiseFreeRenderIsUnchanged) {
  const RenderResult r = Synthetic(48, 40, 0.0, [](int x, int y) { return 1.0 + ((x * 7 + y * 3) % 5); }, 1);
  const ImageF d = DenoisePreview(r);
  for (size_t i = 0; i < r.radiance.data().size(); ++i)
    ASSERT_NEAR(d.data()[i], r.radiance.data()[i], 1e-6 * r.radiance.data()[i]);
}

// Pure noise on a flat image: the filter averages it down (the raw RMSE is sigma / sqrt(2)).
TEST(Denoise, AveragesNoiseOnAFlatImage) {
  const RenderResult r = Synthetic(64, 64, 0.3, Flat, 2);
  const double raw = Rmse(r.radiance, Flat, 0, 64);
  const double dn = Rmse(DenoisePreview(r), Flat, 0, 64);
  EXPECT_NEAR(raw, 0.3 / std::sqrt(2.0), 0.02);
  EXPECT_LT(dn, raw / 4);
}

// A step the guide does not show (a shadow edge on a flat field): the cross-validation keeps
// the filter from blurring across it. The columns next to the edge stay within a fifth of the
// step; a fixed 16-pixel filter would put them half a step off.
TEST(Denoise, KeepsAnEdgeTheGuideCannotSee) {
  const RenderResult r = Synthetic(64, 64, 0.1, Step, 3);
  const ImageF d = DenoisePreview(r);
  double near_edge = 0;
  for (int y = 0; y < 64; ++y) near_edge += (d(31, y, 1) - 1.0 + d(32, y, 1) - 2.0) / 128;
  EXPECT_LT(std::abs(near_edge), 0.2);
  EXPECT_LT(Rmse(d, Step, 30, 34), 0.2);
  // Away from the edge it still smooths.
  EXPECT_LT(Rmse(d, Step, 0, 24), Rmse(r.radiance, Step, 0, 24) / 2);
}

}  // namespace
}  // namespace mesoscan
