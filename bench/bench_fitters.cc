// Lens-shift fitter benchmark: profiles per second of each fitter (fast, LM, Ceres) at N = 15,
// 25, 50, 100, 200 samples, with the phase RMS error against the Cramer-Rao bound; then the fast
// fitter (Fit, and FitMany's four lanes) against Ceres set up as well as we know
// (CompareWithCeres: the `speedup vs ceres` column of the first table is against the library's
// strict-tolerance kCeres; the fast_vs_best_ceres lines are the figures to quote).
// Figures, not assertions. CSV: $MESOSCAN_BENCH_OUT/fitters.csv (one row per fitter and N), then
// the float-vs-double check and the pipeline mix (per-pixel cost of the reconstruction's two
// passes: 4 parameters on a 1-in-25 subsample, 3 parameters at the smooth frequency everywhere,
// fast against Ceres).
//
// Profiles: b = a sin(phi + 2 pi f x) + d + noise, x uniform over [-1, 1] projector px (the
// pipeline's centred shift positions, one stripe period), f within +-5 % of 0.5 cycles/px,
// a = 0.2, d = 0.5, sigma = 0.01 (a / sigma = 20), phase uniform. Single thread.

#include <benchmark/benchmark.h>
#include <ceres/ceres.h>
#include <ceres/tiny_solver.h>
#include <time.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "core/numbers.h"
#include "heightfield/lens_shift_fit.h"

namespace mesoscan {
namespace {

constexpr double kF0 = 0.5;

struct ProfileSet {
  std::vector<double> x;
  std::vector<float> b;  // count x n
  std::vector<double> phase, frequency;
  double sigma = 0.0, amplitude = 0.0;
  int n = 0, count = 0;
};

ProfileSet MakeProfiles(int n, int count, double offset, uint64_t seed) {
  ProfileSet s;
  s.n = n;
  s.count = count;
  s.amplitude = 0.2;
  s.sigma = 0.01;
  for (int i = 0; i < n; ++i) s.x.push_back(-1.0 + 2.0 * i / (n - 1));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 1.0);
  s.b.resize(static_cast<size_t>(n) * count);
  for (int p = 0; p < count; ++p) {
    const double phase = -kPi + 2 * kPi * uni(rng);
    const double f = kF0 * (0.95 + 0.1 * uni(rng));
    s.phase.push_back(phase);
    s.frequency.push_back(f);
    for (int k = 0; k < n; ++k)
      s.b[static_cast<size_t>(p) * n + k] = static_cast<float>(
          s.amplitude * std::sin(phase + 2 * kPi * f * s.x[k]) + offset + s.sigma * noise(rng));
  }
  return s;
}

struct Row {
  std::string fitter;
  int n = 0;
  double profiles_per_s = 0, ns_per_profile = 0;
  double phase_rms = 0, crlb_rms = 0;
  int valid = 0, count = 0;
};
std::map<std::pair<std::string, int>, Row>& Rows() {
  static std::map<std::pair<std::string, int>, Row> rows;
  return rows;
}

// fitter_id: 0 fast (default: double accumulation), 1 fast (float accumulation), 2 lm, 3 ceres.
void BM_Fit(benchmark::State& state) {
  const int fitter_id = static_cast<int>(state.range(0));
  const int n = static_cast<int>(state.range(1));
  LensShiftFitOptions options;
  options.fitter = fitter_id == 2   ? LensShiftFitter::kLm
                   : fitter_id == 3 ? LensShiftFitter::kCeres
                                    : LensShiftFitter::kFast;
  options.double_accumulation = fitter_id != 1;
  const std::string name = fitter_id == 1 ? "fast_float" : LensShiftFitterName(options.fitter);
  // Accuracy set: the same 2000 profiles for every fitter (seed depends on N only), so the
  // phase RMS figures compare the fitters on identical data.
  const int count = 2000;
  const ProfileSet set = MakeProfiles(n, count, 0.5, 100 + n);
  const LensShiftBatchFitter fitter(set.x, kF0, options);

  int64_t i = 0;
  for (auto _ : state) {
    const LensShiftFit fit = fitter.Fit(set.b.data() + static_cast<size_t>(i % count) * n);
    benchmark::DoNotOptimize(fit);
    ++i;
  }
  state.SetItemsProcessed(state.iterations());

  // Phase RMS error against the truth, and the phase-averaged CRLB at the profiles' f.
  Row row;
  row.fitter = name;
  row.n = n;
  row.count = count;
  double se = 0, crlb = 0, iterations = 0;
  for (int p = 0; p < count; ++p) {
    const LensShiftFit fit = fitter.Fit(set.b.data() + static_cast<size_t>(p) * n);
    iterations += fit.iterations;
    if (!fit.valid) continue;
    ++row.valid;
    const double e = std::remainder(fit.phase - set.phase[p], 2 * kPi);
    se += e * e;
    if (p < 500) crlb += LensShiftPhaseCrlb(set.sigma, set.amplitude, set.x, set.frequency[p]);
  }
  row.phase_rms = std::sqrt(se / std::max(row.valid, 1));
  row.crlb_rms = std::sqrt(crlb / std::min(count, 500));
  state.counters["phase_rms"] = row.phase_rms;
  state.counters["rms/crlb"] = row.phase_rms / row.crlb_rms;
  state.counters["iterations"] = iterations / count;
  state.counters["valid"] = static_cast<double>(row.valid) / count;
  Rows()[{name, n}] = row;
}

void Args(benchmark::internal::Benchmark* b) {
  for (int f = 0; f < 4; ++f)
    for (int n : {15, 25, 50, 100, 200}) b->Args({f, n});
}
BENCHMARK(BM_Fit)->Apply(Args)->Unit(benchmark::kNanosecond);

// Float vs double accumulation of the fast fitter on large offsets (offset / amplitude 100,
// a / sigma 1000): max phase difference between the two.
void FloatVsDouble(std::FILE* out) {
  for (int n : {50, 100, 200}) {
    ProfileSet set = MakeProfiles(n, 5000, 0.0, 7 + n);
    // Rescale to offset 100 a and a / sigma = 1000.
    std::mt19937_64 rng(3);
    std::normal_distribution<double> noise(0.0, 1.0);
    for (int p = 0; p < set.count; ++p)
      for (int k = 0; k < n; ++k)
        set.b[static_cast<size_t>(p) * n + k] = static_cast<float>(
            set.amplitude * std::sin(set.phase[p] + 2 * kPi * set.frequency[p] * set.x[k]) +
            100 * set.amplitude + 2e-4 * noise(rng));
    LensShiftFitOptions of, od;
    of.double_accumulation = false;
    od.double_accumulation = true;
    const LensShiftBatchFitter ff(set.x, kF0, of), fd(set.x, kF0, od);
    double worst = 0, sum2 = 0;
    for (int p = 0; p < set.count; ++p) {
      const float* b = set.b.data() + static_cast<size_t>(p) * n;
      const double d = std::remainder(ff.Fit(b).phase - fd.Fit(b).phase, 2 * kPi);
      worst = std::max(worst, std::abs(d));
      sum2 += d * d;
    }
    const double crlb = std::sqrt(LensShiftPhaseCrlb(2e-4, set.amplitude, set.x, kF0));
    std::fprintf(out,
                 "float_vs_double,N=%d,offset/a=100,a/sigma=1000,max_dphi=%.3e,rms_dphi=%.3e,"
                 "sigma_phi=%.3e\n",
                 n, worst, std::sqrt(sum2 / set.count), crlb);
  }
}

}  // namespace
}  // namespace mesoscan

double ThreadCpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

namespace mesoscan {
namespace {

// The pipeline's mix (heightfield/reconstruct.cc, smooth_frequency): the 4-parameter fit on a
// 1-in-`subsample` set of pixels for the frequency map, then every pixel with f held at the map
// (3 parameters). Per-pixel cost of fast and Ceres in thread CPU time, and the phase difference
// of the two in the 3-parameter fit (the one the points come from), against sigma_phi.
void PipelineMix(std::FILE* out, int subsample) {
  for (int n : {25, 50, 100}) {
    const ProfileSet set = MakeProfiles(n, 2000, 0.5, 100 + n);
    // [fast, ceres][4 params, 3 params]: the fastest of 3 interleaved rounds (shared machine).
    double ns[2][2] = {{1e300, 1e300}, {1e300, 1e300}};
    std::vector<double> phase[2];
    for (int round = 0; round < 3; ++round) {
      for (int f = 0; f < 2; ++f) {
        for (int fixed = 0; fixed < 2; ++fixed) {
          LensShiftFitOptions o;
          o.fitter = f == 0 ? LensShiftFitter::kFast : LensShiftFitter::kCeres;
          o.fit_frequency = fixed == 0;
          const LensShiftBatchFitter fitter(set.x, kF0, o);
          const int count = f == 0 ? set.count : 300;
          const double t0 = ThreadCpuSeconds();
          for (int p = 0; p < count; ++p) {
            const LensShiftFit fit =
                fitter.Fit(set.b.data() + static_cast<size_t>(p) * n, 1, set.frequency[p]);
            if (fixed && round == 0) phase[f].push_back(fit.phase);
          }
          ns[f][fixed] = std::min(ns[f][fixed], 1e9 * (ThreadCpuSeconds() - t0) / count);
        }
      }
    }
    double worst = 0;
    for (size_t p = 0; p < phase[1].size(); ++p)
      worst = std::max(worst, std::abs(std::remainder(phase[0][p] - phase[1][p], 2 * kPi)));
    const double sigma_phi =
        std::sqrt(LensShiftPhaseCrlb(set.sigma, set.amplitude, set.x, kF0, false));
    const double fast = ns[0][0] / subsample + ns[0][1];
    const double ceres = ns[1][0] / subsample + ns[1][1];
    std::fprintf(out,
                 "pipeline_mix,N=%d,subsample=1/%d,fast_ns=%.0f,ceres_ns=%.0f,speedup=%.1f,"
                 "fast3_ns=%.0f,ceres3_ns=%.0f,max_dphi_3param=%.2e,sigma_phi=%.2e\n",
                 n, subsample, fast, ceres, ceres / fast, ns[0][1], ns[1][1], worst, sigma_phi);
  }
}

// The fast fitter's statistical stopping rule (frequency_tolerance_sigma, default 1e-3) against
// frequency_tolerance alone (sigma 0): on the bench's profiles (a / sigma = 20) and on clean
// ones (a / sigma = 1000), the largest phase and frequency differences against their noise, and
// the mean Newton iterations of both.
void ToleranceCheck(std::FILE* out) {
  for (double snr : {20.0, 1000.0}) {
    for (int n : {15, 50, 200}) {
      ProfileSet set = MakeProfiles(n, 2000, 0.5, 900 + n);
      if (snr != 20.0) {
        std::mt19937_64 rng(11);
        std::normal_distribution<double> noise(0.0, 1.0);
        set.sigma = set.amplitude / snr;
        for (int p = 0; p < set.count; ++p)
          for (int k = 0; k < n; ++k)
            set.b[static_cast<size_t>(p) * n + k] = static_cast<float>(
                set.amplitude * std::sin(set.phase[p] + 2 * kPi * set.frequency[p] * set.x[k]) +
                0.5 + set.sigma * noise(rng));
      }
      LensShiftFitOptions loose, strict;
      strict.frequency_tolerance_sigma = 0.0;
      const LensShiftBatchFitter fl(set.x, kF0, loose), fs(set.x, kF0, strict);
      double worst_phi = 0, worst_f = 0, it_l = 0, it_s = 0;
      for (int p = 0; p < set.count; ++p) {
        const float* b = set.b.data() + static_cast<size_t>(p) * n;
        const LensShiftFit a = fl.Fit(b), c = fs.Fit(b);
        worst_phi = std::max(worst_phi, std::abs(std::remainder(a.phase - c.phase, 2 * kPi)));
        worst_f = std::max(worst_f, std::abs(a.frequency - c.frequency));
        it_l += a.iterations;
        it_s += c.iterations;
      }
      // Frequency sigma of the 4-parameter fit: the CRLB of f (Fisher information at phase 0).
      const double sigma_phi = std::sqrt(LensShiftPhaseCrlb(set.sigma, set.amplitude, set.x, kF0));
      std::fprintf(out,
                   "stopping_rule,N=%d,a/sigma=%.0f,max_dphi=%.2e,sigma_phi=%.2e,max_df=%.2e,"
                   "iterations=%.2f,strict_iterations=%.2f\n",
                   n, snr, worst_phi, sigma_phi, worst_f, it_l / set.count, it_s / set.count);
    }
  }
}

// The pipeline's fixed-frequency pass as it runs now: LensShiftRowFitter::FitRow on rows of
// 2176 pixels (samples frame-major, per-frame gains, per-pixel frequency varying smoothly along
// the row) against LensShiftBatchFitter::Fit of each pixel's strided profile (the per-pixel path
// it replaced). Thread CPU ns per pixel (fastest of 5 interleaved rounds) and the largest phase
// difference of the two, against sigma_phi.
void RowKernel(std::FILE* out) {
  constexpr int kWidth = 2176, kRows = 16;
  for (int n : {25, 50, 100}) {
    const ProfileSet set = MakeProfiles(n, kWidth * kRows, 0.5, 300 + n);
    std::mt19937_64 rng(5);
    std::normal_distribution<double> jitter(0.0, 0.005);
    std::vector<float> gain(n);
    for (float& g : gain) g = static_cast<float>(1.0 + jitter(rng));
    // Frame-major rows: rows[(r * n + k) * kWidth + j] = pixel (r, j), frame k, divided by the
    // gain (the fit multiplies it back); frequency map: +-1 % along the row.
    std::vector<float> rows(static_cast<size_t>(kRows) * n * kWidth), freq(kWidth * kRows);
    for (int r = 0; r < kRows; ++r)
      for (int j = 0; j < kWidth; ++j) {
        const int p = r * kWidth + j;
        freq[p] = static_cast<float>(kF0 * (0.99 + 0.02 * j / kWidth));
        for (int k = 0; k < n; ++k)
          rows[(static_cast<size_t>(r) * n + k) * kWidth + j] =
              set.b[static_cast<size_t>(p) * n + k] / gain[k];
      }
    LensShiftFitOptions o;
    o.fit_frequency = false;
    const LensShiftRowFitter row_fitter(set.x, kF0, o);
    const LensShiftBatchFitter batch(set.x, kF0, o);
    std::vector<uint8_t> use(kWidth, 1);
    std::vector<LensShiftFit> fits_row(kWidth * kRows), fits_px(kWidth * kRows);
    std::vector<float> buf(n);
    double ns_row = 1e300, ns_px = 1e300;
    for (int round = 0; round < 5; ++round) {
      double t0 = ThreadCpuSeconds();
      for (int r = 0; r < kRows; ++r)
        row_fitter.FitRow(rows.data() + static_cast<size_t>(r) * n * kWidth, kWidth, kWidth,
                          gain.data(), freq.data() + r * kWidth, use.data(),
                          fits_row.data() + r * kWidth);
      ns_row = std::min(ns_row, 1e9 * (ThreadCpuSeconds() - t0) / (kWidth * kRows));
      t0 = ThreadCpuSeconds();
      for (int r = 0; r < kRows; ++r) {
        const float* row = rows.data() + static_cast<size_t>(r) * n * kWidth;
        for (int j = 0; j < kWidth; ++j) {
          for (int k = 0; k < n; ++k) buf[k] = row[static_cast<size_t>(k) * kWidth + j] * gain[k];
          fits_px[r * kWidth + j] = batch.Fit(buf.data(), 1, freq[r * kWidth + j]);
        }
      }
      ns_px = std::min(ns_px, 1e9 * (ThreadCpuSeconds() - t0) / (kWidth * kRows));
    }
    double worst = 0;
    int valid_diff = 0;
    for (size_t p = 0; p < fits_row.size(); ++p) {
      valid_diff += fits_row[p].valid != fits_px[p].valid;
      worst =
          std::max(worst, std::abs(std::remainder(fits_row[p].phase - fits_px[p].phase, 2 * kPi)));
    }
    const double sigma_phi =
        std::sqrt(LensShiftPhaseCrlb(set.sigma, set.amplitude, set.x, kF0, false));
    std::fprintf(out,
                 "row_kernel,N=%d,row_ns_per_pixel=%.1f,per_pixel_ns=%.1f,speedup=%.2f,"
                 "max_dphi=%.2e,sigma_phi=%.2e,validity_differs=%d\n",
                 n, ns_row, ns_px, ns_px / ns_row, worst, sigma_phi, valid_diff);
  }
}

// ---------------------------------------------------------------------------------------------
// Ceres baselines: the same 4-parameter least squares (b = a sin(phi + 2 pi f x) + d) through
// Ceres set up as well as we know how, so that "fast vs Ceres" is not against a crippled
// baseline. Every variant starts where the library's kCeres starts (the linear fit of
// (a sin phi, a cos phi, d) at f0) and is timed on the same profiles as the fast fitter, in
// thread CPU time, interleaved rounds, the fastest round counting. Equal error: each variant's
// phase RMS against the truth, and its largest phase difference to the fast fitter against
// sigma_phi.
//  - lib:            the library's kCeres (AutoDiff, dynamic residual count, parameter blocks
//                    (phi, a, d) and f, DENSE_QR, tolerances 1e-14 / 1e-16 / 1e-12)
//  - autodiff_qr:    AutoDiff, one block of 4, DENSE_QR, Ceres' default tolerances
//  - analytic_qr:    analytic Jacobian (one sincos per sample), one block of 4, DENSE_QR, defaults
//  - analytic_chol:  same with DENSE_NORMAL_CHOLESKY
//  - analytic_chol_reuse: same, one Problem built once and re-used for every profile (only the
//                    data pointer and the start change): what a careful batch user would write
//  - analytic_chol_reuse_tight: same with function / parameter tolerance 1e-10 (where the
//                    defaults stop further than 1 % of sigma_phi from the minimum)
//  - tiny_solver:    ceres::TinySolver (Ceres' header-only LM for tiny dense problems, not
//                    ceres::Solve) with the analytic Jacobian; for reference

struct StartFit {
  double p[4];  // phi, a, f, d
};

// The linear fit at f0 (as the library's LinearFitAtFrequency): (cos, sin, 1) least squares.
bool LinearStart(const float* b, const std::vector<double>& x, double f0, StartFit* s) {
  Eigen::Matrix3d g = Eigen::Matrix3d::Zero();
  Eigen::Vector3d q = Eigen::Vector3d::Zero();
  for (size_t k = 0; k < x.size(); ++k) {
    const double th = 2 * kPi * f0 * x[k];
    const Eigen::Vector3d row(std::cos(th), std::sin(th), 1.0);
    g += row * row.transpose();
    q += row * static_cast<double>(b[k]);
  }
  const Eigen::Vector3d c = g.ldlt().solve(q);
  s->p[0] = std::atan2(c(0), c(1));
  s->p[1] = std::hypot(c(0), c(1));
  s->p[2] = f0;
  s->p[3] = c(2);
  return std::isfinite(s->p[0]) && std::isfinite(s->p[1]) && std::isfinite(s->p[3]);
}

struct AutoResidual {
  AutoResidual(const float* b, const double* x, int n) : b(b), x(x), n(n) {}
  template <typename T>
  bool operator()(const T* p, T* r) const {
    for (int k = 0; k < n; ++k) r[k] = p[1] * sin(p[0] + (2 * kPi) * p[2] * x[k]) + p[3] - T(b[k]);
    return true;
  }
  const float* b;
  const double* x;
  int n;
};

// Residuals and analytic Jacobian (row-major n x 4 for Ceres).
class AnalyticResidual : public ceres::CostFunction {
 public:
  AnalyticResidual(const double* x, int n) : x_(x), n_(n) {
    set_num_residuals(n);
    mutable_parameter_block_sizes()->push_back(4);
  }
  void set_data(const float* b) { b_ = b; }
  bool Evaluate(double const* const* params, double* r, double** jac) const override {
    const double* p = params[0];
    for (int k = 0; k < n_; ++k) {
      const double w = 2 * kPi * x_[k];
      const double th = p[0] + w * p[2];
      const double s = std::sin(th), c = std::cos(th);
      r[k] = p[1] * s + p[3] - b_[k];
      if (jac && jac[0]) {
        double* j = jac[0] + 4 * k;
        j[0] = p[1] * c;
        j[1] = s;
        j[2] = p[1] * c * w;
        j[3] = 1.0;
      }
    }
    return true;
  }

