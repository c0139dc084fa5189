#include "heightfield/phase_harmonics.h"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/error.h"
#include "core/numbers.h"
#include "heightfield/phase_shift.h"

namespace mesoscan {

void HarmonicsOptions::Check() const {
  if (sample_pixels < 100)
    MESOSCAN_BAD_INPUT("HarmonicsOptions.sample_pixels: expected >= 100, got " << sample_pixels);
  if (!(min_phase_error_rad >= 0))
    MESOSCAN_BAD_INPUT("HarmonicsOptions.min_phase_error_rad: expected >= 0, got "
                       << min_phase_error_rad);
  if (!(min_significance >= 0))
    MESOSCAN_BAD_INPUT("HarmonicsOptions.min_significance: expected >= 0, got "
                       << min_significance);
}

Json ProjectorHarmonics::ToJson() const {
  Json j = {{"fitted", fitted},
            {"applied", applied},
            {"pixels", pixels},
            {"harmonics", harmonics},
            {"blur_px", blur_px},
            {"gamma", gamma},
            {"gamma_misfit_rad", gamma_misfit_rad},
            {"phase_error_rms_rad", phase_error_rms_rad},
            {"residual_rms_rad", residual_rms_rad}};
  if (!reason.empty()) j["reason"] = reason;
  return j;
}

namespace {

constexpr int kNumH = kMaxHarmonic - 1;  // h_2 .. h_kMaxHarmonic

double ValueOf(double x) { return x; }
template <class T, int N>
double ValueOf(const ceres::Jet<T, N>& x) {
  return x.a;
}

double WrapPi(double d) { return d - 2 * kPi * std::round(d / (2 * kPi)); }

// A period's solver projections: B cos theta = cos_row . I, B sin theta = sin_row . I
// (heightfield/phase_shift.h WrappedPhaseSolver's pseudo-inverse rows 1 and 2).
struct PeriodModel {
  double period = 0;
  std::vector<double> deltas, cos_row, sin_row;
};

PeriodModel MakePeriodModel(double period, const std::vector<double>& deltas) {
  const int K = static_cast<int>(deltas.size());
  Eigen::MatrixXd m(K, 3);
  for (int k = 0; k < K; ++k) m.row(k) << 1.0, std::cos(deltas[k]), -std::sin(deltas[k]);
  const Eigen::MatrixXd pinv = (m.transpose() * m).inverse() * m.transpose();
  PeriodModel pm;
  pm.period = period;
  pm.deltas = deltas;
  for (int k = 0; k < K; ++k) pm.cos_row.push_back(pinv(1, k)), pm.sin_row.push_back(pinv(2, k));
  return pm;
}

// The solver's projections (C, S) of the distorted sine at true phase theta; s = (2 pi sigma)^2.
template <class T>
void ModelProjections(const PeriodModel& pm, const T& theta, const T* h, const T& s, T* c_out,
                      T* s_out) {
  T att[kNumH];
  for (int n = 2; n <= kMaxHarmonic; ++n)
    att[n - 2] = h[n - 2] * exp(-s * double(n * n - 1) / (2.0 * pm.period * pm.period));
  T c = T(0.0), sn = T(0.0);
  for (size_t k = 0; k < pm.deltas.size(); ++k) {
    const T phi = theta + pm.deltas[k];
    T v = cos(phi);
    for (int n = 2; n <= kMaxHarmonic; ++n) v += att[n - 2] * cos(double(n) * phi);
    c += pm.cos_row[k] * v;
    sn += pm.sin_row[k] * v;
  }
  *c_out = c;
  *s_out = sn;
}

// One pixel: every period's measured phase against the model's phase at the pixel's u.
struct PixelResidual {
  const std::vector<PeriodModel>* models;
  std::vector<double> theta;  // measured, per period
  template <class T>
  bool operator()(const T* u, const T* h, const T* s, T* r) const {
    for (size_t p = 0; p < models->size(); ++p) {
      const PeriodModel& pm = (*models)[p];
      T c, sn;
      ModelProjections(pm, u[0] * (2 * kPi / pm.period), h, s[0], &c, &sn);
      T d = theta[p] - atan2(sn, c);
      d -= 2 * kPi * std::round(ValueOf(d) / (2 * kPi));
      r[p] = d;
    }
    return true;
  }
};

struct Prior {
  double weight;
  template <class T>
  bool operator()(const T* h, const T* s, T* r) const {
    for (int n = 0; n < kNumH; ++n) r[n] = weight * h[n];
    r[kNumH] = 1e-3 * weight * s[0];
    return true;
  }
};

// Per period: the inverse of theta -> F(theta) on a uniform grid of the measured phase (the
// correction to add, rad) and F' there (the information-equivalent modulation of the corrected
// phase is the measured one times F').
struct PhaseTable {
  std::vector<float> corr, amp;
};
constexpr int kTable = 2048;     // output bins
constexpr int kForward = 16384;  // forward samples

bool BuildTable(const PeriodModel& pm, const double* h, double s, PhaseTable* out) {
  std::vector<double> x(kForward + 1), a(kForward + 1);
  for (int j = 0; j <= kForward; ++j) {
    const double th = 2 * kPi * j / kForward;
    double c, sn;
    ModelProjections(pm, th, h, s, &c, &sn);
    x[j] = th + WrapPi(std::atan2(sn, c) - th);
    if (j > 0 && !(x[j] > x[j - 1])) return false;
  }
  // The information the measured phase holds on the true one: var(theta) = var(theta_measured)
  // / F'^2: the measured modulation (B |z|) times F'.
  for (int j = 0; j <= kForward; ++j) {
    const int j0 = std::max(0, j - 1), j1 = std::min(kForward, j + 1);
    a[j] = (x[j1] - x[j0]) / (2 * kPi * (j1 - j0) / kForward);
  }
  if (!(x[kForward] - x[0] > 2 * kPi - 1e-9 && x[kForward] - x[0] < 2 * kPi + 1e-9)) return false;
  out->corr.resize(kTable);
  out->amp.resize(kTable);
  int j = 0;
  for (int m = 0; m < kTable; ++m) {
    const double t = 2 * kPi * m / kTable;
    double tt = t;
    while (tt < x[0]) tt += 2 * kPi;
    while (tt >= x[0] + 2 * kPi) tt -= 2 * kPi;
    if (tt < x[j]) j = 0;
    while (j + 1 < kForward && x[j + 1] <= tt) ++j;
    const double f = (tt - x[j]) / (x[j + 1] - x[j]);
    const double th = 2 * kPi * (j + f) / kForward;
    out->corr[m] = static_cast<float>(WrapPi(th - tt));
    out->amp[m] = static_cast<float>(a[j] + f * (a[j + 1] - a[j]));
  }
  return true;
}

// theta (measured) -> true phase in [0, 2 pi), and the modulation ratio.
double Corrected(const PhaseTable& t, double theta, double* amp) {
  const double pos = theta * (kTable / (2 * kPi));
  double fl = std::floor(pos);
  const double f = pos - fl;
  int m0 = static_cast<int>(fl) % kTable;
  if (m0 < 0) m0 += kTable;
  const int m1 = (m0 + 1) % kTable;
  *amp = t.amp[m0] + f * (t.amp[m1] - t.amp[m0]);
  double th = theta + t.corr[m0] + f * (t.corr[m1] - t.corr[m0]);
  th -= 2 * kPi * std::floor(th / (2 * kPi));
  return th;
}

// RMS over the phase of F_p(theta) - theta.
double PhaseErrorRms(const PeriodModel& pm, const double* h, double s) {
  constexpr int kN = 512;
  double s2 = 0;
  for (int j = 0; j < kN; ++j) {
    const double th = 2 * kPi * j / kN;
    double c, sn;
    ModelProjections(pm, th, h, s, &c, &sn);
    s2 += std::pow(WrapPi(std::atan2(sn, c) - th), 2);
  }
  return std::sqrt(s2 / kN);
}

// h_n / h_1 of (0.5 + 0.5 cos phi)^g.
std::vector<double> GammaHarmonics(double g) {
  constexpr int kN = 512;
  std::vector<double> c(kMaxHarmonic + 1, 0.0);
  for (int j = 0; j < kN; ++j) {
    const double phi = 2 * kPi * j / kN;
    const double f = std::pow(0.5 + 0.5 * std::cos(phi), g);
    for (int n = 1; n <= kMaxHarmonic; ++n) c[n] += f * std::cos(n * phi);
  }
  std::vector<double> h(kNumH);
  for (int n = 2; n <= kMaxHarmonic; ++n) h[n - 2] = c[n] / c[1];
  return h;
}

// Worst period's RMS over the phase of the difference of two harmonic sets' phase errors.
double PhaseErrorDistance(const std::vector<PeriodModel>& models, const double* h1,
                          const double* h2, double s) {
  constexpr int kN = 256;
  double worst = 0;
  for (const PeriodModel& pm : models) {
    double s2 = 0;
    for (int j = 0; j < kN; ++j) {
      const double th = 2 * kPi * j / kN;
      double c1, s1, c2, s2_;
      ModelProjections(pm, th, h1, s, &c1, &s1);
      ModelProjections(pm, th, h2, s, &c2, &s2_);
      s2 += std::pow(WrapPi(std::atan2(s1, c1) - std::atan2(s2_, c2)), 2);
    }
    worst = std::max(worst, std::sqrt(s2 / kN));
  }
  return worst;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + mid, v.end());
  return v[mid];
}

}  // namespace

