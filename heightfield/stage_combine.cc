#include "heightfield/stage_combine.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "heightfield/phase_shift.h"

namespace mesoscan {
namespace {

double Wrap2Pi(double a) {
  // fmod is exact: within one period either way it returns a itself (the libm call is skipped).
  if (std::abs(a) < 2 * kPi) return a < 0 ? a + 2 * kPi : a;
  a = std::fmod(a, 2 * kPi);
  return a < 0 ? a + 2 * kPi : a;
}

}  // namespace

void CombineOptions::Check() const {
  if (!(max_unwrap_residual > 0))
    MESOSCAN_BAD_INPUT("max_unwrap_residual: expected > 0, got " << max_unwrap_residual);
  if (!(systematic_phase_noise >= 0))
    MESOSCAN_BAD_INPUT("systematic_phase_noise: expected >= 0, got " << systematic_phase_noise);
  if (!(max_combination_residual_px > 0 && max_combination_residual_px < 1))
    MESOSCAN_BAD_INPUT("max_combination_residual_px: expected a value in (0, 1), got "
                       << max_combination_residual_px);
  if (!(confidence_t > 0)) MESOSCAN_BAD_INPUT("confidence_t: expected > 0, got " << confidence_t);
  if (!(min_confidence >= 0 && min_confidence < 1))
    MESOSCAN_BAD_INPUT("min_confidence: expected a value in [0, 1), got " << min_confidence);
  if (!(phase_shift_fallback_confidence > 0 && phase_shift_fallback_confidence <= 1))
    MESOSCAN_BAD_INPUT("phase_shift_fallback_confidence: expected a value in (0, 1], got "
                       << phase_shift_fallback_confidence);
  if (isolated_max_region_px < 0)
    MESOSCAN_BAD_INPUT("isolated_max_region_px: expected >= 0, got " << isolated_max_region_px);
}

// std::lround for |v| < 2^31 without the libm call (3 M calls per full-resolution scan): v - its
// truncation is exact there, so the half-way test is too.
long RoundHalfAway(double v) {
  const long t = static_cast<long>(v);  // rounds towards zero
  const double frac = v - static_cast<double>(t);
  return frac >= 0.5 ? t + 1 : frac <= -0.5 ? t - 1 : t;
}

double RoundHalfAwayD(double v) {
  if (!(std::abs(v) < 4503599627370496.0)) return std::round(v);  // 2^52: already an integer
  const double t = static_cast<double>(static_cast<int64_t>(v));  // truncated, exact
  const double frac = v - t;                                      // exact
  const double r = frac >= 0.5 ? t + 1 : frac <= -0.5 ? t - 1 : t;
  return r == 0 ? std::copysign(0.0, v) : r;  // std::round keeps the sign of a zero
}

namespace {

// Did the lens-shift stage estimate (and apply) per-frame shifter positions?
bool PositionsEstimated(const Json& fc) {
  if (!fc.is_object() || !fc.contains("model") || !fc["model"].is_string()) return false;
  if (fc.contains("valid") && fc["valid"].is_boolean() && !fc["valid"].get<bool>()) return false;
  return fc["model"].get<std::string>().find("positions") != std::string::npos;
}

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

// The unwrapper's inputs of one block's active pixels (sigmas[a], pixel active[a]), pixel-major
// (th[a * nper + p]): per period a loop over the pixels (the divisions in vector lanes).
void UnwrapInputs(const PhaseShiftPixels& ps, const std::vector<WrappedPhaseSolver>& solvers,
                  double systematic_phase_noise, const std::vector<size_t>& active,
                  const std::vector<double>& sigmas, std::vector<double>* th,
                  std::vector<double>* wt) {
  const size_t na = active.size();
  const int nper = static_cast<int>(solvers.size());
  th->resize(na * nper), wt->resize(na * nper);
  const double sys2 = std::pow(systematic_phase_noise, 2);
  for (int p = 0; p < nper; ++p) {
    const WrappedPhaseSolver& solver = solvers[p];
    const float* th_p = ps.theta[p].data();
    const float* mod_p = ps.modulation[p].data();
    double* th_out = th->data() + p;
    double* wt_out = wt->data() + p;
    for (size_t a = 0; a < na; ++a) {
      const size_t i = active[a];
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

ColumnHints UnwrapPhaseShift(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const PixelStates& state, const CombineOptions& options) {
  const size_t np = state.size();
  const int nper = static_cast<int>(plan.periods.size());
  if (nper == 0 || static_cast<int>(ps.theta.size()) != nper || ps.level.size() != np) return {};
  const TemporalUnwrapper unwrapper(plan.PeriodList(), plan.projector_width,
                                    options.max_unwrap_residual);
  const std::vector<WrappedPhaseSolver> solvers = SolversOf(plan);
  ColumnHints u = ColumnHints::For(np, plan.projector_width);
  if (u.size() != np) return {};
  constexpr int kBlock = 4096;
  const int blocks = static_cast<int>((np + kBlock - 1) / kBlock);
  ParallelForRows(blocks, [&](int b0, int b1) {
    std::vector<double> th, wt, sigmas;
    std::vector<size_t> active;
    std::vector<UnwrapResult> unwrapped;
    for (int b = b0; b < b1; ++b) {
      const size_t i_end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
      sigmas.clear(), active.clear();
      for (size_t i = static_cast<size_t>(b) * kBlock; i < i_end; ++i) {
        if (state[i] != PixelState::kActive) continue;
        sigmas.push_back(std::max(PhaseShiftSigma(plan, ps, i), 1e-4 * ps.level[i]));
        active.push_back(i);
      }
      UnwrapInputs(ps, solvers, options.systematic_phase_noise, active, sigmas, &th, &wt);
      unwrapped.resize(active.size());
      unwrapper.UnwrapMany(th.data(), wt.data(), static_cast<int>(active.size()), unwrapped.data());
      for (size_t a = 0; a < active.size(); ++a)
        if (unwrapped[a].valid) u.Set(active[a], unwrapped[a].u);
    }
  });
  return u;
}

CombinedPixels CombinePhases(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                             const LensShiftPixels& ls, const CombineOptions& options,
                             PixelStates* state_out) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  PixelStates& state = *state_out;
  const size_t np = state.size();
  const auto& periods = plan.periods;
  const int nper = static_cast<int>(periods.size());
  const bool use_ls = !ls.empty();
  const TemporalUnwrapper unwrapper(plan.PeriodList(), plan.projector_width,
                                    options.max_unwrap_residual);
  const std::vector<WrappedPhaseSolver> solvers = SolversOf(plan);
  const auto& modulation = ps.modulation;
  const auto& ps_res = ps.residual_rms;
  const auto& level = ps.level;

  CombinedPixels out;
  const bool reference_positions = use_ls && options.reference_positions_to_phase_shift &&
                                   PositionsEstimated(ls.frame_corrections);
  const bool coarse = options.keep_coarse || reference_positions;
  // One array per task (12.5 MB each at 3 Mpx: their page faults and fills were ~65 MB on
  // one core while the other waited).
  ParallelFor(6, [&](int64_t a) {
    switch (a) {
      case 0:
        out.u.assign(np, kNaN);
        break;
      case 1:
        if (coarse) out.u_coarse.assign(np, kNaN);
        break;
      case 2:
        if (coarse) out.unwrap_residual.assign(np, kNaN);
        break;
      case 3:
        out.confidence.assign(np, 0.0f);
        break;
      case 4:
        out.sigma_u.assign(np, kNaN);
        break;
      default:
        out.source.assign(np, use_ls ? 0 : 1);
        break;
    }
  });
  const bool fallback = use_ls && options.phase_shift_fallback;
  const bool hinted = ps.u_unwrapped.size() == np;
  // Rows of the ROI do not matter here: blocks of 4096 pixels.
  constexpr int kBlock = 4096;
  const int blocks = static_cast<int>((np + kBlock - 1) / kBlock);
  ParallelForRows(blocks, [&](int b0, int b1) {
    // Per block: the unwrapper's inputs of the active pixels first, then all of them unwrapped
    // at once (four pixels at a time: UnwrapAtMany at the hinted orders, else UnwrapMany), then
    // the rest per pixel.
    std::vector<double> th, wt, sigmas, hint;
    std::vector<size_t> active;
    std::vector<UnwrapResult> unwrapped;
    for (int b = b0; b < b1; ++b) {
      const size_t i_begin = static_cast<size_t>(b) * kBlock;
      const size_t i_end = std::min(np, i_begin + kBlock);
      th.clear(), wt.clear(), sigmas.clear(), active.clear();
      for (size_t i = i_begin; i < i_end; ++i) {
        // Graceful defocus: a failed lens-shift fit falls back to phase shifting.
        if (fallback && state[i] == PixelState::kFitFailed) state[i] = PixelState::kActive;
        if (state[i] != PixelState::kActive) continue;
        // Per-sample noise: from the lens-shift residual (many samples) or the phase-shift
        // residuals (K > 3), else a floor of 1% of the white level; plus a systematic part
        // (model errors: harmonics, defocus, jitter) proportional to the modulation.
        const double sigma =
            use_ls && ls.samples[i] > 4
                ? ls.residual_rms[i] *
                      std::sqrt(ls.samples[i] / (ls.samples[i] - ls.fit_parameters))
                : PhaseShiftSigma(plan, ps, i);
        sigmas.push_back(std::max(sigma, 1e-4 * level[i]));
        active.push_back(i);
      }
      UnwrapInputs(ps, solvers, options.systematic_phase_noise, active, sigmas, &th, &wt);
      unwrapped.resize(active.size());
      if (hinted) {
        // The fringe orders phase shifting chose on its own (UnwrapPhaseShift), the mean and
        // residual with these weights; the full search where that fails.
        hint.resize(active.size());
        for (size_t a = 0; a < active.size(); ++a) hint[a] = ps.u_unwrapped.At(active[a]);
        unwrapper.UnwrapAtMany(th.data(), wt.data(), hint.data(), static_cast<int>(active.size()),
                               unwrapped.data());
        for (size_t a = 0; a < active.size(); ++a)
          if (!unwrapped[a].valid)
            unwrapped[a] = unwrapper.Unwrap(th.data() + a * nper, wt.data() + a * nper);
      } else {
        unwrapper.UnwrapMany(th.data(), wt.data(), static_cast<int>(active.size()),
                             unwrapped.data());
      }
      for (size_t a = 0; a < active.size(); ++a) {
        const size_t i = active[a];
        const double sigma = sigmas[a];
        const UnwrapResult& ur = unwrapped[a];
        if (coarse) {
          out.u_coarse[i] = static_cast<float>(ur.u);
          out.unwrap_residual[i] = static_cast<float>(ur.residual);
        }
        if (!ur.valid) {
          state[i] = PixelState::kUnwrapFailed;
          continue;
        }
        double u = ur.u, c = 1.0;
        bool ls_pixel = use_ls && std::isfinite(ls.phase0[i]);
        if (ls_pixel) {
          out.sigma_u[i] = static_cast<float>(
              std::sqrt(2.0 * sigma * sigma / (ls.samples[i] * ls.amplitude[i] * ls.amplitude[i])) /
              kPi);
          // Eq. 2: alpha = lambda (round(omega w / lambda - phi) + phi), lambda = 2 px, phi the
          // fine phase in cycles. u_fine = 1/2 - phase0 / pi (mod 2), see reconstruct.h.
          const double phi = Wrap2Pi(kPi / 2 - ls.phase0[i]) / (2 * kPi);  // cycles in [0, 1)
          u = 2.0 * (RoundHalfAwayD(ur.u / 2.0 - phi) + phi);
          const double comb = ur.u - u;
          const double e = std::pow(ls.residual_rms[i] / ls.amplitude[i], 2);  // Eq. 4's E
          c = 1.0 - std::sqrt(e * options.confidence_t);
          if (fallback && !(c >= options.min_confidence && c > 0)) {
            ls_pixel = false;  // the stripes have lost their contrast: phase shifting decides
            u = ur.u;
          } else if (std::abs(comb) > options.max_combination_residual_px) {
            // Good stripes that disagree with the coarse column by a period: neither is trusted.
            state[i] = PixelState::kCombination;
            continue;
          } else {
            c *= 1.0 - std::pow(comb / options.max_combination_residual_px, 2);
          }
        }
        if (!ls_pixel) {
          out.source[i] = 1;
          double info = 0.0;  // Fisher information of u from the periods
          // Fallback pixels: the model errors (systematic_phase_noise) count as in the weights.
          const double sys2 = use_ls ? std::pow(options.systematic_phase_noise, 2) : 0.0;
          for (int p = 0; p < nper; ++p)
            info += std::pow(2 * kPi / periods[p].period, 2) /
                    (solvers[p].ThetaVariance(sigma, modulation[p][i]) + sys2);
          out.sigma_u[i] = static_cast<float>(1.0 / std::sqrt(info));
          double e = 0.0;
          for (int p = 0; p < nper; ++p)  // (no array: 3 frames, residual 0)
            if (!ps_res[p].empty()) e = std::max(e, std::pow(ps_res[p][i] / modulation[p][i], 2));
          c = 1.0 - std::sqrt(e * options.confidence_t);
          if (use_ls) c *= options.phase_shift_fallback_confidence;
        }
        if (nper > 1) c *= 1.0 - std::pow(ur.residual / options.max_unwrap_residual, 2);
        c = std::clamp(c, 0.0, 1.0);
        if (!(c >= options.min_confidence) || c <= 0) {
          state[i] = PixelState::kLowConfidence;
          continue;
        }
        out.u[i] = static_cast<float>(u);
        out.confidence[i] = static_cast<float>(c);
      }
    }
  });
  if (reference_positions) {
    // The differences gathered in parallel (counted per block, then written at the blocks'
    // offsets); their median does not depend on the order.
    auto use = [&](size_t i) {
      return out.source[i] == 0 && std::isfinite(out.u[i]) && std::isfinite(out.u_coarse[i]);
    };
    std::vector<size_t> count(static_cast<size_t>(blocks) + 1, 0);
    ParallelFor(blocks, [&](int64_t b) {
      const size_t i_end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
      size_t n = 0;
      for (size_t i = static_cast<size_t>(b) * kBlock; i < i_end; ++i) n += use(i);
      count[static_cast<size_t>(b) + 1] = n;
    });
    for (int b = 0; b < blocks; ++b) count[b + 1] += count[b];
    std::vector<float> d(count[blocks]);
    ParallelFor(blocks, [&](int64_t b) {
      const size_t i_end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
      size_t k = count[b];
      for (size_t i = static_cast<size_t>(b) * kBlock; i < i_end; ++i)
        if (use(i)) d[k++] = out.u_coarse[i] - out.u[i];
    });
    if (d.size() >= 1000) {
      std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
      out.ls_offset_px = d[d.size() / 2];
      ParallelForRows(blocks, [&](int b0, int b1) {
        const size_t i_end = std::min(np, static_cast<size_t>(b1) * kBlock);
        for (size_t i = static_cast<size_t>(b0) * kBlock; i < i_end; ++i)
          if (out.source[i] == 0 && std::isfinite(out.u[i]))
            out.u[i] = static_cast<float>(out.u[i] + out.ls_offset_px);
      });
    }
  }
  return out;
}

void RejectIsolatedColumns(const RoiGrid& grid, const CombineOptions& options,
                           CombinedPixels* combined, PixelStates* state) {
  if (options.isolated_max_region_px <= 0 || grid.pixels() == 0) return;
  std::vector<float>& u = combined->u;
  // filterSpeckles takes 16-bit signed values: u in fixed point, as many fractional bits as the
  // projector's range allows (16ths of a pixel up to 2000 px).
  std::vector<float> row_max(grid.height, 0.0f);
  ParallelForRows(grid.height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      float m = 0.0f;
      const float* row = u.data() + static_cast<size_t>(y) * grid.width;
      for (int x = 0; x < grid.width; ++x)
        if (std::isfinite(row[x])) m = std::max(m, std::abs(row[x]));
      row_max[y] = m;
    }
  });
  const float u_max = row_max.empty() ? 0.0f : *std::max_element(row_max.begin(), row_max.end());
  const double scale = std::min(16.0, 32000.0 / std::max(1.0f, u_max));
  constexpr int16_t kNone = std::numeric_limits<int16_t>::min();
  cv::Mat fixed(grid.height, grid.width, CV_16SC1);
  ParallelForRows(grid.height, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y) {
      int16_t* row = fixed.ptr<int16_t>(y);
      for (int x = 0; x < grid.width; ++x) {
        const float v = u[static_cast<size_t>(y) * grid.width + x];
        row[x] = std::isfinite(v) ? static_cast<int16_t>(RoundHalfAway(v * scale)) : kNone;
      }
    }
  });
  // filterSpeckles (serial) on bands of rows in parallel, each with `margin` rows of its
  // neighbours on either side, keeping its own rows' verdicts: the same as one call on the whole
  // image. A region of at most S pixels spans at most S rows, so a band sees all of it; a larger
  // region that leaves the band reaches any pixel of the band's own rows by a path of more than
  // `margin` >= S pixels inside the band, so the band sees more than S of its pixels too.
  const int max_region = options.isolated_max_region_px;
  const int margin = max_region + 1;
  const int band_rows = std::max(256, 8 * margin);
  const int bands = (grid.height + band_rows - 1) / band_rows;
  ParallelFor(bands, [&](int64_t band) {
    const int y0 = static_cast<int>(band) * band_rows;
    const int y1 = std::min(grid.height, y0 + band_rows);
    const int m0 = std::max(0, y0 - margin), m1 = std::min(grid.height, y1 + margin);
    cv::Mat part = fixed.rowRange(m0, m1).clone();
    cv::filterSpeckles(part, kNone, max_region,
                       std::max(1.0, options.isolated_max_step_px * scale));
    for (int y = y0; y < y1; ++y) {
      const int16_t* row = part.ptr<int16_t>(y - m0);
      for (int x = 0; x < grid.width; ++x) {
        const size_t i = static_cast<size_t>(y) * grid.width + x;
        if (row[x] != kNone || !std::isfinite(u[i])) continue;
        (*state)[i] = PixelState::kIsolated;
        u[i] = std::numeric_limits<float>::quiet_NaN();
        combined->confidence[i] = 0.0f;
      }
    }
  });
}

}  // namespace mesoscan
