#pragma once
// Evaluation of a reconstruction against a simulated session's ground truth (sim/README.md,
// gt_points.exr): depth errors, coverage, mixed pixels, and the lens-shift Cramer-Rao floor.
// Used by `mesoscan reconstruct` when the session has ground truth, by tests and benchmarks;
// never by the reconstruction itself.

#include <functional>

#include "core/image.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "heightfield/frames.h"
#include "heightfield/reconstruct.h"
#include "session/session.h"

namespace mesoscan {

// Errors of reconstructed points against a simulated session's gt_points.exr. The depth error of a
// pixel is the Z (world height) difference at the same camera pixel, metres; only pixels where
// both are finite enter the error figures. Coverage = reconstructed / ground-truth-lit pixels
// inside `roi` (empty = whole image).
struct GroundTruthErrors {
  int64_t pixels_gt = 0;      // ground truth finite (lit surface) inside the ROI
  int64_t pixels_both = 0;    // ... and reconstructed
  double coverage = 0.0;      // pixels_both / pixels_gt
  double rms_m = 0.0;         // RMS of the Z error
  double mean_m = 0.0;        // mean (bias)
  double median_abs_m = 0.0;  // median |error|
  double p99_abs_m = 0.0;     // 99th percentile |error|
  double max_abs_m = 0.0;
  int64_t gross = 0;            // |error| > gross_threshold_m
  double gross_fraction = 0.0;  // gross / pixels_both
  double gross_threshold_m = 0.0;
  // 10x the RMS of the inliers (|e| < 5 median |e|): the errors' own scale (the gross threshold
  // before it was absolute; a scan whose errors are all wrong has a large one).
  double inlier_scale_m = 0.0;
  // Mixed pixels, where gt_points.exr has the simulator's footprint channels (lit_fraction,
  // relief; sim/README.md): a lit pixel is mixed if part of its footprint is unlit or the
  // footprint's relief (distance from one plane) exceeds mixed_relief_m = inlier_scale_m / 10
  // (the inliers' RMS): it sees more than one smooth surface, and is to be
  // rejected. Coverage of the single-surface lit pixels is then the fair figure. Without
  // the channels every lit pixel counts as single-surface.
  bool footprint_known = false;
  double mixed_relief_m = 0.0;
  int64_t pixels_mixed = 0;      // lit (per pixels_gt) and mixed
  int64_t mixed_kept = 0;        // ... and reconstructed anyway
  int64_t gross_mixed = 0;       // ... with a gross error
  double coverage_single = 0.0;  // reconstructed / lit single-surface pixels
  ImageF error;                  // camera grid, Z error (m), NaN where not both
  Json ToJson() const;
};
// An error is gross if |error| > gross_threshold_m; <= 0: kGrossErrorM, an absolute threshold
// (the promise of the reconstruction: no point kept more than 100 um from the surface).
inline constexpr double kGrossErrorM = 100e-6;
GroundTruthErrors EvaluateAgainstGroundTruth(const Session& session, const ScanPoints& points,
                                             const PixelRect& roi = {},
                                             double gross_threshold_m = 0.0);

// The same in two steps, so that the reading (the larger part: a 5-channel float EXR, 62 MB and
// ~0.35 CPU-s at 3 Mpx) can overlap the reconstruction (`mesoscan reconstruct` starts it once
// the frames are released). ReadGroundTruthPoints throws as EvaluateAgainstGroundTruth does.
struct GroundTruthPoints {
  std::filesystem::path path;  // session root / ground_truth.points
  ImageF image;
  ImageInfo info;
};
GroundTruthPoints ReadGroundTruthPoints(const Session& session);
GroundTruthErrors EvaluateAgainstGroundTruth(const GroundTruthPoints& gt, const ScanPoints& points,
                                             const PixelRect& roi = {},
                                             double gross_threshold_m = 0.0);

// Cramer-Rao floor of the lens-shift depth RMS over the pixels where `error` is finite:
// var(phi) from the Fisher information (LensShiftPhaseCrlb, frequency held as in the second fit
// pass) at each pixel's fitted amplitude and frequency, with the noise sigma a known noise model
// gives at the fitted offset, carried through dZ/du. Needs diagnostics (keep_diagnostics) of a
// lens-shift reconstruction; returns 0 where there is none or no pixel qualifies.
double LensShiftDepthCrlbRms(const Session& session, const ReconstructDiagnostics& diagnostics,
                             const ImageF& error, const std::function<double(double)>& sigma);
// The same floor per camera pixel (metres; NaN where `error` or dZ/du is not finite); empty
// without lens-shift diagnostics.
ImageF LensShiftDepthCrlbMap(const Session& session, const ReconstructDiagnostics& diagnostics,
                             const ImageF& error, const std::function<double(double)>& sigma);

}  // namespace mesoscan
