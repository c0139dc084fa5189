#pragma once
// The per-pixel records the reconstruction stages (heightfield/reconstruct.h) pass to each other:
// plain structs of planar arrays on the ROI grid (row-major, index y * width + x, the ROI's own
// origin), one struct per stage output, so that what a stage reads and writes is visible in its
// signature. NaN marks a value that was not computed.

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "core/json.h"
#include "heightfield/frames.h"

namespace mesoscan {

// Why a pixel has no point. Every pixel starts kActive (or kOutside) in the classify stage
// (heightfield/stage_classify.h), which creates the state array; each later stage may only move a
// kActive pixel to the one rejection it owns (listed per value), and the triangulation moves the
// survivors to kOk. So the state a pixel ends in names the stage that rejected it.
enum class PixelState : uint8_t {
  kOutside = 0,     // classify: outside the ROI or masked out (--mask)
  kSaturated,       // classify: a frame is saturated at this pixel
  kUnlit,           // classify (white - black < min_lit) or phase shift (no white frame:
                    // twice the phase-shift offset < min_lit)
  kUnmodulated,     // phase shift: modulation of some period < min_modulation x white level
  kFitFailed,       // lens shift: the profile fit is invalid (with phase_shift_fallback the
                    // combine stage lets such a pixel back in, decided by phase shifting alone)
  kUnwrapFailed,    // combine: no absolute coordinate (phase shift: temporal unwrapping
                    // inconsistent, residual > max_unwrap_residual)
  kCombination,     // combine: coarse and fine disagree (a period jump, paper Eq. 2)
  kLowConfidence,   // combine: paper Eq. 4 confidence below min_confidence
  kIsolated,        // combine (RejectIsolatedColumns): u continued by too few neighbours, an
                    // isolated fringe order (low signal: the periods' phases are mostly noise)
  kInconsistent,    // consistency: the phases contradict the pixel's column beyond their noise
  kAmbiguous,       // consistency: the noise cannot fix the fringe order or the stripes'
                    // period
  kUncertain,       // consistency (RejectUncertainPoints): the predicted depth sigma is too
                    // large to trust (a code too coarse or too noisy for the promised 100 um)
  kNoIntersection,  // triangulate: the camera ray misses the projector plane
  kDiscontinuity,   // mixed pixels: a mixed pixel at a depth step or shadow edge
  kActive,          // still in the running
  kOk,              // triangulate: a point (unless mixed pixels rejects it later)
};

using PixelStates = std::vector<PixelState>;

// The ROI in camera pixels and the size of the per-pixel arrays.
struct RoiGrid {
  PixelRect roi;  // x, y: camera pixel of ROI pixel (0, 0); w, h: size
  int width = 0, height = 0;
  size_t pixels() const { return static_cast<size_t>(width) * height; }
  static RoiGrid Of(const FrameStack& stack) {
    return {stack.roi(), stack.width(), stack.height()};
  }
};

// Classify stage: the state array and the white/black frames.
struct PixelClasses {
  PixelStates state;
  std::vector<float> white_level;  // white - black frame, linear units; NaN without white frame
  std::vector<float> black_value;  // black frame, linear units; 0 without one
  int64_t pixels_roi = 0;          // inside ROI and mask
  int64_t pixels_saturated = 0;
  // The lit threshold (ClassifyOptions::min_lit): the phase-shift stage applies it to its own
  // white level when there is no white frame.
  double min_lit = 0.02;
};

// A projector column per pixel in 16 bits, for fringe-order hints (UnwrapPhaseShift): they live
// through the lens-shift fit, the stage with the memory peak, and need a fraction of a period
// only. q = round((u + 1) scale) for u in [-1, range), scale = floor(65534 / (range + 2)) steps
// per px (34 for a 1920-px projector: within 0.015 px); kNone where there is no column.
struct ColumnHints {
  static constexpr uint16_t kNone = 0xFFFF;
  std::vector<uint16_t> q;
  double scale = 0.0;
  // Hints for n pixels (none set) of a projector `range_px` wide; empty if it is wider than
  // 16 bits can hold at one step per px.
  static ColumnHints For(size_t n, double range_px) {
    ColumnHints h;
    h.scale = std::floor(65534.0 / (range_px + 2.0));
    if (h.scale >= 1.0) h.q.assign(n, kNone);
    return h;
  }
  void Set(size_t i, double u) {
    if (u >= -1.0 && (u + 1.0) * scale < 65534.0)
      q[i] = static_cast<uint16_t>(std::lround((u + 1.0) * scale));
  }
  double At(size_t i) const {
    return q[i] == kNone ? std::numeric_limits<double>::quiet_NaN() : q[i] / scale - 1.0;
  }
  size_t size() const { return q.size(); }
};

// Phase-shift stage: per period p (plan order) the wrapped phase, modulation and residual.
struct PhaseShiftPixels {
  std::vector<std::vector<float>> theta;       // [p][i], radians in [0, 2 pi)
  std::vector<std::vector<float>> modulation;  // [p][i], B, linear units
  // [p][i], linear units; [p] empty for a period of 3 frames (their fit is exact: residual 0).
  std::vector<std::vector<float>> residual_rms;
  // White level: with a white frame the classify stage's white_level of every pixel (the stream
  // moves it here, PixelClasses::white_level is then empty until the driver moves it back for the
  // mixed pixels); without one 2 x the offset of the first period (kActive pixels, else NaN).
  std::vector<float> level;
  int64_t pixels_lit = 0;  // kActive after this stage: lit, unsaturated, modulated
  // The column unwrapped from these phases alone (stage_phase_shift.h UnwrapPhaseShift); empty
  // if not made (the combine stage then searches the fringe orders).
  ColumnHints u_unwrapped;
  // The projector response the phases were checked for (heightfield/phase_harmonics.h
  // ProjectorHarmonics::ToJson); null where not estimated.
  Json projector_response;
};

// Lens-shift stage: the fitted profile (heightfield/lens_shift_fit.h) per pixel; empty arrays
// when the session has no lens-shift frames or they are not used.
struct LensShiftPixels {
  std::vector<float> phase0;     // phase at shift 0 with the pixel's frequency, radians
  std::vector<float> amplitude;  // a, linear units (after luminance normalisation)
  std::vector<float> frequency;  // f, cycles per projector px
  // d and f are read by the frame corrections (on the frequency subsample) and the diagnostics
  // only: empty after a fixed-frequency pass unless LensShiftStageOptions::keep_offset_frequency
  // (peak RSS).
  std::vector<float> offset;        // d
  std::vector<float> residual_rms;  // linear units
  std::vector<float> samples;       // samples used
  int64_t pixels_fitted = 0;        // profiles fitted (valid or not)
  // Free parameters of the fits whose residuals estimate the noise: 4 with the per-pixel
  // frequency kept (fit_frequency without smooth_frequency), else 3.
  int fit_parameters = 3;
  // Per-frame gains and shifter positions estimated jointly with the fits
  // (heightfield/frame_corrections.h FrameCorrections::ToJson); null if not run.
  Json frame_corrections;
  bool empty() const { return phase0.empty(); }
};

// Combine stage: unwrapping, paper Eq. 2 and Eq. 4.
struct CombinedPixels {
  std::vector<float> u;  // final projector column, px; NaN if rejected
  // Absolute column from phase shifting, px, and the unwrapping residual, sigma units (empty
  // without CombineOptions::keep_coarse unless the positions' reference needed them).
  std::vector<float> u_coarse;
  std::vector<float> unwrap_residual;
  std::vector<float> confidence;  // [0, 1]; 0 if rejected
  std::vector<float> sigma_u;     // predicted sigma of u, px
  // Which codec fixed u (points.exr `source`): 0 the periodic refinement, the lens shift (the
  // absolute codec, phase shifting, for the period), 1 the absolute codec alone.
  std::vector<uint8_t> source;
  // Offset added to the lens-shift pixels' u against phase shifting (CombineOptions::
  // reference_positions_to_phase_shift), px; 0 where not applied.
  double ls_offset_px = 0.0;
};

}  // namespace mesoscan
