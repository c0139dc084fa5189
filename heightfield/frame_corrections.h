#pragma once
// Per-frame corrections of a lens-shift capture, estimated jointly with the per-pixel fits.
//
// Every camera pixel j sees the lens-shift profile
//   I_kj = g_k (d_j + alpha_j cos theta_kj + beta_j sin theta_kj) + noise,
//   theta_kj = 2 pi f_j (x_k + delta_k),
// with f_j the pixel's frequency (the smoothed frequency map), x_k the nominal shift positions
// (referenced to the centre of the range), g_k the frame's brightness gain (lamp, shutter) and
// delta_k the shifter's position error of frame k (missed steps, backlash, lead-screw
// non-linearity), both shared by all pixels of the frame.
//
// Why joint: the part of the gain jitter that lies in the band of each pixel's sinusoid (a cosine
// and a sine at f in the frame index) is absorbed by a per-pixel fit and biases its phase by
// ~ (d / a) * jitter; a frame mean or a few alternating least-squares steps from g = 1 leave it
// there. Multiplied by the pixel's own modulation that jitter also puts energy at 2 f (out of the
// band) with a phase that follows the pixel's phase, so over many pixels with different phases it
// is identifiable. EstimateFrameCorrections minimises the weighted least-squares objective over
// all frame parameters and all per-pixel coefficients together: Gauss-Newton on the frame
// parameters with the per-pixel coefficients eliminated exactly (Schur complement, variable
// projection), a handful of iterations from the given starting gains.
//
// Which information fixes the in-band gains (cos / sin of 2 pi f x over the frames): the
// profiles' 2 f signature is biased by the stripes' own harmonic (hence freeze_in_band_gains),
// frame means by the stripes left in the view's average (a 128x96 view of the tilted bar:
// 2.6e-3 of the level), alternating least squares cannot see them at all. What is unbiased is
// the phase: phase shifting predicts every pixel's lens-shift phase (PhaseConstraint), and an
// in-band gain error moves the fitted phases by (d / a) times a sinusoid of the phase, which no
// constant absorbs. With a reference the in-band gains are set from it (a weighted least-squares
// fit of the phase disagreement, with the constant between the cues and the phase-shift
// frames' own gain-error shapes as nuisance parameters, the estimate shrunk towards the start
// by how far it stands out of its own noise) and everything else as before, the in-band
// directions held.
//
// Gauges: the gains are normalised to mean 1 (a common scale is absorbed by every pixel's
// coefficients); the positions are identifiable up to an affine map x -> s0 + s1 x (the phase
// and the frequency map absorb it), so delta is returned orthogonal to {1, x}.

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/json.h"
#include "heightfield/frames.h"

