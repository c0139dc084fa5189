// ReconstructOptions: the stages' checks and the report.json form.
#include "core/error.h"
#include "heightfield/reconstruct.h"

namespace mesoscan {

void ReconstructOptions::Check() const {
  plan.codecs.Check();
  load.Check();
  classify.Check();
  phase_shift.Check();
  combine.Check();
  consistency.Check();
  mixed_pixels.Check();
  resample.Check();
}

Json ReconstructOptions::ToJson() const {
  Json j;
  const PixelRect& roi = load.roi;
  j["roi"] = {roi.x, roi.y, roi.w, roi.h};
  j["mask"] = classify.mask_path;
  j["fitter"] = LensShiftFitterName(lens_shift.fitter);
  j["use_lens_shift"] = plan.use_lens_shift;
  j["normalize_luminance"] = gains.normalize_luminance;
  j["lens_shift_box_filter"] = lens_shift.box_filter;
  j["fit_frequency"] = lens_shift.fit_frequency;
  j["smooth_frequency"] = lens_shift.smooth_frequency;
  j["phase_shift_fallback"] = combine.phase_shift_fallback;
  j["phase_shift_fallback_confidence"] = combine.phase_shift_fallback_confidence;
  j["frame_gain_method"] = FrameGainMethodName(lens_shift.frame_gain_method);
  j["correct_positions"] = lens_shift.correct_positions;
  j["min_lit"] = classify.min_lit;
  j["min_modulation"] = phase_shift.min_modulation;
  j["max_unwrap_residual"] = phase_shift.max_unwrap_residual;
  j["max_combination_residual_px"] = combine.max_combination_residual_px;
  j["confidence_t"] = combine.confidence_t;
  j["min_confidence"] = combine.min_confidence;
  j["systematic_phase_noise"] = phase_shift.systematic_phase_noise;
  j["phase_harmonics"] = phase_shift.harmonics.mode == HarmonicsMode::kAuto ? "auto"
                         : phase_shift.harmonics.mode == HarmonicsMode::kOn ? "on"
                                                                            : "off";
  j["check_consistency"] = consistency.enabled;
  j["max_depth_sigma_m"] = consistency.max_depth_sigma_m;
  j["max_depth_sigma_per_footprint"] = consistency.max_depth_sigma_per_footprint;
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
  j["codecs"] = plan.codecs.ToJson();
  return j;
}

}  // namespace mesoscan
