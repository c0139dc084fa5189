#pragma once
// Reconstruction stage 2, classify: creates the per-pixel state array (heightfield/pixel_buffers.h)
// on the ROI: kOutside where the user mask is 0, kSaturated where any frame of the stack is
// saturated, kUnlit where white - black < min_lit (with a white frame), kActive elsewhere; and
// the white level and black value per pixel.

#include <string>

#include "heightfield/frames.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_plan.h"
#include "session/session.h"

namespace mesoscan {

struct ClassifyOptions {
  // Mask on the camera grid (any image format OIIO reads, camera width x height): pixels whose
  // grey value is 0 are not reconstructed. Empty: no mask.
  std::string mask_path;
  // Lit if white - black >= min_lit (linear frame units in [0, 1]), > 0.
  double min_lit = 0.02;
  void Check() const;
};

// Throws Error (bad input) naming the mask if it is unreadable or not camera-sized.
PixelClasses ClassifyPixels(const FrameStack& stack, const ReconstructPlan& plan, int camera_width,
                            int camera_height, const ClassifyOptions& options);

// The saturation verdict on frames decoded after ClassifyPixels ran (the stream classifies while
// the lens-shift frames still decode): a pixel saturated in `stack` that is neither kOutside nor
// kSaturated in `classified` becomes kSaturated there and in classes->state (white level NaN,
// black value 0), as ClassifyPixels would have marked it; classes->pixels_saturated counts it.
// Returns how many pixels it moved.
int64_t ClassifyLateSaturation(const FrameStack& stack, PixelStates* classified,
                               PixelClasses* classes);

}  // namespace mesoscan
