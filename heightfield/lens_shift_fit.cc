#include "heightfield/lens_shift_fit.h"

#include <ceres/ceres.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstring>
#include <limits>
#include <memory>
#include <numbers>
#include <type_traits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.h"
#include "core/fast_atan.h"
#include "core/numbers.h"
#include "core/simd_clones.h"

namespace mesoscan {
namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;

// kFast: the data moments W_m = sum y t^m e^{i w_j x} (t = x / X, X = max |x|) are taken around a
// grid frequency f_j, and sum y e^{i (w_j + eps) x} = sum_m (i eps')^m / m! W_m with
// eps' = 2 pi (f - f_j) X. Truncating after kOrder leaves a relative error below
// kRadius^(kOrder+1) / (kOrder+1)! = 0.35^8 / 8! = 5.5e-9 for |eps'| <= kRadius, which sets the
// grid spacing h = kRadius / (pi X). The data-independent sums (Gram matrix) use order kGramOrder
// at twice the radius: 0.7^11 / 11! = 5e-10. The residual SSR = sum y^2 - J inherits the
// truncation: residual_rms has a floor of sqrt(5.5e-9) a = 7.4e-5 a (irrelevant below
// a / sigma = 1e4); phase, amplitude and frequency are exact to ~1e-8.
//
// Float vs double accumulation (LensShiftFitOptions::double_accumulation): the moments are
// dot products of the centred profile with the basis rows; float rounding of a length-N sum is
// ~sqrt(N) 6e-8 relative to |W| ~ N a / 2, i.e. ~1e-7 rad of phase whatever the offset (the
// profile is centred first; uncentred, an offset of 100 a would multiply it by 100). Measured
// max |phi_float - phi_double|: 1.4e-7 rad (N 50), 1.7e-7 rad (N 200) at offset 100 a and
// a / sigma = 1000, where sigma_phi = 2.1e-4 / 1.0e-4 rad: below 0.2 % of the noise. But the
// residual SSR = sum y^2 - J takes the float rounding of J (~1e-7 relative) directly: the
// residual_rms floor rises from 7.4e-5 a (double) to ~3e-4 a (float), which would bias the
// confidence of very clean pixels. The speed difference is within our measurement noise (SSE2:
// 4 float lanes vs 2 double, but the Newton part dominates), so double is the default.
constexpr int kOrder = 7;
constexpr int kMoments = 2 * (kOrder + 1);  // real rows: t^m cos, t^m sin
constexpr int kGramOrder = 10;
constexpr double kRadius = 0.35;
// Newton steps beyond the grid radius are still evaluated up to this |eps'| (truncation error
// 0.5^8 / 8! = 1e-7 relative, transient only) before the moments are re-centred.
constexpr double kEvalRadius = 0.5;
// Largest Newton step in eps' (the main lobe of the objective is ~pi / 2 wide in eps').
constexpr double kMaxStep = 0.25;
constexpr int kMaxGridHalf = 64;
// Fixed frequency (fit_frequency == false, the pipeline's second pass): a grid kFineFactor times
// finer, so |eps'| <= kRadius / kFineFactor = 0.011 and moments to order kFineOrder suffice
// (truncation 0.011^4 / 4! = 6e-10 relative, below the 4-parameter tables' 5.5e-9): half the
// basis rows per pixel.
constexpr int kFineFactor = 32;
constexpr int kFineOrder = 3;
constexpr int kFineMoments = 2 * (kFineOrder + 1);
constexpr int kStackSamples = 512;
// Accepting a fit needs a / d above float rounding of a constant profile (6e-8 per sample).
constexpr double kMinRelativeAmplitude = 1e-5;

using Cd = std::complex<double>;

// i^m (re + i im), with i^m applied as a rotation (no complex multiply).
inline Cd TimesIPower(int m, double re, double im) {
  switch (m & 3) {
    case 0:
      return Cd(re, im);
    case 1:
      return Cd(-im, re);
    case 2:
      return Cd(-re, -im);
    default:
      return Cd(im, -re);
  }
}

typedef double V4d __attribute__((vector_size(32)));
typedef float V4f __attribute__((vector_size(16)));
typedef double V2d __attribute__((vector_size(16)));
typedef int64_t V4l __attribute__((vector_size(32)));

// Four floats as doubles (exact). Built element by element: GCC lowers __builtin_convertvector
// of a 16-byte float vector into two 128-bit halves through memory, where this is one
// vcvtps2pd in the AVX2 clone (FitBlock's loop ~10 % shorter).
// (Through a pointer: a function returning a 32-byte vector has another ABI with AVX.)
inline void Widen(V4f v, V4d* out) { *out = V4d{v[0], v[1], v[2], v[3]}; }
// The samples v widened, minus `about` (the centring reference).
inline void Centred(V4f v, const V4d& about, V4d* out) {
  Widen(v, out);
  *out -= about;
}

double WrapPhase(double phi) {
  // To (-pi, pi] (already there: atan2's range, but for -pi).
  if (phi > -kPi && phi <= kPi) return phi;
  phi = std::remainder(phi, kTwoPi);
  if (phi <= -kPi) phi += kTwoPi;
  return phi;
}

// Order needed for a Taylor series in r = |argument| whose m-th coefficient is bounded by
// (scale) / m!: the smallest K with r^(K+1) / (K+1)! <= 1e-12, capped at max_order. Late
// Newton iterations (small eps') then skip most of the terms.
int NeededOrder(double r, int max_order) {
  static const std::array<double, 24> kMaxR = [] {
    std::array<double, 24> t{};
    double fact = 1.0;
    for (int k = 0; k < 24; ++k) {
      fact *= k + 1;  // (k + 1)!
      t[k] = std::pow(fact * 1e-12, 1.0 / (k + 1));
    }
    return t;
  }();
  for (int k = 0; k < max_order; ++k)
    if (r <= kMaxR[k]) return k;
  return max_order;
}

// Horner evaluation of p(e) = sum_{m <= top} c_m e^m and its first two derivatives.
template <int kN>
void Horner(const std::array<Cd, kN>& c, double e, int top, Cd* p, Cd* p1, Cd* p2) {
  Cd v = c[top], d1 = 0.0, d2 = 0.0;
  for (int m = top - 1; m >= 0; --m) {
    d2 = d2 * e + 2.0 * d1;
    d1 = d1 * e + v;
    v = v * e + c[m];
  }
  *p = v;
  *p1 = d1;
  *p2 = d2;
}

template <int kN>
Cd HornerValue(const std::array<Cd, kN>& c, double e, int top) {
  Cd v = c[top];
  for (int m = top - 1; m >= 0; --m) v = v * e + c[m];
  return v;
}

// Fills a LensShiftFit from the fitted parameters and decides validity (shared by all fitters).
LensShiftFit Finalize(double phi, double a, double f, double d, double ssr, int n, int iterations,
                      bool converged, double f0, const LensShiftFitOptions& options) {
  LensShiftFit fit;
  if (a < 0.0) {
    a = -a;
    phi += kPi;
  }
  const int p = options.fit_frequency ? 4 : 3;
  ssr = std::max(ssr, 0.0);
  fit.phase = WrapPhase(phi);
  fit.amplitude = a;
  fit.frequency = f;
  fit.offset = d;
  fit.samples_used = n;
  fit.iterations = iterations;
  fit.converged = converged;
  fit.residual_rms = n > 0 ? std::sqrt(ssr / n) : 0.0;
  double snr = 0.0;
  if (n > p) {
    const double sigma_hat = std::sqrt(ssr / (n - p));
    const double sigma_a = sigma_hat * std::sqrt(2.0 / n);
    fit.phase_sigma = a > 0.0 ? sigma_a / a : std::numeric_limits<double>::infinity();
    snr = sigma_a > 0.0 ? a / sigma_a : std::numeric_limits<double>::infinity();
  }
  const bool finite = std::isfinite(fit.phase) && std::isfinite(a) && std::isfinite(f) &&
                      std::isfinite(d) && std::isfinite(fit.residual_rms) &&
                      std::isfinite(fit.phase_sigma);
  fit.valid = finite && converged && n > p && a > options.min_amplitude &&
              a > kMinRelativeAmplitude * std::abs(d) && snr >= options.min_amplitude_snr &&
              std::abs(f - f0) <= options.max_frequency_deviation * std::abs(f0);
  if (!fit.valid) {
    // Invalid fits carry finite best-effort values (0 where nothing meaningful exists).
    for (double* v : {&fit.phase, &fit.amplitude, &fit.frequency, &fit.offset, &fit.residual_rms,
                      &fit.phase_sigma})
      if (!std::isfinite(*v)) *v = 0.0;
  }
  return fit;
}

LensShiftFit InvalidFit(int n, double f0) {
  LensShiftFit fit;
  fit.samples_used = n;
  fit.frequency = f0;
  return fit;
}

// Linear least squares of b = c0 cos(w x) + c1 sin(w x) + c2 at fixed f (the starting point of
// the iterative fitters). Returns false if the 3x3 normal matrix is singular.
bool LinearFitAtFrequency(const float* b, const double* x, int n, double f, double* phi, double* a,
                          double* d) {
  Eigen::Matrix3d g = Eigen::Matrix3d::Zero();
  Eigen::Vector3d q = Eigen::Vector3d::Zero();
  for (int k = 0; k < n; ++k) {
    const double th = kTwoPi * f * x[k];
    const Eigen::Vector3d row(std::cos(th), std::sin(th), 1.0);
    g += row * row.transpose();
    q += row * static_cast<double>(b[k]);
  }
  Eigen::LDLT<Eigen::Matrix3d> ldlt(g);
  if (ldlt.info() != Eigen::Success || !(std::abs(g.determinant()) > 1e-12 * n * n * n))
    return false;
  const Eigen::Vector3d c = ldlt.solve(q);
  *phi = std::atan2(c(0), c(1));
  *a = std::hypot(c(0), c(1));
  *d = c(2);
  return std::isfinite(*phi) && std::isfinite(*a) && std::isfinite(*d);
}

// ---------------------------------------------------------------------------------------------
// kLm: the paper's two-step Levenberg-Marquardt (Ritz et al. 2012, Sec. 5.2).

double SumSquares(const float* b, const double* x, int n, const Eigen::Vector4d& p) {
  double s = 0.0;
  for (int k = 0; k < n; ++k) {
    const double r = p(1) * std::sin(p(0) + kTwoPi * p(2) * x[k]) + p(3) - b[k];
    s += r * r;
  }
  return s;
}

LensShiftFit FitLm(const float* b, const double* x, int n, double f0,
                   const LensShiftFitOptions& options) {
  const int p = options.fit_frequency ? 4 : 3;
  if (n < p) return InvalidFit(n, f0);
  double mean = 0.0;
  for (int k = 0; k < n; ++k) mean += b[k];
  mean /= n;
  double var = 0.0;
  for (int k = 0; k < n; ++k) var += (b[k] - mean) * (b[k] - mean);
  var /= n;
  const double scale = std::sqrt(2.0 * var);  // amplitude of a sine with this variance
  if (!(scale > 0.0) || !std::isfinite(scale)) return InvalidFit(n, f0);

  // Step 1: phase only, on the normalised profile (b - mean) / scale with a = 1 and f = f0.
  // Start at the best of 8 phases so the 1-D LM begins inside the right basin.
  auto cost1 = [&](double phi) {
    double s = 0.0;
    for (int k = 0; k < n; ++k) {
      const double r = std::sin(phi + kTwoPi * f0 * x[k]) - (b[k] - mean) / scale;
      s += r * r;
    }
    return s;
  };
  double phi = 0.0, best = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 8; ++i) {
    const double c = cost1(i * kPi / 4);
    if (c < best) best = c, phi = i * kPi / 4;
  }
  int iterations = 0;
  double lambda = 1e-3;
  for (int it = 0; it < options.max_iterations; ++it, ++iterations) {
    double jtj = 0.0, jtr = 0.0;
    for (int k = 0; k < n; ++k) {
      const double th = phi + kTwoPi * f0 * x[k];
      const double r = std::sin(th) - (b[k] - mean) / scale;
      const double j = std::cos(th);
      jtj += j * j;
      jtr += j * r;
    }
    bool accepted = false;
    double step = 0.0;
    for (int tries = 0; tries < 10 && !accepted; ++tries) {
      step = -jtr / (jtj * (1.0 + lambda) + 1e-300);
      const double c = cost1(phi + step);
      if (c <= best) {
        accepted = true;
        best = c;
        phi += step;
        lambda = std::max(lambda * 0.1, 1e-12);
      } else {
        lambda *= 10.0;
      }
    }
    if (!accepted || std::abs(step) < 1e-10) break;
  }

