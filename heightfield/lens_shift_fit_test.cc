#include "heightfield/lens_shift_fit.h"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <numbers>
#include <random>
#include <vector>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace mesoscan {
namespace {

constexpr double kF0 = 0.5;  // 2-px stripes: 0.5 cycles per projector px

// Shift positions as the pipeline passes them: n frames uniformly over [-1, 1] projector px
// (range_steps -2048..2048 at 2048 steps/px), referenced to the centre of the range.
std::vector<double> CentredPositions(int n, double half_range = 1.0) {
  std::vector<double> x(n);
  for (int i = 0; i < n; ++i) x[i] = -half_range + 2.0 * half_range * i / std::max(n - 1, 1);
  return x;
}

struct Truth {
  double phase, amplitude, frequency, offset;
};

std::vector<float> Profile(const Truth& t, const std::vector<double>& x, double sigma,
                           std::mt19937_64* rng) {
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<float> b(x.size());
  for (size_t i = 0; i < x.size(); ++i)
    b[i] = static_cast<float>(t.amplitude * std::sin(t.phase + 2 * kPi * t.frequency * x[i]) +
                              t.offset + (sigma > 0 ? sigma * noise(*rng) : 0.0));
  return b;
}

double PhaseDiff(double a, double b) { return std::remainder(a - b, 2 * kPi); }

LensShiftFitOptions Options(LensShiftFitter fitter) {
  LensShiftFitOptions o;
  o.fitter = fitter;
  return o;
}

const LensShiftFitter kAllFitters[] = {LensShiftFitter::kFast, LensShiftFitter::kLm,
                                       LensShiftFitter::kCeres};

TEST(LensShiftFit, NamesRoundTripAndOptionsCheck) {
  for (LensShiftFitter f : kAllFitters) EXPECT_EQ(ParseLensShiftFitter(LensShiftFitterName(f)), f);
  EXPECT_THROW(ParseLensShiftFitter("newton"), Error);
  LensShiftFitOptions o;
  EXPECT_NO_THROW(o.Check());
  o.max_iterations = 0;
  EXPECT_THROW(o.Check(), Error);
  o = {};
  o.max_frequency_deviation = 1.5;
  EXPECT_THROW(o.Check(), Error);
  EXPECT_THROW(LensShiftBatchFitter({}, kF0, {}), Error);
  EXPECT_THROW(LensShiftBatchFitter(CentredPositions(10), 0.0, {}), Error);
}

TEST(LensShiftFit, CrlbMatchesClosedFormForCentredUniformPositions) {
  // With f known, centred uniform x over whole periods give var(phi) >= 2 sigma^2 / (N a^2)
  // (Ritz et al. 2012, Sec. 6) up to O(1/N) from sampling. Fitting f adds the phi-f coupling
  // sum x cos^2(psi) = sum x cos(2 psi) / 2, which vanishes only on average over phi: for x
  // spanning one stripe period it raises the phase-averaged bound by a few percent, never
  // lowers it.
  for (int n : {15, 50, 200}) {
    const auto x = CentredPositions(n);
    const double sigma = 0.01, a = 0.3;
    const double closed = 2 * sigma * sigma / (n * a * a);
    const double fixed_f = LensShiftPhaseCrlb(sigma, a, x, kF0, false);
    const double free_f = LensShiftPhaseCrlb(sigma, a, x, kF0);
    std::printf("CRLB / (2 sigma^2 / N a^2): N %d: f fixed %.4f, f fitted %.4f\n", n,
                fixed_f / closed, free_f / closed);
    EXPECT_NEAR(fixed_f / closed, 1.0, 3.0 / n) << "n " << n;
    EXPECT_GE(free_f, fixed_f * (1 - 1e-12));
    EXPECT_LT(free_f, 1.1 * fixed_f);
  }
  // Off-centre positions make phi and f strongly correlated: the bound grows a lot.
  auto x = CentredPositions(50);
  for (double& v : x) v += 2.0;
  EXPECT_GT(LensShiftPhaseCrlb(0.01, 0.3, x, kF0),
            5 * LensShiftPhaseCrlb(0.01, 0.3, x, kF0, false));
}

// Noise-free profiles: every fitter recovers every parameter to rounding (float samples carry
// 6e-8 relative error, so phase errors of ~1e-6 rad are the floor).
TEST(LensShiftFit, ExactRecoveryNoiseFree) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (LensShiftFitter fitter : kAllFitters) {
    for (int n : {15, 50, 200}) {
      const auto x = CentredPositions(n);
      const LensShiftBatchFitter batch(x, kF0, Options(fitter));
      for (int trial = 0; trial < 20; ++trial) {
        const Truth t{-kPi + 2 * kPi * uni(rng), 0.05 + 0.4 * uni(rng),
                      kF0 * (0.8 + 0.4 * uni(rng)), 0.1 + 0.5 * uni(rng)};
        const auto b = Profile(t, x, 0.0, &rng);
        const LensShiftFit fit = batch.Fit(b.data());
        ASSERT_TRUE(fit.valid) << LensShiftFitterName(fitter) << " n " << n << " trial " << trial;
        EXPECT_NEAR(PhaseDiff(fit.phase, t.phase), 0.0, 2e-6) << LensShiftFitterName(fitter);
        EXPECT_NEAR(fit.amplitude, t.amplitude, 2e-6);
        EXPECT_NEAR(fit.frequency, t.frequency, 2e-6);
        EXPECT_NEAR(fit.offset, t.offset, 2e-6);
        // kFast computes SSR = sum y^2 - J with the moments truncated at tau = 5.5e-9 relative
        // (lens_shift_fit.cc): |dSSR| <= tau N a^2, a floor of sqrt(tau) a = 7.4e-5 a on the
        // RMS, far below any real noise (a / sigma < 1e4). The others evaluate the residual
        // directly: float rounding of the samples only.
        const double floor = fitter == LensShiftFitter::kFast ? 7.4e-5 * t.amplitude : 2e-7;
        EXPECT_LT(fit.residual_rms, floor);
        EXPECT_GT(fit.phase, -kPi);
        EXPECT_LE(fit.phase, kPi);
      }
    }
  }
}

