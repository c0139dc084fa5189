// Reconstruct(): the driver that chains and times the stages (see reconstruct.h).
#include "heightfield/reconstruct.h"

#include <tbb/parallel_for.h>

#include <algorithm>

#include "heightfield/stage_height_field.h"
#include "heightfield/stage_mixed_pixels.h"
#include "heightfield/stage_stream.h"

namespace mesoscan {
namespace {

void CheckCalibrated(const Session& session) {
  if (session.rig.uncalibrated)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Key(session.root / "session.json", "rig"),
                          "a calibration session (no calibrated K, distortion and "
                          "world_from_device), expected a calibrated rig (mesoscan calibrate)");
}

// The front's wall times: decode (until the last frame), what of the overlapped sine-frame
// stages ran after it, then the lens-shift frames' gains ("normalize"); front_s is the whole.
void RecordFrontTimings(const StreamedFrames& front, double front_s, ReconstructSummary* sum) {
  sum->timings_s.back().second = front.decode_s;
  const double ps_s = std::max(0.0, front.phase_shift_s - front.decode_s);
  sum->timings_s.emplace_back("phase_shift", ps_s);
  sum->timings_s.emplace_back("normalize", std::max(0.0, front_s - front.decode_s - ps_s));
}

// The plan's figures, the frame gains and the lens-shift frame corrections.
void SummarizeFrames(const ReconstructPlan& plan, const FrameGains& gains,
                     const Json& frame_corrections, double ls_offset_px, ReconstructSummary* sum) {
  sum->frame_gains = gains.session_gain;
  sum->frame_corrections = frame_corrections;
  if (sum->frame_corrections.is_object())  // the positions' constant, from phase shifting
    sum->frame_corrections["phase_shift_offset_px"] = ls_offset_px;
  sum->unwrapping = plan.unwrapping;
  sum->axis = std::string(1, plan.axis);
  sum->used_lens_shift = plan.use_lens_shift();
  sum->lens_shift_frames = static_cast<int>(plan.ls_stack.size());
  sum->phase_shift_frames = plan.PhaseShiftFrames();
}

// The pixel counts (the final states) and the predicted depth RMS.
void SummarizePixels(const Rig& rig, const PixelClasses& classes, const RoiGrid& grid,
                     const std::vector<float>& sigma_z, ReconstructSummary* sum) {
  sum->pixels_total = static_cast<int64_t>(rig.camera.width) * rig.camera.height;
  sum->pixels_roi = classes.pixels_roi;
  sum->pixels_saturated = classes.pixels_saturated;
  CountFinalStates(classes.state, sum);
  sum->predicted_depth_rms_m = PredictedDepthRms(grid, classes.state, sigma_z);
}

}  // namespace

