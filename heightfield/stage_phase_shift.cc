#include "heightfield/stage_phase_shift.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/error.h"
#include "core/log.h"
#include "core/parallel.h"
#include "heightfield/phase_shift.h"

namespace mesoscan {

void PhaseShiftStageOptions::Check() const {
  if (!(min_modulation > 0 && min_modulation <= 0.5))
    MESOSCAN_BAD_INPUT("min_modulation: expected a value in (0, 0.5], got " << min_modulation);
}

PhaseShiftPixels DecodePhaseShift(const FrameStack& stack, const ReconstructPlan& plan,
                                  const FrameGains& gains, const PixelClasses& classes,
                                  const PhaseShiftStageOptions& options, PixelStates* state_out) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  PixelStates& state = *state_out;
  const RoiGrid grid = RoiGrid::Of(stack);
  const int w = grid.width, h = grid.height;
  const size_t np = grid.pixels();
  const auto& periods = plan.periods;
  const int nper = static_cast<int>(periods.size());
  const bool has_white = plan.has_white();
  const double proj_gamma = plan.projector_gamma;
  const bool linearize_gamma = std::abs(proj_gamma - 1.0) > 1e-9 && has_white;
  if (std::abs(proj_gamma - 1.0) > 1e-9 && !has_white)
    MESOSCAN_LOG(kWarning) << plan.label
                           << ": projector gamma without white/black frames: sine patterns are "
                              "decoded as if linear (phase bias from harmonics)";
  std::vector<WrappedPhaseSolver> solvers;
  for (const auto& p : periods) solvers.emplace_back(p.deltas);
  const std::vector<float>& white_level = classes.white_level;
  const std::vector<float>& black_value = classes.black_value;
  const std::vector<float>& inv_gain = gains.inv_gain;

  PhaseShiftPixels out;
  out.theta.assign(nper, std::vector<float>(np, kNaN));
  out.modulation.assign(nper, std::vector<float>(np, kNaN));
  out.residual_rms.resize(nper);  // three samples fit exactly: no residual array (peak RSS)
  for (int p = 0; p < nper; ++p)
    if (periods[p].stack_frames.size() > 3) out.residual_rms[p].assign(np, kNaN);
  out.level.assign(np, kNaN);
  auto& theta = out.theta;
  auto& modulation = out.modulation;
  auto& level = out.level;
  ParallelForRows(h, [&](int y0, int y1) {
    std::vector<float> buf;
    std::vector<WrappedPhaseSolver::Result> solved;  // SolveMany's (without gamma)
    const size_t i0 = static_cast<size_t>(y0) * w, n = static_cast<size_t>(y1 - y0) * w;
    for (int p = 0; p < nper; ++p) {
      const int K = static_cast<int>(periods[p].stack_frames.size());
      buf.resize(static_cast<size_t>(K) * n);
      for (int k = 0; k < K; ++k) {
        const int sk = periods[p].stack_frames[k];
        stack.Gather(sk, i0, n, buf.data() + k * n);
        const float g = inv_gain[sk];
        for (size_t j = 0; j < n; ++j) buf[k * n + j] *= g;
      }
      constexpr size_t kTile = 256;  // SolveMany's results per tile (they stay in L1)
      solved.resize(kTile);
      for (size_t j = 0; j < n; ++j) {
        if (!linearize_gamma && j % kTile == 0)  // every pixel (a few not kActive: solved anyway)
          solvers[p].SolveMany(buf.data() + j, n, static_cast<int>(std::min(kTile, n - j)),
                               solved.data());
        const size_t i = i0 + j;
        if (state[i] != PixelState::kActive) continue;
        if (linearize_gamma) {
          // v^g is what the camera sees (relative to white); undo it per sample.
          const float wl = white_level[i], bl = black_value[i];
          for (int k = 0; k < K; ++k) {
            float& s = buf[k * n + j];
            const double v = std::clamp((s - bl) / wl, 0.0f, 1.0f);
            s = static_cast<float>(std::pow(v, 1.0 / proj_gamma) * wl);
          }
        }
        const auto r = linearize_gamma ? solvers[p].Solve(buf.data() + j, static_cast<int>(n))
                                       : solved[j % kTile];
        if (!r.valid) continue;
        theta[p][i] = r.theta;
        modulation[p][i] = r.modulation;
        if (!out.residual_rms[p].empty()) out.residual_rms[p][i] = r.residual_rms;
        if (p == 0 && !has_white) level[i] = 2.0f * r.offset;
      }
    }
    for (size_t j = 0; j < n; ++j) {
      const size_t i = i0 + j;
      if (state[i] != PixelState::kActive) continue;
      if (has_white) level[i] = white_level[i];
      if (!(level[i] >= classes.min_lit)) {
        state[i] = PixelState::kUnlit;
        continue;
      }
      for (int p = 0; p < nper; ++p)
        if (!(modulation[p][i] >= options.min_modulation * level[i]))
          state[i] = PixelState::kUnmodulated;
    }
  });
  for (size_t i = 0; i < np; ++i) out.pixels_lit += state[i] == PixelState::kActive;
  return out;
}

}  // namespace mesoscan
