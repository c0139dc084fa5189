#pragma once
// Reconstruction stages 1-4 (decode, classify, gains, phase shift) as one stream: the
// lens-shift frames (most of a session) are decoded while the other frames (white, black, sine
// patterns) are classified, normalised and phase-shift decoded on the same TBB pool; the sine,
// white and black frames are released as soon as the phase shift is done, so that only the
// lens-shift frames stay for the stages that need whole profiles (frequency map, frame corrections,
// per-pixel fit). The lens-shift frames' gains follow once they are all in, from samples gathered
// as each of them decoded (GatheredSamples: the sine branch picks the pixels). With lens shift, the
// sine branch also unwraps the phase shift on its own (stage_phase_shift.h UnwrapPhaseShift: the
// fringe orders, ~0.25 CPU-s at full resolution, moved off the time after the last frame) and makes
// the lens-shift frames' phase reference. Equivalent to running decode, classify, gains and phase
// shift in turn, except that the sine gains' pixel sample cannot leave out pixels that are
// saturated in a lens-shift frame only (they are marked kSaturated afterwards, as classify would
// have).

#include <cstddef>

#include "heightfield/frames.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_classify.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_phase_shift.h"
#include "heightfield/stage_plan.h"
#include "session/session.h"

namespace mesoscan {

struct StreamStageOptions {
  FrameLoadOptions load;
  ClassifyOptions classify;
  GainOptions gains;
  PhaseShiftStageOptions phase_shift;
};

struct StreamedFrames {
  FrameStack stack;      // the lens-shift frames (every frame if the plan has none)
  PixelClasses classes;  // classify, then moved on by the phase shift; with a white frame
                         // white_level is moved to ps.level (see PhaseShiftPixels::level)
  FrameGains gains;      // sine and lens-shift frames
  PhaseShiftPixels ps;
  double decode_s = 0.0;       // when the last frame was decoded, s after the call
  double phase_shift_s = 0.0;  // when the overlapped sine-frame work was done, s after the call
};

StreamedFrames DecodeAndPhaseShift(const Session& session, const ReconstructPlan& plan,
                                   const StreamStageOptions& options);

}  // namespace mesoscan