  // Step 2: all parameters (phi, a, f, d) on the raw profile, Marquardt-scaled damping.
  Eigen::Vector4d params(phi, scale, f0, mean);
  double cost = SumSquares(b, x, n, params);
  lambda = 1e-3;
  bool converged = false;
  for (int it = 0; it < options.max_iterations; ++it) {
    ++iterations;
    Eigen::Matrix4d jtj = Eigen::Matrix4d::Zero();
    Eigen::Vector4d jtr = Eigen::Vector4d::Zero();
    for (int k = 0; k < n; ++k) {
      const double w = kTwoPi * x[k];
      const double th = params(0) + w * params(2);
      const double s = std::sin(th), c = std::cos(th);
      const double r = params(1) * s + params(3) - b[k];
      const Eigen::Vector4d j(params(1) * c, s, options.fit_frequency ? params(1) * c * w : 0.0,
                              1.0);
      jtj.selfadjointView<Eigen::Lower>().rankUpdate(j);
      jtr += j * r;
    }
    jtj = jtj.selfadjointView<Eigen::Lower>();
    if (!options.fit_frequency) {
      jtj.row(2).setZero();
      jtj.col(2).setZero();
      jtj(2, 2) = 1.0;
    }
    bool accepted = false;
    Eigen::Vector4d step = Eigen::Vector4d::Zero();
    for (int tries = 0; tries < 10 && !accepted; ++tries) {
      Eigen::Matrix4d a = jtj;
      a.diagonal() *= 1.0 + lambda;
      step = -a.ldlt().solve(jtr);
      if (!step.allFinite()) {
        lambda *= 10.0;
        continue;
      }
      const double c = SumSquares(b, x, n, params + step);
      if (c <= cost) {
        accepted = true;
        params += step;
        const double rel = (cost - c) / std::max(cost, 1e-300);
        cost = c;
        lambda = std::max(lambda * 0.1, 1e-12);
        if (std::abs(step(2)) < options.frequency_tolerance && rel < 1e-12) converged = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!accepted) {
      // No downhill step even with heavy damping: at the minimum to machine precision.
      converged = true;
      break;
    }
    if (converged) break;
  }
  return Finalize(params(0), params(1), params(2), params(3), cost, n, iterations, converged, f0,
                  options);
}

// ---------------------------------------------------------------------------------------------
// kCeres: the reference. Parameters (phi, a, d) and f in two blocks so f can be held constant.

struct ProfileResidual {
  ProfileResidual(const float* b, const double* x, int n) : b(b), x(x), n(n) {}
  template <typename T>
  bool operator()(const T* pad, const T* f, T* residuals) const {
    for (int k = 0; k < n; ++k)
      residuals[k] = pad[1] * sin(pad[0] + kTwoPi * f[0] * x[k]) + pad[2] - T(b[k]);
    return true;
  }
  const float* b;
  const double* x;
  int n;
};

LensShiftFit FitCeres(const float* b, const double* x, int n, double f0,
                      const LensShiftFitOptions& options) {
  const int p = options.fit_frequency ? 4 : 3;
  if (n < p) return InvalidFit(n, f0);
  double pad[3];
  if (!LinearFitAtFrequency(b, x, n, f0, &pad[0], &pad[1], &pad[2])) return InvalidFit(n, f0);
  double f = f0;
  ceres::Problem::Options problem_options;
  problem_options.enable_fast_removal = false;
  ceres::Problem problem(problem_options);
  auto* cost = new ceres::AutoDiffCostFunction<ProfileResidual, ceres::DYNAMIC, 3, 1>(
      new ProfileResidual(b, x, n), n);
  problem.AddResidualBlock(cost, nullptr, pad, &f);
  if (!options.fit_frequency) problem.SetParameterBlockConstant(&f);
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::DENSE_QR;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = 1e-14;
  solver_options.gradient_tolerance = 1e-16;
  solver_options.parameter_tolerance = 1e-12;
  solver_options.logging_type = ceres::SILENT;
  solver_options.minimizer_progress_to_stdout = false;
  solver_options.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &problem, &summary);
  const bool converged = summary.termination_type == ceres::CONVERGENCE;
  return Finalize(pad[0], pad[1], f, pad[2], 2.0 * summary.final_cost, n,
                  static_cast<int>(summary.iterations.size()), converged, f0, options);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// kFast tables and fitter

struct LensShiftBatchFitter::Tables {
  int n = 0;
  double x_scale = 1.0;  // X = max |x|
  double h = 0.0;        // grid spacing (cycles / px)
  int grid_half = 0;     // grid f_j = f0 + j h, j in [-grid_half, grid_half]
  // Per grid point: kMoments x n row-major basis rows t^m cos(w_j x), t^m sin(w_j x), in float
  // and double (the accumulation type is an option).
  std::vector<Eigen::Matrix<float, kMoments, Eigen::Dynamic, Eigen::RowMajor>> basis_f;
  std::vector<Eigen::Matrix<double, kMoments, Eigen::Dynamic, Eigen::RowMajor>> basis_d;
  // Fine tables (fixed frequency only): kFineMoments rows per grid point instead.
  bool fine = false;
  std::vector<Eigen::Matrix<float, kFineMoments, Eigen::Dynamic, Eigen::RowMajor>> fine_f;
  std::vector<Eigen::Matrix<double, kFineMoments, Eigen::Dynamic, Eigen::RowMajor>> fine_d;
  // Per grid point: Horner coefficients in eps' of sum e^{i (w_j + eps) x} and of
  // sum e^{2 i (w_j + eps) x}.
  std::vector<std::array<Cd, kGramOrder + 1>> e1, e2;
  // The same interleaved per order m: e1 re, e1 im, e2 re, e2 im (one vector per order).
  std::vector<std::array<double, 4 * (kGramOrder + 1)>> e12;
  // Per grid point: the double basis rows transposed, n x rows (frame-major: one sample's
  // rows are contiguous), for AccumulateMoments.
  std::vector<std::vector<double>> km;
  // x_{n-1-k} = -x_k for every k to 1e-15 X: the basis rows of sample n-1-k are those of
  // sample k times their parity (FitFourLanes folds the sample pairs).
  bool symmetric = false;
};

namespace {

struct Objective {
  double j = 0, j1 = 0, j2 = 0;  // projected energy q^T G^-1 q and its eps' derivatives
  // J''' where it was evaluated at eps' = 0 with derivatives (the start: Halley's first step),
  // else NaN.
  double j3 = std::numeric_limits<double>::quiet_NaN();
  double c[3] = {0, 0, 0};   // coefficients of (cos, sin, 1) at eps'
  double dc[3] = {0, 0, 0};  // their eps' derivatives (with `derivatives` only)
  bool ok = false;
};

// Horner's scheme with two derivatives at eps for a polynomial whose coefficients are vectors V
// (one V per order, contiguous from `coef`, orders 0..top): writes the value, the first and the
// second derivative, one V each, to `out`. Every lane rounds as the scalar recurrence would.
// Through memcpy and pointers, not V by value (the AVX2 clone's ABI, as AtanReduced).
template <class V>
inline __attribute__((always_inline)) void HornerVec(const void* coef, int top, double eps,
                                                     void* out) {
  const auto* c8 = static_cast<const unsigned char*>(coef);
  const V zero = {};
  V v, d1 = zero, d2 = zero;
  std::memcpy(&v, c8 + sizeof(V) * top, sizeof v);
  for (int m = top - 1; m >= 0; --m) {
    V c;
    std::memcpy(&c, c8 + sizeof(V) * m, sizeof c);
    d2 = d2 * eps + (d1 + d1);
    d1 = d1 * eps + v;
    v = v * eps + c;
  }
  auto* o8 = static_cast<unsigned char*>(out);
  std::memcpy(o8, &v, sizeof v);
  std::memcpy(o8 + sizeof v, &d1, sizeof d1);
  std::memcpy(o8 + 2 * sizeof v, &d2, sizeof d2);
}

// The Taylor polynomials of Evaluate with two derivatives at eps: z_coef (complex) to order
// top_z into z[0..2] (value, first, second derivative, 2 values each), and the interleaved Gram
// coefficients e12 (e1 re, e1 im, e2 re, e2 im per order) to order top_g into e[0..2] (4 values
// each). Each lane rounds as the complex scalar recurrences would.
MESOSCAN_SIMD_CLONES
void HornerWithDerivatives(const Cd* z_coef, int top_z, const double* e12, int top_g, double eps,
                           double* z_out, double* e_out) {
  HornerVec<V4d>(e12, top_g, eps, e_out);
  HornerVec<V2d>(z_coef, top_z, eps, z_out);
}

// A complex number as two values of T (a scalar or four lanes).
template <class T>
struct ReIm {
  T re, im;
};

// J'''(0) for Halley's first step, from the third Taylor coefficients (z3 of the moments, e13 and
// e23 of the Gram sums: derivatives 6 z3 etc.) and Evaluate's quantities at eps' = 0.
// Differentiating J'' = 2 w''.c - c.M''c + 2 r.c' (r = w' - M'c, c' = M^-1 r) once more:
//   J''' = 2 w'''.c + 2 w''.c' - c.M'''c - 2 c'.M''c + 2 r'.c' + 2 r.c'',
//   r' = w'' - M''c - M'c',  c'' = M^-1 (r' - M'c').
// Templated on the scalar or the four-lane vector type (FitFourLanes uses the same arithmetic);
// the result through a pointer (a vector returned by value would change the ABI between the AVX2
// clone and the default, see AtanReduced).
template <class T>
inline __attribute__((always_inline)) void ThirdDerivativeAtZero(
    const ReIm<T>& z3c, const ReIm<T>& e13c, const ReIm<T>& e23c, const T& C, const T& E,
    const T& C1, const T& E1, const T& C2, const T& E2, const T& y0, double n, const T& a,
    const T& b, const T& d, const T& inv_det, const T& a1, const T& b1, const T& d1, const T& a2,
    const T& b2, const T& d2, const T& wu2, const T& wv2, const T& cc, const T& cs, const T& cc1,
    const T& cs1, const T& ru, const T& rv, T* j3) {
  const double inv_n = 1.0 / n;
  const T z3r = 6.0 * z3c.re, z3i = 6.0 * z3c.im;
  const T C3 = 6.0 * e13c.re, E3 = 6.0 * e13c.im, g23r = 6.0 * e23c.re, g23i = 6.0 * e23c.im;
  const T a3 = 0.5 * g23r - 2.0 * (C * C3 + 3.0 * C1 * C2) * inv_n;
  const T b3 = 0.5 * g23i - (C3 * E + 3.0 * C2 * E1 + 3.0 * C1 * E2 + C * E3) * inv_n;
  const T d3 = -0.5 * g23r - 2.0 * (E * E3 + 3.0 * E1 * E2) * inv_n;
  const T wu3 = z3r - C3 * y0 * inv_n, wv3 = z3i - E3 * y0 * inv_n;
  const T m2u = a2 * cc + b2 * cs, m2v = b2 * cc + d2 * cs;      // M'' c
  const T m1u = a1 * cc1 + b1 * cs1, m1v = b1 * cc1 + d1 * cs1;  // M' c'
  const T rpu = wu2 - m2u - m1u, rpv = wv2 - m2v - m1v;          // r'
  const T su = rpu - m1u, sv = rpv - m1v;
  const T cc2 = (d * su - b * sv) * inv_det, cs2 = (a * sv - b * su) * inv_det;  // c''
  const T m3c = cc * (a3 * cc + b3 * cs) + cs * (b3 * cc + d3 * cs);
  *j3 = 2.0 * (wu3 * cc + wv3 * cs) + 2.0 * (wu2 * cc1 + wv2 * cs1) - m3c -
        2.0 * (cc1 * m2u + cs1 * m2v) + 2.0 * (rpu * cc1 + rpv * cs1) + 2.0 * (ru * cc2 + rv * cs2);
}

// J(eps') = q^T G^-1 q (variable projection: sum y^2 - J is the residual of the best linear fit
// at that frequency), with derivatives for Newton. G = [[A, B, C], [B, D, E], [C, E, n]] over
// the basis (cos, sin, 1) and q = (u, v, y0); the constant column is eliminated by its Schur
// complement, leaving a 2x2 system (scalar code: this runs a few times per pixel).
Objective Evaluate(const std::array<Cd, kOrder + 1>& z_coef, double y0,
                   const std::array<Cd, kGramOrder + 1>& e1c,
                   const std::array<Cd, kGramOrder + 1>& e2c,
                   const std::array<double, 4 * (kGramOrder + 1)>& e12c, double n, double eps,
                   bool derivatives) {
  Objective o;
  Cd z, z1 = 0.0, z2 = 0.0, e1, e11 = 0.0, e12 = 0.0, e2, e21 = 0.0, e22 = 0.0;
  const bool at_zero = derivatives && eps == 0.0;
  if (at_zero) {
    // The usual start (f = f0 on a grid point): the polynomials' low coefficients.
    z = z_coef[0], z1 = z_coef[1], z2 = 2.0 * z_coef[2];
    e1 = e1c[0], e11 = e1c[1], e12 = 2.0 * e1c[2];
    e2 = e2c[0], e21 = e2c[1], e22 = 2.0 * e2c[2];
  } else {
    // Derivatives need two more terms than the value for the same accuracy.
    const int extra = derivatives ? 2 : 0;
    const int top_z = std::min(NeededOrder(std::abs(eps), kOrder) + extra, kOrder);
    const int top_g = std::min(NeededOrder(2.0 * std::abs(eps), kGramOrder) + extra, kGramOrder);
    if (derivatives) {
      double zd[6], ed[12];
      HornerWithDerivatives(z_coef.data(), top_z, e12c.data(), top_g, eps, zd, ed);
      z = Cd(zd[0], zd[1]), z1 = Cd(zd[2], zd[3]), z2 = Cd(zd[4], zd[5]);
      e1 = Cd(ed[0], ed[1]), e2 = Cd(ed[2], ed[3]);
      e11 = Cd(ed[4], ed[5]), e21 = Cd(ed[6], ed[7]);
      e12 = Cd(ed[8], ed[9]), e22 = Cd(ed[10], ed[11]);
    } else {
      z = HornerValue<kOrder + 1>(z_coef, eps, top_z);
      Cd v1 = e1c[top_g], v2 = e2c[top_g];
      for (int m = top_g - 1; m >= 0; --m) {
        v1 = v1 * eps + e1c[m];
        v2 = v2 * eps + e2c[m];
      }
      e1 = v1;
      e2 = v2;
    }
  }
  const double inv_n = 1.0 / n;
  const double C = e1.real(), E = e1.imag();
  // Reduced 2x2 system M c = w after eliminating the constant.
  const double a = 0.5 * (n + e2.real()) - C * C * inv_n;
  const double b = 0.5 * e2.imag() - C * E * inv_n;
  const double d = 0.5 * (n - e2.real()) - E * E * inv_n;
  const double wu = z.real() - C * y0 * inv_n;
  const double wv = z.imag() - E * y0 * inv_n;
  const double det = a * d - b * b;
  if (!(det > 1e-12 * n * n)) return o;
  const double inv_det = 1.0 / det;
  const double cc = (d * wu - b * wv) * inv_det;
  const double cs = (a * wv - b * wu) * inv_det;
  o.c[0] = cc;
  o.c[1] = cs;
  o.c[2] = (y0 - C * cc - E * cs) * inv_n;
  o.j = wu * cc + wv * cs + y0 * y0 * inv_n;
  o.ok = std::isfinite(o.j);
  if (!derivatives) return o;
  // First and second eps' derivatives of the reduced system.
  const double C1 = e11.real(), E1 = e11.imag(), C2 = e12.real(), E2 = e12.imag();
  const double a1 = 0.5 * e21.real() - 2.0 * C * C1 * inv_n;
  const double b1 = 0.5 * e21.imag() - (C1 * E + C * E1) * inv_n;
  const double d1 = -0.5 * e21.real() - 2.0 * E * E1 * inv_n;
  const double a2 = 0.5 * e22.real() - 2.0 * (C1 * C1 + C * C2) * inv_n;
  const double b2 = 0.5 * e22.imag() - (C2 * E + 2.0 * C1 * E1 + C * E2) * inv_n;
  const double d2 = -0.5 * e22.real() - 2.0 * (E1 * E1 + E * E2) * inv_n;
  const double wu1 = z1.real() - C1 * y0 * inv_n, wv1 = z1.imag() - E1 * y0 * inv_n;
  const double wu2 = z2.real() - C2 * y0 * inv_n, wv2 = z2.imag() - E2 * y0 * inv_n;
  // M' c and c' = M^-1 (w' - M' c).
  const double mc_u = a1 * cc + b1 * cs, mc_v = b1 * cc + d1 * cs;
  const double ru = wu1 - mc_u, rv = wv1 - mc_v;
  const double cc1 = (d * ru - b * rv) * inv_det;
  const double cs1 = (a * rv - b * ru) * inv_det;
  o.dc[0] = cc1;
  o.dc[1] = cs1;
  o.dc[2] = -(C1 * cc + C * cc1 + E1 * cs + E * cs1) * inv_n;
  o.j1 = 2.0 * (wu1 * cc + wv1 * cs) - (cc * mc_u + cs * mc_v);
  const double m2c = cc * (a2 * cc + b2 * cs) + cs * (b2 * cc + d2 * cs);
  o.j2 = 2.0 * (wu2 * cc + wv2 * cs) + 2.0 * (wu1 * cc1 + wv1 * cs1) -
         2.0 * (cc1 * mc_u + cs1 * mc_v) - m2c;
  o.ok = o.ok && std::isfinite(o.j1) && std::isfinite(o.j2);
  if (at_zero)
    ThirdDerivativeAtZero<double>({z_coef[3].real(), z_coef[3].imag()},
                                  {e1c[3].real(), e1c[3].imag()}, {e2c[3].real(), e2c[3].imag()}, C,
                                  E, C1, E1, C2, E2, y0, n, a, b, d, inv_det, a1, b1, d1, a2, b2,
                                  d2, wu2, wv2, cc, cs, cc1, cs1, ru, rv, &o.j3);
  return o;
}

// Moments of the centred profile y at grid point gi: Horner coefficients i^m W_m / m! and
// y0 = sum y.
// kRows basis rows (orders 0 .. kRows / 2 - 1); higher coefficients are 0.
template <typename Scalar, int kRows, typename Basis>
void Moments(const Basis& basis, const Scalar* y, int n, std::array<Cd, kOrder + 1>* z_coef) {
  const Eigen::Map<const Eigen::Matrix<Scalar, Eigen::Dynamic, 1>> yv(y, n);
  const Eigen::Matrix<Scalar, kRows, 1> w = basis * yv;
  // i^m W_m / m! with i^m applied as a rotation (no complex multiply).
  constexpr std::array<double, kOrder + 1> kInvFact = [] {
    std::array<double, kOrder + 1> f{};
    double v = 1.0;
    for (int m = 0; m <= kOrder; ++m) {
      if (m > 0) v /= m;
      f[m] = v;
    }
    return f;
  }();
  for (int m = kRows / 2; m <= kOrder; ++m) (*z_coef)[m] = 0.0;
  for (int m = 0; m < kRows / 2; ++m) {
    const double re = kInvFact[m] * w(2 * m), im = kInvFact[m] * w(2 * m + 1);
    (*z_coef)[m] = TimesIPower(m, re, im);
  }
}

}  // namespace

namespace {

// w[r] = sum_k basis_km[k * 4 kVec + r] y_k, y0 = sum_k y_k, y2 = sum_k y_k^2 with
// y_k = b[k] - mean in double: the moments of the centred profile (two sets of accumulators
// for even and odd k, added at the end; y0 and y2 in a second, 4-wide loop, which keeps the
// first one within the 16 vector registers).
template <int kVec>
inline __attribute__((always_inline)) void AccumulateMomentsT(const double* basis_km,
                                                              const float* b, int n, double mean,
                                                              double* w, double* y0_out,
                                                              double* y2_out) {
  constexpr int kRows = 4 * kVec;
  const V4d zero = {0, 0, 0, 0};
  V4d acc0[kVec], acc1[kVec];
  for (int v = 0; v < kVec; ++v) acc0[v] = acc1[v] = zero;
  int k = 0;
  for (; k + 1 < n; k += 2) {
    const V4d va = zero + (static_cast<double>(b[k]) - mean);
    const V4d vb = zero + (static_cast<double>(b[k + 1]) - mean);
    const double* ra = basis_km + static_cast<size_t>(k) * kRows;
    for (int v = 0; v < kVec; ++v) {
      V4d ba, bb;
      std::memcpy(&ba, ra + 4 * v, sizeof ba);
      std::memcpy(&bb, ra + kRows + 4 * v, sizeof bb);
      acc0[v] += ba * va;
      acc1[v] += bb * vb;
    }
  }
  if (k < n) {
    const V4d va = zero + (static_cast<double>(b[k]) - mean);
    const double* ra = basis_km + static_cast<size_t>(k) * kRows;
    for (int v = 0; v < kVec; ++v) {
      V4d ba;
      std::memcpy(&ba, ra + 4 * v, sizeof ba);
      acc0[v] += ba * va;
    }
  }
  for (int v = 0; v < kVec; ++v) {
    const V4d s = acc0[v] + acc1[v];
    std::memcpy(w + 4 * v, &s, sizeof s);
  }
  V4d s0 = zero, s2 = zero;
  for (k = 0; k + 3 < n; k += 4) {
    V4f f;
    std::memcpy(&f, b + k, sizeof f);
    V4d y;
    Widen(f, &y);
    y -= mean;
    s0 += y;
    s2 += y * y;
  }
  double y0 = (s0[0] + s0[1]) + (s0[2] + s0[3]), y2 = (s2[0] + s2[1]) + (s2[2] + s2[3]);
  for (; k < n; ++k) {
    const double y = static_cast<double>(b[k]) - mean;
    y0 += y;
    y2 += y * y;
  }
  *y0_out = y0;
  *y2_out = y2;
}

MESOSCAN_SIMD_CLONES
void AccumulateMoments(int rows, const double* basis_km, const float* b, int n, double mean,
                       double* w, double* y0, double* y2) {
  if (rows == kMoments)
    AccumulateMomentsT<kMoments / 4>(basis_km, b, n, mean, w, y0, y2);
  else
    AccumulateMomentsT<kFineMoments / 4>(basis_km, b, n, mean, w, y0, y2);
}

// z_coef[m] = i^m w_m / m! from the moments w (2 rows per order m: cos, sin; kRows rows).
void ZCoefficients(const double* w, int rows, std::array<Cd, kOrder + 1>* z_coef) {
  static_assert(kMoments % 4 == 0 && kFineMoments % 4 == 0);
  double inv_fact = 1.0;
  for (int m = 0; m <= kOrder; ++m) {
    if (m > 0) inv_fact /= m;
    if (2 * m >= rows) {
      (*z_coef)[m] = 0.0;
      continue;
    }
    const double re = inv_fact * w[2 * m], im = inv_fact * w[2 * m + 1];
    (*z_coef)[m] = TimesIPower(m, re, im);
  }
}

// The kFast fit of one all-finite profile b (n samples, gathered contiguously).
template <typename Scalar>
LensShiftFit FastFit(const LensShiftBatchFitter::Tables& t, const float* b, float mean, double f0,
                     double f_start, const LensShiftFitOptions& options, Scalar* y) {
  const int n = t.n;
  const int p = options.fit_frequency ? 4 : 3;
  if (n < p) return InvalidFit(n, f0);
  // Centre the profile on its mean (any reference works: it is added back to d). The moments
  // then scale with the amplitude, not with the offset: float accumulation and Taylor
  // truncation errors stay relative to a. Subtracted in the accumulation type: exact in double,
  // so the fit does not depend on the float rounding of the mean.
  double y0 = 0.0, y2 = 0.0;
  if constexpr (std::is_same_v<Scalar, float>) {
    const Eigen::Map<const Eigen::ArrayXf> bv(b, n);
    Eigen::Map<Eigen::Array<Scalar, Eigen::Dynamic, 1>> yv(y, n);
    yv = bv.template cast<Scalar>() - static_cast<Scalar>(mean);
    y0 = static_cast<double>(yv.sum());
    y2 = static_cast<double>(yv.square().sum());
  }
  const double two_pi_x = kTwoPi * t.x_scale;
  // Grid point nearest to the starting frequency.
  auto nearest = [&](double f) { return static_cast<int>(std::nearbyint((f - f0) / t.h)); };
  int j = nearest(f_start);
  if (std::abs(j) > t.grid_half) return InvalidFit(n, f0);
  double eps = two_pi_x * (f_start - (f0 + j * t.h));
  std::array<Cd, kOrder + 1> z_coef;
  auto moments = [&](int jj) {
    const int g = jj + t.grid_half;
    if constexpr (std::is_same_v<Scalar, float>) {
      if (t.fine)
        Moments<float, kFineMoments>(t.fine_f[g], y, n, &z_coef);
      else
        Moments<float, kMoments>(t.basis_f[g], y, n, &z_coef);
    } else {
      // Centring, y0, y2 and the moments in one pass (the same y0 and y2 every time).
      const int rows = t.fine ? kFineMoments : kMoments;
      double w[kMoments];
      AccumulateMoments(rows, t.km[g].data(), b, n, static_cast<double>(mean), w, &y0, &y2);
      ZCoefficients(w, rows, &z_coef);
    }
  };
  moments(j);
  const double nd = n;
  auto eval = [&](double e, bool derivs) {
    return Evaluate(z_coef, y0, t.e1[j + t.grid_half], t.e2[j + t.grid_half],
                    t.e12[j + t.grid_half], nd, e, derivs);
  };
  Objective o = eval(eps, options.fit_frequency);
  if (!o.ok) return InvalidFit(n, f0);
  int iterations = 0;
  bool converged = !options.fit_frequency;
  const double eps_tol = options.frequency_tolerance * two_pi_x;
  // Newton converges quadratically: after a step s the error is ~ kQuadratic s^2 (kQuadratic
  // ~ |J''' / 2 J''| ~ 1 for the main lobe; 4 for margin), so a step below final_step is the
  // last one needed.
  constexpr double kQuadratic = 4.0;
  const double final_step = std::sqrt(eps_tol / kQuadratic);
  // The statistical criterion (frequency_tolerance_sigma): the remaining error against the
  // standard error of eps', sqrt(2 sigma^2 / -J'') with sigma^2 = (sum y^2 - J) / (n - 4).
  const double sigma_factor =
      options.frequency_tolerance_sigma > 0.0 && n > 4 ? 2.0 / (n - 4) : 0.0;
  const double tol_sigma_sq_factor =
      options.frequency_tolerance_sigma * options.frequency_tolerance_sigma * sigma_factor;
  while (!converged && iterations < options.max_iterations) {
    ++iterations;
    // Newton step on J'(eps') = 0 towards a maximum; uphill gradient step where J is not concave.
    double step = o.j2 < 0.0 ? -o.j1 / o.j2 : (o.j1 > 0.0 ? kMaxStep : -kMaxStep);
    // At the start (eps' = 0, J''' known): Halley's step, the Newton step divided by
    // 1 - q, q = -step J''' / (2 J''), where |q| <= 0.5. Its error is third order in the step,
    // so the Newton step that follows is usually already below the last-step bound.
    if (iterations == 1 && o.j2 < 0.0 && std::isfinite(o.j3)) {
      const double q = -0.5 * step * o.j3 / o.j2;
      if (std::abs(q) <= 0.5) step /= 1.0 - q;
    }
    step = std::clamp(step, -kMaxStep, kMaxStep);
    // The last step is below max(final_step, sqrt(tol / kQuadratic)), tol = tolerance_sigma
    // sqrt(var_eps), var_eps = sigma_factor (sum y^2 - J) / -J'': squared twice and multiplied
    // out, without a division or a square root (FitFourLanes decides the same way).
    bool last = std::abs(step) < final_step;
    if (!last && sigma_factor > 0.0 && o.j2 < 0.0) {
      const double s2 = step * step;
      last =
          kQuadratic * kQuadratic * s2 * s2 * -o.j2 < tol_sigma_sq_factor * std::max(y2 - o.j, 0.0);
    }
    if (o.j2 < 0.0 && last && std::abs(eps + step) <= kEvalRadius) {
      // Converged: the remaining error after this Newton step is below the tolerance; take it
      // without a line search, extrapolating the coefficients to first order (their error is
      // O(step^2), below 1e-7 relative) and J to second order.
      eps += step;
      for (int i = 0; i < 3; ++i) o.c[i] += o.dc[i] * step;
      o.j += step * (o.j1 + 0.5 * step * o.j2);
      converged = true;
      break;
    }
    Objective next;
    bool accepted = false;
    for (int halving = 0; halving < 12; ++halving) {
      const double e = std::clamp(eps + step, -kEvalRadius, kEvalRadius);
      next = eval(e, true);
      if (next.ok && next.j >= o.j - 1e-15 * std::abs(o.j)) {
        step = e - eps;
        accepted = true;
        break;
      }
      step *= 0.5;
    }
    if (!accepted) {
      // No uphill step at any scale: the maximum to machine precision.
      converged = true;
      break;
    }
    eps += step;
    o = next;
    if (std::abs(step) < eps_tol) converged = true;
    if (std::abs(eps) > kRadius) {
      // Re-centre the Taylor expansion on the grid point nearest to the current frequency.
      const double f = f0 + j * t.h + eps / two_pi_x;
      const int jn = nearest(f);
      if (std::abs(jn) > t.grid_half)
        return Finalize(0, 0, f, mean, 0, n, iterations, false, f0,
                        options);  // frequency out of range
      j = jn;
      eps = two_pi_x * (f - (f0 + j * t.h));
      moments(j);
      o = eval(eps, true);
      if (!o.ok) return InvalidFit(n, f0);
    }
  }
  const double f = f0 + j * t.h + eps / two_pi_x;
  // Model y = c0 cos + c1 sin + c2 = a sin(phi + theta) + c2: c0 = a sin phi, c1 = a cos phi.
  const double phi = FastAtan2(o.c[0], o.c[1]);
  const double a = std::sqrt(o.c[0] * o.c[0] + o.c[1] * o.c[1]);  // data units: no overflow
  const double ssr = y2 - o.j;
  return Finalize(phi, a, f, o.c[2] + mean, ssr, n, iterations, converged, f0, options);
}

// ---------------------------------------------------------------------------------------------
// The 4-parameter kFast fit of four profiles at once (LensShiftBatchFitter::FitMany): FastFit's
// steps with the four profiles in the lanes of one vector, so that its fixed work per profile
// (the Taylor evaluations of the variable-projection objective with their divisions, the
// stopping rule's arithmetic) runs once per four profiles. Every lane starts at f0 (grid
// point 0, eps' = 0) and takes FastFit's steps (Halley's first, then Newton's) with its stopping
// rules; the group costs as many evaluations as its slowest lane needs. A lane that
// leaves the common case (a rejected step that would need halving, a step beyond the grid
// radius that would re-centre the moments, a non-concave start, the iteration cap) is marked
// and refitted by FastFit alone. Results equal FastFit's to rounding (the moments are summed in
// another order, and the Taylor orders are those the largest |eps'| of the lanes needs).

struct LaneInput {
  const double* basis_km;  // grid point 0: n x kMoments, frame-major
  const double* e12;       // grid point 0: Gram Horner coefficients, 4 per order
  int n = 0;
  bool symmetric = false;  // x_{n-1-k} = -x_k (Tables::symmetric)
  int max_iterations = 0;
  double eps_tol = 0, final_step = 0, sigma_factor = 0, tol_sigma_sq_factor = 0;
  double sqrt_2_over_n_minus_4 = 0;  // sigma_a / residual_rms = sqrt(n / (n - 4)) sqrt(2 / n)
};

struct LaneOutput {
  double c[3][4];      // (a sin phi, a cos phi, d - mean) per lane
  double j[4], y2[4];  // projected energy and sum of squared centred samples
  double eps[4];       // final eps' (grid point 0)
  int64_t iterations[4];
  int64_t redo[4];  // != 0: the lane left the common case, FastFit alone decides it
  // Finalize's quantities: phi in (-pi, pi], a, sum y^2 - J, sqrt(max(SSR, 0) / n),
  // sigma_a / a and sigma_a (the SNR a / sigma_a is tested as a >= min_snr sigma_a).
  double phase[4], amplitude[4], ssr[4], residual_rms[4], phase_sigma[4], sigma_a[4];
};

struct LaneObjective {
  V4d j, j1, j2, j3, c0, c1, c2, dc0, dc1, dc2;  // j3: with EvaluateLanes' kThirdAtZero only
  V4l ok;
};

// Lane helpers as macros: a vector passed or returned by value would change the ABI between the
// AVX2 clone and the default (see AtanReduced).
#define MESOSCAN_LANE_ABS(v) ((v) < 0 ? -(v) : (v))
#define MESOSCAN_LANE_SELECT(m, a, b) ((m) ? (a) : (b))
#define MESOSCAN_LANE_FINITE(v) (((v) - (v)) == 0)

// Evaluate (derivatives = true) in the lanes: z Horner coefficients per lane (zr, zi: orders
// 0..top_z), the shared Gram coefficients e12 (orders 0..top_g), each lane at its eps.
// kSymmetric (positions symmetric about 0): sum sin((w + eps) x) and sum sin(2 (w + eps) x) are
// 0 for every eps, so their Horner chains are skipped (their table coefficients are 0 up to
// rounding).
// kThirdAtZero (eps = 0 in every lane, top_z and top_g >= 2): also J'''(0) from the order-3
// coefficients (ThirdDerivativeAtZero), for Halley's first step.
template <bool kSymmetric, bool kThirdAtZero = false>
inline __attribute__((always_inline)) void EvaluateLanes(const V4d* zr, const V4d* zi, int top_z,
                                                         const double* e12, int top_g,
                                                         const V4d& eps, const V4d& y0, double n,
                                                         LaneObjective* o) {
  const V4d zero = {0, 0, 0, 0};
  V4d vr = zr[top_z], vi = zi[top_z], r1 = zero, i1 = zero, r2 = zero, i2 = zero;
  for (int m = top_z - 1; m >= 0; --m) {
    r2 = r2 * eps + (r1 + r1);
    i2 = i2 * eps + (i1 + i1);
    r1 = r1 * eps + vr;
    i1 = i1 * eps + vi;
    vr = vr * eps + zr[m];
    vi = vi * eps + zi[m];
  }
  V4d g[4], g1[4], g2[4];
  constexpr int kStep = kSymmetric ? 2 : 1;  // chains e1 re, (e1 im), e2 re, (e2 im)
  for (int q = 0; q < 4; ++q) {
    g[q] = zero + (kSymmetric && q % 2 ? 0.0 : e12[4 * top_g + q]);
    g1[q] = zero;
    g2[q] = zero;
  }
  for (int m = top_g - 1; m >= 0; --m) {
    for (int q = 0; q < 4; q += kStep) {
      g2[q] = g2[q] * eps + (g1[q] + g1[q]);
      g1[q] = g1[q] * eps + g[q];
      g[q] = g[q] * eps + e12[4 * m + q];
    }
  }
  const double inv_n = 1.0 / n;
  const V4d C = g[0], E = g[1];
  const V4d a = 0.5 * (n + g[2]) - C * C * inv_n;
  const V4d b = 0.5 * g[3] - C * E * inv_n;
  const V4d d = 0.5 * (n - g[2]) - E * E * inv_n;
  const V4d wu = vr - C * y0 * inv_n;
  const V4d wv = vi - E * y0 * inv_n;
  const V4d det = a * d - b * b;
  const V4l regular = det > 1e-12 * n * n;
  const V4d inv_det = 1.0 / MESOSCAN_LANE_SELECT(regular, det, zero + 1.0);
  const V4d cc = (d * wu - b * wv) * inv_det;
  const V4d cs = (a * wv - b * wu) * inv_det;
  o->c0 = cc;
  o->c1 = cs;
  o->c2 = (y0 - C * cc - E * cs) * inv_n;
  o->j = wu * cc + wv * cs + y0 * y0 * inv_n;
  const V4d C1 = g1[0], E1 = g1[1], C2 = g2[0], E2 = g2[1];
  const V4d a1 = 0.5 * g1[2] - 2.0 * C * C1 * inv_n;
  const V4d b1 = 0.5 * g1[3] - (C1 * E + C * E1) * inv_n;
  const V4d d1 = -0.5 * g1[2] - 2.0 * E * E1 * inv_n;
  const V4d a2 = 0.5 * g2[2] - 2.0 * (C1 * C1 + C * C2) * inv_n;
  const V4d b2 = 0.5 * g2[3] - (C2 * E + 2.0 * C1 * E1 + C * E2) * inv_n;
  const V4d d2 = -0.5 * g2[2] - 2.0 * (E1 * E1 + E * E2) * inv_n;
  const V4d wu1 = r1 - C1 * y0 * inv_n, wv1 = i1 - E1 * y0 * inv_n;
  const V4d wu2 = r2 - C2 * y0 * inv_n, wv2 = i2 - E2 * y0 * inv_n;
  const V4d mc_u = a1 * cc + b1 * cs, mc_v = b1 * cc + d1 * cs;
  const V4d ru = wu1 - mc_u, rv = wv1 - mc_v;
  const V4d cc1 = (d * ru - b * rv) * inv_det;
  const V4d cs1 = (a * rv - b * ru) * inv_det;
  o->dc0 = cc1;
  o->dc1 = cs1;
  o->dc2 = -(C1 * cc + C * cc1 + E1 * cs + E * cs1) * inv_n;
  o->j1 = 2.0 * (wu1 * cc + wv1 * cs) - (cc * mc_u + cs * mc_v);
  const V4d m2c = cc * (a2 * cc + b2 * cs) + cs * (b2 * cc + d2 * cs);
  o->j2 = 2.0 * (wu2 * cc + wv2 * cs) + 2.0 * (wu1 * cc1 + wv1 * cs1) -
          2.0 * (cc1 * mc_u + cs1 * mc_v) - m2c;
  o->ok = regular & MESOSCAN_LANE_FINITE(o->j) & MESOSCAN_LANE_FINITE(o->j1) &
          MESOSCAN_LANE_FINITE(o->j2);
  if constexpr (kThirdAtZero) {
    // The sine chains of the symmetric case are 0 (as above).
    const double s1 = kSymmetric ? 0.0 : e12[13], s2 = kSymmetric ? 0.0 : e12[15];
    ThirdDerivativeAtZero<V4d>({zr[3], zi[3]}, {zero + e12[12], zero + s1},
                               {zero + e12[14], zero + s2}, C, E, C1, E1, C2, E2, y0, n, a, b, d,
                               inv_det, a1, b1, d1, a2, b2, d2, wu2, wv2, cc, cs, cc1, cs1, ru, rv,
                               &o->j3);
  }
}

// Correctly rounded square roots of the lanes (as std::sqrt): SSE2 (baseline x86-64) halves.
inline __attribute__((always_inline)) void LaneSqrt(const V4d& v, V4d* out) {
#if defined(__SSE2__)
  __m128d lo, hi;
  std::memcpy(&lo, &v, sizeof lo);
  std::memcpy(&hi, reinterpret_cast<const char*>(&v) + sizeof lo, sizeof hi);
  lo = _mm_sqrt_pd(lo);
  hi = _mm_sqrt_pd(hi);
  std::memcpy(out, &lo, sizeof lo);
  std::memcpy(reinterpret_cast<char*>(out) + sizeof lo, &hi, sizeof hi);
#else
  for (int l = 0; l < 4; ++l) (*out)[l] = std::sqrt(v[l]);
#endif
}

inline __attribute__((always_inline)) double LaneMaxAbs(const V4d& v, const V4l& mask) {
  const V4d zero = {0, 0, 0, 0};
  const V4d a = MESOSCAN_LANE_SELECT(mask, MESOSCAN_LANE_ABS(v), zero);
  return std::max(std::max(a[0], a[1]), std::max(a[2], a[3]));
}

inline __attribute__((always_inline)) bool LaneAny(const V4l& m) {
  return (m[0] | m[1] | m[2] | m[3]) != 0;
}

// Eight basis rows r of one sample (or sample pair) into the accumulators: acc[r] += bk[r] *
// (r even-parity ? even : odd). With positions symmetric about 0, row 2m + c (t^m cos, t^m sin)
// has parity (-1)^(m + c): rows 0, 3, 4, 7 of every group of 8 are even, so a sample pair
// (k, n-1-k) enters them as its sum and the others as its difference. A single sample passes
// itself as both.
static_assert(kFineMoments == 8 && kMoments == 16, "AddParityRows takes groups of 8 rows");
inline __attribute__((always_inline)) void AddParityRows(const double* bk, const V4d& even,
                                                         const V4d& odd, V4d* acc) {
  acc[0] += bk[0] * even;
  acc[1] += bk[1] * odd;
  acc[2] += bk[2] * odd;
  acc[3] += bk[3] * even;
  acc[4] += bk[4] * even;
  acc[5] += bk[5] * odd;
  acc[6] += bk[6] * odd;
  acc[7] += bk[7] * even;
}

// Four profiles: samples yb[k * 4 + l] (lane l, sample k), centring references mean[l]. Straight
// vector code with pointer arguments only (the clones' ABI, as FitBlock).
MESOSCAN_SIMD_CLONES
void FitFourLanes(const LaneInput* in, const float* yb, const double* mean_in, LaneOutput* out) {
  const int n = in->n;
  const V4d zero = {0, 0, 0, 0};
  V4d mean;
  std::memcpy(&mean, mean_in, sizeof mean);
  // Moments of the centred profiles against the 16 basis rows, in two passes of 8 rows (the
  // accumulators of one pass fit the 16 vector registers).
  V4d w[kMoments];
  V4d y0 = zero, y2 = zero;
  if (in->symmetric) {
    // Positions symmetric about 0 (x_{n-1-k} = -x_k): row 2m + c (t^m cos, t^m sin) has parity
    // (-1)^(m + c), so sample pairs (k, n-1-k) enter as s = y_k + y_{n-1-k} in the even rows and
    // d = y_k - y_{n-1-k} in the odd ones: half the products. The middle sample of odd n sits
    // at x = 0 and is added on its own.
    const int half_n = n / 2;
    for (int half = 0; half < 2; ++half) {
      V4d acc[8];
      for (int r = 0; r < 8; ++r) acc[r] = zero;
      for (int k = 0; k < half_n; ++k) {
        V4f va, vb;
        std::memcpy(&va, yb + 4 * k, sizeof va);
        std::memcpy(&vb, yb + 4 * (n - 1 - k), sizeof vb);
        V4d ya;
        Centred(va, mean, &ya);
        V4d yc;
        Centred(vb, mean, &yc);
        const V4d sum = ya + yc, dif = ya - yc;
        const double* bk = in->basis_km + static_cast<size_t>(k) * kMoments + 8 * half;
        AddParityRows(bk, sum, dif, acc);  // rows 8 half + r
        if (half == 0) {
          y0 += sum;
          y2 += ya * ya + yc * yc;
        }
      }
      if (n % 2 != 0) {
        V4f v;
        std::memcpy(&v, yb + 4 * half_n, sizeof v);
        V4d y;
        Centred(v, mean, &y);
        const double* bk = in->basis_km + static_cast<size_t>(half_n) * kMoments + 8 * half;
        AddParityRows(bk, y, y, acc);
        if (half == 0) {
          y0 += y;
          y2 += y * y;
        }
      }
      for (int r = 0; r < 8; ++r) w[8 * half + r] = acc[r];
    }
  } else {
    for (int half = 0; half < 2; ++half) {
      V4d acc[8];
      for (int r = 0; r < 8; ++r) acc[r] = zero;
      for (int k = 0; k < n; ++k) {
        V4f v;
        std::memcpy(&v, yb + 4 * k, sizeof v);
        V4d y;
        Centred(v, mean, &y);
        const double* bk = in->basis_km + static_cast<size_t>(k) * kMoments + 8 * half;
        AddParityRows(bk, y, y, acc);
        if (half == 0) {
          y0 += y;
          y2 += y * y;
        }
      }
      for (int r = 0; r < 8; ++r) w[8 * half + r] = acc[r];
    }
  }
  // Horner coefficients i^m W_m / m! (ZCoefficients).
  V4d zr[kOrder + 1], zi[kOrder + 1];
  double inv_fact = 1.0;
  for (int m = 0; m <= kOrder; ++m) {
    if (m > 0) inv_fact /= m;
    const V4d re = inv_fact * w[2 * m], im = inv_fact * w[2 * m + 1];
    switch (m & 3) {
      case 0:
        zr[m] = re, zi[m] = im;
        break;
      case 1:
        zr[m] = -im, zi[m] = re;
        break;
      case 2:
        zr[m] = -re, zi[m] = -im;
        break;
      default:
        zr[m] = im, zi[m] = -re;
        break;
    }
  }
  const double nd = n;
  V4d eps = zero;
  LaneObjective o;
  const bool sym = in->symmetric;
  if (sym)  // at eps' = 0: orders 0..2 exactly, and J''' from order 3
    EvaluateLanes<true, true>(zr, zi, 2, in->e12, 2, eps, y0, nd, &o);
  else
    EvaluateLanes<false, true>(zr, zi, 2, in->e12, 2, eps, y0, nd, &o);
  const V4l all = {-1, -1, -1, -1};
  V4l redo = ~o.ok & all;
  V4l active = o.ok;
  V4l iterations = {0, 0, 0, 0};
  constexpr double kQuadratic = 4.0;
  for (int it = 0; it < in->max_iterations && LaneAny(active); ++it) {
    iterations -= active;  // active lanes are -1
    const V4l concave = o.j2 < 0;
    V4d step =
        MESOSCAN_LANE_SELECT(concave, -o.j1 / MESOSCAN_LANE_SELECT(concave, o.j2, zero - 1.0),
                             MESOSCAN_LANE_SELECT(o.j1 > 0, zero + kMaxStep, zero - kMaxStep));
    if (it == 0) {  // FastFit's Halley step at the start
      const V4d q = -0.5 * step * o.j3 / MESOSCAN_LANE_SELECT(concave, o.j2, zero - 1.0);
      const V4l halley = concave & (MESOSCAN_LANE_ABS(q) <= 0.5);
      step = MESOSCAN_LANE_SELECT(halley, step / (1.0 - q), step);
    }
    step = MESOSCAN_LANE_SELECT(step > kMaxStep, zero + kMaxStep, step);
    step = MESOSCAN_LANE_SELECT(step < -kMaxStep, zero - kMaxStep, step);
    // FastFit's last-step test, without a division or a square root.
    V4l last = MESOSCAN_LANE_ABS(step) < in->final_step;
    if (in->sigma_factor > 0.0) {
      const V4d s2 = step * step;
      const V4d ssr = o.j < y2 ? y2 - o.j : zero;
      last |= concave & (kQuadratic * kQuadratic * s2 * s2 * -o.j2 < in->tol_sigma_sq_factor * ssr);
    }
    const V4l finish = active & concave & last & (MESOSCAN_LANE_ABS(eps + step) <= kEvalRadius);
    if (LaneAny(finish)) {
      // FastFit's last step: coefficients to first order, J to second.
      eps = MESOSCAN_LANE_SELECT(finish, eps + step, eps);
      o.c0 = MESOSCAN_LANE_SELECT(finish, o.c0 + o.dc0 * step, o.c0);
      o.c1 = MESOSCAN_LANE_SELECT(finish, o.c1 + o.dc1 * step, o.c1);
      o.c2 = MESOSCAN_LANE_SELECT(finish, o.c2 + o.dc2 * step, o.c2);
      o.j = MESOSCAN_LANE_SELECT(finish, o.j + step * (o.j1 + 0.5 * step * o.j2), o.j);
      active &= ~finish;
      if (!LaneAny(active)) break;
    }
    V4d e = eps + step;
    e = MESOSCAN_LANE_SELECT(e > kEvalRadius, zero + kEvalRadius, e);
    e = MESOSCAN_LANE_SELECT(e < -kEvalRadius, zero - kEvalRadius, e);
    e = MESOSCAN_LANE_SELECT(active, e, eps);
    const double r = LaneMaxAbs(e, active);
    const int top_z = std::min(NeededOrder(r, kOrder) + 2, kOrder);
    const int top_g = std::min(NeededOrder(2.0 * r, kGramOrder) + 2, kGramOrder);
    LaneObjective next;
    if (sym)
      EvaluateLanes<true>(zr, zi, top_z, in->e12, top_g, e, y0, nd, &next);
    else
      EvaluateLanes<false>(zr, zi, top_z, in->e12, top_g, e, y0, nd, &next);
    const V4l accept = next.ok & (next.j >= o.j - 1e-15 * MESOSCAN_LANE_ABS(o.j));
    redo |= active & ~accept;  // FastFit would halve the step: left to it
    active &= accept;
    step = e - eps;
    eps = MESOSCAN_LANE_SELECT(active, e, eps);
    o.j = MESOSCAN_LANE_SELECT(active, next.j, o.j);
    o.j1 = MESOSCAN_LANE_SELECT(active, next.j1, o.j1);
    o.j2 = MESOSCAN_LANE_SELECT(active, next.j2, o.j2);
    o.c0 = MESOSCAN_LANE_SELECT(active, next.c0, o.c0);
    o.c1 = MESOSCAN_LANE_SELECT(active, next.c1, o.c1);
    o.c2 = MESOSCAN_LANE_SELECT(active, next.c2, o.c2);
    o.dc0 = MESOSCAN_LANE_SELECT(active, next.dc0, o.dc0);
    o.dc1 = MESOSCAN_LANE_SELECT(active, next.dc1, o.dc1);
    o.dc2 = MESOSCAN_LANE_SELECT(active, next.dc2, o.dc2);
    const V4l recentre = active & (MESOSCAN_LANE_ABS(eps) > kRadius);
    redo |= recentre;  // FastFit would re-centre the moments: left to it
    active &= ~recentre;
    active &= ~(MESOSCAN_LANE_ABS(step) < in->eps_tol);  // converged
  }
  redo |= active;  // the iteration cap: left to FastFit (converged = false there)
  // Finalize's arithmetic in the lanes: phi = atan2(c0, c1) (FastAtan2's steps), a, the
  // residual and the amplitude's noise (the validity decision stays scalar).
  {
    const V4d cc = o.c0, cs = o.c1;
    const V4d ay = MESOSCAN_LANE_ABS(cc), ax = MESOSCAN_LANE_ABS(cs);
    const V4d hi = ay > ax ? ay : ax, lo = ay > ax ? ax : ay;
    const V4d t = hi > 0 ? lo / (hi > 0 ? hi : zero + 1.0) : zero;
    V4d at;
    AtanOfRatio(t, ay, ax, &at);
    at = cs < 0 ? kPi - at : at;
    at = cc < 0 ? -at : at;
    at = at <= -kPi ? zero + kPi : at;  // WrapPhase: (-pi, pi]
    V4d a, rms;
    LaneSqrt(cc * cc + cs * cs, &a);
    const V4d ssr0 = y2 - o.j;
    const V4d ssr = ssr0 > 0 ? ssr0 : zero;
    LaneSqrt(ssr / nd, &rms);
    // Finalize's sigma_a = sqrt(SSR / (n - 4)) sqrt(2 / n), from the rms (to rounding).
    const V4d sigma_a = rms * in->sqrt_2_over_n_minus_4;
    const V4d inf = zero + std::numeric_limits<double>::infinity();
    const V4d phase_sigma = a > 0 ? sigma_a / (a > 0 ? a : zero + 1.0) : inf;
    std::memcpy(out->phase, &at, sizeof at);
    std::memcpy(out->amplitude, &a, sizeof a);
    std::memcpy(out->ssr, &ssr0, sizeof ssr0);
    std::memcpy(out->residual_rms, &rms, sizeof rms);
    std::memcpy(out->phase_sigma, &phase_sigma, sizeof phase_sigma);
    std::memcpy(out->sigma_a, &sigma_a, sizeof sigma_a);
  }
  std::memcpy(out->c[0], &o.c0, sizeof o.c0);
  std::memcpy(out->c[1], &o.c1, sizeof o.c1);
  std::memcpy(out->c[2], &o.c2, sizeof o.c2);
  std::memcpy(out->j, &o.j, sizeof o.j);
  std::memcpy(out->y2, &y2, sizeof y2);
  std::memcpy(out->eps, &eps, sizeof eps);
  std::memcpy(out->iterations, &iterations, sizeof iterations);
  std::memcpy(out->redo, &redo, sizeof redo);
}

// Copies the finite samples (and their positions) of a strided profile.
int GatherFinite(const float* b, int stride, const double* x, int n, std::vector<float>* bf,
                 std::vector<double>* xf) {
  bf->clear();
  xf->clear();
  for (int k = 0; k < n; ++k) {
    const float v = b[static_cast<std::ptrdiff_t>(k) * stride];
    if (std::isfinite(v)) {
      bf->push_back(v);
      xf->push_back(x[k]);
    }
  }
  return static_cast<int>(bf->size());
}

// fine: the fixed-frequency tables (a finer grid, fewer moments); only for fit_frequency false.
std::shared_ptr<const LensShiftBatchFitter::Tables> BuildTables(const std::vector<double>& x,
                                                                double f0,
                                                                const LensShiftFitOptions& o,
                                                                bool fine = false) {
  auto t = std::make_shared<LensShiftBatchFitter::Tables>();
  const int n = static_cast<int>(x.size());
  t->n = n;
  double xmax = 0.0;
  for (double v : x) xmax = std::max(xmax, std::abs(v));
  t->x_scale = xmax > 0.0 ? xmax : 1.0;
  t->symmetric = true;
  for (int k = 0; k < n; ++k)
    t->symmetric = t->symmetric && std::abs(x[k] + x[n - 1 - k]) <= 1e-15 * t->x_scale;
  t->fine = fine;
  const int factor = fine ? kFineFactor : 1;
  t->h = kRadius / (kPi * t->x_scale) / factor;
  const double span = o.max_frequency_deviation * std::abs(f0);
  t->grid_half = std::min(kMaxGridHalf * factor, static_cast<int>(std::ceil(span / t->h)) + 1);
  const int grid = 2 * t->grid_half + 1;
  t->basis_f.resize(fine ? 0 : grid);
  t->basis_d.resize(fine ? 0 : grid);
  t->fine_f.resize(fine ? grid : 0);
  t->fine_d.resize(fine ? grid : 0);
  t->e1.resize(grid);
  t->e2.resize(grid);
  t->e12.resize(grid);
  t->km.resize(grid);
  Eigen::Matrix<double, kMoments, Eigen::Dynamic, Eigen::RowMajor> bd(kMoments, n);
  for (int g = 0; g < grid; ++g) {
    const double fj = f0 + (g - t->grid_half) * t->h;
    std::array<Cd, kGramOrder + 1> p1{}, p2{};  // sum t^m e^{i w x}, sum t^m e^{2 i w x}
    for (int k = 0; k < n; ++k) {
      const double tk = x[k] / t->x_scale;
      const double th = kTwoPi * fj * x[k];
      const Cd e(std::cos(th), std::sin(th));
      const Cd ee(std::cos(2.0 * th), std::sin(2.0 * th));
      double tm = 1.0;
      for (int m = 0; m <= kGramOrder; ++m) {
        if (m <= kOrder) {
          bd(2 * m, k) = tm * e.real();
          bd(2 * m + 1, k) = tm * e.imag();
        }
        p1[m] += tm * e;
        p2[m] += tm * ee;
        tm *= tk;
      }
    }
    const int rows = fine ? kFineMoments : kMoments;
    t->km[g].resize(static_cast<size_t>(n) * rows);
    for (int k = 0; k < n; ++k)
      for (int r = 0; r < rows; ++r) t->km[g][static_cast<size_t>(k) * rows + r] = bd(r, k);
    if (fine) {
      t->fine_d[g] = bd.topRows<kFineMoments>();
      t->fine_f[g] = t->fine_d[g].cast<float>();
    } else {
      t->basis_d[g] = bd;
      t->basis_f[g] = bd.cast<float>();
    }
    // Horner coefficients: sum e^{i (w + eps) x} = sum_m (i eps')^m / m! P_m, and with 2 i eps'
    // for the doubled frequency.
    double inv_fact = 1.0;
    Cd i1 = 1.0, i2 = 1.0;
    for (int m = 0; m <= kGramOrder; ++m) {
      if (m > 0) inv_fact /= m, i1 *= Cd(0.0, 1.0), i2 *= Cd(0.0, 2.0);
      t->e1[g][m] = i1 * inv_fact * p1[m];
      t->e2[g][m] = i2 * inv_fact * p2[m];
      t->e12[g][4 * m] = t->e1[g][m].real();
      t->e12[g][4 * m + 1] = t->e1[g][m].imag();
      t->e12[g][4 * m + 2] = t->e2[g][m].real();
      t->e12[g][4 * m + 3] = t->e2[g][m].imag();
    }
  }
  return t;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Public API

const char* LensShiftFitterName(LensShiftFitter fitter) {
  switch (fitter) {
    case LensShiftFitter::kFast:
      return "fast";
    case LensShiftFitter::kLm:
      return "lm";
    case LensShiftFitter::kCeres:
      return "ceres";
  }
  return "?";
}

LensShiftFitter ParseLensShiftFitter(const std::string& name, const std::string& option) {
  if (name == "fast") return LensShiftFitter::kFast;
  if (name == "lm") return LensShiftFitter::kLm;
  if (name == "ceres") return LensShiftFitter::kCeres;
  MESOSCAN_BAD_OPTION(option, "unknown fitter '" << name << "' (expected fast, lm or ceres)");
}

void LensShiftFitOptions::Check() const {
  if (max_iterations < 1)
    MESOSCAN_BAD_INPUT("lens-shift fit: max_iterations " << max_iterations << " must be >= 1");
  if (!(frequency_tolerance > 0.0))
    MESOSCAN_BAD_INPUT("lens-shift fit: frequency_tolerance " << frequency_tolerance
                                                              << " must be > 0");
  if (!(frequency_tolerance_sigma >= 0.0))
    MESOSCAN_BAD_INPUT("lens-shift fit: frequency_tolerance_sigma " << frequency_tolerance_sigma
                                                                    << " must be >= 0");
  if (!(max_frequency_deviation > 0.0 && max_frequency_deviation < 1.0))
    MESOSCAN_BAD_INPUT("lens-shift fit: max_frequency_deviation " << max_frequency_deviation
                                                                  << " must be in (0, 1)");
  if (!(min_amplitude_snr >= 0.0))
    MESOSCAN_BAD_INPUT("lens-shift fit: min_amplitude_snr " << min_amplitude_snr
                                                            << " must be >= 0");
  if (!(min_amplitude >= 0.0))
    MESOSCAN_BAD_INPUT("lens-shift fit: min_amplitude " << min_amplitude << " must be >= 0");
}

LensShiftFit FitLensShiftProfile(const float* b, const double* x, int n, double f0,
                                 const LensShiftFitOptions& options, int stride) {
  std::vector<float> bf;
  std::vector<double> xf;
  const int used = GatherFinite(b, stride, x, n, &bf, &xf);
  if (!(std::isfinite(f0) && f0 != 0.0)) return InvalidFit(used, f0);
  for (double v : xf)
    if (!std::isfinite(v)) return InvalidFit(used, f0);
  switch (options.fitter) {
    case LensShiftFitter::kLm:
      return FitLm(bf.data(), xf.data(), used, f0, options);
    case LensShiftFitter::kCeres:
      return FitCeres(bf.data(), xf.data(), used, f0, options);
    case LensShiftFitter::kFast:
      break;
  }
  const auto tables = BuildTables(xf, f0, options);
  std::vector<double> y(std::max(used, 1));
  const float mean = used > 0 ? Eigen::Map<const Eigen::ArrayXf>(bf.data(), used).mean() : 0.0f;
  return FastFit<double>(*tables, bf.data(), mean, f0, f0, options, y.data());
}

LensShiftBatchFitter::LensShiftBatchFitter(std::vector<double> x, double f0,
                                           const LensShiftFitOptions& options)
    : x_(std::move(x)), f0_(f0), options_(options) {
  options_.Check();
  if (x_.empty()) MESOSCAN_BAD_INPUT("lens-shift fit: no shift positions");
  for (double v : x_)
    if (!std::isfinite(v)) MESOSCAN_BAD_INPUT("lens-shift fit: a shift position is not finite");
  if (!(std::isfinite(f0_) && f0_ != 0.0))
    MESOSCAN_BAD_INPUT("lens-shift fit: nominal frequency " << f0_ << " must be finite and != 0");
  if (options_.fitter == LensShiftFitter::kFast)
    tables_ = BuildTables(x_, f0_, options_, /*fine=*/!options_.fit_frequency);
}

LensShiftFit LensShiftBatchFitter::Fit(const float* b, int stride) const {
  return Fit(b, stride, f0_);
}

LensShiftFit LensShiftBatchFitter::Fit(const float* b, int stride, double f_start) const {
  const int n = num_samples();
  // Gather into a contiguous buffer (stack for the usual sizes) unless already contiguous.
  std::array<float, kStackSamples> stack_b;
  std::vector<float> heap_b;
  const float* buf = b;
  if (stride != 1) {
    float* dst = stack_b.data();
    if (n > kStackSamples) {
      heap_b.resize(n);
      dst = heap_b.data();
    }
    for (int k = 0; k < n; ++k) dst[k] = b[static_cast<std::ptrdiff_t>(k) * stride];
    buf = dst;
  }
  // One vectorised pass: the mean (centring reference) and the finiteness of every sample
  // (NaN/Inf make the sum non-finite; so does overflow, which the fallback handles too).
  const float sum = Eigen::Map<const Eigen::ArrayXf>(buf, n).sum();
  if (!std::isfinite(sum) || !std::isfinite(f_start)) {
    // NaN/Inf samples (or an overflowing sum): fit the finite samples on their own positions.
    LensShiftFitOptions o = options_;
    std::vector<float> bf;
    std::vector<double> xf;
    const int used = GatherFinite(buf, 1, x_.data(), n, &bf, &xf);
    if (!std::isfinite(f_start)) return InvalidFit(used, f0_);
    LensShiftFit fit = FitLensShiftProfile(bf.data(), xf.data(), used, f_start, o);
    // Validity bounds are relative to f0, not to the start.
    if (fit.valid && std::abs(fit.frequency - f0_) > o.max_frequency_deviation * std::abs(f0_))
      fit.valid = false;
    return fit;
  }
  switch (options_.fitter) {
    case LensShiftFitter::kLm: {
      LensShiftFit fit = FitLm(buf, x_.data(), n, f_start, options_);
      if (fit.valid &&
          std::abs(fit.frequency - f0_) > options_.max_frequency_deviation * std::abs(f0_))
        fit.valid = false;
      return fit;
    }
    case LensShiftFitter::kCeres: {
      LensShiftFit fit = FitCeres(buf, x_.data(), n, f_start, options_);
      if (fit.valid &&
          std::abs(fit.frequency - f0_) > options_.max_frequency_deviation * std::abs(f0_))
        fit.valid = false;
      return fit;
    }
    case LensShiftFitter::kFast:
      break;
  }
  if (options_.double_accumulation) {
    std::array<double, kStackSamples> stack_y;
    std::vector<double> heap_y;
    double* y = stack_y.data();
    if (n > kStackSamples) {
      heap_y.resize(n);
      y = heap_y.data();
    }
    return FastFit<double>(*tables_, buf, sum / n, f0_, f_start, options_, y);
  }
  std::array<float, kStackSamples> stack_y;
  std::vector<float> heap_y;
  float* y = stack_y.data();
  if (n > kStackSamples) {
    heap_y.resize(n);
    y = heap_y.data();
  }
  return FastFit<float>(*tables_, buf, sum / n, f0_, f_start, options_, y);
}

void LensShiftBatchFitter::FitMany(const float* b, std::ptrdiff_t profile_stride, int sample_stride,
                                   int count, LensShiftFit* out) const {
  const int n = num_samples();
  auto single = [&](int p) { out[p] = Fit(b + p * profile_stride, sample_stride); };
  if (options_.fitter != LensShiftFitter::kFast || !options_.fit_frequency ||
      !options_.double_accumulation || n < 5 || n > kStackSamples) {
    for (int p = 0; p < count; ++p) single(p);
    return;
  }
  const Tables& t = *tables_;
  const double two_pi_x = kTwoPi * t.x_scale;
  LaneInput in;
  in.basis_km = t.km[t.grid_half].data();
  in.e12 = t.e12[t.grid_half].data();
  in.n = n;
  in.symmetric = t.symmetric;
  in.max_iterations = options_.max_iterations;
  in.eps_tol = options_.frequency_tolerance * two_pi_x;
  in.final_step = std::sqrt(in.eps_tol / 4.0);  // FastFit's kQuadratic
  in.sigma_factor = options_.frequency_tolerance_sigma > 0.0 ? 2.0 / (n - 4) : 0.0;
  in.tol_sigma_sq_factor =
      options_.frequency_tolerance_sigma * options_.frequency_tolerance_sigma * in.sigma_factor;
  in.sqrt_2_over_n_minus_4 = std::sqrt(2.0 / (n - 4));
  const double max_df = options_.max_frequency_deviation * std::abs(f0_);
  alignas(32) float yb[4 * kStackSamples];
  int p0 = 0;
  for (; p0 + 4 <= count; p0 += 4) {
    // Lane-interleaved copy and the per-lane float sums (FastFit's centring reference; a
    // non-finite sum: NaN / Inf samples, left to Fit).
    V4f sum = {0, 0, 0, 0};
    const float* src[4];
    for (int l = 0; l < 4; ++l) src[l] = b + (p0 + l) * profile_stride;
    int k = 0;
    if (profile_stride == 1) {
      // Frame-major rows of adjacent pixels: one load per sample.
      for (; k < n; ++k) {
        V4f v;
        std::memcpy(&v, src[0] + static_cast<std::ptrdiff_t>(k) * sample_stride, sizeof v);
        std::memcpy(yb + 4 * k, &v, sizeof v);
        sum += v;
      }
    } else if (sample_stride == 1) {
      // Contiguous profiles: 4 x 4 blocks transposed in registers.
      for (; k + 4 <= n; k += 4) {
        V4f r0, r1, r2, r3;
        std::memcpy(&r0, src[0] + k, sizeof r0);
        std::memcpy(&r1, src[1] + k, sizeof r1);
        std::memcpy(&r2, src[2] + k, sizeof r2);
        std::memcpy(&r3, src[3] + k, sizeof r3);
        const V4f t0 = __builtin_shufflevector(r0, r1, 0, 4, 1, 5);  // a0 b0 a1 b1
        const V4f t1 = __builtin_shufflevector(r2, r3, 0, 4, 1, 5);  // c0 d0 c1 d1
        const V4f t2 = __builtin_shufflevector(r0, r1, 2, 6, 3, 7);  // a2 b2 a3 b3
        const V4f t3 = __builtin_shufflevector(r2, r3, 2, 6, 3, 7);  // c2 d2 c3 d3
        const V4f c0 = __builtin_shufflevector(t0, t1, 0, 1, 4, 5);
        const V4f c1 = __builtin_shufflevector(t0, t1, 2, 3, 6, 7);
        const V4f c2 = __builtin_shufflevector(t2, t3, 0, 1, 4, 5);
        const V4f c3 = __builtin_shufflevector(t2, t3, 2, 3, 6, 7);
        std::memcpy(yb + 4 * k, &c0, sizeof c0);
        std::memcpy(yb + 4 * k + 4, &c1, sizeof c1);
        std::memcpy(yb + 4 * k + 8, &c2, sizeof c2);
        std::memcpy(yb + 4 * k + 12, &c3, sizeof c3);
        sum += c0;
        sum += c1;
        sum += c2;
        sum += c3;
      }
    }
    for (; k < n; ++k) {
      const std::ptrdiff_t o = static_cast<std::ptrdiff_t>(k) * sample_stride;
      const V4f v = {src[0][o], src[1][o], src[2][o], src[3][o]};
      std::memcpy(yb + 4 * k, &v, sizeof v);
      sum += v;
    }
    bool lane_ok[4];
    alignas(32) double mean[4];
    bool any = false;
    for (int l = 0; l < 4; ++l) {
      lane_ok[l] = std::isfinite(sum[l]);
      mean[l] = lane_ok[l] ? static_cast<double>(sum[l] / static_cast<float>(n)) : 0.0;
      any = any || lane_ok[l];
    }
    if (!any) {
      for (int l = 0; l < 4; ++l) single(p0 + l);
      continue;
    }
    for (int l = 0; l < 4; ++l)
      if (!lane_ok[l])
        for (int k = 0; k < n; ++k) yb[4 * k + l] = 0.0f;
    LaneOutput r;
    FitFourLanes(&in, yb, mean, &r);
    for (int l = 0; l < 4; ++l) {
      if (!lane_ok[l] || r.redo[l]) {
        single(p0 + l);
        continue;
      }
      // Finalize with the lanes' arithmetic: the same values; Finalize itself wherever the fit
      // is not valid (its clean-up of non-finite values).
      const double f = f0_ + r.eps[l] / two_pi_x, d = r.c[2][l] + mean[l];
      const int iterations = static_cast<int>(r.iterations[l]);
      LensShiftFit& fit = out[p0 + l];
      fit.phase = r.phase[l];
      fit.amplitude = r.amplitude[l];
      fit.frequency = f;
      fit.offset = d;
      fit.residual_rms = r.residual_rms[l];
      fit.phase_sigma = r.phase_sigma[l];
      fit.samples_used = n;
      fit.iterations = iterations;
      fit.converged = true;
      const double a = fit.amplitude;
      fit.valid = std::isfinite(fit.phase) && std::isfinite(a) && std::isfinite(f) &&
                  std::isfinite(d) && std::isfinite(fit.residual_rms) &&
                  std::isfinite(fit.phase_sigma) && a > options_.min_amplitude &&
                  a > kMinRelativeAmplitude * std::abs(d) &&
                  a >= options_.min_amplitude_snr * r.sigma_a[l] && std::abs(f - f0_) <= max_df;
      if (!fit.valid)
        fit = Finalize(fit.phase, a, f, d, r.ssr[l], n, iterations, true, f0_, options_);
    }
  }
  for (; p0 < count; ++p0) single(p0);
}

int LensShiftBatchFitter::num_samples() const { return static_cast<int>(x_.size()); }
const std::vector<double>& LensShiftBatchFitter::positions() const { return x_; }
double LensShiftBatchFitter::nominal_frequency() const { return f0_; }
const LensShiftFitOptions& LensShiftBatchFitter::options() const { return options_; }

// ---------------------------------------------------------------------------------------------
// LensShiftRowFitter: the fixed-frequency fit of 4 pixels at once.

namespace {

constexpr int kLanes = 4;

// The lanes' results (see FitBlock).
struct BlockResult {
  double phase[kLanes];           // phi at x = 0, (-pi, pi]
  double cc[kLanes], cs[kLanes];  // a sin phi, a cos phi
  double offset[kLanes];          // d (the constant, the centring reference added back)
  double ssr[kLanes];             // sum of squared residuals
  double y0[kLanes];   // sum of the samples about the first (not finite: a sample was not)
  int64_t ok[kLanes];  // != 0: the 3x3 system was regular
  // Finalize's figures of the lanes, vectorised (LensShiftRowFitter::FitRow, nk > 3 for the
  // last two): a = |(cc, cs)|, residual_rms, phase_sigma and the amplitude's SNR.
  double amplitude[kLanes], residual_rms[kLanes], phase_sigma[kLanes], snr[kLanes];
};

// out[l] = sqrt(v[l]): correctly rounded like std::sqrt (lens_shift_fit.cc is compiled with
// -fno-math-errno, so the four are one vector instruction).
inline void SqrtLanes(const double* v, double* out) {
  for (int l = 0; l < kLanes; ++l) out[l] = std::sqrt(v[l]);
}

// Four pixels (samples b[k * stride + l], l < 4, times gain[k]) at grid point with transposed
// basis rows basis_km (nk x kFineMoments) and Gram Horner coefficients e1c, e2c (order top_g),
// each lane at its own eps' (eps[l]): FastFit<double> + Evaluate(derivatives = false) of
// LensShiftBatchFitter, lane by lane, and phi = atan2(cc, cs) to 1e-16 rad. Straight-line vector
// code: no vector-typed argument or return value (their ABI differs between the clones).
MESOSCAN_SIMD_CLONES
void FitBlock(const double* basis_km, const double* basis_sum, int nk, bool symmetric,
              const float* b, size_t stride, const float* gain, const double* eps_in, const Cd* e1c,
              const Cd* e2c, int top_g, double sqrt_2_over_n, BlockResult* r) {
  // Accumulated about the first sample, then moved to the mean (the moments are linear in the
  // samples: W_m(y - mu) = W_m(y) - mu sum_k B_mk), so that, as in FastFit, the moments scale
  // with the amplitude, not the offset, and the Taylor truncation stays relative to the
  // amplitude; one pass over the samples.
  V4f v0;
  std::memcpy(&v0, b, sizeof v0);
  v0 *= gain[0];
  V4d ref;
  Widen(v0, &ref);
  const V4d zero = {0, 0, 0, 0};
  V4d w[kFineMoments], y0 = zero, y2 = zero;
  for (V4d& v : w) v = zero;
  // Positions symmetric about 0 (Tables::symmetric): sample pairs (k, nk-1-k) fold into the
  // rows as in FitFourLanes (AddParityRows), half the products; the middle sample of an odd
  // count below with the rest.
  int k = 0;
  if (symmetric) {
    const int half = nk / 2;
    for (; k < half; ++k) {
      const int kc = nk - 1 - k;
      V4f va, vc;
      std::memcpy(&va, b + k * stride, sizeof va);
      std::memcpy(&vc, b + kc * stride, sizeof vc);
      va *= gain[k];
      vc *= gain[kc];
      V4d ya;
      Centred(va, ref, &ya);
      V4d yc;
      Centred(vc, ref, &yc);
      const V4d sum = ya + yc, dif = ya - yc;
      AddParityRows(basis_km + static_cast<size_t>(k) * kFineMoments, sum, dif, w);
      y0 += sum;
      y2 += ya * ya + yc * yc;
    }
  }
  const int k_end = symmetric ? (nk + 1) / 2 : nk;
  for (; k < k_end; ++k) {
    V4f v;
    std::memcpy(&v, b + k * stride, sizeof v);
    v *= gain[k];
    V4d y;
    Centred(v, ref, &y);
    AddParityRows(basis_km + static_cast<size_t>(k) * kFineMoments, y, y, w);
    y0 += y;
    y2 += y * y;
  }
  const V4d sum_about_first = y0;
  {
    const double nd = nk;
    const V4d mu = y0 / nd;
    for (int r = 0; r < kFineMoments; ++r) w[r] -= mu * basis_sum[r];
    y2 -= mu * y0;
    ref += mu;
    y0 = zero;
  }
  // Horner coefficients i^m W_m / m! (Moments) and their value at eps' (order 3: the rows).
  V4d eps;
  std::memcpy(&eps, eps_in, sizeof eps);
  const double inv2 = 0.5, inv6 = 0.5 / 3.0;
  V4d zr = w[7] * inv6, zi = -(w[6] * inv6);  // m = 3: (im, -re)
  zr = zr * eps + (-(w[4] * inv2));           // m = 2: (-re, -im)
  zi = zi * eps + (-(w[5] * inv2));
  zr = zr * eps + (-w[3]);  // m = 1: (-im, re)
  zi = zi * eps + w[2];
  zr = zr * eps + w[0];  // m = 0
  zi = zi * eps + w[1];
  // Gram sums sum e^{i (w + eps) x} and sum e^{2 i (w + eps) x}.
  V4d g1r = zero + e1c[top_g].real(), g1i = zero + e1c[top_g].imag();
  V4d g2r = zero + e2c[top_g].real(), g2i = zero + e2c[top_g].imag();
  for (int m = top_g - 1; m >= 0; --m) {
    g1r = g1r * eps + e1c[m].real();
    g1i = g1i * eps + e1c[m].imag();
    g2r = g2r * eps + e2c[m].real();
    g2i = g2i * eps + e2c[m].imag();
  }
  // Reduced 2x2 system after eliminating the constant (Evaluate).
  const double nd = nk, inv_n = 1.0 / nd;
  const V4d C = g1r, E = g1i;
  const V4d a = 0.5 * (nd + g2r) - C * C * inv_n;
  const V4d bb = 0.5 * g2i - C * E * inv_n;
  const V4d d = 0.5 * (nd - g2r) - E * E * inv_n;
  const V4d wu = zr - C * y0 * inv_n;
  const V4d wv = zi - E * y0 * inv_n;
  const V4d det = a * d - bb * bb;
  const V4l ok = det > 1e-12 * nd * nd;
  const V4d inv_det = 1.0 / det;
  const V4d cc = (d * wu - bb * wv) * inv_det;  // a sin phi
  const V4d cs = (a * wv - bb * wu) * inv_det;  // a cos phi
  const V4d c2 = (y0 - C * cc - E * cs) * inv_n;
  const V4d j = wu * cc + wv * cs + y0 * y0 * inv_n;
  const V4d offset = c2 + ref, ssr = y2 - j;
  // phi = atan2(cc, cs): atan of t = min / max in [0, 1], reduced to |u| <= tan(pi / 8).
  const V4d ay = cc < 0 ? -cc : cc, ax = cs < 0 ? -cs : cs;
  const V4d hi = ay > ax ? ay : ax, lo = ay > ax ? ax : ay;
  const V4d t = hi > 0 ? lo / hi : zero;
  V4d at;
  AtanOfRatio(t, ay, ax, &at);
  at = cs < 0 ? kPi - at : at;
  at = cc < 0 ? -at : at;  // cc == -0.0 with cs < 0 gives pi, not -pi: (-pi, pi] as WrapPhase
  std::memcpy(r->phase, &at, sizeof at);
  std::memcpy(r->cc, &cc, sizeof cc);
  std::memcpy(r->cs, &cs, sizeof cs);
  std::memcpy(r->offset, &offset, sizeof offset);
  std::memcpy(r->ssr, &ssr, sizeof ssr);
  std::memcpy(r->y0, &sum_about_first, sizeof sum_about_first);
  std::memcpy(r->ok, &ok, sizeof ok);
  // FitRow's Finalize figures, the same operations lane by lane: ssr clamped at 0 as
  // std::max(ssr, 0.0) (NaN stays), a, ssr / n and, with nk > 3, sigma_a.
  const V4d ssr0 = ssr < 0.0 ? zero : ssr;
  const V4d a2 = cc * cc + cs * cs, ms = ssr0 / nd;
  V4d amp, rms;
  SqrtLanes(reinterpret_cast<const double*>(&a2), reinterpret_cast<double*>(&amp));
  SqrtLanes(reinterpret_cast<const double*>(&ms), reinterpret_cast<double*>(&rms));
  std::memcpy(r->amplitude, &amp, sizeof amp);
  std::memcpy(r->residual_rms, &rms, sizeof rms);
  if (nk > 3) {
    const V4d v3 = ssr0 / static_cast<double>(nk - 3);
    V4d s3;
    SqrtLanes(reinterpret_cast<const double*>(&v3), reinterpret_cast<double*>(&s3));
    const V4d sigma_a = s3 * sqrt_2_over_n;
    const V4d inf = zero + std::numeric_limits<double>::infinity();
    const V4d phase_sigma = amp > 0.0 ? sigma_a / amp : inf;
    const V4d snr = sigma_a > 0.0 ? amp / sigma_a : inf;
    std::memcpy(r->phase_sigma, &phase_sigma, sizeof phase_sigma);
    std::memcpy(r->snr, &snr, sizeof snr);
  }
}

}  // namespace

LensShiftRowFitter::LensShiftRowFitter(std::vector<double> x, double f0,
                                       const LensShiftFitOptions& options)
    : batch_(std::move(x), f0, options) {
  if (options.fitter != LensShiftFitter::kFast || options.fit_frequency)
    MESOSCAN_BAD_INPUT("lens-shift row fit: needs the fast fitter with a fixed frequency");
  const LensShiftBatchFitter::Tables& t = *batch_.tables_;
  const size_t nk = static_cast<size_t>(t.n);
  basis_sum_.assign(t.km.size() * kFineMoments, 0.0);
  for (size_t g = 0; g < t.km.size(); ++g)
    for (size_t k = 0; k < nk; ++k)
      for (int m = 0; m < kFineMoments; ++m)
        basis_sum_[g * kFineMoments + m] += t.km[g][k * kFineMoments + m];
}

void LensShiftRowFitter::FitRow(const float* b, size_t stride, int n, const float* gain,
                                const float* f, const uint8_t* use, LensShiftFit* out) const {
  const LensShiftBatchFitter::Tables& t = *batch_.tables_;
  const int nk = t.n;
  const double f0 = batch_.f0_;
  const LensShiftFitOptions& options = batch_.options_;
  const double two_pi_x = kTwoPi * t.x_scale;
  // The per-pixel path: the gain-normalised profile, contiguous.
  auto fallback = [&](int j) {
    std::array<float, kStackSamples> stack_b;
    std::vector<float> heap_b;
    float* p = stack_b.data();
    if (nk > kStackSamples) {
      heap_b.resize(nk);
      p = heap_b.data();
    }
    for (int k = 0; k < nk; ++k) p[k] = b[static_cast<size_t>(k) * stride + j] * gain[k];
    out[j] = batch_.Fit(p, 1, f[j]);
  };
  // Grid point of pixel j's frequency (FastFit's nearest), or false: off the tables.
  auto grid_of = [&](int j, int* g) {
    const double fj = f[j];
    if (!std::isfinite(fj)) return false;
    const double q = std::nearbyint((fj - f0) / t.h);
    if (!(std::abs(q) <= t.grid_half)) return false;
    *g = static_cast<int>(q);
    return true;
  };
  const bool lanes_ok = nk >= 3;  // FastFit's n >= p
  const double sqrt_2_over_n = std::sqrt(2.0 / nk);
  for (int j0 = 0; j0 < n; j0 += kLanes) {
    const int cnt = std::min(kLanes, n - j0);
    bool lane[kLanes] = {false, false, false, false};
    int g_block = 0;
    bool have = false;
    for (int l = 0; l < cnt; ++l) {
      const int j = j0 + l;
      if (!use[j]) continue;
      int g = 0;
      if (!lanes_ok || cnt < kLanes || !grid_of(j, &g) || (have && g != g_block)) {
        fallback(j);
        continue;
      }
      g_block = g;
      have = true;
      lane[l] = true;
    }
    if (!have) continue;
    const double f_grid = f0 + g_block * t.h;
    double eps[kLanes];
    double max_eps = 0.0;
    for (int l = 0; l < kLanes; ++l) {
      eps[l] = lane[l] ? two_pi_x * (static_cast<double>(f[j0 + l]) - f_grid) : 0.0;
      max_eps = std::max(max_eps, std::abs(eps[l]));
    }
    const int gi = g_block + t.grid_half;
    const int top_g = NeededOrder(2.0 * max_eps, kGramOrder);
    BlockResult r;
    FitBlock(t.km[gi].data(), basis_sum_.data() + static_cast<size_t>(gi) * kFineMoments, nk,
             t.symmetric, b + j0, stride, gain, eps, t.e1[gi].data(), t.e2[gi].data(), top_g,
             sqrt_2_over_n, &r);
    for (int l = 0; l < kLanes; ++l) {
      if (!lane[l]) continue;
      const int j = j0 + l;
      if (!std::isfinite(r.y0[l])) {  // a sample is NaN or Inf: the finite ones alone
        fallback(j);
        continue;
      }
      if (!r.ok[l] || !std::isfinite(r.ssr[l])) {
        out[j] = InvalidFit(nk, f0);
        continue;
      }
      // Finalize (fixed frequency, converged, phase already in (-pi, pi]) without its
      // remainder() and atan2.
      // (a, the residual and the phase's sigma and SNR from FitBlock's lanes.)
      LensShiftFit& fit = out[j];
      const double a = r.amplitude[l];
      const double d = r.offset[l];
      fit.phase = r.phase[l];
      fit.amplitude = a;
      fit.frequency = f_grid + eps[l] / two_pi_x;
      fit.offset = d;
      fit.samples_used = nk;
      fit.iterations = 0;
      fit.converged = true;
      fit.residual_rms = r.residual_rms[l];
      double snr = 0.0;
      fit.phase_sigma = 0.0;
      if (nk > 3) {
        fit.phase_sigma = r.phase_sigma[l];
        snr = r.snr[l];
      }
      const bool finite = std::isfinite(fit.phase) && std::isfinite(a) &&
                          std::isfinite(fit.frequency) && std::isfinite(d) &&
                          std::isfinite(fit.residual_rms) && std::isfinite(fit.phase_sigma);
      fit.valid = finite && nk > 3 && a > options.min_amplitude &&
                  a > kMinRelativeAmplitude * std::abs(d) && snr >= options.min_amplitude_snr &&
                  std::abs(fit.frequency - f0) <= options.max_frequency_deviation * std::abs(f0);
      if (!fit.valid) {
        for (double* v : {&fit.phase, &fit.amplitude, &fit.frequency, &fit.offset,
                          &fit.residual_rms, &fit.phase_sigma})
          if (!std::isfinite(*v)) *v = 0.0;
      }
    }
  }
}

double LensShiftPhaseCrlbAt(double sigma, double amplitude, const std::vector<double>& x, double f,
                            double phase, bool fit_frequency) {
  // Fisher information F = J^T J / sigma^2 of b = a sin(phi + 2 pi f x) + d, columns
  // d/dphi = a cos psi, d/da = sin psi, d/df = 2 pi x a cos psi, d/dd = 1.
  Eigen::Matrix4d jtj = Eigen::Matrix4d::Zero();
  for (double xk : x) {
    const double psi = phase + kTwoPi * f * xk;
    const Eigen::Vector4d j(amplitude * std::cos(psi), std::sin(psi),
                            kTwoPi * xk * amplitude * std::cos(psi), 1.0);
    jtj += j * j.transpose();
  }
  if (!fit_frequency) {
    Eigen::Matrix3d m;
    const int idx[3] = {0, 1, 3};
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) m(r, c) = jtj(idx[r], idx[c]);
    return sigma * sigma * m.inverse()(0, 0);
  }
  return sigma * sigma * jtj.inverse()(0, 0);
}

double LensShiftPhaseCrlb(double sigma, double amplitude, const std::vector<double>& x, double f,
                          bool fit_frequency) {
  // var(phi) is a smooth periodic function of phi (harmonics of 2 phi from sin^2, cos^2): 64
  // evenly spaced phases average it exactly to rounding for all practical x.
  constexpr int kPhases = 64;
  double s = 0.0;
  for (int i = 0; i < kPhases; ++i)
    s += LensShiftPhaseCrlbAt(sigma, amplitude, x, f, kTwoPi * i / kPhases, fit_frequency);
  return s / kPhases;
}

}  // namespace mesoscan