// The three fitters minimise the same objective: on noisy profiles they agree to a small
// fraction of the noise-induced phase error (here 1% of sigma_phi).
TEST(LensShiftFit, FittersReachTheSameMinimum) {
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int n : {15, 50, 200}) {
    const auto x = CentredPositions(n);
    const LensShiftBatchFitter fast(x, kF0, Options(LensShiftFitter::kFast));
    const LensShiftBatchFitter lm(x, kF0, Options(LensShiftFitter::kLm));
    const LensShiftBatchFitter ceres(x, kF0, Options(LensShiftFitter::kCeres));
    for (int trial = 0; trial < 50; ++trial) {
      const Truth t{-kPi + 2 * kPi * uni(rng), 0.2, kF0 * (0.85 + 0.3 * uni(rng)), 0.4};
      const double sigma = 0.02;  // a / sigma = 10
      const auto b = Profile(t, x, sigma, &rng);
      const double sigma_phi = std::sqrt(LensShiftPhaseCrlb(sigma, t.amplitude, x, t.frequency));
      const LensShiftFit r = ceres.Fit(b.data());
      ASSERT_TRUE(r.valid) << "n " << n << " trial " << trial;
      for (const LensShiftBatchFitter* f : {&fast, &lm}) {
        const LensShiftFit g = f->Fit(b.data());
        ASSERT_TRUE(g.valid) << LensShiftFitterName(f->options().fitter);
        EXPECT_LT(std::abs(PhaseDiff(g.phase, r.phase)), 0.01 * sigma_phi)
            << LensShiftFitterName(f->options().fitter) << " n " << n << " trial " << trial;
        EXPECT_NEAR(g.frequency, r.frequency, 1e-3 * std::abs(kF0));
        EXPECT_NEAR(g.residual_rms, r.residual_rms, 1e-3 * r.residual_rms);
      }
    }
  }
}

TEST(LensShiftFit, SingleProfileMatchesBatchAndHonoursStride) {
  std::mt19937_64 rng(13);
  const auto x = CentredPositions(40);
  const Truth t{1.0, 0.3, 0.52, 0.5};
  const auto b = Profile(t, x, 0.01, &rng);
  std::vector<float> strided(b.size() * 3, std::numeric_limits<float>::quiet_NaN());
  for (size_t i = 0; i < b.size(); ++i) strided[3 * i] = b[i];
  for (LensShiftFitter fitter : kAllFitters) {
    const LensShiftBatchFitter batch(x, kF0, Options(fitter));
    const LensShiftFit a = batch.Fit(b.data());
    const LensShiftFit s = batch.Fit(strided.data(), 3);
    const LensShiftFit p = FitLensShiftProfile(b.data(), x.data(), 40, kF0, Options(fitter));
    ASSERT_TRUE(a.valid && s.valid && p.valid);
    EXPECT_EQ(a.phase, s.phase);
    EXPECT_NEAR(a.phase, p.phase, 1e-9);
    EXPECT_EQ(a.samples_used, 40);
  }
}

