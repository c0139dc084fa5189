#include "heightfield/mixed_pixels.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "core/error.h"

namespace mesoscan {
namespace {

constexpr double kFootprint = 55e-6;  // the paper rig's camera footprint, m
constexpr double kSigma = 1e-6;       // depth sigma of every pixel, m

struct Grid {
  int w, h;
  std::vector<float> z, sigma, white;
  std::vector<uint8_t> unlit;
  Grid(int w_, int h_)
      : w(w_),
        h(h_),
        z(static_cast<size_t>(w_) * h_, 0.0f),
        sigma(z.size(), static_cast<float>(kSigma)),
        white(z.size(), 0.5f),
        unlit(z.size(), 0) {}
  float& Z(int x, int y) { return z[static_cast<size_t>(y) * w + x]; }
  std::vector<uint8_t> Find(const MixedPixelOptions& o = {}) const {
    MixedPixelInput in;
    in.width = w;
    in.height = h;
    in.z = z.data();
    in.sigma_z = sigma.data();
    in.white = white.data();
    in.unlit = unlit.data();
    in.footprint_m = kFootprint;
    return FindMixedPixels(in, o);
  }
  int Count(const std::vector<uint8_t>& r) const {
    int n = 0;
    for (uint8_t v : r) n += v;
    return n;
  }
};

// A 93 um step along x (the paper ramp's sheet) with one column that saw both sheets: it decodes
// to their mean and must go; the columns on either side agree with their own sheet and stay.
TEST(MixedPixels, RejectsThePixelBetweenTwoSheets) {
  Grid g(20, 8);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) g.Z(x, y) = x < 10 ? 0.0f : x == 10 ? 46.5e-6f : 93e-6f;
  const auto r = g.Find();
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) EXPECT_EQ(r[static_cast<size_t>(y) * g.w + x], x == 10) << x;
  // A quarter mix (23 um from its sheet, > 3 sigma of the difference) goes too.
  for (int y = 0; y < g.h; ++y) g.Z(10, y) = 23e-6f;
  EXPECT_EQ(g.Count(g.Find()), g.h);
}

// The same 20 um deviation as a ridge (above both sides' extrapolations) is real relief and
// stays; as a point between two levels 40 um apart it is a mixed pixel.
TEST(MixedPixels, KeepsARidgeButNotAStepOfTheSameSize) {
  Grid ridge(20, 8), step(20, 8);
  for (int y = 0; y < 8; ++y) {
    ridge.Z(10, y) = 20e-6f;
    for (int x = 0; x < 20; ++x) step.Z(x, y) = x < 10 ? 0.0f : x == 10 ? 20e-6f : 40e-6f;
  }
  EXPECT_EQ(ridge.Count(ridge.Find()), 0);
  EXPECT_EQ(step.Count(step.Find()), 8);
}

// Noise only: a tilted plane with Gaussian depth noise of the declared sigma. The step test needs
// both sides beyond 3 sigma with opposite signs: ~2e-6 per pixel and axis, so 40000 pixels should
// lose about 0.2; more than 3 (Poisson tail 1e-4) means the test rejects noise.
TEST(MixedPixels, NoiseAloneIsNotRejected) {
  Grid g(200, 200);
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0.0, kSigma);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) g.Z(x, y) = static_cast<float>(1e-3 + 20e-6 * x + n(rng));
  EXPECT_LE(g.Count(g.Find()), 3);
}

// An isolated spike far beyond the footprint threshold goes (outlier test), also next to a hole.
TEST(MixedPixels, RejectsSpikesAndPointsOffTheirOnlySide) {
  Grid g(20, 20);
  g.Z(10, 10) = 200e-6f;
  for (int y = 0; y < g.h; ++y) g.Z(3, y) = NAN;  // a hole column: x = 4 has one side along x
  g.Z(4, 15) = 100e-6f;
  const auto r = g.Find();
  EXPECT_EQ(r[10 * 20 + 10], 1);
  EXPECT_EQ(r[15 * 20 + 4], 1);
  EXPECT_EQ(g.Count(r), 2);
  MixedPixelOptions off;
  off.outlier_footprints = 0;
  EXPECT_EQ(g.Count(g.Find(off)), 0);
}

// A lit pixel beside a shadow whose white level is well below its lit neighbour's is partly
// shadowed (its brightness centroid is off centre): rejected. One at 95 % of it is kept.
TEST(MixedPixels, RejectsPartlyShadowedPixels) {
  Grid g(12, 4);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < 3; ++x) {
      g.unlit[static_cast<size_t>(y) * g.w + x] = 1;
      g.Z(x, y) = NAN;
    }
  for (int y = 0; y < g.h; ++y) g.white[static_cast<size_t>(y) * g.w + 3] = y < 2 ? 0.2f : 0.475f;
  const auto r = g.Find();
  for (int y = 0; y < g.h; ++y) EXPECT_EQ(r[static_cast<size_t>(y) * g.w + 3], y < 2) << y;
  EXPECT_EQ(g.Count(r), 2);
  MixedPixelOptions off;
  off.shadow_edge_ratio = 0;
  EXPECT_EQ(g.Count(g.Find(off)), 0);
}

