#include "heightfield/stage_gains.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>

#include "core/error.h"
#include "core/numbers.h"
#include "heightfield/phase_shift.h"

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

PhaseReference MakePhaseReference(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                                  const PixelStates& state, int max_pixels) {
  PhaseReference ref;
  const int nper = static_cast<int>(plan.periods.size());
  const size_t np = state.size();
  if (!plan.use_lens_shift() || nper == 0 || static_cast<int>(ps.theta.size()) != nper ||
      ps.level.size() != np)
    return ref;
  for (int p = 0; p < nper; ++p)
    if (ps.theta[p].size() != np || ps.modulation[p].size() != np) return ref;
  std::optional<TemporalUnwrapper> unwrapper;
  std::vector<WrappedPhaseSolver> solvers;
  try {
    unwrapper.emplace(plan.PeriodList(), plan.projector_width);
    for (const auto& p : plan.periods) solvers.emplace_back(p.deltas);
  } catch (const Error&) {
    return ref;  // the combine stage names the problem
  }
  auto usable = [&](size_t i) {
    if (state[i] != PixelState::kActive || !(ps.level[i] > 0)) return false;
    for (int p = 0; p < nper; ++p)
      if (!std::isfinite(ps.theta[p][i]) || !(ps.modulation[p][i] >= 0.05 * ps.level[i]))
        return false;
    return true;
  };
  // Counted in parallel (a pass over eight arrays of every pixel).
  const size_t n_usable = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, np, 1 << 16), size_t{0},
      [&](const tbb::blocked_range<size_t>& r, size_t n) {
        for (size_t i = r.begin(); i < r.end(); ++i) n += usable(i);
        return n;
      },
      std::plus<size_t>());
  if (n_usable == 0) return ref;
  // About 1 in `stride` of the usable pixels, scattered by a multiplicative hash of the index (a
  // regular stride could fall on the same few columns of every row, i.e. the same few stripe
  // phases).
  const uint64_t stride =
      std::max<uint64_t>(1, (n_usable + max_pixels - 1) / std::max(1, max_pixels));
  // The sample (a 64-bit division per pixel and the usable test) in parallel over fixed chunks,
  // kept in pixel order; the rest per sample pixel as before.
  constexpr size_t kChunk = 1 << 16;
  const size_t n_chunks = (np + kChunk - 1) / kChunk;
  std::vector<std::vector<uint32_t>> chunk_pixels(n_chunks);
  tbb::parallel_for<int64_t>(0, static_cast<int64_t>(n_chunks), [&](int64_t c) {
    const size_t end = std::min(np, (static_cast<size_t>(c) + 1) * kChunk);
    for (size_t i = static_cast<size_t>(c) * kChunk; i < end; ++i)
      if ((static_cast<uint64_t>(i) * 2654435761ull >> 7) % stride == 0 && usable(i))
        chunk_pixels[c].push_back(static_cast<uint32_t>(i));
  });
  std::vector<uint32_t> sample;
  for (const std::vector<uint32_t>& chunk : chunk_pixels)
    sample.insert(sample.end(), chunk.begin(), chunk.end());
  std::vector<double> th(nper), wt(nper);
  for (const uint32_t i : sample) {
    const double sigma = 0.01 * ps.level[i];
    double info = 0;
    for (int p = 0; p < nper; ++p) {
      th[p] = ps.theta[p][i];
      const double var = solvers[p].ThetaVariance(sigma, ps.modulation[p][i]) + 0.02 * 0.02;
      wt[p] = 1.0 / var;
      info += std::pow(2 * kPi / plan.periods[p].period, 2) * wt[p];
    }
    const UnwrapResult ur = unwrapper->Unwrap(th.data(), wt.data());
    if (!ur.valid || !(info > 0)) continue;
    for (int p = 0; p < nper; ++p) {
      // d phi_ls / d theta_p = -pi du/dtheta_p, du/dtheta_p = omega_p P / (2 pi).
      const double P = plan.periods[p].period, rate = 2 * kPi / P;
      const double omega = wt[p] * rate * rate / info;
      const double s = -kPi * omega * P / (2 * kPi);
      const double r = ps.level[i] / ps.modulation[p][i];
      ref.nuisance.push_back(static_cast<float>(s * r * std::cos(th[p])));
      ref.nuisance.push_back(static_cast<float>(s * r * std::sin(th[p])));
      ref.nuisance.push_back(static_cast<float>(s * std::cos(2 * th[p])));
      ref.nuisance.push_back(static_cast<float>(s * std::sin(2 * th[p])));
    }
    ref.pixels.push_back(static_cast<uint32_t>(i));
    ref.u_px.push_back(static_cast<float>(ur.u));
    ref.sigma_u_px.push_back(static_cast<float>(1.0 / std::sqrt(info)));
  }
  ref.ls_centre_px = plan.LensShiftCentre();
  ref.nuisance_per_pixel = 4 * nper;
  return ref;
}