TEST(LensShiftFit, FixedFrequencyUsesTheGivenStart) {
  std::mt19937_64 rng(14);
  const auto x = CentredPositions(30);
  const Truth t{-2.0, 0.3, 0.55, 0.5};
  const auto b = Profile(t, x, 0.0, &rng);
  for (LensShiftFitter fitter : kAllFitters) {
    LensShiftFitOptions o = Options(fitter);
    o.fit_frequency = false;
    const LensShiftBatchFitter batch(x, kF0, o);
    const LensShiftFit fit = batch.Fit(b.data(), 1, 0.55);
    ASSERT_TRUE(fit.valid) << LensShiftFitterName(fitter);
    EXPECT_EQ(fit.frequency, 0.55);
    EXPECT_NEAR(PhaseDiff(fit.phase, t.phase), 0.0, 2e-6);
    // At the wrong frequency the fit is biased and its residual shows it.
    const LensShiftFit off = batch.Fit(b.data());
    EXPECT_GT(off.residual_rms, 100 * fit.residual_rms + 1e-4);
  }
}

TEST(LensShiftFit, NegativeNominalFrequency) {
  std::mt19937_64 rng(15);
  const auto x = CentredPositions(25);
  const Truth t{0.7, 0.3, -0.47, 0.5};
  const auto b = Profile(t, x, 0.0, &rng);
  for (LensShiftFitter fitter : kAllFitters) {
    const LensShiftFit fit = LensShiftBatchFitter(x, -kF0, Options(fitter)).Fit(b.data());
    ASSERT_TRUE(fit.valid) << LensShiftFitterName(fitter);
    EXPECT_NEAR(fit.frequency, -0.47, 1e-6);
    EXPECT_NEAR(PhaseDiff(fit.phase, 0.7), 0.0, 2e-6);
  }
}

// ---------------------------------------------------------------------------------------------
// Stress suite: degenerate and hostile profiles. Never a throw, never a non-finite field in a
// valid fit, bounded iterations, and valid == false where the fit means nothing.

void ExpectSane(const LensShiftFit& fit, const LensShiftFitOptions& o, const char* what) {
  SCOPED_TRACE(what);
  for (double v :
       {fit.phase, fit.amplitude, fit.frequency, fit.offset, fit.residual_rms, fit.phase_sigma})
    EXPECT_TRUE(std::isfinite(v));
  EXPECT_LE(fit.iterations, 2 * o.max_iterations);  // LM: two stages of max_iterations
  if (fit.valid) {
    EXPECT_GT(fit.phase, -kPi);
    EXPECT_LE(fit.phase, kPi);
    EXPECT_GE(fit.amplitude, 0.0);
  }
}

class LensShiftStress : public ::testing::TestWithParam<LensShiftFitter> {};

TEST_P(LensShiftStress, DegenerateProfiles) {
  const LensShiftFitOptions o = Options(GetParam());
  const auto x = CentredPositions(50);
  const LensShiftBatchFitter batch(x, kF0, o);
  std::mt19937_64 rng(21);
  auto fit = [&](const std::vector<float>& b, const char* what) {
    LensShiftFit r;
    EXPECT_NO_THROW(r = batch.Fit(b.data())) << what;
    ExpectSane(r, o, what);
    return r;
  };
  // Constant, at zero and far from zero.
  EXPECT_FALSE(fit(std::vector<float>(50, 0.0f), "zero").valid);
  EXPECT_FALSE(fit(std::vector<float>(50, 0.7f), "constant").valid);
  EXPECT_FALSE(fit(std::vector<float>(50, 3e4f), "large constant").valid);
  // Huge values whose squares overflow float.
  EXPECT_NO_THROW(fit(Profile({0.3, 3e30, 0.5, 1e30}, x, 0.0, &rng), "huge"));
  // NaN / Inf samples: a few are left out, the fit stays exact.
  const Truth t{0.4, 0.3, 0.53, 0.5};
  auto b = Profile(t, x, 0.0, &rng);
  b[3] = std::numeric_limits<float>::quiet_NaN();
  b[17] = std::numeric_limits<float>::infinity();
  b[40] = -std::numeric_limits<float>::infinity();
  LensShiftFit r = fit(b, "nan/inf");
  EXPECT_TRUE(r.valid);
  EXPECT_EQ(r.samples_used, 47);
  EXPECT_NEAR(PhaseDiff(r.phase, t.phase), 0.0, 2e-6);
  EXPECT_FALSE(
      fit(std::vector<float>(50, std::numeric_limits<float>::quiet_NaN()), "all nan").valid);
  // Clipped (saturated) profile: symmetric clipping keeps the phase; the residual shows it.
  b = Profile(t, x, 0.0, &rng);
  for (float& v : b) v = std::clamp(v, 0.3f, 0.7f);
  r = fit(b, "clipped");
  EXPECT_TRUE(r.valid);
  EXPECT_NEAR(PhaseDiff(r.phase, t.phase), 0.0, 0.05);
  EXPECT_GT(r.residual_rms, 1e-3);
  // Frequency off by +-30 % from nominal: still found exactly.
  for (double rel : {0.7, 1.3}) {
    const Truth tf{-1.2, 0.3, kF0 * rel, 0.5};
    r = fit(Profile(tf, x, 0.0, &rng), "frequency off");
    EXPECT_TRUE(r.valid) << rel;
    EXPECT_NEAR(r.frequency, tf.frequency, 1e-6) << rel;
    EXPECT_NEAR(PhaseDiff(r.phase, tf.phase), 0.0, 2e-6) << rel;
  }
  // Offset far above the amplitude (1e3 x) with noise 1 % of the amplitude.
  const Truth to{2.5, 0.01, 0.51, 10.0};
  const double sigma_phi = std::sqrt(LensShiftPhaseCrlb(1e-4, 0.01, x, 0.51));
  r = fit(Profile(to, x, 1e-4, &rng), "offset >> amplitude");
  EXPECT_TRUE(r.valid);
  EXPECT_NEAR(PhaseDiff(r.phase, to.phase), 0.0, 5 * sigma_phi);
}