// A 40 um letter edge (the coin) with 3 um depth noise per pixel: the column that saw both levels
// sits 20 um from each side's extrapolation, inside the step test's 3 sigma (22 um) but beyond
// the dimmed-step test's 2.5 sigma. It goes only because it is also dimmer than its neighbours
// (part of its footprint saw the wall); at the neighbours' white level it is kept.
TEST(MixedPixels, RejectsADimmedStepThatTheStepTestMisses) {
  Grid g(20, 6);
  std::fill(g.sigma.begin(), g.sigma.end(), 3e-6f);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      g.Z(x, y) = x < 10 ? 0.0f : x == 10 ? 20e-6f : 40e-6f;
      g.white[static_cast<size_t>(y) * g.w + x] = x == 10 && y < 3 ? 0.35f : 0.5f;
    }
  const auto r = g.Find();
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x)
      EXPECT_EQ(r[static_cast<size_t>(y) * g.w + x], x == 10 && y < 3) << x << "," << y;
  MixedPixelOptions off;
  off.dim_ratio = 0;
  EXPECT_EQ(g.Count(g.Find(off)), 0);
}

// A kink from a flat face onto a dim, steep flank (20 um per pixel, white 0.3 against 0.5): the
// first flank pixel is 8 sigma off the flat side's line and dimmer than its flat neighbour, but
// on its own side's line: the jump between the lines is no sharper than the flank itself, so it
// is real relief and stays. Without the sharpness condition it would go.
TEST(MixedPixels, KeepsTheKinkOntoADimFlank) {
  Grid g(24, 6);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      g.Z(x, y) = x < 10 ? 0.0f : static_cast<float>(20e-6 * (x - 9));
      g.white[static_cast<size_t>(y) * g.w + x] = x < 10 ? 0.5f : 0.3f;
    }
  EXPECT_EQ(g.Count(g.Find()), 0);
  MixedPixelOptions any_jump;
  any_jump.dim_sharpness = 0;
  EXPECT_EQ(g.Count(g.Find(any_jump)), g.h);
}

// A wall two pixels wide, both pixels dimmed: x = 10 (15 um, a 3/8 mix) is a dimmed step in the
// first pass; x = 11 (30 um) is not, because its left side's line runs through the mixed x = 10
// and meets it. With x = 10 removed, the second pass judges x = 11 by its clean right side,
// 10 um (4 sigma) off the upper face at a sharp edge: it goes too.
TEST(MixedPixels, SecondPassJudgesTheNeighbourOfAMixedPixelByItsCleanSide) {
  Grid g(24, 4);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      g.Z(x, y) = x < 10 ? 0.0f : x == 10 ? 15e-6f : x == 11 ? 30e-6f : 40e-6f;
      g.white[static_cast<size_t>(y) * g.w + x] = x == 10 || x == 11 ? 0.35f : 0.5f;
    }
  MixedPixelOptions one;
  one.passes = 1;
  const auto r1 = g.Find(one), r2 = g.Find();
  for (int x = 0; x < g.w; ++x) {
    EXPECT_EQ(r1[x], x == 10) << x;
    EXPECT_EQ(r2[x], x == 10 || x == 11) << x;
  }
  EXPECT_EQ(g.Count(r2), 2 * g.h);
}

// Dark albedo spots (60 % of the white level) on a smooth noisy plane agree with both sides:
// a spot goes only when noise puts it beyond 2.5 sigma of one of its four extrapolations, ~5 %
// of the spots (binomial: 400 spots, mean ~20, sd ~4.4); more than 40 means the test rejects
// texture, not steps. The bright pixels around them are never dimmed, and are not rejected.
TEST(MixedPixels, DarkSpotsOnASmoothSurfaceAreMostlyKept) {
  Grid g(200, 200);
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0.0, kSigma);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      g.Z(x, y) = static_cast<float>(1e-3 + 20e-6 * x + n(rng));
      if (x % 10 == 5 && y % 10 == 5) g.white[static_cast<size_t>(y) * g.w + x] = 0.3f;
    }
  const auto r = g.Find();
  int spots = 0, others = 0;
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) (x % 10 == 5 && y % 10 == 5 ? spots : others) += r[y * g.w + x];
  std::printf("dark spots rejected: %d of 400; other pixels: %d\n", spots, others);
  EXPECT_LE(spots, 40);
  EXPECT_LE(others, 3);
}

