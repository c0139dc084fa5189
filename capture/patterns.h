#pragma once
// Pattern generation: the images the projector displays (session-format.md "Patterns") and the
// standard frame plan of a lens-shift scan.
//
// The lens shifter moves the projected image optically; what the projector *displays* (the
// window's pixels) never changes with the shift. RenderPattern therefore has no shift parameter:
// it renders the displayed image, i.e. the image at shift 0. Resampling that image at integer
// pixels of the unshifted grid would not model the optics (a one-pixel stripe pattern moved by
// half a pixel is not a grey image). A simulator that needs the light reaching a continuous
// position x of the unshifted (calibrated) projector image plane uses ValueAtShift, which
// evaluates Pattern::Value at x - shift (pixel footprints for stripes, the continuous cosine for
// sine).

#include <vector>

#include "capture/session.h"
#include "core/image.h"

namespace mesoscan {

// The displayed image: width x height, pixel (u, v) = pattern.Value(u, v) in [0, 1], optionally
// mapped through the projector's response (the light each pixel emits, relative to white).
ImageF RenderPattern(const Pattern& pattern, int width, int height,
                     const Response& response = Response());
inline ImageF RenderPattern(const Pattern& pattern, const PinholeCamera& projector,
                            const Response& response = Response()) {
  return RenderPattern(pattern, projector.width, projector.height, response);
}

// Displayed value seen at continuous position (x, y) of the unshifted projector image plane when
// the shifter has moved the image by shift_px along shift_axis ('x' or 'y'): Value(x - shift).
double ValueAtShift(const Pattern& pattern, double x, double y, double shift_px, char shift_axis);

// Nominal shift in projector px of a frame: shift_steps / steps_per_px (0 without a shifter).
double ShiftPx(const Frame& frame, const Rig& rig);

// The standard acquisition plan (Ritz et al. 2012: phase shift for the absolute column, lens
// shift for sub-pixel refinement).
struct FramePlanOptions {
  std::vector<double> periods_px{7, 11, 13};    // sine periods (> 2), coprime: unambiguous to LCM
  int phases = 3;                               // phases per period (>= 3), 2*pi*k/phases
  char axis = 'x';                              // axis of the sine and stripes patterns
  int lens_shift_frames = 50;                   // 0 or >= 4 stripes frames
  std::array<int, 2> range_steps{-2048, 2048};  // shifter positions spanned (end exclusive)
  bool white = true;                            // a white frame (albedo)
  bool black = true;                            // a black frame (modulation bounds)
  std::string frame_dir = "frames";             // frame files go to <frame_dir>/<name>.png
  void Check() const;
};

// Frames of the plan: ps<period>_<k>.png, ls_<nnn>.png (shift_steps evenly spaced from
// range_steps[0], step (max - min) / lens_shift_frames), white.png, black.png.
std::vector<Frame> MakeStandardFrames(const FramePlanOptions& options);

}  // namespace mesoscan