namespace mesoscan {

// How the pipeline sets the gains of the lens-shift frames: the joint estimate (default), the
// alternating least squares of frames.h alone (the older behaviour), or frame means over
// the fitted pixels (the classic baseline).
enum class FrameGainMethod { kJoint, kAlternating, kFrameMeans };
const char* FrameGainMethodName(FrameGainMethod m);  // "joint", "als", "means"

struct FrameCorrectionOptions {
  FrameGainMethod method = FrameGainMethod::kJoint;
  bool estimate_gains = true;
  bool estimate_positions = true;
  int iterations = 6;  // Gauss-Newton iterations, >= 1
  // With gains: stop the position model after its first Gauss-Newton step where that step
  // predicts a drop of the objective too small for the model to be chosen (a score test; the
  // prediction is then FrameCorrections::position_chi2_gain). false: always solved in full.
  bool stop_position_model_early = true;
  // Keep the gains' components in the band of the sinusoid (cos / sin of 2 pi f x over the
  // frames) at their start instead of estimating them (see the .cc).
  // Default: kept. Measured on the simulator (coin, 15 frames, 2% jitter, gain error RMS of the
  // lens-shift frames): joint in-band 4.2e-3, frame means 9.0e-4, means with the out-of-band part
  // joint 9.0e-4; on harmonic-free synthetic profiles the joint in-band estimate reaches the
  // floor (frame_corrections_test). The stripes' own 2 f harmonic (duty cycle 0.45 at fill
  // factor 0.9) is the suspected bias of the in-band estimate.
  bool freeze_in_band_gains = true;
  // Pipeline hook: start from frame means over the fitted pixels (else from the given gains).
  bool start_from_frame_means = true;
  // ... but only where the view's stripes average out: |sum a e^{i phi}| / sum d over the
  // first-pass fits at most this (else the start is the given gains, in band too).
  // CorrectLensShiftFrames with FirstPassFits::amplitude only.
  double max_residual_stripe = 5e-3;
  // ... and at most this fraction of the RMS deviation of the frame-mean gains from 1 (the
  // jitter they would correct), so their bias stays well below what they remove, >= 0.
  double max_stripe_to_jitter = 0.25;
  int max_pixels = 12000;  // pixels used (a regular subsample of the candidates), >= 16
  // Positions beyond this many projector pixels from nominal mark the estimate as failed (the
  // nominal positions are kept), > 0.
  double max_position_error_px = 0.3;
  // Positions are kept only if their RMS reaches this (px): smaller errors cost nothing
  // measurable, and in-band gain jitter left in the gains can pose as such small positions.
  double min_position_rms_px = 0.003;
  // Gains outside [1 - this, 1 + this] likewise, in (0, 1).
  double max_gain_deviation = 0.3;
  // With a phase-shift reference: the in-band correction it gives is multiplied by a factor in
  // [0, 1], the posterior mean under a normal prior whose variance is the larger of the white
  // jitter the starting gains show and the estimate's own excess over its noise (empirical
  // Bayes, see the .cc). Without it the reference's noise is added to the gains where there is
  // no in-band jitter to correct (small views). false: applied in full.
  bool shrink_in_band_gains = true;
};

// The projector coordinate that phase shifting alone decoded at a sample of pixels: it predicts
// each pixel's lens-shift phase (phi = pi/2 - pi u at shift 0, stage_combine.cc) independently of
// the lens-shift frames' gains, which is what makes the in-band part of the gain jitter
// identifiable (see EstimateFrameCorrections). Built by stage_gains.h MakePhaseReference.
struct PhaseReference {
  std::vector<uint32_t> pixels;   // stack pixels
  std::vector<float> u_px;        // projector coordinate along the decoded axis, px
  std::vector<float> sigma_u_px;  // its predicted standard deviation, px
  // The phase-shift frames' own gain errors move u by a sinusoid of each period's phase (first
  // harmonic, scaled by offset / modulation, and second harmonic): per pixel, nuisance[q *
  // nuisance_per_pixel + m] are those shapes' derivatives of the predicted lens-shift phase
  // (radians per unit coefficient), fitted along with the in-band gains so that they do not
  // bias them.
  int nuisance_per_pixel = 0;
  std::vector<float> nuisance;
  double ls_centre_px = 0.0;  // the lens-shift positions' centre (the fit's x = 0), px
  // The lens-shift frames' samples at `pixels`, if the stream stage gathered them while the
  // frames decoded (else empty): CorrectLensShiftFrames reads them instead of the stack.
  GatheredSamples samples;
  bool empty() const { return pixels.empty(); }
};

// Per sample pixel of EstimateFrameCorrections: the predicted phase of the lens-shift profile at
// x = 0 in the fitter's convention (I = d + a sin(phi + 2 pi f x), heightfield/lens_shift_fit.h),
// up to one constant shared by all pixels (estimated), and its standard deviation; NaN: none.
struct PhaseConstraint {
  std::vector<double> phase;
  std::vector<double> sigma;
  int nuisance_per_pixel = 0;  // PhaseReference::nuisance, per pixel of phase
  std::vector<float> nuisance;
};

struct FrameCorrections {
  std::vector<double> gains;         // per frame, mean 1 (the starting gains if not estimated)
  std::vector<double> positions_px;  // per-frame position error delta_k, orthogonal to {1, x}
  int pixels_used = 0;
  int iterations = 0;
  // "gains" or "gains+positions" ("positions" if gains were not estimated): see the .cc on why
  // in-band gains and positions are not estimated together.
  std::string model;
  // The drop of the weighted objective when positions are added (predicted by their first step
  // where that stopped them, FrameCorrectionOptions::stop_position_model_early).
  double position_chi2_gain = 0.0;
  bool position_model_stopped = false;  // ... stopped after its first step (a score test)
  double view_residual_stripe = 0.0;    // see FrameCorrectionOptions::max_residual_stripe
  bool valid = false;                   // false: the starting gains and zero positions are returned
  double position_rms_px = 0.0;
  // The in-band gain components set from the phase-shift reference (PhaseConstraint): the
  // pixels used, the correction applied in the last round (relative gain along cos / sin of
  // 2 pi f x, after the shrinkage) and the estimate's standard error; in_band_pixels = 0:
  // in-band gains kept at their start.
  int in_band_pixels = 0;
  double in_band_correction[2] = {0.0, 0.0};
  double in_band_sigma = 0.0;
  double in_band_shrink = 0.0;  // the factor applied (shrink_in_band_gains; 1 without)
  Json ToJson() const;
};

// samples[j * nk + k]: frame k of pixel j (linear radiance, not gain-normalised), n pixels;
// freq[j] the pixel's frequency (cycles per projector px), x[k] the nominal positions,
// initial_gains[k] the starting gains (e.g. from frame means). Non-finite samples or frequencies
// drop the pixel; robust to outlier pixels (relative residual beyond median + 4 MAD). Never
// throws on data, never returns non-finite values.
FrameCorrections EstimateFrameCorrections(const std::vector<float>& samples, int nk,
                                          const std::vector<double>& freq,
                                          const std::vector<double>& x,
                                          const std::vector<double>& initial_gains,
                                          const FrameCorrectionOptions& options,
                                          const PhaseConstraint* reference = nullptr);

// The per-pixel frequency of stack pixel i (e.g. the smoothed frequency map evaluated there,
// NaN: none), asked for at the pixels used only.
using FrequencyAt = std::function<float(uint32_t)>;

// The same on frames `frames` (stack indices) of `stack` at stack pixels `pixels`, with the
// per-pixel frequency f_map(pixel); the samples from `gathered` where it holds those pixels'
// (in that order) for every one of the frames, of an integer stack.
FrameCorrections EstimateFrameCorrections(const FrameStack& stack, const std::vector<int>& frames,
                                          const std::vector<uint32_t>& pixels,
                                          const FrequencyAt& f_map, const std::vector<double>& x,
                                          const std::vector<double>& initial_gains,
                                          const FrameCorrectionOptions& options,
                                          const PhaseConstraint* reference = nullptr,
                                          const GatheredSamples* gathered = nullptr);

}  // namespace mesoscan

