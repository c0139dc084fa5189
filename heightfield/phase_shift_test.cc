#include "heightfield/phase_shift.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <random>
#include <vector>

#include "core/error.h"

namespace mesoscan {
namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;

double CircDiff(double a, double b) { return std::remainder(a - b, kTwoPi); }

std::vector<double> EqualSteps(int k) {
  std::vector<double> d(k);
  for (int i = 0; i < k; ++i) d[i] = kTwoPi * i / k;
  return d;
}

std::vector<float> Frames(const std::vector<double>& deltas, double a, double b, double theta,
                          double sigma, std::mt19937_64* rng) {
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<float> s(deltas.size());
  for (size_t k = 0; k < deltas.size(); ++k)
    s[k] = static_cast<float>(a + b * std::cos(theta + deltas[k]) +
                              (sigma > 0 ? sigma * noise(*rng) : 0.0));
  return s;
}

TEST(WrappedPhaseSolver, ExactRecoveryEqualAndUnequalSteps) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const std::vector<std::vector<double>> sets = {
      EqualSteps(3),        EqualSteps(4),   EqualSteps(8),
      {0.0, 1.0, 2.5, 4.0}, {0.3, 0.9, 2.0}, {0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0}};
  for (const auto& deltas : sets) {
    const WrappedPhaseSolver solver(deltas);
    for (int trial = 0; trial < 200; ++trial) {
      const double theta = kTwoPi * uni(rng), a = 0.2 + 0.6 * uni(rng), b = 0.05 + 0.3 * uni(rng);
      const auto s = Frames(deltas, a, b, theta, 0.0, &rng);
      const auto r = solver.Solve(s.data());
      ASSERT_TRUE(r.valid);
      // float samples and outputs: ~1e-7 relative rounding.
      EXPECT_NEAR(CircDiff(r.theta, theta), 0.0, 2e-6 / b) << deltas.size();
      EXPECT_NEAR(r.modulation, b, 1e-6);
      EXPECT_NEAR(r.offset, a, 1e-6);
      EXPECT_LT(r.residual_rms, 1e-6);
      EXPECT_GE(r.theta, 0.0f);
      EXPECT_LT(r.theta, static_cast<float>(kTwoPi));
    }
  }
}

TEST(WrappedPhaseSolver, StridedSamplesAndBadInput) {
  const auto deltas = EqualSteps(4);
  const WrappedPhaseSolver solver(deltas);
  std::mt19937_64 rng(2);
  const auto s = Frames(deltas, 0.5, 0.3, 1.0, 0.0, &rng);
  std::vector<float> strided(16, -1.0f);
  for (int k = 0; k < 4; ++k) strided[4 * k] = s[k];
  EXPECT_EQ(solver.Solve(s.data()).theta, solver.Solve(strided.data(), 4).theta);
  std::vector<float> bad = s;
  bad[2] = std::nanf("");
  const auto r = solver.Solve(bad.data());
  EXPECT_FALSE(r.valid);
  EXPECT_EQ(r.modulation, 0.0f);
  EXPECT_THROW(WrappedPhaseSolver({0.0, 1.0}), Error);
  EXPECT_THROW(WrappedPhaseSolver({0.0, 1.0, 1.0 + kTwoPi}), Error);  // 2 distinct mod 2 pi
  EXPECT_THROW(WrappedPhaseSolver({0.0, 1.0, std::nan("")}), Error);
}

