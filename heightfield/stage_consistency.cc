#include "heightfield/stage_consistency.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <sstream>

#include "core/error.h"
#include "core/log.h"
#include "core/numbers.h"
#include "heightfield/phase_shift.h"

namespace mesoscan {
namespace {

// Wrapped to (-pi, pi]: fmod's remainder, then the half turn. The remainder a - n 2pi (n the
// truncated quotient) is exact, so one fused multiply-add gives it where a / 2pi rounds to that
// n, and a second where it does not (the remainder then has the wrong sign or a whole turn too
// many: n is one off towards the remainder's sign). libm's fmod (~130 instructions per call at
// these quotients) only for NaN, infinities and quotients beyond 2^49.
double WrapPi(double a) {
  constexpr double kTurn = 2 * kPi;
  if (std::abs(a) < 0x1p49 * kTurn) {
    double n = static_cast<double>(static_cast<int64_t>(a / kTurn));
    double r = std::fma(-n, kTurn, a);
    if (std::abs(r) >= kTurn || (a >= 0 ? r < 0 : r > 0)) {
      n += r > 0 ? 1 : -1;
      r = std::fma(-n, kTurn, a);
    }
    a = r == 0 ? std::copysign(0.0, a) : r;  // fmod's zero has a's sign
  } else {
    a = std::fmod(a, kTurn);
  }
  if (a > kPi) a -= kTurn;
  if (a <= -kPi) a += kTurn;
  return a;
}

// Per-sample noise (linear frame units) against the white level, measured on the lens-shift fit
// residuals of the session: medians in bins of equal pixel count, linear in between, held at
// the ends. Empty (At() = 0) with fewer than kMinPixels fitted pixels.
class LevelNoise {
 public:
  static constexpr size_t kMinPixels = 400;
  static constexpr int kBins = 16;

  LevelNoise(const PhaseShiftPixels& ps, const LensShiftPixels& ls, int params) {
    if (ls.empty() || ps.level.size() != ls.residual_rms.size()) return;
    std::vector<std::pair<float, float>> pts;  // level, sigma
    const size_t np = ls.residual_rms.size();
    const size_t stride = std::max<size_t>(1, np / 200000);
    for (size_t i = 0; i < np; i += stride) {
      const float n = ls.samples[i], r = ls.residual_rms[i], lv = ps.level[i];
      // Every fitted profile, valid or not: where the stripes are gone the residual is the
      // noise itself.
      if (!(n > params + 1) || !std::isfinite(r) || !(lv > 0)) continue;
      pts.emplace_back(lv, static_cast<float>(r * std::sqrt(n / (n - params))));
    }
    if (pts.size() < kMinPixels) return;
    // The bins of the sorted order without sorting: their edges placed by halving, then each
    // bin's middle element (its level) and median sigma.
    const size_t per = pts.size() / kBins;
    std::vector<size_t> edge(kBins + 1);
    for (int b = 0; b < kBins; ++b) edge[b] = b * per;
    edge[kBins] = pts.size();
    PlaceEdges(edge, 0, kBins, &pts);
    std::vector<float> s;
    for (int b = 0; b < kBins; ++b) {
      const size_t b0 = edge[b], b1 = edge[b + 1], mid = (b0 + b1) / 2;
      std::nth_element(pts.begin() + b0, pts.begin() + mid, pts.begin() + b1);
      s.clear();
      for (size_t k = b0; k < b1; ++k) s.push_back(pts[k].second);
      std::nth_element(s.begin(), s.begin() + s.size() / 2, s.end());
      level_.push_back(pts[mid].first);
      sigma_.push_back(s[s.size() / 2]);
    }
  }
  bool empty() const { return level_.empty(); }
  double At(double level) const {
    if (level_.empty() || !std::isfinite(level)) return 0.0;
    if (level <= level_.front()) return sigma_.front();
    if (level >= level_.back()) return sigma_.back();
    const size_t k = std::upper_bound(level_.begin(), level_.end(), level) - level_.begin();
    const double t = (level - level_[k - 1]) / std::max(1e-30, double(level_[k] - level_[k - 1]));
    return sigma_[k - 1] + t * (sigma_[k] - sigma_[k - 1]);
  }

 private:
  // Partitions pts so that the elements between edge[lo] and edge[hi] stand in the bins they
  // would in the sorted order (each bin's own order left as it falls).
  static void PlaceEdges(const std::vector<size_t>& edge, int lo, int hi,
                         std::vector<std::pair<float, float>>* pts) {
    if (hi - lo < 2) return;
    const int mid = (lo + hi) / 2;
    std::nth_element(pts->begin() + edge[lo], pts->begin() + edge[mid], pts->begin() + edge[hi]);
    PlaceEdges(edge, lo, mid, pts);
    PlaceEdges(edge, mid, hi, pts);
  }