TEST_P(LensShiftStress, NoiseWithoutSignalIsRejected) {
  // Pure noise, zero amplitude, and amplitude far below the noise (a = 0.05 sigma): the
  // amplitude test (a / sigma_a >= 4) rejects them; with f free the fitter picks the best f,
  // which inflates the false-accept rate above the fixed-f 3e-4, but it stays small.
  const LensShiftFitOptions o = Options(GetParam());
  const auto x = CentredPositions(50);
  const LensShiftBatchFitter batch(x, kF0, o);
  std::mt19937_64 rng(22);
  const int trials = GetParam() == LensShiftFitter::kCeres ? 100 : 400;
  for (double a : {0.0, 0.05}) {
    int accepted = 0;
    for (int i = 0; i < trials; ++i) {
      const auto b = Profile({1.0, a, kF0, 0.5}, x, 1.0, &rng);
      LensShiftFit r;
      EXPECT_NO_THROW(r = batch.Fit(b.data()));
      ExpectSane(r, o, "noise");
      accepted += r.valid;
    }
    EXPECT_LE(accepted, trials / 50) << "a " << a;
  }
}

TEST_P(LensShiftStress, TooFewSamples) {
  const LensShiftFitOptions o = Options(GetParam());
  std::mt19937_64 rng(23);
  const Truth t{0.3, 0.3, 0.5, 0.5};
  for (int n : {1, 2, 3, 4}) {
    const auto x = CentredPositions(n);
    const auto b = Profile(t, x, 0.0, &rng);
    LensShiftFit r;
    EXPECT_NO_THROW(r = LensShiftBatchFitter(x, kF0, o).Fit(b.data())) << n;
    ExpectSane(r, o, "few samples");
    EXPECT_FALSE(r.valid) << n;  // 4 parameters need >= 5 samples for a residual
  }
  // Fixed frequency: 3 parameters, 4 samples is the minimum.
  LensShiftFitOptions of = o;
  of.fit_frequency = false;
  const auto x = CentredPositions(4);
  const LensShiftFit r = LensShiftBatchFitter(x, kF0, of).Fit(Profile(t, x, 0.0, &rng).data());
  EXPECT_TRUE(r.valid);
  EXPECT_NEAR(PhaseDiff(r.phase, t.phase), 0.0, 2e-6);
  // 5 samples, 4 parameters, noise-free: exact.
  const auto x5 = CentredPositions(5);
  const Truth t5{0.3, 0.3, 0.45, 0.5};
  const LensShiftFit r5 = LensShiftBatchFitter(x5, kF0, o).Fit(Profile(t5, x5, 0.0, &rng).data());
  EXPECT_TRUE(r5.valid);
  EXPECT_NEAR(PhaseDiff(r5.phase, t5.phase), 0.0, 1e-5);
}

INSTANTIATE_TEST_SUITE_P(AllFitters, LensShiftStress, ::testing::ValuesIn(kAllFitters),
                         [](const auto& info) { return LensShiftFitterName(info.param); });

// ---------------------------------------------------------------------------------------------
// Randomised property test: the fast fitter is unbiased and efficient (reaches the CRLB).

int PropertyCount() {
  if (const char* env = std::getenv("MESOSCAN_PROPERTY_COUNT"))
    return std::max(1000, std::atoi(env));
#if defined(NDEBUG) && !defined(__SANITIZE_ADDRESS__)
  return 1000000;
#else
  return 40000;  // Debug / ASan: same assertion, fewer profiles
#endif
}

