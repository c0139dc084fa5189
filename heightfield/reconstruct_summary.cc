// ReconstructSummary: the report.json figures, counts and diagnostics of a reconstruction.
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "heightfield/reconstruct.h"

namespace mesoscan {

double ReconstructSummary::Seconds(const std::string& stage) const {
  for (const auto& [name, s] : timings_s)
    if (name == stage) return s;
  return 0.0;
}

std::string ReconstructSummary::BriefReport() const {
  std::ostringstream o;
  o << "reconstruct: " << pixels_valid << " points of " << pixels_roi << " pixels (" << pixels_lit
    << " lit, " << pixels_fitted << " fitted), " << (used_lens_shift ? "lens shift + " : "")
    << (phase_shift_frames > 0 ? "phase shift" : unwrapping)  // else a planned codec alone
    << (used_lens_shift ? "" : " only") << " (" << unwrapping << " unwrapping), " << total_s
    << " s";
  return o.str();
}

Json ReconstructSummary::ToJson() const {
  Json j;
  Json t = Json::object();
  for (const auto& [name, s] : timings_s) t[name] = s;
  t["total"] = total_s;
  t["last_frame"] = last_frame_s;
  j["timings_s"] = t;
  Json c = Json::object();
  for (const auto& [name, s] : cpu_s) c[name] = s;
  c["total"] = cpu_total_s;
  j["cpu_s"] = c;
  j["pixels"] = {{"total", pixels_total},
                 {"roi", pixels_roi},
                 {"lit", pixels_lit},
                 {"fitted", pixels_fitted},
                 {"valid", pixels_valid},
                 {"saturated", pixels_saturated},
                 {"rejected_unwrap", pixels_rejected_unwrap},
                 {"rejected_combination", pixels_rejected_combination},
                 {"rejected_confidence", pixels_rejected_confidence},
                 {"rejected_isolated", pixels_rejected_isolated},
                 {"rejected_inconsistent", pixels_rejected_inconsistent},
                 {"rejected_ambiguous", pixels_rejected_ambiguous},
                 {"rejected_uncertain", pixels_rejected_uncertain},
                 {"rejected_discontinuity", pixels_rejected_discontinuity}};
  j["frames"] = {{"lens_shift", lens_shift_frames}, {"phase_shift", phase_shift_frames}};
  j["frame_gains"] = frame_gains;
  j["frame_corrections"] = frame_corrections;
  if (!projector_response.is_null()) j["projector_response"] = projector_response;
  j["unwrapping"] = unwrapping;
  j["axis"] = axis;
  j["used_lens_shift"] = used_lens_shift;
  j["predicted_depth_rms_m"] = predicted_depth_rms_m;
  j["consistency"] = consistency.ToJson();
  return j;
}

void CountFinalStates(const PixelStates& state, ReconstructSummary* s) {
  for (const PixelState st : state) {
    s->pixels_rejected_discontinuity += st == PixelState::kDiscontinuity;
    s->pixels_valid += st == PixelState::kOk;
    s->pixels_rejected_unwrap += st == PixelState::kUnwrapFailed;
    s->pixels_rejected_combination += st == PixelState::kCombination;
    s->pixels_rejected_confidence += st == PixelState::kLowConfidence;
    s->pixels_rejected_isolated += st == PixelState::kIsolated;
    s->pixels_rejected_inconsistent += st == PixelState::kInconsistent;
    s->pixels_rejected_ambiguous += st == PixelState::kAmbiguous;
    s->pixels_rejected_uncertain += st == PixelState::kUncertain;
  }
}

double PredictedDepthRms(const RoiGrid& grid, const PixelStates& state,
                         const std::vector<float>& sigma_z) {
  double s2 = 0;
  int64_t n = 0;
  for (int y = 0; y < grid.height; y += 4)
    for (int x = 0; x < grid.width; x += 4) {
      const size_t i = static_cast<size_t>(y) * grid.width + x;
      if (state[i] == PixelState::kOk && std::isfinite(sigma_z[i])) {
        s2 += static_cast<double>(sigma_z[i]) * sigma_z[i];
        ++n;
      }
    }
  return n ? std::sqrt(s2 / n) : 0.0;
}

ReconstructDiagnostics CollectDiagnostics(const Rig& rig, const RoiGrid& grid,
                                          const PhaseShiftPixels& ps, const LensShiftPixels& ls,
                                          const CombinedPixels& combined, ImageF dz_du) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  const int w = grid.width, h = grid.height;
  const size_t np = grid.pixels();
  auto to_cam = [&](const std::vector<float>& v) {
    ImageF im(rig.camera.width, rig.camera.height, 1, kNaN);
    if (v.empty()) return im;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        im(x + grid.roi.x, y + grid.roi.y) = v[static_cast<size_t>(y) * w + x];
    return im;
  };
  ReconstructDiagnostics d;
  d.u_coarse = to_cam(combined.u_coarse);
  d.unwrap_residual = to_cam(combined.unwrap_residual);
  std::vector<float> mod(np, kNaN);
  for (size_t i = 0; i < np; ++i) {
    float m = std::numeric_limits<float>::infinity();
    for (size_t p = 0; p < ps.modulation.size(); ++p)
      m = std::min(m, ps.modulation[p][i] / ps.level[i]);
    mod[i] = std::isfinite(m) ? m : kNaN;
  }
  d.ps_modulation = to_cam(mod);
  d.white_level = to_cam(ps.level);
  d.ls_amplitude = to_cam(ls.amplitude);
  d.ls_offset = to_cam(ls.offset);
  d.ls_frequency = to_cam(ls.frequency);
  d.ls_residual_rms = to_cam(ls.residual_rms);
  d.ls_samples = to_cam(ls.samples);
  d.dz_du = std::move(dz_du);
  d.u = to_cam(combined.u);
  d.sigma_u = to_cam(combined.sigma_u);
  return d;
}

}  // namespace mesoscan
