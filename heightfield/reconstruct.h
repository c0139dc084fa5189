#pragma once
// The reconstruction pipeline: a capture session (docs/formats.md) to a
// scan (docs/formats.md). Reconstruct() is a short driver that chains and times the
// stages, each a function in its own file with its options struct; they pass plain
// struct-of-arrays records on the ROI (heightfield/pixel_buffers.h) and one per-pixel state array
// (PixelState: why a pixel has no point; each rejection is owned by one stage).
//
//  0. plan (stage_plan.h): which frames are decoded and what each encodes;
//  1. decode (frames.h LoadFrames): parallel decode (uint16), black level, camera response,
//     saturation;
//  2. classify (stage_classify.h): ROI, mask, saturation, lit from white/black frames;
//  3. gains (stage_gains.h): per-frame luminance normalisation (Ritz et al. 2012, Sec. 5.1);
//  4. phase shift (stage_phase_shift.h), the absolute codec (heightfield/codec.h): wrapped
//     phase and modulation per period, and (with lens shift, while its frames still decode) the
//     column unwrapped from them alone (UnwrapPhaseShift), whose fringe orders it keeps;
//  5. lens shift (stage_lens_shift.h), the periodic codec that refines it: the profile fit per
//     pixel, positions referenced to the centre of the shift range -> u modulo 2 px (optional
//     5-sample box filter);
//  6. combine (stage_combine.h), through the codecs' per-pixel records: the absolute
//     coordinate u_c (phase shifting's temporal or hierarchical unwrapping, with the lens-shift
//     noise as weights, at the fringe orders of step 4 where they hold), combination (paper
//     Eq. 2), confidence (paper Eq. 4) times modulation and unwrapping consistency;
//     6b. isolated fringe orders (stage_combine.h RejectIsolatedColumns);
//     6c. consistency (stage_consistency.h): the frames' own model at every pixel (phases that
//     contradict the column, fringe orders or stripe periods the noise cannot fix), and a
//     capture contradicting itself refused;
//  7. triangulate (stage_triangulate.h) with camera and projector distortion;
//  8. mixed pixels (stage_mixed_pixels.h), then points whose predicted depth sigma is too large
//     (stage_consistency.h RejectUncertainPoints); NaN and confidence 0 wherever a point is
//     rejected;
//  9. height field (stage_height_field.h) on a regular world grid, normals; report.json figures
//     (reconstruct_summary.cc).
// ReconstructPoints assembles stages 0-8 (Reconstruct and calibration's flat-target scan both
// run it); each stage's options struct is nested in ReconstructOptions.
// Pixels that are masked, unlit, unmodulated or outside the ROI are never fitted. Ground-truth
// evaluation is in sim/ground_truth.h, the error map in sim/error_map_png.h.

#include <functional>
#include <string>
#include <vector>

#include "core/image.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "core/stage_timer.h"
#include "heightfield/frame_corrections.h"
#include "heightfield/frames.h"
#include "heightfield/lens_shift_fit.h"
#include "heightfield/mixed_pixels.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/resample.h"
#include "heightfield/stage_classify.h"
#include "heightfield/stage_combine.h"
#include "heightfield/stage_consistency.h"
#include "heightfield/stage_gains.h"
#include "heightfield/stage_lens_shift.h"
#include "heightfield/stage_phase_shift.h"
#include "heightfield/stage_plan.h"
#include "heightfield/stage_triangulate.h"
#include "session/session.h"