// The tests at least 2 pixels from every edge skip the bounds checks (MixedPixelJudge::
// Mixed<true>); beyond the edge the border path reads "no point", "no white level", "not unlit".
// So a field padded by 2 pixels of exactly that must get the same verdicts, with the old edge
// pixels now judged by the interior path: a random field of steps, spikes, holes, dim and unlit
// pixels, every test on, two passes.
TEST(MixedPixels, InteriorAndBorderPathsAgree) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  Grid g(23, 17);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      const size_t i = static_cast<size_t>(y) * g.w + x;
      const float r = unit(rng);
      g.z[i] = r < 0.1f ? std::nanf("") : (x > 11 ? 40e-6f : 0.0f) + (r < 0.25f ? 15e-6f : 0.0f);
      g.sigma[i] = unit(rng) < 0.05f ? std::nanf("") : static_cast<float>(kSigma);
      g.white[i] = unit(rng) < 0.2f ? 0.1f : 0.5f;
      g.unlit[i] = std::isnan(g.z[i]) && unit(rng) < 0.5f;
    }
  Grid padded(g.w + 4, g.h + 4);
  std::fill(padded.z.begin(), padded.z.end(), std::nanf(""));
  std::fill(padded.white.begin(), padded.white.end(), std::nanf(""));
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      const size_t i = static_cast<size_t>(y) * g.w + x;
      const size_t j = static_cast<size_t>(y + 2) * padded.w + x + 2;
      padded.z[j] = g.z[i];
      padded.sigma[j] = g.sigma[i];
      padded.white[j] = g.white[i];
      padded.unlit[j] = g.unlit[i];
    }
  MixedPixelOptions o;
  o.passes = 2;
  const auto r = g.Find(o), rp = padded.Find(o);
  int rejected = 0;
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      const uint8_t v = r[static_cast<size_t>(y) * g.w + x];
      rejected += v;
      EXPECT_EQ(v, rp[static_cast<size_t>(y + 2) * padded.w + x + 2]) << x << "," << y;
    }
  EXPECT_GT(rejected, 10);  // the field exercises the tests
  EXPECT_EQ(padded.Count(rp), rejected);
}

TEST(MixedPixels, OptionsAreChecked) {
  MixedPixelOptions o;
  o.max_sigmas = 0;
  EXPECT_THROW(o.Check(), Error);
  o = {};
  o.outlier_footprints = -1;
  EXPECT_THROW(o.Check(), Error);
  o = {};
  o.shadow_edge_ratio = 1.5;
  EXPECT_THROW(o.Check(), Error);
  o = {};
  o.dim_ratio = -0.1;
  EXPECT_THROW(o.Check(), Error);
  o = {};
  o.dim_sigmas = 0;
  EXPECT_THROW(o.Check(), Error);
  o = {};
  o.dim_sharpness = -1;
  EXPECT_THROW(o.Check(), Error);
  o = {};
  o.passes = 0;
  EXPECT_THROW(o.Check(), Error);
  Grid g(1, 1);
  EXPECT_EQ(g.Count(g.Find()), 0);
}

// The later passes judge again only the pixels near the previous pass's rejections. Every pixel
// judged again on the cleaned heights would repeat the verdicts of the others (their inputs have
// not changed), so the passes must equal that plain form: per pass, the single pass on the
// heights with everything rejected so far removed, or'ed in. A field of steps, spikes and noise
// that keeps rejecting for several passes.
TEST(MixedPixels, LaterPassesEqualJudgingEverythingAgain) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::normal_distribution<double> n(0.0, kSigma);
  Grid g(120, 90);
  for (int y = 0; y < g.h; ++y)
    for (int x = 0; x < g.w; ++x) {
      const float r = unit(rng);
      g.Z(x, y) =
          static_cast<float>((x / 17 + y / 23) % 3 * 30e-6 + n(rng)) + (r < 0.03f ? 25e-6f : 0.0f);
      if (r > 0.98f) g.Z(x, y) = std::nanf("");
      g.white[static_cast<size_t>(y) * g.w + x] = unit(rng) < 0.1f ? 0.2f : 0.5f;
    }
  MixedPixelOptions o;
  o.passes = 4;
  const std::vector<uint8_t> got = g.Find(o);
  MixedPixelOptions one = o;
  one.passes = 1;
  std::vector<uint8_t> want = g.Find(one);
  int later = 0;
  for (int pass = 1; pass < o.passes; ++pass) {
    Grid cleaned = g;
    for (size_t i = 0; i < want.size(); ++i)
      if (want[i]) cleaned.z[i] = std::nanf("");
    const std::vector<uint8_t> more = cleaned.Find(one);
    for (size_t i = 0; i < want.size(); ++i) {
      later += more[i] && !want[i];
      want[i] |= more[i];
    }
  }
  std::printf("rejected %d, of which %d by the later passes\n", g.Count(want), later);
  EXPECT_GT(later, 5);
  EXPECT_EQ(got, want);
}

}  // namespace
}  // namespace mesoscan