TEST(LensShiftFitProperty, UnbiasedAndEfficient) {
  // Profiles with known parameters: N in {15, 25, 50, 100, 200}, phase uniform, f within +-10 %
  // of f0, a / sigma log-uniform in [10, 100], offset in [0.2, 0.8]. Errors are normalised by
  // each profile's exact CRLB at its true parameters; an unbiased efficient estimator gives
  // mean 0 and variance 1. Asserted: |bias| < 0.05 sigma_phi, variance within 10 % of the CRLB.
  const int count = PropertyCount();
  const int sizes[] = {15, 25, 50, 100, 200};
  std::vector<LensShiftBatchFitter> fitters;
  std::vector<std::vector<double>> xs;
  for (int n : sizes) {
    xs.push_back(CentredPositions(n));
    fitters.emplace_back(xs.back(), kF0, LensShiftFitOptions{});
  }
  constexpr int kBatch = 1000;
  const int batches = (count + kBatch - 1) / kBatch;
  std::vector<double> sum(batches), sum2(batches);
  std::vector<int> invalid(batches), used(batches);
  ParallelFor(batches, [&](int64_t bi) {
    std::mt19937_64 rng(1000 + bi);  // fixed seed per batch: deterministic under any threading
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    std::normal_distribution<double> noise(0.0, 1.0);
    std::vector<float> b(200);
    double s = 0, s2 = 0;
    for (int i = 0; i < kBatch && bi * kBatch + i < count; ++i) {
      const int which = static_cast<int>(uni(rng) * 5) % 5;
      const auto& x = xs[which];
      const double phase = -kPi + 2 * kPi * uni(rng);
      const double f = kF0 * (0.9 + 0.2 * uni(rng));
      const double a = 0.2;
      const double sigma = a / std::exp(std::log(10.0) + std::log(10.0) * uni(rng));
      const double d = 0.2 + 0.6 * uni(rng);
      // Samples and the Fisher information from one rotation recurrence over the uniform x
      // (sin/cos per sample would dominate the run time).
      const int n = static_cast<int>(x.size());
      const double dpsi = 2 * kPi * f * (x[1] - x[0]);
      const double cd = std::cos(dpsi), sd = std::sin(dpsi);
      double c = std::cos(phase + 2 * kPi * f * x[0]), sn = std::sin(phase + 2 * kPi * f * x[0]);
      // Fisher sums of J = (a c, s, 2 pi x a c, 1) / sigma (a and 2 pi applied below).
      double scc = 0, ssc = 0, sss = 0, sxcc = 0, sxsc = 0, sxxcc = 0, sc = 0, ss = 0, sxc = 0;
      for (int k = 0; k < n; ++k) {
        b[k] = static_cast<float>(a * sn + d + sigma * noise(rng));
        const double xk = x[k];
        scc += c * c, ssc += sn * c, sss += sn * sn, sxcc += xk * c * c, sxsc += xk * sn * c;
        sxxcc += xk * xk * c * c, sc += c, ss += sn, sxc += xk * c;
        const double c2 = c * cd - sn * sd;
        sn = sn * cd + c * sd;
        c = c2;
      }
      const double w = 2 * kPi;
      Eigen::Matrix4d fisher;
      fisher << a * a * scc, a * ssc, w * a * a * sxcc, a * sc,                //
          a * ssc, sss, w * a * sxsc, ss,                                      //
          w * a * a * sxcc, w * a * sxsc, w * w * a * a * sxxcc, w * a * sxc,  //
          a * sc, ss, w * a * sxc, static_cast<double>(n);
      const LensShiftFit fit = fitters[which].Fit(b.data());
      if (!fit.valid) {
        ++invalid[bi];
        continue;
      }
      const double crlb = sigma * sigma * fisher.inverse()(0, 0);
      const double e = PhaseDiff(fit.phase, phase) / std::sqrt(crlb);
      s += e;
      s2 += e * e;
      ++used[bi];
    }
    sum[bi] = s;
    sum2[bi] = s2;
  });
  double s = 0, s2 = 0;
  int n_used = 0, n_invalid = 0;
  for (int i = 0; i < batches; ++i)
    s += sum[i], s2 += sum2[i], n_used += used[i], n_invalid += invalid[i];
  const double mean = s / n_used;
  const double var = s2 / n_used - mean * mean;
  RecordProperty("profiles", n_used);
  RecordProperty("bias_over_sigma", std::to_string(mean));
  RecordProperty("var_over_crlb", std::to_string(var));
  std::printf("property test: %d profiles, bias %.4f sigma_phi, var/CRLB %.4f, invalid %d\n",
              n_used, mean, var, n_invalid);
  EXPECT_EQ(n_invalid, 0);
  EXPECT_LT(std::abs(mean), 0.05);
  EXPECT_NEAR(var, 1.0, 0.10);
}

// ---------------------------------------------------------------------------------------------
// Float vs double accumulation of the kFast moments (both on the mean-centred profile).