// SolveMany promises Solve's results bit for bit (the phase-shift stage's output must not
// depend on which is used): every field compared by its bits, over random tiles with non-finite
// samples, zero modulation, phases at 0 and at the quadrant boundaries, n not a multiple of 4.
TEST(WrappedPhaseSolver, SolveManyMatchesSolveBitForBit) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const std::vector<std::vector<double>> sets = {
      EqualSteps(3), EqualSteps(4), EqualSteps(5), {0.0, 1.1, 2.9, 4.4}};
  auto bits = [](float v) {
    uint32_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
  };
  int64_t compared = 0, fallback_lanes = 0;
  for (const auto& deltas : sets) {
    const WrappedPhaseSolver solver(deltas);
    const int k = static_cast<int>(deltas.size());
    for (int n : {1, 3, 4, 63, 64, 65, 200, 1027}) {
      const size_t stride = static_cast<size_t>(n) + 5;  // tile wider than the pixels solved
      std::vector<float> tile(static_cast<size_t>(k) * stride, 0.0f);
      for (int j = 0; j < n; ++j) {
        const int kind = static_cast<int>(uni(rng) * 10);
        const double theta = kind == 0   ? 0.0
                             : kind == 1 ? std::numbers::pi / 2 * static_cast<int>(uni(rng) * 4)
                                         : kTwoPi * uni(rng);
        const double b = kind == 2 ? 0.0 : 0.5 * uni(rng);
        std::vector<float> f = Frames(deltas, 0.5, b, theta, kind == 3 ? 0.0 : 1e-3, &rng);
        if (kind == 4)
          f[static_cast<size_t>(uni(rng) * k)] = std::numeric_limits<float>::quiet_NaN();
        if (kind == 5) f[0] = std::numeric_limits<float>::infinity();
        for (int i = 0; i < k; ++i) tile[static_cast<size_t>(i) * stride + j] = f[i];
      }
      std::vector<WrappedPhaseSolver::Result> many(n);
      solver.SolveMany(tile.data(), stride, n, many.data());
      for (int j = 0; j < n; ++j) {
        const auto r = solver.Solve(tile.data() + j, static_cast<int>(stride));
        fallback_lanes += !r.valid;
        EXPECT_EQ(r.valid, many[j].valid) << "k " << k << " n " << n << " j " << j;
        EXPECT_EQ(bits(r.theta), bits(many[j].theta)) << "k " << k << " n " << n << " j " << j;
        EXPECT_EQ(bits(r.modulation), bits(many[j].modulation)) << "k " << k << " j " << j;
        EXPECT_EQ(bits(r.offset), bits(many[j].offset)) << "k " << k << " j " << j;
        EXPECT_EQ(bits(r.residual_rms), bits(many[j].residual_rms)) << "k " << k << " j " << j;
        ++compared;
      }
    }
  }
  EXPECT_GT(compared, 5000);
  EXPECT_GT(fallback_lanes, 50);  // the non-finite lanes were exercised
}

