#pragma once
// Reconstruction stage 6, combine: per kActive pixel the noise sigma (from the lens-shift or
// phase-shift residuals), temporal/hierarchical unwrapping of the periods' wrapped phases
// (heightfield/phase_shift.h TemporalUnwrapper) to the coarse column u_c, the combination with the
// lens-shift fine phase (paper Eq. 2: u = 2 (round(u_c / 2 - phi) + phi), phi in cycles), and the
// confidence (paper Eq. 4, times the combination and unwrapping consistency). Moves pixels to
// kUnwrapFailed, kCombination or kLowConfidence.

#include <vector>

#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct CombineOptions {
  // Temporal unwrapping: the consistency residual (heightfield/phase_shift.h, RMS over periods
  // of the weighted circular residual in sigma units, ~1 for consistent data) above which a
  // pixel is rejected, > 0.
  double max_unwrap_residual = 4.0;
  // Phase error (radians per period) added in quadrature to each period's noise-predicted phase
  // variance before unwrapping: model errors that noise does not explain (projector harmonics,
  // defocus, residual brightness jitter), >= 0.
  double systematic_phase_noise = 0.02;
  // Combination (paper Eq. 2): |u_coarse - u| above this (px; the fine period is 2 px, so 1 is
  // the ambiguity limit) rejects the pixel as a period jump, in (0, 1).
  double max_combination_residual_px = 0.6;
  // Paper Eq. 4: c = 1 - sqrt(E t), clamped to [0, 1], with E the mean squared residual of the
  // profile in units of its fitted amplitude (E = (rms / a)^2: pure noise of the same size as the
  // signal gives E = 1). t = 4 reaches c = 0 at rms = a / 2. > 0.
  double confidence_t = 4.0;
  // Points with confidence below this are rejected (NaN, confidence 0), in [0, 1).
  double min_confidence = 0.05;
  // Graceful defocus: with lens shift, a pixel whose lens-shift fit failed or fell below
  // min_confidence (defocus blurred the 2-px stripes away) takes the phase-shift estimate of u
  // instead, with its own predicted sigma (systematic_phase_noise included) and its confidence
  // scaled by phase_shift_fallback_confidence, in (0, 1]; points.exr `source` = 1 there.
  bool phase_shift_fallback = true;
  double phase_shift_fallback_confidence = 0.5;
  // Where the lens-shift stage estimated the shifter positions (frame_corrections
  // model with "positions"), they are known only up to an affine map: the per-pixel frequency
  // absorbs its slope, but its constant (the mean position error of the lens-shift frames against
  // the calibrated shift 0) moves every lens-shift u alike. The phase-shift frames, taken at
  // shift 0, fix it: the median of u_coarse - u over the lens-shift pixels (>= 1000) is added to
  // their u (CombinedPixels::ls_offset_px).
  bool reference_positions_to_phase_shift = true;
  // RejectIsolatedColumns: a 4-connected region of pixels whose u differ from a neighbour's by at
  // most isolated_max_step_px is kept only if it has more than isolated_max_region_px pixels
  // (OpenCV's filterSpeckles). A wrong fringe order moves u by several px at random, so where
  // noise makes the unwrapping guess, the guesses do not join their neighbours; a surface seen
  // by the camera is a region of many pixels. 0 turns it off; step in (0, smallest period / 2).
  int isolated_max_region_px = 16;
  double isolated_max_step_px = 3.0;
  // Keep CombinedPixels::u_coarse and unwrap_residual (the diagnostics); false: left empty
  // unless the positions' reference above needs u_coarse (2 arrays of 12.5 MB at 3 Mpx less to
  // fill and write). The pipeline sets it from ReconstructOptions::keep_diagnostics.
  bool keep_coarse = true;
  void Check() const;
};

// Phase shifting's own absolute column: u of every kActive pixel, unwrapped with the
// noise the phase-shift frames show (their residuals, else 1% of the white level), in 16 bits
// (ColumnHints: a fraction of a period is all the fringe orders need), none where the unwrapping
// fails or elsewhere; empty if the plan has no periods. The stream stage runs it while
// the lens-shift frames still decode, and CombinePhases then takes each pixel's fringe orders
// from it (PhaseShiftPixels::u_unwrapped) instead of searching them again: only the weighted
// mean and its residual wait for the lens-shift noise. The same result wherever both noise
// estimates pick the same orders; the full search where the orders fail with the final weights.
ColumnHints UnwrapPhaseShift(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const PixelStates& state, const CombineOptions& options);

// `ls` may be empty (phase shifting alone). With ps.u_unwrapped (UnwrapPhaseShift), the fringe
// orders come from it.
CombinedPixels CombinePhases(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const LensShiftPixels& ls, const CombineOptions& options,
                             PixelStates* state);

// Stage 6b: moves the kActive pixels of small regions of consistent u (CombineOptions::
// isolated_max_region_px) to kIsolated, their u to NaN and their confidence to 0.
void RejectIsolatedColumns(const RoiGrid& grid, const CombineOptions& options,
                           CombinedPixels* combined, PixelStates* state);

// std::lround(v) for |v| < 2^31 (half-way cases away from zero) without the libm call.
long RoundHalfAway(double v);
// std::round(v), the same bits for every double (NaN and beyond 2^52 by std::round itself).
double RoundHalfAwayD(double v);

}  // namespace mesoscan
