#pragma once
// Per-pixel lens-shift profile fitting (Ritz et al., Computers & Graphics 36, 2012, Sec. 4-5).
//
// While the lens shifter moves the projected one-pixel stripes, a camera pixel sees the profile
//   b(x) = a sin(phi + 2 pi f x) + d                                            (paper Eq. 1)
// over the shift positions x (projector pixels). The caller references x to the CENTRE of the
// shift range, so phi is the phase at the centre: for centred x the Fisher information of phi
// decouples from f and fitting f costs (almost) nothing in var(phi). The frequency f varies over
// the image (lens-shifter gain); its nominal value f0 = 1/period (0.5 cycles/px for 2-px stripes)
// may have either sign (the caller's convention).
//
// Three fitters reach the same least-squares minimum over (phi, a, f, d):
//  - kFast: variable projection. The linear part (a sin phi, a cos phi, d) is solved in closed
//    form for a given f from per-pixel moments sum b x^m e^{i 2 pi f_j x} (Taylor in f around a
//    grid frequency f_j near f0, shared tables precomputed once per batch), then a safeguarded
//    1-D Newton on f (its first step from f0 a Halley step: the third derivative there is free)
//    maximises the projected energy without touching the data again.
//  - kLm: the paper's two-step Levenberg-Marquardt (step 1: phase only, a = 1, f = f0 on the
//    normalised profile; step 2: all four parameters), hand-written with fixed-size Eigen 4x4.
//  - kCeres: the same 4-parameter least squares through Ceres with autodiff (the reference;
//    one Problem per profile: slow by design).
//
// Failures are values: no fitter throws on data (NaN/Inf samples, constant or clipped profiles,
// pure noise). A result with valid == false has no meaning; the pipeline gives it confidence 0.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace mesoscan {

enum class LensShiftFitter { kFast, kLm, kCeres };

// "fast", "lm", "ceres".
const char* LensShiftFitterName(LensShiftFitter fitter);
// Inverse of LensShiftFitterName; throws Error(kUsage) at the options field `option` otherwise.
LensShiftFitter ParseLensShiftFitter(const std::string& name,
                                     const std::string& option = "LensShiftStageOptions.fitter");

struct LensShiftFitOptions {
  // Which solver; all three minimise the same least-squares objective.
  LensShiftFitter fitter = LensShiftFitter::kFast;
  // Iteration cap of the solver (Newton steps on f for kFast, LM steps per stage for kLm, Ceres
  // iterations for kCeres), >= 1. Every fitter stops after at most this many.
  int max_iterations = 20;
  // Convergence: stop when a step changes f by less than this (cycles per projector px), > 0.
  double frequency_tolerance = 1e-7;
  // kFast also stops once the error left after its last Newton step (~4 step^2) is below this
  // fraction of the frequency's standard error (estimated from the residual and the curvature
  // of the objective), >= 0; 0: frequency_tolerance alone. A frequency error of 1e-3 of its
  // noise moves phi by far less: phi at the centred x = 0 is decoupled from f to first order.
  // Noise-free profiles have a zero standard error, so frequency_tolerance still holds there.
  double frequency_tolerance_sigma = 1e-2;
  // Fit the per-pixel frequency (4 parameters). false: f stays at the starting frequency and
  // only (phi, a, d) are fitted (3 parameters, a linear problem).
  bool fit_frequency = true;
  // A fitted f outside f0 * (1 +- max_frequency_deviation) marks the fit invalid (the minimum is
  // a side lobe or noise), in (0, 1).
  double max_frequency_deviation = 0.5;
  // valid requires the amplitude to stand out of the noise: a / sigma_a >= min_amplitude_snr,
  // with sigma_a = sigma_hat sqrt(2 / n) and sigma_hat the residual standard deviation
  // (n - p degrees of freedom). Pure noise gives a / sigma_a ~ Rayleigh(1): 4 rejects it with
  // probability ~1 - 3e-4 (fixed f). >= 0.
  double min_amplitude_snr = 4.0;
  // valid requires a > min_amplitude (data units, >= 0) and a > 1e-5 |d| (float rounding of a
  // constant profile).
  double min_amplitude = 0.0;
  // kFast only: accumulate the per-pixel moments in double (true) or float (false). Both work
  // on the mean-centred profile. Measured (bench_fitters, lens_shift_fit_test): float moves the
  // phase by <= 1.8e-7 rad (N 50-200, offset / amplitude 100, a / sigma 1000: <= 0.2 % of
  // sigma_phi), but its rounding enters SSR = sum y^2 - J directly and lifts the residual_rms
  // floor from 7.4e-5 a to ~3e-4 a, for a speed gain within the noise of our measurements.
  // Double is the default.
  bool double_accumulation = true;

  void Check() const;  // throws mesoscan::Error (bad input) naming the offending field
};

struct LensShiftFit {
  double phase = 0.0;         // phi at x = 0, radians, wrapped to (-pi, pi]
  double amplitude = 0.0;     // a >= 0, data units
  double frequency = 0.0;     // f, cycles per unit of x (projector px)
  double offset = 0.0;        // d, data units
  double residual_rms = 0.0;  // sqrt(sum of squared residuals / samples_used), data units
  // Standard deviation of phase predicted from the residual: sigma_hat sqrt(2 / n) / a with
  // sigma_hat^2 = SSR / (n - p) (the CRLB with the estimated noise; radians).
  double phase_sigma = 0.0;
  int samples_used = 0;  // finite samples that entered the fit
  int iterations = 0;    // solver iterations spent (all stages)
  bool converged = false;
  bool valid = false;  // every field finite and meaningful; false: ignore the fit
};