  std::vector<float> level_, sigma_;
};

// The combine stage's per-sample noise of pixel i (stage_combine.cc).
double CombineSigma(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                    const LensShiftPixels& ls, bool ls_pixel, int params, size_t i) {
  double sigma;
  if (ls_pixel && ls.samples[i] > 4) {
    sigma = ls.residual_rms[i] * std::sqrt(ls.samples[i] / (ls.samples[i] - params));
  } else {
    sigma = 0.01 * ps.level[i];
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
  }
  return std::max(sigma, 1e-4 * ps.level[i]);
}

// The phase differences (radians, per period) of two columns `offset` px apart.
std::vector<double> CodeDifference(const std::vector<double>& periods, double offset) {
  std::vector<double> out(periods.size());
  for (size_t p = 0; p < periods.size(); ++p) {
    const double c = offset / periods[p];
    out[p] = 2 * kPi * (c - std::round(c));
  }
  return out;
}

// A column offset the code comes close to confusing with no offset, and the phase differences
// there.
struct Rival {
  double offset = 0;
  std::vector<double> diff;
};

// The offsets the code comes closest to confusing (at least half the finest period, less than
// the projector's width): the interior local minima of the code distance over the offset, the
// closest kMaxRivals. A pixel is decoded to a wrong fringe order only if its phase errors cover
// about half the distance to one of them (in its own noise: sum over periods of difference^2 /
// variance). The far end of the range is no minimum of its own: a pixel reaches offsets up to
// its distance to the farther projector edge, checked per pixel (a cue period as wide as the
// projector is ambiguous only at the projector's edges). Empty for a single period (no fringe
// order to choose: its depth sigma bounds it instead).
std::vector<Rival> RivalColumns(const ReconstructPlan& plan) {
  constexpr size_t kMaxRivals = 32;
  const std::vector<double> periods = plan.PeriodList();
  const size_t n = periods.size();
  if (n < 2 || !(plan.projector_width > 0)) return {};
  const double finest = *std::min_element(periods.begin(), periods.end());
  const double step = finest / 2000.0;
  auto norm2 = [&](double d) {  // CodeDifference's squared norm, without its array
    double n2 = 0;
    for (const double period : periods) {
      const double c = d / period, v = 2 * kPi * (c - std::round(c));
      n2 += v * v;
    }
    return n2;
  };
  std::vector<std::pair<double, double>> minima;  // norm^2, offset
  double prev2 = std::numeric_limits<double>::infinity(), prev1 = prev2;
  const size_t steps = static_cast<size_t>((plan.projector_width - finest / 2) / step);
  for (size_t k = 0; k <= steps; ++k) {
    const double d = finest / 2 + k * step;
    const double cur = norm2(d);
    if (k >= 2 && prev1 <= prev2 && prev1 <= cur) minima.emplace_back(prev1, d - step);
    prev2 = prev1;
    prev1 = cur;
  }
  std::sort(minima.begin(), minima.end());
  if (minima.size() > kMaxRivals) minima.resize(kMaxRivals);
  std::vector<Rival> rivals;
  for (const auto& m : minima) rivals.push_back({m.second, CodeDifference(periods, m.second)});
  return rivals;
}

// Each sine period checked against the lens-shift stripes alone, on a sample of the pixels with a
// stripes fit: the fine column (mod 2 px) and the period's wrapped phase must agree at some
// stripe period (the nearest of 2 x period candidates) within 5 sigma. The fraction of pixels
// where they do not, per period; -1 for a period too long for the test to tell (its candidates'
// spacing below 2.5 x that tolerance: a random phase would pass more than 80 % of the time);
// empty without lens shift.
std::vector<double> StripePairFailures(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                                       const LensShiftPixels& ls, double ls_offset_px,
                                       const LevelNoise& noise, int params,
                                       const std::vector<WrappedPhaseSolver>& solvers, double sys2,
                                       double var_scale) {
  const int nper = static_cast<int>(plan.periods.size());
  if (ls.empty() || ls.phase0.size() != ps.level.size()) return {};
  const size_t np = ls.phase0.size();
  const size_t stride = std::max<size_t>(1, np / 20000);
  std::vector<int64_t> tried(nper, 0), failed(nper, 0);
  std::vector<double> tol2_sum(nper, 0.0);
  for (size_t i = 0; i < np; i += stride) {
    if (!std::isfinite(ls.phase0[i]) || !(ps.level[i] > 0)) continue;
    double sigma = noise.At(ps.level[i]);
    if (ls.samples[i] > params + 1 && std::isfinite(ls.residual_rms[i]))
      sigma = std::max(sigma, ls.residual_rms[i] * std::sqrt(static_cast<double>(ls.samples[i]) /
                                                             (ls.samples[i] - params)));
    const double phi =
        std::fmod(std::fmod(kPi / 2 - ls.phase0[i], 2 * kPi) + 2 * kPi, 2 * kPi) / (2 * kPi);
    const double u_fine = 2.0 * phi + ls_offset_px;
    for (int p = 0; p < nper; ++p) {
      const double theta = ps.theta[p][i], b = ps.modulation[p][i];
      if (!std::isfinite(theta) || !(b > 0)) continue;
      const double lambda = plan.periods[p].period;
      const double tol2 = 25 * var_scale * (solvers[p].ThetaVariance(sigma, b) + sys2);
      const int candidates = static_cast<int>(std::min(2.0 * std::ceil(lambda), 256.0));
      double best = kPi;
      for (int k = 0; k < candidates; ++k)
        best = std::min(best, std::abs(WrapPi(theta - 2 * kPi * (u_fine + 2.0 * k) / lambda)));
      ++tried[p];
      tol2_sum[p] += tol2;
      failed[p] += best * best > tol2;
    }
  }
  std::vector<double> out(nper, -1.0);
  for (int p = 0; p < nper; ++p) {
    if (tried[p] < 100) continue;
    // Candidates 2 px apart in u: their phases lie 4 pi / period apart (2 pi / period for an
    // odd integer period); a random phase is within the tolerance of one too often beyond that.
    const double spacing = 2 * kPi / plan.periods[p].period;
    if (spacing < 2.5 * std::sqrt(tol2_sum[p] / tried[p])) continue;
    out[p] = static_cast<double>(failed[p]) / tried[p];
  }
  return out;
}

std::string FrameList(const Session& session, const ReconstructPlan& plan,
                      const std::vector<int>& stack_frames) {
  std::ostringstream o;
  const size_t n = stack_frames.size();
  for (size_t k = 0; k < n; ++k) {
    if (n > 4 && k == 2) {
      o << ", ... ";
      k = n - 1;
    } else if (k) {
      o << ", ";
    }
    o << session.frames[plan.frames[stack_frames[k]]].file;
  }
  return o.str();
}

}  // namespace

void ConsistencyOptions::Check() const {
  if (!(max_phase_z > 0)) MESOSCAN_BAD_INPUT("max_phase_z: expected > 0, got " << max_phase_z);
  if (!(min_order_margin_sigma > 0))
    MESOSCAN_BAD_INPUT("min_order_margin_sigma: expected > 0, got " << min_order_margin_sigma);
  if (!(max_inconsistent_fraction >= 0 && max_inconsistent_fraction <= 1))
    MESOSCAN_BAD_INPUT("max_inconsistent_fraction: expected a value in [0, 1], got "
                       << max_inconsistent_fraction);
  if (!(max_depth_sigma_m > 0))
    MESOSCAN_BAD_INPUT("max_depth_sigma_m: expected > 0, got " << max_depth_sigma_m);
  if (!(max_depth_sigma_per_footprint >= 0) || !std::isfinite(max_depth_sigma_per_footprint))
    MESOSCAN_BAD_INPUT("max_depth_sigma_per_footprint: expected >= 0, got "
                       << max_depth_sigma_per_footprint);
}

Json ConsistencyReport::ToJson() const {
  return {{"tested", tested},
          {"inconsistent", inconsistent},
          {"ambiguous", ambiguous},
          {"ambiguous_stripes", ambiguous_stripes},
          {"period_inconsistent_fraction", period_inconsistent_fraction},
          {"period_phase_rms_rad", period_phase_rms_rad},
          {"noise_model", noise_model},
          {"noise_scale", noise_scale},
          {"decoded", decoded},
          {"contradicted_fraction", contradicted_fraction},
          {"period_phase_excess", period_phase_excess}};
}

namespace {

// The fixed quantities of the per-pixel tests: the periods' solvers and rates, the rival
// columns, and the options' thresholds.
struct PhaseTests {
  PhaseTests(const ReconstructPlan& plan, const ConsistencyOptions& options)
      : nper(static_cast<int>(plan.periods.size())),
        rivals(RivalColumns(plan)),
        period_list(plan.PeriodList()),
        finest_period(
            period_list.empty() ? 0.0 : *std::min_element(period_list.begin(), period_list.end())),
        min_rival_d2(std::pow(2 * options.min_order_margin_sigma, 2)),
        sys2(std::pow(options.systematic_phase_noise, 2)),
        max_coarse_sigma_px(1.0 / options.min_order_margin_sigma),
        tz(options.max_phase_z) {
    for (const auto& p : plan.periods) solvers.emplace_back(p.deltas);
    for (const Rival& r : rivals) {
      double n2 = 0;
      for (const double v : r.diff) n2 += v * v;
      rivals_min_norm2 = std::min(rivals_min_norm2, n2);
    }
    rate.resize(nper);
    for (int p = 0; p < nper; ++p) rate[p] = 2 * kPi / plan.periods[p].period;
  }
  int nper;
  std::vector<WrappedPhaseSolver> solvers;
  std::vector<Rival> rivals;
  std::vector<double> period_list;
  double finest_period;
  double min_rival_d2;
  double rivals_min_norm2 = std::numeric_limits<double>::infinity();
  double sys2;
  double max_coarse_sigma_px;
  double tz;
  std::vector<double> rate;
};

// The predicted phase variance checked against the phases themselves, on the lens-shift
// pixels (whose column is precise): median over pixels of d^2 / var is 0.455 for an honest
// prediction (chi^2, one degree of freedom). Where the prediction is too large (the median
// over periods), every predicted variance is scaled down to match: the noise model and the
// systematic term are upper bounds (and lens-shift frames out of order raise their fit
// residuals, not the sine frames' noise); a coarse column 1.6x less precise than predicted
// failed the stripes' test at 93 % of a plane's pixels whose points were at the Cramer-Rao
// floor. Never up: where the phases disagree more than predicted, the wrong columns
// of a mislabelled set would set the scale; the contradiction verdict below speaks for them.
double PhaseVarianceScale(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                          const LensShiftPixels& ls, const LevelNoise& noise, int params,
                          const PhaseTests& t, const CombinedPixels& combined,
                          const PixelStates& state) {
  const int nper = t.nper;
  const size_t np = state.size();
  double var_scale = 1.0;
  std::vector<std::vector<float>> q(nper);
  const size_t stride = std::max<size_t>(1, np / 20000);
  for (size_t i = 0; i < np; i += stride) {
    const double u = combined.u[i];
    if (state[i] != PixelState::kActive || !std::isfinite(u) || combined.source[i] != 0) continue;
    const double sigma =
        std::max(CombineSigma(plan, ps, ls, true, params, i), noise.At(ps.level[i]));
    for (int p = 0; p < nper; ++p) {
      const double v = t.solvers[p].ThetaVariance(sigma, ps.modulation[p][i]) + t.sys2;
      const double d = WrapPi(ps.theta[p][i] - t.rate[p] * u);
      if (std::isfinite(d) && v > 0) q[p].push_back(static_cast<float>(d * d / v));
    }
  }
  std::vector<double> ratio;
  for (int p = 0; p < nper; ++p) {
    if (q[p].size() < 200) continue;
    std::nth_element(q[p].begin(), q[p].begin() + q[p].size() / 2, q[p].end());
    ratio.push_back(q[p][q[p].size() / 2] / 0.455);
  }
  if (!ratio.empty()) {
    std::nth_element(ratio.begin(), ratio.begin() + ratio.size() / 2, ratio.end());
    const double r = ratio[ratio.size() / 2];
    if (r < 1) var_scale = std::max(r, 1.0 / 256);
  }
  return var_scale;
}

// The median of a chi-square variable of k degrees of freedom (exact for 1 and 2, else the
// Wilson-Hilferty approximation, within 0.5 % from 3 on).
double ChiSquareMedian(int k) {
  if (k == 1) return 0.4549;
  if (k == 2) return 2 * std::log(2.0);
  const double a = 2.0 / (9.0 * k);
  return k * std::pow(1 - a, 3);
}

// As PhaseVarianceScale, without lens shift: the column of a phase-shift pixel is the weighted
// mean of its own periods' phases (the unwrapping), so sum over periods of d^2 / var is
// chi-square with nper - 1 degrees of freedom where the predicted variances are honest. Where
// the prediction is too large (the median of that sum over pixels below chi-square's), every
// predicted variance is scaled down to match; never up. The predicted noise (1% of the level
// without residuals of its own, plus the systematic term) is an upper bound that a three-step
// set cannot check per pixel; its own phases can, on every pixel at once.
double PhaseOnlyVarianceScale(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                              const LensShiftPixels& ls, const LevelNoise& noise, int params,
                              const PhaseTests& t, const CombinedPixels& combined,
                              const PixelStates& state) {
  const int nper = t.nper;
  if (nper < 2 || !plan.periods_unwrap) return 1.0;
  const size_t np = state.size();
  const size_t stride = std::max<size_t>(1, np / 20000);
  std::vector<float> q;
  for (size_t i = 0; i < np; i += stride) {
    const double u = combined.u[i];
    if (state[i] != PixelState::kActive || !std::isfinite(u)) continue;
    const double sigma =
        std::max(CombineSigma(plan, ps, ls, false, params, i), noise.At(ps.level[i]));
    double chi2 = 0;
    for (int p = 0; p < nper; ++p) {
      const double v = t.solvers[p].ThetaVariance(sigma, ps.modulation[p][i]) + t.sys2;
      chi2 += std::pow(WrapPi(ps.theta[p][i] - t.rate[p] * u), 2) / v;
    }
    if (std::isfinite(chi2)) q.push_back(static_cast<float>(chi2));
  }
  if (q.size() < 200) return 1.0;
  std::nth_element(q.begin(), q.begin() + q.size() / 2, q.end());
  const double r = q[q.size() / 2] / ChiSquareMedian(nper - 1);
  return r < 1 ? std::max(r, 1.0 / 256) : 1.0;
}

// The nearest wrong fringe order of a pixel at column u, in its own phase noise (var per
// period, var_max their largest): unsure unless at least twice the margin away (a wrong order
// needs an error of half that distance). Only offsets that stay within the projector count: up
// to the farther edge, where the code distance is checked too (the range's end, approached by
// the edge columns).
bool FringeOrderUnsure(const ReconstructPlan& plan, const PhaseTests& t, double u,
                       const std::vector<double>& var, double var_max) {
  if (t.rivals.empty()) return false;
  const int nper = t.nper;
  bool order_unsure = false;
  const double reach = std::max(u, plan.projector_width - u);
  const auto too_close = [&](const std::vector<double>& r) {
    double d2 = 0;
    for (int p = 0; p < nper; ++p) d2 += r[p] * r[p] / var[p];
    return !(d2 >= t.min_rival_d2);
  };
  if (!(t.rivals_min_norm2 / var_max >= t.min_rival_d2))
    for (const Rival& r : t.rivals)
      if (r.offset <= reach && too_close(r.diff)) {
        order_unsure = true;
        break;
      }
  if (!order_unsure && reach >= t.finest_period / 2 && reach < plan.projector_width) {
    double d2 = 0;
    for (int p = 0; p < nper; ++p) {
      const double c = reach / t.period_list[p];
      d2 += std::pow(2 * kPi * (c - std::round(c)), 2) / var[p];
    }
    order_unsure = !(d2 >= t.min_rival_d2);
  }
  return order_unsure;
}

// The counts of the per-pixel tests (summed over the pixels, per period where so named).
struct PixelTally {
  explicit PixelTally(int nper)
      : period_bad(nper, 0),
        period_worst(nper, 0),
        period_d2(nper, 0.0),
        period_var(nper, 0.0),
        period_n(nper, 0) {}
  int64_t tested = 0, inconsistent = 0, ambiguous = 0, stripes = 0;
  std::vector<int64_t> period_bad, period_worst;
  std::vector<double> period_d2, period_var;
  std::vector<int64_t> period_n;
  int64_t failed_before = 0;  // kUnwrapFailed or kCombination: the combine stage's contradictions
  int64_t explained_before = 0;  // kCombination where the coarse column cannot fix the period
};

// Every decoded pixel tested: its phases against its column (kInconsistent beyond max_phase_z),
// its fringe order and stripes' period against the noise (kAmbiguous); pixels that fail lose
// their column and confidence, phase-shift-only pixels get their sigma with the measured noise.
PixelTally TestPixels(const ReconstructPlan& plan, const PhaseShiftPixels& ps,
                      const LensShiftPixels& ls, const LevelNoise& noise, int params,
                      const PhaseTests& t, double var_scale, CombinedPixels* combined,
                      PixelStates* state_out) {
  PixelStates& state = *state_out;
  const int nper = t.nper;
  const size_t np = state.size();
  const bool use_ls = !ls.empty();
  const std::vector<double>& rate = t.rate;
  const std::vector<WrappedPhaseSolver>& solvers = t.solvers;
  const double sys2 = t.sys2, tz = t.tz, max_coarse_sigma_px = t.max_coarse_sigma_px;
  constexpr int kBlock = 4096;
  const int blocks = static_cast<int>((np + kBlock - 1) / kBlock);
  PixelTally total(nper);
  std::mutex mutex;
  // The sums of squares per block of pixels, added in block order after the loop: the figures
  // do not depend on how the blocks were shared among the threads.
  std::vector<double> block_d2(static_cast<size_t>(blocks) * nper, 0.0);
  std::vector<double> block_v2(static_cast<size_t>(blocks) * nper, 0.0);
  tbb::parallel_for(tbb::blocked_range<int>(0, blocks, 8), [&](const auto& range) {
    const int b0 = range.begin(), b1 = range.end();
    int64_t t_n = 0, i_n = 0, a_n = 0, s_n = 0;
    std::vector<int64_t> bad(nper, 0), worst(nper, 0), n_good(nper, 0);
    std::vector<double> z(nper), var(nper), dp(nper);
    int64_t f_n = 0, x_n = 0;
    for (size_t i = static_cast<size_t>(b0) * kBlock; i < std::min(np, size_t(b1) * kBlock); ++i) {
      double* d2 = &block_d2[(i / kBlock) * nper];
      double* v2 = &block_v2[(i / kBlock) * nper];
      const double u = combined->u[i];
      if (state[i] == PixelState::kUnwrapFailed || state[i] == PixelState::kCombination) {
        // A contradiction, unless the noise explains it: a coarse column too uncertain to fix
        // the stripes' period (a combination "failure" is then a guess gone wrong).
        bool explained = false;
        if (state[i] == PixelState::kCombination) {
          const double sigma =
              std::max(CombineSigma(plan, ps, ls, true, params, i), noise.At(ps.level[i]));
          double info = 0.0;
          for (int p = 0; p < nper; ++p)
            info += rate[p] * rate[p] /
                    (var_scale * (solvers[p].ThetaVariance(sigma, ps.modulation[p][i]) + sys2));
          explained = !(1.0 / std::sqrt(info) <= max_coarse_sigma_px);
        }
        if (explained)
          ++s_n, ++x_n;
        else
          ++f_n;
        continue;
      }
      if (state[i] != PixelState::kActive || !std::isfinite(u)) continue;
      ++t_n;
      const bool ls_pixel = use_ls && combined->source[i] == 0;
      double sigma = CombineSigma(plan, ps, ls, ls_pixel, params, i);
      sigma = std::max(sigma, noise.At(ps.level[i]));
      const double su = ls_pixel ? combined->sigma_u[i] : 0.0;
      double info = 0.0, var_max = 0.0, z_max = 0.0;
      int p_max = 0;
      for (int p = 0; p < nper; ++p) {
        var[p] = var_scale * (solvers[p].ThetaVariance(sigma, ps.modulation[p][i]) + sys2);
        var_max = std::max(var_max, var[p]);
        info += rate[p] * rate[p] / var[p];
        dp[p] = WrapPi(ps.theta[p][i] - rate[p] * u);
        z[p] = std::abs(dp[p]) / std::sqrt(var[p] + std::pow(rate[p] * su, 2));
        if (!(z[p] <= z_max)) z_max = z[p], p_max = p;  // NaN counts as the worst
      }
      const double coarse_sigma_px = 1.0 / std::sqrt(info);
      bool reject_inconsistent = !(z_max <= tz);
      if (reject_inconsistent) {
        ++worst[p_max];
        for (int p = 0; p < nper; ++p) bad[p] += !(z[p] <= tz);
      } else {
        for (int p = 0; p < nper; ++p) {
          d2[p] += std::pow(dp[p], 2);
          v2[p] += var[p] + std::pow(rate[p] * su, 2);
          ++n_good[p];
        }
      }
      const bool order_unsure = FringeOrderUnsure(plan, t, u, var, var_max);
      const bool stripes_unsure = ls_pixel && !(coarse_sigma_px <= max_coarse_sigma_px);
      if (reject_inconsistent) {
        state[i] = PixelState::kInconsistent;
        ++i_n;
      } else if (order_unsure || stripes_unsure) {
        state[i] = PixelState::kAmbiguous;
        ++a_n;
        s_n += stripes_unsure && !order_unsure;
      } else if (!ls_pixel) {
        // Phase shifting alone: its sigma with the measured noise, if larger.
        const double sys_fallback = use_ls ? sys2 : 0.0;
        double info_ps = 0.0;
        for (int p = 0; p < nper; ++p)
          info_ps +=
              rate[p] * rate[p] /
              (var_scale * (solvers[p].ThetaVariance(sigma, ps.modulation[p][i]) + sys_fallback));
        const float s = static_cast<float>(1.0 / std::sqrt(info_ps));
        if (s > combined->sigma_u[i]) combined->sigma_u[i] = s;
      }
      if (state[i] != PixelState::kActive) {
        combined->u[i] = std::numeric_limits<float>::quiet_NaN();
        combined->confidence[i] = 0.0f;
      }
    }
    std::lock_guard<std::mutex> lock(mutex);
    total.tested += t_n, total.inconsistent += i_n, total.ambiguous += a_n, total.stripes += s_n,
        total.failed_before += f_n;
    total.explained_before += x_n;
    for (int p = 0; p < nper; ++p) {
      total.period_bad[p] += bad[p], total.period_worst[p] += worst[p];
      total.period_n[p] += n_good[p];
    }
  });
  for (int b = 0; b < blocks; ++b)
    for (int p = 0; p < nper; ++p) {
      total.period_d2[p] += block_d2[static_cast<size_t>(b) * nper + p];
      total.period_var[p] += block_v2[static_cast<size_t>(b) * nper + p];
    }
  return total;
}

void Summarise(const PixelTally& t, int nper, ConsistencyReport* report) {
  report->tested = t.tested;
  report->inconsistent = t.inconsistent;
  report->ambiguous = t.ambiguous;
  report->ambiguous_stripes = t.stripes;
  report->decoded = t.tested + t.failed_before + t.explained_before;
  report->contradicted_fraction =
      report->decoded ? static_cast<double>(t.failed_before + t.inconsistent) / report->decoded
                      : 0.0;
  report->period_phase_excess.assign(nper, 0.0);
  for (int p = 0; p < nper; ++p) {
    report->period_inconsistent_fraction[p] =
        report->tested ? static_cast<double>(t.period_bad[p]) / report->tested : 0.0;
    report->period_phase_rms_rad[p] =
        t.period_n[p] ? std::sqrt(t.period_d2[p] / t.period_n[p]) : 0.0;
    report->period_phase_excess[p] =
        t.period_n[p] ? std::sqrt(t.period_d2[p] / std::max(1e-300, t.period_var[p])) : 0.0;
  }
}

// A capture whose phases contradict each other at most pixels is refused: named by the periods
// whose phases stand out (their error, over the pixels that passed, several times their noise
// and the other periods'), else the sine and lens-shift frames as a whole (too noisy for their
// code, or not the frames described). Left alone, such a capture keeps the pixels where a wrong
// column happens to fit every period.
void RefuseContradictedCapture(const ReconstructPlan& plan, const Session& session,
                               const PhaseShiftPixels& ps, const LensShiftPixels& ls,
                               const LevelNoise& noise, int params, const PhaseTests& t,
                               double var_scale, const PixelTally& tally,
                               const ConsistencyReport& report, const CombinedPixels& combined) {
  const int nper = t.nper;
  std::vector<int> named;
  bool blame_stripes = false;
  const std::vector<double> pair = StripePairFailures(plan, ps, ls, combined.ls_offset_px, noise,
                                                      params, t.solvers, t.sys2, var_scale);
  if (!pair.empty()) {
    // Each short period against the stripes alone (independent of the unwrapping): a period
    // that contradicts them at many pixels is named; every period alike: the stripes.
    int informative = 0, failing = 0;
    for (int p = 0; p < nper; ++p) {
      if (!(pair[p] >= 0)) continue;
      ++informative;
      if (pair[p] > 0.1) {
        named.push_back(p);
        ++failing;
      }
    }
    if (informative > 1 && failing == informative) {
      named.clear();
      blame_stripes = true;
    }
  } else {
    double least = std::numeric_limits<double>::infinity();
    for (int p = 0; p < nper; ++p)
      if (tally.period_n[p] > 0) least = std::min(least, report.period_phase_excess[p]);
    for (int p = 0; p < nper; ++p)
      if (nper > 1 && tally.period_n[p] >= 20 && report.period_phase_excess[p] > 2.0 &&
          report.period_phase_excess[p] > 2.0 * least)
        named.push_back(p);
  }
  std::ostringstream o;
  const int pct = static_cast<int>(std::lround(100 * report.contradicted_fraction));
  if (blame_stripes) {
    o << FrameList(session, plan, plan.ls_stack) << ": the lens-shift frames contradict every "
      << "sine period at " << pct << "% of the decoded pixels (frames swapped, mislabelled in "
      << "session.json, or of another capture?)";
  } else if (!named.empty()) {
    for (size_t k = 0; k < named.size(); ++k) {
      const PhasePeriod& pp = plan.periods[named[k]];
      o << (k ? "; " : "") << FrameList(session, plan, pp.stack_frames) << " (sine period "
        << pp.period << " px)";
    }
    o << ": " << (named.size() > 1 ? "their phases contradict" : "its phases contradict")
      << " the other frames at " << pct << "% of the decoded pixels (frames swapped, copied, "
      << "mislabelled in session.json, in other units or of another capture?)";
  } else {
    o << "the sine" << (!ls.empty() ? " and lens-shift" : "") << " frames contradict each other at "
      << pct << "% of the decoded pixels: too dark or noisy for their code, or not the frames "
      << "session.json describes";
  }
  MESOSCAN_BAD_INPUT_AT(ErrorSite::File(session.root / "session.json"), o.str());
}

}  // namespace

ConsistencyReport CheckPhaseConsistency(const ReconstructPlan& plan, const Session& session,
                                        const PhaseShiftPixels& ps, const LensShiftPixels& ls,
                                        const ConsistencyOptions& options, CombinedPixels* combined,
                                        PixelStates* state_out) {
  ConsistencyReport report;
  const int nper = static_cast<int>(plan.periods.size());
  report.period_inconsistent_fraction.assign(nper, 0.0);
  report.period_phase_rms_rad.assign(nper, 0.0);
  if (!options.enabled || nper == 0 || static_cast<int>(ps.theta.size()) != nper) return report;
  const int params = options.four_parameter_fit ? 4 : 3;
  const LevelNoise noise(ps, ls, params);
  report.noise_model = !noise.empty();
  const PhaseTests tests(plan, options);
  const double var_scale =
      ls.empty() ? PhaseOnlyVarianceScale(plan, ps, ls, noise, params, tests, *combined, *state_out)
                 : PhaseVarianceScale(plan, ps, ls, noise, params, tests, *combined, *state_out);
  report.noise_scale = std::sqrt(var_scale);
  const PixelTally tally =
      TestPixels(plan, ps, ls, noise, params, tests, var_scale, combined, state_out);
  Summarise(tally, nper, &report);
  // The verdict. Where the frames are what session.json says, the periods and the stripes agree
  // within their noise at nearly every pixel.
  if (report.decoded >= options.min_pixels_for_verdict &&
      report.contradicted_fraction > options.max_inconsistent_fraction)
    RefuseContradictedCapture(plan, session, ps, ls, noise, params, tests, var_scale, tally, report,
                              *combined);
  MESOSCAN_LOG(kDebug) << "consistency: " << report.ToJson().dump();
  return report;
}

int64_t RejectUncertainPoints(const RoiGrid& grid, const std::vector<float>& sigma_z,
                              const ConsistencyOptions& options, const PinholeCamera& camera,
                              ScanPoints* points, PixelStates* state_out) {
  const double max_sigma_m = options.max_depth_sigma_m;
  if (!(max_sigma_m > 0) || sigma_z.size() != grid.pixels()) return 0;
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  // The footprint's share: sigma_z <= k |X - C| / f, i.e. sigma_z^2 <= per_m2 |X - C|^2.
  const double focal = std::max(std::abs(camera.K(0, 0)), std::abs(camera.K(1, 1)));
  const double per_m = focal > 0 ? options.max_depth_sigma_per_footprint / focal : 0.0;
  const Vec3d centre = camera.CentreInWorld();
  PixelStates& state = *state_out;
  const int w = grid.width;
  std::atomic<int64_t> n{0};
  tbb::parallel_for(tbb::blocked_range<int>(0, grid.height, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    int64_t rows_n = 0;
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (state[i] != PixelState::kOk || sigma_z[i] <= max_sigma_m) continue;
        const int cx = x + grid.roi.x, cy = y + grid.roi.y;
        if (per_m > 0) {
          const Vec3d p(points->xyz(cx, cy, 0), points->xyz(cx, cy, 1), points->xyz(cx, cy, 2));
          if (sigma_z[i] <= per_m * (p - centre).norm()) continue;
        }
        ++rows_n;
        state[i] = PixelState::kUncertain;
        for (int c = 0; c < 3; ++c) points->xyz(cx, cy, c) = kNaN;
        points->confidence(cx, cy) = 0.0f;
        if (!points->source.empty()) points->source(cx, cy) = kNaN;
      }
    n += rows_n;
  });
  return n.load();
}

}  // namespace mesoscan
