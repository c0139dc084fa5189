#include "heightfield/stage_gains.h"

#include <algorithm>
#include <cmath>

#include "core/numbers.h"

namespace mesoscan {

FrameGains UnitGains(const ReconstructPlan& plan, size_t session_frames) {
  FrameGains g;
  g.session_gain.assign(session_frames, 1.0);
  g.inv_gain.assign(plan.frames.size(), 1.0f);
  return g;
}

FrameGains EstimateLuminanceGains(const FrameStack& stack, const ReconstructPlan& plan,
                                  const PixelStates& state, size_t session_frames,
                                  const GainOptions& options) {
  FrameGains g = UnitGains(plan, session_frames);
  EstimateLuminanceGains(stack, plan, state, GainGroup::kPhaseShift, options, &g);
  EstimateLuminanceGains(stack, plan, state, GainGroup::kLensShift, options, &g);
  return g;
}

void EstimateLuminanceGains(const FrameStack& stack, const ReconstructPlan& plan,
                            const PixelStates& state, GainGroup group, const GainOptions& options,
                            FrameGains* gains) {
  FrameGains& g = *gains;
  if (!options.normalize_luminance) return;
  const size_t np = state.size();
  std::vector<uint32_t> sample;
  size_t n_active = 0;
  for (size_t i = 0; i < np; ++i) n_active += state[i] == PixelState::kActive;
  const size_t stride = std::max<size_t>(1, n_active / 20000);
  for (size_t i = 0, c = 0; i < np; ++i)
    if (state[i] == PixelState::kActive && (c++ % stride) == 0)
      sample.push_back(static_cast<uint32_t>(i));
  auto apply = [&](const GainModel& m, const std::vector<double>& gains) {
    for (size_t k = 0; k < m.frames.size(); ++k) {
      g.inv_gain[m.frames[k]] = static_cast<float>(1.0 / gains[k]);
      g.session_gain[plan.frames[m.frames[k]]] = gains[k];
    }
  };
  if (group == GainGroup::kPhaseShift) {
    // Sine frames: a DC shared by every period, a cosine and a sine per period.
    GainModel ps;
    const auto& periods = plan.periods;
    const int nper = static_cast<int>(periods.size());
    for (int p = 0; p < nper; ++p)
      for (size_t k = 0; k < periods[p].stack_frames.size(); ++k) {
        std::vector<double> row(1 + 2 * nper, 0.0);
        row[0] = 1.0;
        row[1 + 2 * p] = std::cos(periods[p].deltas[k]);
        row[2 + 2 * p] = -std::sin(periods[p].deltas[k]);
        ps.frames.push_back(periods[p].stack_frames[k]);
        ps.design.push_back(row);
      }
    apply(ps, EstimateFrameGains(stack, ps, sample));
  }
  if (group == GainGroup::kLensShift && plan.use_lens_shift()) {
    // Lens-shift frames: DC plus the nominal sinusoid and its first two derivatives by
    // frequency (x^m cos, x^m sin; the per-pixel frequency deviates from nominal by several
    // percent, which the gains must not absorb). Note: jitter along the sinusoid itself
    // (the part that biases the phase, ~jitter * sqrt(2/N) * d/a rad) is absorbed by each
    // pixel's fit and cannot be told from the pattern without a spatial assumption; frame
    // averages were tried and are worse unless the view holds hundreds of stripe periods.
    const double centre = plan.LensShiftCentre();
    GainModel ls;
    for (size_t k = 0; k < plan.ls_stack.size(); ++k) {
      const double x = plan.ls_shift_px[k] - centre, ph = kPi * x;
      ls.frames.push_back(plan.ls_stack[k]);
      ls.design.push_back({1.0, std::cos(ph), std::sin(ph), x * std::cos(ph), x * std::sin(ph),
                           x * x * std::cos(ph), x * x * std::sin(ph)});
    }
    apply(ls, EstimateFrameGains(stack, ls, sample));
  }
}

}  // namespace mesoscan
