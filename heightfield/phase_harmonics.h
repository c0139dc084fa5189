#pragma once
// Harmonics-aware phase shifting. A projector whose response is not linear (a gamma, or any
// monotone curve) shows each sine 0.5 + 0.5 cos(phi) as f(0.5 + 0.5 cos phi), which is even in
// phi: in units of its fundamental, cos phi + sum_n h_n cos(n phi). With few phase steps the
// harmonics alias onto the fundamental (three steps: n = 2, 4, 5, ... ) and the least-squares
// phase of a period is off by a function of the phase alone, the same at every pixel (the
// response is the projector's): theta_measured = F_p(theta). Defocus blurs the projected light
// after the response, attenuating harmonic n of period P by exp(-(2 pi sigma / P)^2 (n^2 - 1) / 2)
// relative to the fundamental (one global sigma).
//
// EstimateProjectorHarmonics fits h_2..h_6 and sigma from the capture itself: at pixels spread
// over the image, the periods' measured phases must all come from one projector coordinate u;
// the fit (Ceres, robust loss, u free per pixel) finds the harmonics that make them agree.
// CorrectPhaseHarmonics then replaces every pixel's phase by F_p^-1 of it (a table per period)
// and its modulation by the information-equivalent one (measured x F_p': the corrected phase's
// predicted sigma), so the periods' unwrapping and the consistency test
// judge fringe orders, not the projector's harmonics.

#include <cstdint>
#include <string>
#include <vector>

#include "core/json.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

enum class HarmonicsMode {
  kAuto,  // estimated; applied where the response is clearly non-linear
  kOn,    // estimated and applied whenever the fit holds
  kOff,   // the plain decode (the phases as the solver gives them)
};

struct HarmonicsOptions {
  HarmonicsMode mode = HarmonicsMode::kAuto;
  // Pixels the fit samples (spread evenly over the kActive ones), >= 100.
  int sample_pixels = 1500;
  // kAuto: applied where the plain decode's phase error that the fit predicts (RMS over the
  // phase, worst period) exceeds this, rad, and is at least min_significance times its standard
  // error (the fit's residual over the square root of the residuals).
  double min_phase_error_rad = 0.005;
  double min_significance = 20.0;
  void Check() const;
};

// Harmonic orders fitted: n = 2 .. kMaxHarmonic.
inline constexpr int kMaxHarmonic = 6;

struct ProjectorHarmonics {
  bool fitted = false;   // the fit ran and converged
  bool applied = false;  // the phases were corrected with it
  std::string reason;    // why not fitted or not applied (empty if applied)
  // h_n relative to the fundamental, n = 2 .. kMaxHarmonic (at focus: no blur).
  std::vector<double> harmonics;
  double blur_px = 0.0;  // the defocus sigma that attenuates them, projector px
  // The pure power law v^gamma whose phase errors are nearest to the fit's, and the RMS of the
  // difference (rad, worst period): how far the response is from a gamma.
  double gamma = 1.0;
  double gamma_misfit_rad = 0.0;
  // Per plan period: the plain decode's phase error that the fit predicts, RMS over the phase.
  std::vector<double> phase_error_rms_rad;
  double residual_rms_rad = 0.0;  // robust RMS of the fit's phase residuals
  int64_t pixels = 0;             // pixels the fit used
  Json ToJson() const;
};

// The fit (no change to ps). Needs two or more periods that unwrap (plan.periods_unwrap); else
// fitted = false with the reason.
ProjectorHarmonics EstimateProjectorHarmonics(const ReconstructPlan& plan,
                                              const PhaseShiftPixels& ps, const PixelStates& state,
                                              const HarmonicsOptions& options);

// The phase a period's least-squares solver reports at true phase theta (radians) under the
// harmonics of `h` (its harmonics and blur), for period `period` px and phase steps `deltas`.
double HarmonicPhase(const ProjectorHarmonics& h, double period, const std::vector<double>& deltas,
                     double theta);

// Replaces theta and modulation of every kActive pixel by the fundamental's (F_p^-1 by a table
// per period). Returns false (ps unchanged, h->reason set) if some period's F_p is not monotone
// (harmonics too strong for its steps to be undone).
bool CorrectPhaseHarmonics(const ReconstructPlan& plan, const PixelStates& state,
                           ProjectorHarmonics* h, PhaseShiftPixels* ps);

}  // namespace mesoscan