namespace {
// The frame gains of one group (EstimateLuminanceGains without the phase reference).
void EstimateGainsOfGroup(const FrameStack& stack, const ReconstructPlan& plan,
                          const PixelStates& state, GainGroup group, FrameGains* gains,
                          const GatheredSamples* gathered);
}  // namespace

void EstimateLuminanceGains(const FrameStack& stack, const ReconstructPlan& plan,
                            const PixelStates& state, GainGroup group, const GainOptions& options,
                            FrameGains* gains, const PhaseShiftPixels* ps,
                            const GatheredSamples* gathered) {
  FrameGains& g = *gains;
  // The lens-shift frames' phase reference and their gains are independent (different members
  // of g, read-only inputs): computed at once, on the otherwise idle second core right after the
  // last frame (~45 and ~80 ms at full resolution, both serial).
  const auto frame_gains = [&] {
    if (options.normalize_luminance) EstimateGainsOfGroup(stack, plan, state, group, &g, gathered);
  };
  if (group == GainGroup::kLensShift && ps) {
    tbb::parallel_invoke([&] { g.phase_reference = MakePhaseReference(plan, *ps, state); },
                         frame_gains);
  } else {
    frame_gains();
  }
}

std::vector<uint32_t> GainSample(const PixelStates& state) {
  const size_t np = state.size();
  // Every stride-th active pixel (the first, then a countdown), per block of pixels on the pool:
  // the blocks' active counts, then each block's picks from its first active pixel's rank.
  constexpr size_t kBlock = 1 << 16;
  const size_t blocks = (np + kBlock - 1) / kBlock;
  std::vector<size_t> active_before(blocks + 1, 0);
  tbb::parallel_for<int64_t>(0, static_cast<int64_t>(blocks), [&](int64_t b) {
    const size_t end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
    size_t n = 0;
    for (size_t i = static_cast<size_t>(b) * kBlock; i < end; ++i)
      n += state[i] == PixelState::kActive;
    active_before[b + 1] = n;
  });
  for (size_t b = 0; b < blocks; ++b) active_before[b + 1] += active_before[b];
  const size_t stride = std::max<size_t>(1, active_before[blocks] / 20000);
  std::vector<std::vector<uint32_t>> picks(blocks);
  tbb::parallel_for<int64_t>(0, static_cast<int64_t>(blocks), [&](int64_t b) {
    const size_t end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
    size_t left = (stride - active_before[b] % stride) % stride;  // actives until the next pick
    for (size_t i = static_cast<size_t>(b) * kBlock; i < end; ++i) {
      if (state[i] != PixelState::kActive) continue;
      if (left == 0) {
        picks[b].push_back(static_cast<uint32_t>(i));
        left = stride;
      }
      --left;
    }
  });
  std::vector<uint32_t> sample;
  for (const std::vector<uint32_t>& p : picks) sample.insert(sample.end(), p.begin(), p.end());
  return sample;
}

namespace {

void EstimateGainsOfGroup(const FrameStack& stack, const ReconstructPlan& plan,
                          const PixelStates& state, GainGroup group, FrameGains* gains,
                          const GatheredSamples* gathered) {
  FrameGains& g = *gains;
  const bool use_gathered = gathered && group == GainGroup::kLensShift && !stack.is_float() &&
                            gathered->Complete(plan.ls_stack);
  const std::vector<uint32_t> sample = use_gathered ? std::vector<uint32_t>() : GainSample(state);
  auto apply = [&](const GainModel& m, const std::vector<double>& gains) {
    for (size_t k = 0; k < m.frames.size(); ++k) {
      g.inv_gain[m.frames[k]] = static_cast<float>(1.0 / gains[k]);
      g.session_gain[plan.frames[m.frames[k]]] = gains[k];
    }
  };
  if (group == GainGroup::kPhaseShift && !plan.periods.empty()) {
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
    if (use_gathered) {
      // The samples gathered while the frames decoded, in the stack's units.
      const size_t n = gathered->pixels.size();
      std::vector<float> by_frame(ls.frames.size() * n);
      tbb::parallel_for<int64_t>(0, static_cast<int64_t>(ls.frames.size()), [&](int64_t k) {
        const std::vector<uint16_t>& codes = gathered->codes[ls.frames[k]];
        float* dst = by_frame.data() + static_cast<size_t>(k) * n;
        for (size_t j = 0; j < n; ++j) dst[j] = stack.Linear(codes[j]);
      });
      apply(ls, EstimateFrameGains(by_frame, n, ls));
    } else {
      apply(ls, EstimateFrameGains(stack, ls, sample));
    }
  }
}

}  // namespace

}  // namespace mesoscan