double HarmonicPhase(const ProjectorHarmonics& h, double period, const std::vector<double>& deltas,
                     double theta) {
  const PeriodModel pm = MakePeriodModel(period, deltas);
  std::vector<double> hh = h.harmonics;
  hh.resize(kNumH, 0.0);
  double c, s;
  ModelProjections(pm, theta, hh.data(), std::pow(2 * kPi * h.blur_px, 2), &c, &s);
  const double t = std::atan2(s, c);
  return t < 0 ? t + 2 * kPi : t;
}

// kAuto: the predicted plain phase error (worst period) must be at least this many times the
// fit's robust residual for the correction to be applied.
constexpr double kMinExplained = 4.0;

ProjectorHarmonics EstimateProjectorHarmonics(const ReconstructPlan& plan,
                                              const PhaseShiftPixels& ps, const PixelStates& state,
                                              const HarmonicsOptions& options) {
  ProjectorHarmonics out;
  out.harmonics.assign(kNumH, 0.0);
  const int nper = static_cast<int>(plan.periods.size());
  if (nper < 2 || !plan.periods_unwrap) {
    out.reason = "one sine period: no other period to compare its phases with";
    return out;
  }
  std::vector<PeriodModel> models;
  for (const PhasePeriod& p : plan.periods) models.push_back(MakePeriodModel(p.period, p.deltas));
  // Well-modulated kActive pixels, evenly spread.
  std::vector<size_t> candidates;
  for (size_t i = 0; i < state.size(); ++i) {
    if (state[i] != PixelState::kActive || !(ps.level[i] > 0)) continue;
    bool ok = true;
    for (int p = 0; p < nper && ok; ++p)
      ok = std::isfinite(ps.theta[p][i]) && ps.modulation[p][i] >= 0.15 * ps.level[i];
    if (ok) candidates.push_back(i);
  }
  const size_t stride = std::max<size_t>(1, candidates.size() / options.sample_pixels);
  std::vector<size_t> pixels;
  for (size_t k = 0; k < candidates.size(); k += stride) pixels.push_back(candidates[k]);
  if (pixels.size() < 100) {
    out.reason = "too few well-modulated pixels (" + std::to_string(pixels.size()) + ")";
    return out;
  }
  const size_t n = pixels.size();
  const TemporalUnwrapper unwrapper(plan.PeriodList(), plan.projector_width,
                                    std::numeric_limits<double>::infinity());
  std::vector<double> theta(n * nper), u(n), weight(nper, 1.0 / (0.1 * 0.1));
  for (size_t a = 0; a < n; ++a)
    for (int p = 0; p < nper; ++p) theta[a * nper + p] = ps.theta[p][pixels[a]];
  double h[kNumH] = {0, 0, 0, 0, 0};
  double s = 0.0;
  std::vector<PhaseTable> tables(nper);
  double sigma_r = 0.0;
  const double prior_weight = 0.03 * std::sqrt(static_cast<double>(n * nper));
  for (int pass = 0; pass < 2; ++pass) {
    // Each pixel's u from its phases as corrected so far (pass 0: as measured).
    std::vector<double> th(nper);
    for (size_t a = 0; a < n; ++a) {
      for (int p = 0; p < nper; ++p) {
        double amp;
        th[p] = pass == 0 ? theta[a * nper + p] : Corrected(tables[p], theta[a * nper + p], &amp);
      }
      u[a] = unwrapper.Unwrap(th.data(), weight.data()).u;
    }
    ceres::Problem::Options po;
    po.enable_fast_removal = false;
    ceres::Problem problem(po);
    for (size_t a = 0; a < n; ++a) {
      if (!std::isfinite(u[a])) continue;
      auto* f =
          new PixelResidual{&models, {theta.begin() + a * nper, theta.begin() + (a + 1) * nper}};
      auto* cost =
          new ceres::AutoDiffCostFunction<PixelResidual, ceres::DYNAMIC, 1, kNumH, 1>(f, nper);
      ceres::LossFunction* loss = pass == 0
                                      ? static_cast<ceres::LossFunction*>(new ceres::HuberLoss(0.1))
                                      : new ceres::CauchyLoss(std::max(0.005, 3 * sigma_r));
      problem.AddResidualBlock(cost, loss, &u[a], h, &s);
    }
    problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<Prior, kNumH + 1, kNumH, 1>(new Prior{prior_weight}),
        nullptr, h, &s);
    problem.SetParameterLowerBound(&s, 0, 0.0);
    problem.SetParameterUpperBound(&s, 0, std::pow(2 * kPi * 4.0, 2));
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_SCHUR;
    so.max_num_iterations = 30;
    so.num_threads = 2;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    if (!summary.IsSolutionUsable()) {
      out.reason = "the fit did not converge";
      return out;
    }
    for (int p = 0; p < nper; ++p)
      if (!BuildTable(models[p], h, s, &tables[p])) {
        out.reason = "the fitted harmonics are too strong for the phase steps to be undone";
        return out;
      }
    // Robust residual scale.
    std::vector<double> res;
    for (size_t a = 0; a < n; ++a) {
      if (!std::isfinite(u[a])) continue;
      std::vector<double> r(nper);
      const double* params[] = {&u[a], h, &s};
      PixelResidual{&models, {theta.begin() + a * nper, theta.begin() + (a + 1) * nper}}(
          params[0], params[1], params[2], r.data());
      for (double v : r) res.push_back(std::abs(v));
    }
    sigma_r = 1.4826 * Median(res);
  }
  out.fitted = true;
  out.pixels = static_cast<int64_t>(n);
  out.harmonics.assign(h, h + kNumH);
  out.blur_px = std::sqrt(s) / (2 * kPi);
  out.residual_rms_rad = sigma_r;
  double worst = 0;
  for (int p = 0; p < nper; ++p) {
    out.phase_error_rms_rad.push_back(PhaseErrorRms(models[p], h, s));
    worst = std::max(worst, out.phase_error_rms_rad.back());
  }
  // The nearest power law (golden section over gamma).
  double lo = 0.2, hi = 5.0;
  const double gr = 0.5 * (std::sqrt(5.0) - 1);
  auto dist = [&](double g) {
    const std::vector<double> hg = GammaHarmonics(g);
    return PhaseErrorDistance(models, hg.data(), h, s);
  };
  double x1 = hi - gr * (hi - lo), x2 = lo + gr * (hi - lo), f1 = dist(x1), f2 = dist(x2);
  for (int it = 0; it < 40; ++it) {
    if (f1 < f2) {
      hi = x2, x2 = x1, f2 = f1, x1 = hi - gr * (hi - lo), f1 = dist(x1);
    } else {
      lo = x1, x1 = x2, f1 = f2, x2 = lo + gr * (hi - lo), f2 = dist(x2);
    }
  }
  out.gamma = 0.5 * (lo + hi);
  out.gamma_misfit_rad = dist(out.gamma);
  const double standard_error = sigma_r / std::sqrt(static_cast<double>(n * nper));
  if (options.mode == HarmonicsMode::kAuto &&
      !(worst > options.min_phase_error_rad && worst > options.min_significance * standard_error)) {
    std::ostringstream why;
    why << "the response is linear within the noise (phase error " << worst << " rad, limit "
        << std::max(options.min_phase_error_rad, options.min_significance * standard_error) << ")";
    out.reason = why.str();
  } else if (options.mode == HarmonicsMode::kAuto && !(worst >= kMinExplained * sigma_r)) {
    // A projector response is shared by every period and pixel: corrected, the phases agree to
    // within a small fraction of the error it predicts (a gamma of 2.2: 0.011 against 0.20 rad).
    // Phases that disagree by about as much as the fitted "response" predicts are frames that
    // contradict each other (swapped, copied, of another capture): the consistency test must
    // see them as they are.
    std::ostringstream why;
    why << "the fitted response does not explain the phases (residual " << sigma_r
        << " rad against a predicted phase error of " << worst << " rad)";
    out.reason = why.str();
  }
  return out;
}