namespace mesoscan {

// The pipeline's options: one struct per stage (each field documented and checked where it is
// declared), nested here; only what is the whole pipeline's lives at this level.
struct ReconstructOptions {
  // Stage 0: which frames are decoded (lens shift or phase shifting alone).
  PlanOptions plan;
  // Stage 1: the camera pixels to reconstruct (roi: x, y, w, h; w == 0 or h == 0: the whole
  // image) and the saturation level.
  FrameLoadOptions load;
  // Stage 2: the user's mask and the lit threshold.
  ClassifyOptions classify;
  // Stage 3: per-frame luminance normalisation (paper Sec. 5.1).
  GainOptions gains;
  // Stage 4: the phase-shift modulation threshold and the periods' unwrapping.
  PhaseShiftStageOptions phase_shift;
  // Stage 5: the lens-shift profile fit and the frame corrections.
  LensShiftStageOptions lens_shift;
  // Stage 6: combination (paper Eq. 2), confidence (Eq. 4), fallback, isolated fringe orders.
  CombineOptions combine;
  // Stage 6c: the frames' own model checked at every pixel; stage 8: the depth sigma limit.
  ConsistencyOptions consistency;
  // Stage 8: mixed pixels at depth steps and shadow edges (heightfield/mixed_pixels.h): rejected
  // rather than placed between the surfaces. reject_mixed_pixels = false keeps them.
  bool reject_mixed_pixels = true;
  MixedPixelOptions mixed_pixels;
  // Stage 9: the height-field grid.
  ResampleOptions resample;
  // Keep per-pixel intermediate images in the summary (tests, benchmarks, CRLB); also keeps the
  // stages' optional outputs (CombineOptions::keep_coarse, LensShiftStageOptions::
  // keep_offset_frequency, whatever those fields say).
  bool keep_diagnostics = false;
  // Called once, on the calling thread, when the frames have been released after the lens-shift
  // stage (the memory peak is behind): `mesoscan reconstruct` starts reading the session's ground
  // truth there, to overlap the remaining stages. Empty: nothing. Not part of ToJson().
  std::function<void()> on_frames_released;

  void Check() const;  // every stage's Check()
  Json ToJson() const;
};

// Per-pixel intermediate results on the camera grid (NaN where not computed).
struct ReconstructDiagnostics {
  ImageF u_coarse;         // absolute projector column from phase shifting, px
  ImageF unwrap_residual;  // px
  ImageF ps_modulation;    // B / white level
  ImageF white_level;      // linear frame units
  ImageF ls_amplitude;     // lens-shift a, linear frame units (after luminance normalisation)
  ImageF ls_offset;        // d
  ImageF ls_frequency;     // f, cycles per projector px
  ImageF ls_residual_rms;  // linear frame units
  ImageF ls_samples;       // samples used
  ImageF dz_du;            // dZ/du of the triangulation, metres per projector px
  ImageF u;                // final projector column
  ImageF sigma_u;          // predicted sigma of u, px (lens shift or phase shift, per source)
};

struct ReconstructSummary {
  // Wall time (s) per stage, in pipeline order: decode, normalize, phase_shift, lens_shift,
  // triangulate, height_field, ...
  StageTimings timings_s;
  // CPU time (s, all threads) per stage; "decode" holds the whole overlapped front (decode,
  // classify, gains, phase shift), whose parts run at once.
  StageTimings cpu_s;
  double cpu_total_s = 0.0;
  int64_t pixels_total = 0;   // camera pixels
  int64_t pixels_roi = 0;     // inside ROI and mask
  int64_t pixels_lit = 0;     // lit, unsaturated, modulated
  int64_t pixels_fitted = 0;  // lens-shift profiles fitted (or phase-shift decoded if none)
  int64_t pixels_valid = 0;   // points with confidence > 0
  int64_t pixels_saturated = 0;
  int64_t pixels_rejected_unwrap = 0;
  int64_t pixels_rejected_combination = 0;
  int64_t pixels_rejected_confidence = 0;
  int64_t pixels_rejected_discontinuity = 0;
  int64_t pixels_rejected_isolated = 0;  // combine: isolated fringe orders (RejectIsolatedColumns)
  int64_t pixels_rejected_inconsistent = 0;  // consistency: phases contradict the column
  int64_t pixels_rejected_ambiguous = 0;     // consistency: fringe order or stripes too uncertain
  int64_t pixels_rejected_uncertain = 0;     // consistency: predicted depth sigma too large
  ConsistencyReport consistency;
  int lens_shift_frames = 0, phase_shift_frames = 0;
  std::vector<double> frame_gains;  // per session frame, 1 where not estimated
  Json frame_corrections;  // lens-shift frames: FrameCorrections::ToJson() (null if not run)
  // The projector response estimated from the sine phases (heightfield/phase_harmonics.h
  // ProjectorHarmonics::ToJson: harmonics, nearest gamma, applied or why not); null if not run.
  Json projector_response;
  std::string unwrapping;  // "temporal", "hierarchical" or "single"
  // Decoded projector axis: "x" (projector_u holds columns) or "y" (rows; horizontal fringes).
  std::string axis = "x";
  bool used_lens_shift = false;
  double total_s = 0.0;
  // When the last frame was decoded, s from the start (the work after it is total_s - this).
  double last_frame_s = 0.0;
  // Cramer-Rao prediction of the depth RMS (m) with the noise estimated from each pixel's own fit
  // residual: var(u) from var(phi) >= 2 sigma^2 / (N a^2) (lens shift; phase shifting alone: the
  // weighted periods), carried through the triangulation (dZ/du), RMS over a subsample of the
  // valid pixels. 0 if no valid pixel.
  double predicted_depth_rms_m = 0.0;
  ReconstructDiagnostics diagnostics;  // filled if options.keep_diagnostics