namespace mesoscan {

// Gains of `frames` as their means over `pixels`, normalised to mean 1; empty where undefined
// (no positive, finite total or a gain <= 0).
std::vector<double> FrameMeanGains(const FrameStack& stack, const std::vector<int>& frames,
                                   const std::vector<uint32_t>& pixels);

// The first (4-parameter) lens-shift pass's fits that CorrectLensShiftFrames reads, compact (the
// pass fits a sparse subsample): the stack pixels with a finite fitted frequency, in increasing
// order, and per entry the fit's amplitude, phase at shift 0 and offset (NaN: not valid).
struct FirstPassFits {
  std::vector<uint32_t> pixels;
  std::vector<float> amplitude, phase, offset;  // empty: no residual-stripe gate input
};

// Pipeline hook (between the frequency pass and the fixed-frequency pass of the lens-shift fit):
// estimates the corrections of frames `frames` on the pixels of `first` (f held at `f_map`),
// starting from gains 1 / inv_gain[frames[k]].
// If valid, writes the new gains into inv_gain (as 1 / g) and adds the positions to *x.
// With a non-empty `reference` (kJoint): on the reference's pixels instead, starting from the
// given gains, in-band gains from the reference (no frame means, no gate); without one, or with
// too few usable reference pixels (200 + 10 per nuisance parameter), as before: frame means
// where the view's residual stripe allows, else the given gains kept.
FrameCorrections CorrectLensShiftFrames(const FrameStack& stack, const std::vector<int>& frames,
                                        const FirstPassFits& first, const FrequencyAt& f_map,
                                        std::vector<double>* x, std::vector<float>* inv_gain,
                                        const FrameCorrectionOptions& options,
                                        const PhaseReference* reference = nullptr);

}  // namespace mesoscan
