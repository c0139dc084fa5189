#pragma once
// Reconstruction stage 4, phase shifting, the absolute codec of the sine frames
// (heightfield/codec.h): per period the least-squares wrapped phase, modulation and residual of
// every kActive pixel (heightfield/phase_shift.h WrappedPhaseSolver), with the projector's gamma
// (ReconstructPlan::projector_gamma) undone per sample when white/black frames give the scale.
// Moves pixels to kUnlit (no white frame: 2 x offset < the classify stage's min_lit) or
// kUnmodulated (modulation < min_modulation x white level of any period). The periods' temporal
// or hierarchical unwrapping (TemporalUnwrapper) gives the absolute coordinate
// (PhaseShiftCodec, read by the combine stage; UnwrapPhaseShift, its fringe orders made early).

#include <optional>
#include <vector>

#include "heightfield/codec.h"
#include "heightfield/frames.h"
#include "heightfield/phase_harmonics.h"
#include "heightfield/phase_shift.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct PhaseShiftStageOptions {
  // Phase-shift modulation B / white level >= min_modulation, in (0, 0.5]; a full-contrast sine
  // gives 0.5.
  double min_modulation = 0.05;
  // Temporal unwrapping: the consistency residual (heightfield/phase_shift.h, RMS over periods
  // of the weighted circular residual in sigma units, ~1 for consistent data) above which a
  // pixel is rejected (kUnwrapFailed), > 0.
  double max_unwrap_residual = 4.0;
  // Phase error (radians per period) added in quadrature to each period's noise-predicted phase
  // variance before unwrapping: model errors that noise does not explain (projector harmonics,
  // defocus, residual brightness jitter), >= 0.
  double systematic_phase_noise = 0.02;
  // The projector's response estimated from the phases and undone (heightfield/phase_harmonics.h)
  // where it is clearly non-linear (kAuto).
  HarmonicsOptions harmonics;
  void Check() const;
};

PhaseShiftPixels DecodePhaseShift(const FrameStack& stack, const ReconstructPlan& plan,
                                  const FrameGains& gains, const PixelClasses& classes,
                                  const PhaseShiftStageOptions& options, PixelStates* state);

// The phase-shift stage's output as an absolute codec: the coordinate unwrapped from the
// periods' phases with weights from each pixel's per-sample noise (the lens-shift residual where
// the combine stage has it: many samples), at the fringe orders of ps.u_unwrapped where they
// hold (else the full search); its sigma from the periods' Fisher information and its confidence
// from the phase-shift residuals (paper Eq. 4 on the worst period). Views plan and ps, which
// must outlive it. Throws Error (bad input) if the periods cannot be unwrapped over the
// projector (TemporalUnwrapper).
class PhaseShiftCodec final : public Codec {
 public:
  // confidence_t: paper Eq. 4's t (CombineOptions::confidence_t).
  PhaseShiftCodec(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                  const PhaseShiftStageOptions& options, double confidence_t = 4.0);
  const char* Name() const override { return "phase_shift"; }
  // Absolute where the periods unwrap (ReconstructPlan::periods_unwrap), else periodic: the
  // phase of the one period, whose order a planned codec fixes.
  CodecKind Kind() const override {
    return unwrapper_ ? CodecKind::kAbsolute : CodecKind::kPeriodic;
  }
  double PeriodPx() const override { return unwrapper_ ? 0.0 : plan_.periods[0].period; }
  std::vector<int> Frames() const override;
  // Every pixel: the phase-shift residuals (periods of K > 3 frames), else 1% of the level.
  void SampleNoise(const size_t* pixels, size_t n, double* sigma) const override;
  void Decode(const size_t* pixels, size_t n, const double* noise, CodecRecord* out) const override;
  void Describe(const size_t* pixels, const double* noise, const uint32_t* which, size_t m,
                bool refined, CodecRecord* out) const override;

 private:
  const ReconstructPlan& plan_;
  const PhaseShiftPixels& ps_;
  PhaseShiftStageOptions options_;
  double confidence_t_;
  std::optional<TemporalUnwrapper> unwrapper_;  // absolute only
  std::vector<WrappedPhaseSolver> solvers_;
};

// Phase shifting's own absolute column: u of every kActive pixel, unwrapped with the noise the
// phase-shift frames show (their residuals, else 1% of the white level), in 16 bits
// (ColumnHints: a fraction of a period is all the fringe orders need), none where the unwrapping
// fails or elsewhere; empty if the plan has no periods. The stream stage runs it while the
// lens-shift frames still decode, and PhaseShiftCodec then takes each pixel's fringe orders from
// it (PhaseShiftPixels::u_unwrapped) instead of searching them again: only the weighted mean and
// its residual wait for the lens-shift noise. The same result wherever both noise estimates pick
// the same orders; the full search where the orders fail with the final weights.
ColumnHints UnwrapPhaseShift(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const PixelStates& state, const PhaseShiftStageOptions& options);

}  // namespace mesoscan
