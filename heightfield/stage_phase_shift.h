#pragma once
// Reconstruction stage 4, phase shifting: per period the least-squares wrapped phase, modulation
// and residual of every kActive pixel (heightfield/phase_shift.h WrappedPhaseSolver), with the
// projector's gamma (ReconstructPlan::projector_gamma) undone per sample when white/black frames
// give the scale. Moves pixels to kUnlit (no white frame: 2 x offset < the classify stage's
// min_lit) or kUnmodulated (modulation < min_modulation x white level of any period).

#include "heightfield/frames.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct PhaseShiftStageOptions {
  // Phase-shift modulation B / white level >= min_modulation, in (0, 0.5]; a full-contrast sine
  // gives 0.5.
  double min_modulation = 0.05;
  void Check() const;
};

PhaseShiftPixels DecodePhaseShift(const FrameStack& stack, const ReconstructPlan& plan,
                                  const FrameGains& gains, const PixelClasses& classes,
                                  const PhaseShiftStageOptions& options, PixelStates* state);

}  // namespace mesoscan