TEST(LensShiftFit, FloatAccumulationErrorIsFarBelowTheNoise) {
  // Measured (this test, Release, 200 profiles each): max |phase(float) - phase(double)| over
  // N = 50..200, offset / amplitude up to 100, a / sigma = 100:
  // see the printed figures; asserted: below 1 % of sigma_phi (CRLB).
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int n : {50, 200}) {
    const auto x = CentredPositions(n);
    LensShiftFitOptions of, od;
    of.double_accumulation = false;
    od.double_accumulation = true;
    const LensShiftBatchFitter ff(x, kF0, of), fd(x, kF0, od);
    for (double offset_ratio : {1.0, 100.0}) {
      const double a = 0.01, sigma = a / 100;
      const double sigma_phi = std::sqrt(LensShiftPhaseCrlb(sigma, a, x, kF0));
      double worst = 0.0;
      for (int i = 0; i < 200; ++i) {
        const Truth t{-kPi + 2 * kPi * uni(rng), a, kF0 * (0.95 + 0.1 * uni(rng)),
                      a * offset_ratio};
        const auto b = Profile(t, x, sigma, &rng);
        const LensShiftFit rf = ff.Fit(b.data()), rd = fd.Fit(b.data());
        ASSERT_TRUE(rf.valid && rd.valid);
        worst = std::max(worst, std::abs(PhaseDiff(rf.phase, rd.phase)));
      }
      std::printf(
          "float vs double accumulation: N %d, offset/a %.0f: max |dphi| %.2e rad = "
          "%.2e sigma_phi\n",
          n, offset_ratio, worst, worst / sigma_phi);
      EXPECT_LT(worst, 0.01 * sigma_phi) << "n " << n << " offset/a " << offset_ratio;
    }
  }
}

// The row kernel solves the same problem as the per-pixel fixed-frequency fit: every pixel of a
// row (frame-major samples, per-frame gains, per-pixel frequency) agrees with
// LensShiftBatchFitter::Fit on its gain-normalised profile to rounding, including the pixels it
// hands to that path (NaN samples, a frequency off the tables or not finite, a 4-pixel block
// that straddles two grid frequencies, the tail of a row whose width is not a multiple of 4),
// and leaves unused pixels untouched. Positions symmetric about 0 (odd and even counts: the
// kernel folds sample pairs) and jittered (n 40: it does not).
TEST(LensShiftRowFit, MatchesThePerPixelFit) {
  std::mt19937_64 rng(51);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int nk : {3, 15, 50, 40}) {
    auto x = CentredPositions(nk);
    if (nk == 40)
      for (double& v : x) v += 0.01 * (uni(rng) - 0.5);
    LensShiftFitOptions o;
    o.fit_frequency = false;
    const LensShiftRowFitter row(x, kF0, o);
    const LensShiftBatchFitter batch(x, kF0, o);
    const int w = 103;  // not a multiple of 4
    std::vector<float> gain(nk), f(w), b(static_cast<size_t>(nk) * w);
    for (float& g : gain) g = static_cast<float>(1.0 + 0.02 * (uni(rng) - 0.5));
    std::vector<uint8_t> use(w, 1);
    for (int j = 0; j < w; ++j) {
      // Frequencies drift along the row (crossing grid points), a few far ones.
      f[j] = static_cast<float>(kF0 * (0.97 + 0.06 * j / w));
      const Truth t{-kPi + 2 * kPi * uni(rng), 0.2, f[j], 0.5 + uni(rng)};
      const auto p = Profile(t, x, j % 7 == 0 ? 0.0 : 0.01, &rng);
      for (int k = 0; k < nk; ++k) b[static_cast<size_t>(k) * w + j] = p[k] / gain[k];
    }
    f[5] = static_cast<float>(kF0 * 3);              // off the tables
    f[9] = std::numeric_limits<float>::quiet_NaN();  // not finite
    b[static_cast<size_t>(nk / 2) * w + 13] = std::numeric_limits<float>::quiet_NaN();
    for (int k = 0; k < nk; ++k) b[static_cast<size_t>(k) * w + 17] = 0.75f;  // constant
    use[21] = 0;
    std::vector<LensShiftFit> out(w);
    out[21].phase = 123.0;
    row.FitRow(b.data(), w, w, gain.data(), f.data(), use.data(), out.data());
    EXPECT_EQ(out[21].phase, 123.0);
    for (int j = 0; j < w; ++j) {
      if (!use[j]) continue;
      std::vector<float> p(nk);
      for (int k = 0; k < nk; ++k) p[k] = b[static_cast<size_t>(k) * w + j] * gain[k];
      const LensShiftFit ref = batch.Fit(p.data(), 1, f[j]);
      const LensShiftFit& got = out[j];
      ASSERT_EQ(got.valid, ref.valid) << "nk " << nk << " pixel " << j;
      EXPECT_EQ(got.samples_used, ref.samples_used) << "pixel " << j;
      if (!ref.valid) continue;
      const double tol = 1e-10 * (1.0 + std::abs(ref.offset) / ref.amplitude);
      EXPECT_NEAR(PhaseDiff(got.phase, ref.phase), 0.0, tol) << "nk " << nk << " pixel " << j;
      EXPECT_NEAR(got.amplitude, ref.amplitude, tol * ref.amplitude) << "pixel " << j;
      EXPECT_NEAR(got.offset, ref.offset, tol * ref.amplitude) << "pixel " << j;
      EXPECT_NEAR(got.frequency, ref.frequency, 1e-15) << "pixel " << j;
      EXPECT_NEAR(got.residual_rms, ref.residual_rms, 1e-6 * ref.amplitude) << "pixel " << j;
      // Noise-free pixels: the residual is the float rounding of the samples (phase_sigma
      // 4e-8-1e-6 rad), and sum y^2 - J takes the double rounding of sum y^2 (~1e-16 of it),
      // which moves it by up to ~30 %: 1e-7 rad absolute.
      EXPECT_NEAR(got.phase_sigma, ref.phase_sigma, 1e-6 * ref.phase_sigma + 1e-7) << "pixel " << j;
    }
    EXPECT_FALSE(out[5].valid);
    EXPECT_FALSE(out[9].valid);
    EXPECT_FALSE(out[17].valid);
    if (nk > 3) {
      EXPECT_TRUE(out[13].valid);  // the finite samples alone
    }
  }
  LensShiftFitOptions four;  // fit_frequency: the row kernel is for the fixed-frequency pass
  EXPECT_THROW(LensShiftRowFitter(CentredPositions(10), kF0, four), Error);
}

