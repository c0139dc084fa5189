// Reconstruct(): the driver that chains and times the stages (see reconstruct.h).
#include "heightfield/reconstruct.h"

#include "core/parallel.h"
#include "heightfield/stage_height_field.h"
#include "heightfield/stage_mixed_pixels.h"

namespace mesoscan {

Scan Reconstruct(const Session& session, const ReconstructOptions& options,
                 ReconstructSummary* summary_out) {
  options.Check();
  ReconstructSummary local_summary;
  ReconstructSummary& sum = summary_out ? *summary_out : local_summary;
  sum = ReconstructSummary();
  StageTimer timer(&sum.timings_s);
  ThreadLimit thread_limit(options.num_threads);
  const Rig& rig = session.rig;
  if (rig.uncalibrated)
    MESOSCAN_BAD_INPUT(session.root.string()
                       << "/session.json: rig: a calibration session (no calibrated K, distortion "
                          "and world_from_device), expected a calibrated rig (mesoscan calibrate)");

  const ReconstructPlan plan = MakeReconstructPlan(session, options.Plan());
  const FrameStack stack = LoadFrames(session, plan.frames, options.Load());
  const RoiGrid grid = RoiGrid::Of(stack);
  timer.Stage("decode");
  PixelClasses classes =
      ClassifyPixels(stack, plan, rig.camera.width, rig.camera.height, options.Classify());
  PixelStates& state = classes.state;
  FrameGains gains =  // refined by the lens-shift stage (frame corrections)
      EstimateLuminanceGains(stack, plan, state, session.frames.size(), options.Gains());
  timer.Stage("normalize");
  const PhaseShiftPixels ps =
      DecodePhaseShift(stack, plan, gains, classes, options.PhaseShift(rig), &state);
  timer.Stage("phase_shift");
  const LensShiftPixels ls = FitLensShift(stack, plan, &gains, options.LensShift(), &state);
  timer.Stage("lens_shift");
  const CombinedPixels combined = CombinePhases(plan, ps, ls, options.Combine(), &state);
  timer.Stage("unwrap_combine");
  TriangulatedPoints tri =
      TriangulatePoints(rig, grid, combined, {options.keep_diagnostics, plan.axis}, &state);
  if (options.reject_mixed_pixels)
    RejectMixedPixels(grid, classes.white_level, tri.sigma_z, options.mixed_pixels, &tri.points,
                      &state);
  timer.Stage("triangulate");
  Scan scan;
  scan.points = std::move(tri.points);
  HeightFieldResult hf = MakeHeightField(scan.points, options.resample);
  scan.height = std::move(hf.height);
  scan.normals = std::move(hf.normals);
  timer.Stage("height_field");

  sum.pixels_total = static_cast<int64_t>(rig.camera.width) * rig.camera.height;
  sum.pixels_roi = classes.pixels_roi;
  sum.pixels_saturated = classes.pixels_saturated;
  sum.pixels_lit = ps.pixels_lit;
  sum.pixels_fitted = plan.use_lens_shift() ? ls.pixels_fitted : ps.pixels_lit;
  CountFinalStates(state, &sum);
  sum.predicted_depth_rms_m = PredictedDepthRms(grid, state, tri.sigma_z);
  sum.frame_gains = gains.session_gain;
  sum.frame_corrections = ls.frame_corrections;
  if (sum.frame_corrections.is_object())  // issue 13: the positions' constant, from phase shifting
    sum.frame_corrections["phase_shift_offset_px"] = combined.ls_offset_px;
  sum.unwrapping = plan.unwrapping;
  sum.axis = std::string(1, plan.axis);
  sum.used_lens_shift = plan.use_lens_shift();
  sum.lens_shift_frames = static_cast<int>(plan.ls_stack.size());
  sum.phase_shift_frames = plan.PhaseShiftFrames();
  if (options.keep_diagnostics)
    sum.diagnostics = CollectDiagnostics(rig, grid, ps, ls, combined, std::move(tri.dz_du));
  sum.total_s = timer.Total();
  scan.report["summary"] = sum.ToJson();
  scan.report["options"] = options.ToJson();
  return scan;
}

}  // namespace mesoscan
