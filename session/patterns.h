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

#include <array>
#include <string>
#include <vector>

#include "core/image.h"
#include "session/session.h"

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

// The frame plan of a session: which patterns, in which order, under which file names. The one
// generator of frame lists: `capture`, `simulate` (objects and calibration boards) and the tests
// all build their frames here, so a captured and a simulated session of the same plan list the
// same files with the same shifter positions.
//
// A scan plan (Ritz et al. 2012): phase shift for the absolute column, lens shift for sub-pixel
// refinement, white and black. A calibration plan (CalibrationPlan below): sines along
// both projector axes, white and black, no lens shift.
struct FramePlanOptions {
  std::vector<double> periods_px{7, 11, 13};  // sine periods along `axis` (> 2), e.g. coprime
  std::vector<double> cross_periods_px;       // sine periods along the other axis (> 2)
  int phases = 3;                             // phases per period (>= 3), 2*pi*k/phases
  char axis = 'x';                            // axis of the first sines and of the stripes
  // Lens-shift (stripes) frames: 0 or >= 4, shift_steps evenly over range_steps including both
  // ends (the shifter accepts both), rounded to integers.
  // Gray code along `axis` (graycode frames gc<k>, and gci<k> with the inverse; axis y: gcy<k>,
  // gciy<k>): 0 bits = none; blocks of graycode_block_px (>= 1) projector px, block_px * 2^bits
  // must cover the projector. cross_graycode_*: the same along the other axis.
  int graycode_bits = 0;
  double graycode_block_px = 1.0;
  int cross_graycode_bits = 0;
  double cross_graycode_block_px = 1.0;
  bool graycode_inverse = true;
  int lens_shift_frames = 50;
  std::array<int, 2> range_steps{-2048, 2048};  // shifter range [min, max], steps
  bool white = true;                            // a white frame (albedo)
  bool black = true;                            // a black frame (modulation bounds)
  std::string frame_dir = "frames";             // frame files go to <frame_dir>/<name><extension>
  std::string extension = ".png";               // ".png", ".bmp", ".tif" ...
  void Check() const;                           // a broken plan is a bug: callers validate input
};

// The calibration plan of a projector of this size: a one-period cue as wide (high) as the
// projector plus 1/16 of it (16 periods), along x and along y; white and black; no lens shift.
FramePlanOptions CalibrationPlan(int projector_width, int projector_height);

// The three-frequency heterodyne set's periods, projector px: 42, 45 and 48 (three steps each
// by default): close periods whose phases the temporal unwrapping orders over the projector
// (`simulate --patterns heterodyne`, `capture --patterns heterodyne`).
std::vector<double> HeterodynePeriods();

// The pattern family of a plan's axes (`simulate --patterns`, `capture --patterns`): "sine"
// and "heterodyne" leave the plan as it is (the caller sets the heterodyne periods where none
// were asked for: HeterodynePeriods); "graycode" replaces the sines of every axis that has some
// (the plan's `axis` always) by a Gray code of the projector's columns (rows for y), W = 1, with
// inverse frames; "sine+graycode" keeps the one sine period of each such axis and adds a
// complementary Gray code of half its width that orders it. `width`, `height`: the projector's.
// Throws Error(kUsage) at the options field `option` for another name, or for sine+graycode with
// other than one period along an axis.
void ApplyPatternSet(const std::string& patterns, int width, int height, FramePlanOptions* plan,
                     const std::string& option);

// "7" -> "07", "37.5" -> "37.5": the period in frame names (docs/formats.md's
// example names frames/ps07_0.png).
std::string PeriodName(double period_px);

// "7,11,13" -> {7, 11, 13}; "" or "none" -> {} (a plan without sines). Every period a finite
// number > 2 (projector px). Throws Error(kUsage) at the options field `option`
// (e.g. "FramePlanOptions.periods_px").
std::vector<double> ParsePeriodList(const std::string& text, const std::string& option);

// Frames of the plan, in this order: sines along `axis` (ps<period>_<k>, e.g. ps07_0.png; axis y:
// psy<period>_<k>), sines along the other axis (likewise), Gray code along `axis` then along the
// other axis (each bit, then its inverse), lens shift ls_<nnn> (shift_steps
// round(min + i * (max - min) / (n - 1))), white, black.
std::vector<Frame> MakeStandardFrames(const FramePlanOptions& options);

}  // namespace mesoscan
