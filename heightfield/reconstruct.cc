// Reconstruct(): the driver that chains and times the stages (see reconstruct.h).
#include "heightfield/reconstruct.h"

#include <algorithm>

#include "core/parallel.h"
#include "heightfield/stage_height_field.h"
#include "heightfield/stage_mixed_pixels.h"
#include "heightfield/stage_stream.h"

namespace mesoscan {

Scan Reconstruct(const Session& session, const ReconstructOptions& options,
                 ReconstructSummary* summary_out) {
  options.Check();
  ReconstructSummary local_summary;
  ReconstructSummary& sum = summary_out ? *summary_out : local_summary;
  sum = ReconstructSummary();
  const double cpu0 = ProcessCpuSeconds();
  StageTimer timer(&sum.timings_s, &sum.cpu_s);
  ThreadLimit thread_limit(options.num_threads);
  const Rig& rig = session.rig;
  if (rig.uncalibrated)
    MESOSCAN_BAD_INPUT(session.root.string()
                       << "/session.json: rig: a calibration session (no calibrated K, distortion "
                          "and world_from_device), expected a calibrated rig (mesoscan calibrate)");

  const ReconstructPlan plan = MakeReconstructPlan(session, options.Plan());
  // Decode, classify, gains and phase shift as one stream (stage_stream.h); each frame is
  // released after the last stage that reads it, the per-period arrays after combining.
  StreamedFrames front =
      DecodeAndPhaseShift(session, plan, {options.Load(), options.Classify(), options.Gains(),
                                          options.PhaseShift(rig)});
  FrameStack& stack = front.stack;
  PixelClasses& classes = front.classes;
  PixelStates& state = classes.state;
  FrameGains& gains = front.gains;  // refined by the lens-shift stage (frame corrections)
  PhaseShiftPixels& ps = front.ps;
  const RoiGrid grid = RoiGrid::Of(stack);
  classes.black_value = {};  // read by phase shifting only: 12.5 MB less at the peak (3 Mpx)
  {  // decode (until the last frame), what of the overlapped sine-frame stages ran after it,
     // then the lens-shift frames' gains
    const double front_s = timer.Stage("decode");
    sum.timings_s.back().second = front.decode_s;
    const double ps_s = std::max(0.0, front.phase_shift_s - front.decode_s);
    sum.timings_s.emplace_back("phase_shift", ps_s);
    sum.timings_s.emplace_back("normalize", std::max(0.0, front_s - front.decode_s - ps_s));
  }
  LensShiftPixels ls = FitLensShift(stack, plan, &gains, options.LensShift(), &state);
  stack = FrameStack();
  if (options.on_frames_released) options.on_frames_released();
  timer.Stage("lens_shift");
  CombinedPixels combined = CombinePhases(plan, ps, ls, options.Combine(), &state);
  const int64_t pixels_lit = ps.pixels_lit, pixels_fitted = ls.pixels_fitted;
  const Json frame_corrections = ls.frame_corrections;
  if (classes.white_level.empty())  // the stream moved it to ps.level (a white frame)
    classes.white_level = options.keep_diagnostics ? ps.level : std::move(ps.level);
  if (!options.keep_diagnostics) {
    ps = PhaseShiftPixels();
    ls = LensShiftPixels();
    combined.u_coarse = {};
    combined.unwrap_residual = {};
  }
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
  sum.pixels_lit = pixels_lit;
  sum.pixels_fitted = plan.use_lens_shift() ? pixels_fitted : pixels_lit;
  CountFinalStates(state, &sum);
  sum.predicted_depth_rms_m = PredictedDepthRms(grid, state, tri.sigma_z);
  sum.frame_gains = gains.session_gain;
  sum.frame_corrections = frame_corrections;
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
  sum.cpu_total_s = ProcessCpuSeconds() - cpu0;
  sum.last_frame_s = front.decode_s;
  scan.report["summary"] = sum.ToJson();
  scan.report["options"] = options.ToJson();
  return scan;
}

}  // namespace mesoscan
