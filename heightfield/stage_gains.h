#pragma once
// Reconstruction stage 3, luminance gains (Ritz et al. 2012, Sec. 5.1: the camera's brightness
// jitters from frame to frame): per-frame gains estimated on a subsample of ~20000 kActive pixels
// (heightfield/frames.h EstimateFrameGains), sine frames and lens-shift frames as two groups.
// The later stages multiply every sample of stack frame k by inv_gain[k]. This is the hook for
// per-frame corrections estimated elsewhere (e.g. jointly with shifter positions): any stage
// between this one and the decoding stages may refine `inv_gain`.

#include <vector>

#include "heightfield/frame_corrections.h"
#include "heightfield/frames.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct GainOptions {
  // false: every gain is 1.
  bool normalize_luminance = true;
};

struct FrameGains {
  std::vector<float> inv_gain;       // per stack frame: 1 / gain
  std::vector<double> session_gain;  // per session frame (1 where not estimated)
  // For the lens-shift stage's frame corrections: the projector coordinate from
  // phase shifting alone at a sample of pixels (MakePhaseReference); empty if not made.
  PhaseReference phase_reference;
};

FrameGains EstimateLuminanceGains(const FrameStack& stack, const ReconstructPlan& plan,
                                  const PixelStates& state, size_t session_frames,
                                  const GainOptions& options);

// The same for one group (sine frames or lens-shift frames) into *gains (sized by
// UnitGains): the driver estimates the sine frames' gains while the lens-shift frames decode.
// The group's frames must be in `stack`; the sample is drawn from `state` as above.
enum class GainGroup { kPhaseShift, kLensShift };
FrameGains UnitGains(const ReconstructPlan& plan, size_t session_frames);

// The gains' pixel sample: every stride-th kActive pixel of `state` (about 20000), increasing.
std::vector<uint32_t> GainSample(const PixelStates& state);

// With `ps` (the phase-shift stage's output) the lens-shift group also makes
// gains->phase_reference from it. With `gathered` (the lens-shift frames' samples at
// GainSample(state), collected while they decoded; used if complete and the stack holds integer
// frames) the lens-shift group reads those instead of gathering them from the stack: the same
// gains.
void EstimateLuminanceGains(const FrameStack& stack, const ReconstructPlan& plan,
                            const PixelStates& state, GainGroup group, const GainOptions& options,
                            FrameGains* gains, const PhaseShiftPixels* ps = nullptr,
                            const GatheredSamples* gathered = nullptr);

// The projector coordinate decoded by phase shifting alone (temporal unwrapping as in the
// combine stage, per-sample noise 1% of the pixel's level) at a scattered sample of about
// max_pixels of the pixels that are kActive in `state` with every period decoded and modulated
// (modulation >= 5% of the level); pixels whose unwrapping is inconsistent are left out.
// Empty without lens shift or when the periods cannot be unwrapped (the combine stage reports
// that).
PhaseReference MakePhaseReference(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                                  const PixelStates& state, int max_pixels = 12000);

}  // namespace mesoscan
