#pragma once
// Reconstruction stage 5, lens shift: the profile of every kActive pixel over the lens-shift
// frames (heightfield/lens_shift_fit.h), positions referenced to the centre of the shift range.
// With fit_frequency and smooth_frequency: the 4-parameter fit on a regular subsample (~100000
// pixels), a robust quadratic frequency map over the image (SmoothFrequencyMap), then the
// 3-parameter fit of every pixel with f held at the map; between the two, the per-frame
// corrections (gains, shifter positions) refine gains->inv_gain and the positions. Moves pixels
// to kFitFailed. Returns empty arrays when the plan has no lens-shift frames. LensShiftCodec reads
// the fits as the periodic codec (period 2 px, heightfield/codec.h) that refines the absolute
// coordinate (paper Eq. 2).

#include <array>
#include <cstddef>
#include <vector>

#include "core/stage_timer.h"
#include "heightfield/codec.h"
#include "heightfield/frame_corrections.h"
#include "heightfield/frames.h"
#include "heightfield/lens_shift_fit.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct LensShiftStageOptions {
  // Lens-shift profile fitter (heightfield/lens_shift_fit.h): fast, lm or ceres.
  LensShiftFitter fitter = LensShiftFitter::kFast;
  // Paper's optional 5-sample box filter along each lens-shift profile (it trades resolution
  // along the shift for noise; the phase at the range centre is unbiased; needs >= 9 frames).
  bool box_filter = false;
  // Fit the per-pixel lens-shift frequency (4-parameter model, paper Eq. 1) ...
  bool fit_frequency = true;
  // ... and replace the per-pixel frequencies by a robust quadratic over the image (the
  // shifter's gain varies smoothly with the optics), then fit the phase again with f held there:
  // the 3-parameter fit has lower variance where the 4-parameter one gains nothing.
  bool smooth_frequency = true;
  // With smooth_frequency (and no box filter): per-frame gains, and shifter position errors if
  // correct_positions, estimated jointly with the per-pixel fits before the fixed-frequency pass
  // (heightfield/frame_corrections.h).
  FrameGainMethod frame_gain_method = FrameGainMethod::kJoint;
  bool correct_positions = true;
  // The fixed-frequency pass with the row kernel (FixedFrequencyRowFitter: pixels of a row in
  // SIMD lanes); false: every pixel through LensShiftBatchFitter::Fit (the reference, slower).
  bool row_kernel = true;
  // Keep LensShiftPixels::offset and frequency (the diagnostics): else they are released
  // before the fixed-frequency pass, which then does not store them.
  bool keep_offset_frequency = true;
  // If set, receives the wall time of each step of the stage (bench_lens_shift_stage).
  StageTimings* step_timings = nullptr;
};

LensShiftPixels FitLensShift(const FrameStack& stack, const ReconstructPlan& plan,
                             FrameGains* gains, const LensShiftStageOptions& options,
                             PixelStates* state);

// The lens-shift fits as a periodic codec of period 2 px: the phase at shift 0 in cycles
// (u_fine = 1/2 - phase0 / pi, mod 2: the stripes' convention), valid where the fit holds; its
// sigma sqrt(2 sigma^2 / (N a^2)) / pi px and its confidence c = 1 - sqrt(E t) (paper Eq. 4, E =
// (rms / a)^2) come with Decode(). Views plan and ls, which must outlive it.
class LensShiftCodec final : public Codec {
 public:
  // confidence_t: paper Eq. 4's t (CombineOptions::confidence_t).
  LensShiftCodec(const ReconstructPlan& plan, const LensShiftPixels& ls, double confidence_t);
  const char* Name() const override { return "lens_shift"; }
  CodecKind Kind() const override { return CodecKind::kPeriodic; }
  double PeriodPx() const override { return 2.0; }
  std::vector<int> Frames() const override { return plan_.ls_stack; }
  // Pixels whose profile fit used more than 4 samples: the residual with its degrees of freedom.
  void SampleNoise(const size_t* pixels, size_t n, double* sigma) const override;
  void Decode(const size_t* pixels, size_t n, const double* noise, CodecRecord* out) const override;
  void Describe(const size_t*, const double*, const uint32_t*, size_t, bool,
                CodecRecord*) const override {}  // Decode() fills sigma_px and confidence
  // The frame corrections estimated the shifter positions: known up to a common offset.
  bool OffsetUnknown() const override;

 private:
  const ReconstructPlan& plan_;
  const LensShiftPixels& ls_;
  double confidence_t_;
};

// A robust quadratic surface f(x, y) through the finite values of `f` (w x h, row-major),
// evaluated everywhere; empty if there are fewer than 50 values. Fitted to ~50000 of them; two
// rounds drop values beyond 4 MADs of the residual.
std::vector<float> SmoothFrequencyMap(const std::vector<float>& f, int w, int h);

// Its quadratic: c . (1, x, y, x^2, x y, y^2) with x, y the pixel centre scaled to [-1, 1] over
// width x height; evaluated where needed instead of stored (the fixed-frequency pass per tile).
struct QuadraticMap {
  std::array<double, 6> c{};
  int width = 0, height = 0;
  void Terms(size_t x, size_t y, double* t) const;
  // Pixels (x0 .. x0 + n - 1, y) into out[0..n).
  void Row(int y, int x0, int n, float* out) const;
  float At(size_t i) const;             // pixel i (row-major): the value Row gives it
  std::vector<float> Evaluate() const;  // every pixel, row-major
};
// SmoothFrequencyMap's fit alone; false where it returns an empty map. With stride > 1, `f` is a
// subsample: its entry (x, y) is pixel (x stride, y stride) of the out_w x out_h grid the map
// covers.
bool FitSmoothFrequencyMap(const std::vector<float>& f, int w, int h, int stride, int out_w,
                           int out_h, QuadraticMap* map);

}  // namespace mesoscan
