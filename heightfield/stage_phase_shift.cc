#include "heightfield/stage_phase_shift.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/error.h"
#include "core/log.h"
#include "core/numbers.h"
#include "heightfield/phase_harmonics.h"

namespace mesoscan {

void PhaseShiftStageOptions::Check() const {
  if (!(min_modulation > 0 && min_modulation <= 0.5))
    MESOSCAN_BAD_INPUT("min_modulation: expected a value in (0, 0.5], got " << min_modulation);
  if (!(max_unwrap_residual > 0))
    MESOSCAN_BAD_INPUT("max_unwrap_residual: expected > 0, got " << max_unwrap_residual);
  if (!(systematic_phase_noise >= 0))
    MESOSCAN_BAD_INPUT("systematic_phase_noise: expected >= 0, got " << systematic_phase_noise);
  harmonics.Check();
}

namespace {

// One decoding pass over every period: the least-squares phases, modulations, residuals and
// level; `linearize_gamma`: plan.projector_gamma undone per sample (white/black frames).
PhaseShiftPixels DecodePass(const FrameStack& stack, const ReconstructPlan& plan,
                            const FrameGains& gains, const PixelClasses& classes,
                            const PhaseShiftStageOptions& options, bool linearize_gamma,
                            PixelStates* state_out) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  PixelStates& state = *state_out;
  const RoiGrid grid = RoiGrid::Of(stack);
  const int w = grid.width, h = grid.height;
  const size_t np = grid.pixels();
  const auto& periods = plan.periods;
  const int nper = static_cast<int>(periods.size());
  const bool has_white = plan.has_white();
  const double proj_gamma = plan.projector_gamma;
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
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
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

}  // namespace

PhaseShiftPixels DecodePhaseShift(const FrameStack& stack, const ReconstructPlan& plan,
                                  const FrameGains& gains, const PixelClasses& classes,
                                  const PhaseShiftStageOptions& options, PixelStates* state) {
  const bool gamma_known = std::abs(plan.projector_gamma - 1.0) > 1e-9;
  const bool linearize_gamma = gamma_known && plan.has_white();
  const bool estimate = options.harmonics.mode != HarmonicsMode::kOff && plan.periods.size() >= 2 &&
                        plan.periods_unwrap;
  if (!estimate) {
    if (gamma_known && !plan.has_white())
      MESOSCAN_LOG(kWarning) << plan.label
                             << ": projector gamma without white/black frames: sine patterns are "
                                "decoded as if linear (phase bias from harmonics)";
    return DecodePass(stack, plan, gains, classes, options, linearize_gamma, state);
  }
  // The phases as measured; the projector's harmonics estimated from them and undone where the
  // response is clearly non-linear; else the session's gamma (if any) undone per sample, as
  // without the estimate.
  const PixelStates before = linearize_gamma ? *state : PixelStates();
  PhaseShiftPixels out = DecodePass(stack, plan, gains, classes, options, false, state);
  ProjectorHarmonics harmonics = EstimateProjectorHarmonics(plan, out, *state, options.harmonics);
  const bool apply = harmonics.fitted && harmonics.reason.empty() &&
                     CorrectPhaseHarmonics(plan, *state, &harmonics, &out);
  if (harmonics.fitted) {
    std::ostringstream h;
    for (size_t n = 0; n < harmonics.harmonics.size(); ++n)
      h << (n ? ", " : "") << "h" << n + 2 << " " << harmonics.harmonics[n];
    std::ostringstream m;
    m << plan.label << ": projector response from " << harmonics.pixels << " pixels: nearest gamma "
      << harmonics.gamma << " (misfit " << harmonics.gamma_misfit_rad << " rad), harmonics "
      << h.str() << ", blur " << harmonics.blur_px << " px; plain phase error up to "
      << *std::max_element(harmonics.phase_error_rms_rad.begin(),
                           harmonics.phase_error_rms_rad.end())
      << " rad RMS, fit residual " << harmonics.residual_rms_rad
      << " rad: " << (apply ? "phases corrected" : harmonics.reason);
    if (apply)
      MESOSCAN_LOG(kInfo) << m.str();
    else
      MESOSCAN_LOG(kDebug) << m.str();
  }
  if (!apply && linearize_gamma) {
    *state = before;
    const Json response = harmonics.ToJson();
    out = DecodePass(stack, plan, gains, classes, options, true, state);
    out.projector_response = response;
    return out;
  }
  if (!apply && gamma_known)
    MESOSCAN_LOG(kWarning) << plan.label
                           << ": projector gamma without white/black frames: sine patterns are "
                              "decoded as if linear (phase bias from harmonics)";
  out.projector_response = harmonics.ToJson();
  return out;
}

namespace {

// Per-sample noise of pixel i from phase shifting alone: the phase-shift residuals (periods of
// K > 3 frames), else a floor of 1% of the white level.
double PhaseShiftSigma(const ReconstructPlan& plan, const PhaseShiftPixels& ps, size_t i) {
  double sigma = 0.01 * ps.level[i];
  double s2 = 0;
  int cnt = 0;
  for (size_t p = 0; p < plan.periods.size(); ++p) {
    const int K = static_cast<int>(plan.periods[p].stack_frames.size());
    if (K > 3) {
      s2 += ps.residual_rms[p][i] * ps.residual_rms[p][i] * K / (K - 3.0);
      ++cnt;
    }
  }
  if (cnt) sigma = std::sqrt(s2 / cnt);
  return sigma;
}

// The unwrapper's inputs of n pixels (pixel pixels[a] with per-sample noise sigmas[a]),
// pixel-major (th[a * nper + p]): per period a loop over the pixels (the divisions in vector
// lanes).
void UnwrapInputs(const PhaseShiftPixels& ps, const std::vector<WrappedPhaseSolver>& solvers,
                  double systematic_phase_noise, const size_t* pixels, size_t n,
                  const double* sigmas, std::vector<double>* th, std::vector<double>* wt) {
  const int nper = static_cast<int>(solvers.size());
  th->resize(n * nper), wt->resize(n * nper);
  const double sys2 = std::pow(systematic_phase_noise, 2);
  for (int p = 0; p < nper; ++p) {
    const WrappedPhaseSolver& solver = solvers[p];
    const float* th_p = ps.theta[p].data();
    const float* mod_p = ps.modulation[p].data();
    double* th_out = th->data() + p;
    double* wt_out = wt->data() + p;
    for (size_t a = 0; a < n; ++a) {
      const size_t i = pixels[a];
      th_out[a * nper] = th_p[i];
      const double var = solver.ThetaVariance(sigmas[a], mod_p[i]) + sys2;
      wt_out[a * nper] = 1.0 / var;
    }
  }
}

std::vector<WrappedPhaseSolver> SolversOf(const ReconstructPlan& plan) {
  std::vector<WrappedPhaseSolver> solvers;
  for (const auto& p : plan.periods) solvers.emplace_back(p.deltas);
  return solvers;
}

}  // namespace

PhaseShiftCodec::PhaseShiftCodec(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                                 const PhaseShiftStageOptions& options, double confidence_t)
    : plan_(plan),
      ps_(ps),
      options_(options),
      confidence_t_(confidence_t),
      solvers_(SolversOf(plan)) {
  if (plan.periods_unwrap)
    unwrapper_.emplace(plan.PeriodList(), plan.projector_width, options.max_unwrap_residual);
}

std::vector<int> PhaseShiftCodec::Frames() const {
  std::vector<int> frames;
  for (const PhasePeriod& p : plan_.periods)
    frames.insert(frames.end(), p.stack_frames.begin(), p.stack_frames.end());
  return frames;
}

void PhaseShiftCodec::SampleNoise(const size_t* pixels, size_t n, double* sigma) const {
  for (size_t a = 0; a < n; ++a)
    if (sigma[a] < 0) sigma[a] = PhaseShiftSigma(plan_, ps_, pixels[a]);
}

void PhaseShiftCodec::Decode(const size_t* pixels, size_t n, const double* noise,
                             CodecRecord* out) const {
  // The unwrapper's inputs, then every pixel unwrapped at once (four pixels at a time:
  // UnwrapAtMany at the hinted orders, else UnwrapMany). Scratch reused by each thread.
  thread_local std::vector<double> th, wt, hint;
  thread_local std::vector<UnwrapResult> unwrapped;
  const int nper = static_cast<int>(plan_.periods.size());
  if (!unwrapper_) {  // periodic: the one period's phase in cycles
    out->Resize(n);
    for (size_t a = 0; a < n; ++a) {
      const float theta = ps_.theta[0][pixels[a]];
      out->value[a] = theta / (2 * kPi);
      out->valid[a] = std::isfinite(theta);
      out->residual[a] = 0.0;
      out->consistency[a] = 1.0;
    }
    return;
  }
  UnwrapInputs(ps_, solvers_, options_.systematic_phase_noise, pixels, n, noise, &th, &wt);
  unwrapped.resize(n);
  if (ps_.u_unwrapped.size() == ps_.level.size()) {
    // The fringe orders phase shifting chose on its own (UnwrapPhaseShift), the mean and
    // residual with these weights; the full search where that fails.
    hint.resize(n);
    for (size_t a = 0; a < n; ++a) hint[a] = ps_.u_unwrapped.At(pixels[a]);
    unwrapper_->UnwrapAtMany(th.data(), wt.data(), hint.data(), static_cast<int>(n),
                             unwrapped.data());
    for (size_t a = 0; a < n; ++a)
      if (!unwrapped[a].valid)
        unwrapped[a] = unwrapper_->Unwrap(th.data() + a * nper, wt.data() + a * nper);
  } else {
    unwrapper_->UnwrapMany(th.data(), wt.data(), static_cast<int>(n), unwrapped.data());
  }
  out->Resize(n);
  for (size_t a = 0; a < n; ++a) {
    const UnwrapResult& ur = unwrapped[a];
    out->value[a] = ur.u;
    out->residual[a] = ur.residual;
    out->valid[a] = ur.valid;
    out->consistency[a] =
        nper > 1 ? 1.0 - std::pow(ur.residual / options_.max_unwrap_residual, 2) : 1.0;
  }
}

void PhaseShiftCodec::Describe(const size_t* pixels, const double* noise, const uint32_t* which,
                               size_t m, bool refined, CodecRecord* out) const {
  const auto& periods = plan_.periods;
  const int nper = static_cast<int>(periods.size());
  const auto& modulation = ps_.modulation;
  const auto& ps_res = ps_.residual_rms;
  // Refined pixels that fall back on this codec: the model errors (systematic_phase_noise)
  // count as in the unwrapping's weights.
  const double sys2 = refined ? std::pow(options_.systematic_phase_noise, 2) : 0.0;
  for (size_t k = 0; k < m; ++k) {
    const uint32_t a = which[k];
    const size_t i = pixels[a];
    const double sigma = noise[a];
    double info = 0.0;  // Fisher information of u from the periods
    for (int p = 0; p < nper; ++p)
      info += std::pow(2 * kPi / periods[p].period, 2) /
              (solvers_[p].ThetaVariance(sigma, modulation[p][i]) + sys2);
    out->sigma_px[a] = 1.0 / std::sqrt(info);
    double e = 0.0;
    for (int p = 0; p < nper; ++p)  // (no array: 3 frames, residual 0)
      if (!ps_res[p].empty()) e = std::max(e, std::pow(ps_res[p][i] / modulation[p][i], 2));
    out->confidence[a] = 1.0 - std::sqrt(e * confidence_t_);
  }
}

ColumnHints UnwrapPhaseShift(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const PixelStates& state, const PhaseShiftStageOptions& options) {
  const size_t np = state.size();
  const int nper = static_cast<int>(plan.periods.size());
  if (nper == 0 || !plan.periods_unwrap || static_cast<int>(ps.theta.size()) != nper ||
      ps.level.size() != np)
    return {};
  const PhaseShiftCodec codec(plan, ps, options);
  ColumnHints u = ColumnHints::For(np, plan.projector_width);
  if (u.size() != np) return {};
  constexpr int kBlock = 4096;
  const int blocks = static_cast<int>((np + kBlock - 1) / kBlock);
  tbb::parallel_for(tbb::blocked_range<int>(0, blocks, 8), [&](const auto& range) {
    const int b0 = range.begin(), b1 = range.end();
    std::vector<double> sigmas;
    std::vector<size_t> active;
    CodecRecord record;
    for (int b = b0; b < b1; ++b) {
      const size_t i_end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
      active.clear();
      for (size_t i = static_cast<size_t>(b) * kBlock; i < i_end; ++i)
        if (state[i] == PixelState::kActive) active.push_back(i);
      sigmas.assign(active.size(), -1.0);
      codec.SampleNoise(active.data(), active.size(), sigmas.data());
      for (size_t a = 0; a < active.size(); ++a)
        sigmas[a] = std::max(sigmas[a], 1e-4 * ps.level[active[a]]);
      codec.Decode(active.data(), active.size(), sigmas.data(), &record);
      for (size_t a = 0; a < active.size(); ++a)
        if (record.valid[a]) u.Set(active[a], record.value[a]);
    }
  });
  return u;
}

}  // namespace mesoscan
