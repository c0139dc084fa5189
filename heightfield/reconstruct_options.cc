// ReconstructOptions: checks, report.json form, and the options of each stage.
#include <cmath>

#include "core/error.h"
#include "heightfield/reconstruct.h"

namespace mesoscan {

void ReconstructOptions::Check() const {
  if (roi.x < 0 || roi.y < 0 || roi.w < 0 || roi.h < 0)
    MESOSCAN_BAD_INPUT("--roi: expected non-negative x,y,w,h");
  if (num_threads < 0) MESOSCAN_BAD_INPUT("--threads: expected >= 0, got " << num_threads);
  if (!(min_lit > 0)) MESOSCAN_BAD_INPUT("min_lit: expected > 0, got " << min_lit);
  if (!(min_modulation > 0 && min_modulation <= 0.5))
    MESOSCAN_BAD_INPUT("min_modulation: expected a value in (0, 0.5], got " << min_modulation);
  if (!(max_unwrap_residual > 0))
    MESOSCAN_BAD_INPUT("max_unwrap_residual: expected > 0, got " << max_unwrap_residual);
  if (!(max_combination_residual_px > 0 && max_combination_residual_px < 1))
    MESOSCAN_BAD_INPUT("max_combination_residual_px: expected a value in (0, 1), got "
                       << max_combination_residual_px);
  if (!(confidence_t > 0)) MESOSCAN_BAD_INPUT("confidence_t: expected > 0, got " << confidence_t);
  if (!(min_confidence >= 0 && min_confidence < 1))
    MESOSCAN_BAD_INPUT("min_confidence: expected a value in [0, 1), got " << min_confidence);
  mixed_pixels.Check();
  if (!(phase_shift_fallback_confidence > 0 && phase_shift_fallback_confidence <= 1))
    MESOSCAN_BAD_INPUT("phase_shift_fallback_confidence: expected a value in (0, 1], got "
                       << phase_shift_fallback_confidence);
  if (!(systematic_phase_noise >= 0))
    MESOSCAN_BAD_INPUT("systematic_phase_noise: expected >= 0, got " << systematic_phase_noise);
  resample.Check();
}

Json ReconstructOptions::ToJson() const {
  Json j;
  j["roi"] = {roi.x, roi.y, roi.w, roi.h};
  j["mask"] = mask_path;
  j["fitter"] = LensShiftFitterName(fitter);
  j["use_lens_shift"] = use_lens_shift;
  j["threads"] = num_threads;
  j["normalize_luminance"] = normalize_luminance;
  j["lens_shift_box_filter"] = lens_shift_box_filter;
  j["fit_frequency"] = fit_frequency;
  j["smooth_frequency"] = smooth_frequency;
  j["phase_shift_fallback"] = phase_shift_fallback;
  j["phase_shift_fallback_confidence"] = phase_shift_fallback_confidence;
  j["frame_gain_method"] = FrameGainMethodName(frame_gain_method);
  j["correct_positions"] = correct_positions;
  j["min_lit"] = min_lit;
  j["min_modulation"] = min_modulation;
  j["max_unwrap_residual"] = max_unwrap_residual;
  j["max_combination_residual_px"] = max_combination_residual_px;
  j["confidence_t"] = confidence_t;
  j["min_confidence"] = min_confidence;
  j["systematic_phase_noise"] = systematic_phase_noise;
  j["reject_mixed_pixels"] = reject_mixed_pixels;
  j["mixed_pixels"] = {{"max_sigmas", mixed_pixels.max_sigmas},
                       {"outlier_footprints", mixed_pixels.outlier_footprints},
                       {"shadow_edge_ratio", mixed_pixels.shadow_edge_ratio},
                       {"dim_ratio", mixed_pixels.dim_ratio},
                       {"dim_sigmas", mixed_pixels.dim_sigmas},
                       {"dim_sharpness", mixed_pixels.dim_sharpness},
                       {"passes", mixed_pixels.passes}};
  j["grid_pixel_size_m"] = resample.pixel_size;
  j["grid_max_edge_footprints"] = resample.max_edge_footprints;
  return j;
}

PlanOptions ReconstructOptions::Plan() const {
  PlanOptions o;
  o.use_lens_shift = use_lens_shift;
  return o;
}

FrameLoadOptions ReconstructOptions::Load() const {
  FrameLoadOptions o;
  o.roi = roi;
  return o;
}

ClassifyOptions ReconstructOptions::Classify() const {
  ClassifyOptions o;
  o.mask_path = mask_path;
  o.min_lit = min_lit;
  return o;
}

GainOptions ReconstructOptions::Gains() const {
  GainOptions o;
  o.normalize_luminance = normalize_luminance;
  return o;
}

PhaseShiftStageOptions ReconstructOptions::PhaseShift(const Rig& rig) const {
  PhaseShiftStageOptions o;
  o.min_lit = min_lit;
  o.min_modulation = min_modulation;
  o.projector_gamma =
      rig.projector_response.kind == Response::Kind::kGamma ? rig.projector_response.gamma : 1.0;
  return o;
}

LensShiftStageOptions ReconstructOptions::LensShift() const {
  LensShiftStageOptions o;
  o.fitter = fitter;
  o.box_filter = lens_shift_box_filter;
  o.fit_frequency = fit_frequency;
  o.smooth_frequency = smooth_frequency;
  o.frame_gain_method = frame_gain_method;
  o.correct_positions = correct_positions;
  o.keep_offset_frequency = keep_diagnostics;
  return o;
}

CombineOptions ReconstructOptions::Combine() const {
  CombineOptions o;
  o.max_unwrap_residual = max_unwrap_residual;
  o.systematic_phase_noise = systematic_phase_noise;
  o.max_combination_residual_px = max_combination_residual_px;
  o.confidence_t = confidence_t;
  o.min_confidence = min_confidence;
  o.four_parameter_fit = fit_frequency && !smooth_frequency;
  o.phase_shift_fallback = phase_shift_fallback;
  o.phase_shift_fallback_confidence = phase_shift_fallback_confidence;
  o.reference_positions_to_phase_shift = correct_positions;
  o.isolated_max_region_px = isolated_max_region_px;
  o.keep_coarse = keep_diagnostics;
  return o;
}

}  // namespace mesoscan