 private:
  const double* x_;
  int n_;
  const float* b_ = nullptr;
};

// TinySolver's function: column-major n x 4 Jacobian.
struct TinyResidual {
  using Scalar = double;
  enum { NUM_RESIDUALS = Eigen::Dynamic, NUM_PARAMETERS = 4 };
  int NumResiduals() const { return n; }
  bool operator()(const double* p, double* r, double* jac) const {
    for (int k = 0; k < n; ++k) {
      const double w = 2 * kPi * x[k];
      const double th = p[0] + w * p[2];
      const double s = std::sin(th), c = std::cos(th);
      r[k] = p[1] * s + p[3] - b[k];
      if (jac) {
        jac[k] = p[1] * c;
        jac[n + k] = s;
        jac[2 * n + k] = p[1] * c * w;
        jac[3 * n + k] = 1.0;
      }
    }
    return true;
  }
  const float* b = nullptr;
  const double* x = nullptr;
  int n = 0;
};

enum CeresVariant {
  kLib,
  kAutodiffQr,
  kAnalyticQr,
  kAnalyticChol,
  kAnalyticCholReuse,
  kAnalyticCholReuseTight,
  kTiny,
  kNumVariants
};
const char* const kVariantNames[kNumVariants] = {
    "lib",           "autodiff_qr",         "analytic_qr",
    "analytic_chol", "analytic_chol_reuse", "analytic_chol_reuse_tight",
    "tiny_solver"};

ceres::Solver::Options DefaultSolverOptions(ceres::LinearSolverType type) {
  ceres::Solver::Options o;  // Ceres' default tolerances: 1e-6 / 1e-10 / 1e-8
  o.linear_solver_type = type;
  o.max_num_iterations = 20;
  o.logging_type = ceres::SILENT;
  o.minimizer_progress_to_stdout = false;
  o.num_threads = 1;
  return o;
}

// Fits profiles [0, count) of `set` with variant v: phase[p] (NaN where not converged),
// iterations summed into *iterations.
void FitCeresVariant(int v, const ProfileSet& set, int count, std::vector<double>* phase,
                     double* iterations) {
  const int n = set.n;
  phase->assign(count, std::numeric_limits<double>::quiet_NaN());
  if (v == kLib) {
    LensShiftFitOptions o;
    o.fitter = LensShiftFitter::kCeres;
    const LensShiftBatchFitter fitter(set.x, kF0, o);
    for (int p = 0; p < count; ++p) {
      const LensShiftFit fit = fitter.Fit(set.b.data() + static_cast<size_t>(p) * n);
      *iterations += fit.iterations;
      if (fit.valid) (*phase)[p] = fit.phase;
    }
    return;
  }
  if (v == kTiny) {
    TinyResidual fn;
    fn.x = set.x.data();
    fn.n = n;
    ceres::TinySolver<TinyResidual> solver;
    solver.options.max_num_iterations = 20;
    for (int p = 0; p < count; ++p) {
      fn.b = set.b.data() + static_cast<size_t>(p) * n;
      StartFit s;
      if (!LinearStart(fn.b, set.x, kF0, &s)) continue;
      Eigen::Vector4d params(s.p[0], s.p[1], s.p[2], s.p[3]);
      const auto& summary = solver.Solve(fn, &params);
      *iterations += summary.iterations;
      if (summary.status != decltype(solver)::HIT_MAX_ITERATIONS)
        (*phase)[p] = params(1) < 0 ? params(0) + kPi : params(0);
    }
    return;
  }
  ceres::Solver::Options options = DefaultSolverOptions(
      v == kAutodiffQr || v == kAnalyticQr ? ceres::DENSE_QR : ceres::DENSE_NORMAL_CHOLESKY);
  const bool reuse = v == kAnalyticCholReuse || v == kAnalyticCholReuseTight;
  if (v == kAnalyticCholReuseTight) {
    options.function_tolerance = 1e-10;
    options.parameter_tolerance = 1e-10;
  }
  double params[4];
  // The re-used Problem (kAnalyticCholReuse): built once, the cost function's data swapped.
  std::unique_ptr<ceres::Problem> shared;
  AnalyticResidual* shared_cost = nullptr;
  if (reuse) {
    shared = std::make_unique<ceres::Problem>();
    shared_cost = new AnalyticResidual(set.x.data(), n);
    shared->AddResidualBlock(shared_cost, nullptr, params);
  }
  for (int p = 0; p < count; ++p) {
    const float* b = set.b.data() + static_cast<size_t>(p) * n;
    StartFit s;
    if (!LinearStart(b, set.x, kF0, &s)) continue;
    std::copy(s.p, s.p + 4, params);
    ceres::Solver::Summary summary;
    if (reuse) {
      shared_cost->set_data(b);
      ceres::Solve(options, shared.get(), &summary);
    } else {
      ceres::Problem problem;
      if (v == kAutodiffQr) {
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<AutoResidual, ceres::DYNAMIC, 4>(
                                     new AutoResidual(b, set.x.data(), n), n),
                                 nullptr, params);
      } else {
        auto* cost = new AnalyticResidual(set.x.data(), n);
        cost->set_data(b);
        problem.AddResidualBlock(cost, nullptr, params);
      }
      ceres::Solve(options, &problem, &summary);
    }
    *iterations += static_cast<double>(summary.iterations.size());
    if (summary.termination_type == ceres::CONVERGENCE)
      (*phase)[p] = params[1] < 0 ? params[0] + kPi : params[0];
  }
}

struct CeresFigure {
  double ns = std::numeric_limits<double>::infinity();
  double phase_rms = 0, max_dphi_sigma = 0, iterations = 0;
  int converged = 0;
};

// Per N: every variant's thread CPU ns per profile (fastest of `rounds` interleaved rounds, with
// the fast fitter in the same rounds), its phase RMS against the truth and its largest phase
// difference to the fast fitter in units of sigma_phi. Returns the fast fitter's ns per N and
// the best ceres::Solve variant's (the one the speed-up is quoted against).
struct CeresComparison {
  int n = 0;
  double fast_ns = std::numeric_limits<double>::infinity(), fast_phase_rms = 0;
  // LensShiftBatchFitter::FitMany (four profiles in vector lanes) on the same profiles, and its
  // largest difference to Fit (phase, rad; validity).
  double many_ns = std::numeric_limits<double>::infinity(), many_max_dphi = 0;
  int many_validity_differs = 0;
  CeresFigure variant[kNumVariants];
  int best = -1;  // fastest ceres::Solve variant at equal error (max dphi < 1 % of sigma_phi)
};

std::vector<CeresComparison> CompareWithCeres(const std::vector<int>& sizes, int rounds) {
  std::vector<CeresComparison> out;
  for (int n : sizes) {
    CeresComparison c;
    c.n = n;
    constexpr int kCeresCount = 300, kFastCount = 5000;
    const ProfileSet set = MakeProfiles(n, kFastCount, 0.5, 100 + n);
    const LensShiftBatchFitter fast(set.x, kF0, LensShiftFitOptions{});
    std::vector<double> fast_phase(kFastCount);
    double se = 0;
    int valid = 0;
    for (int p = 0; p < kFastCount; ++p) {
      const LensShiftFit fit = fast.Fit(set.b.data() + static_cast<size_t>(p) * n);
      fast_phase[p] = fit.valid ? fit.phase : std::numeric_limits<double>::quiet_NaN();
      if (p < kCeresCount && fit.valid) {
        const double e = std::remainder(fit.phase - set.phase[p], 2 * kPi);
        se += e * e;
        ++valid;
      }
    }
    c.fast_phase_rms = std::sqrt(se / std::max(valid, 1));
    std::vector<LensShiftFit> many(kFastCount);
    fast.FitMany(set.b.data(), n, 1, kFastCount, many.data());
    for (int p = 0; p < kFastCount; ++p) {
      c.many_validity_differs += many[p].valid != std::isfinite(fast_phase[p]);
      if (many[p].valid && std::isfinite(fast_phase[p]))
        c.many_max_dphi = std::max(
            c.many_max_dphi, std::abs(std::remainder(many[p].phase - fast_phase[p], 2 * kPi)));
    }
    const double sigma_phi = std::sqrt(LensShiftPhaseCrlb(set.sigma, set.amplitude, set.x, kF0));
    for (int round = 0; round < rounds; ++round) {
      {
        const double t0 = ThreadCpuSeconds();
        double sink = 0;
        for (int p = 0; p < kFastCount; ++p)
          sink += fast.Fit(set.b.data() + static_cast<size_t>(p) * n).phase;
        benchmark::DoNotOptimize(sink);
        c.fast_ns = std::min(c.fast_ns, 1e9 * (ThreadCpuSeconds() - t0) / kFastCount);
      }
      {
        const double t0 = ThreadCpuSeconds();
        fast.FitMany(set.b.data(), n, 1, kFastCount, many.data());
        benchmark::DoNotOptimize(many.data());
        c.many_ns = std::min(c.many_ns, 1e9 * (ThreadCpuSeconds() - t0) / kFastCount);
      }
      for (int v = 0; v < kNumVariants; ++v) {
        std::vector<double> phase;
        double iterations = 0;
        const double t0 = ThreadCpuSeconds();
        FitCeresVariant(v, set, kCeresCount, &phase, &iterations);
        CeresFigure& f = c.variant[v];
        f.ns = std::min(f.ns, 1e9 * (ThreadCpuSeconds() - t0) / kCeresCount);
        if (round > 0) continue;
        f.iterations = iterations / kCeresCount;
        double s2 = 0;
        for (int p = 0; p < kCeresCount; ++p) {
          if (!std::isfinite(phase[p])) continue;
          ++f.converged;
          const double e = std::remainder(phase[p] - set.phase[p], 2 * kPi);
          s2 += e * e;
          if (std::isfinite(fast_phase[p]))
            f.max_dphi_sigma =
                std::max(f.max_dphi_sigma,
                         std::abs(std::remainder(phase[p] - fast_phase[p], 2 * kPi)) / sigma_phi);
        }
        f.phase_rms = std::sqrt(s2 / std::max(f.converged, 1));
      }
    }
    for (int v = 0; v < kNumVariants; ++v) {
      if (v == kTiny) continue;
      const CeresFigure& f = c.variant[v];
      if (f.converged < kCeresCount * 99 / 100 || !(f.max_dphi_sigma < 0.01)) continue;
      if (c.best < 0 || f.ns < c.variant[c.best].ns) c.best = v;
    }
    out.push_back(c);
  }
  return out;
}

void PrintCeresComparison(std::FILE* out, const std::vector<CeresComparison>& rows) {
  for (const CeresComparison& c : rows) {
    for (int v = 0; v < kNumVariants; ++v) {
      const CeresFigure& f = c.variant[v];
      std::fprintf(out,
                   "ceres_variant,N=%d,variant=%s,ns=%.0f,speedup_fast=%.1f,iterations=%.2f,"
                   "converged=%d,phase_rms=%.5e,fast_phase_rms=%.5e,max_dphi_vs_fast/sigma_phi="
                   "%.1e%s\n",
                   c.n, kVariantNames[v], f.ns, f.ns / c.fast_ns, f.iterations, f.converged,
                   f.phase_rms, c.fast_phase_rms, f.max_dphi_sigma, v == c.best ? ",best" : "");
    }
    if (c.best >= 0)
      std::fprintf(out,
                   "fast_vs_best_ceres,N=%d,ceres=%s,ceres_ns=%.0f,fast_ns=%.1f,speedup=%.1f,"
                   "fit_many_ns=%.1f,speedup_many=%.1f,many_max_dphi=%.1e,"
                   "many_validity_differs=%d\n",
                   c.n, kVariantNames[c.best], c.variant[c.best].ns, c.fast_ns,
                   c.variant[c.best].ns / c.fast_ns, c.many_ns, c.variant[c.best].ns / c.many_ns,
                   c.many_max_dphi, c.many_validity_differs);
  }
}

}  // namespace
}  // namespace mesoscan