// The fast fitter's statistical stopping rule (frequency_tolerance_sigma) against the absolute
// tolerance alone: the phase moves by a small fraction of its noise, on noisy and on clean
// profiles (bench_fitters stopping_rule: <= 2.4e-3 sigma_phi measured).
TEST(LensShiftFit, StoppingRuleMovesThePhaseFarBelowTheNoise) {
  std::mt19937_64 rng(61);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int n : {15, 100}) {
    const auto x = CentredPositions(n);
    LensShiftFitOptions loose, strict;
    strict.frequency_tolerance_sigma = 0.0;
    const LensShiftBatchFitter fl(x, kF0, loose), fs(x, kF0, strict);
    for (double snr : {20.0, 1000.0}) {
      const double a = 0.2, sigma = a / snr;
      const double sigma_phi = std::sqrt(LensShiftPhaseCrlb(sigma, a, x, kF0));
      double worst = 0.0;
      for (int i = 0; i < 300; ++i) {
        const Truth t{-kPi + 2 * kPi * uni(rng), a, kF0 * (0.95 + 0.1 * uni(rng)), 0.5};
        const auto b = Profile(t, x, sigma, &rng);
        const LensShiftFit rl = fl.Fit(b.data()), rs = fs.Fit(b.data());
        ASSERT_EQ(rl.valid, rs.valid);
        if (rl.valid) worst = std::max(worst, std::abs(PhaseDiff(rl.phase, rs.phase)));
      }
      EXPECT_LT(worst, 0.01 * sigma_phi) << "n " << n << " a/sigma " << snr;
    }
  }
  LensShiftFitOptions bad;
  bad.frequency_tolerance_sigma = -1.0;
  EXPECT_THROW(bad.Check(), Error);
}

TEST(LensShiftFit, BatchFitIsThreadSafe) {
  const auto x = CentredPositions(50);
  const LensShiftBatchFitter batch(x, kF0, {});
  std::mt19937_64 rng(41);
  std::vector<std::vector<float>> profiles;
  for (int i = 0; i < 256; ++i)
    profiles.push_back(Profile({0.01 * i, 0.3, 0.5 + 1e-4 * i, 0.5}, x, 0.01, &rng));
  std::vector<double> serial(profiles.size()), parallel(profiles.size());
  for (size_t i = 0; i < profiles.size(); ++i) serial[i] = batch.Fit(profiles[i].data()).phase;
  ParallelFor(static_cast<int64_t>(profiles.size()),
              [&](int64_t i) { parallel[i] = batch.Fit(profiles[i].data()).phase; });
  EXPECT_EQ(serial, parallel);
}

}  // namespace
}  // namespace mesoscan

