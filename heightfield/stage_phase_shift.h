#pragma once
// Reconstruction stage 3, phase shifting: per period the least-squares wrapped phase, modulation
// and residual of every kActive pixel (heightfield/phase_shift.h WrappedPhaseSolver), with the
// projector's gamma undone per sample when white/black frames give the scale. Moves pixels to
// kUnlit (no white frame: 2 x offset < min_lit) or kUnmodulated (modulation < min_modulation x
// white level of any period).

#include "heightfield/frames.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct PhaseShiftStageOptions {
  double min_lit = 0.02;         // as ClassifyOptions::min_lit
  double min_modulation = 0.05;  // B / white level, in (0, 0.5]
  double projector_gamma = 1.0;  // the rig's projector response (1: linear)
};

PhaseShiftPixels DecodePhaseShift(const FrameStack& stack, const ReconstructPlan& plan,
                                  const FrameGains& gains, const PixelClasses& classes,
                                  const PhaseShiftStageOptions& options, PixelStates* state);

}  // namespace mesoscan
