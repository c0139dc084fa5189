#include "brdf/warp2d.h"

#include <gtest/gtest.h>

#include <random>

#include "core/error.h"

namespace mesoscan {
namespace {

// A lumpy 2-parameter table: [2][3][5][7].
Warp2D MakeWarp() {
  std::vector<double> data;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int i = 0; i < 2 * 3 * 5 * 7; ++i) data.push_back(uni(rng) < 0.2 ? 0.0 : uni(rng));
  return Warp2D(7, 5, data, {{0.0, 1.0}, {-1.0, 0.5, 2.0}}, true, "test");
}

TEST(Warp2D, SampleAndInvertAreInverse) {
  const Warp2D w = MakeWarp();
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int i = 0; i < 2000; ++i) {
    const double params[2] = {uni(rng), -1.5 + 4 * uni(rng)};  // includes clamped values
    const Eigen::Vector2d u(uni(rng), uni(rng));
    const auto [pos, pdf] = w.Sample(u, params);
    const auto [back, pdf2] = w.Invert(pos, params);
    EXPECT_NEAR(back.x(), u.x(), 1e-7);
    EXPECT_NEAR(back.y(), u.y(), 1e-7);
    EXPECT_NEAR(pdf, pdf2, 1e-9 * (1 + pdf));
    EXPECT_NEAR(pdf, w.Eval(pos, params), 1e-9 * (1 + pdf));
    EXPECT_GT(pdf, 0.0);
  }
}

TEST(Warp2D, DensityIntegratesToOne) {
  const Warp2D w = MakeWarp();
  const double params[2] = {0.3, 1.2};
  // The bilinear interpolant is integrated exactly by a midpoint rule aligned to its patches only
  // in the limit; 600^2 points give ~1e-6.
  const int n = 600;
  double sum = 0;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) sum += w.Eval({(i + 0.5) / n, (j + 0.5) / n}, params);
  EXPECT_NEAR(sum / (n * n), 1.0, 1e-5);
}

TEST(Warp2D, SamplesFollowTheDensity) {
  // Mean of x under the density vs. its quadrature.
  const Warp2D w = MakeWarp();
  const double params[2] = {0.7, 0.0};
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const int m = 200000;
  double mean = 0, mean2 = 0;
  for (int i = 0; i < m; ++i) {
    const double x = w.Sample({uni(rng), uni(rng)}, params).first.x();
    mean += x;
    mean2 += x * x;
  }
  mean /= m;
  const double sd = std::sqrt(mean2 / m - mean * mean);
  const int n = 400;
  double q = 0;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const double x = (i + 0.5) / n;
      q += x * w.Eval({x, (j + 0.5) / n}, params);
    }
  q /= n * n;
  EXPECT_NEAR(mean, q, 5 * sd / std::sqrt(m) + 1e-5);
}

TEST(Warp2D, RejectsBadTables) {
  EXPECT_THROW(Warp2D(1, 5, std::vector<double>(5, 1.0), {}, true, "t"), Error);
  EXPECT_THROW(Warp2D(2, 2, {1, 1, 1}, {}, true, "t"), Error);
  EXPECT_THROW(Warp2D(2, 2, {1, -1, 1, 1}, {}, true, "t"), Error);
  EXPECT_THROW(Warp2D(2, 2, {1, NAN, 1, 1}, {}, false, "t"), Error);
  EXPECT_THROW(Warp2D(2, 2, {0, 0, 0, 0}, {}, true, "t"), Error);
  EXPECT_THROW(Warp2D(2, 2, std::vector<double>(8, 1.0), {{1.0, 0.0}}, true, "t"), Error);
  EXPECT_NO_THROW(Warp2D(2, 2, {0, 0, 0, 0}, {}, false, "t"));
}

}  // namespace
}  // namespace mesoscan