namespace mesoscan {
namespace {

// FitMany (four profiles in vector lanes) gives Fit's result for every profile to rounding:
// symmetric and asymmetric positions, odd and even n, a count that leaves a tail, both profile
// layouts, noisy and clean profiles, and the profiles the lanes hand back to Fit (NaN samples,
// a frequency far enough off f0 to re-centre the moments, constant and pure-noise profiles).
TEST(LensShiftFit, FitManyMatchesFit) {
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  int compared = 0, valid = 0;
  for (double f0 : {kF0, -kF0}) {
    for (int n : {5, 15, 50, 51, 40}) {
      auto x = CentredPositions(n);
      if (n == 40)  // asymmetric: jittered positions
        for (double& v : x) v += 0.01 * (uni(rng) - 0.5);
      const LensShiftBatchFitter fitter(x, f0, {});
      constexpr int kCount = 43;  // 10 groups of four and a tail of three
      std::vector<std::vector<float>> profiles;
      for (int p = 0; p < kCount; ++p) {
        const double sigma = p % 3 == 0 ? 1e-4 : 0.02;
        double f = f0 * (0.95 + 0.1 * uni(rng));
        if (p % 11 == 5) f = f0 * 1.25;  // beyond the grid radius: re-centred by Fit
        Truth t{-kPi + 2 * kPi * uni(rng), 0.2, f, 0.5};
        if (p % 13 == 7) t.amplitude = 0.0;  // pure noise (or constant)
        auto b = Profile(t, x, p % 13 == 7 && p % 2 ? 0.0 : sigma, &rng);
        if (p % 17 == 3) b[n / 2] = std::numeric_limits<float>::quiet_NaN();
        profiles.push_back(b);
      }
      // Profile-major (profile_stride n, sample_stride 1) and frame-major with a gap
      // (sample k of profile p at k * (3 kCount) + 3 p), as a sparse row of frames.
      // Also frame-major without a gap (profile_stride 1: one vector load per sample).
      std::vector<float> major(static_cast<size_t>(kCount) * n), frames(3 * kCount * n, 0.f),
          dense(static_cast<size_t>(kCount) * n);
      for (int p = 0; p < kCount; ++p)
        for (int k = 0; k < n; ++k) {
          major[static_cast<size_t>(p) * n + k] = profiles[p][k];
          frames[static_cast<size_t>(k) * 3 * kCount + 3 * p] = profiles[p][k];
          dense[static_cast<size_t>(k) * kCount + p] = profiles[p][k];
        }
      std::vector<LensShiftFit> a(kCount), b(kCount), c(kCount);
      fitter.FitMany(major.data(), n, 1, kCount, a.data());
      fitter.FitMany(frames.data(), 3, 3 * kCount, kCount, b.data());
      fitter.FitMany(dense.data(), 1, kCount, kCount, c.data());
      for (int p = 0; p < kCount; ++p) {
        const LensShiftFit ref = fitter.Fit(profiles[p].data());
        for (const LensShiftFit* g : {&a[p], &b[p], &c[p]}) {
          ++compared;
          ASSERT_EQ(g->valid, ref.valid) << "f0 " << f0 << " n " << n << " profile " << p;
          EXPECT_EQ(g->samples_used, ref.samples_used);
          EXPECT_EQ(g->converged, ref.converged);
          if (!ref.valid) continue;
          ++valid;
          const double tol = 1e-9 * std::max(1.0, std::abs(ref.offset));
          EXPECT_NEAR(PhaseDiff(g->phase, ref.phase), 0.0, 1e-9) << "n " << n << " p " << p;
          EXPECT_NEAR(g->amplitude, ref.amplitude, tol);
          EXPECT_NEAR(g->frequency, ref.frequency, 1e-9);
          EXPECT_NEAR(g->offset, ref.offset, tol);
          EXPECT_NEAR(g->residual_rms, ref.residual_rms, 1e-6 * ref.residual_rms + 1e-9);
          EXPECT_NEAR(g->phase_sigma, ref.phase_sigma, 1e-6 * ref.phase_sigma + 1e-12);
        }
      }
    }
  }
  EXPECT_GT(valid, compared / 2);
  // Any other configuration loops over Fit: the 3-parameter fit, float accumulation, LM.
  const auto x = CentredPositions(30);
  std::vector<float> b(30 * 5);
  for (int p = 0; p < 5; ++p) {
    const auto prof = Profile({0.3 * p, 0.2, kF0, 0.5}, x, 0.01, &rng);
    std::copy(prof.begin(), prof.end(), b.begin() + 30 * p);
  }
  for (int config = 0; config < 3; ++config) {
    LensShiftFitOptions o;
    if (config == 0) o.fit_frequency = false;
    if (config == 1) o.double_accumulation = false;
    if (config == 2) o.fitter = LensShiftFitter::kLm;
    const LensShiftBatchFitter fitter(x, kF0, o);
    std::vector<LensShiftFit> out(5);
    fitter.FitMany(b.data(), 30, 1, 5, out.data());
    for (int p = 0; p < 5; ++p) EXPECT_EQ(out[p].phase, fitter.Fit(b.data() + 30 * p).phase);
  }
}

}  // namespace
}  // namespace mesoscan
