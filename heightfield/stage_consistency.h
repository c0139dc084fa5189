#pragma once
// Reconstruction stage 5c, consistency: the frames' own model checked at every decoded pixel.
// A pixel's final column u predicts the wrapped phase of every phase-shift period
// (theta_p = 2 pi u / period_p); the measured phases must agree within their noise, the noise
// must allow the fringe orders that were chosen, and (with lens shift) the coarse column must fix
// the 2-px stripes' period. So a capture that contradicts its session.json (swapped or copied
// frames, swapped period labels, phases out of order, a frame of another object, frames in the
// wrong units) or that is too noisy for its code (dark frames, a cue too coarse for the stripes)
// loses those pixels instead of giving wrong points with confidence; and a period (or the
// lens-shift set) that contradicts the others at most pixels is named and refused.
//
// The per-sample noise is the larger of the combine stage's (the pixel's own residuals) and a
// noise model measured on the session itself: the lens-shift fit residuals, binned by white
// level (a three-phase period has no residual of its own, and a pixel whose stripes failed has
// no lens-shift residual).
//
// Moves pixels to kInconsistent (phases disagree with u) or kAmbiguous (the noise cannot fix the
// fringe order or the stripes' period); sets combined->sigma_u to the sigma with the measured
// noise where that is larger (phase-shift pixels). After triangulation, RejectUncertainPoints
// drops points whose predicted depth sigma is too large to be trusted.

#include <string>
#include <vector>

#include "core/camera.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "heightfield/pixel_buffers.h"
#include "heightfield/stage_plan.h"

namespace mesoscan {

struct ConsistencyOptions {
  bool enabled = true;
  // |measured - predicted phase| / sigma above which a pixel's phases contradict its column.
  double max_phase_z = 6.0;
  // A wrong fringe order must need at least this many sigmas of phase error (per period, the
  // code's separation against the pixel's largest phase sigma); with lens shift, the coarse
  // column's sigma must be at most 1 px (half the stripes' period) over this.
  double min_order_margin_sigma = 5.0;
  // As PhaseShiftStageOptions (the pipeline copies it from there): added in quadrature to the
  // noise-predicted phase variance, rad.
  double systematic_phase_noise = 0.02;
  // A period whose phases contradict the final columns at more than this fraction of the tested
  // pixels (at least min_pixels_for_verdict of them) is refused (Error naming its frames).
  double max_inconsistent_fraction = 0.2;
  int64_t min_pixels_for_verdict = 200;
  bool four_parameter_fit = false;  // the lens-shift fit's free parameters were 4 (sigma's dof)
  // Points whose predicted depth sigma exceeds the larger of max_depth_sigma_m and
  // max_depth_sigma_per_footprint times the point's camera footprint (its distance from the
  // camera over the focal length) are rejected (RejectUncertainPoints), > 0 and >= 0. On a rig
  // of 55 um samples (the paper's) the first holds: a point kept is within 5 sigma of the
  // surface, i.e. within 100 um. A coarser rig (a VGA camera over a larger field) keeps the
  // depth noise its own lateral sampling allows (0.36 footprints: 5 sigma within 2 samples), so
  // its Gray-code or three-step captures are not all refused.
  double max_depth_sigma_m = 20e-6;
  double max_depth_sigma_per_footprint = 0.36;
  void Check() const;
};

struct ConsistencyReport {
  int64_t tested = 0;        // pixels with a column tested
  int64_t inconsistent = 0;  // moved to kInconsistent
  int64_t ambiguous = 0;     // moved to kAmbiguous
  // Pixels whose coarse column cannot fix the stripes' period: kAmbiguous ones, and kCombination
  // ones (the combine stage's "period jump" is then a guess gone wrong, not a contradiction).
  int64_t ambiguous_stripes = 0;
  std::vector<double> period_inconsistent_fraction;  // per plan period, of the tested pixels
  std::vector<double> period_phase_rms_rad;          // per period: RMS of |d| over good pixels
  // Per period: that RMS over its noise-predicted RMS (~1 where the period is what it claims).
  std::vector<double> period_phase_excess;
  int64_t decoded = 0;  // tested, plus the pixels the combine stage found contradictory
  // Of the decoded pixels: unwrapping or combination failed, or phases contradicting u.
  double contradicted_fraction = 0.0;
  bool noise_model = false;  // a noise model was measured from the lens-shift residuals
  // The predicted phase sigmas were scaled by this to match the phases themselves (<= 1; 1: the
  // prediction was not too large).
  double noise_scale = 1.0;
  Json ToJson() const;
};

// Runs the checks on the kActive pixels with a finite combined->u. Throws Error (bad input)
// naming the frames of a period (or the lens-shift frames) that contradict the rest of the
// session at more than max_inconsistent_fraction of the pixels.
ConsistencyReport CheckPhaseConsistency(const ReconstructPlan& plan, const Session& session,
                                        const PhaseShiftPixels& ps, const LensShiftPixels& ls,
                                        const ConsistencyOptions& options, CombinedPixels* combined,
                                        PixelStates* state);

// After triangulation: kOk points whose predicted depth sigma exceeds max_sigma_m are moved to
// kUncertain (NaN, confidence 0): with max_sigma_m = 20 um, a point within 5 sigma is within
// 100 um. Returns the number rejected.
int64_t RejectUncertainPoints(const RoiGrid& grid, const std::vector<float>& sigma_z,
                              const ConsistencyOptions& options, const PinholeCamera& camera,
                              ScanPoints* points, PixelStates* state);

}  // namespace mesoscan