  double Seconds(const std::string& stage) const;
  std::string BriefReport() const;
  Json ToJson() const;
};

// Stages 0-8 (plan to mixed pixels): the one assembly of the stages that Reconstruct and
// calibration's flat-target scan (calibration/calibrate_mount.h) run. Times the stages on
// `timer` and fills the summary's frame figures (not the pixel counts: CountFinalStates). Throws
// as Reconstruct.
struct ReconstructedPoints {
  ReconstructPlan plan;
  RoiGrid grid;
  PixelClasses classes;       // the final states; white_level (mixed pixels) on the ROI grid
  PhaseShiftPixels ps;        // empty unless options.keep_diagnostics
  LensShiftPixels ls;         // empty unless options.keep_diagnostics
  CombinedPixels combined;    // u_coarse, unwrap_residual empty unless options.keep_diagnostics
  TriangulatedPoints tri;     // the points (camera grid) and their sigma_z (ROI grid)
  double last_frame_s = 0.0;  // when the last frame was decoded, s after the call
};
ReconstructedPoints ReconstructPoints(const Session& session, const ReconstructOptions& options,
                                      StageTimer* timer, ReconstructSummary* summary);

// Runs the pipeline on a session already read by ReadSession. Throws Error for bad input (a mask
// of the wrong size, a session whose patterns cannot decode); never for data (a pixel that cannot
// be reconstructed is NaN with confidence 0). The returned Scan's report holds the summary and
// options; the caller adds the session path and ground-truth figures (sim/ground_truth.h).
Scan Reconstruct(const Session& session, const ReconstructOptions& options,
                 ReconstructSummary* summary = nullptr);

// The summary's pixel counts from the final states (reconstruct_summary.cc).
void CountFinalStates(const PixelStates& state, ReconstructSummary* summary);
// RMS of the predicted depth sigma over the kOk pixels (every 4th pixel of every 4th row).
double PredictedDepthRms(const RoiGrid& grid, const PixelStates& state,
                         const std::vector<float>& sigma_z);
// The per-pixel intermediate images on the camera grid.
ReconstructDiagnostics CollectDiagnostics(const Rig& rig, const RoiGrid& grid,
                                          const PhaseShiftPixels& ps, const LensShiftPixels& ls,
                                          const CombinedPixels& combined, ImageF dz_du);

}  // namespace mesoscan