ReconstructedPoints ReconstructPoints(const Session& session, const ReconstructOptions& options,
                                      StageTimer* timer, ReconstructSummary* sum) {
  options.Check();
  const Rig& rig = session.rig;
  CheckCalibrated(session);
  ReconstructedPoints out;
  out.plan = MakeReconstructPlan(session, options.plan);
  const ReconstructPlan& plan = out.plan;
  // The stages' optional outputs that only the diagnostics read.
  CombineOptions combine = options.combine;
  combine.keep_coarse = options.keep_diagnostics;
  LensShiftStageOptions lens_shift = options.lens_shift;
  lens_shift.keep_offset_frequency = options.keep_diagnostics;
  // Decode, classify, gains and phase shift as one stream (stage_stream.h); each frame is
  // released after the last stage that reads it, the per-period arrays after combining.
  StreamedFrames front = DecodeAndPhaseShift(
      session, plan, {options.load, options.classify, options.gains, options.phase_shift});
  FrameStack& stack = front.stack;
  PixelClasses& classes = out.classes = std::move(front.classes);
  PixelStates& state = classes.state;
  FrameGains& gains = front.gains;  // refined by the lens-shift stage (frame corrections)
  PhaseShiftPixels& ps = out.ps = std::move(front.ps);
  const RoiGrid grid = out.grid = RoiGrid::Of(stack);
  classes.black_value = {};  // read by phase shifting only: 12.5 MB less at the peak (3 Mpx)
  RecordFrontTimings(front, timer->Stage("decode"), sum);
  out.last_frame_s = front.decode_s;
  // Lens shift: the refinement, with the frame corrections.
  LensShiftPixels& ls = out.ls = FitLensShift(stack, plan, &gains, lens_shift, &state);
  // The frames' pages go back to the kernel a frame per task (~300 MB at full resolution).
  tbb::parallel_for<int64_t>(0, stack.num_frames(),
                             [&](int64_t k) { stack.Release(static_cast<int>(k)); });
  stack = FrameStack();
  if (options.on_frames_released) options.on_frames_released();
  timer->Stage("lens_shift");
  // Combine: the fringe orders, paper Eq. 2 and 4, isolated fringe orders.
  CombinedPixels& combined = out.combined =
      CombinePhases(plan, ps, ls, combine, &state, options.phase_shift);
  RejectIsolatedColumns(grid, combine, &combined, &state);
  // Consistency: the frames' own model at every pixel (ps and ls are still whole here).
  ConsistencyOptions consistency = options.consistency;
  consistency.systematic_phase_noise = options.phase_shift.systematic_phase_noise;
  consistency.four_parameter_fit = ls.fit_parameters == 4;
  sum->consistency = CheckPhaseConsistency(plan, session, ps, ls, consistency, &combined, &state);
  sum->pixels_lit = ps.pixels_lit;
  sum->projector_response = ps.projector_response;
  sum->pixels_fitted = plan.use_lens_shift() ? ls.pixels_fitted : ps.pixels_lit;
  SummarizeFrames(plan, gains, ls.frame_corrections, combined.ls_offset_px, sum);
  if (classes.white_level.empty())  // the stream moved it to ps.level (a white frame)
    classes.white_level = options.keep_diagnostics ? ps.level : std::move(ps.level);
  if (!options.keep_diagnostics) {  // what the later stages do not read
    ps = PhaseShiftPixels();
    ls = LensShiftPixels();
    combined.u_coarse = {};
    combined.unwrap_residual = {};
  }
  timer->Stage("unwrap_combine");
  // Triangulate, then mixed pixels.
  TriangulatedPoints& tri = out.tri =
      TriangulatePoints(rig, grid, combined, {options.keep_diagnostics, plan.axis}, &state);
  if (options.reject_mixed_pixels)
    RejectMixedPixels(grid, classes.white_level, tri.sigma_z, options.mixed_pixels, &tri.points,
                      &state);
  // A code alone (no phase, no stripes) is exact to its blocks, not limited by noise: its depth
  // sigma is its resolution (points.exr sigma_z), not a doubt about the point.
  const bool quantised = plan.periods.empty() && !plan.use_lens_shift();
  if (options.consistency.enabled && !quantised)
    RejectUncertainPoints(grid, tri.sigma_z, options.consistency, rig.camera, &tri.points, &state);
  timer->Stage("triangulate");
  return out;
}

Scan Reconstruct(const Session& session, const ReconstructOptions& options,
                 ReconstructSummary* summary_out) {
  ReconstructSummary local_summary;
  ReconstructSummary& sum = summary_out ? *summary_out : local_summary;
  sum = ReconstructSummary();
  const double cpu0 = ProcessCpuSeconds();
  StageTimer timer(&sum.timings_s, &sum.cpu_s);
  ReconstructedPoints r = ReconstructPoints(session, options, &timer, &sum);
  Scan scan;
  scan.points = std::move(r.tri.points);
  HeightFieldResult hf = MakeHeightField(scan.points, options.resample);
  scan.height = std::move(hf.height);
  scan.normals = std::move(hf.normals);
  timer.Stage("height_field");

  SummarizePixels(session.rig, r.classes, r.grid, r.tri.sigma_z, &sum);
  if (options.keep_diagnostics)
    sum.diagnostics =
        CollectDiagnostics(session.rig, r.grid, r.ps, r.ls, r.combined, std::move(r.tri.dz_du));
  sum.total_s = timer.Total();
  sum.cpu_total_s = ProcessCpuSeconds() - cpu0;
  sum.last_frame_s = r.last_frame_s;
  scan.report["summary"] = sum.ToJson();
  scan.report["options"] = options.ToJson();
  return scan;
}

}  // namespace mesoscan
