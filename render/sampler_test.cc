#include "render/sampler.h"

#include <gtest/gtest.h>

#include <set>
#include <vector>

namespace mesoscan {
namespace {

TEST(Sobol, FirstPointsOfTheTwoDimensions) {
  // Dimension 1 against the direction numbers directly, for a 40-bit index.
  const uint64_t big = 0xB5A3C1F00Dull;
  uint64_t m = 1;
  uint32_t expect = 0;
  for (int k = 1; k <= 40; ++k) {
    if (k > 1) m = (m << 1) ^ m;
    if ((big >> (k - 1)) & 1)
      expect ^= static_cast<uint32_t>(k <= 32 ? m << (32 - k) : m >> (k - 32));
  }
  EXPECT_EQ(SobolBits(big, 1), expect);
  const double d0[] = {0, 0.5, 0.25, 0.75, 0.125};
  const double d1[] = {0, 0.5, 0.75, 0.25, 0.625};  // direction numbers m = 1, 3, 5
  for (int i = 0; i < 5; ++i) {
    EXPECT_EQ(SobolBits(i, 0) * 0x1p-32, d0[i]) << i;
    EXPECT_EQ(SobolBits(i, 1) * 0x1p-32, d1[i]) << i;
  }
}

TEST(Sobol, OwenScrambleIsABijectionOnTheTopBits) {
  // A nested uniform scramble permutes the 2^k elementary intervals of any level k.
  for (uint32_t seed : {1u, 77u, 0xdeadbeefu}) {
    std::set<uint32_t> seen;
    for (uint32_t i = 0; i < 256; ++i) seen.insert(OwenScramble(i << 24, seed) >> 24);
    EXPECT_EQ(seen.size(), 256u);
  }
}

// Every prefix of 4^k samples of a pixel is a (0, 2k, 2)-net in each 2D request: each of the
// 16 cells of every elementary partition (16x1, 8x2, 4x4, 2x8, 1x16) holds exactly one point.
TEST(ZSobolSampler, SixteenSamplesAreANetInEveryDimensionPair) {
  for (int log2_spp : {4, 6, 8}) {
    ZSobolSampler s(log2_spp, 64, 48, 3);
    for (int px : {0, 5, 17}) {
      std::vector<std::vector<double>> u(16);
      for (int i = 0; i < 16; ++i) {
        s.StartPixelSample(px, px / 2, i);
        for (int d = 0; d < 6; ++d) {
          double a, b;
          s.Get2D(&a, &b);
          u[i].push_back(a);
          u[i].push_back(b);
        }
      }
      for (int d = 0; d < 6; ++d)
        for (int bx = 0; bx <= 4; ++bx) {
          const int nx = 1 << bx, ny = 16 / nx;
          std::set<int> cells;
          for (int i = 0; i < 16; ++i)
            cells.insert(static_cast<int>(u[i][2 * d] * nx) * ny +
                         static_cast<int>(u[i][2 * d + 1] * ny));
          EXPECT_EQ(cells.size(), 16u) << "log2_spp " << log2_spp << " pixel " << px << " dim " << d
                                       << " partition " << nx << "x" << ny;
        }
    }
  }
}

TEST(ZSobolSampler, SeedsChangeEveryValueAndTheSameSeedRepeats) {
  ZSobolSampler a(6, 32, 32, 1), b(6, 32, 32, 2), c(6, 32, 32, 1);
  int same = 0;
  for (int i = 0; i < 64; ++i) {
    a.StartPixelSample(3, 4, i);
    b.StartPixelSample(3, 4, i);
    c.StartPixelSample(3, 4, i);
    for (int d = 0; d < 5; ++d) {
      const double x = a.Get1D(), y = b.Get1D(), z = c.Get1D();
      EXPECT_EQ(x, z);
      same += x == y;
    }
  }
  EXPECT_EQ(same, 0);
}

// The per-pixel cache of the permuted pixel digits changes nothing: visiting pixels in any
// order gives the values of a fresh sampler.
TEST(ZSobolSampler, CacheIsTransparent) {
  ZSobolSampler a(6, 40, 30, 4);
  for (int x : {3, 4, 3, 17, 3}) {
    for (int i : {0, 5, 63}) {
      ZSobolSampler fresh(6, 40, 30, 4);
      a.StartPixelSample(x, 2, i);
      fresh.StartPixelSample(x, 2, i);
      for (int d = 0; d < 60; ++d) EXPECT_EQ(a.Get1D(), fresh.Get1D());
    }
  }
}

// Neighbouring pixels get different points (not the same pattern repeated).
TEST(ZSobolSampler, PixelsDiffer) {
  ZSobolSampler s(4, 16, 16, 9);
  s.StartPixelSample(0, 0, 0);
  const double a = s.Get1D();
  s.StartPixelSample(1, 0, 0);
  const double b = s.Get1D();
  EXPECT_NE(a, b);
}

}  // namespace
}  // namespace mesoscan