bool CorrectPhaseHarmonics(const ReconstructPlan& plan, const PixelStates& state,
                           ProjectorHarmonics* h, PhaseShiftPixels* ps) {
  const int nper = static_cast<int>(plan.periods.size());
  std::vector<double> hh = h->harmonics;
  hh.resize(kNumH, 0.0);
  const double s = std::pow(2 * kPi * h->blur_px, 2);
  std::vector<PhaseTable> tables(nper);
  for (int p = 0; p < nper; ++p)
    if (!BuildTable(MakePeriodModel(plan.periods[p].period, plan.periods[p].deltas), hh.data(), s,
                    &tables[p])) {
      h->reason = "the fitted harmonics are too strong for the phase steps to be undone";
      return false;
    }
  for (int p = 0; p < nper; ++p) {
    std::vector<float>& theta = ps->theta[p];
    std::vector<float>& mod = ps->modulation[p];
    for (size_t i = 0; i < state.size(); ++i) {
      if (state[i] != PixelState::kActive || !std::isfinite(theta[i])) continue;
      double amp;
      const float t = static_cast<float>(Corrected(tables[p], theta[i], &amp));
      theta[i] = t < static_cast<float>(2 * kPi) ? t : 0.0f;  // [0, 2 pi) in float too
      if (amp > 0) mod[i] = static_cast<float>(mod[i] * amp);
    }
  }
  h->applied = true;
  h->reason.clear();
  return true;
}

}  // namespace mesoscan
