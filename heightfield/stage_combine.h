#pragma once
// Reconstruction stage 6, combine: the codecs' per-pixel records (heightfield/codec.h) into the
// projector coordinate u of every kActive pixel: the absolute codec's coordinate (phase shifting:
// its periods unwrapped with the per-sample noise of the refinement's fits where there are any),
// refined by the periodic codec (the lens shift: paper Eq. 2, u = P (round(u_c / P - phi) + phi),
// phi in cycles, P = 2 px), its sigma, and the confidence (the periodic codec's paper Eq. 4,
// times the combination and the absolute codec's consistency; the absolute codec's own where it
// decides alone). Moves pixels to kUnwrapFailed, kCombination or kLowConfidence.

#include <vector>

#include "heightfield/codec.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_lens_shift.h"
#include "heightfield/stage_phase_shift.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct CombineOptions {
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

// The combination of an absolute codec's coordinate with a periodic codec's phase (refinement:
// nullptr for the absolute codec alone), with `level` the pixels' white level (the noise floor:
// 1e-4 of it).
CombinedPixels CombineCodecs(const Codec& absolute, const Codec* refinement,
                             const std::vector<float>& level, const CombineOptions& options,
                             PixelStates* state);

// The scan's codecs: phase shifting (absolute; with ps.u_unwrapped its fringe orders come from
// it) refined by the lens shift (`ls` empty: phase shifting alone).
CombinedPixels CombinePhases(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const LensShiftPixels& ls, const CombineOptions& options,
                             PixelStates* state, const PhaseShiftStageOptions& phase_shift = {});

// Stage 6b: moves the kActive pixels of small regions of consistent u (CombineOptions::
// isolated_max_region_px) to kIsolated, their u to NaN and their confidence to 0.
void RejectIsolatedColumns(const RoiGrid& grid, const CombineOptions& options,
                           CombinedPixels* combined, PixelStates* state);

// std::lround(v) for |v| < 2^31 (half-way cases away from zero) without the libm call.
long RoundHalfAway(double v);
// std::round(v), the same bits for every double (NaN and beyond 2^52 by std::round itself).
double RoundHalfAwayD(double v);

}  // namespace mesoscan