// Fits one profile: n samples b[i * stride] at positions x[i]. Non-finite samples are left out
// (the fit uses the rest). f0: starting / nominal frequency. Allocates: for batches use
// LensShiftBatchFitter.
LensShiftFit FitLensShiftProfile(const float* b, const double* x, int n, double f0,
                                 const LensShiftFitOptions& options, int stride = 1);

// All pixels of a capture share the shift positions x; this precomputes what depends only on x
// and f0 once (kFast: Taylor moment tables on a grid of frequencies around f0).
// Fit() is const, thread-safe and allocation-free for kFast and kLm (kCeres allocates its
// Problem per call). Profiles with non-finite samples fall back to the per-profile path.
// FitMany() fits many profiles with the same results, four at a time in vector lanes (the
// 4-parameter kFast fit about 2x cheaper per profile).
class LensShiftBatchFitter {
 public:
  // x: n >= 1 finite positions (projector px, referenced to the centre of the shift range);
  // f0 != 0. Throws mesoscan::Error (bad input) otherwise or if options.Check() fails.
  LensShiftBatchFitter(std::vector<double> x, double f0, const LensShiftFitOptions& options);

  // Samples b[i * stride], i in [0, num_samples()).
  LensShiftFit Fit(const float* b, int stride = 1) const;
  // Same with a per-pixel starting frequency f_start (e.g. a smoothed frequency map for a second
  // pass with fit_frequency == false); validity bounds stay relative to f0.
  LensShiftFit Fit(const float* b, int stride, double f_start) const;

  // Fit(b_p, sample_stride) of `count` profiles: profile p's samples are
  // b[p * profile_stride + k * sample_stride]; out[p] equals Fit's result to rounding. With kFast
  // and fit_frequency (the 4-parameter fit, double accumulation, 5..512 samples) four profiles
  // share the lanes of one vector through the Newton iterations, so the fixed work per profile
  // (Taylor evaluations, divisions, square roots) is paid once per four; a profile that leaves
  // the common case (NaN / Inf samples, a step that needs halving or re-centring) is refitted by
  // Fit. Any other configuration loops over Fit. Thread-safe, allocation-free.
  void FitMany(const float* b, std::ptrdiff_t profile_stride, int sample_stride, int count,
               LensShiftFit* out) const;

  int num_samples() const;
  const std::vector<double>& positions() const;
  double nominal_frequency() const;
  const LensShiftFitOptions& options() const;

  struct Tables;  // implementation detail (lens_shift_fit.cc)

 private:
  friend class LensShiftRowFitter;
  std::vector<double> x_;
  double f0_;
  LensShiftFitOptions options_;
  std::shared_ptr<const Tables> tables_;  // immutable, shared by copies
};

// The fixed-frequency fit (3 parameters: phi, a, d at a given f) of many pixels at once: the
// pipeline's main pass, every pixel of an image row with its frequency held at a smooth map.
// Same least-squares problem and the same method as LensShiftBatchFitter (fit_frequency false,
// kFast): the moments of the mean-centred profile against the basis rows of the grid frequency
// nearest to f, then the closed-form solve at f. Here four pixels that share a grid frequency
// are accumulated together in SIMD lanes (the samples of a row are frame-major, so a lane load
// is one contiguous load) and solved together; results equal LensShiftBatchFitter::Fit's to
// rounding (summation order). Pixels with non-finite samples, a non-finite frequency or one
// off the tables, and the pixels of a 4-pixel block whose grid frequency differs from the
// block's, go through LensShiftBatchFitter::Fit.
class LensShiftRowFitter {
 public:
  // As LensShiftBatchFitter; options.fitter must be kFast and options.fit_frequency false
  // (throws mesoscan::Error, bad input, otherwise).
  LensShiftRowFitter(std::vector<double> x, double f0, const LensShiftFitOptions& options);

  // Pixels j in [0, n) with use[j] != 0: samples b[k * stride + j] (frame k) times gain[k]
  // (rounded to float, as a gain-normalised frame would be), starting frequency f[j]; the fit
  // into out[j] (untouched where use[j] == 0). Thread-safe, allocation-free unless a pixel
  // falls back to LensShiftBatchFitter::Fit with more than 512 samples.
  void FitRow(const float* b, size_t stride, int n, const float* gain, const float* f,
              const uint8_t* use, LensShiftFit* out) const;

  int num_samples() const { return batch_.num_samples(); }
  const LensShiftBatchFitter& batch_fitter() const { return batch_; }

 private:
  LensShiftBatchFitter batch_;
  // Per grid point of the fixed-frequency tables, the 8 basis rows' sums over the samples.
  std::vector<double> basis_sum_;
};

// Cramer-Rao lower bound on var(phi) (rad^2) for the model above with white Gaussian noise of
// standard deviation sigma at positions x: [F^-1]_phi,phi of the exact Fisher information
// F = J^T J / sigma^2 (J: derivatives by phi, a, f, d; by phi, a, d if !fit_frequency).
// For centred uniform x it is ~ 2 sigma^2 / (N a^2).
double LensShiftPhaseCrlbAt(double sigma, double amplitude, const std::vector<double>& x, double f,
                            double phase, bool fit_frequency = true);
// Average of LensShiftPhaseCrlbAt over phase uniform in [0, 2 pi): the bound for a pooled
// variance over random phases.
double LensShiftPhaseCrlb(double sigma, double amplitude, const std::vector<double>& x, double f,
                          bool fit_frequency = true);

}  // namespace mesoscan
