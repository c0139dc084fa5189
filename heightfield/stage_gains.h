#pragma once
// Reconstruction stage 2, luminance gains (Ritz et al. 2012, Sec. 5.1: the camera's brightness
// jitters from frame to frame): per-frame gains estimated on a subsample of ~20000 kActive pixels
// (heightfield/frames.h EstimateFrameGains), sine frames and lens-shift frames as two groups.
// The later stages multiply every sample of stack frame k by inv_gain[k]. This is the hook for
// per-frame corrections estimated elsewhere (e.g. jointly with shifter positions): any stage
// between this one and the decoding stages may refine `inv_gain`.

#include <vector>

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
};

FrameGains EstimateLuminanceGains(const FrameStack& stack, const ReconstructPlan& plan,
                                  const PixelStates& state, size_t session_frames,
                                  const GainOptions& options);

// The same for one group (sine frames or lens-shift frames) into *gains (sized by
// UnitGains): the driver estimates the sine frames' gains while the lens-shift frames decode.
// The group's frames must be in `stack`; the sample is drawn from `state` as above.
enum class GainGroup { kPhaseShift, kLensShift };
FrameGains UnitGains(const ReconstructPlan& plan, size_t session_frames);
void EstimateLuminanceGains(const FrameStack& stack, const ReconstructPlan& plan,
                            const PixelStates& state, GainGroup group, const GainOptions& options,
                            FrameGains* gains);

}  // namespace mesoscan