int main(int argc, char** argv) {
  // MESOSCAN_BENCH_ROW_ONLY=1: only the row-kernel figures (stdout).
  const char* row_only = std::getenv("MESOSCAN_BENCH_ROW_ONLY");
  if (row_only && std::string(row_only) == "1") {
    mesoscan::RowKernel(stdout);
    mesoscan::ToleranceCheck(stdout);
    return 0;
  }
  // MESOSCAN_BENCH_CERES_ONLY=1: only the fast-vs-Ceres comparison (stdout), 7 rounds.
  const char* ceres_only = std::getenv("MESOSCAN_BENCH_CERES_ONLY");
  if (ceres_only && std::string(ceres_only) == "1") {
    mesoscan::PrintCeresComparison(stdout, mesoscan::CompareWithCeres({15, 25, 50, 100, 200}, 7));
    return 0;
  }
  // MESOSCAN_BENCH_FIT_MANY_N=n: FitMany alone on 5000 profiles of n samples, repeated (for a
  // profiler), then its thread CPU ns per profile.
  if (const char* many_n = std::getenv("MESOSCAN_BENCH_FIT_MANY_N")) {
    const int n = std::atoi(many_n);
    const auto set = mesoscan::MakeProfiles(n, 5000, 0.5, 100 + n);
    mesoscan::LensShiftFitOptions o;
    if (const char* it = std::getenv("MESOSCAN_BENCH_FIT_MANY_ITERATIONS"))
      o.max_iterations = std::atoi(it);  // 1: (almost) no Newton steps, the moments' share
    const mesoscan::LensShiftBatchFitter fitter(set.x, mesoscan::kF0, o);
    std::vector<mesoscan::LensShiftFit> out(5000);
    const double t0 = ThreadCpuSeconds();
    for (int rep = 0; rep < 2000; ++rep) fitter.FitMany(set.b.data(), n, 1, 5000, out.data());
    std::printf("FitMany N %d: %.1f ns/profile\n", n, 1e9 * (ThreadCpuSeconds() - t0) / 1e7);
    return 0;
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();

  using mesoscan::Rows;
  const char* out_dir = std::getenv("MESOSCAN_BENCH_OUT");
  const std::filesystem::path dir = out_dir ? out_dir : ".";
  std::filesystem::create_directories(dir);
  const auto path = dir / "fitters.csv";
  std::FILE* csv = std::fopen(path.c_str(), "w");
  if (!csv) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    return 1;
  }
  std::fprintf(csv,
               "fitter,N,ns_per_profile,profiles_per_s,phase_rms_rad,crlb_rms_rad,rms_over_crlb,"
               "valid_fraction,speedup_vs_ceres\n");
  // Timing for the CSV: each fitter again on the same profiles, single thread, in thread CPU
  // time (the machine may be shared: wall time includes other processes' slices, and a busy
  // sibling hyperthread inflates CPU time too). Blocks of profiles per fitter, interleaved
  // over kRounds rounds so that every fitter sees the same load; the fastest block counts.
  constexpr int kRounds = 5;
  std::map<std::pair<std::string, int>, mesoscan::ProfileSet> sets;
  std::map<std::pair<std::string, int>, mesoscan::LensShiftBatchFitter> fitters;
  for (auto& [key, row] : Rows()) {
    mesoscan::LensShiftFitOptions o;
    o.fitter = row.fitter == "lm"      ? mesoscan::LensShiftFitter::kLm
               : row.fitter == "ceres" ? mesoscan::LensShiftFitter::kCeres
                                       : mesoscan::LensShiftFitter::kFast;
    o.double_accumulation = row.fitter != "fast_float";
    const int count = row.fitter == "ceres" ? 100 : row.fitter == "lm" ? 400 : 5000;
    sets.emplace(key, mesoscan::MakeProfiles(row.n, count, 0.5, 100 + row.n));
    fitters.emplace(key, mesoscan::LensShiftBatchFitter(sets.at(key).x, mesoscan::kF0, o));
    row.ns_per_profile = std::numeric_limits<double>::infinity();
  }
  for (int round = 0; round < kRounds; ++round) {
    for (auto& [key, row] : Rows()) {
      const auto& set = sets.at(key);
      const auto& fitter = fitters.at(key);
      const double t0 = ThreadCpuSeconds();
      double sink = 0;
      for (int p = 0; p < set.count; ++p)
        sink += fitter.Fit(set.b.data() + static_cast<size_t>(p) * row.n).phase;
      const double s = ThreadCpuSeconds() - t0;
      benchmark::DoNotOptimize(sink);
      row.ns_per_profile = std::min(row.ns_per_profile, 1e9 * s / set.count);
      row.profiles_per_s = 1e9 / row.ns_per_profile;
    }
  }
  for (auto& [key, row] : Rows()) {
    const auto it = Rows().find({"ceres", row.n});
    const double speedup =
        it != Rows().end() ? it->second.ns_per_profile / row.ns_per_profile : 0.0;
    std::fprintf(csv, "%s,%d,%.1f,%.0f,%.5e,%.5e,%.4f,%.4f,%.1f\n", row.fitter.c_str(), row.n,
                 row.ns_per_profile, row.profiles_per_s, row.phase_rms, row.crlb_rms,
                 row.phase_rms / row.crlb_rms, static_cast<double>(row.valid) / row.count, speedup);
    std::printf(
        "%-10s N %3d: %9.1f ns/profile  %10.0f profiles/s  phase RMS %.4e = %.4f x CRLB"
        "  valid %.4f  speedup vs ceres %.1f\n",
        row.fitter.c_str(), row.n, row.ns_per_profile, row.profiles_per_s, row.phase_rms,
        row.phase_rms / row.crlb_rms, static_cast<double>(row.valid) / row.count, speedup);
  }
  // The headline: fast (Fit and FitMany) against the best-set-up Ceres at equal error.
  const auto ceres_rows = mesoscan::CompareWithCeres({15, 25, 50, 100, 200}, 7);
  mesoscan::PrintCeresComparison(csv, ceres_rows);
  mesoscan::PrintCeresComparison(stdout, ceres_rows);
  mesoscan::FloatVsDouble(csv);
  mesoscan::FloatVsDouble(stdout);
  // Full resolution: 3.1 Mpx, stride 5 in x and y (reconstruct.cc kFrequencySamples).
  mesoscan::PipelineMix(csv, 25);
  mesoscan::PipelineMix(stdout, 25);
  mesoscan::RowKernel(csv);
  mesoscan::RowKernel(stdout);
  mesoscan::ToleranceCheck(csv);
  mesoscan::ToleranceCheck(stdout);
  std::fclose(csv);
  std::printf("wrote %s\n", path.c_str());
  return 0;
}