TEST(WrappedPhaseSolver, NoiseVarianceMatchesTheory) {
  // Equal steps: var(theta) = 2 sigma^2 / (K B^2). Unequal steps: the first-order propagation
  // through (M^T M)^-1, which depends on theta. 20000 draws: the sample variance has a relative
  // standard error of sqrt(2 / 20000) = 1 %, so 5 % is a 5-sigma band.
  std::mt19937_64 rng(3);
  const double sigma = 0.002, b = 0.3, a = 0.5;
  for (const auto& deltas :
       {EqualSteps(3), EqualSteps(5), std::vector<double>{0.0, 0.7, 2.9, 4.1}}) {
    const WrappedPhaseSolver solver(deltas);
    if (deltas.size() != 4) {
      EXPECT_NEAR(solver.ThetaVariance(sigma, b), 2 * sigma * sigma / (deltas.size() * b * b),
                  1e-12);
    }
    for (double theta : {0.3, 2.0, 4.5}) {
      const int n = 20000;
      double s1 = 0, s2 = 0;
      for (int i = 0; i < n; ++i) {
        const auto s = Frames(deltas, a, b, theta, sigma, &rng);
        const double e = CircDiff(solver.Solve(s.data()).theta, theta);
        s1 += e;
        s2 += e * e;
      }
      const double var = s2 / n - (s1 / n) * (s1 / n);
      EXPECT_NEAR(var / solver.ThetaVarianceAt(sigma, b, theta), 1.0, 0.05)
          << deltas.size() << " theta " << theta;
      EXPECT_LT(std::abs(s1 / n), 5 * std::sqrt(var / n));  // unbiased
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Temporal unwrapping

std::vector<double> PhasesAt(double u, const std::vector<double>& periods) {
  std::vector<double> t;
  for (double p : periods) {
    double v = std::fmod(kTwoPi * u / p, kTwoPi);
    if (v < 0) v += kTwoPi;
    t.push_back(v);
  }
  return t;
}

TEST(TemporalUnwrapper, CoprimePeriodsNoiseFreeEveryColumn) {
  const std::vector<double> periods = {7, 11, 13};
  const TemporalUnwrapper unwrapper(periods, 1001);
  const std::vector<double> w(3, 1e4);
  // Every column and fractional positions, the half-pixel margins at both ends included.
  for (double u = -0.5; u < 1000.5; u += 0.0625) {
    const auto t = PhasesAt(u, periods);
    const UnwrapResult r = unwrapper.Unwrap(t.data(), w.data());
    ASSERT_TRUE(r.valid) << u;
    ASSERT_NEAR(r.u, u, 1e-9) << u;
    EXPECT_LT(r.residual, 1e-6);
  }
}

// Noisy phases: every column is recovered (no fringe-order error) and the position error and
// the consistency residual follow the noise model. Phase noise sigma = 0.06 rad is 1 % of a
// period; the code separation of 7/11/13 is 0.05 cycles, so 3-sigma errors (0.03 cycles) stay
// below half of it.
void CheckNoisyUnwrapping(const std::vector<double>& periods, double range, double lo, double hi) {
  const TemporalUnwrapper unwrapper(periods, range);
  const double sigma = 0.06;
  const std::vector<double> w(periods.size(), 1.0 / (sigma * sigma));
  double info = 0;  // predicted sigma_u = 1 / sqrt(sum w (2 pi / p)^2)
  for (double p : periods) info += w[0] * std::pow(kTwoPi / p, 2);
  const double sigma_u = 1.0 / std::sqrt(info);
  std::mt19937_64 rng(4);
  std::normal_distribution<double> noise(0.0, sigma);
  double se = 0, chi = 0;
  int count = 0;
  for (int col = 0; col < static_cast<int>(range); ++col) {
    for (double frac : {-0.49, 0.0, 0.25, 0.49}) {
      const double u = col + frac;
      if (u < lo || u >= hi) continue;
      auto t = PhasesAt(u, periods);
      for (double& v : t) v = std::fmod(v + noise(rng) + kTwoPi, kTwoPi);
      const UnwrapResult r = unwrapper.Unwrap(t.data(), w.data());
      ASSERT_TRUE(r.valid) << u;
      ASSERT_LT(std::abs(r.u - u), 6 * sigma_u) << "u " << u << " got " << r.u;
      se += (r.u - u) * (r.u - u);
      chi += r.residual * r.residual;
      ++count;
    }
  }
  EXPECT_NEAR(std::sqrt(se / count) / sigma_u, 1.0, 0.05);
  EXPECT_NEAR(chi / count, 1.0, 0.05);  // residual in sigma units: E[chi^2 / (m - 1)] = 1
}

TEST(TemporalUnwrapper, CoprimePeriodsWithNoise) {
  std::printf("7/11/13 over 1001 px: code separation %.4f cycles\n",
              TemporalUnwrapper({7, 11, 13}, 1001).separation_cycles());
  // An 800 px projector: every column incl. the outer half pixels.
  CheckNoisyUnwrapping({7, 11, 13}, 800, -0.5, 799.5);
  // Width = code period (1001 px): u = -0.5 and 1000.5 are the same code, so the outermost
  // 6 sigma_u (0.3 px) alias; everything inside is recovered.
  CheckNoisyUnwrapping({7, 11, 13}, 1001, -0.2, 1000.2);
}

// Integer period ratios let Unwrap score the candidates from per-pixel residual tables (and,
// with three periods, from the few smallest entries of two tables). Periods perturbed by 1e-10
// have no such structure and take the plain scan over every candidate: both must pick the same
// fringe orders, on good phases, noisy ones and random ones (where the ranking is close). (Not
// on 7/11/13 over 1001 px: its two ends alias exactly, and which of two equal candidates wins is
// then decided by rounding, in either path.)
TEST(TemporalUnwrapper, ResidualTablesPickTheSameCandidatesAsTheFullScan) {
  for (const auto& [periods, range] : {std::pair{std::vector<double>{7, 11, 13}, 800.0},
                                       std::pair{std::vector<double>{13, 11, 7}, 900.0},
                                       std::pair{std::vector<double>{12.5, 8, 9}, 1000.0},
                                       std::pair{std::vector<double>{800, 20}, 800.0}}) {
    std::vector<double> perturbed = periods;
    for (double& p : perturbed) p *= 1.0 + 1e-10;
    const TemporalUnwrapper tables(periods, range), scan(perturbed, range);
    std::mt19937_64 rng(9);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    std::normal_distribution<double> noise(0.0, 1.0);
    const int m = static_cast<int>(periods.size());
    int valid = 0;
    for (int p = 0; p < 100000; ++p) {
      const double sigma = p % 3 == 0 ? 0.3 : 0.03;
      auto t = PhasesAt(-0.5 + range * uni(rng), periods);
      std::vector<double> w(m);
      for (int i = 0; i < m; ++i) {
        t[i] = p % 10 == 0 ? kTwoPi * uni(rng) : t[i] + sigma * noise(rng);
        w[i] = (0.5 + uni(rng)) / (sigma * sigma);
      }
      const UnwrapResult a = tables.Unwrap(t.data(), w.data());
      const UnwrapResult b = scan.Unwrap(t.data(), w.data());
      ASSERT_EQ(a.valid, b.valid) << p;
      ASSERT_NEAR(a.u, b.u, 1e-6) << p;
      ASSERT_NEAR(a.residual, b.residual, 1e-6) << p;
      valid += a.valid;
    }
    EXPECT_GT(valid, 50000);
  }
}

uint64_t Bits(double d) {
  uint64_t b;
  std::memcpy(&b, &d, sizeof(b));
  return b;
}

// Pixels for the lane tests: good, noisy and random phases, non-finite values, weights that are
// 0, negative, tiny or huge (their sums overflow), phases on fringe-order boundaries.
void LaneTestPixels(const std::vector<double>& periods, double range, int n,
                    std::vector<double>* theta, std::vector<double>* weight) {
  const int m = static_cast<int>(periods.size());
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 1.0);
  theta->assign(static_cast<size_t>(n) * m, 0.0);
  weight->assign(theta->size(), 0.0);
  for (int p = 0; p < n; ++p) {
    const double sigma = p % 3 == 0 ? 0.3 : p % 3 == 1 ? 0.03 : 0.001;
    const double u = -0.5 + range * uni(rng);
    const auto t = PhasesAt(p % 7 == 0 ? std::round(u * 2.0) / 2.0 : u, periods);
    for (int i = 0; i < m; ++i) {
      double& th = (*theta)[static_cast<size_t>(p) * m + i];
      double& w = (*weight)[static_cast<size_t>(p) * m + i];
      th = p % 10 == 0 ? kTwoPi * uni(rng) : p % 7 == 0 ? t[i] : t[i] + sigma * noise(rng);
      w = (0.5 + uni(rng)) / (sigma * sigma);
      const int kind = static_cast<int>(rng() % 400);
      if (kind == 0) th = std::nan("");
      if (kind == 1) th = std::numeric_limits<double>::infinity();
      if (kind == 2) w = 0.0;
      if (kind == 3) w = -1.0;
      if (kind == 4) w = 1e-300;
      if (kind == 5) w = 1e300;
      if (kind == 6) th = -th - 40.0;
    }
  }
}

const std::pair<std::vector<double>, double> kLaneTestSets[] = {{{7, 11, 13}, 800.0},
                                                                {{13, 7, 11}, 800.0},
                                                                {{7, 11, 13}, 1001.0},
                                                                {{12.5, 8, 9}, 1000.0},
                                                                {{800, 20}, 800.0}};

// Does u_a fall on the same fringe order as u_b in every period?
bool SameOrders(double u_a, double u_b, const double* theta, const std::vector<double>& periods) {
  for (size_t i = 0; i < periods.size(); ++i) {
    const double t = theta[i] / kTwoPi - std::floor(theta[i] / kTwoPi);
    if (std::nearbyint(u_a / periods[i] - t) != std::nearbyint(u_b / periods[i] - t)) return false;
  }
  return true;
}

void ExpectSameResult(const UnwrapResult& want, const UnwrapResult& got, int p) {
  ASSERT_EQ(Bits(want.u), Bits(got.u)) << p;
  ASSERT_EQ(Bits(want.residual), Bits(got.residual)) << p;
  ASSERT_EQ(want.valid, got.valid) << p;
  ASSERT_EQ(want.ambiguous_edge, got.ambiguous_edge) << p;
}

// UnwrapMany (four pixels at a time in the common case) gives Unwrap()'s results to the last bit
// (LaneTestPixels), on period sets with and without the common case, and counts that are not a
// multiple of four.
TEST(TemporalUnwrapper, UnwrapManyMatchesUnwrapBitForBit) {
  for (const auto& [periods, range] : kLaneTestSets) {
    const TemporalUnwrapper unwrapper(periods, range);
    const int m = static_cast<int>(periods.size());
    const int n = 60003;
    std::vector<double> theta, weight;
    LaneTestPixels(periods, range, n, &theta, &weight);
    std::vector<UnwrapResult> many(n);
    unwrapper.UnwrapMany(theta.data(), weight.data(), n, many.data());
    for (int p = 0; p < n; ++p)
      ExpectSameResult(
          unwrapper.Unwrap(&theta[static_cast<size_t>(p) * m], &weight[static_cast<size_t>(p) * m]),
          many[p], p);
  }
}

// UnwrapAt (the combine stage's fringe orders from phase shifting alone, the weights from the
// lens-shift noise): at the u that Unwrap() finds with the same weights, Unwrap()'s result to
// the last bit; at the u found with other weights (the noise scaled by 0.3-3 per pixel, as a
// different noise estimate would), the same wherever both find the same orders (the common
// case); and UnwrapAtMany's lanes give UnwrapAt()'s results to the last bit.
TEST(TemporalUnwrapper, UnwrapAtMatchesUnwrapWhereTheOrdersAgree) {
  for (const auto& [periods, range] : kLaneTestSets) {
    const TemporalUnwrapper unwrapper(periods, range);
    const int m = static_cast<int>(periods.size());
    const int n = 30001;
    std::vector<double> theta, weight;
    LaneTestPixels(periods, range, n, &theta, &weight);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> scale(0.3, 3.0);
    std::vector<double> other(weight.size());
    for (size_t q = 0; q < other.size(); ++q) other[q] = weight[q] * std::pow(scale(rng), -2);
    std::vector<double> hint_same(n), hint_other(n);
    std::vector<UnwrapResult> want(n);
    int agree = 0, valid = 0;
    for (int p = 0; p < n; ++p) {
      const double* th = &theta[static_cast<size_t>(p) * m];
      want[p] = unwrapper.Unwrap(th, &weight[static_cast<size_t>(p) * m]);
      const UnwrapResult o = unwrapper.Unwrap(th, &other[static_cast<size_t>(p) * m]);
      hint_same[p] = want[p].u;
      hint_other[p] = o.valid ? o.u : std::nan("");
      if (want[p].valid) {
        ++valid;
        ExpectSameResult(
            want[p], unwrapper.UnwrapAt(th, &weight[static_cast<size_t>(p) * m], hint_same[p]), p);
      }
      if (want[p].valid && o.valid && SameOrders(o.u, want[p].u, th, periods)) {
        ++agree;
        ExpectSameResult(
            want[p], unwrapper.UnwrapAt(th, &weight[static_cast<size_t>(p) * m], hint_other[p]), p);
      }
    }
    std::printf("%zu periods: %d of %d valid pixels on the same orders\n", periods.size(), agree,
                valid);
    EXPECT_GT(agree, 0.95 * valid) << agree << " of " << valid;
    for (const std::vector<double>* hints : {&hint_same, &hint_other}) {
      std::vector<UnwrapResult> many(n);
      unwrapper.UnwrapAtMany(theta.data(), weight.data(), hints->data(), n, many.data());
      for (int p = 0; p < n; ++p)
        ExpectSameResult(unwrapper.UnwrapAt(&theta[static_cast<size_t>(p) * m],
                                            &weight[static_cast<size_t>(p) * m], (*hints)[p]),
                         many[p], p);
    }
  }
}

TEST(TemporalUnwrapper, InconsistentPhasesAreFlagged) {
  // Random phases (a pixel mixing two surfaces, or no signal): the residual exposes them unless
  // they happen to fall within the 4-sigma acceptance tube around one of the 1001 valid codes.
  // The tube's share of the code space scales with sigma^2: ~5 % at sigma = 0.005 rad.
  const std::vector<double> periods = {7, 11, 13};
  const TemporalUnwrapper unwrapper(periods, 1001);
  const double sigma = 0.005;
  const std::vector<double> w(3, 1.0 / (sigma * sigma));
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> uni(0.0, kTwoPi);
  int flagged = 0;
  const int n = 4000;
  for (int i = 0; i < n; ++i) {
    const double t[3] = {uni(rng), uni(rng), uni(rng)};
    flagged += !unwrapper.Unwrap(t, w.data()).valid;
  }
  std::printf("random phases flagged: %.1f %%\n", 100.0 * flagged / n);
  EXPECT_GE(flagged, n * 9 / 10);
  // A single corrupted period (half a period off) is flagged too.
  auto t = PhasesAt(500.3, periods);
  t[1] = std::fmod(t[1] + kTwoPi / 2, kTwoPi);
  EXPECT_FALSE(unwrapper.Unwrap(t.data(), w.data()).valid);
  // Non-finite input or weight <= 0.
  const double bad[3] = {std::nan(""), 1.0, 1.0};
  EXPECT_FALSE(unwrapper.Unwrap(bad, w.data()).valid);
  const double zero_w[3] = {1.0, 0.0, 1.0};
  EXPECT_FALSE(unwrapper.Unwrap(t.data(), zero_w).valid);
}

TEST(TemporalUnwrapper, HierarchicalCuePlusShortPeriods) {
  // A cue period >= the width gives u coarsely; 64 and 16 px refine it (chained coarse to fine).
  const std::vector<double> periods = {1024, 64, 16};
  const TemporalUnwrapper unwrapper(periods, 1000);
  const std::vector<double> sigma = {0.02, 0.02, 0.02};
  std::vector<double> w;
  for (double s : sigma) w.push_back(1.0 / (s * s));
  std::mt19937_64 rng(6);
  std::normal_distribution<double> noise(0.0, 1.0);
  for (double u = -0.4; u < 999.5; u += 0.37) {
    auto t0 = PhasesAt(u, periods);
    const UnwrapResult exact = unwrapper.Unwrap(t0.data(), w.data());
    ASSERT_TRUE(exact.valid) << u;
    ASSERT_NEAR(exact.u, u, 1e-9);
    for (int i = 0; i < 3; ++i) t0[i] = std::fmod(t0[i] + sigma[i] * noise(rng) + kTwoPi, kTwoPi);
    const UnwrapResult r = unwrapper.Unwrap(t0.data(), w.data());
    ASSERT_TRUE(r.valid) << u;
    // sigma_u ~ 16 / 2 pi * 0.02 = 0.05 px: a wrong fringe order would be >= 16 px off.
    ASSERT_NEAR(r.u, u, 0.3) << u;
  }
  // Two periods only: cue + fine (the plain hierarchical scanner).
  const TemporalUnwrapper two({800, 20}, 800);
  for (double u = 0; u < 799.5; u += 1.3) {
    const auto t = PhasesAt(u, {800, 20});
    const double w2[2] = {1e4, 1e4};
    const UnwrapResult r = two.Unwrap(t.data(), w2);
    ASSERT_TRUE(r.valid) << u;
    ASSERT_NEAR(r.u, u, 1e-9) << u;
  }
}

TEST(TemporalUnwrapper, OnePeriodCueAsWideAsTheProjector) {
  // 16 periods + a one-period cue exactly as wide (high) as the projector (the held-back real
  // rig: 1824 px / 114 px and 1140 px / 71.25 px). Columns at opposite edges share nearly the
  // same code: they are marked ambiguous, every other column decodes.
  for (const auto& [range, fine] : {std::pair{1824.0, 114.0}, std::pair{1140.0, 71.25}}) {
    const std::vector<double> periods = {range, fine};
    const TemporalUnwrapper unwrapper(periods, range);
    const double e = unwrapper.edge_margin_px();
    EXPECT_GT(e, 0.0);
    EXPECT_LE(e, 5.0) << "only a few columns at each edge";
    EXPECT_GE(unwrapper.separation_cycles(), TemporalUnwrapper::kMinSeparationCycles);
    const double w[2] = {1.0 / (0.003 * 0.003), 1.0 / (0.003 * 0.003)};
    std::mt19937_64 rng(11);
    std::normal_distribution<double> noise(0.0, 0.003);
    int ambiguous = 0, interior = 0, rejected = 0;
    for (double u = -0.4; u < range - 0.5; u += 0.29) {
      auto t = PhasesAt(u, periods);
      for (double& x : t) x = std::fmod(x + noise(rng) + 2 * kTwoPi, kTwoPi);
      const UnwrapResult r = unwrapper.Unwrap(t.data(), w);
      if (u >= e + 0.5 && u <= range - 1.5 - e) {
        // sigma_u = 114 / 2 pi * 0.003 = 0.054 px: 0.4 px is 7 sigma, a wrong order >= 71 px.
        // The consistency test (4 sigma) rejects ~6e-5 of the interior columns by chance.
        ++interior;
        if (!r.valid) {
          ++rejected;
          continue;
        }
        ASSERT_NEAR(r.u, u, 0.4) << range << " " << u;
      } else if (r.valid) {
        // Next to the band a column may still decode: then correctly.
        ASSERT_NEAR(r.u, u, 0.4) << range << " " << u;
      } else {
        ++ambiguous;
        EXPECT_TRUE(r.ambiguous_edge) << u;
      }
    }
    EXPECT_GT(ambiguous, 0);
    EXPECT_LE(rejected, 2) << interior;
  }
  // A cue longer than the width is unambiguous everywhere.
  EXPECT_EQ(TemporalUnwrapper({2000, 114}, 1824).edge_margin_px(), 0.0);
  // Sets that repeat inside the projector are still refused (the band would be too wide).
  EXPECT_THROW(TemporalUnwrapper({700, 50}, 800), Error);
}

TEST(TemporalUnwrapper, SinglePeriodAndRejectedSets) {
  // One period >= width: the wrapped phase is the answer.
  const TemporalUnwrapper one({1200}, 1000);
  const double t = kTwoPi * 333.25 / 1200, w = 1e4;
  const UnwrapResult r = one.Unwrap(&t, &w);
  EXPECT_TRUE(r.valid);
  EXPECT_NEAR(r.u, 333.25, 1e-9);
  EXPECT_EQ(r.residual, 0.0);
  // Periods that cannot tell all columns apart.
  EXPECT_THROW(TemporalUnwrapper({8, 12}, 1000), Error);  // repeats every 24 px
  EXPECT_THROW(TemporalUnwrapper({16}, 1000), Error);
  EXPECT_THROW(TemporalUnwrapper({512, 16}, 800), Error);  // 512 and 16 align at 512 px
  EXPECT_THROW(TemporalUnwrapper({}, 1000), Error);
  EXPECT_THROW(TemporalUnwrapper({7, -11}, 1000), Error);
  EXPECT_NO_THROW(TemporalUnwrapper({7, 11, 13}, 1001));
}

}  // namespace
}  // namespace mesoscan
